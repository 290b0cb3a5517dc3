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
  ``[controller]`` table may hold. Every subclass's ``from_plant`` first
  refuses anything but a plant instance (None, a plant class) with a clear
  ``TypeError`` (:func:`check_plant`, applied when the class is defined); a
  controller that does not carry the affine term ``f(x0, u0)`` of its
  linearization calls :func:`check_operating_point`.
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
import functools
import inspect
from collections.abc import Callable
from typing import TYPE_CHECKING, Any, ClassVar, TypeVar

import numpy as np

from shinro_ctrl.concurrency import CallGuard
from shinro_ctrl.errors import InvalidArgument
from shinro_ctrl.registry import Registry
from shinro_ctrl.types import Matrix, Vector

if TYPE_CHECKING:
    from shinro_ctrl.plants.base import Plant

__all__ = [
    "CONTROLLER_REGISTRY",
    "CallGuard",
    "Controller",
    "check_operating_point",
    "check_plant",
    "checks_plant",
    "default_input_bounds",
]


T = TypeVar("T")

#: Every concrete :class:`Controller` subclass defined so far, by class name (``Controller.__init_subclass__``).
CONTROLLER_REGISTRY: Registry[Controller] = Registry("controller", "shinro_ctrl.controllers")


def checks_plant(func: Callable[..., T]) -> Callable[..., T]:
    """``from_plant`` preceded by :func:`check_plant` (every controller's, applied by ``__init_subclass__``)."""
    if getattr(func, "plant_checked", False):
        return func

    @functools.wraps(func)
    def from_plant(cls: type, *args: Any, **kwargs: Any) -> T:
        if args or "plant" in kwargs:
            check_plant(args[0] if args else kwargs["plant"], f"{cls.__name__}.from_plant")
        return func(cls, *args, **kwargs)

    from_plant.plant_checked = True  # type: ignore[attr-defined]
    return from_plant


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

    def __setattr__(self, name: str, value: object) -> None:
        """A public array attribute (a gain, a model matrix, a bound) is stored as a read-only copy.

        The caller can read ``ctrl.K`` but not change the controller through it (``ctrl.K[0, 0] = 5``
        raises ``ValueError: assignment destination is read-only``), nor does the controller keep a
        view of the caller's own array. Rebinding the attribute is still possible; private
        (``_name``) arrays are the controller's working buffers and stay writable.
        """
        if type(value) is np.ndarray and value.flags.writeable and not name.startswith("_"):
            value = value.copy()
            value.flags.writeable = False
        object.__setattr__(self, name, value)

    def __init_subclass__(cls, **kwargs: object) -> None:
        super().__init_subclass__(**kwargs)
        if "stateful" not in cls.__dict__:
            # default: a controller with its own reset() carries memory between calls
            cls.stateful = any("reset" in c.__dict__ for c in cls.__mro__ if c is not Controller and c is not object)
        if isinstance(cls.__dict__.get("from_plant"), classmethod):
            cls.from_plant = classmethod(checks_plant(cls.__dict__["from_plant"].__func__))
        CONTROLLER_REGISTRY.register(cls)  # skips abstract and private classes

    @classmethod
    @abc.abstractmethod
    def from_plant(cls, plant: Plant, *args: Any, **kwargs: Any) -> Controller:
        """Build the controller for ``plant`` (a :class:`~shinro_ctrl.plants.base.Plant`)."""

    @classmethod
    def option_keys(cls) -> tuple[str, ...]:
        """The keys a scenario's ``[controller]`` table may hold: ``from_plant``'s keyword names."""
        import inspect

        params = list(inspect.signature(cls.from_plant).parameters.values())[1:]
        return tuple(p.name for p in params if p.kind not in (p.VAR_POSITIONAL, p.VAR_KEYWORD))

    @classmethod
    def option_annotations(cls) -> dict[str, object]:
        """Key → type annotation of the keys :meth:`option_keys` lists (the scenario layer checks types by them)."""
        import inspect

        params = list(inspect.signature(cls.from_plant).parameters.values())[1:]
        return {
            p.name: p.annotation
            for p in params
            if p.kind not in (p.VAR_POSITIONAL, p.VAR_KEYWORD) and p.annotation is not p.empty
        }

    @abc.abstractmethod
    def __call__(self, x: Vector, ref: Vector | Matrix | None = None) -> np.ndarray:
        """Return the input ``u (m,)`` for the state ``x (n,)``."""

    def reset(self) -> None:  # noqa: B027 - an optional hook: a memoryless controller has nothing to forget
        """Forget any internal memory (warm starts, previous input)."""


