"""Inverted pendulum: a point mass on a massless rod, hinged at the origin."""

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

__all__ = ["InvertedPendulum"]


class InvertedPendulum(Plant):
    r"""Point-mass pendulum with the angle measured from upright.

    State ``[theta, theta_dot]`` (rad, rad/s), input ``[tau]`` (N m at the
    pivot). With a hinge damping torque ``-b theta_dot``:

    .. math::

        \ddot\theta = \frac{g}{l}\sin\theta + \frac{\tau - b\dot\theta}{m l^2}

    Upright (``theta = 0``) is the unstable equilibrium and the default
    operating point. In MuJoCo the hinge turns about +y, so a positive angle
    tips the mass toward +x.

    Args:
        mass: Bob mass [kg], > 0.
        length: Rod length [m], > 0.
        damping: Hinge damping [N m s/rad], >= 0.
        gravity: Gravitational acceleration [m/s²], >= 0.
        dt: Step [s], > 0.
        state_bounds: Optional ``(min (2,), max (2,))`` or ``{min, max}``, ``min < max``:
            inelastic stops (:meth:`Plant.stop`: an angle past a bound is put on it and its rate
            into the bound zeroed; a rate past a bound is clipped). In MuJoCo the hinge gets the
            angle range (the rate bounds act standalone only). Contacts count in
            ``constraint_violations``.
        backend: Array backend kept for API compatibility (numpy).
    """

    aliases = ("pendulum",)
    state_names = ("theta", "theta_dot")
    input_names = ("tau",)
    param_names = ("mass", "length", "damping", "gravity")
    asset = "inverted_pendulum.xml"
    position_indices = (0,)
    velocity_indices = (1,)

    def __init__(
        self,
        mass: float = 0.1,
        length: float = 0.5,
        damping: float = 0.0,
        gravity: float = 9.81,
        dt: float = 0.01,
        state_bounds: StateBounds | None = None,
        backend: ArrayBackend | None = None,
    ):
        self.m = check_positive("mass", mass)
        self.l = check_positive("length", length)
        self.b = check_nonnegative("damping", damping)
        self.g = check_nonnegative("gravity", gravity)
        self.state_bounds = _parse_bounds(state_bounds, 2, [-3.14, -10.0], [3.14, 10.0])
        self._init(
            dt=dt,
            params={"mass": self.m, "length": self.l, "damping": self.b, "gravity": self.g},
            backend=backend,
        )

    def equations(self, bk, x, u, p):
        theta, theta_dot = bk.unpack(x, 2)
        (tau,) = bk.unpack(u, 1)
        ml2 = p["mass"] * p["length"] ** 2
        theta_ddot = p["gravity"] / p["length"] * bk.sin(theta) + (tau - p["damping"] * theta_dot) / ml2
        return bk.stack([theta_dot, theta_ddot])

    # engine mode: hinge "hinge", motor actuator "hinge"
    def mjcf_patch(self) -> MjcfPatch:
        return MjcfPatch(
            asset=self.asset,
            timestep=self.dt,
            gravity=(0.0, 0.0, -self.g),
            inertials={"pole": (self.m, (0.0, 0.0, self.l))},
            joint_damping={"hinge": self.b},
            geom_fromto={"rod": (0.0, 0.0, 0.0, 0.0, 0.0, self.l)},
            joint_range=self._hinge_range(),
        )

    def _hinge_range(self) -> dict[str, tuple[float, float]]:
        """The angle bounds as the MuJoCo hinge's range (the same stop in both loops)."""
        if self.state_bounds is None:
            return {}
        lo, hi = float(self.state_bounds[0][0]), float(self.state_bounds[1][0])
        return {"hinge": (lo, hi)} if math.isfinite(lo) and math.isfinite(hi) else {}

    def engine_state_map(self, x0: ArrayLike | None = None) -> tuple[np.ndarray, np.ndarray]:
        """``x = T @ z`` with MuJoCo's ``z = [hinge, hinge_dot]``.

        See :meth:`Plant.engine_state_map`.
        """
        perm = np.array([0, 1])
        return np.eye(2)[perm], perm

    def engine_read(self, engine) -> np.ndarray:
        return np.array([engine.get_joint_qpos("hinge"), engine.get_joint_vel("hinge")])

    def engine_write(self, engine, x: np.ndarray) -> None:
        engine.set_joint_qpos("hinge", x[0])
        engine.set_joint_vel("hinge", x[1])
        engine.forward()

    def engine_apply(self, engine, u: np.ndarray) -> None:
        engine.set_joint_ctrl("hinge", u[0])
