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

The plant is the *model*; its simulation state lives in the engine it holds
(:attr:`Plant.simulation`): its own :class:`~shinro_ctrl.plants.standalone.StandaloneEngine`,
or an attached MuJoCo engine. Both keep one contract (``apply``, ``step``,
``read``, ``write``), so :meth:`Plant.step` does not branch on the engine.
Engine mode is duck-typed: a plant never imports the engine. It tells the
engine how to match the MJCF model to its parameters (:meth:`mjcf_patch`) and
how to read and write its state and inputs (:meth:`Plant.engine_read`,
:meth:`Plant.engine_write`, :meth:`Plant.engine_apply`). The class docstring
of :class:`Plant` lists every hook a new plant may implement.
"""

from __future__ import annotations

import inspect
import math
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, field, is_dataclass
from typing import TYPE_CHECKING, ClassVar

import casadi as cs
import numpy as np

from shinro_ctrl.backend import ArrayBackend, BackendArray, CasadiBackend, ListBackend, NumpyBackend, ScalarBackend
from shinro_ctrl.concurrency import CallGuard
from shinro_ctrl.errors import ConfigError, InvalidArgument, NonFiniteError
from shinro_ctrl.linearization import MODEL_DISCRETIZATIONS, ExactJacobian, LinearModel, discretize, fd_jacobians
from shinro_ctrl.plants.standalone import Engine, StandaloneEngine
from shinro_ctrl.registry import Registry
from shinro_ctrl.validation import all_finite, as_vector, check_positive, close_match_hint, did_you_mean, unknown_keys

if TYPE_CHECKING:
    from numpy.typing import ArrayLike

__all__ = ["PLANT_REGISTRY", "MjcfPatch", "Plant"]

#: Every :class:`Plant` subclass defined so far, by class name and ``aliases`` (``Plant.__init_subclass__``).
PLANT_REGISTRY: Registry[Plant] = Registry("plant", "shinro_ctrl.plants")

#: Keys a ``[plant]`` mapping may carry at run time besides the constructor's arguments (the seed's
#: ``from_config`` contract: an attached engine and, for the arm, the model's joint groups).
RUNTIME_KEYS = ("engine", "joint_groups")

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
        joint_range: Joint name → ``(min, max)``: the joint becomes limited
            (``limited="true"``) with this range, the stop the standalone
            :meth:`Plant.clip_state` models (e.g. the cart-pole's track).
        model_file: True when ``asset`` is the user's own model file (``MjcfPlant``) rather than a built-in
            plant's matched twin: the MuJoCo loop then keeps the file's own options (integrator, contacts,
            limits, friction loss, clamps) and only ``model="matched"`` idealizes a copy (see
            ``MujocoEngine.for_plant``).
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
    joint_range: dict[str, tuple[float, float]] = field(default_factory=dict)
    model_file: bool = False


class Plant:
    """Base class of every plant model: the model, holding the engine that holds its simulation state.

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
    * :meth:`clip_state` ``(x) -> x``: documented state limits (track
      limits, state bounds) as inelastic stops (:meth:`stop`); must accept
      one state ``(n,)`` and a batch ``(N, n)`` (the batch rollout calls it on batches).
    * :meth:`equilibrium` ``() -> (x0, u0)``: the default operating point.
    * :meth:`state_limits` ``() -> (lo, hi)``: the declared limits of the state.
    * :meth:`input_bounds` ``() -> (u_min, u_max)``: the inputs' physical range (±inf: none).
    * :meth:`body_force_map` ``(body) -> G (n, 3)``: world body forces in the standalone loop.
    * :meth:`mjcf_patch` ``() -> MjcfPatch``: how the MJCF asset is matched to
      the parameters (engine mode).
    * :meth:`engine_read` ``(engine) -> x``, :meth:`engine_write`
      ``(engine, x)``, :meth:`engine_apply` ``(engine, u)``: the state and
      input in engine mode.
    * :meth:`engine_state_map` ``(x0) -> (T, perm)``: the plant state in
      MuJoCo's coordinates (cross-checks of the linearization).
    * ``tracked_states`` (optional attribute): the states the tracking error uses.

    Threads: the model methods (:meth:`dynamics`, :meth:`linearize`,
    :meth:`get_model`, :meth:`symbolic`) may be called from any number of
    threads at once. :meth:`step` changes the simulation state: a call that
    enters while another thread is inside :meth:`step` of the same plant raises
    :class:`~shinro_ctrl.errors.ConcurrentUse` (use one plant per thread).

    Attributes:
        state_names: Names of the state components, length ``n``.
        input_names: Names of the inputs, length ``m``.
        param_names: Names of the physical parameters (constructor names).
        asset: MJCF asset file of the matched MuJoCo model, or None.
        dt: Step [s].
        state: Current state ``(n,)`` (the last one read from the engine).
    """

    state_names: ClassVar[tuple[str, ...]] = ()
    input_names: ClassVar[tuple[str, ...]] = ()
    param_names: ClassVar[tuple[str, ...]] = ()
    asset: ClassVar[str | None] = None
    position_indices: ClassVar[tuple[int, ...]] = ()
    velocity_indices: ClassVar[tuple[int, ...]] = ()
    #: Short names a scenario or the CLI may use instead of the class name (``("cartpole",)``).
    aliases: ClassVar[tuple[str, ...]] = ()
    #: True for a plant that takes an IK solver at construction (``ik=``; the arm).
    takes_ik: ClassVar[bool] = False
    #: Declared state bounds ``(lo (n,), hi (n,))`` (±inf: none) of plants that take ``state_bounds``; the
    #: default :meth:`clip_state` stops the state there and :meth:`state_limits` reports them.
    state_bounds: tuple[np.ndarray, np.ndarray] | None = None

    def __init_subclass__(cls, **kwargs: object) -> None:
        """Register every subclass under its class name (and its ``aliases``) in :data:`PLANT_REGISTRY`."""
        super().__init_subclass__(**kwargs)
        PLANT_REGISTRY.register(cls, aliases=cls.__dict__.get("aliases", ()))

    # ------------------------------------------------------------------ set-up
    def _init(self, *, dt: float, params: Mapping[str, float], backend: ArrayBackend | None = None) -> None:
        """Store validated parameters, allocate per-instance caches and the standalone engine.

        ``backend`` is the seed's keyword, accepted and not used: numbers are numpy arrays.
        """
        self.dt = check_positive("dt", dt)
        missing = [k for k in self.param_names if k not in params]
        if missing:  # a bug in a subclass, not a user error
            raise TypeError(f"{type(self).__name__} did not store parameters {missing}")
        self._params: dict[str, float] = {k: float(params[k]) for k in self.param_names}
        self._pvec = np.array([self._params[k] for k in self.param_names], dtype=float)
        self._symbolic: dict[bool, cs.Function] = {}
        self._exact: ExactJacobian | None = None
        self._exact_step: ExactJacobian | None = None
        self._step_guard = CallGuard(f"{type(self).__name__}.step")  # a subclass's own step holds it too
        self._standalone = StandaloneEngine(self)
        self._engine: Engine | None = None  # an attached physics engine
        self._sim: Engine = self._standalone  # the engine that holds the state
        self._x = np.zeros(self.state_dim)
        self._contact = 0.0  # depth of the last standalone step's contact with a stop
        self._limited_joints: list[str] = []  # engine joints with the stops of clip_state

    @property
    def state_dim(self) -> int:
        """Number of states ``n``."""
        return len(self.state_names)

    @property
    def input_dim(self) -> int:
        """Number of inputs ``m``."""
        return len(self.input_names)

    # ------------------------------------------------------ state deviations
    @property
    def tangent_dim(self) -> int:
        """Dimension of a state deviation ``dx`` (:meth:`difference`): ``state_dim`` but on a floating base.

        The linear models (:meth:`linearize`, :meth:`linear_model`) and every gain, covariance and
        QP the controllers and estimators build live in these coordinates.
        """
        return self.state_dim

    @property
    def tangent_names(self) -> tuple[str, ...]:
        """Names of the deviation coordinates ``(tangent_dim,)`` (:attr:`state_names` but on a floating base)."""
        return tuple(self.state_names)

    def difference(self, x: ArrayLike, x_ref: ArrayLike) -> np.ndarray:
        """The deviation ``dx = x ⊖ x_ref`` ``(..., tangent_dim)`` of states ``x (..., n)`` from ``x_ref``.

        Every controller and estimator measures a state's deviation from its reference with this
        hook. Default ``x − x_ref``; a plant whose configuration holds unit quaternions (a floating
        base) returns the tangent-space deviation (see :meth:`MjcfPlant.difference`).
        """
        return np.asarray(x, dtype=float) - np.asarray(x_ref, dtype=float)

    def tangent_maps(self, x: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
        """``(D, E)``: ``∂ difference(·, x)/∂x``, ``∂ retract(x, ·)/∂dx`` at 0 (identities but on a floating base)."""
        n = self.state_dim
        return np.eye(n), np.eye(n)

    def retract(self, x_ref: ArrayLike, dx: ArrayLike) -> np.ndarray:
        """The state ``x_ref ⊕ dx`` ``(..., n)`` reached from ``x_ref`` by the deviation ``dx (..., tangent_dim)``.

        The inverse of :meth:`difference`: ``difference(retract(x_ref, dx), x_ref) = dx``. Default
        ``x_ref + dx``.
        """
        return np.asarray(x_ref, dtype=float) + np.asarray(dx, dtype=float)

    def params(self) -> dict[str, float]:
        """The physical parameters by constructor name (a copy)."""
        return dict(self._params)

    def dynamics_params(self) -> dict[str, float]:
        """The parameters of :meth:`equations` by :attr:`param_names` (a copy; ``p`` of ``symbolic(params=True)``)."""
        return dict(self._params)

    def equilibrium(self) -> tuple[np.ndarray, np.ndarray]:
        """The documented default operating point ``(x0 (n,), u0 (m,))``."""
        return np.zeros(self.state_dim), np.zeros(self.input_dim)

    # ------------------------------------------------------------ state
    @property
    def state(self) -> np.ndarray:
        """The current state ``(n,)``: the last one stepped, set or read from the engine."""
        return self._x

    @state.setter
    def state(self, x: ArrayLike) -> None:
        x = np.array(x, dtype=float)
        self._x = x
        self._sim.write(self, x)

    @property
    def simulation(self) -> Engine:
        """The engine holding the simulation state: the attached physics engine, else the :class:`StandaloneEngine`."""
        return self._sim

    @property
    def engine(self) -> Engine | None:
        """The attached physics engine, or None (standalone)."""
        return self._engine

    # -------------------------------------------------------------- dynamics
    def equations(
        self, bk: ArrayBackend, x: BackendArray, u: BackendArray, p: Mapping[str, BackendArray]
    ) -> BackendArray:
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

    def check_model_domain(self, x: np.ndarray) -> None:
        """Hook: raise :class:`~shinro_ctrl.errors.NonFiniteError` when the model is undefined at ``x (n,)``.

        Called by :meth:`dynamics`, :meth:`linearize` and :meth:`step` before evaluating (e.g. the
        quadrotor's Euler-angle singularity). Default: defined everywhere.
        """

    def dynamics(
        self, state: ArrayLike, control: ArrayLike, params: Mapping[str, ArrayLike] | None = None
    ) -> np.ndarray:
        """Evaluate the continuous dynamics numerically, ``ẋ = f(x, u)``.

        Args:
            state: State ``x`` ``(n,)`` or a batch ``(N, n)``.
            control: Input ``u`` ``(m,)`` or ``(N, m)``; a scalar or ``(N,)`` when ``m == 1``.
            params: Optional per-instance overrides, name → scalar or ``(N,)``.

        Returns:
            ``xdot`` with the broadcast shape of ``x``: ``(n,)`` or ``(N, n)``.

        Raises:
            InvalidArgument: wrong shapes.
            NonFiniteError: ``x`` or ``u`` holds NaN or inf, or ``ẋ`` overflows float64.
        """
        n, m = self.state_dim, self.input_dim
        x = np.asarray(state, dtype=float)
        u = np.asarray(control, dtype=float)
        if m == 1 and (u.ndim == 0 or (u.ndim == 1 and x.ndim == 2 and u.shape[0] != 1)):
            u = u[..., None]
        if x.shape[-1:] != (n,) or u.shape[-1:] != (m,):
            raise InvalidArgument(
                f"{type(self).__name__}.dynamics: expected x (..., {n}) and u (..., {m}) "
                f"but found {x.shape} and {u.shape}"
            )
        if not (np.isfinite(x).all() and np.isfinite(u).all()):
            for what, v, names in (("x", x, self.state_names), ("u", u, self.input_names)):
                if not np.isfinite(v).all():
                    k = int(np.argwhere(~np.isfinite(v))[0][-1])
                    raise NonFiniteError(
                        f"{type(self).__name__}.dynamics: {what} holds NaN or inf (in {names[k]}): "
                        f"{np.array2string(v, precision=4)}"
                    )
        if x.ndim == 1 and u.ndim == 1 and not params:
            self.check_model_domain(x)
            try:
                xdot = self.equations(_SCALAR, x, u, self._params)
            except OverflowError:
                xdot = None
            if xdot is None or not np.all(np.isfinite(xdot)):
                raise NonFiniteError(
                    f"{type(self).__name__}.dynamics overflows float64 at state x = {x.tolist()}, "
                    f"input u = {u.tolist()} (reduce the state or the input)"
                )
            return xdot
        try:
            np.broadcast_shapes(x.shape[:-1], u.shape[:-1])
        except ValueError:
            raise InvalidArgument(
                f"{type(self).__name__}.dynamics: batch shapes of x {x.shape} and u {u.shape} do not match"
            ) from None
        for row in x.reshape(-1, n):
            self.check_model_domain(row)
        p: dict[str, BackendArray] = dict(self._params)
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

    def symbolic_step(self) -> cs.Function:
        """The standalone step ``x⁺ = F(x, u, p)`` as a CasADi ``Function`` named ``"F"`` (without stops).

        Default: semi-implicit Euler over ``position_indices`` / ``velocity_indices``, exactly
        :meth:`integrate` before :meth:`clip_state`. A plant that overrides :meth:`integrate`
        overrides this too (the tests compare the two at random points).
        """
        x = cs.SX.sym("x", self.state_dim)
        u = cs.SX.sym("u", self.input_dim)
        p = cs.SX.sym("p", len(self.param_names))
        pmap = {k: p[i] for i, k in enumerate(self.param_names)}
        xd = self.equations(_CASADI, x, u, pmap)
        new = [x[i] for i in range(self.state_dim)]
        if not self.position_indices:
            new = [x[i] + self.dt * xd[i] for i in range(self.state_dim)]  # no mechanical split: explicit Euler
        for q, v in zip(self.position_indices, self.velocity_indices, strict=True):
            new[v] = x[v] + self.dt * xd[v]
            new[q] = x[q] + self.dt * new[v]
        return cs.Function("F", [x, u, p], [cs.vertcat(*new)], ["x", "u", "p"], ["x_next"])

    def operating_point(self, x0: ArrayLike | None, u0: ArrayLike | None) -> tuple[np.ndarray, np.ndarray]:
        """``(x0 (n,), u0 (m,))`` validated; a None side takes :meth:`equilibrium`'s."""
        if x0 is None or u0 is None:
            xe, ue = self.equilibrium()
            x0 = xe if x0 is None else x0
            u0 = ue if u0 is None else u0
        return as_vector("x0", x0, self.state_dim), as_vector("u0", u0, self.input_dim)

    def linearize(
        self, x0: ArrayLike | None = None, u0: ArrayLike | None = None, *, method: str = "exact", eps: float = 1e-6
    ) -> tuple[np.ndarray, np.ndarray]:
        """Continuous-time Jacobians ``(A_c (n, n), B_c (n, m))`` at ``(x0, u0)``.

        Args:
            x0: Operating state ``(n,)``; default :meth:`equilibrium`.
            u0: Operating input ``(m,)``; default :meth:`equilibrium`.
            method: ``"exact"`` (CasADi, compiled once per plant) or ``"fd"``
                (central finite differences of :meth:`dynamics`).
            eps: Finite-difference step (``"fd"`` only).
        """
        x0, u0 = self.operating_point(x0, u0)
        self.check_model_domain(x0)
        if method == "exact":
            if self._exact is None:
                self._exact = ExactJacobian(self.symbolic(params=True), self._pvec)
            A, B = self._exact(x0, u0)
        elif method == "fd":
            eps = check_positive("eps", eps)
            self._check_fd_step(x0, u0, eps)
            with np.errstate(all="ignore"):
                A, B = fd_jacobians(lambda X, U: self.equations(_NUMPY, X, U, self._params), x0, u0, eps)
        else:
            raise InvalidArgument(f"unknown linearization method {method!r}; valid: exact, fd")
        if not all_finite(A, B):
            where = f"at state x0 = {x0.tolist()}, input u0 = {u0.tolist()}" + (
                f" with eps = {eps:g}" if method == "fd" else ""
            )
            self._check_finite_model(A, B, f"{type(self).__name__}.linearize ({method}) {where}")
        return A, B

    def _check_fd_step(self, x0: np.ndarray, u0: np.ndarray, eps: float) -> None:
        z = np.concatenate([x0, u0])
        if np.any(z + eps == z) or np.any(z - eps == z):
            k = int(np.argmax(np.abs(z)))
            raise InvalidArgument(
                f"{type(self).__name__}.linearize (fd): eps = {eps:g} is below float64's resolution at "
                f"|{(*self.state_names, *self.input_names)[k]}| = {abs(z[k]):g} (spacing "
                f"{np.spacing(abs(z[k])):g}); the finite differences would be zero: use a larger eps"
            )

    def step_jacobians(self, x0: ArrayLike | None = None, u0: ArrayLike | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Exact Jacobians ``(A (n, n), B (n, m))`` of the standalone step :meth:`symbolic_step` at ``(x0, u0)``.

        This is the ``discretization="step"`` model: the linearization of the discrete step the
        standalone loop takes (stops not included: away from a limit they do not act).
        """
        x0, u0 = self.operating_point(x0, u0)
        self.check_model_domain(x0)
        if self._exact_step is None:
            self._exact_step = ExactJacobian(self.symbolic_step(), self._pvec)
        A, B = self._exact_step(x0, u0)
        if not all_finite(A, B):
            self._check_finite_model(A, B, f"{type(self).__name__} step model at state x0 = {x0.tolist()}")
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
        x0: ArrayLike | None = None,
        u0: ArrayLike | None = None,
        *,
        method: str = "exact",
        discretization: str = "euler",
        eps: float = 1e-6,
    ) -> LinearModel:
        """The discrete model at ``dt`` with its context (see :class:`LinearModel`).

        ``discretization``: ``"euler"``, ``"zoh"``, ``"rk4"`` of the continuous Jacobians, or
        ``"step"``, the exact Jacobians of the standalone step (:meth:`step_jacobians`; with
        ``method="fd"``, central differences of :meth:`integrate`).
        """
        x0, u0 = self.operating_point(x0, u0)
        A_c, B_c = self.linearize(x0, u0, method=method, eps=eps)
        if discretization not in MODEL_DISCRETIZATIONS:
            raise InvalidArgument(
                f"unknown discretization {discretization!r}; valid: {', '.join(MODEL_DISCRETIZATIONS)}"
            )
        if discretization == "step":
            if method == "exact":
                A, B = self.step_jacobians(x0, u0)
            else:
                A, B = fd_jacobians(self._integrate_batch, x0, u0, eps)
        else:
            with np.errstate(all="ignore"):
                A, B = discretize(A_c, B_c, self.dt, discretization)
        if not all_finite(A, B):
            self._check_finite_model(A, B, f"{type(self).__name__} {discretization} model at dt = {self.dt:g} s")
        names = (tuple(self.state_names), tuple(self.input_names))
        return LinearModel(A, B, self.dt, x0, u0, A_c, B_c, method, discretization, *names)

    def discrete_offset(self, model: LinearModel) -> np.ndarray:
        """The affine term ``c (n,)`` of ``model``: ``x⁺ ≈ x0 + A (x − x0) + B (u − u0) + c``.

        Zero at an equilibrium. For ``discretization="step"`` it is the standalone step's own
        ``F(x0, u0) − x0``; otherwise the drift ``f(x0, u0)`` discretized as ``B`` is.
        """
        if model.discretization == "step":
            F = self.symbolic_step()
            return self.difference(np.asarray(F(model.x0, model.u0, self._pvec), dtype=float).reshape(-1), model.x0)
        drift = np.asarray(self.dynamics(model.x0, model.u0), dtype=float).reshape(-1, 1)
        return discretize(model.A_c, drift, model.dt, model.discretization)[1][:, 0]

    def _integrate_batch(self, X: np.ndarray, U: np.ndarray) -> np.ndarray:
        """:meth:`integrate` row by row on ``(N, n)``, ``(N, m)`` (the finite-difference reference of the step)."""
        X, U = np.broadcast_arrays(np.atleast_2d(X), np.atleast_2d(U)[..., : self.input_dim])
        return np.array([self.integrate(x.copy(), u.copy()) for x, u in zip(X, U, strict=True)])

    def statespace(
        self,
        x0: ArrayLike | None = None,
        u0: ArrayLike | None = None,
        *,
        discrete: bool = True,
        measured: Sequence[str] | None = None,
    ) -> object:
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
        self,
        x0: ArrayLike | None = None,
        u0: ArrayLike | None = None,
        eps: float = 1e-6,
        *,
        method: str = "exact",
        discretization: str = "euler",
    ) -> tuple[np.ndarray, np.ndarray]:
        """Discrete ``(A (n, n), B (n, m))`` at ``dt`` around ``(x0, u0)`` (the seed's signature).

        The seed's default model: the continuous Jacobians at ``(x0, u0)`` (default
        :meth:`equilibrium`), Euler-discretized, ``A = I + dt ∂f/∂x``, ``B = dt ∂f/∂u``.

        Args:
            x0: Operating state ``(n,)``.
            u0: Operating input ``(m,)``.
            eps: Finite-difference step, used with ``method="fd"`` (the seed's central
                differences); the default ``"exact"`` Jacobians need none.
            method: ``"exact"`` or ``"fd"``.
            discretization: ``"euler"`` (default), ``"zoh"``, ``"rk4"`` or ``"step"``.
        """
        lm = self.linear_model(x0, u0, method=method, discretization=discretization, eps=eps)
        return lm.A, lm.B

    # ------------------------------------------------------------------ step
    def _input(self, u: ArrayLike) -> np.ndarray:
        """``u`` validated as a finite ``(m,)`` array."""
        if type(u) is np.ndarray and u.dtype == np.float64 and u.shape == (len(self.input_names),):
            if math.isfinite(sum(u.tolist())):  # the hot path: no message built (a finite sum: all finite)
                return u
        return as_vector(f"{type(self).__name__} input u", u, self.input_dim)

    def integrate(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        """Hook: one standalone step from ``x (n,)`` under ``u (m,)``.

        Default: semi-implicit Euler, velocities first, then positions with them, then
        :meth:`clip_state`.
        """
        dt = self.dt
        xd = self.equations(_LIST, x, u, self._params)
        new = x.tolist()
        if not self.position_indices:  # no mechanical split: explicit Euler
            new = [a + dt * b for a, b in zip(new, xd, strict=True)]
        for q, v in zip(self.position_indices, self.velocity_indices, strict=True):
            new[v] += dt * xd[v]
            new[q] += dt * new[v]
        return self.clip_state(np.array(new))

    def clip_state(self, x: np.ndarray) -> np.ndarray:
        """Hook: the plant's documented state limits as inelastic stops (:meth:`stop`).

        By default :attr:`state_bounds` (identity without them).

        Args:
            x: One state ``(n,)`` or a batch ``(N, n)`` (may be modified in place).

        Returns:
            The clipped state(s), same shape.
        """
        bounds = self.state_bounds
        return x if bounds is None else self.stop(x, *bounds)

    def stop(self, x: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
        """Inelastic stops at ``lo``/``hi`` ``(n,)`` (±inf: none), in place on ``x (n,)`` or ``(N, n)``.

        A position (``position_indices``) outside its range is put on the limit and its velocity
        (the paired ``velocity_indices`` entry) is zeroed if it points further out: the stop
        absorbs the motion into it, as MuJoCo's joint limit does. Any other state outside its
        range is clipped. For one state the depth of the contact (how far the step went past a
        limit, in the state's units; 0 without contact) is kept for :meth:`limit_violation`.
        """
        below, above = x < lo, x > hi
        if not (below.any() or above.any()):
            if x.ndim == 1:
                self._contact = 0.0
            return x
        if x.ndim == 1:
            self._contact = float(np.max(np.where(below, lo - x, 0.0) + np.where(above, x - hi, 0.0)))
        for q, v in zip(self.position_indices, self.velocity_indices, strict=True):
            into = (below[..., q] & (x[..., v] < 0.0)) | (above[..., q] & (x[..., v] > 0.0))
            if x.ndim == 1:
                if into:
                    x[v] = 0.0
            else:
                x[into, v] = 0.0
        np.clip(x, lo, hi, out=x)
        return x

    def limit_violation(self) -> float:
        """Depth of the last step's contact with a state limit (0 when none): counted by ``constraint_violations``.

        Standalone: how far the step went past a stop of :meth:`clip_state` before it was stopped.
        MuJoCo: the penetration of an active joint-limit constraint on a joint of
        ``mjcf_patch().joint_range`` (the same stops), read from the engine.
        """
        if self._engine is None:
            return self._contact
        joints = self._limited_joints
        return self._engine.joint_limit_depth(joints) if joints else 0.0

    def step(self, u: ArrayLike) -> np.ndarray:
        """Advance one step of ``dt`` with input ``u`` held.

        The plant's engine (:attr:`simulation`) takes the input, steps and is read back:
        semi-implicit Euler (:meth:`integrate`) standalone, or one physics-engine step.

        Args:
            u: Input ``(m,)`` (a scalar when ``m == 1``).

        Returns:
            The new state ``(n,)``.

        Raises:
            ValueError: ``u`` has the wrong shape.
            NonFiniteError: ``u`` holds NaN or inf, or the state is where the model is undefined.
            SimulationDiverged: the state became non-finite.
            ConcurrentUse: another thread is stepping this plant.
        """
        u = self._input(u)
        guard = self._step_guard
        if not guard.acquire(False):
            raise guard.refused()
        try:
            self._x = x = self._sim.advance(self, u)  # apply, step, read
        finally:
            guard.release()
        return x.copy()

    def get_state(self) -> np.ndarray:
        """The current state ``(n,)`` (read from the engine when one is attached)."""
        if self._engine is not None:
            self._x = self._sim.read(self)
        return self._x.copy()

    def set_state(self, x: ArrayLike) -> None:
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

    # ------------------------------------------------------- limits and outputs
    def state_limits(self) -> tuple[np.ndarray, np.ndarray]:
        """Declared limits ``(lo (n,), hi (n,))`` of the state (±inf where none): :attr:`state_bounds` by default."""
        if self.state_bounds is not None:
            return self.state_bounds[0].copy(), self.state_bounds[1].copy()
        return np.full(self.state_dim, -np.inf), np.full(self.state_dim, np.inf)

    def input_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Hook: the inputs' physical range ``(u_min (m,), u_max (m,))``, ±inf where none (the default: none).

        What the actuators can deliver (a motor's torque limit, MuJoCo's ``ctrlrange``), not a design
        choice: the controllers' ``from_plant`` take these as their input bounds when the user gives none
        (see :func:`~shinro_ctrl.controllers.base.default_input_bounds`), and the runs count the steps spent
        at them (``saturation_fraction``). With a MuJoCo engine attached, the default is the engine
        model's ``ctrlrange`` mapped onto the inputs (``engine.input_ranges``: a realistic variant's motor
        limits); standalone, none.
        """
        ranges = getattr(self._engine, "input_ranges", None)
        if callable(ranges):
            return ranges(self)
        return np.full(self.input_dim, -np.inf), np.full(self.input_dim, np.inf)

    def state_ranges(self) -> tuple[np.ndarray, np.ndarray]:
        """Hook: the states' physical range ``(x_min (n,), x_max (n,))``, ±inf where none (the default: none).

        The mechanism's own limits (a model file's joint ranges), not a design choice: the controllers
        that take state bounds (``LinearMPC``, ``NonlinearMPC``) use them by default where the user gives
        none (see :func:`~shinro_ctrl.controllers.base.default_state_bounds`). Unlike :attr:`state_bounds`
        (the standalone step's stops, which built-in plants declare for numerical safety), these are
        limits a design must respect.
        """
        return np.full(self.state_dim, -np.inf), np.full(self.state_dim, np.inf)

    def body_force_map(self, body: str) -> np.ndarray:
        """``G (n, 3)``: how a world-frame force ``F`` [N] at ``body``'s centre of mass changes ``ẋ`` (``ẋ += G F``).

        Used by the :class:`StandaloneEngine` for body-force disturbances (MuJoCo
        applies the force itself). Plants that accept such forces override this;
        the base accepts none.

        Raises:
            InvalidArgument: the plant takes no force on ``body``.
        """
        raise InvalidArgument(
            f"{type(self).__name__} takes no body-force disturbance on '{body}'; disturb an input "
            f"({', '.join(self.input_names)}) instead"
        )

    def output_matrix(self, measured: Sequence[str | int] | str | int | None = None) -> np.ndarray:
        """The measurement matrix ``C (p, n)`` of the measured states: ``y = C x``.

        Args:
            measured: State names (or indices) in the order of ``y``; None
                means every state (``C = I``).

        Returns:
            The rows of the identity at the measured states, ``(p, n)``.

        Raises:
            InvalidArgument: an unknown name (listing the valid ones), an index
                out of range, a repeated state, or an empty list.
        """
        names = self.state_names
        if measured is None:
            return np.eye(self.state_dim)
        if isinstance(measured, str) or not hasattr(measured, "__iter__"):
            measured = [measured]
        idx: list[int] = []
        for s in measured:
            if isinstance(s, str):
                if s not in names:
                    raise InvalidArgument(
                        f"measured: unknown state '{s}' of {type(self).__name__}"
                        f"{close_match_hint(s, names)} (valid: {', '.join(names)})"
                    )
                i = names.index(s)
            elif isinstance(s, int | np.integer) and not isinstance(s, bool) and 0 <= s < self.state_dim:
                i = int(s)
            else:
                raise InvalidArgument(f"measured: expected state names ({', '.join(names)}) but found {s!r}")
            if i in idx:
                raise InvalidArgument(f"measured: state '{names[i]}' is listed twice")
            idx.append(i)
        if not idx:
            raise InvalidArgument(f"measured: expected at least one state name ({', '.join(names)}) but found []")
        return np.eye(self.state_dim)[idx]

    # ------------------------------------------------------------ engine mode
    def physics_engine(self, engine: Engine | None) -> None:
        """Attach a physics engine (or detach with None).

        On attach the plant's state is read from the engine and the engine holds the simulation
        state; on detach the plant's standalone engine takes over from the last state.
        """
        if engine is not None and self.asset is None:
            raise InvalidArgument(f"{type(self).__name__} has no MuJoCo model to attach an engine to")
        self._check_engine(engine)
        if engine is None:
            self._engine = None
            self._sim = self._standalone
            self._standalone.write(self, self._x)
            return
        self._engine = engine
        self._sim = engine
        try:
            self._limited_joints = list(self.mjcf_patch().joint_range)
        except (NotImplementedError, InvalidArgument):
            self._limited_joints = []
        self._x = engine.read(self)

    def _check_engine(self, engine: Engine | None) -> None:
        """Raise InvalidArgument unless ``engine`` is None or behaves like a MujocoEngine."""
        needed = (
            "step",
            "forward",
            "get_joint_qpos",
            "get_joint_vel",
            "set_joint_ctrl",
            "read",
            "write",
            "apply",
            "advance",
        )
        if engine is not None and not all(callable(getattr(engine, a, None)) for a in needed):
            raise InvalidArgument(
                f"{type(self).__name__}.physics_engine expects a MujocoEngine (or None), got {type(engine).__name__}"
            )
        if engine is not None and getattr(engine, "model", None) is not None:
            self._check_engine_matches(engine)

    def _check_engine_matches(self, engine: Engine) -> None:
        """Raise InvalidArgument when ``engine`` was built for another plant (type, ``dt`` or a parameter).

        The engine's compiled model is compared with what :meth:`mjcf_patch` would
        write into it (see ``MujocoEngine.for_plant``): step, gravity, body masses
        and positions, joint damping and ranges; a body or joint the patch names but the
        model lacks means another plant type. The first mismatch is named. Masses,
        positions, damping and ranges are compared only for a ``matched`` engine (a
        realistic variant or a model file carries its own).
        """
        try:
            patch = self.mjcf_patch()
        except NotImplementedError:
            return
        m, name = engine.model, type(self).__name__
        rel = 1e-6
        built_for = getattr(engine, "plant_type", None)
        if isinstance(built_for, str) and built_for != name:
            raise InvalidArgument(
                f"{name}.physics_engine: the engine was built for another plant type: {built_for}, not {name}; "
                "build it with MujocoEngine.for_plant(plant)"
            )

        def differs(a: ArrayLike, b: ArrayLike) -> bool:
            a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
            return a.shape != b.shape or bool(np.any(np.abs(a - b) > rel * np.maximum(1.0, np.abs(b))))

        def mismatch(what: str, engine_value: object, plant_value: object) -> InvalidArgument:
            return InvalidArgument(
                f"{name}.physics_engine: the engine was built for another plant: {what} is {engine_value} in the "
                f"engine but {plant_value} in the plant; build it with MujocoEngine.for_plant(plant)"
            )

        engine_dt = float(getattr(engine, "dt", m.opt.timestep))
        if differs(engine_dt, self.dt):
            raise mismatch("dt", f"{engine_dt:g} s", f"{self.dt:g} s")
        if differs(m.opt.gravity, patch.gravity):
            raise mismatch("gravity", list(np.round(m.opt.gravity, 6)), list(patch.gravity))
        for kind, names in (
            ("body", [*patch.inertials, *patch.body_pos, *patch.body_inertia]),
            ("joint", [*patch.joint_damping, *patch.joint_range]),
        ):
            for item in names:
                try:
                    getattr(m, kind)(item)
                except KeyError:
                    raise InvalidArgument(
                        f"{name}.physics_engine: the engine was built for another plant type: its model "
                        f"({engine.source}) has no {kind} '{item}', which {name} needs"
                    ) from None
        if getattr(engine, "variant", "matched") != "matched":
            return  # a realistic variant or the user's own file: its physics are its own, not the parameters'
        for body, (mass, ipos) in patch.inertials.items():
            if differs(m.body(body).mass[0], mass):
                raise mismatch(f"the mass of body '{body}'", f"{m.body(body).mass[0]:g} kg", f"{mass:g} kg")
            if differs(m.body(body).ipos, ipos):
                raise mismatch(f"the centre of mass of body '{body}'", list(m.body(body).ipos), list(ipos))
        for body, pos in patch.body_pos.items():
            if differs(m.body(body).pos, pos):
                raise mismatch(f"the position of body '{body}'", list(m.body(body).pos), list(pos))
        for joint, damping in patch.joint_damping.items():
            dof = int(m.joint(joint).dofadr[0])
            if differs(m.dof_damping[dof], damping):
                raise mismatch(f"the damping of joint '{joint}'", f"{m.dof_damping[dof]:g}", f"{damping:g}")
        for joint, rng in patch.joint_range.items():
            j = m.joint(joint)
            if not bool(m.jnt_limited[j.id]) or differs(j.range, rng):
                have = list(j.range) if bool(m.jnt_limited[j.id]) else "unlimited"
                raise mismatch(f"the range of joint '{joint}'", have, list(rng))

    def mjcf_patch(self) -> MjcfPatch:
        """Hook: how the plant's MJCF asset must be edited to match its parameters."""
        raise NotImplementedError(f"{type(self).__name__} has no matched MuJoCo model")

    def engine_state_map(self, x0: ArrayLike | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Hook: how the plant's state relates to MuJoCo's ``z = [qpos..., qvel...]``.

        Returns:
            ``(T (n, n), perm (n,))`` with ``x_plant = T @ z`` (``z`` in the
            order of ``mjd_transitionFD``); ``perm[i]`` is the index in ``z``
            of the coordinate state ``i`` is built on (same joint, same
            derivative order), so ``T == eye(n)[perm]`` unless the plant uses
            other coordinates. Inputs map 1:1 onto actuators (``ctrl = u``).
        """
        raise NotImplementedError(f"{type(self).__name__} has no MuJoCo state map")

    def engine_read(self, engine: Engine) -> np.ndarray:
        """Hook: the plant state ``x (n,)`` read from the engine's joints (engine mode)."""
        raise NotImplementedError(f"{type(self).__name__} has no engine mode")

    def engine_write(self, engine: Engine, x: np.ndarray) -> None:
        """Hook: write the plant state ``x (n,)`` into the engine's joints (engine mode)."""
        raise NotImplementedError(f"{type(self).__name__} has no engine mode")

    def engine_apply(self, engine: Engine, u: np.ndarray) -> None:
        """Hook: apply the input ``u (m,)`` to the engine's actuators (engine mode)."""
        raise NotImplementedError(f"{type(self).__name__} has no engine mode")

    # ------------------------------------------------------------------ config
    @classmethod
    def config_keys(cls) -> tuple[str, ...]:
        """The keys a ``[plant]`` table may hold: the constructor's arguments (not ``backend`` nor ``ik``)."""
        sig = inspect.signature(cls.__init__)
        return tuple(k for k in sig.parameters if k not in ("self", "backend", "ik"))

    @classmethod
    def from_config(
        cls,
        config: Mapping[str, object] | object,
        backend: ArrayBackend | None = None,
        *,
        engine: Engine | None = None,
        **extra: object,
    ) -> Plant:
        """Build the plant from a mapping or dataclass of constructor arguments (the seed's signature).

        Args:
            config: Constructor keyword arguments (a ``type`` key is ignored). A mapping may
                also carry a runtime-injected ``engine`` (the seed's contract), attached after
                construction.
            backend: The seed's array backend; accepted, numbers are numpy arrays.
            engine: Optional engine to attach.
            extra: Construction-time collaborators a subclass takes (the arm's ``ik``).

        Raises:
            ConfigError: an unknown key (with the closest valid one) or an
                invalid value (naming the key).
        """
        kwargs, runtime = split_config(config)
        engine = runtime.get("engine", engine)
        allowed = cls.config_keys()
        bad = unknown_keys(kwargs, allowed)
        if bad:
            raise ConfigError(f"[plant] {cls.__name__}: unknown key '{bad[0]}'{did_you_mean(bad[0], allowed)}")
        try:
            plant = cls(**kwargs, **extra)
        except (TypeError, ValueError, FileNotFoundError) as exc:  # a missing model file is a bad [plant] value
            raise ConfigError(f"[plant] {cls.__name__}: {exc}") from exc
        if engine is not None:
            plant.physics_engine(engine)
        return plant

    def __repr__(self) -> str:
        args = ", ".join(f"{k}={v:g}" for k, v in self._params.items())
        return f"{type(self).__name__}({args}, dt={self.dt:g})"


def split_config(config: Mapping[str, object] | object) -> tuple[dict[str, object], dict[str, object]]:
    """``(constructor kwargs, runtime keys)`` of a ``[plant]`` mapping or dataclass (``type`` dropped).

    The runtime keys (:data:`RUNTIME_KEYS`: ``engine``, ``joint_groups``) are the seed's runtime-injected
    objects, never constructor arguments.
    """
    if is_dataclass(config) and not isinstance(config, type):
        config = asdict(config)
    if not isinstance(config, Mapping):
        raise ConfigError(f"[plant] expected a table of constructor arguments, got {type(config).__name__}")
    kwargs = {k: v for k, v in config.items() if k != "type" and k not in RUNTIME_KEYS}
    runtime = {k: config[k] for k in RUNTIME_KEYS if k in config}
    return kwargs, runtime
