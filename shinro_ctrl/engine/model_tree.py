"""Read an MJCF (or URDF) file into a plain-numpy :class:`~shinro_ctrl.multibody.ModelTree`.

This is the one place that turns MuJoCo's compiled ``MjModel`` arrays into
the description :class:`~shinro_ctrl.multibody.RigidBodyTree` builds exact
dynamics from (``plants.mjcf.MjcfPlant`` imports it: the agreed exception to
"plants never import the engine").

Supported: fixed-base trees of hinge and slide joints; actuators with a joint
transmission, no activation dynamics, ``fixed``/``affine`` gain and
``none``/``affine`` bias (``motor``, ``position``, ``velocity`` and
equivalent ``general`` actuators). Everything else is refused with one clear
error naming the element.
"""

from __future__ import annotations

import hashlib
import os
import tempfile
from pathlib import Path
from typing import Any

import mujoco
import numpy as np

from shinro_ctrl.errors import InvalidArgument
from shinro_ctrl.multibody import ActuatorInfo, BodyInfo, JointInfo, ModelTree
from shinro_ctrl.resources import asset_path, list_assets

__all__ = ["load_model", "read_model_tree", "resolve_model_path", "urdf_with_motors"]

_JOINT_KINDS = {int(mujoco.mjtJoint.mjJNT_HINGE): "hinge", int(mujoco.mjtJoint.mjJNT_SLIDE): "slide"}
_BAD_JOINTS = {int(mujoco.mjtJoint.mjJNT_FREE): "free", int(mujoco.mjtJoint.mjJNT_BALL): "ball"}
_GAIN = {int(mujoco.mjtGain.mjGAIN_FIXED): "fixed", int(mujoco.mjtGain.mjGAIN_AFFINE): "affine"}
_BIAS = {int(mujoco.mjtBias.mjBIAS_NONE): "none", int(mujoco.mjtBias.mjBIAS_AFFINE): "affine"}
_DSBL = mujoco.mjtDisableBit


def resolve_model_path(model: str | os.PathLike) -> Path:
    """The absolute path of a model: an existing file path, or a shipped asset name.

    Raises:
        FileNotFoundError: neither (the message lists the shipped assets).
        InvalidArgument: not a path or a string, or empty.
    """
    if not isinstance(model, str | os.PathLike) or isinstance(model, bytes):
        raise InvalidArgument(f"model must be an MJCF/URDF file path or a shipped asset name, got {model!r}")
    if not os.fspath(model).strip():
        raise InvalidArgument("model path is empty: give an MJCF/URDF file path or a shipped asset name")
    p = Path(model).expanduser()
    if p.is_dir():
        raise FileNotFoundError(f"model path '{model}' is a directory, not an MJCF/URDF file")
    if p.is_file():
        return p.resolve()
    try:
        return asset_path(model).resolve()
    except FileNotFoundError:
        raise FileNotFoundError(
            f"model file not found: '{model}' (shipped assets: {', '.join(list_assets()) or 'none'})"
        ) from None


def urdf_with_motors(path: str | os.PathLike) -> Path:
    """An MJCF file for a URDF robot, with one motor on every hinge and slide joint.

    URDF describes no actuators, so MuJoCo compiles a URDF without any. This
    writes MuJoCo's translation of the URDF plus a motor (gain 1, gear 1,
    named after its joint) per hinge/slide joint, with contacts disabled (the
    symbolic model has none), to a cache file in the system's temporary
    folder, keyed by the URDF's path and modification time. Mesh paths stay
    relative to the URDF's folder. A URDF whose translation already has
    actuators is returned unchanged. MuJoCo writes the translation with six
    significant digits, so its inertias differ from the URDF's by about 1e-6
    relative; plant and engine both load the translation and agree exactly.

    Returns:
        The path of the MJCF file to load (plant and engine alike).

    Raises:
        FileNotFoundError: no such file.
        InvalidArgument: MuJoCo cannot read the URDF.
    """
    src = resolve_model_path(path)
    try:
        spec = mujoco.MjSpec.from_file(str(src))
    except ValueError as exc:
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise InvalidArgument(f"MuJoCo cannot load URDF '{src}': {first}") from exc
    if len(spec.actuators):
        return src
    for kind in ("meshdir", "texturedir"):
        folder = Path(getattr(spec, kind) or ".")
        setattr(spec, kind, str(folder if folder.is_absolute() else (src.parent / folder).resolve()))
    for joint in spec.joints:
        if int(joint.type) in _JOINT_KINDS and joint.name:
            motor = spec.add_actuator()
            motor.name = joint.name
            motor.target = joint.name
            motor.trntype = mujoco.mjtTrn.mjTRN_JOINT
    spec.option.disableflags = int(spec.option.disableflags) | int(_DSBL.mjDSBL_CONTACT)
    key = hashlib.sha1(f"{src}:{src.stat().st_mtime_ns}".encode()).hexdigest()[:12]
    out = Path(tempfile.gettempdir()) / "shinro_ctrl_urdf" / f"{src.stem}-{key}.xml"
    if not out.is_file():
        out.parent.mkdir(parents=True, exist_ok=True)
        tmp = out.with_suffix(f".{os.getpid()}.tmp")
        tmp.write_text(spec.to_xml(), encoding="utf-8")
        os.replace(tmp, out)  # atomic: concurrent workers never read a half-written file
    return out


