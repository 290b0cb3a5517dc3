"""The :class:`MujocoEngine`: a MuJoCo model and its data, stepped with divergence checks."""

from __future__ import annotations

import math
from pathlib import Path
from typing import TYPE_CHECKING

import mujoco
import numpy as np

from shinro_ctrl.engine.access import _FREE, _HINGE, _SLIDE, NamedAccess
from shinro_ctrl.engine.mjcf import _apply_patch, _check_substeps, _compile, _load_spec
from shinro_ctrl.engine.render import OffscreenRenderer
from shinro_ctrl.engine.warnings import (
    _DOF_WARNINGS,
    _HANDLER,
    _RESET_WARNINGS,
    _WARNINGS,
    install_warning_handler,
    take_warning_messages,
)
from shinro_ctrl.errors import InvalidArgument, SimulationDiverged

if TYPE_CHECKING:
    from shinro_ctrl.plants.base import Plant

__all__ = ["MujocoEngine"]


class MujocoEngine(NamedAccess):
    """A MuJoCo model and its data, with named and checked access.

    Args:
        path_or_xml: An MJCF file path, the name of a shipped asset (such as
            ``"cartpole.xml"``), or an MJCF XML string (anything starting
            with ``<``).
        substeps: Number of ``mj_step`` calls per :meth:`step`, >= 1.

    Attributes:
        model: The ``mujoco.MjModel``.
        data: The ``mujoco.MjData``.
        substeps: ``mj_step`` calls per :meth:`step`.
        source: Where the model came from (a path or ``"<xml string>"``).
        joint_names, actuator_names, body_names, site_names: Names in id
            order (``body_names[0]`` is ``"world"``).

    Raises:
        FileNotFoundError: the model file does not exist or is a directory
            (the message holds the path and the shipped assets).
        InvalidArgument: an empty path, an argument that is not a path or a
            string, or XML that is invalid or does not compile (MuJoCo's
            message); a ``ValueError``.
    """

    def __init__(self, path_or_xml: str | Path, *, substeps: int = 1):
        spec, source = _load_spec(path_or_xml)
        self._setup(_compile(spec, source), substeps, source)

    @classmethod
    def from_model(cls, model: mujoco.MjModel, *, substeps: int = 1, source: str = "<MjModel>") -> MujocoEngine:
        """Wrap an already compiled ``MjModel`` (a fresh ``MjData`` is made)."""
        engine = cls.__new__(cls)
        engine._setup(model, substeps, source)
        return engine

    @classmethod
    def for_plant(cls, plant: Plant, *, substeps: int = 1, model: str | Path | None = None) -> MujocoEngine:
        """Load a plant's MJCF asset and match it to the plant's parameters.

        Every field of ``plant.mjcf_patch()`` is written through ``MjSpec``:
        point masses (``inertials``, with a :data:`TINY_INERTIA` diagonal),
        body positions and inertias, joint damping, visual geom ``fromto`` /
        ``size``, gravity and the timestep ``patch.timestep / substeps``. The
        integrator is set to Euler with ``mjDSBL_EULERDAMP`` (explicit
        damping, like the analytic model). The engine is not attached to the
        plant: call ``plant.physics_engine(engine)`` for that.

        Args:
            plant: A plant with ``mjcf_patch()`` (see ``plants.base.MjcfPatch``).
            substeps: ``mj_step`` calls per :meth:`step`; the engine's
                :attr:`dt` equals ``plant.dt`` whatever this value.
            model: Optional MJCF path or shipped asset name replacing the
                plant's own asset (it must use the same names); a path is
                tried first, then the shipped assets. Without it the plant's
                own asset is taken from the package's assets folder only, so
                a same-named file in the current directory never shadows it.

        Raises:
            KeyError: the patch names a body, joint or geom the model lacks.
            FileNotFoundError: the asset does not exist.
            ValueError: the asset is invalid or the patched model does not compile.
        """
        substeps = _check_substeps(substeps)
        if not callable(getattr(plant, "mjcf_patch", None)):
            raise InvalidArgument(
                f"MujocoEngine.for_plant expects a plant instance such as CartPole(), got {type(plant).__name__} "
                f"{plant!r}"
            )
        patch = plant.mjcf_patch()
        spec, source = _load_spec(patch.asset, shipped=True) if model is None else _load_spec(model)
        _apply_patch(spec, patch, substeps)
        engine = cls.from_model(_compile(spec, source), substeps=substeps, source=source)
        engine.plant_type = type(plant).__name__  # physics_engine refuses an engine built for another plant type
        return engine

    # ------------------------------------------------------------------ set-up
    plant_type: str | None = None  # the plant class for_plant built this engine for (None: any model)

    def _setup(self, model: mujoco.MjModel, substeps: int, source: str) -> None:
        if not _HANDLER["installed"]:
            install_warning_handler()
        self.model = model
        self.data = mujoco.MjData(model)
        self.substeps = _check_substeps(substeps)
        self.source = source
        m = model
        # Views into MjData (stable for the data's lifetime; cached for speed).
        self._qpos = self.data.qpos
        self._qvel = self.data.qvel
        self._ctrl = self.data.ctrl
        self._warn = self.data.warning.number

        self.joint_names: tuple[str, ...] = tuple(m.joint(i).name for i in range(m.njnt))
        self.actuator_names: tuple[str, ...] = tuple(m.actuator(i).name for i in range(m.nu))
        self.body_names: tuple[str, ...] = tuple(m.body(i).name for i in range(m.nbody))
        self.site_names: tuple[str, ...] = tuple(m.site(i).name for i in range(m.nsite))

        self._joint: dict[str, int] = {n: i for i, n in enumerate(self.joint_names) if n}
        scalar = [(n, i) for n, i in self._joint.items() if int(m.jnt_type[i]) in (_HINGE, _SLIDE)]
        self._qadr = {n: int(m.jnt_qposadr[i]) for n, i in scalar}
        self._vadr = {n: int(m.jnt_dofadr[i]) for n, i in scalar}
        self._body = {n: i for i, n in enumerate(self.body_names) if n}
        self._site = {n: i for i, n in enumerate(self.site_names) if n}
        self._act = {n: i for i, n in enumerate(self.actuator_names) if n}
        # A joint driven by exactly one actuator may also be addressed by its joint name.
        by_joint: dict[int, list[int]] = {}
        for a in range(m.nu):
            if int(m.actuator_trntype[a]) == int(mujoco.mjtTrn.mjTRN_JOINT):
                by_joint.setdefault(int(m.actuator_trnid[a, 0]), []).append(a)
        for name, j in self._joint.items():
            if name not in self._act and len(by_joint.get(j, ())) == 1:
                self._act[name] = by_joint[j][0]

        free = [i for i in range(m.njnt) if int(m.jnt_type[i]) == _FREE]
        self._free = free[0] if free else None

        mujoco.mj_forward(m, self.data)
        self._kin_stale = False
        self._warn_seen = self._warn.tobytes()
        take_warning_messages()

    # ------------------------------------------------------------- properties
    @property
    def dt(self) -> float:
        """Time advanced by one :meth:`step`: ``opt.timestep * substeps`` [s]."""
        return float(self.model.opt.timestep) * self.substeps

    @property
    def time(self) -> float:
        """Simulation time [s]."""
        return float(self.data.time)

    @property
    def has_free_joint(self) -> bool:
        """Whether the model has a free joint (a floating base)."""
        return self._free is not None

    def __repr__(self) -> str:
        m = self.model
        return (
            f"MujocoEngine({self.source!r}, nq={m.nq}, nv={m.nv}, nu={m.nu}, dt={self.dt:g}, substeps={self.substeps})"
        )

    # ------------------------------------------- the plant contract (plants.standalone.Engine)
    def apply(self, plant: Plant, u: np.ndarray) -> None:
        """Set the actuators from the plant input ``u (m,)`` (the plant's ``engine_apply``)."""
        plant.engine_apply(self, u)

    def read(self, plant: Plant) -> np.ndarray:
        """The plant's state ``(n,)`` from MuJoCo's (the plant's ``engine_read``)."""
        return plant.engine_read(self)

    def write(self, plant: Plant, x: np.ndarray) -> None:
        """Set MuJoCo's state from the plant's ``x (n,)`` (the plant's ``engine_write``)."""
        plant.engine_write(self, x)

    def joint_limit_depth(self, joints: list[str]) -> float:
        """Deepest penetration [m or rad] of an active joint-limit constraint on ``joints`` (0: none active).

        Read from the constraints of the last step (``efc_*``): a row of type
        ``mjCNSTR_LIMIT_JOINT`` on one of the joints, its distance ``efc_pos`` (negative inside).
        """
        d = self.data
        if d.nefc == 0:
            return 0.0
        ids = {self._joint_id(name) for name in joints}
        depth = 0.0
        limit = int(mujoco.mjtConstraint.mjCNSTR_LIMIT_JOINT)
        for row in np.flatnonzero(d.efc_type[: d.nefc] == limit).tolist():
            if int(d.efc_id[row]) in ids:
                depth = max(depth, -float(d.efc_pos[row]), 1e-12)
        return depth

    # ------------------------------------------------------------- simulation
    def forward(self) -> None:
        """Recompute every derived quantity (``mj_forward``) from the current state."""
        mujoco.mj_forward(self.model, self.data)
        self._kin_stale = False

    def step(self) -> None:
        """Advance :attr:`dt`: ``substeps`` calls of ``mj_step``, then check.

        Raises:
            SimulationDiverged: MuJoCo raised a warning during the step (it
                then resets the state itself) or ``qpos`` / ``qvel`` became
                non-finite. The message names the warning and the time, and
                quotes MuJoCo's own warning text when it issued one.
        """
        m, d = self.model, self.data
        t0 = d.time
        for _ in range(self.substeps):
            mujoco.mj_step(m, d)
        self._kin_stale = True
        if self._warn.tobytes() != self._warn_seen or not math.isfinite(
            sum(self._qpos.tolist(), sum(self._qvel.tolist()))
        ):
            self._diverged(t0)

    def reset(self) -> None:
        """Reset the data to the model's initial state (``mj_resetData``) and run ``forward``."""
        mujoco.mj_resetData(self.model, self.data)
        self.forward()
        self._warn_seen = self._warn.tobytes()
        take_warning_messages()

    def _diverged(self, t0: float) -> None:
        m = self.model
        seen = np.frombuffer(self._warn_seen, dtype=self._warn.dtype)
        now = self._warn.copy()
        self._warn_seen = now.tobytes()
        span = f"during the step from t = {t0:.6g} s to {t0 + self.dt:.6g} s"
        said = take_warning_messages()
        quoted = "; MuJoCo: " + " / ".join(f'"{msg}"' for msg in dict.fromkeys(said)) if said else ""
        raised = [i for i in range(now.shape[0]) if now[i] > seen[i]]
        if not raised:
            raise SimulationDiverged(
                f"MuJoCo simulation diverged {span}: non-finite state, "
                f"qpos = {np.array2string(self._qpos, precision=4)}, "
                f"qvel = {np.array2string(self._qvel, precision=4)}{quoted}"
            )
        parts = []
        for i in raised:
            name, text = _WARNINGS.get(i, (f"warning {i}", "MuJoCo warning"))
            info = int(self.data.warning.lastinfo[i])
            where = ""
            if i in _DOF_WARNINGS and 0 <= info < m.nv:
                where = f" at DOF {info} (joint '{self.joint_names[int(m.dof_jntid[info])]}')"
            elif i == int(mujoco.mjtWarning.mjWARN_BADCTRL) and 0 <= info < m.nu:
                where = f" at actuator {info} ('{self.actuator_names[info]}')"
            parts.append(f"{name} ({text}){where}")
        reset = (
            "; MuJoCo has reset the state to the model's initial configuration"
            if any(i in _RESET_WARNINGS for i in raised)
            else ""
        )
        raise SimulationDiverged(f"MuJoCo simulation diverged {span}: {', '.join(parts)}{reset}{quoted}")

    # ------------------------------------------- offscreen rendering (video.py)
    def make_renderer(self, width: int = 320, height: int = 240, *, shadows: bool = False) -> OffscreenRenderer:
        """An offscreen renderer of this engine's model, showing its current data.

        MuJoCo picks its OpenGL backend from ``MUJOCO_GL`` when ``mujoco`` is
        first imported (see :mod:`shinro_ctrl.video`, which chooses one
        before that import). Close the renderer when done (or use it as a
        context manager): MuJoCo's own finalizer may fail at interpreter exit.

        Args:
            width: Image width [px], 16 to 8192.
            height: Image height [px], 16 to 8192.
            shadows: Render the lights' shadows. Off by default: with software
                rendering (OSMesa) shadows cost about ten times the rest of a
                frame (60 ms against 5 ms for the cart-pole at 320 × 240).

        Raises:
            InvalidArgument: a size out of range.
            RuntimeError: no OpenGL context could be created (the message
                names ``MUJOCO_GL`` and MuJoCo's reason).
        """
        return OffscreenRenderer(self, width, height, shadows=shadows)
