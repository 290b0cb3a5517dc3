r"""Model files: the inertial parameters of chosen bodies and joint damping, armature and friction loss.

:func:`identify_model_file` estimates, for an :class:`~shinro_ctrl.plants.MjcfPlant`, whole bodies
(``body:NAME``: mass, centre of mass and inertia about it, ten parameters) and joint parameters
(``joint:NAME.damping``, ``.armature``, ``.frictionloss``) from logged joint positions (velocities if
measured) and inputs, through the inverse-dynamics regressor ``Y(q, q̇, q̈) π = y``
(:mod:`~shinro_ctrl.identification.regressor`, built from our RNEA). Steps:

1. **Derivatives by a non-causal filter.** ``q`` (and ``q̇`` when measured) are low-passed by a
   zero-phase FIR filter (:func:`lowpass_kernel`: a Blackman-windowed sinc with ``2M + 1`` taps,
   ``M = ⌈3 fs/f_c⌉``, applied centred, so without lag) at ``cutoff`` Hz; ``q̇`` (if not measured) and
   ``q̈`` are central differences of the filtered signals. The input, held over each sample interval
   (zero-order hold), is taken at sample ``k`` as
   ``(u_{k−1} + u_k)/2`` (the central difference of ``q̇`` at ``k`` averages ``q̈`` over
   ``[t_{k−1}, t_{k+1}]``) and passed through the *same* filter ("parallel filtering": both sides of the
   linear equation see one filter). ``edge`` samples at each end (default ``M + 1``: the filter's
   transients) are dropped.
2. **Weighted least squares** over every sample and joint: rows weighted by ``1/σ_j``, ``σ_j`` the
   residual standard deviation of joint ``j`` after a first fit with unit weights. In relative coordinates
   ``z = (π − π_prior) ⊘ s`` (``s`` the parameters' own scales: a body's prior mass ``m``, ``m L`` for
   its first moments and ``m L²`` for its inertias, ``L`` the larger of its COM distance and 5 cm; a
   joint parameter's prior, at least the value that would explain 5 % of its joint's RMS torque) the
   eigen-decomposition of the information ``s Yᵀ W² Y s`` splits π into the directions the data
   determines and those it does not: a direction of eigenvalue
   ``λ`` is determined when its relative standard error ``1/√λ`` is below ``max_rel_std`` — not, e.g.,
   the mass of a body on a single hinge, which enters only as ``m c``. The others are **held at the
   prior** (the model file's values) and named.
3. **Physical consistency.** If the least-squares estimate has every body's pseudo-inertia
   ``J(π) ≻ 0`` and every joint parameter ``> 0`` it is the constrained optimum. Otherwise the same
   quadratic cost over the determined directions (the held ones stay at the prior) is minimized with a
   log-det barrier ``−μ Σ log det J_b(π)`` (and ``−μ Σ log π_j``) by damped Newton steps from the
   (consistent) prior, ``μ`` driven to ``10⁻¹²`` of the cost's curvature: a convex problem without an
   SDP solver, every iterate consistent (:func:`_barrier`). The log-Cholesky coordinates of
   :mod:`~shinro_ctrl.identification.regressor` give the same set; the barrier works on π directly.
4. **Uncertainty.** The residuals of filtered data are correlated in time, so the covariance of π is the
   sandwich (batch-means) estimate: the estimator's per-sample scores summed over blocks of ``block``
   samples (several correlation lengths ``fs/cutoff``), then ``Cov = Σ_blocks S Sᵀ``. The reported
   parameters (mass, COM, inertia about the COM) get it by the delta method; a reported parameter that
   depends on an undetermined direction is listed in ``held``. ``result.fit_percent`` is MATLAB's fit
   ``100 (1 − ‖y − Yπ‖/‖y − ȳ‖)`` of each joint's torque ``y`` on the estimation data.

:meth:`ModelFileIdentification.write_model` writes the model file with the identified bodies' inertials
and joints' parameters (``MjSpec`` edit, atomic) so ``design``/``run`` take it.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from shinro_ctrl.errors import IdentificationError, InvalidArgument, UnknownName
from shinro_ctrl.identification.data import Experiment
from shinro_ctrl.identification.regressor import (
    InertialRegressor,
    ParamError,
    ParamSpec,
    parse_param_names,
    physical_from_pi,
    pseudo_inertia,
)
from shinro_ctrl.identification.result import IdentificationResult

if TYPE_CHECKING:
    from shinro_ctrl.plants.mjcf import MjcfPlant

__all__ = ["ModelFileIdentification", "identify_model_file", "lowpass_kernel", "regressor_data"]


@dataclass
class ModelFileIdentification:
    """The result of :func:`identify_model_file`.

    Attributes:
        result: The table-ready :class:`IdentificationResult` (physical parameters ``BODY.mass``,
            ``BODY.com_x`` …, ``BODY.Ixx`` … about the COM in the body frame, ``JOINT.damping`` …).
        pi: The estimate of the linear parameters ``(k,)`` (regressor order, ``pi_names``).
        pi_prior: The model file's ``(k,)``.
        pi_cov: Their covariance ``(k, k)`` (zero along the held directions).
        pi_names: Names of π's entries.
        bodies: Body name → ``{"mass", "ipos" (3,), "fullinertia" (6,)}`` (inertia about the COM: xx, yy,
            zz, xy, xz, yz) of the estimate.
        joints: Joint name → ``{"damping": …, …}`` of the estimate.
        rank: The number of directions of π the data determined (the rest held at the prior).
        constrained: Whether the barrier enforced physical consistency (the least-squares estimate was not).
        model_path: The model file identified.
    """

    result: IdentificationResult
    pi: np.ndarray
    pi_prior: np.ndarray
    pi_cov: np.ndarray
    pi_names: list[str]
    bodies: dict[str, dict[str, object]] = field(default_factory=dict)
    joints: dict[str, dict[str, float]] = field(default_factory=dict)
    constrained: bool = False
    model_path: str = ""
    rank: int = 0

    def consistent(self) -> bool:
        """Every identified body's pseudo-inertia positive definite and every joint parameter ``>= 0``."""
        nb = len(self.bodies)
        ok = all(np.linalg.eigvalsh(pseudo_inertia(self.pi[10 * b : 10 * b + 10])).min() > 0 for b in range(nb))
        return ok and bool(np.all(self.pi[10 * nb :] >= 0))

    def write_model(self, path: str | Path) -> Path:
        """Write the model file with the estimates (MjSpec edit, atomic); returns the path written."""
        from shinro_ctrl.engine.model_edit import write_inertials

        return write_inertials(self.model_path, path, self.bodies, self.joints)


