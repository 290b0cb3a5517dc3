r"""The condensed (input-only) MPC QP around a pre-stabilizing feedback, solved by DAQP.

The model and the cost are those of :class:`~shinro_ctrl.controllers.mpc.LinearMPC`
in deviation variables ``e_k = x_k − x_op``, ``δu_k = u_k − u_op``:

.. math::

    e_{k+1} = A e_k + B\,\delta u_k + d, \qquad
    J = \tfrac12 \sum_{k=0}^{N-1} \big[\lVert e_k - \rho_k \rVert_Q^2 + \lVert \delta u_k - \nu \rVert_R^2\big]
        + \tfrac12 \lVert e_N - \rho_N \rVert_{P_f}^2 + \sum_{k=1}^{N} \big(w_1 \mathbf 1^\top s_k
        + \tfrac{w_2}{2} \lVert s_k \rVert^2\big).

**Pre-stabilization.** The inputs are written around a stabilizing feedback,
``δu_k = −K e_k + v_k`` with ``K`` the LQR gain of the DARE of the same
``(A, B, Q, R)``, so the predictions run on ``A_cl = A − B K``:

.. math::

    X = S_x e_0 + S_v v + c, \qquad U = U_x e_0 + U_v v + c_u,

with ``X = (e_0 … e_N)``, ``U = (δu_0 … δu_{N−1})``, block ``(k, j)`` of ``S_v``
equal to ``A_cl^{k−1−j} B`` (``j < k``), ``S_x = (A_cl^k)_k``, ``c_k =
Σ_{j<k} A_cl^{k−1−j} d``, ``U_x = −K̄ S_x``, ``U_v = I − K̄ S_v``, ``c_u = −K̄ c``
(``K̄ = I_N ⊗ K``, first ``N`` blocks). Since ``A_cl`` is stable the powers
decay and the Hessian stays well conditioned at any horizon; with the DARE's
terminal cost (``P_f = P``) it is exactly ``I_N ⊗ (R + BᵀPB)`` — the cost is
``e_0ᵀ P e_0 + Σ v_kᵀ (R + BᵀPB) v_k`` — and the unconstrained optimum is
``v = 0``, the LQR input. (Plain condensing in ``u`` reaches cond(H) ≈ 6e9 at
``N = 100`` on the cart-pole.)

**The QP.** With the decision vector ``z = (s, v)`` (slacks first: DAQP
treats the first entries of its bound vectors as simple bounds, here ``s ≥ 0``)

.. math::

    \min_z \tfrac12 z^\top H z + (F e_0 + f_r)^\top z \quad\text{s.t.}\quad
    \ell - E e_0 \le G z \le h - E e_0, \quad s \ge 0,

``H = blkdiag(w_2 I, S_vᵀ Q̄ S_v + U_vᵀ R̄ U_v)``, ``F`` and ``f_r`` (reference
and offset terms) the matching gradient blocks, and one row of ``G`` per
bounded input and stage (``U_v`` rows), per rate bound and stage (differences
of ``U_v`` rows; the first stage's bounds move with the previously applied
input), per bounded state and stage ``k = 1..N`` (``S_v`` rows; with soft
bounds two rows, ``e − s ≤ h`` and ``e + s ≥ ℓ``, sharing one slack, as in the
sparse formulation). Rows are scaled to unit norm. Rows that do not depend on
``z`` (a state the inputs cannot move yet, e.g. a position one Euler step
ahead) are kept out of the QP and checked directly.

Everything above is built once per model. A call computes ``e_0``, ``F e_0``,
``E e_0`` into preallocated buffers, hands them to one :class:`daqp.Model`
(workspace, Cholesky factor of ``H`` and ``G H^{-1/2}`` kept; the working set
of the previous solve is the warm start) and solves. DAQP's dual active-set
method returns the exact optimum of the QP (up to rounding) or an
infeasibility flag; :meth:`CondensedQP.explain_infeasibility` then names the
constraint group and stage from an elastic LP's Farkas certificate.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import daqp
import numpy as np
import scipy.linalg
import scipy.optimize

from shinro_ctrl.errors import InvalidArgument

__all__ = [
    "DAQP_STATUS",
    "DEFAULT_DAQP_SETTINGS",
    "MAX_DENSE_SIZE",
    "CondensedQP",
    "DenseQP",
    "DenseRowGroup",
    "DenseSolveInfo",
    "condensed_size",
    "prestabilizing_gain",
]

#: DAQP's exit flags (``daqp/include/constants.h``).
DAQP_STATUS: dict[int, str] = {
    2: "solved (soft optimal)",
    1: "solved",
    -1: "primal infeasible",
    -2: "cycling",
    -3: "unbounded",
    -4: "iteration limit",
    -5: "nonconvex",
    -6: "overdetermined initial active set",
    -7: "time limit",
    -8: "unsupported",
}

#: DAQP settings for an exact solve of a strictly convex QP: no proximal
#: regularization (``eps_prox = 0``; ``H`` is positive definite), a primal
#: tolerance of 1e-9 on unit-norm rows (DAQP's default 1e-6 lets a bound be
#: exceeded by that much without entering the active set, which moves the
#: optimum by as much). Overridable through ``settings``.
DEFAULT_DAQP_SETTINGS: dict[str, Any] = {
    "primal_tol": 1e-9,
    "dual_tol": 1e-12,
    "eps_prox": 0.0,
    "iter_limit": 10_000,
}

#: Largest dense problem :class:`CondensedQP` builds: entries of the prediction
#: matrices (``S_v``) plus the Hessian and the constraint rows (80 bytes per
#: 10 entries; 10 million is 80 MB). Larger problems belong to the sparse path.
MAX_DENSE_SIZE = 10_000_000

_FIXED_ROW_TOL = 1e-13  # a row whose norm is below this (relative) does not depend on z
_INF = 1e30  # DAQP_INF: DAQP treats |bound| >= 1e30 as absent; finite, so 0·bound stays 0 in the residuals

#: Matrix-vector products on the per-call path with more entries than this use a plain loop
#: (``einsum``) instead of BLAS: multithreaded OpenBLAS gemv on a busy machine stalled calls
#: for ~50 ms at N = 400 (threads waiting for cores), while one thread needs ~0.3 ms.
_BLAS_MAX = 1 << 17


def _mv(M: np.ndarray, v: np.ndarray, out: np.ndarray) -> np.ndarray:
    """``out = M @ v`` on one thread (BLAS for small ``M``, an einsum loop for large)."""
    if M.size > _BLAS_MAX:
        return np.einsum("ij,j->i", M, v, out=out)
    return np.matmul(M, v, out=out)


@dataclass(frozen=True)
class DenseRowGroup:
    """A block of constraint rows of one kind at consecutive stages.

    Row ``start + (k − first_stage)·width + j`` holds component ``labels[j]``
    at stage ``k`` (indices into :attr:`CondensedQP.G`'s rows, before any row
    is dropped as fixed).

    Attributes:
        name: ``"input bounds"``, ``"rate bounds"`` or ``"state bounds"``.
        start: First row.
        width: Rows per stage.
        first_stage: Stage of the first block.
        stages: Number of stages.
        labels: Meaning of each row within a stage (length ``width``).
    """

    name: str
    start: int
    width: int
    first_stage: int
    stages: int
    labels: tuple[str, ...]

    @property
    def stop(self) -> int:
        """One past the last row."""
        return self.start + self.width * self.stages

    def locate(self, row: int) -> tuple[int, str]:
        """The ``(stage, label)`` of a row inside this group."""
        k, j = divmod(row - self.start, self.width)
        return self.first_stage + k, self.labels[j]


@dataclass(frozen=True)
class DenseSolveInfo:
    """What one :meth:`CondensedQP.solve` did.

    Attributes:
        status: :data:`DAQP_STATUS` name of the exit flag (``"solved"`` …).
        exitflag: DAQP's exit flag (1 optimal; < 0 failure).
        iterations: Active-set iterations.
        active_set_size: Number of constraints active at the returned point
            (nonzero multipliers), simple slack bounds included.
        kkt_residual: Largest of the stationarity residual
            ``‖H z + f + Gᵀλ‖∞``, the largest bound violation and the largest
            complementarity product ``|λ_i (b_i − g_iᵀ z)|`` (rows of unit
            norm); NaN when not solved.
        solve_time_s: DAQP's own solve time [s].
        objective: MPC cost ``J`` at the solution (the constant terms in
            ``e_0`` and the references included); NaN when not solved.
    """

    status: str
    exitflag: int
    iterations: int
    active_set_size: int
    kkt_residual: float
    solve_time_s: float
    objective: float

    @property
    def solved(self) -> bool:
        """True for an optimal exit."""
        return self.exitflag in (1, 2)


@dataclass(frozen=True)
class DenseQP:
    """The condensed QP of one state: ``min ½ zᵀHz + fᵀz  s.t.  lower ≤ A z ≤ upper``.

    ``A`` stacks the slack rows (an identity block, ``s ≥ 0``) over the
    constraint rows of :attr:`CondensedQP.G` (unscaled, fixed rows included,
    as their own rows of zeros); the constant ``const`` completes the MPC cost
    ``J = ½ zᵀHz + fᵀz + const``.

    Attributes:
        H: Hessian ``(nz, nz)``.
        f: Linear cost ``(nz,)``.
        A: Constraint rows ``(ns + rows, nz)``.
        lower: Lower bounds (``-inf`` where none).
        upper: Upper bounds (``inf`` where none).
        const: Constant cost term.
    """

    H: np.ndarray
    f: np.ndarray
    A: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    const: float


def condensed_size(n: int, m: int, N: int, *, u_rows: int, rate_rows: int, x_rows: int, soft: bool) -> int:
    """Dense matrix entries a :class:`CondensedQP` holds (the quantity :data:`MAX_DENSE_SIZE` caps).

    Args:
        n, m, N: States, inputs, horizon.
        u_rows: Bounded inputs per stage.
        rate_rows: Rate-bounded inputs per stage.
        x_rows: Bounded states per stage.
        soft: Soft state bounds (one slack and two rows per bounded state and stage).
    """
    ns = N * x_rows if soft else 0
    nv = N * m
    rows = N * (u_rows + rate_rows + x_rows * (2 if soft else 1))
    return (N + 1) * n * nv + (ns + nv) ** 2 + rows * (ns + nv + n)


def prestabilizing_gain(A: np.ndarray, B: np.ndarray, Q: np.ndarray, R: np.ndarray) -> np.ndarray:
    """The LQR gain ``K = (R + BᵀPB)⁻¹ BᵀPA`` of the DARE of ``(A, B, Q, R)``, or zeros.

    Args:
        A: State matrix ``(n, n)``.
        B: Input matrix ``(n, m)``.
        Q: State weight ``(n, n)``, symmetric PSD.
        R: Input weight ``(m, m)``, symmetric positive definite.

    Returns:
        ``K`` ``(m, n)``; zeros when the DARE has no stabilizing solution
        (plain condensing then, well conditioned only for stable ``A``).
    """
    n, m = B.shape
    try:
        P = scipy.linalg.solve_discrete_are(A, B, Q, R)
    except (np.linalg.LinAlgError, ValueError):
        return np.zeros((m, n))
    if not np.all(np.isfinite(P)):
        return np.zeros((m, n))
    P = 0.5 * (P + P.T)
    BtP = B.T @ P
    K = np.linalg.solve(R + BtP @ B, BtP @ A)
    if np.max(np.abs(np.linalg.eigvals(A - B @ K)), initial=0.0) >= 1.0:
        return np.zeros((m, n))
    return K


def _vec(name: str, value: Any, size: int, default: float) -> np.ndarray:
    if value is None:
        return np.full(size, default)
    v = np.asarray(value, dtype=float)
    if v.ndim == 0:
        v = np.full(size, float(v))
    if v.shape != (size,):
        raise InvalidArgument(f"{name}: expected ({size},) but found {v.shape}")
    if np.any(np.isnan(v)):
        raise InvalidArgument(f"{name} must not contain NaN")
    return v


def _mat(name: str, value: Any, shape: tuple[int, int]) -> np.ndarray:
    M = np.asarray(value, dtype=float)
    if M.shape != shape:
        raise InvalidArgument(f"{name}: expected {shape} but found {M.shape}")
    if not np.all(np.isfinite(M)):
        raise InvalidArgument(f"{name} must be finite")
    return M


def _fmt(v: np.ndarray) -> str:
    return np.array2string(np.asarray(v), precision=4, suppress_small=True)


def _stages(stages: list[int]) -> str:
    """``[0, 1, 2, 5]`` -> ``"0-2, 5"``."""
    out: list[str] = []
    start = prev = stages[0]
    for s in [*stages[1:], None]:
        if s is not None and s == prev + 1:
            prev = s
            continue
        out.append(f"{start}" if start == prev else f"{start}-{prev}")
        if s is not None:
            start = prev = s
    return ", ".join(out)


class CondensedQP:
    r"""The condensed MPC QP of one linear model, built once and solved per state by DAQP.

    Args:
        A: Discrete state matrix ``(n, n)``.
        B: Discrete input matrix ``(n, m)``.
        Q: Stage state weight ``(n, n)``, symmetric PSD.
        R: Stage input weight ``(m, m)``, symmetric positive definite.
        P_f: Terminal weight ``(n, n)``, symmetric PSD.
        horizon: ``N >= 1``.
        K: Pre-stabilizing gain ``(m, n)``; default :func:`prestabilizing_gain`
            of ``(A, B, Q, R)``.
        x_op: Operating-point state ``(n,)`` [absolute]; default zeros.
        u_op: Operating-point input ``(m,)``; default zeros.
        offset: Affine model term ``d`` ``(n,)``; default zeros.
        u_min, u_max: Input bounds ``(m,)`` [absolute], ±inf where none.
        x_min, x_max: State bounds ``(n,)`` on ``x_1 … x_N`` [absolute].
        du_max: Rate bounds ``(m,)`` (``|u_k − u_{k−1}| ≤ du_max``, ``u_{−1}``
            the ``u_prev`` passed to :meth:`solve`), or None.
        soft: Soft state bounds (one slack per bounded state and stage).
        soft_weight_l1: ``w_1 ≥ 0``.
        soft_weight_quad: ``w_2 > 0``.
        state_names, input_names: For the row labels.
        settings: Overrides of :data:`DEFAULT_DAQP_SETTINGS` (any key DAQP's
            ``Model.settings`` knows).

    Attributes:
        n, m, N: Sizes.
        K: The pre-stabilizing gain ``(m, n)``.
        H: Hessian ``(nz, nz)`` (slacks first).
        F: ``∂f/∂e_0`` ``(nz, n)``.
        G: Constraint rows ``(rows, nz)`` (unscaled; fixed rows included).
        E: ``(rows, n)``: the bounds of row ``r`` are ``ℓ_r − E_r e_0``, ``h_r − E_r e_0``.
        groups: The :class:`DenseRowGroup` blocks of ``G``, by name.
        n_var: ``nz`` (slacks + ``N m``).
        n_slack: Number of slacks ``ns``.
        z: The latest solution ``(nz,)`` (DAQP's array; None before a solve).
        lam: Its multipliers ``(ns + rows kept,)`` (scaled rows).

    Raises:
        InvalidArgument: wrong shapes, NaN bounds, a problem larger than
            :data:`MAX_DENSE_SIZE`, DAQP rejecting the set-up or a setting.
    """

    def __init__(
        self,
        A: Any,
        B: Any,
        Q: Any,
        R: Any,
        P_f: Any,
        horizon: int,
        *,
        K: Any = None,
        x_op: Any = None,
        u_op: Any = None,
        offset: Any = None,
        u_min: Any = None,
        u_max: Any = None,
        x_min: Any = None,
        x_max: Any = None,
        du_max: Any = None,
        soft: bool = False,
        soft_weight_l1: float = 1e2,
        soft_weight_quad: float = 1e2,
        state_names: Any = None,
        input_names: Any = None,
        settings: dict[str, Any] | None = None,
    ):
        B_ = np.asarray(B, dtype=float)
        if B_.ndim != 2:
            raise InvalidArgument(f"B: expected (n, m) but found {B_.shape}")
        n, m = B_.shape
        N = int(horizon)
        if N < 1:
            raise InvalidArgument(f"horizon must be >= 1, got {horizon!r}")
        self.n, self.m, self.N = n, m, N
        self.A = _mat("A", A, (n, n))
        self.B = _mat("B", B_, (n, m))
        self.Q = _mat("Q", Q, (n, n))
        self.R = _mat("R", R, (m, m))
        self.P_f = _mat("P_f", P_f, (n, n))
        self.K = prestabilizing_gain(self.A, self.B, self.Q, self.R) if K is None else _mat("K", K, (m, n))
        self.x_op = _vec("x_op", x_op, n, 0.0)
        self.u_op = _vec("u_op", u_op, m, 0.0)
        self.offset = _vec("offset", offset, n, 0.0)
        self.u_min, self.u_max = _vec("u_min", u_min, m, -np.inf), _vec("u_max", u_max, m, np.inf)
        self.x_min, self.x_max = _vec("x_min", x_min, n, -np.inf), _vec("x_max", x_max, n, np.inf)
        self.du_max = None if du_max is None else _vec("du_max", du_max, m, np.inf)
        self.soft = bool(soft)
        self.w1, self.w2 = float(soft_weight_l1), float(soft_weight_quad)
        if self.soft and not (self.w2 > 0 and math.isfinite(self.w2) and self.w1 >= 0 and math.isfinite(self.w1)):
            raise InvalidArgument(f"soft weights must be w1 >= 0, w2 > 0 and finite, got {self.w1!r}, {self.w2!r}")
        self.state_names = tuple(state_names) if state_names is not None else tuple(f"x[{i}]" for i in range(n))
        self.input_names = tuple(input_names) if input_names is not None else tuple(f"u[{i}]" for i in range(m))

        self._xb = np.flatnonzero(np.isfinite(self.x_min) | np.isfinite(self.x_max))
        self._ub = np.flatnonzero(np.isfinite(self.u_min) | np.isfinite(self.u_max))
        self._rb = np.zeros(0, dtype=int) if self.du_max is None else np.flatnonzero(np.isfinite(self.du_max))
        w = self._xb.size
        ns = N * w if self.soft else 0
        nv = N * m
        rows = N * self._ub.size + N * self._rb.size + N * w * (2 if self.soft else 1)
        size = condensed_size(n, m, N, u_rows=self._ub.size, rate_rows=self._rb.size, x_rows=w, soft=self.soft)
        if size > MAX_DENSE_SIZE:
            raise InvalidArgument(
                f"horizon {N} makes the condensed QP too large: {size:,} dense matrix entries "
                f"(n = {n}, m = {m}, {rows} constraint rows); the limit is {MAX_DENSE_SIZE:,}. "
                "Use the sparse OSQP path (solver='osqp') or a shorter horizon"
            )
        self.n_slack, self.n_var = ns, ns + nv
        self._settings = dict(DEFAULT_DAQP_SETTINGS)
        if settings:
            self._settings.update(settings)
        self._build()
        self._setup()
        self.set_reference()

    # ============================================================ building
    def _build(self) -> None:
        n, m, N = self.n, self.m, self.N
        A, B, K = self.A, self.B, self.K
        ns, nv, nz = self.n_slack, N * m, self.n_var
        Acl = A - B @ K
        # powers: Apow[k] = Acl^k (k = 0..N), AB[p] = Acl^p B
        Apow = np.empty((N + 1, n, n))
        Apow[0] = np.eye(n)
        for k in range(N):
            Apow[k + 1] = Acl @ Apow[k]
        AB = Apow[:N] @ B
        Sx = Apow.reshape((N + 1) * n, n)
        Sv = np.zeros(((N + 1) * n, nv))
        Sv4 = Sv.reshape(N + 1, n, N, m)
        for p in range(N):
            j = np.arange(N - p)
            Sv4[j + 1 + p, :, j, :] = AB[p]
        c = np.zeros((N + 1, n))
        if np.any(self.offset != 0):
            for k in range(N):
                c[k + 1] = Acl @ c[k] + self.offset
        c = c.ravel()
        # K̄ = I_N ⊗ K applied block by block: (K̄ M)_k = K M_k
        Ux = -(K @ Sx[: N * n].reshape(N, n, n)).reshape(nv, n)
        Uv = np.eye(nv) - (K @ Sv[: N * n].reshape(N, n, nv)).reshape(nv, nv)
        cu = -(c[: N * n].reshape(N, n) @ K.T).ravel()
        # weighted blocks: QS = Q̄ S (stage weight Q for k < N, P_f at N), RU = R̄ U
        Sv3 = Sv.reshape(N + 1, n, nv)
        QSv = np.empty_like(Sv3)
        np.matmul(self.Q, Sv3[:N], out=QSv[:N])
        QSv[N] = self.P_f @ Sv3[N]
        QSv = QSv.reshape((N + 1) * n, nv)
        Sx3 = Sx.reshape(N + 1, n, n)
        QSx = np.empty_like(Sx3)
        np.matmul(self.Q, Sx3[:N], out=QSx[:N])
        QSx[N] = self.P_f @ Sx3[N]
        QSx = QSx.reshape((N + 1) * n, n)
        RUv = (self.R @ Uv.reshape(N, m, nv)).reshape(nv, nv)
        RUx = (self.R @ Ux.reshape(N, m, n)).reshape(nv, n)
        Hv = Sv.T @ QSv + Uv.T @ RUv
        Hv = 0.5 * (Hv + Hv.T)
        H = np.zeros((nz, nz))
        H[ns:, ns:] = Hv
        if ns:
            H[np.arange(ns), np.arange(ns)] = self.w2
        F = np.zeros((nz, n))
        F[ns:] = QSv.T @ Sx + RUv.T @ Ux
        self.H, self.F = H, F
        self._Fv = np.ascontiguousarray(F[ns:])
        self.cond_H = float(np.linalg.cond(Hv))
        # reference maps (on v): f_ρ = -QSvᵀ vec(ρ), f_ν = -RUvᵀ (1 ⊗ ν); offset term f_d
        self._QSv, self._RUv, self._QSx, self._RUx = QSv, RUv, QSx, RUx
        self._Sx, self._Sv, self._Ux, self._Uv, self._c, self._cu = Sx, Sv, Ux, Uv, c, cu
        self._Grho_const = -QSv.reshape(N + 1, n, nv).sum(axis=0).T  # (nv, n): constant ρ
        self._Gnu = -RUv.reshape(N, m, nv).sum(axis=0).T  # (nv, m)
        self._f_d = QSv.T @ c + RUv.T @ cu
        self._W = Sx.T @ QSx + Ux.T @ RUx  # const(e0) = ½ e0ᵀ W e0 + wᵀ e0 + c0

        # ---- constraint rows
        Gs: list[np.ndarray] = []
        Es: list[np.ndarray] = []
        los: list[np.ndarray] = []
        his: list[np.ndarray] = []
        groups: list[DenseRowGroup] = []
        r0 = 0

        def add(name: str, G: np.ndarray, E: np.ndarray, lo: np.ndarray, hi: np.ndarray, width: int, first: int,
                labels: list[str]) -> None:  # fmt: skip
            nonlocal r0
            Gs.append(G)
            Es.append(E)
            los.append(lo)
            his.append(hi)
            groups.append(DenseRowGroup(name, r0, width, first, G.shape[0] // width, tuple(labels)))
            r0 += G.shape[0]

        ui = self._ub
        if ui.size:
            idx = (np.arange(N)[:, None] * m + ui[None, :]).ravel()
            G = np.zeros((idx.size, nz))
            G[:, ns:] = Uv[idx]
            lo = np.tile(self.u_min[ui] - self.u_op[ui], N) - cu[idx]
            hi = np.tile(self.u_max[ui] - self.u_op[ui], N) - cu[idx]
            labels = [f"{self.input_names[i]} in [{self.u_min[i]:g}, {self.u_max[i]:g}]" for i in ui]
            add("input bounds", G, Ux[idx], lo, hi, ui.size, 0, labels)
        ri = self._rb
        self._rate0: slice | None = None
        if ri.size:
            assert self.du_max is not None
            idx = (np.arange(N)[:, None] * m + ri[None, :]).ravel()
            G = np.zeros((idx.size, nz))
            G[:, ns:] = Uv[idx]
            E = Ux[idx].copy()
            cc = cu[idx].copy()
            r = ri.size
            G[r:, ns:] -= Uv[idx[:-r]]
            E[r:] -= Ux[idx[:-r]]
            cc[r:] -= cu[idx[:-r]]
            dm = np.tile(self.du_max[ri], N)
            labels = [f"|Δ{self.input_names[i]}| <= {self.du_max[i]:g}" for i in ri]
            self._rate0 = slice(r0, r0 + r)
            add("rate bounds", G, E, -dm - cc, dm - cc, r, 0, labels)
        xi = self._xb
        if xi.size:
            w = xi.size
            idx = (np.arange(1, N + 1)[:, None] * n + xi[None, :]).ravel()
            xlo = np.tile(self.x_min[xi] - self.x_op[xi], N) - c[idx]
            xhi = np.tile(self.x_max[xi] - self.x_op[xi], N) - c[idx]
            if not self.soft:
                G = np.zeros((idx.size, nz))
                G[:, ns:] = Sv[idx]
                labels = [f"{self.state_names[i]} in [{self.x_min[i]:g}, {self.x_max[i]:g}]" for i in xi]
                add("state bounds", G, Sx[idx], xlo, xhi, w, 1, labels)
            else:
                # per stage: w rows e - s <= hi, then w rows e + s >= lo (slack (k-1)·w + j)
                G = np.zeros((N, 2, w, nz))
                G[:, 0, :, ns:] = Sv[idx].reshape(N, w, nv)
                G[:, 1, :, ns:] = G[:, 0, :, ns:]
                s_idx = np.arange(ns).reshape(N, w)
                kk, jj = np.meshgrid(np.arange(N), np.arange(w), indexing="ij")
                G[kk, 0, jj, s_idx] = -1.0
                G[kk, 1, jj, s_idx] = 1.0
                E = np.repeat(Sx[idx].reshape(N, 1, w, n), 2, axis=1)
                lo = np.stack([np.full((N, w), -np.inf), xlo.reshape(N, w)], axis=1)
                hi = np.stack([xhi.reshape(N, w), np.full((N, w), np.inf)], axis=1)
                lab_hi = [f"{self.state_names[i]} <= {self.x_max[i]:g}" for i in xi]
                lab_lo = [f"{self.state_names[i]} >= {self.x_min[i]:g}" for i in xi]
                add("state bounds", G.reshape(-1, nz), E.reshape(-1, n), lo.ravel(), hi.ravel(), 2 * w, 1,
                    lab_hi + lab_lo)  # fmt: skip
        self.G = np.concatenate(Gs) if Gs else np.zeros((0, nz))
        self.E = np.concatenate(Es) if Es else np.zeros((0, n))
        self._lo = np.concatenate(los) if los else np.zeros(0)
        self._hi = np.concatenate(his) if his else np.zeros(0)
        self.groups: dict[str, DenseRowGroup] = {g.name: g for g in groups}
        self._group_list = groups

        # ---- rows kept for DAQP (scaled to unit norm) and fixed rows (no z dependence)
        norms = np.linalg.norm(self.G, axis=1)
        scale_ref = max(float(norms.max(initial=0.0)), 1.0)
        fixed = norms <= _FIXED_ROW_TOL * scale_ref
        self._kept = np.flatnonzero(~fixed)
        self._fixed = np.flatnonzero(fixed)
        inv = 1.0 / norms[self._kept]
        self._row_scale = inv
        self._Gk = np.ascontiguousarray(self.G[self._kept] * inv[:, None])
        self._Ek = np.ascontiguousarray(self.E[self._kept] * inv[:, None])
        self._lo_k = np.clip(self._lo[self._kept] * inv, -_INF, _INF)
        self._hi_k = np.clip(self._hi[self._kept] * inv, -_INF, _INF)
        # fixed rows as one-sided rows [E; -E] e0 <= [h; -l]
        Ef = self.E[self._fixed]
        self._Ef2 = np.ascontiguousarray(np.vstack([Ef, -Ef]))
        self._bf2 = np.concatenate([self._hi[self._fixed], -self._lo[self._fixed]]) + 1e-9
        # rate rows of stage 0 inside the kept rows (their bounds follow u_prev)
        self._rate0_k: np.ndarray | None = None
        if self._rate0 is not None:
            pos = np.searchsorted(self._kept, np.arange(self._rate0.start, self._rate0.stop))
            self._rate0_k = pos + ns
            self._rate0_scale = inv[pos]
            self._rate0_comp = self._rb

        # ---- per-call buffers
        mk = self._kept.size
        self._mtot = ns + mk
        self._e0 = np.zeros(n)
        self._f = np.zeros(nz)
        self._f[:ns] = self.w1
        self._fv = self._f[ns:]
        self._fr = np.zeros(nv)  # reference + offset part of f on v
        self._bu = np.empty(self._mtot)
        self._bl = np.empty(self._mtot)
        self._bu[:ns] = _INF
        self._bl[:ns] = 0.0
        self._bu_g = self._bu[ns:]
        self._bl_g = self._bl[ns:]
        self._tmp = np.empty(mk)
        self._tmp_f = np.empty(2 * self._fixed.size)
        self._fviol = np.empty(2 * self._fixed.size, dtype=bool)
        # KKT residual: [H, Gᵀ] (z, λ_G) in one product
        self._HG = np.ascontiguousarray(np.hstack([self.H, self._Gk.T]))
        self._zl = np.zeros(nz + mk)
        self._rb_buf = np.zeros(nz + 3 * mk + 2 * ns)
        self._gz = np.empty(mk)
        self._lp = np.empty(mk)
        # plan: (X, U) = [[Sx, Sv], [Ux, Uv]] (e0, v) + const (absolute units)
        self._PM = np.ascontiguousarray(np.block([[self._Sx, self._Sv], [self._Ux, self._Uv]]))
        self._pc = np.concatenate([self._c + np.tile(self.x_op, N + 1), self._cu + np.tile(self.u_op, N)])
        self._ev = np.zeros(n + nv)
        self._nX = (N + 1) * n
        self.X: np.ndarray | None = None
        self.U: np.ndarray | None = None
        self._sense0 = np.zeros(self._mtot, dtype=np.intc)
        self.z: np.ndarray | None = None
        self.lam: np.ndarray | None = None
        self._w_lin = np.zeros(n)
        self._c0 = 0.0

    def _setup(self) -> None:
        # A throwaway state-independent set-up (bounds at e0 = 0, no u_prev); every solve updates them.
        self._fill(np.zeros(self.n), None)
        self._model = daqp.Model()
        self._model.settings = self._settings
        bad = [k for k in self._settings if k not in self._model.settings]
        if bad:
            raise InvalidArgument(f"unknown DAQP setting '{bad[0]}'; valid settings: {', '.join(self._model.settings)}")
        flag, _ = self._model.setup(self.H, self._f, self._Gk, self._bu, self._bl, self._sense0.copy())
        if flag < 0:
            raise InvalidArgument(f"DAQP rejected the condensed MPC problem (setup exit flag {flag})")
        self._model.settings = self._settings
        self._fresh = True

    # ============================================================ per call
    def set_reference(self, ref: np.ndarray | None = None, u_ref: np.ndarray | None = None) -> None:
        """Set the references (absolute units) the next solves track; ``None`` = the operating point.

        Args:
            ref: State reference ``(n,)`` or trajectory ``(N + 1, n)``.
            u_ref: Input reference ``(m,)``.
        """
        n, m, N = self.n, self.m, self.N
        fr = self._f_d.copy()
        rho = np.zeros((N + 1) * n)
        if ref is not None:
            r = np.asarray(ref, dtype=float)
            if r.shape == (n,):
                fr += self._Grho_const @ (r - self.x_op)
                rho = np.tile(r - self.x_op, N + 1)
            else:
                rho = (r.reshape(N + 1, n) - self.x_op).ravel()
                fr -= self._QSv.T @ rho
        nu = np.zeros(N * m)
        if u_ref is not None:
            nu1 = np.asarray(u_ref, dtype=float) - self.u_op
            fr += self._Gnu @ nu1
            nu = np.tile(nu1, N)
        self._fr[:] = fr
        # const(e0) = ½‖Sx e0 + c − ρ‖²_Q̄ + ½‖Ux e0 + c_u − ν̄‖²_R̄ = ½ e0ᵀWe0 + wᵀe0 + c0
        dx = self._c - rho
        du = self._cu - nu
        self._w_lin = self._QSx.T @ dx + self._RUx.T @ du
        Qb_dx = dx.reshape(N + 1, n).copy()
        Qb_dx[:N] = Qb_dx[:N] @ self.Q.T
        Qb_dx[N] = self.P_f @ Qb_dx[N]
        Rb_du = (du.reshape(N, m) @ self.R.T).ravel()
        self._c0 = 0.5 * (float(dx @ Qb_dx.ravel()) + float(du @ Rb_du))

    def _fill(self, e0: np.ndarray, u_prev_dev: np.ndarray | None) -> None:
        """Write ``f`` and the bound vectors for ``e0`` (and the previous input) into the buffers."""
        _mv(self._Fv, e0, self._fv)
        np.add(self._fv, self._fr, out=self._fv)
        _mv(self._Ek, e0, self._tmp)
        np.subtract(self._hi_k, self._tmp, out=self._bu_g)
        np.subtract(self._lo_k, self._tmp, out=self._bl_g)
        if self._rate0_k is not None:
            ix = self._rate0_k
            if u_prev_dev is None:
                self._bu[ix] = _INF
                self._bl[ix] = -_INF
            else:
                shift = u_prev_dev[self._rate0_comp] * self._rate0_scale
                self._bu[ix] += shift
                self._bl[ix] += shift

    def solve(self, x: np.ndarray, u_prev: np.ndarray | None = None) -> DenseSolveInfo:
        """Solve the QP for the measured state ``x`` (absolute, finite, ``(n,)``).

        Args:
            x: Measured state ``(n,)``.
            u_prev: Previously applied input ``(m,)`` [absolute] for the rate
                bounds of the first move; None = no rate bound on it.

        Returns:
            A :class:`DenseSolveInfo`. On success :attr:`z`, :attr:`lam` and
            the plan :attr:`X` ``(N + 1, n)``, :attr:`U` ``(N, m)`` (absolute
            units, new arrays) hold the solution; on failure they are None.
        """
        e0 = self._e0
        np.subtract(x, self.x_op, out=e0)
        self._fill(e0, None if u_prev is None else u_prev - self.u_op)
        self.z = self.lam = self.X = self.U = None
        if self._fixed.size:
            _mv(self._Ef2, e0, self._tmp_f)
            if np.greater(self._tmp_f, self._bf2, out=self._fviol).any():
                return DenseSolveInfo(DAQP_STATUS[-1], -1, 0, 0, math.nan, 0.0, math.nan)
        model = self._model
        if self._mtot:
            model.update(f=self._f, bupper=self._bu, blower=self._bl)
        else:
            model.update(f=self._f)
        z, fval, flag, info = model.solve()
        if flag < 0 and not self._fresh:
            # a warm start from a failed or distant working set can stall: retry once from scratch
            self.reset()
            model.update(f=self._f, bupper=self._bu, blower=self._bl)
            z, fval, flag, info = model.solve()
        self._fresh = flag < 0
        if flag != 1 and flag != 2:
            return DenseSolveInfo(DAQP_STATUS.get(flag, f"exit flag {flag}"), flag, info["iterations"],
                                  0, math.nan, info["solve_time"], math.nan)  # fmt: skip
        lam = info["lam"]
        self.z, self.lam = z, lam
        ev = self._ev
        ev[: self.n] = e0
        ev[self.n :] = z[self.n_slack :]
        XU = _mv(self._PM, ev, np.empty(self._PM.shape[0]))
        XU += self._pc
        self.X = XU[: self._nX].reshape(self.N + 1, self.n)
        self.U = XU[self._nX :].reshape(self.N, self.m)
        objective = fval + 0.5 * float(e0 @ self._W @ e0) + float(self._w_lin @ e0) + self._c0
        return DenseSolveInfo(
            DAQP_STATUS[flag],
            flag,
            info["iterations"],
            int(np.count_nonzero(lam)),
            self.kkt_residual(),
            info["solve_time"],
            objective,
        )

    def kkt_residual(self) -> float:
        """KKT residual of the latest solution (see :class:`DenseSolveInfo`); NaN without one.

        One buffer holds every term that must vanish or be <= 0 at an exact
        optimum (``|Hz + f + Gᵀλ|``, ``g_iᵀz − h_i``, ``ℓ_i − g_iᵀz``, the
        complementarity products ``λ⁺_i (h_i − g_iᵀz) + λ⁻_i (ℓ_i − g_iᵀz)``,
        ``−s``, ``−λ_s s``); the residual is its largest entry (at least 0).
        """
        z, lam = self.z, self.lam
        if z is None or lam is None:
            return math.nan
        ns, nz, mk = self.n_slack, self.n_var, self._kept.size
        zl, rb = self._zl, self._rb_buf
        zl[:nz] = z
        zl[nz:] = lam[ns:]
        stat = rb[:nz]
        _mv(self._HG, zl, stat)
        stat += self._f
        if ns:
            stat[:ns] += lam[:ns]
        np.abs(stat, out=stat)
        if mk:
            gz, lp = self._gz, self._lp
            t1 = rb[nz : nz + mk]
            t2 = rb[nz + mk : nz + 2 * mk]
            comp = rb[nz + 2 * mk : nz + 3 * mk]
            lg = zl[nz:]
            _mv(self._Gk, z, gz)
            np.subtract(gz, self._bu_g, out=t1)
            np.subtract(self._bl_g, gz, out=t2)
            np.maximum(lg, 0.0, out=lp)
            np.multiply(lp, t1, out=comp)  # λ⁺ (g z − h) <= 0
            np.minimum(lg, 0.0, out=lp)
            np.multiply(lp, t2, out=lp)  # λ⁻ (ℓ − g z) >= 0
            np.subtract(lp, comp, out=comp)
        if ns:
            sl = rb[nz + 3 * mk :]
            np.negative(z[:ns], out=sl[:ns])
            np.multiply(lam[:ns], sl[:ns], out=sl[ns:])
        return float(rb.max(initial=0.0))

    def first_input(self, out: np.ndarray) -> np.ndarray:
        """Write ``u_0`` (absolute, unclipped) of the latest solution into ``out`` ``(m,)``."""
        assert self.U is not None
        out[:] = self.U[0]
        return out

    def plan(self) -> tuple[np.ndarray, np.ndarray, float]:
        """States ``(N + 1, n)`` and inputs ``(N, m)`` [absolute] of the latest solution, and the largest slack."""
        assert self.z is not None and self.X is not None and self.U is not None
        ns = self.n_slack
        return self.X, self.U, float(self.z[:ns].max()) if ns else 0.0

    def reset(self) -> None:
        """Forget the working set (the next solve starts cold)."""
        if self._mtot:
            self._model.update(sense=self._sense0.copy())
        self._fresh = True

    def problem(self, x: Any, u_prev: Any = None) -> DenseQP:
        """The condensed QP for state ``x`` (fresh arrays, unscaled rows; nothing is solved)."""
        e0 = np.asarray(x, dtype=float) - self.x_op
        ns, nz = self.n_slack, self.n_var
        f = np.empty(nz)
        f[:ns] = self.w1
        f[ns:] = self.F[ns:] @ e0 + self._fr
        Ee = self.E @ e0
        lo, hi = self._lo - Ee, self._hi - Ee
        if self._rate0 is not None:
            sl = self._rate0
            if u_prev is None:
                lo[sl], hi[sl] = -np.inf, np.inf
            else:
                d = (np.asarray(u_prev, dtype=float) - self.u_op)[self._rb]
                lo[sl] += d
                hi[sl] += d
        Aall = np.vstack([np.eye(ns, nz), self.G])
        lower = np.concatenate([np.zeros(ns), lo])
        upper = np.concatenate([np.full(ns, np.inf), hi])
        const = 0.5 * float(e0 @ self._W @ e0) + float(self._w_lin @ e0) + self._c0
        return DenseQP(self.H.copy(), f, Aall, lower, upper, const)

    # ======================================================== infeasibility
    def explain_infeasibility(self, x: Any, u_prev: Any = None) -> str | None:
        """Name the constraint group and stage that make the QP at ``x`` infeasible.

        Solves the elastic LP ``min Σ t  s.t.  ℓ − t ≤ G z ≤ h + t, s ≥ 0, t ≥ 0``
        (HiGHS). A positive optimum certifies infeasibility, and its
        multipliers ``y`` (``Gᵀ y = 0`` on the free variables) are a Farkas
        certificate: the rows with ``y ≠ 0`` cannot hold together. The stage
        named is the first one where the culprit group (state, then rate,
        then input bounds) enters the certificate.

        Returns:
            The explanation, or None when the LP finds the problem feasible
            (no certificate: the failure was numerical).
        """
        qp = self.problem(x, u_prev)
        ns = self.n_slack
        G = qp.A[ns:]
        lo, hi = qp.lower[ns:], qp.upper[ns:]
        norms = np.linalg.norm(G, axis=1)
        scale = np.where(norms > 0, norms, 1.0)
        Gs, los, his = G / scale[:, None], lo / scale, hi / scale
        up = np.flatnonzero(np.isfinite(his))
        dn = np.flatnonzero(np.isfinite(los))
        nz, nu_, nd = self.n_var, up.size, dn.size
        # variables [z, t_up, t_dn]; rows  G z - t <= h,  -G z - t <= -l
        A_ub = np.zeros((nu_ + nd, nz + nu_ + nd))
        A_ub[:nu_, :nz] = Gs[up]
        A_ub[:nu_, nz : nz + nu_] = -np.eye(nu_)
        A_ub[nu_:, :nz] = -Gs[dn]
        A_ub[nu_:, nz + nu_ :] = -np.eye(nd)
        b_ub = np.concatenate([his[up], -los[dn]])
        cost = np.concatenate([np.zeros(nz), np.ones(nu_ + nd)])
        bounds = [(0, None)] * ns + [(None, None)] * (nz - ns) + [(0, None)] * (nu_ + nd)
        res = scipy.optimize.linprog(cost, A_ub=A_ub, b_ub=b_ub, bounds=bounds, method="highs")
        if res.status != 0 or res.fun <= 1e-9:
            return None
        y = np.zeros(G.shape[0])
        marg = -np.asarray(res.ineqlin.marginals)
        y[up] += marg[:nu_]
        y[dn] += marg[nu_:]
        return self._explain(y)

    def _explain(self, weight: np.ndarray) -> str:
        peak = float(np.max(np.abs(weight)))
        involved: dict[str, list[int]] = {}
        first: dict[str, int] = {}
        for g in self._group_list:
            seg = np.abs(weight[g.start : g.stop])
            gmax = float(seg.max(initial=0.0))
            if gmax <= 1e-9 * peak:
                continue
            hits = np.flatnonzero(seg > 1e-3 * gmax)
            involved[g.name] = sorted({g.first_stage + int(h) // g.width for h in hits})
            first[g.name] = g.start + int(hits[0])
        culprit = next((nm for nm in ("state bounds", "rate bounds", "input bounds") if nm in first), None)
        if culprit is None:  # pragma: no cover - a certificate always has a row
            return "the infeasibility certificate is empty"
        k, label = self.groups[culprit].locate(first[culprit])
        others = [f"{nm} at stages {_stages(s)}" for nm, s in involved.items() if nm != culprit]
        return (
            f"{culprit} at stage {k} ({label}) cannot be met from this state under the dynamics"
            f" (conflict over stages {_stages(involved[culprit])})"
            + (" together with the " + "; ".join(others) if others else "")
        )

    def describe(self) -> str:
        """One line: sizes, conditioning and the rows kept."""
        return (
            f"condensed QP (DAQP): {self.n_var} variables ({self.n_slack} slacks), {self.G.shape[0]} rows "
            f"({self._fixed.size} fixed), cond(H_v) = {self.cond_H:.3g}"
        )
