"""Read an MJCF (or URDF) file into a plain-numpy :class:`~shinro_ctrl.multibody.ModelTree`.

This is the one place that loads a model file and turns MuJoCo's compiled
``MjModel`` arrays into the description
:class:`~shinro_ctrl.multibody.RigidBodyTree` builds exact dynamics from
(``plants.mjcf.MjcfPlant`` imports it: the agreed exception to "plants never
import the engine"; the engine loads its files through :func:`load_spec`).

Loading (:func:`load_spec`, :func:`load_model`): the kind of a file is read
from its content, not its name (:func:`model_kind`: root element
``<mujoco>`` for MJCF, ``<robot>`` for URDF), so ``arm.mjcf``, ``ARM.XML``
and a URDF saved as ``robot.xml`` all load the same way in every command.
MuJoCo's own warnings while loading are collected and reported as a
:class:`~shinro_ctrl.engine.warnings.ModelWarning`, never printed by MuJoCo.

Supported by :func:`read_robot` / :func:`read_model_tree`: fixed-base trees
of hinge and slide joints; fixed tendons (springs, dampers); gravity
compensation; actuators with a joint, fixed-tendon or site transmission,
``none``/``filter``/``filterexact``/``integrator`` activation dynamics,
``fixed``/``affine`` gain and ``none``/``affine`` bias (``motor``,
``position``, ``velocity``, ``intvelocity`` and equivalent ``general``
actuators); active ``joint``, ``connect`` and ``weld`` equality constraints
(:func:`read_equalities`; a URDF ``<mimic>`` is a joint equality in MuJoCo).
Joint and tendon friction loss and ranges, and the control, force and
activation clamps, are read and recorded (they act in MuJoCo's loop only).
Everything else in a file is refused in one error that lists every
unsupported feature by the name of its element, with the reason and the fix
where one exists; so is every non-finite or invalid number (a ``NaN``
gravity, an infinite mass).
"""

from __future__ import annotations

import hashlib
import io
import os
import re
import tempfile
import warnings
import xml.etree.ElementTree as ET
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path

import mujoco
import numpy as np

from shinro_ctrl.engine.warnings import ModelWarning, collect_messages
from shinro_ctrl.errors import InvalidArgument
from shinro_ctrl.multibody import ActuatorInfo, BodyInfo, JointInfo, ModelTree, SiteInfo, TendonInfo
from shinro_ctrl.multibody.constraints import Constraint
from shinro_ctrl.multibody.contacts import ContactFrame
from shinro_ctrl.resources import asset_path, list_assets

__all__ = [
    "ModelWarning",
    "RobotModel",
    "load_model",
    "load_spec",
    "model_kind",
    "read_equalities",
    "read_model_tree",
    "read_robot",
    "resolve_model_path",
    "urdf_with_motors",
]

_JOINT_KINDS = {int(mujoco.mjtJoint.mjJNT_HINGE): "hinge", int(mujoco.mjtJoint.mjJNT_SLIDE): "slide"}
_FLOATING_JOINTS = {int(mujoco.mjtJoint.mjJNT_FREE): "free", int(mujoco.mjtJoint.mjJNT_BALL): "ball"}
_ALL_JOINTS = {**_JOINT_KINDS, **_FLOATING_JOINTS}
_GAIN = {int(mujoco.mjtGain.mjGAIN_FIXED): "fixed", int(mujoco.mjtGain.mjGAIN_AFFINE): "affine"}
_BIAS = {int(mujoco.mjtBias.mjBIAS_NONE): "none", int(mujoco.mjtBias.mjBIAS_AFFINE): "affine"}
_DSBL = mujoco.mjtDisableBit
_TRANSMISSIONS = {
    int(mujoco.mjtTrn.mjTRN_JOINT): "joint",
    int(mujoco.mjtTrn.mjTRN_JOINTINPARENT): "joint",  # the same as joint for hinge and slide joints
    int(mujoco.mjtTrn.mjTRN_TENDON): "tendon",
    int(mujoco.mjtTrn.mjTRN_SITE): "site",
}
_DYNAMICS = {
    int(mujoco.mjtDyn.mjDYN_NONE): "none",
    int(mujoco.mjtDyn.mjDYN_FILTER): "filter",
    int(mujoco.mjtDyn.mjDYN_FILTEREXACT): "filterexact",
    int(mujoco.mjtDyn.mjDYN_INTEGRATOR): "integrator",
}
#: The equality constraints modelled exactly (shinro_ctrl.multibody.constraints).
_EQ_KINDS = {
    int(mujoco.mjtEq.mjEQ_JOINT): "joint",
    int(mujoco.mjtEq.mjEQ_CONNECT): "connect",
    int(mujoco.mjtEq.mjEQ_WELD): "weld",
}
#: Root element -> model kind.
_ROOTS = {"mujoco": "mjcf", "robot": "urdf"}
#: Suffixes MuJoCo's ``MjSpec.from_file`` recognizes itself (it picks its decoder by the exact suffix).
_NATIVE_SUFFIXES = (".xml", ".urdf")


# ------------------------------------------------------------------- loading
def resolve_model_path(model: str | os.PathLike[str]) -> Path:
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


def model_kind(path: str | os.PathLike[str]) -> str:
    """``"mjcf"`` or ``"urdf"``: the kind of a model file, read from its root element (not its name).

    Raises:
        InvalidArgument: the file is empty, is not XML, or its root element is
            neither ``<mujoco>`` nor ``<robot>`` (the message names the file).
        FileNotFoundError: no such file.
    """
    path = Path(path)
    data = path.read_bytes()
    if not data.strip():
        raise InvalidArgument(f"model file '{path}' is empty (expected an MJCF <mujoco> or URDF <robot> XML file)")
    try:
        data.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = data[: exc.start].count(b"\n") + 1
        raise InvalidArgument(
            f"model file '{path}' is not UTF-8 text: byte 0x{data[exc.start]:02x} on line {line} (save it as UTF-8)"
        ) from None
    try:
        root = ""
        for _, element in ET.iterparse(io.BytesIO(data), events=("start",)):
            root = element.tag.rsplit("}", 1)[-1]
            break
    except ET.ParseError as exc:
        raise InvalidArgument(
            f"model file '{path}' is not a valid XML file ({exc}); expected an MJCF <mujoco> or URDF <robot> model"
        ) from None
    if root not in _ROOTS:
        raise InvalidArgument(
            f"model file '{path}' is neither MJCF nor URDF: its root element is <{root}>, expected <mujoco> "
            "(MJCF) or <robot> (URDF)"
        )
    return _ROOTS[root]