_REGRESSORS: dict[tuple, InertialRegressor] = {}


def _regressor(plant: MjcfPlant, spec: ParamSpec) -> InertialRegressor:
    """The regressor of ``plant``'s file for ``spec``, built once per file version (a few tenths of a second on a
    7-DOF arm)."""
    path = Path(plant.model_path)
    key = (str(path), path.stat().st_mtime_ns, tuple(plant.active_actuators), spec)
    if key not in _REGRESSORS:
        if len(_REGRESSORS) > 16:
            _REGRESSORS.clear()
        _REGRESSORS[key] = InertialRegressor(plant, spec)
    return _REGRESSORS[key]


def lowpass_kernel(fs: float, cutoff: float) -> np.ndarray:
    """The zero-phase FIR low-pass: a Blackman-windowed sinc, cutoff ``f_c`` (−6 dB), ``2M + 1`` taps with
    ``M = ⌈3 fs/f_c⌉``, unit gain at 0 Hz: ``h_n = w_n 2 (f_c/fs) sinc(2 (f_c/fs)(n − M)) / Σ``."""
    M = int(np.ceil(3.0 * fs / cutoff))
    n = np.arange(2 * M + 1) - M
    h = 2 * cutoff / fs * np.sinc(2 * cutoff / fs * n) * np.blackman(2 * M + 1)
    return h / h.sum()


def _filtered(x: np.ndarray, h: np.ndarray) -> np.ndarray:
    """Each column of ``x`` convolved with the symmetric ``h``, centred (no lag; the ends are transients)."""
    return np.stack([np.convolve(c, h, mode="same") for c in np.atleast_2d(x.T)], axis=1)


