"""Write a model file with identified inertial and joint parameters (an ``MjSpec`` edit, written atomically).

Used by :meth:`shinro_ctrl.identification.mjcf.ModelFileIdentification.write_model`: each named body gets
an explicit inertial (``mass``, ``ipos``, and the inertia about the COM in the body frame as principal
moments ``inertia`` with their axes ``iquat``), each named joint its ``damping``, ``armature`` or
``frictionloss``. Asset folders are made absolute so the file written elsewhere still finds its meshes.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from pathlib import Path

import mujoco
import numpy as np

from shinro_ctrl.engine.model_tree import load_spec
from shinro_ctrl.errors import InvalidArgument
from shinro_ctrl.files import atomic_write

__all__ = ["write_inertials"]


def write_inertials(
    source: str | os.PathLike[str],
    path: str | os.PathLike[str],
    bodies: Mapping[str, Mapping[str, object]],
    joints: Mapping[str, Mapping[str, float]],
) -> Path:
    """Write ``source`` to ``path`` (MJCF) with ``bodies``' inertials and ``joints``' parameters replaced.

    Args:
        source: The model file.
        path: The file to write (atomically).
        bodies: Body name → ``{"mass", "ipos" (3,), "fullinertia" (xx, yy, zz, xy, xz, yz)}``.
        joints: Joint name → ``{"damping" | "armature" | "frictionloss": value}``.

    Raises:
        InvalidArgument: an unknown body or joint, or a model MuJoCo cannot compile with the new values.
    """
    spec, src, _ = load_spec(source)
    base = src.parent
    for attr in ("meshdir", "texturedir"):
        d = getattr(spec, attr, "")
        setattr(spec, attr, str((base / d).resolve()) if d else str(base))
    for name, vals in bodies.items():
        b = spec.body(name)
        if b is None:
            raise InvalidArgument(f"write_inertials: no body '{name}' in {src}")
        b.explicitinertial = True
        b.mass = float(vals["mass"])  # type: ignore[arg-type]
        b.ipos = np.asarray(vals["ipos"], dtype=float)
        xx, yy, zz, xy, xz, yz = np.asarray(vals["fullinertia"], dtype=float)
        lam, V = np.linalg.eigh(np.array([[xx, xy, xz], [xy, yy, yz], [xz, yz, zz]]))
        if np.linalg.det(V) < 0:
            V[:, 0] = -V[:, 0]
        quat = np.zeros(4)
        mujoco.mju_mat2Quat(quat, V.reshape(-1))
        b.iquat = quat  # principal axes: MuJoCo's own form of an inertia (I_c = R diag(λ) Rᵀ)
        b.inertia = lam
    for name, vals in joints.items():
        j = spec.joint(name)
        if j is None:
            raise InvalidArgument(f"write_inertials: no joint '{name}' in {src}")
        for attr, v in vals.items():
            cur = getattr(j, attr)
            if isinstance(cur, np.ndarray):  # MuJoCo >= 3.3 stores damping per polynomial coefficient
                cur = cur.copy()
                cur[0] = float(v)
                setattr(j, attr, cur)
            else:
                setattr(j, attr, float(v))
    try:
        spec.compile()
    except ValueError as exc:
        raise InvalidArgument(f"write_inertials: MuJoCo cannot compile the identified model: {exc}") from None
    xml = spec.to_xml()
    return atomic_write(Path(path), lambda f: f.write(xml))
