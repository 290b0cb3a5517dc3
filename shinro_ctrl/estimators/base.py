"""The :class:`Estimator` interface: what the closed loop asks for the state.

The loop never hands the plant's true state to a controller. At every step it
passes the measurement ``y`` (the measured outputs, with sensor noise) and the
input ``u`` applied over the previous step to :meth:`Estimator.update`, and
feeds the controller the returned estimate ``x_hat``. :class:`FullState` is
the identity (every state measured, no filtering): the default, so a scenario
without an ``[estimator]`` table behaves as full-state feedback.

A subclass writes :meth:`reset` and :meth:`update`; its ``measured`` indices
tell the loop which states make up ``y`` (``y = C x`` with ``C`` the rows of
the identity at ``measured``).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import TYPE_CHECKING, Any

import numpy as np

from shinro_ctrl.concurrency import CallGuard
from shinro_ctrl.controllers.base import checks_plant
from shinro_ctrl.registry import Registry
from shinro_ctrl.types import Vector, Weight

if TYPE_CHECKING:
    from shinro_ctrl.plants.base import Plant

__all__ = ["ESTIMATOR_REGISTRY", "Estimator"]

#: Every concrete :class:`Estimator` subclass defined so far, by class name (``Estimator.__init_subclass__``).
ESTIMATOR_REGISTRY: Registry[Estimator] = Registry("estimator", "shinro_ctrl.estimators")


class Estimator(ABC):
    """A state estimator ``x_hat = update(y, u)``.

    Attributes:
        n: Number of states.
        measured: Indices ``(p,)`` of the measured states, in the order of ``y``.
        stateful: True when the estimate depends on past calls (filters);
            the loop calls :meth:`reset` before every run regardless.

    Threads: a filter's estimate depends on the order of its calls, and its
    update works in buffers it owns, so :meth:`update` and :meth:`reset` of
    one object must come from one thread at a time: a call that enters while
    another thread is inside raises :class:`~shinro_ctrl.errors.ConcurrentUse`.
    Separate objects (one per thread) run in parallel safely.
    """

    n: int
    measured: tuple[int, ...]
    stateful: bool = True

    @property
    def _busy(self) -> CallGuard:
        """The guard of :meth:`update` and :meth:`reset` (see the class docstring: threads)."""
        try:
            return self.__dict__["_guard"]
        except KeyError:  # the first call: created once, atomically (dict.setdefault holds the GIL)
            return self.__dict__.setdefault("_guard", CallGuard(type(self).__name__))

    def __init_subclass__(cls, **kwargs: object) -> None:
        super().__init_subclass__(**kwargs)
        if isinstance(cls.__dict__.get("from_plant"), classmethod):  # None or a plant class: a clear TypeError
            cls.from_plant = classmethod(checks_plant(cls.__dict__["from_plant"].__func__))
        ESTIMATOR_REGISTRY.register(cls)  # skips abstract and private classes

    @classmethod
    def from_plant(cls, plant: Plant, **options: Any) -> Estimator:
        """Build the estimator for ``plant``; the keywords are the ``[estimator]`` table's keys."""
        raise NotImplementedError(f"{cls.__name__} has no from_plant factory")

    @abstractmethod
    def reset(self, x0_hat: Vector, P0: Weight | None = None) -> None:
        """Start from the estimate ``x0_hat (n,)`` (and covariance ``P0 (n, n)`` where the filter has one)."""

    @abstractmethod
    def update(self, y: Vector, u: Vector) -> np.ndarray:
        """Take the measurement ``y (p,)`` and the input ``u (m,)`` held over the last step; return ``x_hat (n,)``.

        ``u`` is the input applied between the previous measurement and this
        one (zero-order hold); on the first call after :meth:`reset` it is
        the operating-point input, and filters skip their prediction.
        """
