"""The optimal control problem of :class:`~shinro_ctrl.controllers.nmpc.NonlinearMPC`, its options and strategies.

:class:`NMPCOptions` holds every option of the controller (each documented
once); :meth:`NMPCOptions.resolve` validates it once. :func:`build_ocp` turns
the dynamics, the weights and the resolved options into one frozen
:class:`NMPCProblem` (the discrete step ``F``, the compiled linearization of
all stages, the terminal weight), which is handed whole to a solution strategy:
:class:`~shinro_ctrl.controllers._nmpc_rti.RealTimeIteration` or
:class:`~shinro_ctrl.controllers._nmpc_ipopt.IpoptSolver`, both behind the
:class:`NMPCStrategy` interface. The module docstring of ``controllers/nmpc.py``
states the OCP.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Protocol

import casadi as cs
import numpy as np

from shinro_ctrl.codegen import compiled
from shinro_ctrl.controllers.lqr import riccati_solution
from shinro_ctrl.controllers.qp.solution import NMPCSolution
from shinro_ctrl.errors import InvalidArgument
from shinro_ctrl.types import Bound, Weight
from shinro_ctrl.validation import as_vector, bound_pair, check_positive, weight_matrix

__all__ = [
    "CODEGEN_MIN_INSTRUCTIONS",
    "INTEGRATORS",
    "PLANT_GIVEN",
    "SOLVERS",
    "NMPCOptions",
    "NMPCProblem",
    "NMPCStrategy",
    "StateManifold",
    "build_ocp",
    "failed_solution",
    "riccati_functions",
    "stage_function",
]

#: Solvers of ``NonlinearMPC``: ``"auto"`` is ``"daqp"``.
SOLVERS = ("auto", "daqp", "osqp", "ipopt")
#: Discrete steps ``F`` of the shooting intervals.
INTEGRATORS = ("rk4", "semi_implicit")
#: Stage functions with more instructions than this are compiled to C when ``codegen`` is None (automatic).
CODEGEN_MIN_INSTRUCTIONS = 5000
#: Options ``from_plant`` fills in from the plant (a scenario cannot set them).
PLANT_GIVEN = ("position_indices", "velocity_indices", "hold", "state_names", "input_names")


@dataclass(frozen=True)
class NMPCOptions:
    """Options of a nonlinear MPC besides the dynamics, ``(Q, R)``, the horizon and ``dt``.

    Attributes:
        x0: Target state ``(n,)`` (the default reference ``r``); default zeros
            (``from_plant``: the plant's equilibrium).
        u0: Input reference ``ū`` ``(m,)`` (e.g. the hover thrust); default
            zeros (``from_plant``: the plant's equilibrium).
        u_min: Hard lower input bounds ``(m,)`` (a scalar broadcasts; -inf = none);
            the returned input is clipped to the bounds.
        u_max: Hard upper input bounds ``(m,)``.
        x_min: Lower state bounds ``(n,)`` on ``x_1 … x_N`` (never on the measured ``x_0``).
        x_max: Upper state bounds ``(n,)``.
        soft: Soft state bounds: slack variables with the penalty
            ``w_1 Σ s + ½ w_2 Σ s²`` (the problem is then never infeasible
            because of a state bound).
        soft_weight_l1: Linear slack weight ``w_1`` >= 0.
        soft_weight_quad: Quadratic slack weight ``w_2`` > 0.
        terminal_cost: Terminal weight ``Q_f``: ``"Q"`` (the stage weight),
            ``"lqr"`` (the DARE of the model linearized at ``(x0, u0)``) or a
            matrix ``(n, n)`` (or its diagonal).
        iterations: SQP iterations per call (1 = real-time iteration).
        tol: KKT residual at which SQP (and IPOPT) stop.
        solver: ``"auto"`` / ``"daqp"`` (condensed QP, DAQP), ``"osqp"`` (the
            sparse multiple-shooting QP, OSQP with in-place value updates) or
            ``"ipopt"`` (the OCP to convergence at every call).
        osqp_settings: Overrides of the sparse QP's OSQP settings (``"osqp"`` only).
        integrator: ``"rk4"`` or ``"semi_implicit"`` (needs ``position_indices``; the states that
            are neither positions nor velocities step by explicit Euler).
        position_indices: Position components of the state, for ``"semi_implicit"``.
        velocity_indices: Their velocities, in the same order.
        init_iterations: SQP iterations allowed on a cold start with ``cold_start="sqp"``.
        cold_start: How the first call after construction or ``reset()`` finds
            its first trajectory: ``"ipopt"`` (the OCP solved to convergence
            by IPOPT; the swing-ups need it: Gauss-Newton SQP from ``x`` held
            over the horizon converges slowly there and to a worse local
            minimum) or ``"sqp"`` (up to ``init_iterations`` SQP iterations
            from ``x`` held). Later calls never use IPOPT.
        hold: Calls per solve: the controller re-plans every ``hold`` calls and
            holds its input in between (``from_plant``: ``dt / plant.dt``).
        codegen: Evaluate the stage linearization (``F`` and its Jacobians,
            all stages at once) as C code compiled by
            :func:`shinro_ctrl.codegen.compiled` (built once, cached on disk;
            CasADi's virtual machine with a one-line note when no compiler
            works): ``True``, ``False``, or ``None`` (default) = compile when
            the stage function has more than :data:`CODEGEN_MIN_INSTRUCTIONS`
            instructions (a 7-DOF arm's 20,000 take 2.6 ms per call of 20
            stages in the virtual machine, 0.1 ms compiled; a cart-pole's few
            hundred gain little and skip the compiler). With it compiled, a
            large condensed QP without state bounds takes the compiled
            Riccati step first (:func:`riccati_functions`; docs/nmpc.md).
        riccati: Take that Riccati step first (``solver = "daqp"``; the
            Riccati functions compiled, or in the virtual machine when no
            compiler works): ``True``, ``False``, or ``None`` (default) = as
            ``codegen`` says above. Neither its unconstrained step nor the QP
            solved where it breaks a bound (in the policy's prestabilized
            variables, :mod:`~shinro_ctrl.controllers.qp.prestabilized`) forms
            the condensed Hessian, whose condition number reaches 10⁸–10⁹ on a
            swing-up (one rounding of ``H`` moves ``u₀`` by ~1e-8): ``True``
            makes every step well conditioned, and the exported C takes the
            same steps (docs/deploying.md).
        state_names: Names of the states, for messages (default ``x[i]``).
        input_names: Names of the inputs, for messages (default ``u[i]``).
    """

    x0: Sequence[float] | np.ndarray | None = None
    u0: float | Sequence[float] | np.ndarray | None = None
    u_min: Bound = None
    u_max: Bound = None
    x_min: Bound = None
    x_max: Bound = None
    soft: bool = False
    soft_weight_l1: float = 1e2
    soft_weight_quad: float = 1e2
    terminal_cost: str | Weight = "Q"
    iterations: int = 1
    tol: float = 1e-6
    solver: str = "auto"
    osqp_settings: Mapping[str, Any] | None = None
    integrator: str = "rk4"
    position_indices: Sequence[int] = ()
    velocity_indices: Sequence[int] = ()
    init_iterations: int = 30
    cold_start: str = "ipopt"
    hold: int = 1
    codegen: bool | None = None
    riccati: bool | None = None
    state_names: Sequence[str] | None = None
    input_names: Sequence[str] | None = None

    def resolve(self, n: int, m: int) -> NMPCOptions:
        """A validated copy for ``n`` states and ``m`` inputs.

        Vectors become float arrays of their sizes (bounds ±inf where absent),
        ``solver="auto"`` becomes ``"daqp"``, indices and names become tuples;
        a matrix ``terminal_cost`` stays as given (:func:`build_ocp` checks it).

        Raises:
            InvalidArgument: a value out of its range, a wrong shape, crossed
                bounds or an unknown name (the message names the option).
            NonFiniteError: NaN or inf where a finite number is needed.
        """
        for name in ("iterations", "hold", "init_iterations"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
                raise InvalidArgument(f"{name} must be an int >= 1, got {value!r}")
        for name, value, allowed in (
            ("cold_start", self.cold_start, ("ipopt", "sqp")),
            ("solver", self.solver, SOLVERS),
            ("integrator", self.integrator, INTEGRATORS),
        ):
            if value not in allowed:
                raise InvalidArgument(f"{name} must be one of {', '.join(allowed)}, got {value!r}")
        w1, w2 = float(self.soft_weight_l1), float(self.soft_weight_quad)
        if not (math.isfinite(w1) and w1 >= 0):
            raise InvalidArgument(f"soft_weight_l1 must be >= 0 and finite, got {self.soft_weight_l1!r}")
        if not (math.isfinite(w2) and w2 > 0):
            raise InvalidArgument(f"soft_weight_quad must be > 0 and finite, got {self.soft_weight_quad!r}")
        if self.codegen is not None and not isinstance(self.codegen, (bool, np.bool_)):
            raise InvalidArgument(f"codegen must be true, false or omitted (automatic), got {self.codegen!r}")
        if self.riccati is not None and not isinstance(self.riccati, (bool, np.bool_)):
            raise InvalidArgument(f"riccati must be true, false or omitted (automatic), got {self.riccati!r}")
        if self.riccati and self.solver in ("osqp", "ipopt"):
            raise InvalidArgument(f"riccati = true needs the condensed QP (solver 'daqp'), got solver {self.solver!r}")
        if isinstance(self.terminal_cost, str) and self.terminal_cost not in ("Q", "lqr"):
            raise InvalidArgument(f"terminal_cost must be 'Q', 'lqr' or an (n, n) matrix, got {self.terminal_cost!r}")
        u_min, u_max = bound_pair("u_min", "u_max", self.u_min, self.u_max, m)
        x_min, x_max = bound_pair("x_min", "x_max", self.x_min, self.x_max, n)
        names = {}
        for name, value, size, default in (
            ("state_names", self.state_names, n, "x"),
            ("input_names", self.input_names, m, "u"),
        ):
            names[name] = tuple(value) if value is not None else tuple(f"{default}[{i}]" for i in range(size))
            if len(names[name]) != size:
                raise InvalidArgument(f"{name}: expected {size} names but found {len(names[name])}")
        return dataclasses.replace(
            self,
            x0=np.zeros(n) if self.x0 is None else as_vector("x0", self.x0, n),
            u0=np.zeros(m) if self.u0 is None else as_vector("u0", self.u0, m),
            u_min=u_min,
            u_max=u_max,
            x_min=x_min,
            x_max=x_max,
            soft=bool(self.soft),
            soft_weight_l1=w1,
            soft_weight_quad=w2,
            iterations=int(self.iterations),
            tol=check_positive("tol", self.tol),
            solver="daqp" if self.solver == "auto" else self.solver,
            position_indices=tuple(int(i) for i in self.position_indices),
            velocity_indices=tuple(int(i) for i in self.velocity_indices),
            init_iterations=int(self.init_iterations),
            hold=int(self.hold),
            **names,
        )


@dataclass(frozen=True, eq=False)
class StateManifold:
    """A floating base's states (unit quaternions in them): the prediction's step and the deviations' maps.

    The OCP then keeps full states ``x (n,)`` in its trajectory and predicts with ``step`` (the plant's
    manifold step), while its cost, its QP and its gaps live in the tangent space (``nt`` coordinates):
    ``e_k = difference(x_k, r)``, the stage Jacobians ``A_k = D(F̄_k) F_x E(x̄_k)``, ``B_k = D(F̄_k) F_u``
    (``F̄_k = F(x̄_k, ū_k)``), the gaps ``d_k = difference(F̄_k, x̄_{k+1})`` and the update
    ``x̄_k ← retract(x̄_k, Δx_k)``.

    The cost ``½ ‖difference(retract(x̄_k, δ), r)‖²_W`` has the chart Jacobian
    ``J_k = ∂ difference(retract(x̄_k, δ), r)/∂δ`` at 0 (:meth:`chart_jacobian`: the identity but
    ``J_r⁻¹(φ)`` on each rotation vector ``φ``); the QP's variables are ``J_k δ_k``, so its Gauss-Newton
    cost ``½ ‖e_k + J_k δ_k‖²_W`` is exact to first order for any weights: ``A_k ← J_{k+1} A_k J_k⁻¹``,
    ``B_k ← J_{k+1} B_k``, ``d_k ← J_{k+1} d_k``, and the step retracts ``J_k⁻¹`` of the QP's.

    Attributes:
        nt: Tangent dimension (``plant.tangent_dim``).
        step: The discrete step ``F(x, u) -> x_next`` over the shooting interval (CasADi).
        difference: ``(x, x_ref) -> dx`` (``plant.difference``; rows of states broadcast).
        retract: ``(x_ref, dx) -> x`` (``plant.retract``).
        tangent_maps: ``x -> (D (nt, n), E (n, nt))`` (``plant.tangent_maps``).
    """

    nt: int
    step: cs.Function
    difference: Callable[[np.ndarray, np.ndarray], np.ndarray]
    retract: Callable[[np.ndarray, np.ndarray], np.ndarray]
    tangent_maps: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]]
    rotations: tuple[int, ...] = ()

    def chart_jacobian(self, e: np.ndarray) -> np.ndarray:
        r"""``J (nt, nt)`` at the deviation ``e = difference(x̄, r)``: ``J_r⁻¹(φ)`` on each rotation vector.

        ``J_r⁻¹(φ) = I + ½ [φ]× + (1/θ² − (1 + cos θ) / (2 θ sin θ)) [φ]×²`` (``θ = |φ| ≤ π``, invertible
        there), the derivative of ``log(exp(φ) exp(δ))`` at ``δ = 0``; ``rotations`` holds each rotation
        vector's first tangent index.
        """
        J = np.eye(self.nt)
        for d in self.rotations:
            phi = e[d : d + 3]
            th = float(np.linalg.norm(phi))
            K = np.array([[0.0, -phi[2], phi[1]], [phi[2], 0.0, -phi[0]], [-phi[1], phi[0], 0.0]])
            small = th < 1e-4  # the series 1/12 + θ²/720 there
            # (1 + cos θ) / (2 θ sin θ) = cot(θ/2) / (2 θ): finite at θ = π
            c = 1.0 / 12.0 + th * th / 720.0 if small else 1.0 / th**2 - 1.0 / (2.0 * th * np.tan(0.5 * th))
            J[d : d + 3, d : d + 3] += 0.5 * K + c * (K @ K)
        return J


@dataclass(frozen=True, eq=False)
class NMPCProblem:
    """The OCP a strategy solves: sizes, the discrete step, the weights and the resolved options.

    Attributes:
        n: States.
        m: Inputs.
        N: Shooting intervals (the horizon).
        dt: Shooting interval [s].
        F: The discrete step ``F(x, u) -> x_next`` (CasADi, SX).
        linearization: All stages at once: ``X (n, N + 1), U (m, N) -> G`` with
            ``G_k = [A_k, B_k, d_k]`` stored as ``(N, n, n + m + 1)``.
        Q: Stage state weight ``(n, n)``.
        R: Stage input weight ``(m, m)``, positive definite.
        Qf: Terminal weight ``(n, n)``.
        W: Stage weights of ``x_1 … x_N`` ``(N, n, n)`` (the last is ``Qf``).
        options: The resolved :class:`NMPCOptions`.
        compiled: The stage linearization is compiled code (``codegen`` true, or automatic on a large model):
            the strategies compile their other stage functions too (the Riccati recursion of
            :func:`riccati_functions`).
        manifold: A floating base's :class:`StateManifold` (None: the states are plain coordinates, the
            deviations subtractions). ``Q``, ``R``, ``Qf`` and ``W`` are then ``(nt, nt)``.
    """

    n: int
    m: int
    N: int
    dt: float
    F: cs.Function
    linearization: cs.Function
    Q: np.ndarray
    R: np.ndarray
    Qf: np.ndarray
    W: np.ndarray
    options: NMPCOptions
    compiled: bool = False
    manifold: StateManifold | None = None

    @property
    def nt(self) -> int:
        """Dimension of a state deviation (``n`` but on a floating base)."""
        return self.n if self.manifold is None else self.manifold.nt

    def deviation(self, X: np.ndarray, ref: np.ndarray) -> np.ndarray:
        """``X − ref`` (rows), or ``difference(X, ref)`` on a floating base."""
        return X - ref if self.manifold is None else self.manifold.difference(X, ref)

    @property
    def x0(self) -> np.ndarray:
        """The target state ``(n,)``."""
        return self.options.x0  # type: ignore[return-value]

    @property
    def u0(self) -> np.ndarray:
        """The input reference ``(m,)``."""
        return self.options.u0  # type: ignore[return-value]

    def objective(self, X: np.ndarray, U: np.ndarray, ref: np.ndarray) -> float:
        """The OCP cost of a trajectory ``X (N + 1, n)``, ``U (N, m)`` towards ``ref (n,)`` (slack terms included)."""
        o = self.options
        E = self.deviation(X, ref)
        dU = U - self.u0
        J = 0.5 * float(np.einsum("ki,ij,kj->", E[:-1], self.Q, E[:-1]))
        J += 0.5 * float(E[-1] @ self.Qf @ E[-1])
        J += 0.5 * float(np.einsum("ki,ij,kj->", dU, self.R, dU))
        if o.soft:  # the optimal slack of each state-bound row is its violation
            with np.errstate(invalid="ignore"):
                s = np.maximum(X[1:] - o.x_max, o.x_min - X[1:])
            s = np.maximum(s[np.isfinite(s)], 0.0)
            J += o.soft_weight_l1 * float(s.sum()) + 0.5 * o.soft_weight_quad * float(s @ s)
        return J


class NMPCStrategy(Protocol):
    """How a :class:`NMPCProblem` is solved at each call: real-time iterations (SQP) or IPOPT.

    A strategy owns its buffers and its warm start; ``NonlinearMPC`` holds one.
    """

    def solve(self, x: np.ndarray, ref: np.ndarray) -> NMPCSolution:
        """The OCP from the measured ``x (n,)`` towards ``ref (n,)`` (validated by the caller).

        A failed solve is returned (``message`` not empty, ``u`` NaN), not raised.
        """
        ...

    def prepare(self) -> tuple[float, float, float] | None:
        """Work for the next call done before its state is known; ``(linearize, condense, other)`` seconds."""
        ...

    def reset(self) -> None:
        """Forget the warm start: the next call starts cold."""
        ...


def rk4_step(f: cs.Function, x: cs.SX, u: cs.SX, h: float) -> cs.SX:
    """One classical RK4 step of ``xdot = f(x, u)`` with ``u`` held for ``h``."""
    k1 = f(x, u)
    k2 = f(x + 0.5 * h * k1, u)
    k3 = f(x + 0.5 * h * k2, u)
    k4 = f(x + h * k3, u)
    return x + h / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)


def build_ocp(
    f: cs.Function,
    Q: Weight,
    R: Weight,
    horizon: int,
    dt: float,
    options: NMPCOptions,
    manifold: StateManifold | None = None,
) -> NMPCProblem:
    """The OCP of dynamics ``f(x, u) -> xdot`` (CasADi) with the given weights, horizon and (unresolved) options.

    With a ``manifold`` (a floating base) the prediction is its ``step`` and the weights are ``(nt, nt)``.

    Raises:
        InvalidArgument: an invalid weight, horizon, ``dt`` or option (the message names it).
        NotStabilizable: ``terminal_cost="lqr"`` at a target where the DARE has no solution.
    """
    n, m = int(f.size1_in(0)), int(f.size1_in(1))
    if isinstance(horizon, bool) or not isinstance(horizon, (int, np.integer)) or horizon < 1:
        raise InvalidArgument(f"horizon must be an int >= 1, got {horizon!r}")
    N = int(horizon)
    h = check_positive("dt", dt)
    o = options.resolve(n, m)
    nt = n if manifold is None else manifold.nt
    if manifold is not None:
        if np.isfinite(o.x_min).any() or np.isfinite(o.x_max).any():  # type: ignore[arg-type]
            raise InvalidArgument("NonlinearMPC on a floating base: state bounds (x_min, x_max) are not supported")
        if o.solver == "ipopt":
            raise InvalidArgument(
                "NonlinearMPC on a floating base: solver 'ipopt' is not supported (its cost is the chordal "
                "attitude error, only good for the cold start); use 'daqp' or 'osqp'"
            )
    Qm = weight_matrix("Q", Q, nt)
    Rm = weight_matrix("R", R, m, definite=True)
    F = _discrete_step(f, n, m, h, o) if manifold is None else manifold.step
    if isinstance(o.terminal_cost, str):
        Qf = Qm.copy() if o.terminal_cost == "Q" else _dare(F, n, m, Qm, Rm, o, manifold)
    else:
        Qf = weight_matrix("terminal_cost", o.terminal_cost, nt)
    linearization, compiled_ = _stage_linearization(F, n, m, N, o.codegen)
    return NMPCProblem(
        n=n,
        m=m,
        N=N,
        dt=h,
        F=F,
        linearization=linearization,
        Q=Qm,
        R=Rm,
        Qf=Qf,
        W=np.stack([Qm] * (N - 1) + [Qf]),
        options=o,
        compiled=compiled_,
        manifold=manifold,
    )


def _discrete_step(f: cs.Function, n: int, m: int, h: float, o: NMPCOptions) -> cs.Function:
    xs, us = cs.SX.sym("x", n), cs.SX.sym("u", m)
    if o.integrator == "rk4":
        x_next = rk4_step(f, xs, us, h)
    else:
        pos, vel = o.position_indices, o.velocity_indices
        if not pos or len(pos) != len(vel):
            raise InvalidArgument("integrator 'semi_implicit' needs the plant's position and velocity indices")
        xd = f(xs, us)
        # the other states (e.g. actuator activations) by explicit Euler
        new = [xs[i] if i in pos or i in vel else xs[i] + h * xd[i] for i in range(n)]
        for q, v in zip(pos, vel, strict=True):
            new[v] = xs[v] + h * xd[v]
            new[q] = xs[q] + h * new[v]
        x_next = cs.vertcat(*new)
    return cs.Function("F", [xs, us], [x_next], ["x", "u"], ["x_next"])


def stage_function(F: cs.Function, n: int, m: int) -> cs.Function:
    """The SX function of one stage, ``(x_k, u_k, x̄_{k+1}) -> G_kᵀ`` with ``G_k = [A_k, B_k, d_k]``.

    ``A_k = ∂F/∂x``, ``B_k = ∂F/∂u``, ``d_k = F(x_k, u_k) − x̄_{k+1}``; the output ``(n + m + 1, n)`` is
    transposed so that its column-major storage is ``G_k`` row-major. The real-time iteration maps it over
    the horizon; the C export (``export/nmpc.py``) generates C from this same function.
    """
    xs, us, xn = cs.SX.sym("x", n), cs.SX.sym("u", m), cs.SX.sym("x_next", n)
    x_next = F(xs, us)
    G = cs.horzcat(cs.jacobian(x_next, xs), cs.jacobian(x_next, us), x_next - xn)
    return cs.Function("nmpc_stage", [xs, us, xn], [cs.densify(G).T])


def _stage_linearization(F: cs.Function, n: int, m: int, N: int, codegen: bool | None) -> tuple[cs.Function, bool]:
    """``G_kᵀ`` of all stages side by side, ``(n + m + 1, N n)`` (stored as ``(N, n, n + m + 1)``); compiled or not.

    One SX stage function (``[A_k, B_k, d_k]`` of one stage), compiled to C when ``codegen`` says so,
    mapped over the horizon in an MX function (an SX ``map`` would unroll it).
    """
    stage = stage_function(F, n, m)
    compile_ = bool(codegen or (codegen is None and stage.n_instructions() > CODEGEN_MIN_INSTRUCTIONS))
    if compile_:
        stage = compiled(stage)
    X = cs.MX.sym("X", n, N + 1)
    U = cs.MX.sym("U", m, N)
    return cs.Function("lin", [X, U], [stage.map(N)(X[:, :N], U, X[:, 1:])], ["X", "U"], ["G"]), compile_


def _dare(
    F: cs.Function, n: int, m: int, Q: np.ndarray, R: np.ndarray, o: NMPCOptions, manifold: StateManifold | None
) -> np.ndarray:
    xs, us = cs.SX.sym("x", n), cs.SX.sym("u", m)
    xn = F(xs, us)
    jac = cs.Function("F_jac", [xs, us], [cs.jacobian(xn, xs), cs.jacobian(xn, us), xn])
    A, B, x1 = (np.array(M, dtype=float) for M in jac(o.x0, o.u0))
    if manifold is not None:  # the tangent step Jacobians D(x⁺) F_x E(x0), D(x⁺) F_u
        D, _ = manifold.tangent_maps(x1.reshape(-1))
        _, E = manifold.tangent_maps(np.asarray(o.x0, dtype=float))
        A, B = D @ A @ E, D @ B
    return riccati_solution(A, B, Q, R, what="terminal_cost='lqr' at the target")


def failed_solution(
    ocp: NMPCProblem,
    message: str,
    status: str,
    total: float,
    X: np.ndarray | None = None,
    U: np.ndarray | None = None,
) -> NMPCSolution:
    """The record of a failed call: ``u`` NaN, ``message`` set, the trajectory ``X``, ``U`` (NaN when not given)."""
    return NMPCSolution(
        status=status, iterations=0, kkt_residual=math.nan, qp_status=status, qp_iterations=0,
        time_linearization_s=0.0, time_condensing_s=0.0, time_qp_s=0.0, time_other_s=0.0,
        solve_time_s=total, states=np.full((ocp.N + 1, ocp.n), np.nan) if X is None else X.copy(),
        inputs=np.full((ocp.N, ocp.m), np.nan) if U is None else U.copy(),
        u=np.full(ocp.m, np.nan), objective=math.nan, message=message,
    )  # fmt: skip


def riccati_functions(n: int, m: int, N: int, codegen: bool) -> tuple[cs.Function, cs.Function]:
    r"""The LTV QP without inequality constraints, solved by a Riccati recursion: ``(backward, forward)``.

    The QP is the one :class:`~shinro_ctrl.controllers.qp.ltv.CondensedLTV` condenses: stage ``k`` maps
    ``Δx_k`` to ``Δx_{k+1} = A_k Δx_k + B_k Δu_k + d_k`` and costs
    ``½ ‖e_{k+1} + Δx_{k+1}‖²_{W_k} + ½ ‖δu_k + Δu_k‖²_R`` (``e = x̄ − r``, ``δu = ū − u_ref``). With the value
    function ``½ Δxᵀ P_k Δx + p_kᵀ Δx`` of stages ``k … N−1`` (``P_N = 0``, ``p_N = 0``), ``S = W_k + P_{k+1}``,
    ``h = S d_k + W_k e_{k+1} + p_{k+1}``, ``R_e = R + B_kᵀ S B_k``, ``G_e = B_kᵀ S A_k``:

    .. math::

        K_k = -R_e^{-1} G_e,\quad \kappa_k = -R_e^{-1} (B_k^\top h + R\,\delta u_k),\quad
        P_k = A_k^\top S A_k + G_e^\top K_k,\quad p_k = A_k^\top h + G_e^\top \kappa_k,

    and the minimizer is the policy ``Δu_k = K_k Δx_k + κ_k`` rolled out from ``Δx_0``: ``O(N (n³ + n² m))``
    instead of the condensed Hessian's ``O(N² n² m)`` and its dense factorization. The forward function
    also returns the QP's gradient at ``ΔU = 0``, ``g_k = R δu_k + B_kᵀ μ_{k+1}`` with the costate
    ``μ_{k+1} = W_k (e_{k+1} + δx_{k+1}) + A_{k+1}ᵀ μ_{k+2}`` along the free response ``δx`` (``ΔU = 0``),
    which is ``−H ΔU`` at the minimizer (the KKT residual of the step).

    Signatures (column-major CasADi shapes; each matches a C-ordered NumPy array of the transposed shape):

    * backward ``(G (n+m+1, N n), W (n, N n), R (m, m), e (N n), du (N m)) -> (KK (m, N (n+1)), Re (m, N m))``
      (``G`` the stage linearization's output, ``KK`` the blocks ``[K_k, κ_k]``, ``Re`` the blocks
      ``R_e = R + B_kᵀ S B_k``: the Hessian of the QP in the prestabilized variables,
      :mod:`~shinro_ctrl.controllers.qp.prestabilized`);
    * forward ``(G, KK, W, R, e, du, dx0 (n)) -> (dU (m, N), dX (n, N), g (m, N), dX_free (n, N))``
      (``dX_free`` the free response ``ΔU = 0`` from ``Δx_0``).

    The stage bodies are SX functions called ``N`` times from MX functions (not unrolled); both MX functions
    are compiled by :func:`shinro_ctrl.codegen.compiled` when ``codegen`` is true (the arm's bodies: about
    10,000 and 13,000 instructions, kept apart because gcc's time grows faster than a function's size).
    """
    sx = cs.SX.sym
    w = n + m + 1
    Gt, W, P, p, e = sx("Gt", w, n), sx("W", n, n), sx("P", n, n), sx("p", n), sx("e", n)
    Gk = Gt.T  # the stage's block of the linearization's output is G_kᵀ: a contiguous slice, transposed in SX
    A, B, d = Gk[:, :n], Gk[:, n : n + m], Gk[:, n + m]
    product = cs.Function("nmpc_riccati_product", [Gt, W, P, p, e], [(W + P) @ Gk, W @ e + p])
    Y, s, R, du = sx("Y", n, w), sx("s", n), sx("R", m, m), sx("du", m)
    # Z = Gᵀ S G = [A B d]ᵀ S [A B d], one triangle (S = W + P is symmetric)
    Z = cs.SX(w, w)
    for i in range(w):
        for j in range(i, w):
            Z[i, j] = Z[j, i] = cs.dot(Gk[:, i], Y[:, j])
    At_h = Z[:n, n + m] + A.T @ s  # Aᵀ h, h = S d + W e + p
    Ge = Z[n : n + m, :n]  # Bᵀ S A
    KK = -cs.solve(R + Z[n : n + m, n : n + m], cs.horzcat(Ge, Z[n : n + m, n + m] + B.T @ s + R @ du))
    K, kappa = KK[:, :n], KK[:, n]
    Pk = cs.SX(n, n)
    for i in range(n):
        for j in range(i, n):
            Pk[i, j] = Pk[j, i] = Z[i, j] + cs.dot(Ge[:, i], K[:, j])
    Re = R + Z[n : n + m, n : n + m]
    update = cs.Function("nmpc_riccati_update", [Gt, Y, s, R, du], [KK, Pk, At_h + Ge.T @ kappa, Re])
    dx, fx, mu, An, Kp = sx("dx", n), sx("fx", n), sx("mu", n), sx("Ant", n, n), sx("KK", m, n + 1)
    u = Kp[:, :n] @ dx + Kp[:, n]
    fwd_stage = cs.Function("nmpc_policy_stage", [Gt, Kp, dx, fx], [u, A @ dx + B @ u + d, A @ fx + d])
    mu_k = W @ (e + fx) + An @ mu  # An = A_{k+1}ᵀ
    grad_stage = cs.Function("nmpc_costate_stage", [An, Gt, W, R, e, fx, mu, du], [mu_k, R @ du + B.T @ mu_k])
    mx = cs.MX.sym
    Gm, Wm, Rm, em, dum = mx("G", n + m + 1, N * n), mx("W", n, N * n), mx("R", m, m), mx("e", N * n), mx("du", N * m)

    def stage(k: int) -> tuple[cs.MX, cs.MX, cs.MX, cs.MX]:
        """``G_kᵀ (n + m + 1, n)``, ``W_k``, ``e_{k+1}``, ``δu_k`` of stage ``k``."""
        return (
            Gm[:, k * n : (k + 1) * n],
            Wm[:, k * n : (k + 1) * n],
            em[k * n : (k + 1) * n],
            dum[k * m : (k + 1) * m],
        )

    Pn, pn = cs.MX.zeros(n, n), cs.MX.zeros(n)
    blocks: list[cs.MX] = [cs.MX()] * N
    reblocks: list[cs.MX] = [cs.MX()] * N
    for k in range(N - 1, -1, -1):
        Gs, Wk, ek, duk = stage(k)
        Yk, sk = product(Gs, Wk, Pn, pn, ek)
        blocks[k], Pn, pn, reblocks[k] = update(Gs, Yk, sk, Rm, duk)
    backward = cs.Function(
        "nmpc_riccati",
        [Gm, Wm, Rm, em, dum],
        [cs.horzcat(*blocks), cs.horzcat(*reblocks)],
        ["G", "W", "R", "e", "du"],
        ["KK", "Re"],
    )
    KKm, dx0 = mx("KK", m, N * (n + 1)), mx("dx0", n)
    dxk, fxk = dx0, dx0
    us, xs, fs = [], [], []
    for k in range(N):
        uk, dxk, fxk = fwd_stage(stage(k)[0], KKm[:, k * (n + 1) : (k + 1) * (n + 1)], dxk, fxk)
        us.append(uk)
        xs.append(dxk)
        fs.append(fxk)
    mu_next, gs = cs.MX.zeros(n), [cs.MX()] * N
    for k in range(N - 1, -1, -1):
        Gs, Wk, ek, duk = stage(k)
        An = Gm[:n, (k + 1) * n : (k + 2) * n] if k + 1 < N else cs.MX.zeros(n, n)
        mu_next, gs[k] = grad_stage(An, Gs, Wk, Rm, ek, fs[k], mu_next, duk)
    forward = cs.Function(
        "nmpc_policy",
        [Gm, KKm, Wm, Rm, em, dum, dx0],
        [cs.horzcat(*us), cs.horzcat(*xs), cs.horzcat(*gs), cs.horzcat(*fs)],
        ["G", "KK", "W", "R", "e", "du", "dx0"],
        ["dU", "dX", "g", "dX_free"],
    )
    if codegen:  # each MX function with its stage bodies as one C library
        return compiled(backward), compiled(forward)
    return backward, forward