def regressor_data(
    plant: MjcfPlant,
    experiments: Experiment | Sequence[Experiment],
    regressor: InertialRegressor,
    *,
    cutoff: float | None = None,
    edge: int | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """Stacked ``Y (S, nq, k)``, ``y (S, nq)`` and ``|q̇| (S, nq)`` of every kept sample, and the cutoff used.

    Raises:
        InvalidArgument: an experiment without every joint position, or a cutoff above the Nyquist frequency.
    """
    exps = [experiments] if isinstance(experiments, Experiment) else list(experiments)
    nq = plant.tree.nq
    names = list(plant.state_names)
    qn, qdn = names[:nq], names[nq : 2 * nq]
    fn = regressor.function
    Ys, ys, vs = [], [], []
    used = 0.0
    for e in exps:
        missing = [n for n in qn if n not in e.outputs]
        if missing:
            raise InvalidArgument(f"{e.source}: the data has no column for the joint positions {', '.join(missing)}")
        fs = 1.0 / e.dt
        fc = float(cutoff) if cutoff is not None else fs / 20.0
        if not 0 < fc < 0.5 * fs:
            raise InvalidArgument(f"cutoff must be in (0, {0.5 * fs:g}) Hz (the Nyquist frequency), got {fc:g}")
        used = fc
        cols = list(e.outputs)
        h = lowpass_kernel(fs, fc)
        q = _filtered(e.y[:, [cols.index(n) for n in qn]], h)
        if all(n in cols for n in qdn):
            qd = _filtered(e.y[:, [cols.index(n) for n in qdn]], h)
        else:
            qd = np.gradient(q, e.dt, axis=0)
        qdd = np.gradient(qd, e.dt, axis=0)
        u = np.asarray(e.u, dtype=float)
        uc = np.vstack([u[:1], 0.5 * (u[:-1] + u[1:]), u[-1:]])  # (N, m): the input around each sample
        uc = _filtered(uc, h)
        cut = int(edge) if edge is not None else h.shape[0] // 2 + 1
        sl = slice(cut, q.shape[0] - cut)
        if sl.stop - sl.start < 10:
            raise InvalidArgument(f"{e.source}: too few samples ({q.shape[0]}) for the filter's {cut}-sample edges")
        S = sl.stop - sl.start
        F = fn.map(S)
        Y, y = F(q[sl].T, qd[sl].T, qdd[sl].T, uc[sl].T)
        k = regressor.k
        Ys.append(np.asarray(Y).reshape(nq, S, k).transpose(1, 0, 2))
        ys.append(np.asarray(y).T)
        vs.append(np.abs(qd[sl]))
    return np.concatenate(Ys), np.concatenate(ys), np.concatenate(vs), used


def identify_model_file(
    plant: MjcfPlant,
    experiments: Experiment | Sequence[Experiment],
    params: Sequence[str],
    *,
    cutoff: float | None = None,
    edge: int | None = None,
    max_rel_std: float = 0.5,
    block: int | None = None,
    min_speed: float = 0.02,
) -> ModelFileIdentification:
    """Identify bodies' inertial parameters and joint parameters of a model-file plant (module docstring).

    Args:
        plant: The :class:`~shinro_ctrl.plants.MjcfPlant` (its file's values are the prior).
        experiments: Data with every joint position measured (velocities optional), and the inputs.
        params: ``body:NAME`` and ``joint:NAME.damping|armature|frictionloss`` names.
        cutoff: The zero-phase low-pass cutoff [Hz] (default a tenth of the Nyquist frequency).
        edge: Samples dropped at each end (default the filter's half length ``M + 1``).
        max_rel_std: A direction of π whose standard error exceeds this fraction of the parameters' scales is
            held at the prior.
        block: Samples per block of the covariance's batch means (default ``10 fs / cutoff``).
        min_speed: A joint's friction-loss rows are used only where ``|q̇| > min_speed`` (the sign is known).
            MuJoCo applies friction loss as a soft constraint that reaches its nominal value only when the
            joint slides fast, so against MuJoCo data the Coulomb model finds a smaller effective value
            (0.027-0.033 for a nominal 0.05 on the test arm, for min_speed 0.02-0.5).

    Raises:
        UnknownName: a parameter name that is not a body or joint of the model (the message lists them).
        IdentificationError: data that determine none of the parameters.
    """
    t_start = time.perf_counter()
    tree = plant.tree
    body_names = [b.name for b in tree.bodies]
    joint_names = [j.name for j in tree.joints]
    try:
        spec = parse_param_names(params, body_names, joint_names)
        reg = _regressor(plant, spec)
    except ParamError as exc:
        raise UnknownName(str(exc)) from None
    Y, y, speed, fc = regressor_data(plant, experiments, reg, cutoff=cutoff, edge=edge)
    S, nq, _ = Y.shape
    exps = [experiments] if isinstance(experiments, Experiment) else list(experiments)
    fs = 1.0 / exps[0].dt
    # friction-loss rows only where the sign of q̇ is known
    mask = np.ones((S, nq), dtype=bool)
    for j, attr in spec.joints:
        if attr == "frictionloss":
            mask[:, j] &= speed[:, j] > min_speed
    prior = reg.pi_prior
    # a joint parameter's scale: its prior, at least the value that would explain 5 % of its joint's torque
    floors = [
        0.05 * np.sqrt(np.mean(y[:, j] ** 2)) / max(np.sqrt(np.mean(Y[:, j, 10 * len(spec.bodies) + n] ** 2)), 1e-300)
        for n, (j, _attr) in enumerate(spec.joints)
    ]
    scale = _scales(prior, len(spec.bodies), np.asarray(floors))

    def solve_ls(w: np.ndarray) -> tuple[np.ndarray, ...]:
        """Minimum-deviation-from-prior WLS over the determined directions, in z = (π − π_prior)/s: π, 1/s, the
        determined and undetermined directions V1, V0, P = V1 Λ⁻¹ V1ᵀ (z = P Aᵀr/s), Λ and x = V1ᵀ z."""
        A = Y * (w * mask)[:, :, None]
        r0 = (y - Y @ prior) * w * mask
        A2 = A.reshape(-1, A.shape[2])
        H = A2.T @ A2
        D = 1.0 / scale
        lam, V = np.linalg.eigh(H / np.outer(D, D))
        lam, V = lam[::-1], V[:, ::-1]
        lam_floor = max(float(lam[0]), 1e-300) * 1e-14
        keep = (lam > lam_floor) & (1.0 / np.sqrt(np.maximum(lam, lam_floor)) < max_rel_std)
        V1, lam1 = V[:, keep], lam[keep]
        x = (V1.T @ ((A2.T @ r0.reshape(-1)) / D)) / lam1
        return prior + (V1 @ x) / D, D, V1, V[:, ~keep], (V1 / lam1) @ V1.T, lam1, x

    pi, D, V1, V0, Pz, lam1, x = solve_ls(np.ones((S, nq)))
    resid = (y - Y @ pi) * mask
    sigma = np.sqrt((resid**2).sum(0) / np.maximum(mask.sum(0) - V1.shape[1] / nq, 1.0))
    sigma = np.where(sigma > 0, sigma, 1.0)
    w = np.broadcast_to(1.0 / sigma, (S, nq))
    pi, D, V1, V0, Pz, lam1, x = solve_ls(w)
    if V1.shape[1] == 0:
        raise IdentificationError(
            "the data determine none of the parameters: excite the joints (e.g. [sim] excitation)"
        )
    nb = len(spec.bodies)
    constrained = not _consistent(pi, nb)
    if constrained:
        pi = _barrier(prior, scale, V1, lam1, x, nb)
    resid = (y - Y @ pi) * w * mask
    # sandwich covariance with batch means: z = Pz Σ_s a_s, a_s = Σ_j (A_sj / D) e_sj the sample's score
    L = int(block) if block is not None else max(1, int(np.ceil(10.0 * fs / fc)))
    nblk = max(1, S // L)
    scores = np.matmul((resid * w * mask)[:, None, :], Y)[:, 0, :] / D  # (S, k): Σ_j e_sj w_sj Y_sj
    sums = np.add.reduceat(scores, np.arange(0, nblk * L, L), axis=0) if nblk > 1 else scores.sum(0)[None]
    dof = S * nq / max(S * nq - V1.shape[1], 1)
    Vz = Pz @ (sums.T @ sums) @ Pz * dof
    cov = (Vz / D[:, None]) / D[None, :]
    out = _result(plant, reg, spec, pi, cov, D, V0, sigma, constrained, time.perf_counter() - t_start)
    out.rank = V1.shape[1]
    # MATLAB's fit % of the joint torques the identified inertials explain, on the estimation data
    err, tau = (y - Y @ pi) * mask, (y - (y * mask).sum(0) / np.maximum(mask.sum(0), 1)) * mask
    for j, name in enumerate(reg.joint_names):
        ratio = float(np.linalg.norm(err[:, j]) / max(np.linalg.norm(tau[:, j]), 1e-300))
        out.result.fit_percent[f"tau_{name}"] = 100.0 * (1.0 - ratio)
        out.result.nrmse[f"tau_{name}"] = ratio
    return out


_E = np.zeros((10, 4, 4))  # J(π) = Σ_i π_i E_i (pseudo_inertia is linear)
for _i in range(10):
    _e = np.zeros(10)
    _e[_i] = 1.0
    _E[_i] = pseudo_inertia(_e)


def _consistent(pi: np.ndarray, nb: int) -> bool:
    """Every body's ``J(π) ≻ 0`` and every joint parameter ``>= 0``."""
    ok = all(np.linalg.eigvalsh(pseudo_inertia(pi[10 * b : 10 * b + 10])).min() > 0 for b in range(nb))
    return ok and bool(np.all(pi[10 * nb :] >= 0))


def _barrier(
    prior: np.ndarray, scale: np.ndarray, V1: np.ndarray, lam1: np.ndarray, x_ls: np.ndarray, nb: int
) -> np.ndarray:
    r"""The physically consistent least-squares estimate by a log-det barrier (convex, SDP-free).

    Over the determined coordinates ``x`` (``π = π_prior + s ⊙ V1 x``; the held directions stay at the
    prior) it minimizes ``½ (x − x̂)ᵀ Λ (x − x̂) − μ (Σ_b log det J_b(π) + Σ_j log π_j)`` by damped Newton
    steps that keep every ``J_b ≻ 0`` and joint parameter ``> 0``, for ``μ`` from ``mean(Λ)/10`` down by tens
    to ``10⁻¹² mean(Λ)``, starting from the prior (which must be consistent; joint parameters use
    ``log(π_j + ε)``, ``ε`` = 1e-9 of their scale, so a zero prior is inside). ``−log det`` of an affine
    matrix is convex, so each stage has one minimum.
    """
    if not _consistent(prior, nb):
        raise IdentificationError("the model file's own inertials are not physically consistent: fix them first")
    B = scale[:, None] * V1  # ∂π/∂x
    k = prior.shape[0]
    eps = 1e-9 * scale[10 * nb :]  # joint parameters: the barrier log(π_j + ε) keeps a zero prior inside
    x = np.zeros(V1.shape[1])

    def barrier(pi: np.ndarray) -> tuple[float, np.ndarray, np.ndarray] | None:
        """(−Σ log det J − Σ log π_j, gradient (k,), Hessian (k, k)) in π, None outside the domain."""
        f, g, H = 0.0, np.zeros(k), np.zeros((k, k))
        for b in range(nb):
            J = pseudo_inertia(pi[10 * b : 10 * b + 10])
            try:
                L = np.linalg.cholesky(J)
            except np.linalg.LinAlgError:
                return None
            f -= 2.0 * np.log(np.diag(L)).sum()
            Ji = np.linalg.inv(J)
            M = np.einsum("ab,ibc->iac", Ji, _E)  # J⁻¹ E_i
            sl = slice(10 * b, 10 * b + 10)
            g[sl] = -np.einsum("iaa->i", M)
            H[sl, sl] = np.einsum("iab,jba->ij", M, M)
        pj = pi[10 * nb :] + eps
        if np.any(pj <= 0):
            return None
        f -= np.log(pj).sum()
        g[10 * nb :] = -1.0 / pj
        H[10 * nb :, 10 * nb :] = np.diag(1.0 / pj**2)
        return f, g, H

    mu = float(lam1.mean()) / 10.0
    stop = float(lam1.mean()) * 1e-12
    while mu > stop:
        for _ in range(50):
            pi = prior + B @ x
            fb = barrier(pi)
            assert fb is not None  # every accepted step stays inside
            f0 = 0.5 * float((x - x_ls) @ (lam1 * (x - x_ls))) + mu * fb[0]
            grad = lam1 * (x - x_ls) + mu * (B.T @ fb[1])
            hess = np.diag(lam1) + mu * (B.T @ fb[2] @ B)
            step = -np.linalg.solve(hess, grad)
            dec = -float(grad @ step)
            if dec < 1e-12 * max(abs(f0), 1.0):
                break
            t = 1.0
            while t > 1e-12:
                xn = x + t * step
                fn = barrier(prior + B @ xn)
                if fn is not None:
                    f1 = 0.5 * float((xn - x_ls) @ (lam1 * (xn - x_ls))) + mu * fn[0]
                    if f1 <= f0 - 0.25 * t * dec:
                        break
                t *= 0.5
            if t <= 1e-12:
                break
            x = xn
        mu /= 10.0
    return prior + B @ x


def _physical(pi: np.ndarray, nb: int) -> np.ndarray:
    return np.concatenate([physical_from_pi(pi[10 * b : 10 * b + 10]) for b in range(nb)] + [pi[10 * nb :]])


def _result(
    plant: MjcfPlant,
    reg: InertialRegressor,
    spec: ParamSpec,
    pi: np.ndarray,
    cov: np.ndarray,
    D: np.ndarray,
    V0: np.ndarray,
    sigma: np.ndarray,
    constrained: bool,
    elapsed: float,
) -> ModelFileIdentification:
    nb, k = len(spec.bodies), reg.k
    names = spec.physical_names(reg.body_names, reg.joint_names)
    phys, phys0 = _physical(pi, nb), _physical(reg.pi_prior, nb)
    # delta method: J = ∂φ/∂π by central differences
    J = np.zeros((k, k))
    for i in range(k):
        h = 1e-6 * max(abs(pi[i]), 1e-3)
        e = np.zeros(k)
        e[i] = h
        J[:, i] = (_physical(pi + e, nb) - _physical(pi - e, nb)) / (2 * h)
    pcov = J @ cov @ J.T
    se = np.sqrt(np.maximum(np.diag(pcov), 0.0))
    # a reported parameter that moves along an undetermined direction of π is not determined
    Vpi = V0 / D[:, None] if V0.size else np.zeros((k, 0))
    held: list[str] = []
    for i, n in enumerate(names):
        gz = J[i] / D  # gradient in the scaled coordinates
        if Vpi.shape[1] and np.linalg.norm(V0.T @ gz) > 1e-3 * max(np.linalg.norm(gz), 1e-300):
            held.append(n)
    sentences = _sentences(V0, D, reg, spec, held)
    est = {n: float(v) for n, v in zip(names, phys, strict=True)}
    pri = {n: float(v) for n, v in zip(names, phys0, strict=True)}
    std = {n: (0.0 if n in held else float(s)) for n, s in zip(names, se, strict=True)}
    interval = {n: (est[n] - 1.96 * std[n], est[n] + 1.96 * std[n]) for n in names}
    d = np.sqrt(np.maximum(np.diag(pcov), 1e-300))
    corr = pcov / np.outer(d, d)
    warnings = list(sentences)
    if constrained:
        warnings.append("the least-squares estimate was not physically consistent: the consistent one is given")
    ivals = [i for i, n in enumerate(names) if n not in held]
    for a in range(len(ivals)):
        for b in range(a + 1, len(ivals)):
            i, j = ivals[a], ivals[b]
            if abs(corr[i, j]) > 0.95:
                warnings.append(f"{names[i]} and {names[j]} are strongly correlated ({corr[i, j]:+.2f})")
    result = IdentificationResult(
        plant_type=type(plant).__name__,
        params=tuple(names),
        estimate=est,
        prior=pri,
        std_error=std,
        interval=interval,
        correlation=corr,
        unidentifiable=sentences,
        held=tuple(held),
        warnings=warnings,
        noise_std={f"tau_{reg.joint_names[j]}": float(s) for j, s in enumerate(sigma)},
        mode="inverse dynamics",
        iterations=0,
        solve_time=elapsed,
        success=True,
        dt=float(plant.dt),
    )
    bodies = {}
    for n, b in enumerate(spec.bodies):
        p = phys[10 * n : 10 * n + 10]
        bodies[reg.body_names[b]] = {"mass": float(p[0]), "ipos": p[1:4].copy(), "fullinertia": p[4:10].copy()}
    joints: dict[str, dict[str, float]] = {}
    for n, (j, attr) in enumerate(spec.joints):
        joints.setdefault(reg.joint_names[j], {})[attr] = float(pi[10 * nb + n])
    return ModelFileIdentification(
        result=result,
        pi=pi,
        pi_prior=reg.pi_prior.copy(),
        pi_cov=cov,
        pi_names=reg.pi_names,
        bodies=bodies,
        joints=joints,
        constrained=constrained,
        model_path=str(plant.model_path),
    )


_READABLE = {"m": "mass", "hx": "mass·com_x", "hy": "mass·com_y", "hz": "mass·com_z"}


def _sentences(V0: np.ndarray, D: np.ndarray, reg: InertialRegressor, spec: ParamSpec, held: list[str]) -> list[str]:
    """One sentence per undetermined direction of π, naming the parameters (physical names where possible)."""
    out = []
    for v in _sparse_basis(V0 / D[:, None]):  # in π units
        v = v / np.abs(v).max()
        big = [i for i in np.argsort(-np.abs(v)) if abs(v[i]) > 0.25]
        labels = []
        for i in big:
            body, attr = reg.pi_names[i].rsplit(".", 1)
            labels.append(f"{body}.{_READABLE.get(attr, attr + ' (about the body origin)')}")
        if len(big) == 1 and reg.pi_names[big[0]].endswith(".m") and big[0] < 10 * len(spec.bodies):
            body = reg.pi_names[big[0]][:-2]
            coms = [n for n in held if n.startswith(body + ".com_")]
            tail = f" ({', '.join(coms)} follow from it)" if coms else ""
            out.append(
                f"{body}.mass and its centre of mass enter only as their product mass·com in this experiment: "
                f"{body}.mass is held at its prior{tail}"
            )
        elif len(big) == 1:
            out.append(f"the data does not see {labels[0]} in this experiment: held at its prior")
        else:
            terms = " ".join(f"{v[i]:+.3g}·{lab}" for i, lab in zip(big, labels, strict=True))
            out.append(f"the combination {terms} is not determined in this experiment: held at its prior")
    return out


def _sparse_basis(N: np.ndarray) -> list[np.ndarray]:
    """A basis of the column space of ``N (k, r)`` in reduced row-echelon form (one pivot entry per vector, the
    fewest parameters per sentence): ``B = Nᵀ``, pivots by QR with column pivoting, ``B[:, P]⁻¹ B``."""
    if N.size == 0:
        return []
    from scipy.linalg import qr

    B = N.T
    _, _, piv = qr(B, pivoting=True, mode="economic")
    P = piv[: B.shape[0]]
    R = np.linalg.solve(B[:, P], B)
    R[np.abs(R) < 1e-6 * np.abs(R).max(axis=1, keepdims=True)] = 0.0
    return list(R)


def _scales(prior: np.ndarray, nb: int, joint_floor: np.ndarray) -> np.ndarray:
    """The parameters' own scales (module docstring): ``m``, ``m L``, ``m L²`` per body, the joint priors (at
    least ``joint_floor``)."""
    out = []
    for b in range(nb):
        p = prior[10 * b : 10 * b + 10]
        m = max(abs(float(p[0])), 1e-3)
        L = max(float(np.linalg.norm(p[1:4])) / m, 0.05)
        out.append(np.r_[m, [m * L] * 3, [m * L * L] * 6])
    out.append(np.maximum(np.abs(prior[10 * nb :]), np.maximum(joint_floor, 1e-12)))
    return np.concatenate(out)
