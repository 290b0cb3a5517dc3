"""The :class:`Controller` contract: what the closed loop relies on, and the registry.

Every controller the simulation runs is a subclass of :class:`Controller`.
Defining a concrete subclass registers it under its class name in
:data:`CONTROLLER_REGISTRY` (``controller_class(name)`` finds it; a scenario's
``[controller] type = "Name"`` selects it), so a new controller needs no edit
of a hand-kept list: put the module in ``shinro_ctrl/controllers/`` (the
package discovers its modules) or define the class anywhere before use.

The contract:

* ``from_plant(plant, **options)`` (classmethod, abstract): build from a plant;
  its keyword names (or :meth:`Controller.option_keys`) are the keys a
  ``[controller]`` table may hold.
* ``__call__(x, ref=None) -> u`` (abstract): the input ``(m,)`` for the state
  ``(n,)`` the loop feeds it (the estimate ``x̂``); ``ref`` is a state
  ``(n,)`` or, with ``preview = p > 0``, the reference samples ``(p + 1, n)``
  from the current time on.
* ``reset()``: forget internal memory (warm starts, previous input).
* ``preview: int``: future reference samples wanted (0 = only the current one).
* ``stateful: bool``: True when a call depends on earlier calls (then the
  loop resets it before each run and a sweep builds a fresh one per worker);
  by default True exactly when the class overrides ``reset``.
* ``u_min`` / ``u_max`` ``(m,)``: input bounds (±inf where unbounded), None
  when the controller has none; ``x_min`` / ``x_max`` ``(n,)`` likewise for
  state bounds it enforces.
* ``x0`` ``(n,)`` / ``u0`` ``(m,)``: the operating point of the design, None
  when there is none (the loop then starts references at the plant's state).
* ``model``: the :class:`~shinro_ctrl.linearization.LinearModel` designed on,
  or None.
"""

from __future__ import annotations

import abc
from typing import Any, ClassVar

import numpy as np

from shinro_ctrl.registry import Registry

__all__ = ["CONTROLLER_REGISTRY", "Controller"]

#: Every concrete :class:`Controller` subclass defined so far, by class name (``Controller.__init_subclass__``).
CONTROLLER_REGISTRY: Registry[Controller] = Registry("controller", "shinro_ctrl.controllers")


class Controller(abc.ABC):
    """A feedback law ``u = controller(x, ref)`` (see the module docstring for the contract).

    Attributes:
        preview: Future reference samples the controller wants (0: none).
        stateful: True when a call depends on earlier calls.
        u_min: Lower input bounds ``(m,)`` or None.
        u_max: Upper input bounds ``(m,)`` or None.
        x_min: Lower state bounds ``(n,)`` or None.
        x_max: Upper state bounds ``(n,)`` or None.
        x0: Operating-point state ``(n,)`` or None.
        u0: Operating-point input ``(m,)`` or None.
        model: The linear model designed on, or None.
    """

    preview: int = 0
    stateful: ClassVar[bool] = False
    u_min: np.ndarray | None = None
    u_max: np.ndarray | None = None
    x_min: np.ndarray | None = None
    x_max: np.ndarray | None = None
    x0: np.ndarray | None = None
    u0: np.ndarray | None = None
    model: Any = None

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        if "stateful" not in cls.__dict__:
            # default: a controller with its own reset() carries memory between calls
            cls.stateful = any("reset" in c.__dict__ for c in cls.__mro__ if c is not Controller and c is not object)
        CONTROLLER_REGISTRY.register(cls)  # skips abstract and private classes

    @classmethod
    @abc.abstractmethod
    def from_plant(cls, plant: Any, *args: Any, **kwargs: Any) -> Controller:
        """Build the controller for ``plant`` (a :class:`~shinro_ctrl.plants.base.Plant`)."""

    @classmethod
    def option_keys(cls) -> tuple[str, ...]:
        """The keys a scenario's ``[controller]`` table may hold: ``from_plant``'s keyword names."""
        import inspect

        params = list(inspect.signature(cls.from_plant).parameters.values())[1:]
        return tuple(p.name for p in params if p.kind not in (p.VAR_POSITIONAL, p.VAR_KEYWORD))

    @classmethod
    def option_annotations(cls) -> dict[str, Any]:
        """Key → type annotation of the keys :meth:`option_keys` lists (the scenario layer checks types by them)."""
        import inspect

        params = list(inspect.signature(cls.from_plant).parameters.values())[1:]
        return {
            p.name: p.annotation
            for p in params
            if p.kind not in (p.VAR_POSITIONAL, p.VAR_KEYWORD) and p.annotation is not p.empty
        }

    @abc.abstractmethod
    def __call__(self, x: Any, ref: Any = None) -> np.ndarray:
        """Return the input ``u (m,)`` for the state ``x (n,)``."""

    def reset(self) -> None:  # noqa: B027 - an optional hook: a memoryless controller has nothing to forget
        """Forget any internal memory (warm starts, previous input)."""
