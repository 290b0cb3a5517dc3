"""The :class:`MujocoEngine`: a MuJoCo model and its data, stepped with divergence checks, with named access.

One object whole: set-up, stepping, the plant contract (``apply / step / read / write``) and the named,
checked access to joints, actuators, bodies and sites (once a mixin, ``engine/access.py``, that read this
class's private tables).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import TYPE_CHECKING, Any

import mujoco
import numpy as np

from shinro_ctrl.engine.contacts import BalanceMonitor, FloorContact, balance_body, floor_contacts
from shinro_ctrl.engine.mjcf import (
    MODEL_CHOICES,
    _apply_patch,
    _check_names,
    _check_substeps,
    _compile,
    _euler_zyx_from_quat,
    _idealize_model_file,
    _load_spec,
    _real,
    _unknown,
    check_default_parameters,
    check_realistic_geometry,
    realistic_asset,
)
from shinro_ctrl.engine.render import OffscreenRenderer
from shinro_ctrl.engine.warnings import (
    _DOF_WARNINGS,
    _HANDLER,
    _RESET_WARNINGS,
    _WARNINGS,
    install_warning_handler,
    take_warning_messages,
)
from shinro_ctrl.errors import InvalidArgument, NonFiniteError, SimulationDiverged

if TYPE_CHECKING:
    from numpy.typing import ArrayLike

    from shinro_ctrl.plants.base import Plant

__all__ = ["ForceClamps", "MujocoEngine"]

_HINGE = int(mujoco.mjtJoint.mjJNT_HINGE)
_SLIDE = int(mujoco.mjtJoint.mjJNT_SLIDE)
_BALL = int(mujoco.mjtJoint.mjJNT_BALL)
_FREE = int(mujoco.mjtJoint.mjJNT_FREE)
_JOINT_TYPES = {_FREE: "free", _BALL: "ball", _SLIDE: "slide", _HINGE: "hinge"}
_NQ = {_FREE: 7, _BALL: 4, _SLIDE: 1, _HINGE: 1}
_NV = {_FREE: 6, _BALL: 3, _SLIDE: 1, _HINGE: 1}


class MujocoEngine:
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
        """The MuJoCo model of a plant's MuJoCo loop: its matched twin, its realistic variant, or a file.

        ``model`` chooses (see :data:`~shinro_ctrl.engine.mjcf.MODEL_CHOICES`); the engine's
        :attr:`variant` says which was built:

        * ``"matched"`` (default for the built-in plants): the plant's own asset with every field of
          ``plant.mjcf_patch()`` written through ``MjSpec`` (point masses with a :data:`TINY_INERTIA`
          diagonal, body positions and inertias, joint damping and ranges, visual geom ``fromto`` / ``size``,
          gravity, the timestep ``patch.timestep / substeps``) and MuJoCo's Euler integrator with
          ``mjDSBL_EULERDAMP`` (explicit damping, like the analytic model): the exact twin ``crosscheck``
          compares. For a model file (``MjcfPlant``), a copy of the file made the twin of its smooth design
          model: Euler with explicit damping, and contacts, joint limits, friction loss and the
          ``ctrlrange`` / ``forcerange`` clamps off.
        * ``"realistic"`` (default for a model file): the real thing. A built-in plant loads its shipped
          ``<asset>_realistic.xml`` (distributed masses, motor limits, joint friction, the default
          integrator; written for the plant's default parameters, which it requires but ``damping``); a model
          file is loaded as written. Only the timestep is set (``plant.dt / substeps``).
        * a path or a shipped asset name: that file as written but the timestep, with its own integrator,
          contacts, limits, friction and clamps; for a built-in plant it must name the bodies and joints the
          plant reads (a ``KeyError`` names the first missing one). Relative paths are tried first, then
          the shipped assets.

        The engine is not attached to the plant: call ``plant.physics_engine(engine)`` for that.

        Args:
            plant: A plant with ``mjcf_patch()`` (see ``plants.base.MjcfPatch``).
            substeps: ``mj_step`` calls per :meth:`step`; the engine's :attr:`dt` equals ``plant.dt``
                whatever this value.
            model: ``"matched"``, ``"realistic"``, an MJCF path or a shipped asset name; None: the default
                above. Without a path the plant's asset is taken from the package's assets folder only, so a
                same-named file in the current directory never shadows it.

        Raises:
            KeyError: the patch (or the plant) names a body, joint or geom the model lacks.
            FileNotFoundError: the asset does not exist (a built-in plant without a realistic variant).
            ValueError: the asset is invalid, the patched model does not compile, or the realistic variant
                is asked for with parameters other than the defaults.
        """
        substeps = _check_substeps(substeps)
        if not callable(getattr(plant, "mjcf_patch", None)):
            raise InvalidArgument(
                f"MujocoEngine.for_plant expects a plant instance such as CartPole(), got {type(plant).__name__} "
                f"{plant!r}"
            )
        patch = plant.mjcf_patch()
        own_file = bool(getattr(patch, "model_file", False))
        if model is None:
            variant = "realistic" if own_file else "matched"
        elif isinstance(model, str) and model in MODEL_CHOICES:
            variant = model
        else:
            variant = "file"
        if own_file and variant != "file":
            spec, source = _load_spec(patch.asset)
            if variant == "matched":
                _idealize_model_file(spec)
        elif variant == "matched":
            spec, source = _load_spec(patch.asset, shipped=True)
            _apply_patch(spec, patch, substeps)
        elif variant == "realistic":
            asset = realistic_asset(patch.asset)
            try:
                spec, source = _load_spec(asset, shipped=True)
            except FileNotFoundError:
                raise FileNotFoundError(
                    f"{type(plant).__name__} has no realistic MuJoCo model ('{asset}' is not shipped); "
                    'use model = "matched" or an MJCF file of your own'
                ) from None
            check_default_parameters(plant, asset)
            check_realistic_geometry(spec, patch, asset, type(plant).__name__)
        else:
            spec, source = _load_spec(model)
            if not own_file:
                _check_names(spec, patch)
        spec.option.timestep = float(patch.timestep) / substeps
        engine = cls.from_model(_compile(spec, source), substeps=substeps, source=source)
        engine.plant_type = type(plant).__name__  # physics_engine refuses an engine built for another plant type
        engine.variant = variant
        return engine

    # ------------------------------------------------------------------ set-up
    plant_type: str | None = None  # the plant class for_plant built this engine for (None: any model)
    #: Which model :meth:`for_plant` built: ``"matched"`` (the plant's exact twin), ``"realistic"`` or
    #: ``"file"`` (a model file as written); ``"file"`` for an engine made from a path, XML or ``MjModel``.
    variant: str = "file"

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

    def advance(self, plant: Plant, u: np.ndarray) -> np.ndarray:
        """:meth:`apply`, :meth:`step`, then :meth:`read`: one step of the plant."""
        plant.engine_apply(self, u)
        self.step()
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

    # ------------------------------------------ named access: joints, actuators, bodies, sites
    def get_joint_qpos(self, name: str) -> float | np.ndarray:
        """Position of a joint: a float for hinge [rad] / slide [m] joints.

        Ball and free joints return a copy of their ``qpos`` block, shape
        ``(4,)`` / ``(7,)`` (quaternions are ``w, x, y, z``).
        """
        try:
            return self._qpos.item(self._qadr[name])
        except (KeyError, TypeError):
            j = self._joint_id(name)
            a = int(self.model.jnt_qposadr[j])
            return self._qpos[a : a + _NQ[int(self.model.jnt_type[j])]].copy()

    def get_joint_vel(self, name: str) -> float | np.ndarray:
        """Velocity of a joint: a float for hinge [rad/s] / slide [m/s] joints.

        Ball and free joints return a copy of their ``qvel`` block, ``(3,)`` /
        ``(6,)`` (free: world linear velocity, then body angular velocity).
        """
        try:
            return self._qvel.item(self._vadr[name])
        except (KeyError, TypeError):
            j = self._joint_id(name)
            a = int(self.model.jnt_dofadr[j])
            return self._qvel[a : a + _NV[int(self.model.jnt_type[j])]].copy()

    def set_joint_qpos(self, name: str, value: ArrayLike) -> None:
        """Set a joint position (a float, or the ``qpos`` block of a ball/free joint).

        Derived quantities are not recomputed: call :meth:`forward` (pose and
        Jacobian queries refresh the kinematics themselves).

        Raises:
            KeyError: unknown joint (the message lists the joints).
            InvalidArgument: ``value`` is not a real number (or, for a ball or
                free joint, a block of the right shape).
            NonFiniteError: ``value`` holds NaN or inf.
        """
        try:
            adr = self._qadr[name]
        except (KeyError, TypeError):
            self._set_block(name, value, self._qpos, self.model.jnt_qposadr, _NQ, "qpos")
        else:
            v = _real(value, f"joint '{name}' position")
            if not math.isfinite(v):
                raise NonFiniteError(f"joint '{name}' position must be finite, got {v}")
            self._qpos[adr] = v
        self._kin_stale = True

    def set_joint_vel(self, name: str, value: ArrayLike) -> None:
        """Set a joint velocity (a float, or the ``qvel`` block of a ball/free joint).

        Raises:
            KeyError: unknown joint (the message lists the joints).
            InvalidArgument: ``value`` is not a real number (or, for a ball or
                free joint, a block of the right shape).
            NonFiniteError: ``value`` holds NaN or inf.
        """
        try:
            adr = self._vadr[name]
        except (KeyError, TypeError):
            self._set_block(name, value, self._qvel, self.model.jnt_dofadr, _NV, "qvel")
            return
        v = _real(value, f"joint '{name}' velocity")
        if not math.isfinite(v):
            raise NonFiniteError(f"joint '{name}' velocity must be finite, got {v}")
        self._qvel[adr] = v

    def set_joint_ctrl(self, actuator_name: str, value: float) -> None:
        """Set one actuator's control (a motor's force [N] or torque [N m] times its gear).

        ``actuator_name`` is an actuator name; the name of a joint driven by
        exactly one actuator is accepted too. No ``ctrlrange`` clamp applies
        unless the model declares one.

        Raises:
            KeyError: unknown actuator (the message lists the actuators).
            InvalidArgument: ``value`` is not one real number (a list, a
                string, ...).
            NonFiniteError: ``value`` is NaN or inf (``data.ctrl`` is left unchanged).
        """
        try:
            i = self._act[actuator_name]
        except (KeyError, TypeError):
            raise _unknown("actuator", actuator_name, self._act) from None
        try:
            v = float(value)
        except (TypeError, ValueError):
            raise InvalidArgument(
                f"control of actuator '{actuator_name}' must be one real number, got {value!r}"
            ) from None
        if not math.isfinite(v):
            raise NonFiniteError(f"control of actuator '{actuator_name}' must be finite, got {v}")
        self._ctrl[i] = v

    def set_body_force(self, name: str, force: ArrayLike) -> None:
        """Apply a world-frame force ``(3,)`` [N] at a body's centre of mass (``xfrc_applied``) until changed.

        Raises:
            UnknownName: no such body (the valid names are listed).
            NonFiniteError: NaN or inf in ``force``.
        """
        b = self._id(self._body, "body", name)
        f = np.asarray(force, dtype=float).reshape(3)
        if not np.all(np.isfinite(f)):
            raise NonFiniteError(f"force on body '{name}' must be finite, got {f}")
        self.data.xfrc_applied[b, :3] = f

    def clear_body_forces(self) -> None:
        """Remove every applied body force and torque (``xfrc_applied = 0``)."""
        self.data.xfrc_applied[:] = 0.0

    def set_ctrl(self, u: ArrayLike) -> None:
        """Set every actuator's control at once, ``u`` of shape ``(nu,)`` in actuator order.

        Raises:
            ValueError: wrong shape.
            NonFiniteError: NaN or inf (``data.ctrl`` is left unchanged).
        """
        u = np.asarray(u, dtype=float).reshape(-1)
        if u.shape != self._ctrl.shape:
            raise InvalidArgument(f"ctrl: expected shape {self._ctrl.shape} but found {u.shape}")
        if not np.all(np.isfinite(u)):
            raise NonFiniteError(f"ctrl must be finite, got {np.array2string(u, precision=4)}")
        self._ctrl[:] = u

    def get_joint_limits(self, name: str) -> tuple[float, float]:
        """``(lo, hi)`` range of a joint [rad or m]; ``(-inf, inf)`` when unlimited."""
        j = self._joint_id(name)
        if not self.model.jnt_limited[j]:
            return -math.inf, math.inf
        lo, hi = self.model.jnt_range[j]
        return float(lo), float(hi)

    def get_state_vector(self) -> np.ndarray:
        """``z = [qpos, qvel, act]``, shape ``(nq + nv + na,)``: MuJoCo's state order (as in
        ``mjd_transitionFD`` when ``nq == nv``); ``act`` (the actuator activations) is empty
        for a model without activation dynamics."""
        if self.model.na:
            return np.concatenate([self._qpos, self._qvel, self.data.act])
        return np.concatenate([self._qpos, self._qvel])

    def set_state_vector(self, z: ArrayLike) -> None:
        """Set ``qpos``, ``qvel``, ``act`` from ``z = [qpos, qvel, act]`` ``(nq + nv + na,)``, run :meth:`forward`.

        Raises:
            ValueError: wrong shape.
            NonFiniteError: NaN or inf.
        """
        nq, nv, na = self.model.nq, self.model.nv, self.model.na
        z = np.asarray(z, dtype=float).reshape(-1)
        if z.shape != (nq + nv + na,):
            what = "[qpos, qvel, act]" if na else "[qpos, qvel]"
            raise InvalidArgument(f"state vector {what}: expected shape ({nq + nv + na},) but found {z.shape}")
        if not np.all(np.isfinite(z)):
            raise NonFiniteError(f"state vector must be finite, got {np.array2string(z, precision=4)}")
        self._qpos[:] = z[:nq]
        self._qvel[:] = z[nq : nq + nv]
        if na:
            self.data.act[:] = z[nq + nv :]
        self.forward()

    # ------------------------------------------------------- the model's input ranges
    def input_actuators(self, plant: Plant) -> list[tuple[int, float] | None]:
        """Which actuator each plant input drives: ``(actuator id, ctrl per unit of u)`` or None, per input ``(m,)``.

        Found by probing the plant's ``engine_apply`` (``ctrl = G u``, one column per unit input; ``data.ctrl``
        is restored). An input that drives no actuator or several (a kinematic plant, a mixer), or an actuator
        driven by several inputs, maps to None.
        """
        m = int(plant.input_dim)
        ctrl = self._ctrl
        saved = ctrl.copy()
        try:
            plant.engine_apply(self, np.zeros(m))
            base = ctrl.copy()
            cols = []
            for i in range(m):
                e = np.zeros(m)
                e[i] = 1.0
                plant.engine_apply(self, e)
                cols.append(ctrl - base)
        except NotImplementedError:
            return [None] * m
        finally:
            ctrl[:] = saved
        G = np.array(cols).T.reshape(self.model.nu, m)
        out: list[tuple[int, float] | None] = []
        for i in range(m):
            acts = np.flatnonzero(G[:, i])
            if acts.size == 1 and np.count_nonzero(G[acts[0]]) == 1:
                out.append((int(acts[0]), float(G[acts[0], i])))
            else:
                out.append(None)
        return out

    def input_ranges(self, plant: Plant) -> tuple[np.ndarray, np.ndarray]:
        """The model's ``ctrlrange`` clamps as bounds on the plant's inputs: ``(u_min (m,), u_max (m,))``, ±inf: none.

        An input maps to an actuator through :meth:`input_actuators`; the actuator's range counts when MuJoCo
        clamps it (``ctrllimited``, and ``clampctrl`` not disabled), divided by the input's scale.
        """
        m = self.model
        lo, hi = np.full(plant.input_dim, -np.inf), np.full(plant.input_dim, np.inf)
        if m.opt.disableflags & int(mujoco.mjtDisableBit.mjDSBL_CLAMPCTRL):
            return lo, hi
        for i, link in enumerate(self.input_actuators(plant)):
            if link is None or not m.actuator_ctrllimited[link[0]]:
                continue
            a, scale = link
            ends = sorted(float(v) / scale for v in m.actuator_ctrlrange[a])
            lo[i], hi[i] = ends
        return lo, hi

    def force_clamp_monitor(self, plant: Plant) -> ForceClamps | None:
        """A reader of the inputs clamped at an actuator's ``forcerange`` in the last step (None: no input can be).

        See :class:`ForceClamps`; None when no input drives an actuator with a force range.
        """
        links = [
            (i, link[0], link[1] > 0)
            for i, link in enumerate(self.input_actuators(plant))
            if link is not None and self.model.actuator_forcelimited[link[0]]
        ]
        return ForceClamps(self, plant.input_dim, links) if links else None

    def balance_monitor(self) -> BalanceMonitor | None:
        """A sampler of the trunk pose and floor contacts for the balance metrics (None: no free joint or no floor).

        See :class:`~shinro_ctrl.engine.contacts.BalanceMonitor`; the trunk is the first free joint's body, the
        floor any plane geom of the world body.
        """
        body = balance_body(self.model)
        return BalanceMonitor(self, body) if body is not None else None

    def floor_contacts(self) -> list[FloorContact]:
        """The active floor contacts and their forces in the contact frame (see :func:`.contacts.floor_contacts`)."""
        return floor_contacts(self)

    # ---------------------------------------------------------- bodies, sites
    def get_body_pose(self, name: str) -> tuple[np.ndarray, np.ndarray]:
        """World pose of a body frame.

        Returns:
            ``(pos (3,) [m], euler (3,) [rad])`` with ZYX Euler angles
            ``[roll, pitch, yaw]`` (``R = Rz(yaw) Ry(pitch) Rx(roll)``) from
            the body quaternion.
        """
        b = self._id(self._body, "body", name)
        self.ensure_kinematics()
        return self.data.xpos[b].copy(), _euler_zyx_from_quat(self.data.xquat[b])

    def get_body_jacobian(self, name: str) -> np.ndarray:
        """Jacobian ``(6, nv)`` of a body frame's origin, world frame, position rows first.

        The angular rows map ``qvel`` to the world angular velocity.
        """
        b = self._id(self._body, "body", name)
        self.ensure_kinematics()
        jac = np.zeros((6, self.model.nv))
        mujoco.mj_jacBody(self.model, self.data, jac[:3], jac[3:], b)
        return jac

    def get_site_pose(self, name: str) -> tuple[np.ndarray, np.ndarray]:
        """World pose of a site: ``(pos (3,) [m], euler (3,) [rad])``, ZYX ``[roll, pitch, yaw]``."""
        s = self._id(self._site, "site", name)
        self.ensure_kinematics()
        quat = np.empty(4)
        mujoco.mju_mat2Quat(quat, self.data.site_xmat[s])
        return self.data.site_xpos[s].copy(), _euler_zyx_from_quat(quat)

    def get_site_jacobian(self, name: str) -> np.ndarray:
        """Jacobian ``(6, nv)`` of a site, world frame, position rows first."""
        s = self._id(self._site, "site", name)
        self.ensure_kinematics()
        jac = np.zeros((6, self.model.nv))
        mujoco.mj_jacSite(self.model, self.data, jac[:3], jac[3:], s)
        return jac

    def ensure_kinematics(self) -> None:
        """Bring body poses (``xpos``/``xquat``) up to date: after a state write or ``mj_step`` they describe the
        previous state (the renderer and the pose readers call this)."""
        if self._kin_stale:
            mujoco.mj_kinematics(self.model, self.data)
            mujoco.mj_comPos(self.model, self.data)
            self._kin_stale = False

    # ------------------------------------------------------------- free base
    def get_free_joint(self, name: str) -> tuple[np.ndarray, np.ndarray]:
        """Copies of a free joint's ``(qpos (7,), qvel (6,))``.

        ``qpos`` is the world position [m] and the ``(w, x, y, z)`` orientation
        quaternion; ``qvel`` the world linear velocity [m/s] and the body-frame
        angular velocity [rad/s].

        Raises:
            KeyError: unknown joint.
            ValueError: the joint is not a free joint.
        """
        j = self._free_joint_id(name)
        a, v = int(self.model.jnt_qposadr[j]), int(self.model.jnt_dofadr[j])
        return self._qpos[a : a + 7].copy(), self._qvel[v : v + 6].copy()

    def set_free_joint(self, name: str, qpos: ArrayLike, qvel: ArrayLike) -> None:
        """Set a free joint's ``qpos (7,)`` and ``qvel (6,)`` (see :meth:`get_free_joint`).

        Raises:
            KeyError: unknown joint.
            ValueError: not a free joint, or wrong shapes.
            NonFiniteError: NaN or inf.
        """
        self._free_joint_id(name)
        self._set_block(name, qpos, self._qpos, self.model.jnt_qposadr, _NQ, "qpos")
        self._set_block(name, qvel, self._qvel, self.model.jnt_dofadr, _NV, "qvel")
        self._kin_stale = True

    def _free_joint_id(self, name: str) -> int:
        j = self._joint_id(name)
        jtype = int(self.model.jnt_type[j])
        if jtype != _FREE:
            raise InvalidArgument(f"joint '{name}' is a {_JOINT_TYPES[jtype]} joint, not a free joint")
        return j

    def pin_free_base(self, x: float, y: float, z: float | None = None, yaw: float = 0.0) -> None:
        """Place the first free joint's body at ``(x, y[, z])`` [m], upright, heading ``yaw`` [rad].

        The orientation becomes the pure yaw rotation, the free joint's
        velocity is zeroed; ``z`` is kept when None. Derived quantities are
        refreshed by the next :meth:`step` or :meth:`forward`.

        Raises:
            ValueError: the model has no free joint.
            NonFiniteError: a non-finite coordinate.
        """
        if self._free is None:
            raise InvalidArgument(f"model {self.source!r} has no free joint to pin")
        vals = [x, y, yaw] if z is None else [x, y, z, yaw]
        if not all(math.isfinite(float(v)) for v in vals):
            raise NonFiniteError(f"pin_free_base arguments must be finite, got {vals}")
        a = int(self.model.jnt_qposadr[self._free])
        dof = int(self.model.jnt_dofadr[self._free])
        q = self._qpos
        q[a], q[a + 1] = float(x), float(y)
        if z is not None:
            q[a + 2] = float(z)
        half = 0.5 * float(yaw)
        q[a + 3 : a + 7] = (math.cos(half), 0.0, 0.0, math.sin(half))
        self._qvel[dof : dof + 6] = 0.0
        self._kin_stale = True

    # ----------------------------------------------------------- derivatives
    def transition_jacobians(self, eps: float = 1e-6, *, centered: bool = True) -> tuple[np.ndarray, np.ndarray]:
        """Discrete transition Jacobians of one ``mj_step`` at the current state and control.

        ``δz⁺ = A δz + B δu`` with ``z = [qpos (tangent, nv), qvel (nv), act (na)]``
        in MuJoCo's order, by ``mjd_transitionFD``. The step is one
        ``opt.timestep`` (not :attr:`dt` when ``substeps > 1``).

        Args:
            eps: Finite-difference step.
            centered: Central (True) or forward differences.

        Returns:
            ``(A (2nv+na, 2nv+na), B (2nv+na, nu))``.
        """
        m = self.model
        n = 2 * m.nv + m.na
        A = np.zeros((n, n))
        B = np.zeros((n, m.nu))
        mujoco.mjd_transitionFD(m, self.data, float(eps), bool(centered), A, B, None, None)
        return A, B

    @property
    def integrator(self) -> str:
        """The integrator's name, e.g. ``"mjINT_EULER"``."""
        return mujoco.mjtIntegrator(int(self.model.opt.integrator)).name

    @property
    def explicit_damping(self) -> bool:
        """Whether ``mjDSBL_EULERDAMP`` is set (Euler treats damping explicitly)."""
        return bool(self.model.opt.disableflags & int(mujoco.mjtDisableBit.mjDSBL_EULERDAMP))

    # ---------------------------------------------------------------- helpers
    def _joint_id(self, name: str) -> int:
        return self._id(self._joint, "joint", name)

    @staticmethod
    def _id(table: dict[str, int], kind: str, name: str) -> int:
        try:
            return table[name]
        except (KeyError, TypeError):
            raise _unknown(kind, name, table) from None

    def _set_block(
        self, name: str, value: Any, arr: np.ndarray, adr: np.ndarray, sizes: dict[int, int], what: str
    ) -> None:
        j = self._joint_id(name)
        jtype = int(self.model.jnt_type[j])
        k = sizes[jtype]
        try:
            v = np.asarray(value, dtype=float).reshape(-1)
        except (TypeError, ValueError):
            raise InvalidArgument(
                f"{_JOINT_TYPES[jtype]} joint '{name}' {what}: expected {k} real numbers, got {value!r}"
            ) from None
        if v.shape != (k,):
            raise InvalidArgument(
                f"{_JOINT_TYPES[jtype]} joint '{name}' {what}: expected shape ({k},) but found {v.shape}"
            )
        if not np.all(np.isfinite(v)):
            raise NonFiniteError(f"joint '{name}' {what} must be finite, got {np.array2string(v, precision=4)}")
        a = int(adr[j])
        arr[a : a + k] = v