def is_model_file(name: object) -> bool:
    """Whether ``name`` names a model file: an MJCF/URDF suffix (any case), or an existing MJCF/URDF by content."""
    if not isinstance(name, str | os.PathLike) or isinstance(name, bytes):
        return False
    p = Path(os.fspath(name))
    if p.suffix.lower() in (".xml", ".mjcf", ".urdf"):
        return True
    if not p.is_file():
        return False
    try:
        model_kind(p)
    except (InvalidArgument, OSError):
        return False
    return True


def _mujoco_message(exc: BaseException) -> str:
    """MuJoCo's error as one line: its first line, plus the element it names."""
    lines = [ln.strip() for ln in str(exc).strip().splitlines() if ln.strip()]
    if not lines:
        return type(exc).__name__
    first = lines[0].removeprefix("Error: ").removeprefix("XML Error: ")
    if first.startswith("XML parse error") and len(lines) > 1:  # tinyxml2: the reason and line on the next line
        detail = re.sub(r"ErrorID=\S+ \(\S+\) ", "", lines[1].removeprefix("Error="))
        return f"not a valid XML file: {detail}"
    element = next((ln for ln in lines[1:] if ln.startswith("Element")), "")
    return first + (f" ({element})" if element else "")


def _includes(text: str, folder: Path) -> dict[str, bytes]:
    """The files ``<include file="...">`` names in ``text`` (recursively), by the attribute as written."""
    out: dict[str, bytes] = {}
    todo = [text]
    while todo:
        for name in re.findall(r"<include\s[^>]*?file\s*=\s*[\"']([^\"']+)[\"']", todo.pop()):
            if name in out:
                continue
            p = Path(name) if Path(name).is_absolute() else folder / name
            if p.is_file():  # else MuJoCo names the missing file
                out[name] = p.read_bytes()
                todo.append(out[name].decode("utf-8", errors="replace"))
    return out


def _parse(path: Path, kind: str) -> mujoco.MjSpec:
    """``MjSpec`` of a model file whatever its suffix (MuJoCo itself picks its decoder by the exact suffix)."""
    if path.suffix in _NATIVE_SUFFIXES:
        return mujoco.MjSpec.from_file(str(path))
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError as exc:
        raise InvalidArgument(f"model file '{path}' is not UTF-8 text ({exc.reason} at byte {exc.start})") from None
    spec = mujoco.MjSpec.from_string(text, include=_includes(text, path.parent) if kind == "mjcf" else None)
    spec.modelfiledir = str(path.parent) + os.sep  # meshes and textures relative to the file, as from_file does
    return spec


def _report(messages: list[str], path: Path) -> None:
    for msg in messages:
        warnings.warn(ModelWarning(f"MuJoCo, loading '{path.name}': {msg}"), stacklevel=3)


def load_spec(model: str | os.PathLike[str], *, shipped: bool = False) -> tuple[mujoco.MjSpec, Path, str]:
    """Parse a model file (MJCF or URDF, by content) into an ``MjSpec``: the one loader of model files.

    Args:
        model: File path or shipped asset name.
        shipped: Look ``model`` up among the shipped assets only (a plant's own
            asset: a same-named file in the current directory never shadows it).

    Returns:
        ``(spec, absolute path, kind)`` with kind ``"mjcf"`` or ``"urdf"``.

    Raises:
        FileNotFoundError: no such file or shipped asset.
        InvalidArgument: not an MJCF/URDF file, or MuJoCo cannot parse it (its message, one line).
    """
    if shipped:
        from shinro_ctrl.resources import shipped_asset

        path = shipped_asset(model).resolve()
    else:
        path = resolve_model_path(model)
    kind = model_kind(path)
    with collect_messages() as said:
        try:
            spec = _parse(path, kind)
        except ValueError as exc:
            what = "URDF" if kind == "urdf" else "MJCF model"
            raise InvalidArgument(f"MuJoCo cannot read {what} '{path}': {_mujoco_message(exc)}") from None
    _report(said, path)
    return spec, path, kind


def _compile(spec: mujoco.MjSpec, source: Path, kind: str) -> mujoco.MjModel:
    """Compile ``spec``; a MuJoCo error becomes one line naming the user's file and, for a URDF, the link.

    When the file holds non-finite numbers, those are named first: MuJoCo's own error for them is about
    what they broke (``sameframe no longer holds``), not about them.
    """
    with collect_messages() as said:
        try:
            m = spec.compile()
        except ValueError as exc:
            bad = _spec_nonfinite(spec, kind)
            if bad:
                what = "URDF" if kind == "urdf" else "MJCF model"
                raise InvalidArgument(
                    f"{what} '{source}' holds non-finite numbers: {', '.join(bad)} (MuJoCo: {_mujoco_message(exc)})"
                ) from None
            raise InvalidArgument(_compile_error(exc, source, kind)) from None
    _report(said, source)
    return m


def _spec_nonfinite(spec: mujoco.MjSpec, kind: str) -> list[str]:
    """The non-finite numbers among the option, body, joint and actuator attributes of ``spec``."""
    out: list[str] = []

    def check(what: str, value: object) -> None:
        v = np.asarray(value, dtype=float)
        unset = v.ndim == 1 and v.size > 1 and np.isnan(v[0]) and not np.any(v[1:])  # MjSpec's "not given"
        if not np.isfinite(v).all() and not unset:
            out.append(f"{what} = [{', '.join(f'{c:g}' for c in v.ravel())}]" if v.ndim else f"{what} = {v:g}")

    check("<option gravity>", spec.option.gravity)
    check("<option timestep>", spec.option.timestep)
    body_word = "link" if kind == "urdf" else "body"
    for b in spec.bodies:
        if b is spec.worldbody:
            continue
        name = f"{body_word} '{b.name}'" if b.name else f"{body_word} #{b.id}"
        for attr, label in (("pos", "pos"), ("quat", "quat"), ("mass", "mass"), ("ipos", "inertial pos")):
            check(f"{name} {label}", getattr(b, attr))
        check(f"{name} inertia", b.inertia)
    for j in spec.joints:
        name = f"joint '{j.name}'" if j.name else f"joint #{j.id}"
        for attr in ("axis", "pos", "damping", "armature", "stiffness", "ref", "springref", "range"):
            check(f"{name} {attr}", getattr(j, attr))
    for a in spec.actuators:
        name = f"actuator '{a.name}'" if a.name else f"actuator #{a.id}"
        check(f"{name} gear", a.gear)
        check(f"{name} gainprm", a.gainprm[:3])
        check(f"{name} biasprm", a.biasprm[:3])
    return out


