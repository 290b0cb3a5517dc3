r"""Grey-box estimation: :func:`identify`, least squares over the plant's exact CasADi dynamics.

The plant's discrete step ``x⁺ = F(x, u, p)`` (its own :meth:`~shinro_ctrl.plants.base.Plant.symbolic_step`
at its ``dt``, the step the closed loops and MuJoCo's Euler integrator take, or RK4 of its continuous
dynamics at the data's sample interval) is written with the chosen parameters ``θ`` as symbols.

**Simulation (output) error**, the default: multiple shooting. Every sample ``k`` of every experiment has
a state variable ``X_k``; within a shooting segment ``X_{k+1} = F(X_k, u_k, p(θ))`` is an equality
constraint, and each segment's first state is free (estimated, with the initial state of the experiment).
The cost is

.. math::

    \min_{\theta, X} \; \tfrac12 \sum_k \sum_{j} \Big(\frac{y_{kj} - X_{k, o_j}}{\sigma_j}\Big)^2

over the measured outputs ``o_j`` only (output-error mode when not every state is measured), with
``σ_j`` a noise level estimated from the data's second differences. IPOPT solves it with exact
derivatives. Segments keep the problem well posed on an open-loop unstable plant: by default a segment
spans five time constants of the plant's fastest unstable mode at its equilibrium (``e⁵ ≈ 150`` growth;
over 50 seeds of the cart-pole, shorter segments, with more estimated starts, gave intervals a little too narrow),
the whole experiment when it has none.

**Prediction error** (``mode="prediction"``, every state measured): the one-step errors
``y_{k+1} − F(y_k, u_k, p(θ))`` are minimized over ``θ`` alone: fast, but the noise in the measured
states it predicts from biases the estimate (errors in variables), and its intervals (white one-step
errors) do not include that bias: the result says so. Use it on low-noise full-state data or for a
first guess; the simulation error is the calibrated one (benchmarks/identification.py).

After the fit, :mod:`~shinro_ctrl.identification.uncertainty` gives the covariance from the residual
Jacobian (the shooting states eliminated through the constraints' Jacobian). A combination of
parameters the data cannot determine to ``max_rel_std`` (relative) is named, and, by default, pinned at
its prior (the fit is repeated with ``vᵀ(θ − θ_prior)/scale = 0``) instead of being fitted to noise.
"""

from __future__ import annotations

import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import casadi as cs
import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from shinro_ctrl.errors import IdentificationError, InvalidArgument, UnknownName
from shinro_ctrl.identification.data import Experiment, check_sampling, select_outputs
from shinro_ctrl.identification.fit import fit_percent, nrmse
from shinro_ctrl.identification.result import IdentificationResult
from shinro_ctrl.identification.uncertainty import (
    Uncertainty,
    describe_direction,
    parameter_uncertainty,
    weak_directions,
)
from shinro_ctrl.plants.base import Plant
from shinro_ctrl.validation import close_match_hint

__all__ = ["IdentificationError", "default_bounds", "discrete_step", "identify"]

MODES = ("simulation", "prediction")
DISCRETIZATIONS = ("plant", "rk4")
#: Parameter-name fragments that mark a quantity that must be positive / nonnegative (default bounds).
POSITIVE = ("mass", "length", "inertia", "radius")
NONNEGATIVE = ("damping", "friction", "armature")
#: Default shooting segment, in time constants ``1/λ`` of the fastest unstable mode (growth ``e⁵`` over one).
SEGMENT_TIME_CONSTANTS = 5.0
#: Weight of the pull to the prior in the cost, per relative unit squared (see :func:`_solve`).
PRIOR_WEIGHT = 1e-6
#: Correlation above which two estimates are reported as hard to tell apart.
CORRELATION_WARN = 0.95


def default_bounds(name: str) -> tuple[float, float]:
    """``(lo, hi)`` by the parameter's name: masses, lengths, inertias, radii > 0; damping, friction >= 0."""
    low = name.lower()
    if any(f in low for f in POSITIVE):
        return 0.0, np.inf  # IPOPT stays strictly inside: the estimate is > 0
    if any(f in low for f in NONNEGATIVE):
        return 0.0, np.inf
    return -np.inf, np.inf