class ForceClamps:
    """Which plant inputs MuJoCo clamped at an actuator's ``forcerange`` in the engine's last step.

    ``d.actuator_force`` (the force of the last ``mj_step``'s ``mj_forward``, so of the last substep) lying
    on an end of its ``forcerange`` (within 1e-9 relative) counts as a clamp at that end. Calling the object
    gives flags ``(m,)``: ``-1`` at the lower bound of the input (the force end it maps to, through the sign
    of the input's scale), ``+1`` at the upper, ``0`` otherwise. Made by :meth:`MujocoEngine.force_clamp_monitor`.
    """

    def __init__(self, engine: MujocoEngine, m: int, links: list[tuple[int, int, bool]]):
        self._force = engine.data.actuator_force
        rng = engine.model.actuator_forcerange
        self._links = [(i, a, float(rng[a, 0]), float(rng[a, 1]), positive) for i, a, positive in links]
        self._flags = np.zeros(m, dtype=np.int8)

    @property
    def inputs(self) -> tuple[int, ...]:
        """The plant inputs that drive a force-limited actuator."""
        return tuple(i for i, *_ in self._links)

    def __call__(self) -> np.ndarray:
        flags = self._flags
        force = self._force
        for i, a, lo, hi, positive in self._links:
            f = force[a]
            end = -1 if f <= lo + 1e-9 * max(1.0, abs(lo)) else 1 if f >= hi - 1e-9 * max(1.0, abs(hi)) else 0
            flags[i] = end if positive else -end
        return flags
