"""Building the condensed MPC QP once per model: prediction matrices, cost, constraint rows, buffers.

:class:`CondensedBuild` is the building half of
:class:`~shinro_ctrl.controllers.qp.condensed.CondensedQP` (a mixin reading the
sizes, model, weights and bounds its ``__init__`` validated). The module
docstring of ``qp/condensed.py`` states the math: ``X = S_x e_0 + S_v v + c``,
``U = U_x e_0 + U_v v + c_u`` around the pre-stabilizing gain ``K``, the
Hessian ``H``, the gradient map ``F`` and the rows ``ℓ − E e_0 ≤ G z ≤ h − E e_0``.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from shinro_ctrl.controllers.lqr import riccati
from shinro_ctrl.controllers.qp.sparse import RowGroup
from shinro_ctrl.errors import InvalidArgument, NotStabilizable

__all__ = [
    "INF",
    "CondensedBuild",
    "DenseRowGroup",
    "check_matrix",
    "check_vector",
    "condensed_size",
    "prestabilizing_gain",
]

_FIXED_ROW_TOL = 1e-13  # a row whose norm is below this (relative) does not depend on z
INF = 1e30  # DAQP_INF: DAQP treats |bound| >= 1e30 as absent; finite, so 0·bound stays 0 in the residuals
_INF = INF


#: A block of constraint rows of one kind at consecutive stages of ``G`` (``"input bounds"``, ``"rate bounds"``
#: or ``"state bounds"``; row indices before any row is dropped as fixed): the sparse QP's
#: :class:`~shinro_ctrl.controllers.qp.sparse.RowGroup`, so both QPs locate and explain rows with the same code.
DenseRowGroup = RowGroup


def condensed_size(n: int, m: int, N: int, *, u_rows: int, rate_rows: int, x_rows: int, soft: bool) -> int:
    """Dense matrix entries a :class:`~shinro_ctrl.controllers.qp.condensed.CondensedQP` holds.

    The quantity :data:`~shinro_ctrl.controllers.qp.condensed.MAX_DENSE_SIZE` caps.

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
        K, _ = riccati(A, B, Q, R, what="the pre-stabilizing gain")
    except NotStabilizable:
        return np.zeros((m, n))
    if np.max(np.abs(np.linalg.eigvals(A - B @ K)), initial=0.0) >= 1.0:
        return np.zeros((m, n))
    return K


def check_vector(name: str, value: Any, size: int, default: float) -> np.ndarray:
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


def check_matrix(name: str, value: Any, shape: tuple[int, int]) -> np.ndarray:
    M = np.asarray(value, dtype=float)
    if M.shape != shape:
        raise InvalidArgument(f"{name}: expected {shape} but found {M.shape}")
    if not np.all(np.isfinite(M)):
        raise InvalidArgument(f"{name} must be finite")
    return M


class CondensedBuild:
    """The building half of ``CondensedQP`` (a mixin): everything computed once per model."""

    n: int
    m: int
    N: int
    n_slack: int
    n_var: int

    def _build(self) -> None:
        """Prediction and cost matrices, constraint rows, the rows DAQP gets, per-call buffers (once)."""
        self._build_prediction()
        self._build_rows()
        self._build_kept_rows()
        self._build_buffers()

    def _build_prediction(self) -> None:
        """``S_x, S_v, c, U_x, U_v, c_u`` on ``A_cl = A − B K``, the Hessian ``H``, ``F`` and the reference maps."""
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

    def _build_rows(self) -> None:
        """The rows ``ℓ − E e_0 ≤ G z ≤ h − E e_0`` of the input, rate and state bounds, in groups."""
        n, m, N = self.n, self.m, self.N
        ns, nz = self.n_slack, self.n_var
        Ux, Uv, cu = self._Ux, self._Uv, self._cu
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
        self._state_rows(add)
        self.G = np.concatenate(Gs) if Gs else np.zeros((0, nz))
        self.E = np.concatenate(Es) if Es else np.zeros((0, n))
        self._lo = np.concatenate(los) if los else np.zeros(0)
        self._hi = np.concatenate(his) if his else np.zeros(0)
        self.groups: dict[str, DenseRowGroup] = {g.name: g for g in groups}
        self._group_list = groups

    def _state_rows(self, add: Callable[..., None]) -> None:
        """State-bound rows of stages 1..N (soft bounds: two rows per bound sharing one slack)."""
        n, N = self.n, self.N
        ns, nv, nz = self.n_slack, N * self.m, self.n_var
        Sx, Sv, c = self._Sx, self._Sv, self._c
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

    def _build_kept_rows(self) -> None:
        """Rows kept for DAQP (scaled to unit norm), fixed rows (no ``z`` dependence), the stage-0 rate rows."""
        ns = self.n_slack
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

    def _build_buffers(self) -> None:
        """Preallocated per-call buffers (bounds, gradient, KKT residual, plan)."""
        n, N = self.n, self.N
        ns, nv, nz = self.n_slack, N * self.m, self.n_var
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