def discrete_step(plant: Plant, discretization: str, dt: float) -> cs.Function:
    """``F(x, u, p) -> x⁺`` over every plant parameter: the plant's own step or RK4 at ``dt``."""
    if discretization == "plant":
        return plant.symbolic_step()
    f = plant.symbolic(params=True)
    x = cs.SX.sym("x", plant.state_dim)
    u = cs.SX.sym("u", plant.input_dim)
    p = cs.SX.sym("p", len(plant.param_names))
    k1 = f(x, u, p)
    k2 = f(x + dt / 2 * k1, u, p)
    k3 = f(x + dt / 2 * k2, u, p)
    k4 = f(x + dt * k3, u, p)
    return cs.Function("F_rk4", [x, u, p], [x + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)], ["x", "u", "p"], ["x_next"])


@dataclass
class _Problem:
    """The least-squares problem of one identification (built once, solved once or twice)."""

    v: cs.MX  # all unknowns: z (scaled parameters), then every experiment's states column-wise
    g: cs.MX  # shooting constraints
    e: cs.MX  # raw residuals y - ŷ
    weight: np.ndarray  # row weights 1/σ
    channel: np.ndarray  # output index of each residual
    lbx: np.ndarray
    ubx: np.ndarray
    x_init: np.ndarray
    free_states: np.ndarray  # indices in v of the estimated segment starts
    dep_states: np.ndarray  # indices in v of the states fixed by the constraints
    k: int
    state_slices: list[slice]  # each experiment's states in v (n * N, column-major)


