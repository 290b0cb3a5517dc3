"""Loading MJCF models and patching them to a plant's parameters (``MjSpec``)."""

from __future__ import annotations

import math
import os
import warnings
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import mujoco
import numpy as np

from shinro_ctrl.engine.model_tree import load_spec
from shinro_ctrl.engine.warnings import ModelWarning, collect_messages
from shinro_ctrl.errors import InvalidArgument, UnknownName
from shinro_ctrl.resources import list_assets
from shinro_ctrl.validation import closest

__all__ = [
    "MODEL_CHOICES",
    "TINY_INERTIA",
    "check_default_parameters",
    "check_realistic_geometry",
    "realistic_asset",
]

#: Diagonal inertia [kg m²] given to the point masses of an ``MjcfPatch``:
#: MuJoCo needs a positive inertia; this one is negligible against ``m l²``.
TINY_INERTIA = 1e-8

#: The MuJoCo models ``MujocoEngine.for_plant(model=...)`` and a scenario's ``[engine] model`` name by a word
#: (anything else is an MJCF path or a shipped asset name): ``matched``, the plant's exact twin (its parameters
#: written in, Euler with explicit damping; for a model file, everything non-smooth off); ``realistic``, the
#: real thing (a built-in plant's ``<asset>_realistic.xml``; a model file as written).
MODEL_CHOICES = ("matched", "realistic")


# ------------------------------------------------------------------- loading
def _check_substeps(substeps: Any) -> int:
    if isinstance(substeps, bool) or not isinstance(substeps, int | np.integer) or substeps < 1:
        raise InvalidArgument(f"substeps must be an integer >= 1, got {substeps!r}")
    return int(substeps)


def _real(value: Any, what: str) -> float:
    try:
        return float(value)
    except (TypeError, ValueError):
        raise InvalidArgument(f"{what} must be one real number, got {value!r}") from None


def _unknown(kind: str, name: Any, names: Iterable[str]) -> UnknownName:
    names = sorted(names)
    near = closest(str(name), names)
    hint = f" (did you mean '{near}'?)" if near is not None else ""
    return UnknownName(f"unknown {kind} {name!r}{hint}; {kind}s in the model: {', '.join(names) or 'none'}")


def _mujoco_message(exc: Exception) -> str:
    lines = [ln.strip() for ln in str(exc).strip().splitlines() if ln.strip()]
    if not lines:
        return type(exc).__name__
    return lines[0] + (f" ({lines[1]})" if len(lines) > 1 and lines[1].startswith("Element") else "")


def _shipped_list() -> str:
    try:
        return ", ".join(list_assets()) or "none"
    except FileNotFoundError:
        return "none"


def _load_spec(path_or_xml: str | Path, *, shipped: bool = False) -> tuple[mujoco.MjSpec, str]:
    """Parse an MJCF path, shipped asset name or XML string into an ``MjSpec``.

    With ``shipped``, ``path_or_xml`` is the name of an asset shipped with the
    package (a plant's own model), looked up in the package's assets folder
    only: a same-named file in the current directory does not shadow it.
    """
    if isinstance(path_or_xml, str) and path_or_xml.lstrip().startswith("<"):
        with collect_messages() as said:
            try:
                spec = mujoco.MjSpec.from_string(path_or_xml)
            except ValueError as exc:
                raise InvalidArgument(f"invalid MJCF XML string: {_mujoco_message(exc)}") from exc
        for msg in said:
            warnings.warn(ModelWarning(f"MuJoCo, loading an XML string: {msg}"), stacklevel=3)
        return spec, "<xml string>"
    if not isinstance(path_or_xml, str | os.PathLike) or isinstance(path_or_xml, bytes):
        raise InvalidArgument(
            "MuJoCo model must be an MJCF file path, a shipped asset name (such as 'cartpole.xml') or an "
            f"MJCF XML string, got {type(path_or_xml).__name__} {path_or_xml!r}"
        )
    if not os.fspath(path_or_xml).strip():
        raise InvalidArgument(
            "MuJoCo model path is empty: give an MJCF file path, a shipped asset name (such as 'cartpole.xml') "
            f"or an MJCF XML string (shipped assets: {_shipped_list()})"
        )
    try:
        spec, path, _ = load_spec(path_or_xml, shipped=shipped)
    except FileNotFoundError:
        if shipped:
            raise FileNotFoundError(
                f"shipped MuJoCo asset not found: '{path_or_xml}' (shipped assets: {_shipped_list()})"
            ) from None
        if Path(path_or_xml).is_dir():
            raise FileNotFoundError(
                f"MuJoCo model path '{path_or_xml}' is a directory, not an MJCF file "
                f"(shipped assets: {_shipped_list()})"
            ) from None
        raise FileNotFoundError(
            f"MuJoCo model file not found: '{path_or_xml}' (shipped assets: {_shipped_list()})"
        ) from None
    return spec, str(path)


