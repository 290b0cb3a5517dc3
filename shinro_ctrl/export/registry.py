"""Exporters by the type they export: :data:`EXPORTERS`, :func:`register_exporter`, :func:`exporter_for`.

An exporter is an object with ``tag`` (``"ctl"`` or ``"est"``) and ``part(obj, ctx) -> Part``
(:class:`Exporter`); ``register_exporter(LQR)`` on its class registers one instance for that type.
:func:`exporter_for` walks the object's class hierarchy (a subclass of ``LQR`` exports as an ``LQR``
unless it registers its own) and refuses an object no exporter handles in one line that lists the
types that can be exported. An exporter that cannot handle one configuration of its type (say,
LQR feed-forward) raises :class:`~shinro_ctrl.errors.ExportError` saying why.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Protocol, TypeVar

from shinro_ctrl.errors import ExportError

if TYPE_CHECKING:
    from shinro_ctrl.controllers.base import Controller
    from shinro_ctrl.estimators.base import Estimator
    from shinro_ctrl.export.parts import Part
    from shinro_ctrl.plants.base import Plant

__all__ = ["EXPORTERS", "ExportContext", "Exporter", "exporter_for", "register_exporter"]


@dataclass(frozen=True)
class ExportContext:
    """What an exporter may need beside the object it exports.

    Attributes:
        name: The export's C name (``NAME``).
        plant: The scenario's plant (its ``symbolic()`` dynamics, ``dt``, names).
        controller: The scenario's controller.
        estimator: The scenario's estimator.
        x_hat_dim: Length of the estimate the estimator hands the controller (``n``, or ``n + m``).
        initial_covariance: The covariance the loop resets a filter with (the scenario's ``P0``), or None.
        x_start: The state the scenario's loop starts from ``(n,)`` (its initial estimate, else its initial
            state), or None; the NonlinearMPC exporter solves its cold start there.
        ref0: The reference at time 0 ``(n,)``, or None.
    """

    name: str
    plant: Plant
    controller: Controller
    estimator: Estimator
    x_hat_dim: int
    initial_covariance: object = None
    x_start: object = None
    ref0: object = None


class Exporter(Protocol):
    """Writes the :class:`~shinro_ctrl.export.parts.Part` of one controller or estimator type."""

    tag: str  # "ctl" (controller) or "est" (estimator)

    def part(self, obj: object, ctx: ExportContext) -> Part:
        """The C of ``obj`` (raises :class:`~shinro_ctrl.errors.ExportError` when it cannot be exported)."""
        ...


#: Exported type -> its exporter (one instance per type).
EXPORTERS: dict[type, Exporter] = {}

E = TypeVar("E")


def register_exporter(*types: type) -> Callable[[type[E]], type[E]]:
    """Class decorator: register an instance of the exporter class for each of ``types``."""

    def deco(cls: type[E]) -> type[E]:
        inst = cls()
        for t in types:
            EXPORTERS[t] = inst  # type: ignore[assignment]
        return cls

    return deco


def exporter_for(obj: object, what: str) -> Exporter:
    """The exporter registered for ``type(obj)`` or its nearest base class.

    Args:
        obj: A controller or an estimator.
        what: ``"controller"`` or ``"estimator"`` (for the message).

    Raises:
        ExportError: no exporter for that type (listing the types that can be exported).
    """
    _load_exporters()
    for cls in type(obj).__mro__:
        exp = EXPORTERS.get(cls)
        if exp is not None:
            return exp
    names = ", ".join(sorted(t.__name__ for t in EXPORTERS))
    raise ExportError(f"cannot export the {what} {type(obj).__name__}: no C exporter for it (exportable: {names})")


def _load_exporters() -> None:
    """Import every module of this package: an exporter module registers its types when imported, so a new
    exporter is a new module here (``export/lqr.py``, ``export/kalman.py``, ...) and no list is edited."""
    import importlib
    import pkgutil

    import shinro_ctrl.export as pkg

    for mod in pkgutil.iter_modules(pkg.__path__):
        if not mod.name.startswith("_"):
            importlib.import_module(f"shinro_ctrl.export.{mod.name}")