def identify(
    plant: Plant,
    data: Experiment | Sequence[Experiment],
    params: Sequence[str],
    *,
    mode: str = "simulation",
    outputs: Sequence[str] | None = None,
    bounds: Mapping[str, tuple[float, float]] | None = None,
    x0: str | np.ndarray | Sequence[np.ndarray] = "estimate",
    segment: float | None = None,
    discretization: str = "plant",
    max_rel_std: float = 0.5,
    on_unidentifiable: str = "prior",
    max_iter: int = 200,
) -> IdentificationResult:
    """Estimate physical parameters of ``plant`` from one or more experiments.

    Args:
        plant: The plant; its current parameters are the priors (starting point, and the value of a
            parameter the data cannot see), its ``dt`` the step of ``discretization="plant"``.
        data: One :class:`~shinro_ctrl.identification.data.Experiment` or several (estimated together,
            each with its own initial state).
        params: Names of the parameters to estimate (a subset of ``plant.param_names``).
        mode: ``"simulation"`` (output error, multiple shooting) or ``"prediction"`` (one-step error,
            every state measured).
        outputs: Use only these measured states (default: all the data measures).
        bounds: Parameter name → ``(lo, hi)``; default masses, lengths, inertias > 0 and damping,
            friction >= 0 (:func:`default_bounds`).
        x0: ``"estimate"`` (default) or the known initial state ``(n,)`` (one for all experiments, or a
            sequence, one per experiment).
        segment: Shooting segment length [s] (simulation mode); default five time constants of the
            fastest unstable mode at the plant's equilibrium, or the whole experiment.
        discretization: ``"plant"`` (the plant's own step; the data must be sampled at ``plant.dt``) or
            ``"rk4"`` (RK4 at the data's sample interval).
        max_rel_std: A parameter combination the data determines only to worse than this fraction of the
            parameters' scales (their priors' magnitudes) is unidentifiable.
        on_unidentifiable: ``"prior"``: hold such combinations at the prior and warn; ``"error"``: raise.
        max_iter: IPOPT iteration limit.

    Returns:
        The :class:`~shinro_ctrl.identification.result.IdentificationResult`.

    Raises:
        UnknownName: a parameter or output the plant does not have (the valid names are listed).
        InvalidArgument: bad options, mismatched sampling, a prior outside its bounds.
        IdentificationError: the data cannot see any of the parameters (too little excitation), or with
            ``on_unidentifiable="error"`` any combination of them.
    """
    t_start = time.perf_counter()
    exps = [data] if isinstance(data, Experiment) else list(data)
    names = _check_params(plant, params)
    if mode not in MODES:
        raise InvalidArgument(f"unknown mode {mode!r}; valid: {', '.join(MODES)}")
    if discretization not in DISCRETIZATIONS:
        raise InvalidArgument(f"unknown discretization {discretization!r}; valid: {', '.join(DISCRETIZATIONS)}")
    if on_unidentifiable not in ("prior", "error"):
        raise InvalidArgument(f"on_unidentifiable must be 'prior' or 'error', got {on_unidentifiable!r}")
    if not max_rel_std > 0:
        raise InvalidArgument(f"max_rel_std must be > 0, got {max_rel_std!r}")
    exps = [_checked_experiment(plant, e, outputs) for e in exps]
    for e in exps[1:]:
        if e.outputs != exps[0].outputs:
            raise InvalidArgument(
                f"experiments measure different outputs: {exps[0].source} {', '.join(exps[0].outputs)}, "
                f"{e.source} {', '.join(e.outputs)}; pass outputs=[...] to use the common ones"
            )
    dt = check_sampling(
        exps, plant.dt if discretization == "plant" else None, what=f"the plant's step (dt = {plant.dt:g} s)"
    )
    F = discrete_step(plant, discretization, dt)
    prior_all = plant.dynamics_params()
    idx = [plant.param_names.index(p) for p in names]
    prior = np.array([prior_all[p] for p in names])
    scale = np.where(np.abs(prior) > 0, np.abs(prior), 1.0)
    lo, hi = _bounds(names, prior, bounds)
    z0 = prior / scale
    x0s = _initial_states(plant, x0, len(exps))
    seg = _segment_samples(plant, segment, dt, mode)

    prob = _build(plant, F, exps, idx, scale, lo / scale, hi / scale, z0, x0s, seg, mode, prior_all)
    sol, stats = _solve(prob, np.zeros((len(names), 0)), z0, max_iter)
    unc, e = _uncertainty(prob, sol, scale, len(exps[0].outputs))
    weak, rel_std = weak_directions(unc.info_rel, max_rel_std)
    messages = [describe_direction(weak[:, i], names, prior, scale) for i in range(weak.shape[1])]
    held: tuple[str, ...] = ()
    if weak.shape[1]:
        if weak.shape[1] == len(names):
            raise IdentificationError(
                "too little excitation: the data cannot see "
                + ", ".join(names)
                + " (the inputs and states barely move them); excite the plant (e.g. [sim] excitation) "
                "or measure more outputs"
            )
        if on_unidentifiable == "error":
            raise IdentificationError("the data cannot determine: " + "; ".join(messages))
        sol, stats2 = _solve(prob, weak, z0, max_iter, warm=sol)
        stats["iter_count"] = stats.get("iter_count", 0) + stats2.get("iter_count", 0)
        stats["success"] = stats2.get("success", False)
        basis = _complement(weak)
        unc, e = _uncertainty(prob, sol, scale, len(exps[0].outputs), basis)
        held = tuple(n for i, n in enumerate(names) if np.max(np.abs(weak[i, :])) > 0.97)
    z = sol[: len(names)]
    theta = z * scale
    interval = np.clip(unc.interval(theta), lo[:, None], hi[:, None])  # a mass's interval stays > 0
    warnings = [
        f"{m} (determined only to ±{100 * r:.0f} %): held at the prior" for m, r in zip(messages, rel_std, strict=True)
    ]
    corr = unc.correlation
    involved = {i for i in range(len(names)) for j in range(weak.shape[1]) if abs(weak[i, j]) > 0.25}  # named
    for a in range(len(names)):
        for b in range(a + 1, len(names)):
            if abs(corr[a, b]) > CORRELATION_WARN and not (a in involved and b in involved):
                warnings.append(
                    f"{names[a]} and {names[b]} are strongly correlated (ρ = {corr[a, b]:+.3f}): the data "
                    "determines mostly a combination of them"
                )
    for i, n in enumerate(names):
        if n not in held and min(abs(theta[i] - lo[i]), abs(theta[i] - hi[i])) <= 1e-6 * scale[i]:
            b = lo[i] if abs(theta[i] - lo[i]) <= abs(theta[i] - hi[i]) else hi[i]
            warnings.append(
                f"{n} ended on its bound {b:g}: the data pushes it beyond, and its interval (cut at the bound) "
                "is not a confidence interval there; check the model or the bounds"
            )
    if mode == "prediction":
        warnings.append(
            "prediction error: noise in the measured states biases the estimates (errors in variables) and the "
            "intervals do not include that bias; confirm with mode='simulation'"
        )
    if not stats.get("success", False):
        warnings.append(f"IPOPT did not converge ({stats.get('return_status', '?')}): the estimates are not optimal")
    yhat = _predictions(prob, sol, exps, F, theta, idx, plant, mode)
    fitp, nr = {}, {}
    for j, out in enumerate(exps[0].outputs):
        y_all = np.concatenate([ex.y[:, j][_rows(mode, ex)] for ex in exps])
        h_all = np.concatenate([h[:, j] for h in yhat])
        fitp[out], nr[out] = fit_percent(y_all, h_all), nrmse(y_all, h_all)
    x0_est = [sol[s].reshape(-1, plant.state_dim)[0] for s in prob.state_slices] if mode == "simulation" else []
    return IdentificationResult(
        plant_type=type(plant).__name__,
        params=tuple(names),
        estimate={n: float(v) for n, v in zip(names, theta, strict=True)},
        prior={n: float(v) for n, v in zip(names, prior, strict=True)},
        std_error={n: float(s) for n, s in zip(names, unc.std, strict=True)},
        interval={n: (float(a), float(b)) for n, (a, b) in zip(names, interval, strict=True)},
        correlation=corr,
        unidentifiable=messages,
        held=held,
        warnings=warnings,
        noise_std={o: float(s) for o, s in zip(exps[0].outputs, unc.noise_std, strict=True)},
        fit_percent=fitp,
        nrmse=nr,
        x0=x0_est,
        mode=mode,
        segment=seg,
        fixed_params={k: v for k, v in prior_all.items() if k not in names},
        cost=0.5 * float(np.sum((prob.weight * e) ** 2)),
        iterations=int(stats.get("iter_count", 0)),
        solve_time=time.perf_counter() - t_start,
        success=bool(stats.get("success", False)),
        discretization=discretization,
        dt=dt,
    )