def _compile_error(exc: BaseException, source: Path, kind: str) -> str:
    msg = _mujoco_message(exc)
    if kind != "urdf":
        return f"MJCF model '{source}' does not compile: {msg}"
    m = re.search(r"Element name '([^']*)'", str(exc))
    link = f"link '{m.group(1)}'" if m and m.group(1) else "a link"
    first = msg.split(" (Element")[0]
    fix = ""
    if "mass and inertia" in first:
        fix = (
            f"; give {link} an <inertial> with a positive <mass> and <inertia>, or add "
            '<mujoco><compiler boundmass="1e-6" boundinertia="1e-9"/></mujoco> inside <robot>'
        )
    elif "inertia" in first:
        fix = f"; the <inertia> of {link} must be positive definite and satisfy the triangle inequality"
    return f"URDF '{source}': {link}: {first} (MuJoCo){fix}"


def load_model(model: str | os.PathLike[str]) -> tuple[mujoco.MjModel, Path]:
    """Compile a model file (MJCF or URDF, recognized by content) with MuJoCo.

    Returns:
        ``(MjModel, absolute path)``.

    Raises:
        FileNotFoundError: no such file or shipped asset.
        InvalidArgument: not a model file, or MuJoCo cannot load it (its message quoted).
    """
    spec, path, kind = load_spec(model)
    return _compile(spec, path, kind), path


# ---------------------------------------------------------------------- URDF
@dataclass(frozen=True)
class _Urdf:
    """What the URDF itself says, for messages in its own terms (MuJoCo's translation loses it)."""

    mimic: dict[str, str] = field(default_factory=dict)  # joint -> the joint it mimics
    friction: tuple[str, ...] = ()  # joints with <dynamics friction> > 0
    floating: tuple[str, ...] = ()  # joints of type floating
    root: str = ""  # the root link
    root_mass: float = 0.0  # mass welded to the root link (through fixed joints)
    root_branches: tuple[str, ...] = ()  # moving joints hanging from the welded root


def _float(text: str | None) -> float:
    try:
        return float(text) if text is not None else 0.0
    except ValueError:
        return 0.0


def _read_urdf(path: Path) -> _Urdf:
    try:
        root = ET.parse(path).getroot()
    except ET.ParseError:
        return _Urdf()
    links = [link.get("name", "") for link in root.findall("link")]
    mass = {
        link.get("name", ""): _float(m.get("value")) if (m := link.find("inertial/mass")) is not None else 0.0
        for link in root.findall("link")
    }
    joints = root.findall("joint")
    children = {c.get("link", "") for j in joints if (c := j.find("child")) is not None}
    mimic, friction, floating = {}, [], []
    for j in joints:
        name = j.get("name", "")
        if (mm := j.find("mimic")) is not None:
            mimic[name] = mm.get("joint", "")
        if (dyn := j.find("dynamics")) is not None and _float(dyn.get("friction")) != 0.0:
            friction.append(name)
        if j.get("type") == "floating":
            floating.append(name)
    top = next((name for name in links if name not in children), "")
    welded, branches, todo = {top}, [], [top]
    while todo:
        parent = todo.pop()
        for j in joints:
            p, c = j.find("parent"), j.find("child")
            if p is None or c is None or p.get("link") != parent:
                continue
            if j.get("type") == "fixed":
                welded.add(c.get("link", ""))
                todo.append(c.get("link", ""))
            else:
                branches.append(j.get("name", ""))
    return _Urdf(
        mimic=mimic,
        friction=tuple(friction),
        floating=tuple(floating),
        root=top,
        root_mass=float(sum(mass.get(name, 0.0) for name in welded)),
        root_branches=tuple(branches),
    )


def _translation_path(src: Path) -> Path:
    key = hashlib.sha1(f"{src}:{src.stat().st_mtime_ns}:mimic-unactuated".encode()).hexdigest()[:12]
    return Path(tempfile.gettempdir()) / "shinro_ctrl_urdf" / f"{src.stem}-{key}.xml"


def urdf_with_motors(path: str | os.PathLike[str]) -> Path:
    """An MJCF file for a URDF robot, with one motor on every hinge and slide joint.

    URDF describes no actuators, so MuJoCo compiles a URDF without any. This
    writes MuJoCo's translation of the URDF plus a motor (gain 1, gear 1,
    named after its joint) per hinge/slide joint except the ``<mimic>`` joints
    (MuJoCo couples those to their leader by an equality constraint: the
    leader's motor drives them), with contacts disabled (the
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
        InvalidArgument: MuJoCo cannot read or compile the URDF (the message
            names the URDF file and the link, never the translation).
    """
    spec, src, kind = load_spec(path)
    if kind != "urdf" or len(spec.actuators):
        return src
    out = _translation_path(src)
    if out.is_file():
        return out
    for attr in ("meshdir", "texturedir"):
        folder = Path(getattr(spec, attr) or ".")
        setattr(spec, attr, str(folder if folder.is_absolute() else (src.parent / folder).resolve()))
    _compile(spec, src, "urdf")  # the URDF's own errors, in its terms, before the translation exists
    mimic = _read_urdf(src).mimic
    for joint in spec.joints:
        if int(joint.type) in _JOINT_KINDS and joint.name and joint.name not in mimic:
            motor = spec.add_actuator()
            motor.name = joint.name
            motor.target = joint.name
            motor.trntype = mujoco.mjtTrn.mjTRN_JOINT
    spec.option.disableflags = int(spec.option.disableflags) | int(_DSBL.mjDSBL_CONTACT)
    with collect_messages():
        try:
            xml = spec.to_xml()
        except ValueError as exc:
            raise InvalidArgument(_compile_error(exc, src, "urdf")) from None
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_suffix(f".{os.getpid()}.tmp")
    tmp.write_text(xml, encoding="utf-8")
    os.replace(tmp, out)  # atomic: concurrent workers never read a half-written file
    return out


# -------------------------------------------------------------- the robot
@dataclass(frozen=True)
class RobotModel:
    """A model file read for :class:`~shinro_ctrl.plants.mjcf.MjcfPlant`.

    Attributes:
        tree: The kinematic tree and its options.
        path: The MJCF file plant and engine load (for a URDF, its translation with motors).
        source: The user's file (the URDF itself for a URDF).
        kind: ``"mjcf"`` or ``"urdf"``.
        keyframe: ``(name, [qpos; qvel; act] (2 nq + na,))`` of the model's first keyframe, or None.
        notes: What the user should know about how the file was read (MuJoCo's warnings
            are reported when it loads; these are ours, e.g. a URDF's base welded to the world).
    """

    tree: ModelTree
    path: Path
    source: Path
    kind: str
    keyframe: tuple[str, np.ndarray] | None = None
    notes: tuple[str, ...] = ()


