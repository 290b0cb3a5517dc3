"""Controllability and observability: ranks, the PBH test per mode, and Gramian conditioning.

* **Rank** of the reachable (observable) subspace, computed by the orthogonal
  staircase (Krylov) iteration ``span{B, AB, A²B, …}`` with re-orthogonalization,
  which stays reliable where the raw Kalman matrix ``[B, AB, …, A^{n−1}B]`` is
  too ill-conditioned to rank (e.g. Euler-discretized models with small ``dt``).
* **PBH** (Popov–Belevitch–Hautus), :func:`pbh_modes`, the one PBH test of the
  package (the LQR's stabilizability and detectability checks and the
  estimators' use it too): the eigenvalue ``λ`` of ``A`` is uncontrollable iff
  ``rank [A − λI, B] < n``, unobservable iff ``rank [A − λI; C] < n``. The
  rank is judged scale-invariantly: on the balanced pair (a diagonal state
  similarity, unit input columns, the ``B`` block scaled to the size of
  ``A − λI``), by ``σ_min`` relative to ``‖[A − λI, B]‖``, with a tolerance
  no smaller than the rounding of ``A − λI`` (``eps·‖A‖``, which dominates
  when ``A`` is close to ``λI``, e.g. ``A = I + dt·A_c`` at a tiny ``dt``).
  Eigenvalues that agree within their rounding are one mode with its
  multiplicity.
* **Gramians**: for a stable ``A`` the infinite-horizon ones,
  ``A W Aᵀ − W + B Bᵀ = 0`` (discrete) or ``A W + W Aᵀ + B Bᵀ = 0``
  (continuous); otherwise the finite-horizon ``W_N = Σ_{k<N} A^k B Bᵀ (Aᵀ)^k``
  or ``W_T = ∫_0^T e^{At} B Bᵀ e^{Aᵀt} dt``. Their condition number
  ``σ_max/σ_min`` says how unevenly the input reaches (the output sees)
  the state directions; it depends on the state units.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.linalg

from shinro_ctrl.errors import InvalidArgument, NotStabilizable
from shinro_ctrl.validation import measurement_matrix, state_space

__all__ = [
    "Mode",
    "PBHMode",
    "StructureReport",
    "check_detectable",
    "check_stabilizable",
    "gramian",
    "pbh_modes",
    "structure_report",
]

PBH_TOL = 1e-9
_EPS = float(np.finfo(float).eps)


@dataclass(frozen=True)
class PBHMode:
    """The PBH verdict on one distinct eigenvalue of ``A`` (see :func:`pbh_modes`).

    Attributes:
        eigenvalue: ``λ`` (the mean of the computed eigenvalues that form the mode).
        multiplicity: Its algebraic multiplicity.
        sigma: ``σ_min / ‖·‖`` of the balanced PBH matrix.
        tol: The tolerance it was judged by (``PBH_TOL`` or the rounding of ``A − λI``, the larger).
        vector: An eigenvector ``(n,)`` of ``A`` (for the state that dominates the mode).
        stable: ``|λ| < 1`` (discrete) or ``Re λ < 0`` (continuous), beyond rounding.
    """

    eigenvalue: complex
    multiplicity: int
    sigma: float
    tol: float
    vector: np.ndarray
    stable: bool

    @property
    def full_rank(self) -> bool:
        """The mode is reachable from ``B`` (visible through ``C``)."""
        return self.sigma > self.tol


def _balance(A: np.ndarray) -> np.ndarray:
    """The diagonal ``d (n,)`` of a balancing similarity ``D⁻¹ A D`` (powers of 2: exact).

    Balanced on the off-diagonal part (a diagonal similarity leaves the diagonal alone, and a
    diagonal near ``I``, as in ``I + dt·A_c``, would stop the balancing before it starts).
    """
    off = A - np.diag(np.diag(A))
    if A.shape[0] == 0 or not np.any(off):
        return np.ones(A.shape[0])
    _, (d, _) = scipy.linalg.matrix_balance(off, permute=False, separate=True)
    return np.asarray(d, dtype=float)


def _stable(lam: complex, discrete: bool, margin: float) -> bool:
    return bool(abs(lam) < 1.0 - margin) if discrete else bool(lam.real < -margin)


def pbh_modes(
    A: np.ndarray, M: np.ndarray, *, discrete: bool = True, dual: bool = False, tol: float = PBH_TOL
) -> tuple[PBHMode, ...]:
    """The PBH rank test of every distinct eigenvalue of ``A``: the package's one PBH test.

    ``dual=False``: controllability of ``(A, B = M (n, m))``, ``rank [A − λI, B] = n``.
    ``dual=True``: observability of ``(A, C = M (p, n))``, ``rank [A − λI; C] = n``
    (the controllability test of ``(Aᵀ, Cᵀ)``, the eigenvectors still those of ``A``).

    Scale-invariant (the verdict does not change with the state, input or
    output units, nor with ``dt`` in ``A = I + dt·A_c``): the state is
    balanced by a diagonal similarity, each input column scaled to unit norm
    and the input block to ``‖A − λI‖``; the rank is deficient when
    ``σ_min([A − λI, βB]) ≤ τ ‖[A − λI, βB]‖`` with ``τ = max(tol, 10³ n eps
    ‖A‖ / ‖[A − λI, βB]‖)`` (the rounding of ``A − λI``). Eigenvalues closer
    than their rounding (a Jordan block splits by ``√(eps ‖A‖ ‖A − λI‖)``)
    form one mode; its ``λ`` is their mean.

    Args:
        A: ``(n, n)``.
        M: ``B (n, m)`` or, with ``dual``, ``C (p, n)``.
        discrete: Stability region for :attr:`PBHMode.stable`: the unit disc or the left half-plane.
        dual: Test observability of ``(A, C)`` instead.
        tol: Smallest relative tolerance.

    Returns:
        One :class:`PBHMode` per distinct eigenvalue.
    """
    A = np.asarray(A, dtype=float)
    n = A.shape[0]
    At, Mt = (A.T, np.asarray(M, dtype=float).T) if dual else (A, np.asarray(M, dtype=float))
    d = _balance(At)
    Ab = At / d[:, None] * d[None, :]
    lam = np.linalg.eigvals(Ab)
    lam_a, V = np.linalg.eig(A)  # the mode shapes, matched to the balanced eigenvalues by value
    Bb = Mt / d[:, None]
    norms = np.linalg.norm(Bb, axis=0)
    Bb = Bb[:, norms > 0] / norms[norms > 0]
    nA = float(np.linalg.norm(Ab, 2)) if n else 0.0
    margin = 100.0 * _EPS * max(1.0, nA)
    eye = np.eye(n)
    modes: list[PBHMode] = []
    used = np.zeros(n, dtype=bool)
    for k in range(n):
        if used[k]:
            continue
        local = float(np.linalg.norm(Ab - lam[k] * eye, 2))
        close = 10.0 * math.sqrt(_EPS * max(nA, 1e-300) * max(local, 1e-300)) + 10.0 * _EPS * nA
        members = np.flatnonzero(~used & (np.abs(lam - lam[k]) <= close))
        used[members] = True
        lam_k = complex(np.mean(lam[members]))
        if abs(lam_k.imag) <= margin:
            lam_k = complex(lam_k.real, 0.0)
        Mk = Ab - lam_k * eye
        nM = float(np.linalg.norm(Mk, 2))
        beta = nM if nM > 0 else 1.0
        P = np.hstack([Mk, beta * Bb.astype(complex)])
        nP = float(np.linalg.norm(P, 2))
        if nP == 0.0:
            sigma, tau = 0.0, tol
        else:
            sv = np.linalg.svd(P, compute_uv=False)
            sigma = float(sv[n - 1]) / nP if sv.size >= n else 0.0
            tau = max(tol, 1e3 * max(n, 1) * _EPS * nA / nP)
        v = V[:, int(np.argmin(np.abs(lam_a - lam_k)))]
        modes.append(PBHMode(lam_k, int(members.size), sigma, tau, v, _stable(lam_k, discrete, margin)))
    return tuple(modes)


def _fmt_lambda(lam: complex) -> str:
    lam = complex(lam)
    return f"{lam.real:.10g}" if lam.imag == 0.0 else f"{lam.real:.10g}{lam.imag:+.6g}j"


def _where(v: np.ndarray, names: Any) -> str:
    i = int(np.argmax(np.abs(v)))
    return f"mostly state '{names[i]}'" if names is not None and i < len(names) else f"mostly state {i}"


def check_stabilizable(A: np.ndarray, B: np.ndarray, *, discrete: bool = True, names: Any = None) -> None:
    """Raise :class:`NotStabilizable` if a mode of ``A`` outside the stable region is unreachable from ``B``.

    ``(A, B)`` is stabilizable iff every eigenvalue with ``|λ| ≥ 1`` (discrete)
    or ``Re λ ≥ 0`` (continuous) passes the PBH test (:func:`pbh_modes`).

    Args:
        A: ``(n, n)``.
        B: ``(n, m)``.
        discrete: The unit disc (True) or the left half-plane as the stable region.
        names: Optional state names, used to describe the offending mode.
    """
    for mode in pbh_modes(A, B, discrete=discrete):
        if not mode.stable and not mode.full_rank:
            region = "|λ| ≥ 1" if discrete else "Re λ ≥ 0"
            raise NotStabilizable(
                f"(A, B) is not stabilizable: the mode λ = {_fmt_lambda(mode.eigenvalue)} "
                f"({_where(mode.vector, names)}) has {region} and the input cannot reach it "
                f"(PBH rank test, relative σ_min = {mode.sigma:.2e} ≤ {mode.tol:.1e})"
            )


def check_detectable(
    A: np.ndarray,
    C: np.ndarray,
    *,
    discrete: bool = True,
    names: Any = None,
    strict: bool = False,
    seen_by: str = "y = C x",
    fix: str = "measure a state that moves with it",
    pair: str = "(A, C)",
) -> None:
    """Raise :class:`NotStabilizable` naming a mode of ``A`` that ``C`` cannot see.

    Detectable (default): every mode with ``|λ| ≥ 1`` (discrete) or
    ``Re λ ≥ 0`` (continuous) passes the PBH test ``rank [A − λI; C] = n``
    (:func:`pbh_modes`); ``strict`` (pole placement) requires every mode
    to (observability). The LQR checks ``(A, Q^½)``: a mode ``Q`` does not
    weight costs nothing, so the Riccati solution leaves it where it is.

    Args:
        A: ``(n, n)``.
        C: ``(p, n)``.
        discrete: The unit disc (True) or the left half-plane as the stable region.
        names: Optional state names ``(n,)`` for the message.
        strict: Require observability instead of detectability.
        seen_by: What ``C`` is, in the message (e.g. the measured states, or ``Q``).
        fix: The remedy, in the message.
        pair: The pair's name in the message.
    """
    for mode in pbh_modes(A, C, discrete=discrete, dual=True):
        if (strict or not mode.stable) and not mode.full_rank:
            what = "observable" if strict else "detectable"
            region = "" if strict else (" with |λ| ≥ 1" if discrete else " with Re λ ≥ 0")
            raise NotStabilizable(
                f"{pair} is not {what}: the mode λ = {_fmt_lambda(mode.eigenvalue)} ({_where(mode.vector, names)})"
                f"{region} cannot be seen from {seen_by} (PBH rank test, relative σ_min = {mode.sigma:.2e} ≤ "
                f"{mode.tol:.1e}); {fix}"
            )


@dataclass(frozen=True)
class Mode:
    """One eigenvalue of ``A`` and its PBH verdicts.

    Attributes:
        eigenvalue: ``λ``.
        state: Name of the state that dominates the eigenvector.
        sigma_c: Relative smallest singular value of the balanced ``[A − λI, B]`` (see :func:`pbh_modes`).
        sigma_o: The same for ``[A − λI; C]``, None without C.
        controllable: ``sigma_c`` above its tolerance.
        observable: ``sigma_o`` above its tolerance (None without C).
        stable: ``|λ| < 1`` (discrete) or ``Re λ < 0`` (continuous).
        multiplicity: Algebraic multiplicity of ``λ``.
    """

    eigenvalue: complex
    state: str
    sigma_c: float
    sigma_o: float | None
    controllable: bool
    observable: bool | None
    stable: bool
    multiplicity: int = 1


@dataclass(frozen=True)
class StructureReport:
    """Result of :func:`structure_report`.

    Attributes:
        n: State dimension.
        controllability_rank: Dimension of the reachable subspace.
        observability_rank: Dimension of the observable subspace (None without C).
        modes: One :class:`Mode` per distinct eigenvalue.
        gramian_c_cond: Condition number of the controllability Gramian (``inf`` if singular).
        gramian_o_cond: Condition number of the observability Gramian (None without C).
        gramian_kind: ``"infinite-horizon"`` or e.g. ``"finite-horizon, 100 steps"``.
        discrete: Whether the pair is discrete.
    """

    n: int
    controllability_rank: int
    observability_rank: int | None
    modes: tuple[Mode, ...]
    gramian_c_cond: float
    gramian_o_cond: float | None
    gramian_kind: str
    discrete: bool

    @property
    def controllable(self) -> bool:
        return self.controllability_rank == self.n

    @property
    def observable(self) -> bool | None:
        return None if self.observability_rank is None else self.observability_rank == self.n

    @property
    def stabilizable(self) -> bool:
        """Every uncontrollable mode is stable."""
        return all(m.controllable or m.stable for m in self.modes)

    @property
    def uncontrollable(self) -> tuple[Mode, ...]:
        return tuple(m for m in self.modes if not m.controllable)

    @property
    def unobservable(self) -> tuple[Mode, ...]:
        return tuple(m for m in self.modes if m.observable is False)

    def format(self) -> str:
        """A few text lines."""
        obs = "" if self.observability_rank is None else f", observability rank {self.observability_rank}/{self.n}"
        lines = [f"  controllability rank {self.controllability_rank}/{self.n}{obs}"]
        oc = "" if self.gramian_o_cond is None else f", observability {_e(self.gramian_o_cond)}"
        lines.append(f"  Gramian condition ({self.gramian_kind}): controllability {_e(self.gramian_c_cond)}{oc}")
        for m in self.uncontrollable:
            lines.append(
                f"  uncontrollable mode λ = {_c(m.eigenvalue)}{_times(m)} (mostly '{m.state}', "
                f"{'stable' if m.stable else 'UNSTABLE'}, PBH σ_min = {m.sigma_c:.1e})"
            )
        for m in self.unobservable:
            lines.append(
                f"  unobservable mode λ = {_c(m.eigenvalue)}{_times(m)} (mostly '{m.state}', "
                f"{'stable' if m.stable else 'UNSTABLE'}, PBH σ_min = {m.sigma_o:.1e})"
            )
        if not self.uncontrollable and not self.unobservable:
            lines.append(
                "  PBH: every mode " + ("controllable and observable" if self.observability_rank else "controllable")
            )
        return "\n".join(lines)


def _times(m: Mode) -> str:
    return f" (×{m.multiplicity}, repeated)" if m.multiplicity > 1 else ""


def _e(v: float) -> str:
    return "inf (singular)" if math.isinf(v) else f"{v:.3g}"


def _c(z: complex) -> str:
    return f"{z.real:+.6g}" if abs(z.imag) < 1e-12 else f"{z.real:+.6g}{z.imag:+.6g}j"


def _orth(M: np.ndarray, tol: float) -> np.ndarray:
    if M.shape[1] == 0:
        return M
    U, s, _ = np.linalg.svd(M, full_matrices=False)
    return U[:, s > tol]


def reachable_rank(A: np.ndarray, B: np.ndarray, tol: float = PBH_TOL) -> int:
    """Dimension of ``span{B, AB, …, A^{n−1}B}`` by an orthogonal staircase iteration."""
    n = A.shape[0]
    scale = max(1.0, float(np.linalg.norm(np.hstack([A, B]), 2)))
    basis = _orth(B, tol * scale)
    new = basis
    while new.shape[1] and basis.shape[1] < n:
        W = A @ new
        for _ in range(2):  # classical Gram-Schmidt twice
            W = W - basis @ (basis.T @ W)
        new = _orth(W, tol * scale)
        basis = np.hstack([basis, new])
    return int(basis.shape[1])


def gramian(A: Any, B: Any, *, discrete: bool = True, horizon: float | None = None) -> tuple[np.ndarray, str]:
    """Controllability Gramian of ``(A, B)`` (pass ``(Aᵀ, Cᵀ)`` for the observability one).

    Args:
        A: ``(n, n)``.
        B: ``(n, m)``.
        discrete: Discrete (True) or continuous pair.
        horizon: Force a finite horizon: steps (discrete) or seconds
            (continuous). Default: infinite horizon when ``A`` is stable,
            else 100 steps or 1 s.

    Returns:
        ``(W (n, n), kind)`` with ``kind`` describing the horizon.
    """
    A, B = state_space(A, B)
    n = A.shape[0]
    lam = np.linalg.eigvals(A)
    stable = bool(np.all(np.abs(lam) < 1.0)) if discrete else bool(np.all(lam.real < 0.0))
    BB = B @ B.T
    if horizon is None and stable:
        if discrete:
            W = scipy.linalg.solve_discrete_lyapunov(A, BB)
        else:
            W = scipy.linalg.solve_continuous_lyapunov(A, -BB)
        return 0.5 * (W + W.T), "infinite-horizon"
    if discrete:
        N = int(horizon) if horizon is not None else 100
        if N < 1:
            raise InvalidArgument(f"horizon must be >= 1 step, got {horizon!r}")
        W = np.zeros((n, n))
        Ak = np.eye(n)
        for _ in range(N):
            AkB = Ak @ B
            W += AkB @ AkB.T
            Ak = A @ Ak
        return 0.5 * (W + W.T), f"finite-horizon, {N} steps"
    T = float(horizon) if horizon is not None else 1.0
    if not (math.isfinite(T) and T > 0):
        raise InvalidArgument(f"horizon must be a positive number of seconds, got {horizon!r}")
    # Van Loan: expm([[-A, BBᵀ], [0, Aᵀ]] T) = [[·, F12], [0, F22]], W_T = F22ᵀ F12.
    M = np.zeros((2 * n, 2 * n))
    M[:n, :n] = -A
    M[:n, n:] = BB
    M[n:, n:] = A.T
    E = scipy.linalg.expm(M * T)
    W = E[n:, n:].T @ E[:n, n:]
    return 0.5 * (W + W.T), f"finite-horizon, {T:g} s"


def _cond(W: np.ndarray) -> float:
    s = np.linalg.svd(W, compute_uv=False)
    return math.inf if s[-1] <= 1e-300 or s[-1] <= 1e-14 * s[0] else float(s[0] / s[-1])


def structure_report(
    A: Any,
    B: Any,
    C: Any = None,
    *,
    discrete: bool = True,
    state_names: Any = None,
    horizon: float | None = None,
    tol: float = PBH_TOL,
) -> StructureReport:
    """Controllability and observability of ``(A, B, C)``.

    Args:
        A: ``(n, n)``.
        B: ``(n, m)``.
        C: ``(p, n)`` output matrix, or None to skip observability.
        discrete: Discrete (True: stable means |λ| < 1) or continuous pair.
        state_names: Names ``(n,)`` for the dominant state of each mode (default ``x[i]``).
        horizon: Gramian horizon for an unstable ``A`` (see :func:`gramian`).
        tol: Relative rank tolerance.

    Returns:
        A :class:`StructureReport`.

    Raises:
        InvalidArgument: wrong shapes.
    """
    A, B = state_space(A, B)
    n = A.shape[0]
    names = [f"x[{i}]" for i in range(n)] if state_names is None else [str(s) for s in state_names]
    if len(names) != n:
        raise InvalidArgument(f"state_names: expected {n} names but found {len(names)}")
    if C is not None:
        C = measurement_matrix(C, n)
    # PBH is a test per distinct eigenvalue (a Jordan block or a repeated root is one mode, with its multiplicity)
    ctrl = pbh_modes(A, B, discrete=discrete, tol=tol)
    obs = (None,) * len(ctrl) if C is None else pbh_modes(A, C, discrete=discrete, dual=True, tol=tol)
    if len(obs) != len(ctrl):  # the same eigenvalues, grouped the same way (the grouping depends on A alone)
        obs = tuple(min(obs, key=lambda o, c=c: abs(o.eigenvalue - c.eigenvalue)) for c in ctrl)
    modes = [
        Mode(
            c.eigenvalue,
            names[int(np.argmax(np.abs(c.vector)))],
            c.sigma,
            None if o is None else o.sigma,
            c.full_rank,
            None if o is None else o.full_rank,
            c.stable,
            c.multiplicity,
        )
        for c, o in zip(ctrl, obs, strict=True)
    ]
    Wc, kind = gramian(A, B, discrete=discrete, horizon=horizon)
    rank_o = cond_o = None
    if C is not None:
        rank_o = reachable_rank(A.T, C.T, tol)
        Wo, _ = gramian(A.T, C.T, discrete=discrete, horizon=horizon)
        cond_o = _cond(Wo)
    return StructureReport(n, reachable_rank(A, B, tol), rank_o, tuple(modes), _cond(Wc), cond_o, kind, bool(discrete))