# ---------------------------------------------------------------- checks
def _check_params(plant: Plant, params: Sequence[str]) -> list[str]:
    if isinstance(params, str):
        params = [p.strip() for p in params.split(",") if p.strip()]
    names = list(params)
    if not names:
        raise InvalidArgument(f"no parameters to identify; {type(plant).__name__} has: {', '.join(plant.param_names)}")
    for p in names:
        if p not in plant.param_names:
            raise UnknownName(
                f"unknown parameter {p!r} of {type(plant).__name__}{close_match_hint(p, plant.param_names)}; "
                f"valid: {', '.join(plant.param_names)}"
            )
    dup = sorted({p for p in names if names.count(p) > 1})
    if dup:
        raise InvalidArgument(f"parameter {dup[0]!r} named twice")
    return names


def _checked_experiment(plant: Plant, exp: Experiment, outputs: Sequence[str] | None) -> Experiment:
    if not isinstance(exp, Experiment):
        raise InvalidArgument(f"identification data must be Experiment objects (load_data), got {type(exp).__name__}")
    if tuple(exp.inputs) != tuple(plant.input_names):
        raise InvalidArgument(
            f"{exp.source}: inputs {', '.join(exp.inputs)} do not match the plant's {', '.join(plant.input_names)}"
        )
    for o in exp.outputs:
        if o not in plant.state_names:
            raise UnknownName(
                f"{exp.source}: output {o!r} is not a state of {type(plant).__name__}"
                f"{close_match_hint(o, plant.state_names)}; states: {', '.join(plant.state_names)}"
            )
    return select_outputs(exp, outputs) if outputs is not None else exp


def _bounds(
    names: list[str], prior: np.ndarray, bounds: Mapping[str, tuple[float, float]] | None
) -> tuple[np.ndarray, np.ndarray]:
    bounds = dict(bounds or {})
    bad = [b for b in bounds if b not in names]
    if bad:
        raise UnknownName(f"bounds for {bad[0]!r}, which is not identified; identified: {', '.join(names)}")
    lo, hi = np.empty(len(names)), np.empty(len(names))
    for i, n in enumerate(names):
        try:
            lo[i], hi[i] = (float(v) for v in bounds.get(n, default_bounds(n)))
        except (TypeError, ValueError):
            raise InvalidArgument(f"bounds[{n!r}] must be a (lo, hi) pair of numbers") from None
        if not lo[i] <= prior[i] <= hi[i] or not lo[i] < hi[i]:
            raise InvalidArgument(
                f"the prior {n} = {prior[i]:g} is outside its bounds [{lo[i]:g}, {hi[i]:g}]"
                if lo[i] < hi[i]
                else f"bounds of {n}: lo must be < hi, got [{lo[i]:g}, {hi[i]:g}]"
            )
    return lo, hi


