"""Controllability and observability: ranks, the PBH test per mode, and Gramian conditioning.

* **Rank** of the reachable (observable) subspace, computed by the orthogonal
  staircase (Krylov) iteration ``span{B, AB, A²B, …}`` with re-orthogonalization,
  which stays reliable where the raw Kalman matrix ``[B, AB, …, A^{n−1}B]`` is
  too ill-conditioned to rank (e.g. Euler-discretized models with small ``dt``).
* **PBH** (Popov–Belevitch–Hautus): the eigenvalue ``λ`` of ``A`` is
  uncontrollable iff ``rank [A − λI, B] < n``, unobservable iff
  ``rank [A − λI; C] < n``. Judged by the smallest singular value relative
  to ``max(1, ‖[A, B]‖)``.
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

from shinro_ctrl.errors import InvalidArgument
from shinro_ctrl.validation import measurement_matrix, state_space

__all__ = ["Mode", "StructureReport", "gramian", "structure_report"]

PBH_TOL = 1e-9


@dataclass(frozen=True)
class Mode:
    """One eigenvalue of ``A`` and its PBH verdicts.

    Attributes:
        eigenvalue: ``λ``.
        state: Name of the state that dominates the eigenvector.
        sigma_c: Smallest singular value of ``[A − λI, B]`` (relative to ``‖[A, B]‖``).
        sigma_o: Smallest singular value of ``[A − λI; C]`` (relative), None without C.
        controllable: ``sigma_c > tol``.
        observable: ``sigma_o > tol`` (None without C).
        stable: ``|λ| < 1`` (discrete) or ``Re λ < 0`` (continuous).
    """

    eigenvalue: complex
    state: str
    sigma_c: float
    sigma_o: float | None
    controllable: bool
    observable: bool | None
    stable: bool


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
                f"  uncontrollable mode λ = {_c(m.eigenvalue)} (mostly '{m.state}', "
                f"{'stable' if m.stable else 'UNSTABLE'}, PBH σ_min = {m.sigma_c:.1e})"
            )
        for m in self.unobservable:
            lines.append(
                f"  unobservable mode λ = {_c(m.eigenvalue)} (mostly '{m.state}', "
                f"{'stable' if m.stable else 'UNSTABLE'}, PBH σ_min = {m.sigma_o:.1e})"
            )
        if not self.uncontrollable and not self.unobservable:
            lines.append(
                "  PBH: every mode " + ("controllable and observable" if self.observability_rank else "controllable")
            )
        return "\n".join(lines)


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


def _pbh(A: np.ndarray, M: np.ndarray, lam: complex, scale: float) -> float:
    n = A.shape[0]
    stack = np.hstack([A - lam * np.eye(n), M.astype(complex)])
    return float(np.linalg.svd(stack, compute_uv=False)[-1]) / scale


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
    scale_c = max(1.0, float(np.linalg.norm(np.hstack([A, B]), 2)))
    scale_o = None if C is None else max(1.0, float(np.linalg.norm(np.vstack([A, C]), 2)))
    lam, V = np.linalg.eig(A)
    modes = []
    seen: list[complex] = []
    for k, l in enumerate(lam):
        if any(abs(l - v) <= 1e-9 * max(1.0, abs(v)) for v in seen):
            continue  # PBH is a test per distinct eigenvalue (a Jordan block or a repeated root counts once)
        seen.append(complex(l))
        sc = _pbh(A, B, l, scale_c)
        so = None if C is None else _pbh(A.T, C.T, np.conj(l), scale_o)
        stable = abs(l) < 1.0 if discrete else l.real < 0.0
        modes.append(
            Mode(
                complex(l),
                names[int(np.argmax(np.abs(V[:, k])))],
                sc,
                so,
                sc > tol,
                None if so is None else so > tol,
                bool(stable),
            )
        )
    Wc, kind = gramian(A, B, discrete=discrete, horizon=horizon)
    rank_o = cond_o = None
    if C is not None:
        rank_o = reachable_rank(A.T, C.T, tol)
        Wo, _ = gramian(A.T, C.T, discrete=discrete, horizon=horizon)
        cond_o = _cond(Wo)
    return StructureReport(n, reachable_rank(A, B, tol), rank_o, tuple(modes), _cond(Wc), cond_o, kind, bool(discrete))
