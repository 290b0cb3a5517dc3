"""Building the condensed MPC QP once per model: prediction matrices, cost, constraint rows.

:func:`build_condensed` computes everything of
:class:`~shinro_ctrl.controllers.qp.condensed.CondensedQP` that depends on the
model, weights and bounds only, and returns it as one :class:`CondensedMatrices`
(the solver object then owns its per-call buffers). The module docstring of
``qp/condensed.py`` states the math: ``X = S_x e_0 + S_v v + c``,
``U = U_x e_0 + U_v v + c_u`` around the pre-stabilizing gain ``K``, the
Hessian ``H``, the gradient map ``F`` and the rows ``ℓ − E e_0 ≤ G z ≤ h − E e_0``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from shinro_ctrl.controllers.lqr import riccati
from shinro_ctrl.controllers.qp.options import MPCOptions
from shinro_ctrl.controllers.qp.sparse import RowGroup
from shinro_ctrl.errors import InvalidArgument, NotStabilizable

__all__ = [
    "INF",
    "CondensedMatrices",
    "DenseRowGroup",
    "build_condensed",
    "check_matrix",
    "condensed_size",
    "prestabilizing_gain",
]

_FIXED_ROW_TOL = 1e-13  # a row whose norm is below this (relative) does not depend on z
INF = 1e30  # DAQP_INF: DAQP treats |bound| >= 1e30 as absent; finite, so 0·bound stays 0 in the residuals


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


def check_matrix(name: str, value: object, shape: tuple[int, int]) -> np.ndarray:
    """``value`` as a finite float array of ``shape``, else :class:`InvalidArgument` naming ``name``."""
    M = np.asarray(value, dtype=float)
    if M.shape != shape:
        raise InvalidArgument(f"{name}: expected {shape} but found {M.shape}")
    if not np.all(np.isfinite(M)):
        raise InvalidArgument(f"{name} must be finite")
    return M


@dataclass(frozen=True, eq=False)
class CondensedMatrices:
    """Everything of the condensed QP that depends on the model, weights and bounds only (built once).

    Attributes:
        H: Hessian ``(nz, nz)`` (slacks first).
        F: ``∂f/∂e_0`` ``(nz, n)``; ``Fv`` its rows of ``v`` (contiguous).
        cond_H: Condition number of the ``v`` block of ``H``.
        Sx, Sv, c: State predictions ``X = Sx e0 + Sv v + c`` (stacked ``(N + 1) n``).
        Ux, Uv, cu: Input predictions ``U = Ux e0 + Uv v + cu`` (stacked ``N m``).
        QSv, QSx, RUx: ``Q̄ Sv``, ``Q̄ Sx``, ``R̄ Ux`` (reference and constant terms).
        Grho_const: ``(nv, n)``: the gradient of a constant state reference.
        Gnu: ``(nv, m)``: the gradient of an input reference.
        f_d: The gradient of the offset ``d`` on ``v``.
        W: ``const(e0) = ½ e0ᵀ W e0 + …``.
        G, E, lo, hi: All constraint rows ``lo − E e0 ≤ G z ≤ hi − E e0`` (unscaled, fixed rows included).
        groups: The row groups of ``G``, in row order.
        rate0: Rows of the stage-0 rate bounds in ``G`` (None without rate bounds).
        kept, fixed: Rows that depend on ``z`` (given to DAQP) and rows that do not.
        Gk, Ek, lo_k, hi_k: The kept rows scaled to unit norm.
        Ef2, bf2: The fixed rows as one-sided rows ``[E; −E] e0 ≤ [h; −ℓ]`` (a small tolerance added).
        rate0_k, rate0_scale: Positions of the stage-0 rate rows among DAQP's rows (after the slacks), their scales.
        HG: ``[H, Gkᵀ]`` for the KKT residual.
        PM, pc: The plan ``(X, U) = PM (e0, v) + pc`` in absolute units.
    """

    H: np.ndarray
    F: np.ndarray
    Fv: np.ndarray
    cond_H: float
    Sx: np.ndarray
    Sv: np.ndarray
    c: np.ndarray
    Ux: np.ndarray
    Uv: np.ndarray
    cu: np.ndarray
    QSv: np.ndarray
    QSx: np.ndarray
    RUx: np.ndarray
    Grho_const: np.ndarray
    Gnu: np.ndarray
    f_d: np.ndarray
    W: np.ndarray
    G: np.ndarray
    E: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    groups: tuple[RowGroup, ...]
    rate0: slice | None
    kept: np.ndarray
    fixed: np.ndarray
    Gk: np.ndarray
    Ek: np.ndarray
    lo_k: np.ndarray
    hi_k: np.ndarray
    Ef2: np.ndarray
    bf2: np.ndarray
    rate0_k: np.ndarray | None
    rate0_scale: np.ndarray | None
    HG: np.ndarray
    PM: np.ndarray
    pc: np.ndarray


def build_condensed(
    A: np.ndarray,
    B: np.ndarray,
    Q: np.ndarray,
    R: np.ndarray,
    Qf: np.ndarray,
    N: int,
    K: np.ndarray,
    opts: MPCOptions,
    bounded: tuple[np.ndarray, np.ndarray, np.ndarray],
) -> CondensedMatrices:
    """Prediction and cost matrices, constraint rows and the rows DAQP gets (once per model).

    Args:
        A, B, Q, R, Qf: Model and weights.
        N: Horizon.
        K: Pre-stabilizing gain ``(m, n)``.
        opts: Resolved options (bounds, operating point, offset, soft weights, names).
        bounded: Indices of the bounded inputs, rate-bounded inputs and bounded states.
    """
    n, m = B.shape
    ub, rb, xb = bounded
    ns = N * xb.size if opts.soft else 0
    p = _prediction(A, B, Q, R, Qf, N, K, opts.offset, opts.soft_weight_quad, ns)
    G, E, lo, hi, groups, rate0 = _rows(p, n, m, N, ns, ub, rb, xb, opts)
    # rows kept for DAQP (scaled to unit norm), fixed rows (no z dependence), the stage-0 rate rows
    norms = np.linalg.norm(G, axis=1)
    scale_ref = max(float(norms.max(initial=0.0)), 1.0)
    fixed_mask = norms <= _FIXED_ROW_TOL * scale_ref
    kept, fixed = np.flatnonzero(~fixed_mask), np.flatnonzero(fixed_mask)
    inv = 1.0 / norms[kept]
    Gk = np.ascontiguousarray(G[kept] * inv[:, None])
    Ef = E[fixed]
    rate0_k = rate0_scale = None
    if rate0 is not None:
        pos = np.searchsorted(kept, np.arange(rate0.start, rate0.stop))
        rate0_k, rate0_scale = pos + ns, inv[pos]
    x0, u0 = opts.x0, opts.u0
    return CondensedMatrices(
        H=p["H"],
        F=p["F"],
        Fv=np.ascontiguousarray(p["F"][ns:]),
        cond_H=p["cond_H"],
        Sx=p["Sx"],
        Sv=p["Sv"],
        c=p["c"],
        Ux=p["Ux"],
        Uv=p["Uv"],
        cu=p["cu"],
        QSv=p["QSv"],
        QSx=p["QSx"],
        RUx=p["RUx"],
        Grho_const=p["Grho_const"],
        Gnu=p["Gnu"],
        f_d=p["f_d"],
        W=p["W"],
        G=G,
        E=E,
        lo=lo,
        hi=hi,
        groups=tuple(groups),
        rate0=rate0,
        kept=kept,
        fixed=fixed,
        Gk=Gk,
        Ek=np.ascontiguousarray(E[kept] * inv[:, None]),
        lo_k=np.clip(lo[kept] * inv, -INF, INF),
        hi_k=np.clip(hi[kept] * inv, -INF, INF),
        Ef2=np.ascontiguousarray(np.vstack([Ef, -Ef])),
        bf2=np.concatenate([hi[fixed], -lo[fixed]]) + 1e-9,
        rate0_k=rate0_k,
        rate0_scale=rate0_scale,
        HG=np.ascontiguousarray(np.hstack([p["H"], Gk.T])),
        PM=np.ascontiguousarray(np.block([[p["Sx"], p["Sv"]], [p["Ux"], p["Uv"]]])),
        pc=np.concatenate([p["c"] + np.tile(x0, N + 1), p["cu"] + np.tile(u0, N)]),
    )


def _prediction(
    A: np.ndarray,
    B: np.ndarray,
    Q: np.ndarray,
    R: np.ndarray,
    Qf: np.ndarray,
    N: int,
    K: np.ndarray,
    offset: np.ndarray,
    w2: float,
    ns: int,
) -> dict[str, np.ndarray | float]:
    """``S_x, S_v, c, U_x, U_v, c_u`` on ``A_cl = A − B K``, the Hessian ``H``, ``F`` and the reference maps."""
    n, m = B.shape
    nv = N * m
    nz = ns + nv
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
    if np.any(offset != 0):
        for k in range(N):
            c[k + 1] = Acl @ c[k] + offset
    c = c.ravel()
    # K̄ = I_N ⊗ K applied block by block: (K̄ M)_k = K M_k
    Ux = -(K @ Sx[: N * n].reshape(N, n, n)).reshape(nv, n)
    Uv = np.eye(nv) - (K @ Sv[: N * n].reshape(N, n, nv)).reshape(nv, nv)
    cu = -(c[: N * n].reshape(N, n) @ K.T).ravel()
    # weighted blocks: QS = Q̄ S (stage weight Q for k < N, Qf at N), RU = R̄ U
    Sv3 = Sv.reshape(N + 1, n, nv)
    QSv = np.empty_like(Sv3)
    np.matmul(Q, Sv3[:N], out=QSv[:N])
    QSv[N] = Qf @ Sv3[N]
    QSv = QSv.reshape((N + 1) * n, nv)
    Sx3 = Sx.reshape(N + 1, n, n)
    QSx = np.empty_like(Sx3)
    np.matmul(Q, Sx3[:N], out=QSx[:N])
    QSx[N] = Qf @ Sx3[N]
    QSx = QSx.reshape((N + 1) * n, n)
    RUv = (R @ Uv.reshape(N, m, nv)).reshape(nv, nv)
    RUx = (R @ Ux.reshape(N, m, n)).reshape(nv, n)
    Hv = Sv.T @ QSv + Uv.T @ RUv
    Hv = 0.5 * (Hv + Hv.T)
    H = np.zeros((nz, nz))
    H[ns:, ns:] = Hv
    if ns:
        H[np.arange(ns), np.arange(ns)] = w2
    F = np.zeros((nz, n))
    F[ns:] = QSv.T @ Sx + RUv.T @ Ux
    return {
        "H": H,
        "F": F,
        "cond_H": float(np.linalg.cond(Hv)),
        "Sx": Sx,
        "Sv": Sv,
        "c": c,
        "Ux": Ux,
        "Uv": Uv,
        "cu": cu,
        "QSv": QSv,
        "QSx": QSx,
        "RUx": RUx,
        # reference maps (on v): f_ρ = -QSvᵀ vec(ρ), f_ν = -RUvᵀ (1 ⊗ ν); offset term f_d
        "Grho_const": -QSv.reshape(N + 1, n, nv).sum(axis=0).T,  # (nv, n): constant ρ
        "Gnu": -RUv.reshape(N, m, nv).sum(axis=0).T,  # (nv, m)
        "f_d": QSv.T @ c + RUv.T @ cu,
        "W": Sx.T @ QSx + Ux.T @ RUx,  # const(e0) = ½ e0ᵀ W e0 + wᵀ e0 + c0
    }


def _rows(
    p: dict,
    n: int,
    m: int,
    N: int,
    ns: int,
    ui: np.ndarray,
    ri: np.ndarray,
    xi: np.ndarray,
    opts: MPCOptions,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, list[RowGroup], slice | None]:
    """The rows ``ℓ − E e_0 ≤ G z ≤ h − E e_0`` of the input, rate and state bounds, in groups."""
    nv = N * m
    nz = ns + nv
    Sx, Sv, c, Ux, Uv, cu = p["Sx"], p["Sv"], p["c"], p["Ux"], p["Uv"], p["cu"]
    u_min, u_max, u0 = opts.u_min, opts.u_max, opts.u0
    names_u, names_x = opts.input_names, opts.state_names
    Gs: list[np.ndarray] = []
    Es: list[np.ndarray] = []
    los: list[np.ndarray] = []
    his: list[np.ndarray] = []
    groups: list[RowGroup] = []
    r0 = 0

    def add(name: str, G: np.ndarray, E: np.ndarray, lo: np.ndarray, hi: np.ndarray, width: int, first: int,
            labels: list[str]) -> None:  # fmt: skip
        nonlocal r0
        Gs.append(G)
        Es.append(E)
        los.append(lo)
        his.append(hi)
        groups.append(RowGroup(name, r0, width, first, G.shape[0] // width, tuple(labels)))
        r0 += G.shape[0]

    if ui.size:
        idx = (np.arange(N)[:, None] * m + ui[None, :]).ravel()
        G = np.zeros((idx.size, nz))
        G[:, ns:] = Uv[idx]
        lo = np.tile(u_min[ui] - u0[ui], N) - cu[idx]
        hi = np.tile(u_max[ui] - u0[ui], N) - cu[idx]
        labels = [f"{names_u[i]} in [{u_min[i]:g}, {u_max[i]:g}]" for i in ui]
        add("input bounds", G, Ux[idx], lo, hi, ui.size, 0, labels)
    rate0: slice | None = None
    if ri.size:
        du_max = opts.du_max
        idx = (np.arange(N)[:, None] * m + ri[None, :]).ravel()
        G = np.zeros((idx.size, nz))
        G[:, ns:] = Uv[idx]
        E = Ux[idx].copy()
        cc = cu[idx].copy()
        r = ri.size
        G[r:, ns:] -= Uv[idx[:-r]]
        E[r:] -= Ux[idx[:-r]]
        cc[r:] -= cu[idx[:-r]]
        dm = np.tile(du_max[ri], N)
        labels = [f"|Δ{names_u[i]}| <= {du_max[i]:g}" for i in ri]
        rate0 = slice(r0, r0 + r)
        add("rate bounds", G, E, -dm - cc, dm - cc, r, 0, labels)
    if xi.size:  # state bounds of stages 1..N (soft bounds: two rows per bound sharing one slack)
        x_min, x_max, x0 = opts.x_min, opts.x_max, opts.x0
        w = xi.size
        idx = (np.arange(1, N + 1)[:, None] * n + xi[None, :]).ravel()
        xlo = np.tile(x_min[xi] - x0[xi], N) - c[idx]
        xhi = np.tile(x_max[xi] - x0[xi], N) - c[idx]
        if not opts.soft:
            G = np.zeros((idx.size, nz))
            G[:, ns:] = Sv[idx]
            labels = [f"{names_x[i]} in [{x_min[i]:g}, {x_max[i]:g}]" for i in xi]
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
            lab_hi = [f"{names_x[i]} <= {x_max[i]:g}" for i in xi]
            lab_lo = [f"{names_x[i]} >= {x_min[i]:g}" for i in xi]
            add("state bounds", G.reshape(-1, nz), E.reshape(-1, n), lo.ravel(), hi.ravel(), 2 * w, 1,
                lab_hi + lab_lo)  # fmt: skip
    G = np.concatenate(Gs) if Gs else np.zeros((0, nz))
    E = np.concatenate(Es) if Es else np.zeros((0, n))
    lo = np.concatenate(los) if los else np.zeros(0)
    hi = np.concatenate(his) if his else np.zeros(0)
    return G, E, lo, hi, groups, rate0