def _initial_states(plant: Plant, x0: object, count: int) -> list[np.ndarray | None]:
    if isinstance(x0, str):
        if x0 != "estimate":
            raise InvalidArgument(f"x0 must be 'estimate' or a state (n,), got {x0!r}")
        return [None] * count
    arr = np.asarray(x0, dtype=float)
    if arr.shape == (plant.state_dim,):
        return [arr] * count
    if arr.shape == (count, plant.state_dim):
        return list(arr)
    raise InvalidArgument(f"x0 must be 'estimate', a state ({plant.state_dim},) or one per experiment, got {arr.shape}")


def _segment_samples(plant: Plant, segment: float | None, dt: float, mode: str) -> int:
    """Samples (intervals) per shooting segment; 0 means the whole experiment."""
    if mode == "prediction":
        return 1
    if segment is not None:
        if not segment > 0:
            raise InvalidArgument(f"segment must be > 0 s, got {segment!r}")
        return max(1, round(segment / dt))
    try:
        A, _ = plant.linearize()
        lam = float(np.max(np.linalg.eigvals(A).real))
    except Exception:
        return 0
    if not np.isfinite(lam) or lam <= 1e-9:
        return 0
    return max(10, round(SEGMENT_TIME_CONSTANTS / lam / dt))


def _noise_level(y: np.ndarray) -> np.ndarray:
    """Per column, a robust noise level from second differences (``var Δ²y = 6σ²`` for white noise)."""
    d2 = y[2:] - 2 * y[1:-1] + y[:-2]
    mad = 1.4826 * np.median(np.abs(d2 - np.median(d2, axis=0)), axis=0) / np.sqrt(6.0)
    spread = np.std(y, axis=0)
    return np.maximum(mad, 1e-4 * spread + 1e-12)


def _rows(mode: str, exp: Experiment) -> slice:
    """The samples that have a residual: all (simulation) or all but the first (prediction)."""
    return slice(1, None) if mode == "prediction" else slice(None)


# ---------------------------------------------------------------- the NLP
def _build(
    plant: Plant,
    F: cs.Function,
    exps: list[Experiment],
    idx: list[int],
    scale: np.ndarray,
    zlo: np.ndarray,
    zhi: np.ndarray,
    z0: np.ndarray,
    x0s: list[np.ndarray | None],
    seg: int,
    mode: str,
    base: dict[str, float],
) -> _Problem:
    n, k = plant.state_dim, len(idx)
    z = cs.MX.sym("z", k)
    pvec = [cs.MX(v) for v in base.values()]
    for j, i in enumerate(idx):
        pvec[i] = scale[j] * z[j]
    p = cs.vertcat(*pvec)
    vs, gs, es, w_rows, ch_rows = [z], [], [], [], []
    lbx, ubx, xinit = [zlo], [zhi], [z0]
    free, dep, slices = [], [], []
    offset = k
    for ex, x0 in zip(exps, x0s, strict=True):
        sel = [plant.state_names.index(o) for o in ex.outputs]
        w = 1.0 / _noise_level(ex.y)
        N = ex.samples
        if mode == "prediction":
            if len(sel) != n:
                raise InvalidArgument(
                    f"{ex.source}: prediction mode needs every state measured (it measures "
                    f"{', '.join(ex.outputs)}); use mode='simulation'"
                )
            Y = np.zeros((n, N))
            Y[sel, :] = ex.y.T  # states in plant order
            pred = F.map(N - 1)(Y[:, :-1], ex.u.T, p)
            e = cs.vec((cs.DM(Y[:, 1:]) - pred)[sel, :].T)  # output-major residuals
            es.append(e)
            w_rows.append(np.repeat(w, N - 1))
            ch_rows.append(np.repeat(np.arange(len(sel)), N - 1))
            continue
        X = cs.MX.sym("X", n, N)
        vs.append(cs.vec(X))
        slices.append(slice(offset, offset + n * N))
        starts = set(range(0, N - 1, seg)) if seg > 0 else {0}
        nxt = F.map(N - 1)(X[:, :-1], ex.u.T, p)
        keep = [c for c in range(1, N) if c not in starts]
        gs.append(cs.vec(X[:, keep] - nxt[:, [c - 1 for c in keep]]))
        for c in range(N):
            cols = np.arange(offset + n * c, offset + n * (c + 1))
            if c == 0 and x0 is not None:
                continue  # known: neither estimated nor constrained
            (free if c in starts else dep).append(cols)
        e = cs.vec((ex.y.T - X[sel, :]).T)  # output-major: all samples of output 0, then output 1 ...
        es.append(e)
        w_rows.append(np.repeat(w, N))
        ch_rows.append(np.repeat(np.arange(len(sel)), N))
        guess = _state_guess(plant, ex, sel)
        lo_x = np.full((n, N), -np.inf)
        hi_x = np.full((n, N), np.inf)
        if x0 is not None:
            guess[:, 0] = lo_x[:, 0] = hi_x[:, 0] = x0
        lbx.append(lo_x.ravel(order="F"))
        ubx.append(hi_x.ravel(order="F"))
        xinit.append(guess.ravel(order="F"))
        offset += n * N
    return _Problem(
        v=cs.vertcat(*vs),
        g=cs.vertcat(*gs) if gs else cs.MX(0, 1),
        e=cs.vertcat(*es),
        weight=np.concatenate(w_rows),
        channel=np.concatenate(ch_rows),
        lbx=np.concatenate(lbx),
        ubx=np.concatenate(ubx),
        x_init=np.concatenate(xinit),
        free_states=np.concatenate(free) if free else np.zeros(0, int),
        dep_states=np.concatenate(dep) if dep else np.zeros(0, int),
        k=k,
        state_slices=slices,
    )


