"""Cart-pole: a cart on a frictionless track with a point-mass pole hinged on top."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from shinro_ctrl.backend import ArrayBackend
from shinro_ctrl.errors import InvalidArgument
from shinro_ctrl.plants.base import MjcfPatch, Plant
from shinro_ctrl.validation import check_nonnegative, check_positive

if TYPE_CHECKING:
    from numpy.typing import ArrayLike

__all__ = ["CartPole"]


class CartPole(Plant):
    r"""Cart-pole with the pole angle measured from upright.

    State ``[x, x_dot, theta, theta_dot]`` (m, m/s, rad, rad/s), input ``[F]``
    (N, horizontal force on the cart). Cart mass ``M``, a point mass ``m`` at
    distance ``l`` on a massless pole, hinge damping torque ``-b theta_dot``.
    Lagrange's equations give

    .. math::

        \begin{bmatrix} M + m & m l \cos\theta \\ m l \cos\theta & m l^2 \end{bmatrix}
        \begin{bmatrix} \ddot x \\ \ddot\theta \end{bmatrix} =
        \begin{bmatrix} F + m l \dot\theta^2 \sin\theta \\ m g l \sin\theta - b \dot\theta \end{bmatrix}

    whose determinant is ``m l² (M + m sin²θ)``. At the upright equilibrium
    (the default operating point) the continuous Jacobians are

    .. math::

        A = \begin{bmatrix} 0 & 1 & 0 & 0 \\ 0 & 0 & -mg/M & b/(Ml) \\ 0 & 0 & 0 & 1 \\
            0 & 0 & (M+m)g/(Ml) & -b(M+m)/(M m l^2) \end{bmatrix},\quad
        B = \begin{bmatrix} 0 \\ 1/M \\ 0 \\ -1/(Ml) \end{bmatrix}.

    A positive angle tips the pole toward +x (MuJoCo hinge about +y).

    Args:
        cart_mass: Cart mass ``M`` [kg], > 0.
        pole_mass: Pole point mass ``m`` [kg], > 0.
        pole_length: Hinge-to-mass distance ``l`` [m], > 0.
        damping: Hinge damping ``b`` [N m s/rad], >= 0.
        gravity: ``g`` [m/s²], >= 0.
        dt: Step [s], > 0.
        track_limits: Optional ``(min, max)`` cart position [m], ``min < max``:
            inelastic stops at the ends of the track. Standalone, a step that
            carries the cart past an end puts it on the end and zeroes its
            velocity into the stop (:meth:`Plant.stop`); in MuJoCo the slider
            gets the same ``range`` (``limited="true"``). Every step in contact
            with a stop counts in ``constraint_violations`` (:meth:`limit_violation`).
        backend: The seed's array backend keyword; accepted, not used (numpy).
    """

    aliases = ("cartpole",)
    state_names = ("x", "x_dot", "theta", "theta_dot")
    input_names = ("force",)
    param_names = ("cart_mass", "pole_mass", "pole_length", "damping", "gravity")
    asset = "cartpole.xml"
    position_indices = (0, 2)
    velocity_indices = (1, 3)

    def __init__(
        self,
        cart_mass: float = 0.5,
        pole_mass: float = 0.1,
        pole_length: float = 0.5,
        damping: float = 0.0,
        gravity: float = 9.81,
        dt: float = 0.01,
        track_limits: tuple[float, float] | None = None,
        backend: ArrayBackend | None = None,
    ):
        self.M = check_positive("cart_mass", cart_mass)
        self.m = check_positive("pole_mass", pole_mass)
        self.l = check_positive("pole_length", pole_length)
        self.b = check_nonnegative("damping", damping)
        self.g = check_nonnegative("gravity", gravity)
        self.track_limits = _track_limits(track_limits)
        if self.track_limits is not None:
            self._track_lo = np.array([self.track_limits[0], -np.inf, -np.inf, -np.inf])
            self._track_hi = np.array([self.track_limits[1], np.inf, np.inf, np.inf])
        self._init(
            dt=dt,
            params={
                "cart_mass": self.M,
                "pole_mass": self.m,
                "pole_length": self.l,
                "damping": self.b,
                "gravity": self.g,
            },
            backend=backend,
        )

    def equations(self, bk, x, u, p):
        _, x_dot, theta, theta_dot = bk.unpack(x, 4)
        (force,) = bk.unpack(u, 1)
        M, m, l, b, g = (p[k] for k in self.param_names)
        s, c = bk.sin(theta), bk.cos(theta)
        rhs_x = force + m * l * theta_dot**2 * s
        rhs_t = m * g * l * s - b * theta_dot
        det = m * l**2 * (M + m * s**2)
        x_ddot = (m * l**2 * rhs_x - m * l * c * rhs_t) / det
        theta_ddot = ((M + m) * rhs_t - m * l * c * rhs_x) / det
        return bk.stack([x_dot, x_ddot, theta_dot, theta_ddot])

    def clip_state(self, x: np.ndarray) -> np.ndarray:
        """The track's ends as inelastic stops (one state ``(4,)`` or a batch ``(N, 4)``, in place).

        The cart position is put on the end it passed and its velocity into the end is zeroed
        (see :meth:`Plant.stop`); the stop's impulse, which acts on the cart alone, changes the
        pole's rate by ``Δθ̇ = −(cos θ / l) Δẋ`` (the mass matrix's coupling), as in MuJoCo.
        """
        if self.track_limits is None:
            return x
        v_before = x[..., 1].copy()
        x = self.stop(x, self._track_lo, self._track_hi)
        # The stop's impulse acts on the cart only: M Δv = [J, 0] gives the pole Δθ̇ = −(cos θ / l) Δẋ.
        dv = x[..., 1] - v_before
        x[..., 3] -= np.cos(x[..., 2]) / self.l * dv
        return x

    def state_limits(self) -> tuple[np.ndarray, np.ndarray]:
        lo, hi = super().state_limits()
        if self.track_limits is not None:
            lo[0], hi[0] = self.track_limits
        return lo, hi

    # engine mode: joints "slider" + "hinge", motor actuator "slider"
    def mjcf_patch(self) -> MjcfPatch:
        return MjcfPatch(
            asset=self.asset,
            timestep=self.dt,
            gravity=(0.0, 0.0, -self.g),
            inertials={"cart": (self.M, (0.0, 0.0, 0.0)), "pole": (self.m, (0.0, 0.0, self.l))},
            joint_damping={"hinge": self.b},
            geom_fromto={"pole_rod": (0.0, 0.0, 0.0, 0.0, 0.0, self.l)},
            joint_range={} if self.track_limits is None else {"slider": self.track_limits},
        )

    def engine_state_map(self, x0: ArrayLike | None = None) -> tuple[np.ndarray, np.ndarray]:
        """``x = T @ z`` with MuJoCo's ``z = [slider, hinge, slider_dot, hinge_dot]``.

        See :meth:`Plant.engine_state_map`.
        """
        perm = np.array([0, 2, 1, 3])  # x = [x, x_dot, theta, theta_dot]
        return np.eye(4)[perm], perm

    def engine_read(self, engine) -> np.ndarray:
        return np.array(
            [
                engine.get_joint_qpos("slider"),
                engine.get_joint_vel("slider"),
                engine.get_joint_qpos("hinge"),
                engine.get_joint_vel("hinge"),
            ]
        )

    def engine_write(self, engine, x: np.ndarray) -> None:
        engine.set_joint_qpos("slider", x[0])
        engine.set_joint_vel("slider", x[1])
        engine.set_joint_qpos("hinge", x[2])
        engine.set_joint_vel("hinge", x[3])
        engine.forward()

    def engine_apply(self, engine, u: np.ndarray) -> None:
        engine.set_joint_ctrl("slider", u[0])


def _track_limits(value: object) -> tuple[float, float] | None:
    """``track_limits`` as a ``(min, max)`` pair of finite numbers with ``min < max``, or None."""
    if value is None:
        return None
    try:
        lo, hi = (float(v) for v in value)
    except (TypeError, ValueError):
        raise InvalidArgument(f"track_limits must be a (min, max) pair, got {value!r}") from None
    if not (math.isfinite(lo) and math.isfinite(hi)):
        raise InvalidArgument(f"track_limits must be finite, got ({lo}, {hi}); omit it for an endless track")
    if not lo < hi:
        raise InvalidArgument(
            f"track_limits: min must be < max (a track of zero or negative length leaves the cart no room), "
            f"got ({lo:g}, {hi:g})"
        )
    return lo, hi