def _compile(spec: mujoco.MjSpec, source: str) -> mujoco.MjModel:
    with collect_messages() as said:
        try:
            model = spec.compile()
        except ValueError as exc:
            raise InvalidArgument(f"MJCF model '{source}' does not compile: {_mujoco_message(exc)}") from exc
    for msg in said:
        warnings.warn(ModelWarning(f"MuJoCo, compiling '{Path(source).name}': {msg}"), stacklevel=3)
    return model


def _find(spec: mujoco.MjSpec, kind: str, name: str) -> Any:
    finder = {"body": spec.body, "joint": spec.joint, "geom": spec.geom}[kind]
    element = finder(name)
    if element is None:
        every = {"body": spec.bodies, "joint": spec.joints, "geom": spec.geoms}[kind]
        raise _unknown(kind, name, [e.name for e in every if e.name])
    return element


def _apply_patch(spec: mujoco.MjSpec, patch: Any, substeps: int) -> None:
    """Write every field of an ``MjcfPatch`` into ``spec`` and set the exact-match options (the ``matched`` twin).

    See :meth:`MujocoEngine.for_plant`: the plant's parameters (point masses, positions, damping, ranges,
    visual geoms, gravity, timestep) and :func:`_exact_match_options`.
    """
    opt = spec.option
    opt.timestep = float(patch.timestep) / substeps
    opt.gravity = np.asarray(patch.gravity, dtype=float)
    _exact_match_options(spec)
    for name, (mass, ipos) in patch.inertials.items():
        body = _find(spec, "body", name)
        body.explicitinertial = True
        body.mass = float(mass)
        body.ipos = np.asarray(ipos, dtype=float)
        body.iquat = np.array([1.0, 0.0, 0.0, 0.0])
        body.inertia = np.full(3, TINY_INERTIA)
        body.fullinertia = np.array([math.nan, 0.0, 0.0, 0.0, 0.0, 0.0])
    for name, pos in patch.body_pos.items():
        _find(spec, "body", name).pos = np.asarray(pos, dtype=float)
    for name, inertia in patch.body_inertia.items():
        body = _find(spec, "body", name)
        body.explicitinertial = True
        body.inertia = np.asarray(inertia, dtype=float)
        body.fullinertia = np.array([math.nan, 0.0, 0.0, 0.0, 0.0, 0.0])
    for name, damping in patch.joint_damping.items():
        joint = _find(spec, "joint", name)
        coeffs = np.array(joint.damping, dtype=float)
        coeffs[0] = float(damping)
        joint.damping = coeffs
    for name, (lo, hi) in getattr(patch, "joint_range", {}).items():
        joint = _find(spec, "joint", name)
        joint.limited = int(mujoco.mjtLimited.mjLIMITED_TRUE)
        joint.range = np.array([lo, hi], dtype=float)
        joint.solref_limit = np.array([2.0 * opt.timestep, 1.0])  # the stiffest stable stop: nearly inelastic
        joint.solimp_limit = np.array([0.99, 0.999, 1e-4, 0.5, 2.0])
    for name, fromto in patch.geom_fromto.items():
        fromto = np.asarray(fromto, dtype=float)
        if fromto.shape != (6,):
            raise InvalidArgument(f"geom_fromto['{name}']: expected shape (6,) but found {fromto.shape}")
        _find(spec, "geom", name).fromto = fromto
    for name, size in patch.geom_size.items():
        geom = _find(spec, "geom", name)
        size = np.asarray(size, dtype=float).reshape(-1)
        if not 1 <= size.shape[0] <= 3:
            raise InvalidArgument(f"geom_size['{name}']: expected 1 to 3 values but found {size.shape[0]}")
        full = np.array(geom.size, dtype=float)
        full[: size.shape[0]] = size
        geom.size = full


def _exact_match_options(spec: mujoco.MjSpec) -> None:
    """MuJoCo's (semi-implicit) Euler with ``mjDSBL_EULERDAMP``: joint damping explicit, as in the analytic models.

    The one place the integrator is chosen for a model: only the ``matched`` twins get it.
    """
    opt = spec.option
    opt.integrator = int(mujoco.mjtIntegrator.mjINT_EULER)
    opt.disableflags = int(opt.disableflags) | int(mujoco.mjtDisableBit.mjDSBL_EULERDAMP)


#: What the ``matched`` copy of a user's model file switches off: everything the smooth design model leaves out.
_NOT_SMOOTH = (
    mujoco.mjtDisableBit.mjDSBL_CONTACT,
    mujoco.mjtDisableBit.mjDSBL_LIMIT,
    mujoco.mjtDisableBit.mjDSBL_FRICTIONLOSS,
    mujoco.mjtDisableBit.mjDSBL_CLAMPCTRL,
)