def _state_guess(plant: Plant, ex: Experiment, sel: list[int]) -> np.ndarray:
    """Starting states ``(n, N)``: the measured ones; a velocity whose position is measured, its derivative."""
    guess = np.zeros((plant.state_dim, ex.samples))
    guess[sel, :] = ex.y.T
    for q, v in zip(plant.position_indices, plant.velocity_indices, strict=True):
        if q in sel and v not in sel:
            guess[v, :] = np.gradient(ex.y[:, sel.index(q)], ex.dt)
    return guess


def _solve(
    prob: _Problem, pinned: np.ndarray, z0: np.ndarray, max_iter: int, warm: np.ndarray | None = None
) -> tuple[np.ndarray, dict]:
    """Solve with IPOPT; ``pinned`` ``(k, q)``: directions held at the prior, ``pinnedᵀ(z − z0) = 0``."""
    r = prob.e * cs.DM(prob.weight)
    g = prob.g
    lbg = [np.zeros(g.shape[0])]
    if pinned.shape[1]:
        g = cs.vertcat(g, cs.mtimes(cs.DM(pinned.T), prob.v[: prob.k] - cs.DM(z0)))
        lbg.append(np.zeros(pinned.shape[1]))
    # a vanishing pull to the prior (PRIOR_WEIGHT per relative unit²) makes the minimum unique along directions
    # the data cannot see; against an identifiable direction's information (>> 1) it moves nothing
    dz = prob.v[: prob.k] - cs.DM(z0)
    nlp = {"x": prob.v, "f": 0.5 * cs.dot(r, r) + 0.5 * PRIOR_WEIGHT * cs.dot(dz, dz), "g": g}
    # Gauss-Newton: the Hessian of the Lagrangian is JᵣᵀJᵣ (the shooting constraints' curvature dropped; the
    # reduced Hessian stays the Gauss-Newton one of the eliminated problem), constant in simulation mode
    Jr = cs.jacobian(r, prob.v)
    lam_f, lam_g, p = cs.MX.sym("lam_f"), cs.MX.sym("lam_g", g.shape[0]), cs.MX.sym("p", 0)
    reg = cs.DM(sp.diags(np.r_[np.full(prob.k, PRIOR_WEIGHT), np.zeros(prob.v.shape[0] - prob.k)]))
    hess = cs.Function("nlp_hess_l", [prob.v, p, lam_f, lam_g], [cs.triu(lam_f * (cs.mtimes(Jr.T, Jr) + reg))])
    opts = {
        "hess_lag": hess,
        "print_time": False,
        "ipopt": {
            "print_level": 0,
            "sb": "yes",
            "max_iter": int(max_iter),
            "tol": 1e-10,
            "acceptable_tol": 1e-7,
            "mu_strategy": "adaptive",
        },
    }
    solver = cs.nlpsol("identify", "ipopt", nlp, opts)
    x_init = prob.x_init if warm is None else warm
    lbg_v = np.concatenate(lbg)
    res = solver(x0=x_init, lbx=prob.lbx, ubx=prob.ubx, lbg=lbg_v, ubg=lbg_v)
    stats = solver.stats()
    sol = np.asarray(res["x"]).ravel()
    if not np.all(np.isfinite(sol)):
        raise IdentificationError(f"the estimation diverged ({stats.get('return_status')}); check the data and priors")
    return sol, stats


