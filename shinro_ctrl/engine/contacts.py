r"""Floor contacts of a floating-base robot in MuJoCo, and the per-step record the balance metrics are computed from.

:func:`floor_contacts` reads MuJoCo's active contacts between the floor (a plane geom of the world body) and
the robot, with the force of each in its contact frame (``mj_contactForce``): the normal force ``f_n`` along
the contact normal and the tangential force ``‖f_t‖`` in the contact plane, with the contact's friction
coefficient ``μ`` (the first of ``contact.friction``; MuJoCo takes the larger of the two geoms'). The force
lies inside the Coulomb friction cone when ``‖f_t‖ ≤ μ f_n``.

:class:`BalanceMonitor` (made by :meth:`MujocoEngine.balance_monitor
<shinro_ctrl.engine.MujocoEngine.balance_monitor>` for a model with a free joint and a floor) samples, after
every step of a run, the pose of the free joint's body (the trunk) and the floor contacts; :meth:`record`
returns them as a :class:`BalanceRecord`, from which :func:`shinro_ctrl.sim.metrics.balance_metrics` computes
the trunk height and orientation errors, the foot slip and the friction-cone fraction.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import mujoco
import numpy as np

if TYPE_CHECKING:
    from shinro_ctrl.engine.core import MujocoEngine

__all__ = ["BalanceMonitor", "BalanceRecord", "FloorContact", "floor_contacts", "floor_geoms"]

_PLANE = int(mujoco.mjtGeom.mjGEOM_PLANE)
_FREE = int(mujoco.mjtJoint.mjJNT_FREE)


@dataclass(frozen=True)
class FloorContact:
    """One active contact between the floor and the robot.

    Attributes:
        geom: Name of the robot's geom (``"geom<id>"`` when unnamed).
        pos: ``(3,)`` world position of the contact point [m].
        normal_force: ``f_n`` [N], along the contact normal (≥ 0 when pressing).
        tangential_force: ``‖f_t‖`` [N], the friction force's magnitude in the contact plane.
        friction: ``μ``, the contact's sliding friction coefficient.
    """

    geom: str
    pos: np.ndarray
    normal_force: float
    tangential_force: float
    friction: float

    @property
    def inside_cone(self) -> bool:
        """``‖f_t‖ ≤ μ f_n`` (within 1e-6 relative, 1e-9 N absolute)."""
        return self.tangential_force <= self.friction * self.normal_force * (1 + 1e-6) + 1e-9


def floor_geoms(model: mujoco.MjModel) -> tuple[int, ...]:
    """The ids of the floor geoms: planes attached to the world body."""
    return tuple(g for g in range(model.ngeom) if int(model.geom_type[g]) == _PLANE and model.geom_bodyid[g] == 0)


def _geom_name(model: mujoco.MjModel, g: int) -> str:
    return model.geom(g).name or f"geom{g}"


def floor_contacts(engine: MujocoEngine) -> list[FloorContact]:
    """The active contacts between a floor plane and the robot, at the engine's current data.

    Each is read with ``mj_contactForce``, which returns the contact force in the contact frame
    (normal first, then the two tangential directions) for pyramidal and elliptic cones alike.
    """
    m, d = engine.model, engine.data
    floors = set(floor_geoms(m))
    out: list[FloorContact] = []
    f6 = np.zeros(6)
    for i in range(d.ncon):
        c = d.contact[i]
        g1, g2 = int(c.geom[0]), int(c.geom[1])
        if (g1 in floors) == (g2 in floors):
            continue  # robot-robot, or floor-floor
        robot = g2 if g1 in floors else g1
        mujoco.mj_contactForce(m, d, i, f6)
        out.append(
            FloorContact(
                _geom_name(m, robot),
                np.array(c.pos, dtype=float),
                float(f6[0]),
                float(np.hypot(f6[1], f6[2])),
                float(c.friction[0]),
            )
        )
    return out


@dataclass
class BalanceRecord:
    """The samples of a run that the balance metrics read (one per step, the first before the first step).

    Attributes:
        trunk_pos: ``(T, 3)`` world position of the trunk (the free joint's body) [m].
        trunk_quat: ``(T, 4)`` its orientation, unit quaternion ``(w, x, y, z)``.
        contact_step: ``(C,)`` sample index of each contact sample.
        contact_geom: ``(C,)`` the robot geom's name.
        contact_pos: ``(C, 3)`` world contact point [m].
        contact_force: ``(C, 2)`` ``[f_n, ‖f_t‖]`` [N].
        contact_friction: ``(C,)`` ``μ``.
        trunk: The trunk body's name.
    """

    trunk_pos: np.ndarray
    trunk_quat: np.ndarray
    contact_step: np.ndarray
    contact_geom: np.ndarray
    contact_pos: np.ndarray
    contact_force: np.ndarray
    contact_friction: np.ndarray
    trunk: str = ""


class BalanceMonitor:
    """Samples the trunk pose and the floor contacts after each step of a run (see :class:`BalanceRecord`).

    Made by :meth:`MujocoEngine.balance_monitor`; call it once before the loop and once after every step.
    """

    def __init__(self, engine: MujocoEngine, body: int):
        self._engine = engine
        self._xpos = engine.data.xpos[body]
        self._xquat = engine.data.xquat[body]
        self.trunk = engine.model.body(body).name
        self._pos: list[np.ndarray] = []
        self._quat: list[np.ndarray] = []
        self._contacts: list[tuple[int, FloorContact]] = []

    def __call__(self) -> None:
        k = len(self._pos)
        self._engine.ensure_kinematics()
        self._pos.append(self._xpos.copy())
        self._quat.append(self._xquat.copy())
        self._contacts.extend((k, c) for c in floor_contacts(self._engine))

    def record(self) -> BalanceRecord:
        """The samples so far."""
        cs = self._contacts
        return BalanceRecord(
            trunk_pos=np.array(self._pos).reshape(-1, 3),
            trunk_quat=np.array(self._quat).reshape(-1, 4),
            contact_step=np.array([k for k, _ in cs], dtype=np.intp),
            contact_geom=np.array([c.geom for _, c in cs], dtype=object),
            contact_pos=np.array([c.pos for _, c in cs]).reshape(-1, 3),
            contact_force=np.array([(c.normal_force, c.tangential_force) for _, c in cs]).reshape(-1, 2),
            contact_friction=np.array([c.friction for _, c in cs]),
            trunk=self.trunk,
        )


def balance_body(model: mujoco.MjModel) -> int | None:
    """The body of the model's first free joint when the model also has a floor, else None."""
    if not floor_geoms(model):
        return None
    for j in range(model.njnt):
        if int(model.jnt_type[j]) == _FREE:
            return int(model.jnt_bodyid[j])
    return None