def _idealize_model_file(spec: mujoco.MjSpec) -> None:
    """Make a user's model file the exact twin of its smooth design model (``MjcfPlant``, ``model="matched"``).

    :func:`_exact_match_options`, and off: contacts, joint-limit forces, friction loss, the ``ctrlrange`` clamp
    (``mjDSBL_CLAMPCTRL``, and ``ctrllimited`` off, which ``mjd_transitionFD`` reads), every actuator's
    ``forcerange`` clamp and every joint's ``actuatorfrcrange``. What ``crosscheck`` compares.
    """
    _exact_match_options(spec)
    opt = spec.option
    for bit in _NOT_SMOOTH:
        opt.disableflags = int(opt.disableflags) | int(bit)
    for act in spec.actuators:
        act.forcelimited = int(mujoco.mjtLimited.mjLIMITED_FALSE)
        # mjd_transitionFD keeps its control nudges inside ctrlrange whenever ctrllimited, mjDSBL_CLAMPCTRL or
        # not: a u0 on the edge gave a one-sided difference, one a rounding error past it (an equilibrium input
        # of 1e-10 above a range [-0.08, 0]) a zero column of B.
        act.ctrllimited = int(mujoco.mjtLimited.mjLIMITED_FALSE)
    for joint in spec.joints:
        joint.actfrclimited = int(mujoco.mjtLimited.mjLIMITED_FALSE)


def _check_names(spec: mujoco.MjSpec, patch: Any) -> None:
    """Raise ``UnknownName`` (a ``KeyError``) for the first body or joint the plant's patch names that ``spec`` lacks.

    A model file given for a built-in plant is loaded as written, but it must describe the same mechanism.
    """
    for name in (*patch.inertials, *patch.body_pos, *patch.body_inertia):
        _find(spec, "body", name)
    for name in (*patch.joint_damping, *getattr(patch, "joint_range", {})):
        _find(spec, "joint", name)


def check_realistic_geometry(spec: mujoco.MjSpec, patch: Any, asset: str, plant_name: str) -> None:
    """Refuse a realistic variant whose body positions differ from those the plant's patch gives (its geometry).

    A plant without float parameters (the arm: its joint offsets) must still have the variant's geometry (to
    10 µm, the precision the variants are written with).

    Raises:
        KeyError: the variant lacks a body the patch names.
        InvalidArgument: naming the first body whose position differs.
    """
    for name, pos in patch.body_pos.items():
        have = np.asarray(_find(spec, "body", name).pos, dtype=float)
        want = np.asarray(pos, dtype=float)
        if have.shape != want.shape or not np.allclose(have, want, rtol=0.0, atol=1e-5):
            raise InvalidArgument(
                f"{plant_name}: the realistic MuJoCo model '{asset}' is built for the default geometry, but body "
                f"'{name}' is at {want.tolist()} in the plant and at {have.tolist()} in the model; use "
                'model = "matched" or an MJCF file of your own'
            )


def realistic_asset(asset: str) -> str:
    """A built-in plant's realistic variant of its matched asset: ``"cartpole.xml"`` -> ``"cartpole_realistic.xml"``."""
    path = Path(asset)
    return f"{path.stem}_realistic{path.suffix or '.xml'}"


def check_default_parameters(plant: Any, asset: str) -> None:
    """Refuse a plant whose physical parameters differ from its class defaults (a realistic variant is built for them).

    The realistic variants are written for the defaults (their masses are distributed over real geoms, so no
    point mass can be rewritten); ``damping`` may differ (the variant carries its own joint friction, and the gap
    is the point). ``dt`` is written into the model.

    Raises:
        InvalidArgument: naming the first parameter that differs, its default, and the way out.
    """
    import inspect

    sig = inspect.signature(type(plant).__init__).parameters
    for name, value in plant.params().items():
        if name == "damping" or name not in sig or sig[name].default is inspect.Parameter.empty:
            continue
        default = sig[name].default
        try:
            same = np.allclose(np.asarray(value, dtype=float), np.asarray(default, dtype=float), rtol=1e-12, atol=0.0)
        except (TypeError, ValueError):
            same = value == default
        if not same:
            raise InvalidArgument(
                f"{type(plant).__name__}: the realistic MuJoCo model '{asset}' is built for the default parameters, "
                f'but {name} = {value!r} (default {default!r}); use model = "matched" (the plant\'s own parameters, '
                "idealized) or an MJCF file of your own"
            )


def _euler_zyx_from_quat(q: np.ndarray) -> np.ndarray:
    """ZYX Euler angles ``[roll, pitch, yaw]`` (3,) of a unit quaternion ``(w, x, y, z)``."""
    w, x, y, z = (float(c) for c in q)
    roll = math.atan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y))
    pitch = math.asin(max(-1.0, min(1.0, 2.0 * (w * y - z * x))))
    yaw = math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
    return np.array([roll, pitch, yaw])