def _uncertainty(
    prob: _Problem,
    sol: np.ndarray,
    scale: np.ndarray,
    channels: int,
    basis: np.ndarray | None = None,
) -> tuple[Uncertainty, np.ndarray]:
    """Residual Jacobian wrt (θ, free segment starts), the shooting states eliminated, and the covariance."""
    v = prob.v
    fe = cs.Function("e", [v], [prob.e, cs.jacobian(prob.e, v)])
    e_dm, Je_dm = fe(sol)
    e = np.asarray(e_dm).ravel()
    Je = _csc(Je_dm)
    k = prob.k
    w_cols = np.concatenate([np.arange(k), prob.free_states]).astype(int)
    if prob.dep_states.size:
        fg = cs.Function("g", [v], [cs.jacobian(prob.g, v)])
        Jg = _csc(fg(sol))
        Gd = Jg[:, prob.dep_states]
        Gw = Jg[:, w_cols]
        dd = -spla.splu(Gd.tocsc()).solve(Gw.toarray())
        J = Je[:, w_cols].toarray() + Je[:, prob.dep_states] @ dd
    else:
        J = Je[:, w_cols].toarray()
    J[:, :k] = J[:, :k] / scale  # per physical parameter
    unc = parameter_uncertainty(J, e, prob.weight, prob.channel, channels, k, scale, basis)
    return unc, e


def _csc(m: cs.DM) -> sp.csc_matrix:
    """A CasADi sparse ``DM`` as a scipy CSC matrix."""
    sparsity = m.sparsity()
    colind, row = np.array(sparsity.colind()), np.array(sparsity.row())
    return sp.csc_matrix((np.asarray(m.nonzeros()), row, colind), shape=m.shape)


def _complement(V: np.ndarray) -> np.ndarray:
    """Orthonormal basis of the complement of ``V``'s columns."""
    k = V.shape[0]
    Q, _ = np.linalg.qr(np.hstack([V, np.eye(k)]))
    return Q[:, V.shape[1] : k]


def _predictions(
    prob: _Problem,
    sol: np.ndarray,
    exps: list[Experiment],
    F: cs.Function,
    theta: np.ndarray,
    idx: list[int],
    plant: Plant,
    mode: str,
) -> list[np.ndarray]:
    """Model outputs at the estimate per experiment: the shooting states (simulation) or one-step predictions."""
    out = []
    if mode == "simulation":
        for ex, s in zip(exps, prob.state_slices, strict=True):
            X = sol[s].reshape(-1, plant.state_dim)
            out.append(X[:, [plant.state_names.index(o) for o in ex.outputs]])
        return out
    p = np.array(list(plant.dynamics_params().values()))
    p[idx] = theta
    for ex in exps:
        sel = [plant.state_names.index(o) for o in ex.outputs]
        Y = np.zeros((plant.state_dim, ex.samples))
        Y[sel, :] = ex.y.T
        pred = np.asarray(F.map(ex.samples - 1)(Y[:, :-1], ex.u.T, p))
        out.append(pred[sel, :].T)
    return out


def simulate_segments(plant: Plant, result: IdentificationResult, data: Experiment) -> np.ndarray:
    """Model outputs ``(N, p)`` on ``data`` with the identified parameters, the segment starts estimated.

    The same shooting segments as the identification (``result.segment`` samples; 0: one segment from an
    estimated initial state); the parameters are fixed at ``result.plant_params``.
    """
    exp = _checked_experiment(plant, data, None)
    dt = check_sampling(
        [exp], plant.dt if result.discretization == "plant" else None, what=f"the plant's step (dt = {plant.dt:g} s)"
    )
    F = discrete_step(plant, result.discretization, dt)
    base = {k: result.plant_params.get(k, v) for k, v in plant.dynamics_params().items()}
    empty = np.zeros(0)
    prob = _build(plant, F, [exp], [], empty, empty, empty, empty, [None], result.segment, "simulation", base)
    sol, _ = _solve(prob, np.zeros((0, 0)), empty, 200)
    X = sol[prob.state_slices[0]].reshape(-1, plant.state_dim)
    return X[:, [plant.state_names.index(o) for o in exp.outputs]]