def read_robot(model: str | os.PathLike[str]) -> RobotModel:
    """Read a model file for ``MjcfPlant``: load, check and read it, in the user's terms.

    A URDF gets a motor per joint (:func:`urdf_with_motors`); every message
    names the user's file and, for a URDF, the URDF element.

    Raises:
        FileNotFoundError: no such file.
        InvalidArgument: not a model file, MuJoCo cannot load it, or it uses
            features ``MjcfPlant`` does not support or holds invalid numbers
            (all of them listed in one message).
    """
    source = resolve_model_path(model)
    kind = model_kind(source)
    urdf = _read_urdf(source) if kind == "urdf" else None
    label = _Label(source=source, kind=kind, urdf=urdf or _Urdf())
    path = source
    if kind == "urdf":
        # MuJoCo's translation drops what it cannot write (a NaN origin becomes 0): check the URDF's own numbers
        own, _ = load_model(source)
        bad = _bad_numbers(own, label)
        if bad:
            raise InvalidArgument(f"{label.file} cannot be read as an MjcfPlant: {'; '.join(bad)}")
        path = urdf_with_motors(source)
    m, _ = load_model(path)
    tree = _read(m, str(path), label)
    keyframe = None
    if m.nkey:
        keyframe = (m.key(0).name, np.concatenate([m.key_qpos[0], m.key_qvel[0], m.key_act[0]]).astype(float))
    notes = []
    if urdf is not None and urdf.root_mass > 0.0 and len(urdf.root_branches) >= 2:
        notes.append(
            f"'{source.name}': MuJoCo welds the URDF's root link '{urdf.root}' ({urdf.root_mass:g} kg, with "
            f"{len(urdf.root_branches)} moving branches: {', '.join(urdf.root_branches)}) to the world: the robot "
            "is simulated fixed-base, hanging in place; a floating base (legs, wheels) is not modelled"
        )
    return RobotModel(tree=tree, path=path, source=source, kind=kind, keyframe=keyframe, notes=tuple(notes))


def read_model_tree(model: str | os.PathLike[str] | mujoco.MjModel, *, path: str = "") -> ModelTree:
    """Read a model file (or a compiled ``MjModel``) into a :class:`ModelTree`.

    Args:
        model: MJCF/URDF path, shipped asset name, or an ``MjModel``.
        path: Recorded as :attr:`ModelTree.path` when ``model`` is an ``MjModel``.

    Raises:
        FileNotFoundError: no such file.
        InvalidArgument: every unsupported feature (free or ball joints, no
            joints, no actuators, an actuator with another transmission,
            other activation dynamics or another gain or bias, tendon, flex or
            inactive equality constraints, spatial tendons that act, fluid
            forces ...) and every non-finite or invalid number, listed at once
            by element name.
    """
    if isinstance(model, mujoco.MjModel):
        m = model
        source = Path(path) if path else Path(m.names[: m.names.find(b"\0")].decode() or "<model>")
    else:
        robot = read_robot(model)
        return robot.tree
    return _read(m, path, _Label(source=source, kind="mjcf", urdf=_Urdf()))


@dataclass(frozen=True)
class _Label:
    source: Path
    kind: str
    urdf: _Urdf

    @property
    def file(self) -> str:
        return f"{'URDF' if self.kind == 'urdf' else 'model'} '{self.source}'"


def _read(m: mujoco.MjModel, path: str, label: _Label) -> ModelTree:
    problems = _unsupported(m, label) + _bad_numbers(m, label)
    if problems:
        raise InvalidArgument(f"{label.file} cannot be read as an MjcfPlant: {'; '.join(problems)}")
    joints, body_joints = _read_joints(m)
    bodies = _read_bodies(m, body_joints)
    actuators = [_read_actuator(m, a) for a in range(m.nu)]
    tree = _tree_with_options(m, path, bodies, joints, actuators)
    return replace(tree, equalities=read_equalities(m, label))


def read_equalities(m: mujoco.MjModel, label: _Label | None = None) -> tuple[Constraint, ...]:
    """The model's active equality constraints as :class:`~shinro_ctrl.multibody.constraints.Constraint`.

    MuJoCo's data layout (``eq_data``): a joint coupling holds ``polycoef``; a body ``connect`` the
    anchor in body 1 then the matching point in body 2; a body ``weld`` the anchor in body 2, then
    ``relpose`` (frame 1's pose in body 1) and ``torquescale``. Site-based ``connect``/``weld`` use
    the sites' frames. Nothing when the model disables equalities; unsupported kinds are
    :func:`_unsupported`'s to refuse.
    """
    urdf = label.urdf if label is not None and label.kind == "urdf" else _Urdf()
    if int(m.opt.disableflags) & int(_DSBL.mjDSBL_EQUALITY):
        return ()
    out = []
    for e in range(m.neq):
        kind = _EQ_KINDS.get(int(m.eq_type[e]))
        if kind is None or not m.eq_active0[e]:
            continue
        o1, o2, data = int(m.eq_obj1id[e]), int(m.eq_obj2id[e]), np.array(m.eq_data[e], dtype=float)
        if kind == "joint":
            name = m.joint(o1).name
            what = (
                f"<mimic> on joint '{name}' (of '{urdf.mimic[name]}')"
                if name in urdf.mimic
                else f"equality {_equality(m, e)}"
            )
            out.append(Constraint("joint", what, joint1=o1, joint2=o2, polycoef=tuple(float(c) for c in data[:5])))
            continue
        what = f"equality {_equality(m, e)}"
        if int(m.eq_objtype[e]) == int(mujoco.mjtObj.mjOBJ_SITE):
            frames = [(int(m.site_bodyid[s]), np.array(m.site_pos[s]), np.array(m.site_quat[s])) for s in (o1, o2)]
        elif kind == "connect":
            frames = [(o1, data[0:3], np.array([1.0, 0, 0, 0])), (o2, data[3:6], np.array([1.0, 0, 0, 0]))]
        else:  # body weld: frame 1 = relpose in body 1, frame 2 = the anchor (body 2's axes)
            frames = [(o1, data[3:6], data[6:10]), (o2, data[0:3], np.array([1.0, 0, 0, 0]))]
        (b1, p1, r1), (b2, p2, r2) = frames
        out.append(
            Constraint(
                kind,
                what,
                body1=b1,
                pos1=p1,
                quat1=r1,
                body2=max(b2, 0),
                pos2=p2,
                quat2=r2,
                rotation=kind == "weld" and float(data[10]) != 0.0,
            )
        )
    return tuple(out)


# ------------------------------------------------------------------- names
def _body(m: mujoco.MjModel, b: int) -> str:
    name = m.body(b).name
    if name:
        return f"'{name}'"
    return f"#{b} (child of {_body(m, int(m.body_parentid[b]))})" if b else "'world'"


def _joint(m: mujoco.MjModel, j: int) -> str:
    name = m.joint(j).name
    return f"'{name}'" if name else f"#{j} (of body {_body(m, int(m.jnt_bodyid[j]))})"


