"""The simulation state of a plant apart from its model: :class:`StandaloneEngine` and the :class:`Engine` contract.

A :class:`~shinro_ctrl.plants.base.Plant` is the *model* (its equations, its
parameters, its step ``integrate``); the *simulation state* lives in an engine
the plant holds (pinocchio's Model/Data, dm_control's Physics). Two engines
keep the same contract, :class:`Engine`:

* :class:`StandaloneEngine` (here): the state ``x (n,)`` stepped by the plant's
  own ``integrate`` (semi-implicit Euler by default), plus world-frame body forces
  through the plant's ``body_force_map``;
* :class:`~shinro_ctrl.engine.MujocoEngine`: MuJoCo's ``MjData``, read and written
  through the plant's ``engine_read`` / ``engine_write`` / ``engine_apply`` hooks.

``Plant.step(u)`` is then the same three calls for both (``apply``, ``step``,
``read``), and a simulation loop applies a disturbance force through the plant's
engine (``plant.simulation.set_body_force``), never by writing ``plant.state``.

This module lives with the plants, not in :mod:`shinro_ctrl.engine`: every plant
builds one, and the plants never import the engine package (which imports
``mujoco``); :mod:`shinro_ctrl.engine` re-exports it.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Protocol, runtime_checkable

import numpy as np

from shinro_ctrl.errors import InvalidArgument, SimulationDiverged

if TYPE_CHECKING:
    from shinro_ctrl.plants.base import Plant

__all__ = ["Engine", "StandaloneEngine"]


def _base_check() -> object:
    """``Plant.check_model_domain`` (the no-op default), imported late: base.py imports this module."""
    from shinro_ctrl.plants.base import Plant

    return Plant.check_model_domain


@runtime_checkable
class Engine(Protocol):
    """What a plant needs from the engine that holds its simulation state.

    ``apply(plant, u)`` sets the input held over the next step, ``step()``
    advances ``dt``, ``read(plant)`` returns the plant's state ``(n,)`` and
    ``write(plant, x)`` sets it; ``advance(plant, u)`` is the three in one call
    (the hot path of ``Plant.step``). ``set_body_force(body, F)`` /
    ``clear_body_forces()`` apply a world-frame force [N] at a body's centre of
    mass during the following steps.
    """

    def apply(self, plant: Plant, u: np.ndarray) -> None: ...

    def step(self) -> None: ...

    def read(self, plant: Plant) -> np.ndarray: ...

    def write(self, plant: Plant, x: np.ndarray) -> None: ...

    def advance(self, plant: Plant, u: np.ndarray) -> np.ndarray:
        """``apply``, ``step`` and ``read`` in one call."""
        ...

    def set_body_force(self, body: str, force: np.ndarray) -> None: ...

    def clear_body_forces(self) -> None: ...


class StandaloneEngine:
    """A plant's state stepped by the plant's own ``integrate`` (no physics engine).

    Args:
        plant: The model this engine steps (``integrate``, ``state_dim``,
            ``input_dim``, ``body_force_map``, ``dt``).

    Attributes:
        plant: The model.

    The step is ``x⁺ = integrate(x, u) + dt Σ G_b F_b`` for the body forces
    ``F_b`` set with :meth:`set_body_force` (``G_b = plant.body_force_map(b)``).
    A step whose state is not finite raises
    :class:`~shinro_ctrl.errors.SimulationDiverged` and keeps the last state.
    Not thread-safe: one engine per plant, one plant per thread (the plant's
    :meth:`~shinro_ctrl.plants.base.Plant.step` guards it).
    """

    def __init__(self, plant: Plant):
        self.plant = plant
        self._x = np.zeros(plant.state_dim)
        self._u = np.zeros(plant.input_dim)
        self._forces: dict[str, np.ndarray] = {}
        self._force_rate: np.ndarray | None = None  # Σ G_b F_b (n,)
        # the plant's domain check, when it has one (a no-op call costs ~2 % of a step)
        check = plant.check_model_domain
        self._domain = check if getattr(check, "__func__", None) is not _base_check() else None

    @property
    def dt(self) -> float:
        """The plant's step [s]."""
        return self.plant.dt

    def apply(self, plant: Plant, u: np.ndarray) -> None:
        """Hold the (validated) input ``u (m,)`` over the next :meth:`step`."""
        self._u = u

    def step(self) -> None:
        """Advance one ``dt`` with the held input (and body forces).

        Raises:
            NonFiniteError: the state is where the plant's model is undefined (``check_model_domain``).
            SimulationDiverged: the new state is not finite (overflow or NaN).
        """
        self.advance(self.plant, self._u)

    def read(self, plant: Plant) -> np.ndarray:
        """The current state ``(n,)`` (the engine's own array: copy it before changing it)."""
        return self._x

    def advance(self, plant: Plant, u: np.ndarray) -> np.ndarray:
        """``apply(plant, u)``, ``step()``, then ``read(plant)``: one step of the plant (``Plant.step``'s path).

        Raises:
            NonFiniteError: the state is where the plant's model is undefined (``check_model_domain``).
            SimulationDiverged: the new state is not finite (overflow or NaN).
        """
        self._u = u
        x = self._x
        if self._domain is not None:
            self._domain(x)
        try:
            new = self.plant.integrate(x, u)
        except (OverflowError, ZeroDivisionError):  # Python-float arithmetic of a diverging state
            new = np.full(x.shape[0], np.nan)
        if self._force_rate is not None:
            new = new + self.plant.dt * self._force_rate
        if not math.isfinite(sum(new.tolist())) and not np.all(np.isfinite(new)):
            raise SimulationDiverged(
                f"{type(self.plant).__name__} state became non-finite after a step from "
                f"{np.array2string(x, precision=4)} with u = {np.array2string(np.asarray(u), precision=4)}"
            )
        self._x = new
        return new

    def write(self, plant: Plant, x: np.ndarray) -> None:
        """Set the state ``(n,)`` (a copy is kept)."""
        self._x = np.array(x, dtype=float)

    def set_body_force(self, body: str, force: np.ndarray) -> None:
        """Apply a world-frame force ``F (3,)`` [N] at ``body``'s centre of mass in the following steps.

        Raises:
            InvalidArgument: the plant takes no force on ``body`` (see ``Plant.body_force_map``),
                or ``F`` is not three finite numbers.
        """
        F = np.asarray(force, dtype=float)
        if F.shape != (3,) or not np.all(np.isfinite(F)):
            raise InvalidArgument(f"body force on '{body}': expected 3 finite numbers, got {force!r}")
        self._forces[body] = self.plant.body_force_map(body) @ F
        self._force_rate = sum(self._forces.values())

    def clear_body_forces(self) -> None:
        """Remove every body force."""
        self._forces.clear()
        self._force_rate = None

    def __repr__(self) -> str:
        return f"StandaloneEngine({type(self.plant).__name__}, dt={self.plant.dt:g})"