def check_plant(plant: object, who: str) -> None:
    """Raise a clear :class:`TypeError` unless ``plant`` is a plant instance (what every ``from_plant`` needs).

    Args:
        plant: The argument given to ``from_plant``.
        who: ``"LQR.from_plant"`` etc., for the message.
    """
    from shinro_ctrl.plants.base import Plant

    if isinstance(plant, Plant):
        return
    if inspect.isclass(plant) and issubclass(plant, Plant):
        raise TypeError(f"{who}() expects a plant instance, got the class {plant.__name__}; pass {plant.__name__}()")
    if plant is None:
        raise TypeError(f"{who}() expects a plant instance (e.g. CartPole()), got None")
    raise TypeError(f"{who}() expects a plant instance (e.g. CartPole()), got {type(plant).__name__}: {plant!r:.60}")


#: Relative size of ``f(x0, u0)`` below which an operating point counts as an equilibrium.
EQUILIBRIUM_TOL = 1e-6


def _names(names: Any, size: int, letter: str) -> list[str]:
    given = list(names) if names is not None else []
    return [str(given[i]) if i < len(given) else f"{letter}[{i}]" for i in range(size)]


def default_input_bounds(plant: Plant, u_min: Any, u_max: Any) -> tuple[Any, Any]:
    """The input bounds a ``from_plant`` designs with: the user's, else the plant's physical range.

    Each side the user leaves None is taken from ``plant.input_bounds()`` (MuJoCo's ``ctrlrange`` for a
    model file, a motor's limit) when that side has a finite entry; it stays None (unbounded) when the
    plant declares none. A side the user gives is kept as given (even wider than the plant's range).

    Args:
        plant: The plant designed on.
        u_min, u_max: The user's bounds ``(m,)`` (a scalar broadcasts) or None.

    Returns:
        ``(u_min, u_max)``: arrays ``(m,)`` with ±inf where unbounded, or None per side.
    """
    return _plant_bounds(getattr(plant, "input_bounds", None), u_min, u_max)


def default_state_bounds(plant: Plant, x_min: Any, x_max: Any) -> tuple[Any, Any]:
    """The state bounds a ``from_plant`` designs with: the user's, else the plant's physical range.

    Like :func:`default_input_bounds` for states: each side the user leaves None is taken from
    ``plant.state_ranges()`` (a model file's joint ranges) when that side has a finite entry.

    Args:
        plant: The plant designed on.
        x_min, x_max: The user's bounds ``(n,)`` (a scalar broadcasts) or None.

    Returns:
        ``(x_min, x_max)``: arrays ``(n,)`` with ±inf where unbounded, or None per side.
    """
    return _plant_bounds(getattr(plant, "state_ranges", None), x_min, x_max)


def _plant_bounds(
    hook: Callable[[], tuple[np.ndarray, np.ndarray]] | None, lo_user: Any, hi_user: Any
) -> tuple[Any, Any]:
    """Each side the user left None from ``hook()`` (the plant's physical range) where it has a finite entry."""
    if (lo_user is not None and hi_user is not None) or not callable(hook):
        return lo_user, hi_user
    lo, hi = hook()
    lo, hi = np.asarray(lo, dtype=float), np.asarray(hi, dtype=float)
    if lo_user is None and np.isfinite(lo).any():
        lo_user = lo
    if hi_user is None and np.isfinite(hi).any():
        hi_user = hi
    return lo_user, hi_user