def load_model(model: str | os.PathLike) -> tuple[mujoco.MjModel, Path]:
    """Compile a model file with ``MjModel.from_xml_path`` (MJCF or URDF).

    Returns:
        ``(MjModel, absolute path)``.

    Raises:
        FileNotFoundError: no such file or shipped asset.
        InvalidArgument: MuJoCo cannot load it (its message quoted).
    """
    path = resolve_model_path(model)
    try:
        return mujoco.MjModel.from_xml_path(str(path)), path
    except ValueError as exc:
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise InvalidArgument(f"MuJoCo cannot load model '{path}': {first}") from exc


def read_model_tree(model: str | os.PathLike | mujoco.MjModel, *, path: str = "") -> ModelTree:
    """Read a model file (or a compiled ``MjModel``) into a :class:`ModelTree`.

    Args:
        model: MJCF/URDF path, shipped asset name, or an ``MjModel``.
        path: Recorded as :attr:`ModelTree.path` when ``model`` is an ``MjModel``.

    Raises:
        FileNotFoundError: no such file.
        InvalidArgument: free or ball joints ("not supported yet", naming the
            joint), no joints, no actuators, an actuator kind other than a joint
            transmission without activation dynamics and with fixed/affine gain
            and none/affine bias (naming it), equality constraints, gravity
            compensation, tendons.
    """
    if isinstance(model, mujoco.MjModel):
        m = model
    else:
        m, p = load_model(model)
        path = str(p)
    label = path or m.names[: m.names.find(b"\0")].decode() or "<model>"

    _check_supported(m, label)
    joints, body_joints = _read_joints(m)
    bodies = _read_bodies(m, body_joints)
    actuators = [_read_actuator(m, a, label) for a in range(m.nu)]
    return _tree_with_options(m, path, bodies, joints, actuators)


def _name(kind: Any, i: int) -> str:
    return kind(i).name or f"#{i}"


