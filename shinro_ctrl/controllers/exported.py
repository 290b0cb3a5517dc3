"""Software in the loop: an exported C controller (``shinro-ctrl export``) run through ``ctypes``.

:class:`Exported` loads ``libNAME.so`` of an exported folder (building it with the folder's Makefile when it
is missing or older than a source) and calls ``NAME_step`` each step: the exact code that will be deployed
runs in either simulation loop. A scenario selects it with ``[controller] type = "Exported"``,
``path = "DIR"``. The exported unit holds its own estimator and takes the measurement: the loop's
estimate (the identity estimator's output, with the scenario's sensor noise) is cut to the exported
measured states (``measured``) before each step.
"""

from __future__ import annotations

import ctypes
import json
import subprocess
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from shinro_ctrl.controllers.base import CallGuard, Controller
from shinro_ctrl.errors import ExportError, MPCInfeasible, NonFiniteError
from shinro_ctrl.types import Matrix, Vector

if TYPE_CHECKING:
    from shinro_ctrl.plants.base import Plant

__all__ = ["Exported"]

_ERROR = 16
_STATUS = {
    16: "non-finite measurement",
    32: "non-finite result (state far outside the model's range)",
    64: "bad argument",
    128: "the MPC's QP is infeasible at this state",
}
_QP_INFEASIBLE = 128


def _library(folder: Path, name: str, build: bool) -> Path:
    lib = folder / f"lib{name}.so"
    sources = [p for p in folder.iterdir() if p.suffix in (".c", ".h") or p.name == "Makefile"]
    stale = not lib.exists() or any(p.stat().st_mtime > lib.stat().st_mtime for p in sources)
    if stale:
        if not build:
            raise ExportError(f"{folder}: lib{name}.so is missing or older than its sources; build it with 'make'")
        proc = subprocess.run(["make", "-s", f"lib{name}.so"], cwd=folder, capture_output=True, text=True, check=False)
        if proc.returncode != 0:
            msg = (proc.stderr or proc.stdout).strip().splitlines()
            raise ExportError(f"building {folder}/lib{name}.so failed: {msg[0] if msg else 'make failed'}")
    return lib


class Exported(Controller):
    """The controller of an exported C folder, called through ``ctypes`` (software in the loop).

    Args:
        path: The exported folder.
        build: Build ``libNAME.so`` when it is missing or stale.

    Attributes:
        name: The C name.
        measured: Indices of the measured states (the entries of ``x`` passed to ``NAME_step``).
        manifest: The folder's ``export.json``.
        x0, u0, u_min, u_max: The exported controller's operating point and input bounds (from ``export.json``).
        last_status: Status code of the last step.
    """

    stateful = True

    def __init__(self, path: str | Path, *, build: bool = True):
        folder = Path(path)
        try:
            manifest = json.loads((folder / "export.json").read_text(encoding="utf-8"))
        except (OSError, ValueError) as exc:
            raise ExportError(f"{folder} is not an exported folder (no readable export.json): {exc}") from None
        if not isinstance(manifest, dict) or manifest.get("format") != "shinro_ctrl export 1":
            raise ExportError(f"{folder} is not an exported folder (export.json has another format)")
        self.manifest = manifest
        self.path = folder
        self.name = name = str(manifest["name"])
        dims = manifest["dims"]
        self.state_dim, self.input_dim, self._p = int(dims["n"]), int(dims["m"]), int(dims["p"])
        names = list(manifest["state_names"])
        self.measured = tuple(names.index(s) for s in manifest["measured"])
        design = manifest.get("design") or {}
        for key in ("x0", "u0", "u_min", "u_max"):  # the design's operating point and bounds, as the loop reads them
            if design.get(key) is not None:
                setattr(self, key, np.asarray(design[key], dtype=float))
        self._lib = ctypes.CDLL(str(_library(folder, name, build).resolve()))
        size = self._lib[f"{name}_workspace_size"]
        size.argtypes, size.restype = [], ctypes.c_ulong
        self._ws = ctypes.create_string_buffer(int(size()))  # opaque here; malloc'ed, so aligned for doubles
        dp = ctypes.POINTER(ctypes.c_double)
        for fn, args in (
            ("init", [ctypes.c_void_p]),
            ("reset", [ctypes.c_void_p, dp]),
            ("set_reference", [ctypes.c_void_p, dp]),
            ("step", [ctypes.c_void_p, dp, dp]),
        ):
            f = getattr(self._lib, f"{name}_{fn}")
            f.argtypes, f.restype = args, ctypes.c_int
        self._step = self._lib[f"{name}_step"]
        self._setref = self._lib[f"{name}_set_reference"]
        self._y = np.zeros(self._p)
        self._r = np.zeros(self.state_dim)
        self._u = np.zeros(self.input_dim)
        self._yp = self._y.ctypes.data_as(dp)
        self._rp = self._r.ctypes.data_as(dp)
        self._up = self._u.ctypes.data_as(dp)
        self._guard = CallGuard(f"Exported({name})")
        self.last_status = 0
        self._lib[f"{name}_init"](self._ws)

    @classmethod
    def from_plant(cls, plant: Plant, *, path: str) -> Exported:
        """The exported folder at ``path`` for ``plant`` (its state and input sizes must match).

        Raises:
            ExportError: not an exported folder, a build failure, or sizes that do not match the plant.
        """
        ctrl = cls(path)
        if (ctrl.state_dim, ctrl.input_dim) != (plant.state_dim, plant.input_dim):
            raise ExportError(
                f"{path}: exported for {ctrl.state_dim} states and {ctrl.input_dim} inputs, but the plant has "
                f"{plant.state_dim} and {plant.input_dim}"
            )
        return ctrl

    def reset(self) -> None:
        """``NAME_reset(ws, NULL)``: the exported initial estimate, integrators and plan index cleared."""
        with self._guard:
            self._lib[f"{self.name}_reset"](self._ws, None)

    def __call__(self, x: Vector, ref: Vector | Matrix | None = None) -> np.ndarray:
        """``NAME_set_reference`` (when ``ref`` is given) and ``NAME_step`` on the measured entries of ``x``.

        Raises:
            NonFiniteError: the C step returned an error status (naming it).
            MPCInfeasible: an exported MPC found its QP infeasible (status ``QP_INFEASIBLE``).
        """
        if not self._guard.acquire(False):
            raise self._guard.refused()
        try:
            xv = np.asarray(x, dtype=float).reshape(-1)
            self._y[:] = xv[list(self.measured)] if xv.shape[0] != self._p else xv
            if ref is not None:
                r = np.asarray(ref, dtype=float)
                self._r[:] = r[0] if r.ndim == 2 else r
                self._setref(self._ws, self._rp)
            st = self._step(self._ws, self._yp, self._up)
            self.last_status = st
            if st >= _ERROR:
                what = ", ".join(v for k, v in _STATUS.items() if st & k)
                if st & _QP_INFEASIBLE:  # as the Python MPC reports it
                    raise MPCInfeasible(f"exported controller {self.name}: status {st} ({what})")
                raise NonFiniteError(f"exported controller {self.name}: status {st} ({what})")
            return self._u.copy()
        finally:
            self._guard.release()

    def __repr__(self) -> str:
        return f"Exported({str(self.path)!r}, name={self.name!r})"