def check_operating_point(plant: Plant, x0: np.ndarray, u0: np.ndarray, who: str) -> None:
    """Raise :class:`InvalidArgument` unless ``(x0, u0)`` is an equilibrium, ``f(x0, u0) = 0``.

    A controller designed on the linearization ``δẋ = A δx + B δu`` at a point
    where ``f(x0, u0) ≠ 0`` drops the constant term ``f(x0, u0)``: the loop
    is pushed by it without knowing (a cart-pole "held" at a velocity, or with
    a force on the cart, falls). Controllers that carry the affine term
    (:class:`~shinro_ctrl.controllers.mpc.LinearMPC`'s ``offset``) do not need
    this check; the others call it from ``from_plant``.

    The residual counts when ``‖f‖∞ > EQUILIBRIUM_TOL · (1 + ‖A‖∞ ‖x0‖∞ + ‖B‖∞ ‖u0‖∞)``
    (the Jacobians at the point). The message names the residual by state
    and, when one exists, the equilibrium input nearest to ``u0`` (the
    least-squares solution of ``f(x0, u) = 0`` by Gauss–Newton, whose
    residual is within the same tolerance); otherwise it says no input holds
    ``x0`` at rest.

    Args:
        plant: The plant.
        x0: Operating state ``(n,)``.
        u0: Operating input ``(m,)``.
        who: The controller, for the message (``"LQR"``).
    """
    x0 = np.asarray(x0, dtype=float)
    u0 = np.asarray(u0, dtype=float)
    # a floating base: the residual in the tangent space, where the linearization lives
    D = plant.tangent_maps(x0)[0] if plant.tangent_dim != plant.state_dim else None
    with np.errstate(all="ignore"):
        f = np.asarray(plant.dynamics(x0, u0), dtype=float).reshape(-1)
        f = f if D is None else D @ f
        A_c, B_c = plant.linearize(x0, u0)
    norm = lambda v: float(np.max(np.abs(v), initial=0.0))  # noqa: E731
    scale = 1.0 + float(np.abs(A_c).sum(axis=1).max(initial=0.0)) * norm(x0)
    scale += float(np.abs(B_c).sum(axis=1).max(initial=0.0)) * norm(u0)
    tol = EQUILIBRIUM_TOL * scale
    if not np.all(np.isfinite(f)) or norm(f) <= tol:
        return  # a non-finite f is the linearization's error to report
    snames = _names(getattr(plant, "tangent_names", None), f.size, "x")
    residual = ", ".join(f"d{snames[i]}/dt = {f[i]:.4g}" for i in np.flatnonzero(np.abs(f) > tol))
    head = (
        f"{who}: the operating point is not an equilibrium: f(x0, u0) has {residual} "
        f"(x0 = {np.array2string(x0, precision=4)}, u0 = {np.array2string(u0, precision=4)}); the linear design "
        "drops this term, so the loop would drift or fall"
    )
    u, r = u0.copy(), f
    best_u, best_r = u, norm(f)
    for _ in range(20):  # Gauss–Newton on f(x0, u) = 0 from u0: the nearest equilibrium input
        with np.errstate(all="ignore"):
            step = np.linalg.lstsq(B_c, -r, rcond=None)[0]
            u = u + step
            r = np.asarray(plant.dynamics(x0, u), dtype=float).reshape(-1)
            r = r if D is None else D @ r
        if not np.all(np.isfinite(r)):
            break
        if norm(r) < best_r:
            best_u, best_r = u.copy(), norm(r)
        if best_r <= tol or norm(step) <= 1e-12 * (1.0 + norm(u)):
            break
        with np.errstate(all="ignore"):
            B_c = plant.linearize(x0, u)[1]
    if best_r <= tol:
        raise InvalidArgument(
            f"{head}; the nearest equilibrium input is u0 = [{', '.join(f'{v:.10g}' for v in best_u)}] "
            "(pass it as u0, or leave u0 out where the plant's equilibrium() gives it)"
        )
    raise InvalidArgument(
        f"{head}; no input holds x0 at rest (the least-squares input "
        f"{np.array2string(best_u, precision=4)} leaves |f| = {best_r:.3g}): choose an x0 at rest, e.g. with zero "
        "velocities, or a controller that carries the affine term (LinearMPC)"
    )
