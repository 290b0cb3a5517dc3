"""Planar double pendulum: two point masses on massless rods, hinge motors."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from shinro_ctrl.backend import ArrayBackend
from shinro_ctrl.plants._bounds import StateBounds
from shinro_ctrl.plants._bounds import state_bounds as _parse_bounds
from shinro_ctrl.plants.base import MjcfPatch, Plant
from shinro_ctrl.validation import check_nonnegative, check_positive

if TYPE_CHECKING:
    from numpy.typing import ArrayLike

__all__ = ["DoublePendulum"]


class DoublePendulum(Plant):
    r"""Double pendulum in absolute rod angles, driven by hinge motors.

    State ``[theta_1, theta_2, omega_1, omega_2]``: each rod's angle from the
    downward vertical and its rate. Input ``[tau_1, tau_2]``: the motor torque
    at the top hinge (world–rod 1) and at the middle hinge (rod 1–rod 2). The
    middle motor acts on the relative angle, so by virtual work the generalized
    forces on the absolute angles are ``Q = [tau_1 - tau_2, tau_2]``. With
    ``Δ = θ1 − θ2``:

    .. math::

        \begin{bmatrix} (m_1+m_2) l_1^2 & m_2 l_1 l_2 \cos Δ \\
                        m_2 l_1 l_2 \cos Δ & m_2 l_2^2 \end{bmatrix} \ddot\theta
        + \begin{bmatrix} m_2 l_1 l_2 \sin Δ \,\dot\theta_2^2 \\
                          -m_2 l_1 l_2 \sin Δ \,\dot\theta_1^2 \end{bmatrix}
        + \begin{bmatrix} (m_1+m_2) g l_1 \sin\theta_1 \\ m_2 g l_2 \sin\theta_2 \end{bmatrix}
        = Q

    Hanging (``θ = 0``) is the default operating point; ``θ1 = θ2 = π`` is the
    upright equilibrium. In MuJoCo the second hinge measures the relative
    angle ``θ2 − θ1``; the engine mode converts.

    Args:
        mass_top, mass_bottom: Bob masses [kg], > 0.
        length_top, length_bottom: Rod lengths [m], > 0.
        dt: Step [s], > 0.
        g: Gravitational acceleration [m/s²], >= 0.
        state_bounds: Optional ``(min (4,), max (4,))`` or ``{min, max}``, ``min < max``:
            inelastic stops in the standalone loop (:meth:`Plant.stop`), counted in
            ``constraint_violations``. MuJoCo's second hinge measures the relative angle, so the
            absolute-angle bounds have no MuJoCo joint range: they act standalone only.
        backend: Array backend kept for API compatibility (numpy).
    """

    aliases = ("double_pendulum",)
    state_names = ("theta_1", "theta_2", "omega_1", "omega_2")
    input_names = ("tau_1", "tau_2")
    param_names = ("mass_top", "mass_bottom", "length_top", "length_bottom", "g")
    asset = "double_pendulum.xml"
    position_indices = (0, 1)
    velocity_indices = (2, 3)

    def __init__(
        self,
        mass_top: float = 0.1,
        mass_bottom: float = 0.1,
        length_top: float = 0.5,
        length_bottom: float = 0.5,
        dt: float = 0.01,
        g: float = 9.81,
        state_bounds: StateBounds | None = None,
        backend: ArrayBackend | None = None,
    ):
        self.m1 = check_positive("mass_top", mass_top)
        self.m2 = check_positive("mass_bottom", mass_bottom)
        self.l1 = check_positive("length_top", length_top)
        self.l2 = check_positive("length_bottom", length_bottom)
        self.g = check_nonnegative("g", g)
        self.state_bounds = _parse_bounds(state_bounds, 4, [-3.14, -3.14, -10.0, -10.0], [3.14, 3.14, 10.0, 10.0])
        self._init(
            dt=dt,
            params={
                "mass_top": self.m1,
                "mass_bottom": self.m2,
                "length_top": self.l1,
                "length_bottom": self.l2,
                "g": self.g,
            },
            backend=backend,
        )

    def upright(self) -> tuple[np.ndarray, np.ndarray]:
        """The upright equilibrium ``(x0, u0)``: both rods pointing up, no torque."""
        return np.array([math.pi, math.pi, 0.0, 0.0]), np.zeros(2)

    def equations(self, bk, x, u, p):
        th1, th2, w1, w2 = bk.unpack(x, 4)
        tau1, tau2 = bk.unpack(u, 2)
        m1, m2, l1, l2, g = (p[k] for k in self.param_names)
        d = th1 - th2
        sd, cd = bk.sin(d), bk.cos(d)
        M11 = (m1 + m2) * l1**2
        M12 = m2 * l1 * l2 * cd
        M22 = m2 * l2**2
        r1 = tau1 - tau2 - m2 * l1 * l2 * sd * w2**2 - (m1 + m2) * g * l1 * bk.sin(th1)
        r2 = tau2 + m2 * l1 * l2 * sd * w1**2 - m2 * g * l2 * bk.sin(th2)
        det = M11 * M22 - M12 * M12
        a1 = (M22 * r1 - M12 * r2) / det
        a2 = (M11 * r2 - M12 * r1) / det
        return bk.stack([w1, w2, a1, a2])

    def energy(self, x: ArrayLike) -> float | np.ndarray:
        """Total mechanical energy [J] of state(s) ``x`` ``(n,)`` or ``(N, n)``; zero potential at the hinge."""
        x = np.asarray(x, dtype=float)
        th1, th2, w1, w2 = (x[..., i] for i in range(4))
        m1, m2, l1, l2, g = self.m1, self.m2, self.l1, self.l2, self.g
        kin = 0.5 * (m1 + m2) * l1**2 * w1**2 + 0.5 * m2 * l2**2 * w2**2
        kin = kin + m2 * l1 * l2 * w1 * w2 * np.cos(th1 - th2)
        pot = -(m1 + m2) * g * l1 * np.cos(th1) - m2 * g * l2 * np.cos(th2)
        return kin + pot

    # engine mode: hinges "hinge_1" (absolute) and "hinge_2" (relative), motors "torque_1"/"torque_2"
    def mjcf_patch(self) -> MjcfPatch:
        return MjcfPatch(
            asset=self.asset,
            timestep=self.dt,
            gravity=(0.0, 0.0, -self.g),
            inertials={"link1": (self.m1, (0.0, 0.0, -self.l1)), "link2": (self.m2, (0.0, 0.0, -self.l2))},
            body_pos={"link2": (0.0, 0.0, -self.l1)},
            geom_fromto={
                "rod1": (0.0, 0.0, 0.0, 0.0, 0.0, -self.l1),
                "rod2": (0.0, 0.0, 0.0, 0.0, 0.0, -self.l2),
            },
        )

    def engine_state_map(self, x0: ArrayLike | None = None) -> tuple[np.ndarray, np.ndarray]:
        """``x = T @ z`` with MuJoCo's ``z = [hinge_1, hinge_2, hinge_1_dot, hinge_2_dot]``.

        See :meth:`Plant.engine_state_map`.
        """
        # hinge_2 is relative: theta_2 = hinge_1 + hinge_2, omega_2 = hinge_1_dot + hinge_2_dot
        T = np.array([[1.0, 0.0, 0.0, 0.0], [1.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 1.0, 1.0]])
        return T, np.arange(4)

    def engine_read(self, engine) -> np.ndarray:
        q1, q2 = engine.get_joint_qpos("hinge_1"), engine.get_joint_qpos("hinge_2")
        v1, v2 = engine.get_joint_vel("hinge_1"), engine.get_joint_vel("hinge_2")
        return np.array([q1, q1 + q2, v1, v1 + v2])

    def engine_write(self, engine, x: np.ndarray) -> None:
        engine.set_joint_qpos("hinge_1", x[0])
        engine.set_joint_qpos("hinge_2", x[1] - x[0])
        engine.set_joint_vel("hinge_1", x[2])
        engine.set_joint_vel("hinge_2", x[3] - x[2])
        engine.forward()

    def engine_apply(self, engine, u: np.ndarray) -> None:
        engine.set_joint_ctrl("torque_1", u[0])
        engine.set_joint_ctrl("torque_2", u[1])