def _check_supported(m: mujoco.MjModel, label: str) -> None:
    """Raise InvalidArgument for the first model feature MjcfPlant does not support (see :func:`read_model_tree`)."""
    for j in range(m.njnt):
        t = int(m.jnt_type[j])
        if t in _BAD_JOINTS:
            raise InvalidArgument(
                f"model '{label}': {_BAD_JOINTS[t]} joint '{_name(m.joint, j)}' is not supported yet "
                "(MjcfPlant handles fixed-base trees of hinge and slide joints)"
            )
    if m.njnt == 0:
        raise InvalidArgument(f"model '{label}' has no joints: nothing moves")
    if m.nu == 0:
        raise InvalidArgument(f"model '{label}' has no actuators: MjcfPlant needs at least one input")
    if m.neq:
        raise InvalidArgument(f"model '{label}': equality constraints are not supported yet ({m.neq} found)")
    if getattr(m, "nflex", 0):
        raise InvalidArgument(f"model '{label}': flexible bodies (flex) are not supported yet ({m.nflex} found)")
    if getattr(m, "nplugin", 0):
        raise InvalidArgument(f"model '{label}': engine plugins are not supported yet ({m.nplugin} found)")
    if m.ntendon:
        raise InvalidArgument(f"model '{label}': tendons are not supported yet ({m.ntendon} found)")
    if np.any(m.body_gravcomp != 0.0):
        b = int(np.flatnonzero(m.body_gravcomp)[0])
        raise InvalidArgument(f"model '{label}': body '{_name(m.body, b)}' uses gravcomp, which is not supported yet")
    if np.any(m.dof_frictionloss != 0.0) and not m.opt.disableflags & int(_DSBL.mjDSBL_FRICTIONLOSS):
        d = int(np.flatnonzero(m.dof_frictionloss)[0])
        raise InvalidArgument(
            f"model '{label}': joint '{_name(m.joint, int(m.dof_jntid[d]))}' has frictionloss (a constraint "
            "force), which is not supported yet"
        )
    for attr, what in (
        ("dof_dampingpoly", "nonlinear damping (more than one damping coefficient)"),
        ("jnt_stiffnesspoly", "nonlinear stiffness (more than one stiffness coefficient)"),
        ("jnt_springyield", "a spring yield"),
    ):
        arr = np.asarray(getattr(m, attr, np.zeros(0)))
        if arr.size and np.any(arr != 0.0):
            row = int(np.flatnonzero(np.any(arr.reshape(arr.shape[0], -1) != 0.0, axis=1))[0])
            j = int(m.dof_jntid[row]) if attr.startswith("dof_") else row
            raise InvalidArgument(
                f"model '{label}': joint '{_name(m.joint, j)}' has {what}, which is not supported yet"
            )
    for attr, what in (
        ("actuator_armature", "armature"),
        ("actuator_damping", "damping"),
        ("actuator_dampingpoly", "nonlinear damping"),
        ("actuator_delay", "a delay"),
    ):
        arr = np.asarray(getattr(m, attr, np.zeros(0)))
        if arr.size and np.any(arr != 0.0):
            a = int(np.flatnonzero(np.any(arr.reshape(arr.shape[0], -1) != 0.0, axis=1))[0])
            raise InvalidArgument(
                f"model '{label}': actuator '{_name(m.actuator, a)}' has {what}, which is not supported yet "
                "(put rotor inertia and damping on the joint: armature, damping)"
            )
    if np.any(np.asarray(getattr(m, "actuator_ctrlnum", np.ones(m.nu))) != 1):
        raise InvalidArgument(f"model '{label}': actuators with several controls are not supported yet")
    if m.opt.density != 0.0 or m.opt.viscosity != 0.0:
        raise InvalidArgument(f"model '{label}': fluid forces (density/viscosity) are not supported yet")


def _read_joints(m: mujoco.MjModel) -> tuple[list[JointInfo], dict[int, list[int]]]:
    """The joints, and body index -> indices of the joints on that body."""
    joints = []
    body_joints: dict[int, list[int]] = {}
    for j in range(m.njnt):
        d = int(m.jnt_dofadr[j])
        b = int(m.jnt_bodyid[j])
        body_joints.setdefault(b, []).append(j)
        joints.append(
            JointInfo(
                name=m.joint(j).name,
                type=_JOINT_KINDS[int(m.jnt_type[j])],
                body=b,
                axis=np.array(m.jnt_axis[j], dtype=float),
                pos=np.array(m.jnt_pos[j], dtype=float),
                qpos0=float(m.qpos0[int(m.jnt_qposadr[j])]),
                damping=float(m.dof_damping[d]),
                armature=float(m.dof_armature[d]),
                stiffness=float(m.jnt_stiffness[j]),
                springref=float(m.qpos_spring[int(m.jnt_qposadr[j])]),
                limited=bool(m.jnt_limited[j]),
                range=(float(m.jnt_range[j, 0]), float(m.jnt_range[j, 1])),
            )
        )
    return joints, body_joints


def _read_bodies(m: mujoco.MjModel, body_joints: dict[int, list[int]]) -> list[BodyInfo]:
    """The bodies in MuJoCo's order (body 0 is the world)."""
    return [
        BodyInfo(
            name=m.body(b).name,
            parent=int(m.body_parentid[b]) if b else -1,
            pos=np.array(m.body_pos[b], dtype=float),
            quat=np.array(m.body_quat[b], dtype=float),
            mass=float(m.body_mass[b]),
            ipos=np.array(m.body_ipos[b], dtype=float),
            iquat=np.array(m.body_iquat[b], dtype=float),
            inertia=np.array(m.body_inertia[b], dtype=float),
            joints=tuple(body_joints.get(b, ())),
        )
        for b in range(m.nbody)
    ]