def _actuator(m: mujoco.MjModel, a: int) -> str:
    name = m.actuator(a).name
    if name:
        return f"'{name}'"
    t, target = int(m.actuator_trntype[a]), int(m.actuator_trnid[a, 0])
    on = {
        int(mujoco.mjtTrn.mjTRN_JOINT): lambda: f"joint {_joint(m, target)}",
        int(mujoco.mjtTrn.mjTRN_TENDON): lambda: f"tendon {_tendon(m, target)}",
        int(mujoco.mjtTrn.mjTRN_SITE): lambda: f"site '{m.site(target).name or target}'",
        int(mujoco.mjtTrn.mjTRN_BODY): lambda: f"body {_body(m, target)}",
    }.get(t, lambda: f"#{target}")()
    return f"#{a} (on {on})"


def _tendon(m: mujoco.MjModel, t: int) -> str:
    name = m.tendon(t).name
    return f"'{name}'" if name else f"#{t}"


def _equality(m: mujoco.MjModel, e: int) -> str:
    name = m.equality(e).name
    kind = mujoco.mjtEq(int(m.eq_type[e])).name.removeprefix("mjEQ_").lower()
    o1, o2 = int(m.eq_obj1id[e]), int(m.eq_obj2id[e])
    on_sites = int(m.eq_objtype[e]) == int(mujoco.mjtObj.mjOBJ_SITE)

    def frame(i: int) -> str:
        return (f"site '{m.site(i).name}'" if m.site(i).name else f"site #{i}") if on_sites else f"body {_body(m, i)}"

    verb, obj = {
        "joint": ("coupling", lambda i: f"joint {_joint(m, i)}"),
        "tendon": ("coupling", lambda i: f"tendon {_tendon(m, i)}"),
        "connect": ("connecting", frame),
        "weld": ("welding", frame),
    }.get(kind, ("", None))
    if obj is None:
        what = f"{kind} #{e}"
    else:
        what = f"{verb} {obj(o1)}" + (f" to {obj(o2)}" if o2 >= 0 else "")
    return f"'{name}' ({what})" if name else what


def _plural(phrase: str) -> str:
    """``"frictionloss on joint"`` -> ``"frictionloss on joints"`` (the last word made plural)."""
    head, _, last = phrase.rpartition(" ")
    last = last[:-1] + "ies" if last.endswith("y") else last + "s"
    return f"{head} {last}".strip()


def _group(items: list[tuple[str, str, str]]) -> list[str]:
    """``(phrase, name, note)`` triples -> one ``"phrase(s) name, name (note)"`` per phrase, in first-seen order."""
    grouped: dict[tuple[str, str], list[str]] = {}
    for phrase, name, note in items:
        names = grouped.setdefault((phrase, note), [])
        if name and name not in names:
            names.append(name)
    out = []
    for (phrase, note), names in grouped.items():
        head = _plural(phrase) if len(names) > 1 else phrase
        out.append(" ".join(part for part in (head, ", ".join(names), f"({note})" if note else "") if part))
    return out


# ------------------------------------------------------------- the checks
def _rows(arr: np.ndarray) -> np.ndarray:
    """Indices of the rows of ``arr`` (any trailing shape) with a nonzero entry."""
    arr = np.asarray(arr)
    if not arr.size:
        return np.zeros(0, dtype=int)
    return np.flatnonzero(np.any(arr.reshape(arr.shape[0], -1) != 0.0, axis=1))


def _is_fixed_tendon(m: mujoco.MjModel, t: int) -> bool:
    """Whether tendon ``t`` is a fixed tendon (every wrap a joint)."""
    adr, num = int(m.tendon_adr[t]), int(m.tendon_num[t])
    return bool(num) and all(int(m.wrap_type[w]) == int(mujoco.mjtWrap.mjWRAP_JOINT) for w in range(adr, adr + num))


def _tendon_actuators(m: mujoco.MjModel) -> list[int]:
    return [a for a in range(m.nu) if int(m.actuator_trntype[a]) == int(mujoco.mjtTrn.mjTRN_TENDON)]


