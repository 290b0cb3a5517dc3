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

__all__ = ["TINY_INERTIA"]

#: Diagonal inertia [kg m²] given to the point masses of an ``MjcfPatch``:
#: MuJoCo needs a positive inertia; this one is negligible against ``m l²``.
TINY_INERTIA = 1e-8


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
    """Write every field of an ``MjcfPatch`` into ``spec`` (see :meth:`MujocoEngine.for_plant`)."""
    opt = spec.option
    opt.timestep = float(patch.timestep) / substeps
    opt.gravity = np.asarray(patch.gravity, dtype=float)
    opt.integrator = int(mujoco.mjtIntegrator.mjINT_EULER)
    opt.disableflags = int(opt.disableflags) | int(mujoco.mjtDisableBit.mjDSBL_EULERDAMP)
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


def _euler_zyx_from_quat(q: np.ndarray) -> np.ndarray:
    """ZYX Euler angles ``[roll, pitch, yaw]`` (3,) of a unit quaternion ``(w, x, y, z)``."""
    w, x, y, z = (float(c) for c in q)
    roll = math.atan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y))
    pitch = math.asin(max(-1.0, min(1.0, 2.0 * (w * y - z * x))))
    yaw = math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
    return np.array([roll, pitch, yaw])