def _read_actuator(m: mujoco.MjModel, a: int, label: str) -> ActuatorInfo:
    """Actuator ``a``, or InvalidArgument naming it when its transmission, dynamics, gain or bias is unsupported."""
    aname = _name(m.actuator, a)
    if int(m.actuator_trntype[a]) != int(mujoco.mjtTrn.mjTRN_JOINT):
        kind = mujoco.mjtTrn(int(m.actuator_trntype[a])).name
        raise InvalidArgument(
            f"model '{label}': actuator '{aname}' uses transmission {kind}; only joint transmissions are supported yet"
        )
    if int(m.actuator_dyntype[a]) != int(mujoco.mjtDyn.mjDYN_NONE):
        kind = mujoco.mjtDyn(int(m.actuator_dyntype[a])).name
        raise InvalidArgument(
            f"model '{label}': actuator '{aname}' has activation dynamics {kind}; only actuators without "
            "(motor, position, velocity, general with dyntype none) are supported yet"
        )
    gt, bt = int(m.actuator_gaintype[a]), int(m.actuator_biastype[a])
    if gt not in _GAIN or bt not in _BIAS:
        raise InvalidArgument(
            f"model '{label}': actuator '{aname}' has gain {mujoco.mjtGain(gt).name} and bias "
            f"{mujoco.mjtBias(bt).name}; supported: fixed/affine gain, none/affine bias"
        )
    gain = tuple(float(c) for c in m.actuator_gainprm[a, :3])
    bias = tuple(float(c) for c in m.actuator_biasprm[a, :3])
    kind = "general"
    if _GAIN[gt] == "fixed" and _BIAS[bt] == "none" and gain[0] == 1.0:
        kind = "motor"
    elif _GAIN[gt] == "fixed" and _BIAS[bt] == "affine" and bias[0] == 0.0:
        if bias[1] == -gain[0] and bias[1] != 0.0:
            kind = "position"
        elif bias[1] == 0.0 and bias[2] == -gain[0]:
            kind = "velocity"
    clamp_ctrl = bool(m.actuator_ctrllimited[a]) and not m.opt.disableflags & int(_DSBL.mjDSBL_CLAMPCTRL)
    return ActuatorInfo(
        name=m.actuator(a).name,
        kind=kind,
        joint=int(m.actuator_trnid[a, 0]),
        gear=float(m.actuator_gear[a, 0]),
        gaintype=_GAIN[gt],
        gainprm=gain,  # type: ignore[arg-type]
        biastype=_BIAS[bt],
        biasprm=bias,  # type: ignore[arg-type]
        ctrlrange=tuple(float(c) for c in m.actuator_ctrlrange[a]) if clamp_ctrl else None,  # type: ignore[arg-type]
        forcerange=tuple(float(c) for c in m.actuator_forcerange[a])  # type: ignore[arg-type]
        if m.actuator_forcelimited[a]
        else None,
    )


def _tree_with_options(
    m: mujoco.MjModel, path: str, bodies: list[BodyInfo], joints: list[JointInfo], actuators: list[ActuatorInfo]
) -> ModelTree:
    """The :class:`ModelTree` with the model's options (gravity, step, integrator, disabled terms)."""
    flags = int(m.opt.disableflags)
    return ModelTree(
        name=m.names[: m.names.find(b"\0")].decode(),
        path=path,
        bodies=tuple(bodies),
        joints=tuple(joints),
        actuators=tuple(actuators),
        gravity=np.array(m.opt.gravity, dtype=float),
        timestep=float(m.opt.timestep),
        integrator=mujoco.mjtIntegrator(int(m.opt.integrator)).name.removeprefix("mjINT_"),
        damping_enabled=not flags & int(_DSBL.mjDSBL_DAMPER),
        springs_enabled=not flags & int(_DSBL.mjDSBL_SPRING),
        actuation_enabled=not flags & int(_DSBL.mjDSBL_ACTUATION),
        gravity_enabled=not flags & int(_DSBL.mjDSBL_GRAVITY),
        disableflags=flags,
    )