def _unsupported(m: mujoco.MjModel, label: _Label) -> list[str]:
    """Every model feature MjcfPlant does not support, grouped by feature, with the fix where one exists."""
    urdf = label.urdf
    out: list[tuple[str, str, str]] = []
    flags = int(m.opt.disableflags)
    floating = [j for j in range(m.njnt) if int(m.jnt_type[j]) in _FLOATING_JOINTS]
    for j in floating:
        kind = _FLOATING_JOINTS[int(m.jnt_type[j])]
        name = m.joint(j).name
        b = int(m.jnt_bodyid[j])
        if label.kind == "urdf" and name in urdf.floating:
            out.append(
                ("floating <joint>", f"'{name}'", "a free-flying base from a URDF: not supported yet (use MJCF)")
            )
        elif kind == "free" and (int(m.body_parentid[b]) != 0 or int(m.body_jntnum[b]) != 1):
            out.append(("free joint", _joint(m, j), "supported only as the one joint of a child of the world"))
        if m.jnt_stiffness[j] != 0.0 and not flags & int(_DSBL.mjDSBL_SPRING):
            out.append((f"stiffness on {kind} joint", _joint(m, j), "not supported yet; set stiffness to 0"))
    driven_joints = {
        int(m.actuator_trnid[a, 0]): a
        for a in range(m.nu)
        if int(m.actuator_trntype[a]) == int(mujoco.mjtTrn.mjTRN_JOINT)
    }
    for j in floating:
        if j in driven_joints:
            out.append(
                ("actuator on a ball or free joint", _actuator(m, driven_joints[j]), "not supported yet; use a site")
            )
    for t in range(m.ntendon):
        adr, num = int(m.tendon_adr[t]), int(m.tendon_num[t])
        if any(
            int(m.wrap_objid[w]) in floating
            for w in range(adr, adr + num)
            if int(m.wrap_type[w]) == int(mujoco.mjtWrap.mjWRAP_JOINT)
        ):
            out.append(("tendon on a ball or free joint", _tendon(m, t), "not supported yet"))
    if floating and m.neq and not flags & int(_DSBL.mjDSBL_EQUALITY):
        out.append(("equality constraints with a ball or free joint", "", "not supported yet"))
    if m.njnt == 0:
        out.append(("no joints", "", "nothing moves"))
    if m.nu == 0:
        out.append(("no actuators", "", "MjcfPlant needs at least one input"))
    if m.neq and not flags & int(_DSBL.mjDSBL_EQUALITY):
        for e in range(m.neq):
            if not m.eq_active0[e]:
                out.append(
                    (
                        "inactive equality constraint",
                        _equality(m, e),
                        "MuJoCo may switch it on at run time, which the design model cannot follow; make it "
                        'active="true" or remove it',
                    )
                )
            elif int(m.eq_type[e]) not in _EQ_KINDS:
                kind = mujoco.mjtEq(int(m.eq_type[e])).name.removeprefix("mjEQ_").lower()
                out.append(
                    (
                        f"{kind} equality constraint",
                        _equality(m, e),
                        "not supported: only joint couplings, connect and weld are modelled exactly",
                    )
                )
    if getattr(m, "nflex", 0):
        out.append((f"flexible bodies (flex, {m.nflex})", "", "not supported yet"))
    if getattr(m, "nplugin", 0):
        out.append((f"engine plugins ({m.nplugin})", "", "not supported yet"))
    driven = {int(m.actuator_trnid[a, 0]) for a in _tendon_actuators(m)}
    for t in range(m.ntendon):
        if not _is_fixed_tendon(m, t):
            forces = []
            if m.tendon_stiffness[t] != 0.0:
                forces.append("stiffness")
            if m.tendon_damping[t] != 0.0:
                forces.append("damping")
            if m.tendon_frictionloss[t] != 0.0 and not flags & int(_DSBL.mjDSBL_FRICTIONLOSS):
                forces.append("frictionloss")
            if m.tendon_limited[t] and not flags & int(_DSBL.mjDSBL_LIMIT):
                forces.append("a range")
            if np.asarray(getattr(m, "tendon_armature", np.zeros(m.ntendon)))[t] != 0.0:
                forces.append("armature")
            if forces or t in driven:
                what = f"with {' and '.join(forces)}" if forces else "driven by an actuator"
                out.append(
                    (
                        "spatial tendon",
                        f"{_tendon(m, t)} {what}",
                        "its length follows a path through sites and wrapping geoms, not supported yet "
                        "(fixed tendons are)",
                    )
                )
            continue
        if np.asarray(getattr(m, "tendon_armature", np.zeros(m.ntendon)))[t] != 0.0:
            out.append(("armature on tendon", _tendon(m, t), "it couples the joints' inertia: not supported yet"))
        lo, hi = (float(v) for v in m.tendon_lengthspring[t])
        if m.tendon_stiffness[t] != 0.0 and lo != hi:
            out.append(
                (
                    "a springlength dead band on tendon",
                    f"{_tendon(m, t)} ([{lo:g}, {hi:g}])",
                    "a spring slack inside a range is not smooth; give one springlength",
                )
            )
        for attr, what in (
            ("tendon_stiffnesspoly", "nonlinear stiffness on tendon"),
            ("tendon_dampingpoly", "nonlinear damping on tendon"),
            ("tendon_springyield", "a spring yield on tendon"),
        ):
            if t in set(_rows(getattr(m, attr, np.zeros(0))).tolist()):
                out.append((what, _tendon(m, t), "not supported yet"))
    for attr, what in (
        ("dof_dampingpoly", "nonlinear damping (more than one damping coefficient) on joint"),
        ("jnt_stiffnesspoly", "nonlinear stiffness (more than one stiffness coefficient) on joint"),
        ("jnt_springyield", "a spring yield on joint"),
    ):
        for row in _rows(getattr(m, attr, np.zeros(0))):
            j = int(m.dof_jntid[row]) if attr.startswith("dof_") else int(row)
            out.append((what, _joint(m, j), "not supported yet"))
    for attr, what in (
        ("actuator_armature", "armature"),
        ("actuator_damping", "damping"),
        ("actuator_dampingpoly", "nonlinear damping"),
        ("actuator_delay", "a delay"),
    ):
        for a in _rows(getattr(m, attr, np.zeros(0))):
            out.append(
                (
                    f"{what} on actuator",
                    _actuator(m, int(a)),
                    "not supported yet; put rotor inertia and damping on the joint: armature, damping",
                )
            )
    for a in np.flatnonzero(np.asarray(getattr(m, "actuator_ctrlnum", np.ones(m.nu))) != 1):
        out.append(("several controls on actuator", _actuator(m, int(a)), "not supported yet"))
    for a in range(m.nu):
        trn = int(m.actuator_trntype[a])
        if trn not in _TRANSMISSIONS:
            kind = mujoco.mjtTrn(trn).name.removeprefix("mjTRN_").lower()
            out.append((f"{kind} transmission on actuator", _actuator(m, a), "supported: joint, fixed tendon and site"))
        elif trn == int(mujoco.mjtTrn.mjTRN_SITE) and int(m.actuator_trnid[a, 1]) >= 0:
            rot = bool(np.any(m.actuator_gear[a, 3:6] != 0.0))
            by_length = m.actuator_gainprm[a, 1] != 0.0 or m.actuator_biasprm[a, 1] != 0.0
            if rot and by_length:
                out.append(
                    (
                        "rotational site transmission with a refsite and a length-dependent gain or bias on actuator",
                        _actuator(m, a),
                        "MuJoCo's rotation length (an axis-angle) is not smooth at zero; set gear[3:6] to 0, "
                        "or drop the length terms of the gain and bias",
                    )
                )
        dyn = int(m.actuator_dyntype[a])
        if dyn not in _DYNAMICS:
            kind = mujoco.mjtDyn(dyn).name.removeprefix("mjDYN_").lower()
            out.append(
                (
                    f"activation dynamics ({kind}) on actuator",
                    _actuator(m, a),
                    "supported: none, filter, filterexact, integrator",
                )
            )
        elif dyn != int(mujoco.mjtDyn.mjDYN_NONE) and int(m.actuator_actnum[a]) != 1:
            out.append((f"{int(m.actuator_actnum[a])} activations on actuator", _actuator(m, a), "supported: one"))
        elif dyn == int(mujoco.mjtDyn.mjDYN_NONE) and int(m.actuator_actnum[a]) != 0:
            out.append(("an activation without dynamics on actuator", _actuator(m, a), "not supported yet"))
        if dyn != int(mujoco.mjtDyn.mjDYN_NONE) and bool(m.actuator_actearly[a]):
            out.append(
                (
                    "actearly on actuator",
                    _actuator(m, a),
                    'its force uses the next step\'s activation, a discrete-time effect; set actearly="false"',
                )
            )
        gt, bt = int(m.actuator_gaintype[a]), int(m.actuator_biastype[a])
        if gt not in _GAIN or bt not in _BIAS:
            gain = mujoco.mjtGain(gt).name.removeprefix("mjGAIN_").lower()
            bias = mujoco.mjtBias(bt).name.removeprefix("mjBIAS_").lower()
            out.append(
                (
                    f"gain {gain} / bias {bias} on actuator",
                    _actuator(m, a),
                    "supported: fixed/affine gain, none/affine bias",
                )
            )
    if m.opt.density != 0.0 or m.opt.viscosity != 0.0:
        out.append(
            (
                "fluid forces",
                f'(<option density="{m.opt.density:g}" viscosity="{m.opt.viscosity:g}">)',
                'drag and lift on every moving body, not supported yet; fix: <option density="0" viscosity="0"/>',
            )
        )
    return _group(out)


