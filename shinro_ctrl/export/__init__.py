"""Export a scenario's controller and estimator as dependency-free C, verified against Python.

* :func:`~shinro_ctrl.export.pipeline.export_scenario` (``shinro-ctrl export``): record the Python loop,
  write the folder, build it with the system compiler and replay the recording in C.
* :func:`load`: the exported folder as a controller (``ctypes``) that ``RobotSim`` runs (software in the loop).
* The framework an exporter plugs into: :mod:`~shinro_ctrl.export.parts` (the C contract of a part, its
  tables and workspace fields), :mod:`~shinro_ctrl.export.registry` (:data:`EXPORTERS` by type),
  :mod:`~shinro_ctrl.export.assemble` (the folder's files). One module per exported type family
  (``lqr``, ``tvlqr``, ``kalman``, ...) registers its exporters when imported.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from shinro_ctrl.export.registry import EXPORTERS, ExportContext, exporter_for, register_exporter

if TYPE_CHECKING:
    from pathlib import Path

    from shinro_ctrl.controllers.exported import Exported

__all__ = ["EXPORTERS", "ExportContext", "exporter_for", "load", "register_exporter"]


def load(path: str | Path, *, build: bool = True) -> Exported:
    """The exported folder at ``path`` as a controller running its compiled C through ``ctypes``.

    Args:
        path: An exported folder (``shinro-ctrl export ... --out DIR``).
        build: Build ``libNAME.so`` with the folder's Makefile when it is missing or older than a source.

    Raises:
        ExportError: not an exported folder, or the build failed.
    """
    from shinro_ctrl.controllers.exported import Exported

    return Exported(path, build=build)
