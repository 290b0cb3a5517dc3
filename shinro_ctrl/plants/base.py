"""The :class:`Plant` base: everything a plant needs except its equations.

A subclass declares its names (``state_names``, ``input_names``,
``param_names``), stores its physical parameters with :meth:`Plant._init`,
and writes its continuous dynamics once in :meth:`Plant.equations` against a
backend ``bk``. This base turns that one definition into

* ``dynamics(x, u)``: numbers, single instance or a batch ``(N, n)``;
* ``symbolic()``: the CasADi ``Function`` ``f(x, u)`` (or ``f(x, u, p)``);
* ``linearize()``: exact Jacobians (CasADi, compiled once) or central FD;
* ``get_model()`` / ``linear_model()``: discrete ``(A, B)`` at ``dt``;
* ``step(u)``: semi-implicit Euler standalone, or one physics-engine step.

Engine mode is duck-typed: a plant never imports the engine. It tells the
engine how to match the MJCF model to its parameters (:meth:`mjcf_patch`) and
how to read and write its state and inputs (:meth:`Plant.engine_read`,
:meth:`Plant.engine_write`, :meth:`Plant.engine_apply`). The class docstring
of :class:`Plant` lists every hook a new plant may implement.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, ClassVar

import casadi as cs
import numpy as np

from shinro_ctrl.backend import CasadiBackend, ListBackend, NumpyBackend, ScalarBackend
from shinro_ctrl.errors import InvalidArgument, NonFiniteError, SimulationDiverged
from shinro_ctrl.linearization import ExactJacobian, LinearModel, discretize, fd_jacobians
from shinro_ctrl.plants._config_mixin import ConfigMixin
from shinro_ctrl.plants._engine_mode import EngineModeMixin
from shinro_ctrl.plants._state_io import StateIOMixin
from shinro_ctrl.registry import Registry
from shinro_ctrl.validation import all_finite, as_vector, check_positive, did_you_mean, unknown_keys

__all__ = ["PLANT_REGISTRY", "MjcfPatch", "Plant"]

#: Every :class:`Plant` subclass defined so far, by class name and ``aliases`` (``Plant.__init_subclass__``).
PLANT_REGISTRY: Registry[Plant] = Registry("plant", "shinro_ctrl.plants")

#: Public hook -> underscore alias (see the :class:`Plant` docstring).
_HOOK_ALIASES = (
    ("equations", "_f"),
    ("integrate", "_integrate"),
    ("clip_state", "_clip_state"),
    ("engine_read", "_engine_read"),
    ("engine_write", "_engine_write"),
    ("engine_apply", "_engine_apply"),
)

_NUMPY = NumpyBackend()
_SCALAR = ScalarBackend()
_CASADI = CasadiBackend()
_LIST = ListBackend()


@dataclass(frozen=True)
class MjcfPatch:
    """Edits that make a plant's MJCF asset match the plant's parameters.

    The engine applies them through ``MjSpec`` before compiling, so the
    analytic and the simulated model describe the same physics for any
    parameter values, not only the defaults.

    Attributes:
        asset: File name of the MJCF asset (see ``resources.asset_path``).
        timestep: Plant step ``dt`` [s]; the engine divides it by its substeps.
        gravity: World gravity vector [m/s²], shape ``(3,)``.
        inertials: Body name → ``(mass [kg], ipos (3,) [m])``: a point mass at
            ``ipos`` in the body frame (the engine adds a tiny inertia).
        body_pos: Body name → position ``(3,)`` in its parent's frame [m].
        body_inertia: Body name → diagonal inertia ``(3,)`` [kg m²] (for rigid
            bodies that are not point masses, such as the quadrotor).
        joint_damping: Joint name → damping [N m s/rad or N s/m].
        geom_fromto: Visual geom name → ``fromto`` ``(6,)`` [m].
        geom_size: Visual geom name → ``size`` (1 to 3 values) [m].
    """

    asset: str
    timestep: float
    gravity: tuple[float, float, float] = (0.0, 0.0, -9.81)
    inertials: dict[str, tuple[float, tuple[float, float, float]]] = field(default_factory=dict)
    body_pos: dict[str, tuple[float, float, float]] = field(default_factory=dict)
    body_inertia: dict[str, tuple[float, float, float]] = field(default_factory=dict)
    joint_damping: dict[str, float] = field(default_factory=dict)
    geom_fromto: dict[str, tuple[float, ...]] = field(default_factory=dict)
    geom_size: dict[str, tuple[float, ...]] = field(default_factory=dict)


class Plant(EngineModeMixin, StateIOMixin, ConfigMixin):
    """Base class of every plant model.

    Subclasses set the class attributes below, call :meth:`_init` from their
    constructor and implement :meth:`equations`. Mechanical plants whose
    position derivatives equal their velocities list the two index groups in
    ``position_indices`` / ``velocity_indices`` and inherit semi-implicit
    Euler; others override :meth:`integrate`. Defining a subclass registers it
    (class name and ``aliases``) for scenarios and the CLI.

    The hooks a plant implements (public, each documented on its method):

    * :meth:`equations` ``(bk, x, u, p) -> xdot`` (required): the continuous
      dynamics, written once against the backend ``bk`` (numbers, batches,
      CasADi symbols all come from it).
    * :meth:`integrate` ``(x, u) -> x_next``: one standalone step (default:
      semi-implicit Euler over ``position_indices``/``velocity_indices``,
      then :meth:`clip_state`).
    * :meth:`clip_state` ``(x) -> x``: documented state clipping (track
      limits, state bounds); must accept one state ``(n,)`` and a batch
      ``(N, n)`` (the batch rollout calls it on batches).
    * :meth:`equilibrium` ``() -> (x0, u0)``: the default operating point.
    * :meth:`mjcf_patch` ``() -> MjcfPatch``: how the MJCF asset is matched to
      the parameters (engine mode).
    * :meth:`engine_read` ``(engine) -> x``, :meth:`engine_write`
      ``(engine, x)``, :meth:`engine_apply` ``(engine, u)``: the state and
      input in engine mode.
    * :meth:`engine_state_map` ``(x0) -> (T, perm)``: the plant state in
      MuJoCo's coordinates (cross-checks of the linearization).
    * ``limit_violation() -> float`` (optional method) and
      ``tracked_states`` (optional attribute): a plant limit metric and the
      states the tracking error uses.

    The underscore names (``_f``, ``_integrate``, ``_clip_state``,
    ``_engine_read``, ``_engine_write``, ``_engine_apply``) are aliases kept
    for plants written against them: a subclass may define either name.

    The engine hooks and attaching an engine live in
    ``plants/_engine_mode.py``, :meth:`state_limits`, :meth:`body_force_map` and
    :meth:`output_matrix` in ``plants/_state_io.py``, :meth:`from_config` in
    ``plants/_config_mixin.py`` (mixins of this class); this list stays the one
    place that names every hook.

    Attributes:
        state_names: Names of the state components, length ``n``.
        input_names: Names of the inputs, length ``m``.
        param_names: Names of the physical parameters (constructor names).
        asset: MJCF asset file of the matched MuJoCo model, or None.
        dt: Step [s].
        state: Current standalone state ``(n,)``.
    """

    state_names: ClassVar[tuple[str, ...]] = ()
    input_names: ClassVar[tuple[str, ...]] = ()
    param_names: ClassVar[tuple[str, ...]] = ()
    asset: ClassVar[str | None] = None
    position_indices: ClassVar[tuple[int, ...]] = ()
    velocity_indices: ClassVar[tuple[int, ...]] = ()
    #: Short names a scenario or the CLI may use instead of the class name (``("cartpole",)``).
    aliases: ClassVar[tuple[str, ...]] = ()

    def __init_subclass__(cls, **kwargs: Any) -> None:
        """Register every subclass under its class name (and its ``aliases``) in :data:`PLANT_REGISTRY`.

        Also binds each public hook and its underscore alias to the same function (whichever
        name the subclass defined), so either may be called at no extra cost.
        """
        super().__init_subclass__(**kwargs)
        for public, private in _HOOK_ALIASES:
            for klass in cls.__mro__:  # the definition nearest to cls, under either name
                own = klass.__dict__
                if public in own or private in own:
                    fn = own[public] if public in own else own[private]
                    break
            setattr(cls, public, fn)
            setattr(cls, private, fn)
        PLANT_REGISTRY.register(cls, aliases=cls.__dict__.get("aliases", ()))

    # ------------------------------------------------------------------ set-up
    def _init(self, *, dt: float, params: Mapping[str, float], backend: Any = None) -> None:
        """Store validated parameters and allocate per-instance caches."""
        self.dt = check_positive("dt", dt)
        missing = [k for k in self.param_names if k not in params]
        if missing:  # a bug in a subclass, not a user error
            raise TypeError(f"{type(self).__name__} did not store parameters {missing}")
        self._params: dict[str, float] = {k: float(params[k]) for k in self.param_names}
        self._pvec = np.array([self._params[k] for k in self.param_names], dtype=float)
        self.bk = backend if backend is not None else _NUMPY
        self.state = np.zeros(self.state_dim)
        self._engine: Any = None
        self._symbolic: dict[bool, cs.Function] = {}
        self._exact: ExactJacobian | None = None

    @property
    def state_dim(self) -> int:
        """Number of states ``n``."""
        return len(self.state_names)

    @property
    def input_dim(self) -> int:
        """Number of inputs ``m``."""
        return len(self.input_names)

    def params(self) -> dict[str, float]:
        """The physical parameters by constructor name (a copy)."""
        return dict(self._params)

    def equilibrium(self) -> tuple[np.ndarray, np.ndarray]:
        """The documented default operating point ``(x0 (n,), u0 (m,))``."""
        return np.zeros(self.state_dim), np.zeros(self.input_dim)

    # -------------------------------------------------------------- dynamics
    def equations(self, bk: Any, x: Any, u: Any, p: Mapping[str, Any]) -> Any:
        """Hook: the continuous dynamics ``xdot = f(x, u; p)``, written once against ``bk``.

        Args:
            bk: The backend (``bk.sin``, ``bk.stack``, ``bk.unpack`` ...): numbers, batches
                ``(N, n)`` or CasADi symbols, whichever the caller needs.
            x: State (``n`` components through ``bk.unpack``).
            u: Input (``m`` components).
            p: Parameter name -> value (numbers, ``(N,)`` arrays or symbols).

        Returns:
            ``xdot`` as ``bk.stack`` of ``n`` components.
        """
        raise NotImplementedError(f"{type(self).__name__} does not define its equations")

    _f = equations

    def dynamics(self, x: Any, u: Any, params: Mapping[str, Any] | None = None) -> np.ndarray:
        """Evaluate the continuous dynamics numerically.

        Args:
            x: State ``(n,)`` or a batch ``(N, n)``.
            u: Input ``(m,)`` or ``(N, m)``; a scalar or ``(N,)`` when ``m == 1``.
            params: Optional per-instance overrides, name → scalar or ``(N,)``.

        Returns:
            ``xdot`` with the broadcast shape of ``x``: ``(n,)`` or ``(N, n)``.
        """
        n, m = self.state_dim, self.input_dim
        x = np.asarray(x, dtype=float)
        u = np.asarray(u, dtype=float)
        if m == 1 and (u.ndim == 0 or (u.ndim == 1 and x.ndim == 2 and u.shape[0] != 1)):
            u = u[..., None]
        if x.shape[-1:] != (n,) or u.shape[-1:] != (m,):
            raise InvalidArgument(
                f"{type(self).__name__}.dynamics: expected x (..., {n}) and u (..., {m}) "
                f"but found {x.shape} and {u.shape}"
            )
        if x.ndim == 1 and u.ndim == 1 and not params:
            try:
                xdot = self.equations(_SCALAR, x, u, self._params)
            except OverflowError:
                xdot = None
            if xdot is None or not np.all(np.isfinite(xdot)):
                if np.all(np.isfinite(x)) and np.all(np.isfinite(u)):
                    raise NonFiniteError(
                        f"{type(self).__name__}.dynamics overflows float64 at x = {x.tolist()}, u = {u.tolist()}"
                    )
            return xdot
        try:
            np.broadcast_shapes(x.shape[:-1], u.shape[:-1])
        except ValueError:
            raise InvalidArgument(
                f"{type(self).__name__}.dynamics: batch shapes of x {x.shape} and u {u.shape} do not match"
            ) from None
        p: dict[str, Any] = dict(self._params)
        if params:
            bad = unknown_keys(params, self.param_names)
            if bad:
                raise InvalidArgument(f"unknown parameter {bad[0]!r}{did_you_mean(bad[0], self.param_names)}")
            p.update({k: np.asarray(v, dtype=float) for k, v in params.items()})
        return self.equations(_NUMPY, x, u, p)

    def symbolic(self, params: bool = False) -> cs.Function:
        """The dynamics as a CasADi ``Function`` named ``"f"``.

        Args:
            params: If True the physical parameters are a third input ``p``
                (ordered as ``param_names``); otherwise they are constants.

        Returns:
            ``f(x, u) -> xdot`` or ``f(x, u, p) -> xdot`` on ``SX``.
        """
        if params not in self._symbolic:
            x = cs.SX.sym("x", self.state_dim)
            u = cs.SX.sym("u", self.input_dim)
            if params:
                p = cs.SX.sym("p", len(self.param_names))
                pmap = {k: p[i] for i, k in enumerate(self.param_names)}
                self._symbolic[True] = cs.Function(
                    "f", [x, u, p], [self.equations(_CASADI, x, u, pmap)], ["x", "u", "p"], ["xdot"]
                )
            else:
                self._symbolic[False] = cs.Function(
                    "f", [x, u], [self.equations(_CASADI, x, u, self._params)], ["x", "u"], ["xdot"]
                )
        return self._symbolic[params]

    def _operating_point(self, x0: Any, u0: Any) -> tuple[np.ndarray, np.ndarray]:
        if x0 is None or u0 is None:
            xe, ue = self.equilibrium()
            x0 = xe if x0 is None else x0
            u0 = ue if u0 is None else u0
        return as_vector("x0", x0, self.state_dim), as_vector("u0", u0, self.input_dim)

    def linearize(
        self, x0: Any = None, u0: Any = None, *, method: str = "exact", eps: float = 1e-6
    ) -> tuple[np.ndarray, np.ndarray]:
        """Continuous-time Jacobians ``(A_c (n, n), B_c (n, m))`` at ``(x0, u0)``.

        Args:
            x0: Operating state ``(n,)``; default :meth:`equilibrium`.
            u0: Operating input ``(m,)``; default :meth:`equilibrium`.
            method: ``"exact"`` (CasADi, compiled once per plant) or ``"fd"``
                (central finite differences of :meth:`dynamics`).
            eps: Finite-difference step (``"fd"`` only).
        """
        x0, u0 = self._operating_point(x0, u0)
        if method == "exact":
            if self._exact is None:
                self._exact = ExactJacobian(self.symbolic(params=True), self._pvec)
            A, B = self._exact(x0, u0)
        elif method == "fd":
            eps = check_positive("eps", eps)
            z = np.concatenate([x0, u0])
            if np.any(z + eps == z) or np.any(z - eps == z):
                k = int(np.argmax(np.abs(z)))
                raise InvalidArgument(
                    f"{type(self).__name__}.linearize (fd): eps = {eps:g} is below float64's resolution at "
                    f"|{(*self.state_names, *self.input_names)[k]}| = {abs(z[k]):g} (spacing "
                    f"{np.spacing(abs(z[k])):g}); the finite differences would be zero: use a larger eps"
                )
            with np.errstate(all="ignore"):
                A, B = fd_jacobians(lambda X, U: self.equations(_NUMPY, X, U, self._params), x0, u0, eps)
        else:
            raise InvalidArgument(f"unknown linearization method {method!r}; valid: exact, fd")
        if not all_finite(A, B):
            where = f"at x0 = {x0.tolist()}, u0 = {u0.tolist()}" + (f" with eps = {eps:g}" if method == "fd" else "")
            self._check_finite_model(A, B, f"{type(self).__name__}.linearize ({method}) {where}")
        return A, B

    def _check_finite_model(self, A: np.ndarray, B: np.ndarray, what: str) -> None:
        """Raise :class:`NonFiniteError` naming the first non-finite entry of ``A`` / ``B``."""
        if all_finite(A, B):
            return
        for name, M, cols in (("A", A, self.state_names), ("B", B, self.input_names)):
            bad = np.argwhere(~np.isfinite(M))
            if bad.size:
                i, j = bad[0]
                raise NonFiniteError(
                    f"{what}: {name}[{self.state_names[i]}, {cols[j]}] = {M[i, j]} overflows float64 "
                    f"({len(bad)} non-finite entries)"
                )

    def linear_model(
        self,
        x0: Any = None,
        u0: Any = None,
        *,
        method: str = "exact",
        discretization: str = "euler",
        eps: float = 1e-6,
    ) -> LinearModel:
        """The discrete model at ``dt`` with its context (see :class:`LinearModel`)."""
        x0, u0 = self._operating_point(x0, u0)
        A_c, B_c = self.linearize(x0, u0, method=method, eps=eps)
        with np.errstate(all="ignore"):
            A, B = discretize(A_c, B_c, self.dt, discretization)
        if not all_finite(A, B):
            self._check_finite_model(A, B, f"{type(self).__name__} {discretization} model at dt = {self.dt:g} s")
        names = (tuple(self.state_names), tuple(self.input_names))
        return LinearModel(A, B, self.dt, x0, u0, A_c, B_c, method, discretization, *names)

    def statespace(self, x0: Any = None, u0: Any = None, *, discrete: bool = True, measured: Any = None) -> Any:
        """The linear model at ``(x0, u0)`` as a named python-control ``StateSpace`` (Euler at ``dt``).

        Args:
            x0, u0: Operating point (default :meth:`equilibrium`).
            discrete: Discrete at ``dt`` (True) or continuous Jacobians.
            measured: Names of the measured states (the outputs); default all states.
        """
        names = list(self.state_names)
        if measured is None:
            C, outputs = None, None
        else:
            outputs = [str(s) for s in measured]
            bad = [s for s in outputs if s not in names]
            if bad:
                raise InvalidArgument(f"measured: unknown state '{bad[0]}'{did_you_mean(bad[0], names)}")
            C = np.eye(self.state_dim)[[names.index(s) for s in outputs]]
        lm = self.linear_model(x0, u0)
        return lm.to_statespace(
            discrete=discrete, C=C, state_names=names, input_names=self.input_names, output_names=outputs
        )

    def get_model(
        self, x0: Any = None, u0: Any = None, *, method: str = "exact", discretization: str = "euler"
    ) -> tuple[np.ndarray, np.ndarray]:
        """Discrete ``(A (n, n), B (n, m))`` at ``dt`` around ``(x0, u0)``."""
        lm = self.linear_model(x0, u0, method=method, discretization=discretization)
        return lm.A, lm.B

    # ------------------------------------------------------------------ step
    def _input(self, u: Any) -> np.ndarray:
        """``u`` validated as a finite ``(m,)`` array."""
        return as_vector(f"{type(self).__name__} input u", u, self.input_dim)

    def integrate(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        """Hook: one standalone step from ``x (n,)`` under ``u (m,)``.

        Default: semi-implicit Euler, velocities first, then positions with them, then
        :meth:`clip_state`.
        """
        dt = self.dt
        xd = self.equations(_LIST, x, u, self._params)
        new = x.tolist()
        for q, v in zip(self.position_indices, self.velocity_indices, strict=True):
            new[v] += dt * xd[v]
            new[q] += dt * new[v]
        return self.clip_state(np.array(new))

    _integrate = integrate

    def clip_state(self, x: np.ndarray) -> np.ndarray:
        """Hook: documented state clipping (state bounds, track limits); identity by default.

        Args:
            x: One state ``(n,)`` or a batch ``(N, n)`` (may be modified in place).

        Returns:
            The clipped state(s), same shape.
        """
        return x

    _clip_state = clip_state

    def step(self, u: Any) -> np.ndarray:
        """Advance one step of ``dt`` with input ``u`` held.

        Standalone: semi-implicit Euler on :meth:`dynamics`. With an engine
        attached: write the actuators, step the engine, read the state back.

        Args:
            u: Input ``(m,)`` (a scalar when ``m == 1``).

        Returns:
            The new state ``(n,)``.

        Raises:
            ValueError: ``u`` has the wrong shape.
            NonFiniteError: ``u`` holds NaN or inf.
            SimulationDiverged: the state became non-finite.
        """
        u = self._input(u)
        if self._engine is not None:
            self.engine_apply(self._engine, u)
            self._engine.step()
            self.state = self.engine_read(self._engine)
        else:
            try:
                x = self.integrate(self.state, u)
            except (OverflowError, ZeroDivisionError):  # Python-float arithmetic of a diverging state
                x = np.full(self.state_dim, np.nan)
            if not math.isfinite(sum(x.tolist())) and not np.all(np.isfinite(x)):
                raise SimulationDiverged(
                    f"{type(self).__name__} state became non-finite after a step from "
                    f"{np.array2string(self.state, precision=4)} with u = {np.array2string(u, precision=4)}"
                )
            self.state = x
        return self.state.copy()

    def get_state(self) -> np.ndarray:
        """The current state ``(n,)`` (read from the engine when one is attached)."""
        if self._engine is not None:
            self.state = self.engine_read(self._engine)
        return self.state.copy()

    def set_state(self, x: Any) -> None:
        """Set the state ``(n,)`` (and the engine's, when one is attached).

        Raises:
            InvalidArgument: wrong shape, or outside the plant's declared limits
                (see :meth:`state_limits`).
            NonFiniteError: NaN or inf.
        """
        x = as_vector(f"{type(self).__name__} state", x, self.state_dim)
        lo, hi = self.state_limits()
        outside = np.flatnonzero((x < lo) | (x > hi))
        if outside.size:
            i = int(outside[0])
            raise InvalidArgument(
                f"{type(self).__name__} state: {self.state_names[i]} = {x[i]:g} is outside the plant's "
                f"limits [{lo[i]:g}, {hi[i]:g}]"
            )
        self.state = x.copy()
        if self._engine is not None:
            self.engine_write(self._engine, x)

    def __repr__(self) -> str:
        args = ", ".join(f"{k}={v:g}" for k, v in self._params.items())
        return f"{type(self).__name__}({args}, dt={self.dt:g})"