def _bad_numbers(m: mujoco.MjModel, label: _Label) -> list[str]:
    """Every non-finite or invalid number MuJoCo compiled but the tree cannot use, by element and attribute."""
    urdf = label.kind == "urdf"
    out: list[str] = []

    def check(what: str, value: np.ndarray, ok: Callable[[np.ndarray], bool] = lambda v: bool(np.isfinite(v).all())):
        v = np.asarray(value, dtype=float)
        if not ok(v):
            shown = f"[{', '.join(f'{c:g}' for c in v.ravel())}]" if v.ndim else f"{float(v):g}"
            out.append(f"{what} = {shown}")

    check("<option gravity>", m.opt.gravity)
    check("<option timestep>", m.opt.timestep, lambda v: bool(np.isfinite(v) and v > 0.0))
    for b in range(1, m.nbody):
        body = f"link {_body(m, b)}" if urdf else f"body {_body(m, b)}"
        check(f"the <origin> of the joint into {body}" if urdf else f"{body} pos", m.body_pos[b])
        check(f"the <origin rpy> of the joint into {body}" if urdf else f"{body} quat", m.body_quat[b])
        check(f"{body} <inertial> <mass>" if urdf else f"{body} mass", m.body_mass[b])
        check(f"{body} <inertial> <origin>" if urdf else f"{body} inertial pos", m.body_ipos[b])
        check(f"{body} <inertial> orientation" if urdf else f"{body} inertial quat", m.body_iquat[b])
        check(f"{body} <inertia>" if urdf else f"{body} inertia", m.body_inertia[b])
    for j in range(m.njnt):
        joint = f"joint {_joint(m, j)}"
        d, qa = int(m.jnt_dofadr[j]), int(m.jnt_qposadr[j])
        check(f"{joint} axis", m.jnt_axis[j])
        check(f"{joint} pos", m.jnt_pos[j])
        check(f"{joint} damping", m.dof_damping[d])
        check(f"{joint} armature (must be >= 0)", m.dof_armature[d], lambda v: bool(np.isfinite(v) and v >= 0.0))
        check(f"{joint} stiffness", m.jnt_stiffness[j])
        check(f"{joint} ref", m.qpos0[qa])
        check(f"{joint} springref", m.qpos_spring[qa])
        if m.jnt_limited[j]:
            check(f"{joint} range", m.jnt_range[j], lambda v: bool(np.isfinite(v).all() and v[0] <= v[1]))
    for a in range(m.nu):
        act = f"actuator {_actuator(m, a)}"
        if int(m.actuator_trntype[a]) == int(mujoco.mjtTrn.mjTRN_SITE):
            check(
                f"{act} gear (all 0: the actuator moves nothing)",
                m.actuator_gear[a],
                lambda v: bool(np.isfinite(v).all() and np.any(v)),
            )
        else:
            check(
                f"{act} gear (0: the actuator moves nothing)",
                m.actuator_gear[a, 0],
                lambda v: bool(np.isfinite(v) and v),
            )
        if int(m.actuator_dyntype[a]) in (int(mujoco.mjtDyn.mjDYN_FILTER), int(mujoco.mjtDyn.mjDYN_FILTEREXACT)):
            check(f"{act} dynprm (the time constant must be > 0)", m.actuator_dynprm[a, 0], lambda v: bool(v > 0.0))
        check(f"{act} gainprm", m.actuator_gainprm[a, :3])
        check(f"{act} biasprm", m.actuator_biasprm[a, :3])
        if m.actuator_ctrllimited[a]:
            check(f"{act} ctrlrange", m.actuator_ctrlrange[a], lambda v: bool(np.isfinite(v).all() and v[0] <= v[1]))
        if m.actuator_forcelimited[a]:
            check(f"{act} forcerange", m.actuator_forcerange[a], lambda v: bool(np.isfinite(v).all() and v[0] <= v[1]))
    for t in range(m.ntendon):
        ten = f"tendon {_tendon(m, t)}"
        adr, num = int(m.tendon_adr[t]), int(m.tendon_num[t])
        check(f"{ten} coef", m.wrap_prm[adr : adr + num])
        check(f"{ten} stiffness", m.tendon_stiffness[t])
        check(f"{ten} damping", m.tendon_damping[t])
        check(f"{ten} springlength", m.tendon_lengthspring[t])
    for b in range(1, m.nbody):
        check(f"body {_body(m, b)} gravcomp", m.body_gravcomp[b])
    for k in range(m.nkey):
        key = f"keyframe '{m.key(k).name}'" if m.key(k).name else f"keyframe #{k}"
        check(f"{key} qpos", m.key_qpos[k])
        check(f"{key} qvel", m.key_qvel[k])
        check(f"{key} act", m.key_act[k])
    if out:
        return [f"invalid numbers (non-finite or out of their domain; fix them in the file): {', '.join(out)}"]
    return []


# ------------------------------------------------------------------- reading
def _read_joints(m: mujoco.MjModel) -> tuple[list[JointInfo], dict[int, list[int]]]:
    """The joints, and body index -> indices of the joints on that body."""
    joints = []
    body_joints: dict[int, list[int]] = {}
    limits = not int(m.opt.disableflags) & int(_DSBL.mjDSBL_LIMIT)
    friction = not int(m.opt.disableflags) & int(_DSBL.mjDSBL_FRICTIONLOSS)
    for j in range(m.njnt):
        d = int(m.jnt_dofadr[j])
        b = int(m.jnt_bodyid[j])
        body_joints.setdefault(b, []).append(j)
        joints.append(
            JointInfo(
                name=m.joint(j).name,
                type=_ALL_JOINTS[int(m.jnt_type[j])],
                body=b,
                axis=np.array(m.jnt_axis[j], dtype=float),
                pos=np.array(m.jnt_pos[j], dtype=float),
                qpos0=float(m.qpos0[int(m.jnt_qposadr[j])]) if int(m.jnt_type[j]) in _JOINT_KINDS else 0.0,
                damping=float(m.dof_damping[d]),
                armature=float(m.dof_armature[d]),
                stiffness=float(m.jnt_stiffness[j]),
                springref=float(m.qpos_spring[int(m.jnt_qposadr[j])]) if int(m.jnt_type[j]) in _JOINT_KINDS else 0.0,
                limited=bool(m.jnt_limited[j]) and limits,
                range=(float(m.jnt_range[j, 0]), float(m.jnt_range[j, 1])),
                frictionloss=float(m.dof_frictionloss[d]) if friction else 0.0,
                actgravcomp=bool(m.jnt_actgravcomp[j]),
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
            gravcomp=float(m.body_gravcomp[b]),
        )
        for b in range(m.nbody)
    ]


def _read_actuator(m: mujoco.MjModel, a: int) -> ActuatorInfo:
    """Actuator ``a`` (already checked by :func:`_unsupported`)."""
    gt, bt = int(m.actuator_gaintype[a]), int(m.actuator_biastype[a])
    gain = (float(m.actuator_gainprm[a, 0]), float(m.actuator_gainprm[a, 1]), float(m.actuator_gainprm[a, 2]))
    bias = (float(m.actuator_biasprm[a, 0]), float(m.actuator_biasprm[a, 1]), float(m.actuator_biasprm[a, 2]))
    kind = "general"
    if _GAIN[gt] == "fixed" and _BIAS[bt] == "none" and gain[0] == 1.0:
        kind = "motor"
    elif _GAIN[gt] == "fixed" and _BIAS[bt] == "affine" and bias[0] == 0.0:
        if bias[1] == -gain[0] and bias[1] != 0.0:
            kind = "position"
        elif bias[1] == 0.0 and bias[2] == -gain[0]:
            kind = "velocity"
    clamp_ctrl = bool(m.actuator_ctrllimited[a]) and not m.opt.disableflags & int(_DSBL.mjDSBL_CLAMPCTRL)
    ctrl = (float(m.actuator_ctrlrange[a, 0]), float(m.actuator_ctrlrange[a, 1]))
    force = (float(m.actuator_forcerange[a, 0]), float(m.actuator_forcerange[a, 1]))
    trn = _TRANSMISSIONS[int(m.actuator_trntype[a])]
    target = int(m.actuator_trnid[a, 0])
    dyn = _DYNAMICS[int(m.actuator_dyntype[a])]
    act_limited = dyn != "none" and bool(m.actuator_actlimited[a])
    return ActuatorInfo(
        name=m.actuator(a).name,
        kind=kind,
        joint=target if trn == "joint" else -1,
        gear=float(m.actuator_gear[a, 0]),
        transmission=trn,
        target=target,
        refsite=int(m.actuator_trnid[a, 1]) if trn == "site" else -1,
        gear6=tuple(float(g) for g in m.actuator_gear[a]),
        dyntype=dyn,
        dynprm=(float(m.actuator_dynprm[a, 0]), float(m.actuator_dynprm[a, 1]), float(m.actuator_dynprm[a, 2])),
        act=int(m.actuator_actadr[a]) if dyn != "none" else -1,
        actrange=(float(m.actuator_actrange[a, 0]), float(m.actuator_actrange[a, 1])) if act_limited else None,
        gaintype=_GAIN[gt],
        gainprm=gain,
        biastype=_BIAS[bt],
        biasprm=bias,
        ctrlrange=ctrl if clamp_ctrl else None,
        forcerange=force if m.actuator_forcelimited[a] else None,
    )


def _read_tendons(m: mujoco.MjModel) -> list[TendonInfo]:
    """The tendons (fixed ones; :func:`_unsupported` refused spatial tendons that act)."""
    flags = int(m.opt.disableflags)
    out = []
    for t in range(m.ntendon):
        if not _is_fixed_tendon(m, t):
            continue
        adr, num = int(m.tendon_adr[t]), int(m.tendon_num[t])
        out.append(
            TendonInfo(
                name=m.tendon(t).name,
                joints=tuple(int(m.wrap_objid[w]) for w in range(adr, adr + num)),
                coefs=tuple(float(m.wrap_prm[w]) for w in range(adr, adr + num)),
                stiffness=float(m.tendon_stiffness[t]),
                springlength=float(m.tendon_lengthspring[t, 0]),
                damping=float(m.tendon_damping[t]),
                frictionloss=0.0 if flags & int(_DSBL.mjDSBL_FRICTIONLOSS) else float(m.tendon_frictionloss[t]),
                limited=bool(m.tendon_limited[t]) and not flags & int(_DSBL.mjDSBL_LIMIT),
                range=(float(m.tendon_range[t, 0]), float(m.tendon_range[t, 1])),
            )
        )
    return out


def _read_sites(m: mujoco.MjModel) -> list[SiteInfo]:
    return [
        SiteInfo(
            name=m.site(s).name,
            body=int(m.site_bodyid[s]),
            pos=np.array(m.site_pos[s], dtype=float),
            quat=np.array(m.site_quat[s], dtype=float),
        )
        for s in range(m.nsite)
    ]


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
        tendons=tuple(_read_tendons(m)),
        sites=tuple(_read_sites(m)),
        frictionloss_enabled=not flags & int(_DSBL.mjDSBL_FRICTIONLOSS),
    )


def read_contact_frames(model: str | os.PathLike[str]) -> dict[str, ContactFrame]:
    """Every geom, site and body of a model file that can be a contact, by name (a geom's name first, then a site's).

    A sphere geom or site is a point contact, anything else a flat one (see
    :mod:`shinro_ctrl.multibody.contacts`); the friction is the larger of the element's and the floor's
    (the world body's geoms).
    """
    m, _ = load_model(model)
    floor = max((float(m.geom_friction[g, 0]) for g in range(m.ngeom) if m.geom_bodyid[g] == 0), default=0.0)
    sphere = int(mujoco.mjtGeom.mjGEOM_SPHERE)
    out: dict[str, ContactFrame] = {}
    for b in range(1, m.nbody):
        name = m.body(b).name
        if name:
            own = [float(m.geom_friction[g, 0]) for g in range(m.ngeom) if m.geom_bodyid[g] == b]
            out[name] = ContactFrame(name, "body", b, np.zeros(3), np.array([1.0, 0, 0, 0]), False, max([floor, *own]))
    for s in range(m.nsite):
        name = m.site(s).name
        if name:
            b = int(m.site_bodyid[s])
            own = [float(m.geom_friction[g, 0]) for g in range(m.ngeom) if m.geom_bodyid[g] == b]
            out[name] = ContactFrame(
                name,
                "site",
                b,
                np.array(m.site_pos[s], dtype=float),
                np.array(m.site_quat[s], dtype=float),
                int(m.site_type[s]) == sphere,
                max([floor, *own]),
            )
    for g in range(m.ngeom):
        name = m.geom(g).name
        if name:
            out[name] = ContactFrame(
                name,
                "geom",
                int(m.geom_bodyid[g]),
                np.array(m.geom_pos[g], dtype=float),
                np.array(m.geom_quat[g], dtype=float),
                int(m.geom_type[g]) == sphere,
                max(floor, float(m.geom_friction[g, 0])),
            )
    return out
