r"""The sparse MPC QP: stacking, row groups and warm-start shift maps.

With ``δx = x − x0``, ``δu = u − u0`` the decision vector is
``z = [δx_0 … δx_N, δu_0 … δu_{N-1}, s_1 … s_N]`` (slacks only with soft
state bounds) and the QP is OSQP's ``min ½ zᵀ P z + qᵀ z  s.t.  l ≤ A z ≤ u``
with ``P = blkdiag(Q, …, Q, Qf, R, …, R, w_2 I)``, ``q`` holding ``w_1`` on
the slacks, and ``A`` stacking one block of rows per :class:`RowGroup`:

.. math::

    \delta x_0 &= x - x_0                                   &&\text{(initial state)}\\
    \delta x_{k+1} &= A \delta x_k + B \delta u_k + d         &&\text{(dynamics)}\\
    u_{min} - u_0 &\le \delta u_k \le u_{max} - u_0          &&\text{(input bounds)}\\
    -\Delta &\le \delta u_k - \delta u_{k-1} \le \Delta       &&\text{(rate bounds)}\\
    x_{min} - x_0 - s_k &\le \delta x_k \le x_{max} - x_0 + s_k &&\text{(state bounds)}\\
    s_k &\ge 0                                              &&\text{(slack bounds)}

:func:`build_sparse` assembles it once from dense blocks (CSC, indices
sorted) and returns a :class:`SparseQP` with the index maps the controller
needs: where ``x``, ``u`` and the slacks sit in ``z``, the row groups, and the
permutations that shift a solution one stage for the next warm start.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np
import scipy.sparse as sp

if TYPE_CHECKING:
    from shinro_ctrl.controllers.qp.options import MPCOptions

__all__ = [
    "INF",
    "MAX_QP_SIZE",
    "QP",
    "RowGroup",
    "SparseQP",
    "build_sparse",
    "fill_linear_cost",
    "fill_rate_rows",
    "qp_size",
]

INF = 1e30  # OSQP_INFTY: what OSQP treats as an absent bound

#: Largest QP :class:`~shinro_ctrl.controllers.mpc.LinearMPC` builds: decision
#: variables, and nonzeros of ``P`` and ``A_con`` together. Two million
#: nonzeros already take OSQP about a gigabyte (factorization fill-in included)
#: and seconds per solve; a horizon beyond this is almost always a typo
#: (``10**8`` used to exhaust the memory and get the process killed).
MAX_QP_SIZE = 2_000_000


class QP(NamedTuple):
    """The QP ``min ½ zᵀ P z + qᵀ z  s.t.  l ≤ A z ≤ u`` in OSQP's form.

    Attributes:
        P: Upper-triangular cost Hessian, CSC ``(n_var, n_var)``.
        q: Linear cost ``(n_var,)``.
        A: Constraint matrix, CSC ``(n_con, n_var)``.
        l: Lower bounds ``(n_con,)`` (±1e30 stands for ±inf).
        u: Upper bounds ``(n_con,)``.
    """

    P: sp.csc_matrix
    q: np.ndarray
    A: sp.csc_matrix
    l: np.ndarray
    u: np.ndarray


@dataclass(frozen=True)
class RowGroup:
    """A block of constraint rows with the same meaning at consecutive stages.

    Rows ``start + (k - first_stage) * width + j`` hold component ``labels[j]``
    of the group at stage ``k``.

    Attributes:
        name: ``"initial state"``, ``"dynamics"``, ``"input bounds"``,
            ``"rate bounds"``, ``"state bounds"`` or ``"slack bounds"``.
        start: First row.
        width: Rows per stage.
        first_stage: Stage of the first block.
        stages: Number of stages.
        labels: Description of each row within a stage (length ``width``).
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


@dataclass
class SparseQP:
    """The assembled sparse QP and its index maps (built once by :func:`build_sparse`).

    Attributes:
        P: Upper-triangular cost Hessian, CSC ``(n_var, n_var)``.
        A: Constraint matrix, CSC ``(n_con, n_var)``.
        q: Default linear cost ``(n_var,)`` (``w_1`` on the slacks, zero elsewhere).
        l: Lower bounds ``(n_con,)`` for a zero state (first rate rows open).
        u: Upper bounds ``(n_con,)``.
        groups: The row groups, in row order.
        ix: Slice of ``δx_0 … δx_N`` in ``z``.
        iu: Slice of ``δu_0 … δu_{N-1}`` in ``z``.
        islack: Slice of the slacks in ``z`` (empty without soft bounds).
        rate_idx: Inputs with a finite rate bound ``(r,)``.
        rate0: Rows of the first-stage rate bounds (None without rate bounds).
        zshift: Primal shift map ``(n_var,)``: stage ``k`` takes stage ``k + 1``, the last repeats.
        yshift: Dual shift map ``(n_con,)``, the same for the rows.
    """

    P: sp.csc_matrix
    A: sp.csc_matrix
    q: np.ndarray
    l: np.ndarray
    u: np.ndarray
    groups: list[RowGroup]
    ix: slice
    iu: slice
    islack: slice
    rate_idx: np.ndarray
    rate0: slice | None
    zshift: np.ndarray
    yshift: np.ndarray

    @property
    def n_var(self) -> int:
        """Decision variables."""
        return self.P.shape[0]

    @property
    def n_con(self) -> int:
        """Constraint rows."""
        return self.A.shape[0]

    def group(self, name: str) -> RowGroup | None:
        """The group called ``name``, or None when the problem has none."""
        return next((g for g in self.groups if g.name == name), None)


class _Triplets:
    """COO triplets of a sparse matrix assembled from repeated dense blocks."""

    def __init__(self) -> None:
        self.r: list[np.ndarray] = []
        self.c: list[np.ndarray] = []
        self.v: list[np.ndarray] = []

    def blocks(self, M: np.ndarray, row0: int, col0: int, count: int, row_step: int, col_step: int) -> None:
        """Place the nonzeros of ``M`` at ``(row0 + i·row_step, col0 + i·col_step)``, i < count."""
        if count <= 0:
            return
        r, c = np.nonzero(M)
        k = np.arange(count)[:, None]
        self.r.append((row0 + k * row_step + r).ravel())
        self.c.append((col0 + k * col_step + c).ravel())
        self.v.append(np.broadcast_to(M[r, c], (count, r.size)).ravel())

    def csc(self, shape: tuple[int, int], *, upper: bool = False) -> sp.csc_matrix:
        """The CSC matrix (duplicates summed, indices sorted); ``upper`` keeps ``r <= c``."""
        r = np.concatenate(self.r) if self.r else np.zeros(0, dtype=int)
        c = np.concatenate(self.c) if self.c else np.zeros(0, dtype=int)
        v = np.concatenate(self.v) if self.v else np.zeros(0)
        if upper:
            keep = r <= c
            r, c, v = r[keep], c[keep], v[keep]
        M = sp.csc_matrix((v, (r, c)), shape=shape)
        M.sum_duplicates()
        M.sort_indices()
        return M


class _Rows:
    """Constraint rows collected group by group (stage-major inside each group)."""

    def __init__(self) -> None:
        self.T = _Triplets()
        self.lo: list[np.ndarray] = []
        self.hi: list[np.ndarray] = []
        self.groups: list[RowGroup] = []
        self.r0 = 0

    def add(self, name: str, l: np.ndarray, u: np.ndarray, width: int, first: int, labels: Any) -> None:
        self.lo.append(l)
        self.hi.append(u)
        self.groups.append(RowGroup(name, self.r0, width, first, l.size // width, tuple(labels)))
        self.r0 += l.size


def qp_size(A: np.ndarray, B: np.ndarray, Q: np.ndarray, R: np.ndarray, N: int, opts: MPCOptions) -> tuple[int, int]:
    """``(decision variables, nonzeros of P and A_con)`` of the QP :func:`build_sparse` makes.

    Exact for the variables; for the nonzeros an upper bound (the terminal
    cost counted dense), computed with Python integers (no overflow).
    ``opts`` is a resolved :class:`~shinro_ctrl.controllers.qp.options.MPCOptions`.
    """
    n, m = B.shape
    w = int(np.count_nonzero(np.isfinite(opts.x_min) | np.isfinite(opts.x_max)))
    mu = int(np.count_nonzero(np.isfinite(opts.u_min) | np.isfinite(opts.u_max)))
    r = 0 if opts.du_max is None else int(np.count_nonzero(np.isfinite(opts.du_max)))
    ns = N * w if opts.soft else 0
    nvar = (N + 1) * n + N * m + ns
    nz_Q, nz_R = (int(np.count_nonzero(np.triu(M))) for M in (Q, R))
    nz_A, nz_B = int(np.count_nonzero(A)), int(np.count_nonzero(B))
    nnz_P = N * nz_Q + n * (n + 1) // 2 + N * nz_R + ns
    nnz_A = n + N * (nz_A + n + nz_B) + N * mu + (2 * N - 1) * r + (N * 4 * w + ns if opts.soft else N * w)
    return nvar, nnz_P + nnz_A


def build_sparse(
    A: np.ndarray, B: np.ndarray, Q: np.ndarray, R: np.ndarray, Qf: np.ndarray, N: int, opts: MPCOptions
) -> SparseQP:
    """Assemble ``P``, ``A_con``, ``q``, ``l``, ``u`` and the index maps (once).

    Args:
        A: Discrete state matrix ``(n, n)``.
        B: Discrete input matrix ``(n, m)``.
        Q: Stage state weight ``(n, n)``.
        R: Stage input weight ``(m, m)``.
        Qf: Terminal weight ``(n, n)``.
        N: Horizon.
        opts: Resolved :class:`~shinro_ctrl.controllers.qp.options.MPCOptions`
            (bounds, operating point, offset, soft weights, names).
    """
    n, m = B.shape
    nx, nu = (N + 1) * n, N * m
    xb_idx = np.flatnonzero(np.isfinite(opts.x_min) | np.isfinite(opts.x_max))  # bounded state components
    nsb = xb_idx.size if opts.soft else 0
    ns = N * nsb
    nvar = nx + nu + ns

    # ---- cost: block diagonal, upper triangle
    Ts = _Triplets()
    Ts.blocks(Q, 0, 0, N, n, n)
    Ts.blocks(Qf, N * n, N * n, 1, 0, 0)
    Ts.blocks(R, nx, nx, N, m, m)
    if ns:
        Ts.blocks(np.array([[opts.soft_weight_quad]]), nx + nu, nx + nu, ns, 1, 1)
    P = Ts.csc((nvar, nvar), upper=True)
    q = np.zeros(nvar)
    q[nx + nu :] = opts.soft_weight_l1

    # ---- constraints: one block of rows per group, stage-major inside each
    rows = _Rows()
    _dynamics_rows(rows, A, B, N, opts)
    _input_rows(rows, m, nx, N, opts)
    rate_idx = _rate_rows(rows, m, nx, N, opts)
    _state_rows(rows, n, nx + nu, N, xb_idx, opts)
    Acon = rows.T.csc((rows.r0, nvar))
    l = np.clip(np.concatenate(rows.lo), -INF, INF)
    u = np.clip(np.concatenate(rows.hi), -INF, INF)
    zshift, yshift = _shift_maps(rows.groups, n, m, N, nsb)
    rate = next((g for g in rows.groups if g.name == "rate bounds"), None)
    return SparseQP(
        P=P,
        A=Acon,
        q=q,
        l=l,
        u=u,
        groups=rows.groups,
        ix=slice(0, nx),
        iu=slice(nx, nx + nu),
        islack=slice(nx + nu, nvar),
        rate_idx=rate_idx,
        rate0=None if rate is None else slice(rate.start, rate.start + rate.width),
        zshift=zshift,
        yshift=yshift,
    )


def fill_linear_cost(
    s: SparseQP,
    Q: np.ndarray,
    R: np.ndarray,
    Qf: np.ndarray,
    opts: MPCOptions,
    ref: np.ndarray | None,
    u_ref: np.ndarray | None,
    q: np.ndarray,
) -> float:
    """Write the linear cost of the references into ``q`` (the slack entries untouched); return the constant term.

    Args:
        s: The sparse QP (index maps).
        Q, R, Qf: Stage and terminal weights.
        opts: Resolved options (operating point).
        ref: State reference ``(n,)`` or ``(N + 1, n)`` [absolute]; None = the operating point.
        u_ref: Input reference ``(m,)`` [absolute]; None = the operating point.
        q: The linear cost ``(n_var,)`` written in place.
    """
    n, m = Q.shape[0], R.shape[0]
    N = (s.ix.stop - s.ix.start) // n - 1
    qx = q[s.ix].reshape(N + 1, n)
    qu = q[s.iu].reshape(N, m)
    const = 0.0
    if ref is None:
        qx[:] = 0.0
    elif ref.ndim == 1:
        rho = ref - opts.x0
        g = Q @ rho
        qx[:N] = -g
        gN = Qf @ rho
        qx[N] = -gN
        const += 0.5 * (N * float(rho @ g) + float(rho @ gN))
    else:
        rho = ref - opts.x0
        G = rho[:N] @ Q
        qx[:N] = -G
        gN = Qf @ rho[N]
        qx[N] = -gN
        const += 0.5 * (float(np.sum(G * rho[:N])) + float(rho[N] @ gN))
    if u_ref is None:
        qu[:] = 0.0
    else:
        nu = u_ref - opts.u0
        g = R @ nu
        qu[:] = -g
        const += 0.5 * N * float(nu @ g)
    return const


def fill_rate_rows(s: SparseQP, opts: MPCOptions, u_prev: np.ndarray | None, l: np.ndarray, u: np.ndarray) -> None:
    """Write the first-stage rate rows of ``l``/``u`` for the previously applied input (None: open rows)."""
    if s.rate0 is None:
        return
    ri = s.rate_idx
    if u_prev is None:
        l[s.rate0] = -INF
        u[s.rate0] = INF
    else:
        c = u_prev[ri] - opts.u0[ri]
        l[s.rate0] = c - opts.du_max[ri]
        u[s.rate0] = c + opts.du_max[ri]


def _dynamics_rows(rows: _Rows, A: np.ndarray, B: np.ndarray, N: int, opts: MPCOptions) -> None:
    n = A.shape[0]
    nx = (N + 1) * n
    In = np.eye(n)
    # initial state: δx_0 = x - x0
    rows.T.blocks(In, 0, 0, 1, 0, 0)
    rows.add("initial state", np.zeros(n), np.zeros(n), n, 0, opts.state_names)
    # dynamics, stage k + 1: A δx_k + B δu_k - δx_{k+1} = -d
    r0 = rows.r0
    rows.T.blocks(A, r0, 0, N, n, n)
    rows.T.blocks(-In, r0, n, N, n, n)
    rows.T.blocks(B, r0, nx, N, n, B.shape[1])
    d = np.tile(-opts.offset, N)
    rows.add("dynamics", d, d.copy(), n, 1, opts.state_names)


def _input_rows(rows: _Rows, m: int, nx: int, N: int, opts: MPCOptions) -> None:
    """Input bounds on u_0 … u_{N-1}."""
    ui = np.flatnonzero(np.isfinite(opts.u_min) | np.isfinite(opts.u_max))
    if not ui.size:
        return
    rows.T.blocks(np.eye(m)[ui], rows.r0, nx, N, ui.size, m)
    labels = [f"{opts.input_names[i]} in [{opts.u_min[i]:g}, {opts.u_max[i]:g}]" for i in ui]
    lo = np.tile(opts.u_min[ui] - opts.u0[ui], N)
    hi = np.tile(opts.u_max[ui] - opts.u0[ui], N)
    rows.add("input bounds", lo, hi, ui.size, 0, labels)


def _rate_rows(rows: _Rows, m: int, nx: int, N: int, opts: MPCOptions) -> np.ndarray:
    """Rate bounds δu_k - δu_{k-1}; stage 0 uses the previously applied input (in l/u). Returns their inputs."""
    if opts.du_max is None:
        return np.zeros(0, dtype=int)
    ri = np.flatnonzero(np.isfinite(opts.du_max))
    if ri.size:
        S = np.eye(m)[ri]
        rows.T.blocks(S, rows.r0, nx, N, ri.size, m)
        rows.T.blocks(-S, rows.r0 + ri.size, nx, N - 1, ri.size, m)
        dm = np.tile(opts.du_max[ri], N)
        lb, ubv = -dm, dm.copy()
        lb[: ri.size], ubv[: ri.size] = -INF, INF  # no previous input yet
        labels = [f"|Δ{opts.input_names[i]}| <= {opts.du_max[i]:g}" for i in ri]
        rows.add("rate bounds", lb, ubv, ri.size, 0, labels)
    return ri


def _state_rows(rows: _Rows, n: int, s0: int, N: int, xi: np.ndarray, opts: MPCOptions) -> None:
    """State bounds on x_1 … x_N (the measured x_0 is never bounded); slacks start at column ``s0``."""
    if not xi.size:
        return
    w = xi.size
    S = np.eye(n)[xi]
    xlo = opts.x_min[xi] - opts.x0[xi]
    xhi = opts.x_max[xi] - opts.x0[xi]
    names, x_min, x_max = opts.state_names, opts.x_min, opts.x_max
    T, r0 = rows.T, rows.r0
    if not opts.soft:
        T.blocks(S, r0, n, N, w, n)
        labels = [f"{names[i]} in [{x_min[i]:g}, {x_max[i]:g}]" for i in xi]
        rows.add("state bounds", np.tile(xlo, N), np.tile(xhi, N), w, 1, labels)
        return
    # per stage: w rows δx - s <= hi, then w rows δx + s >= lo
    Iw = np.eye(w)
    T.blocks(S, r0, n, N, 2 * w, n)
    T.blocks(-Iw, r0, s0, N, 2 * w, w)
    T.blocks(S, r0 + w, n, N, 2 * w, n)
    T.blocks(Iw, r0 + w, s0, N, 2 * w, w)
    lb = np.concatenate([np.full((N, w), -INF), np.tile(xlo, (N, 1))], axis=1).ravel()
    ubv = np.concatenate([np.tile(xhi, (N, 1)), np.full((N, w), INF)], axis=1).ravel()
    lab_hi = [f"{names[i]} <= {x_max[i]:g}" for i in xi]
    lab_lo = [f"{names[i]} >= {x_min[i]:g}" for i in xi]
    rows.add("state bounds", lb, ubv, 2 * w, 1, lab_hi + lab_lo)
    T.blocks(Iw, rows.r0, s0, N, w, w)
    ns = N * w
    rows.add("slack bounds", np.zeros(ns), np.full(ns, INF), w, 1, [f"slack {names[i]}" for i in xi])


def _shift_maps(groups: list[RowGroup], n: int, m: int, N: int, nsb: int) -> tuple[np.ndarray, np.ndarray]:
    """Warm-start shift maps: stage k takes stage k+1, the last stage repeats."""
    nx, nu = (N + 1) * n, N * m

    def shifted(start: int, width: int, stages: int) -> np.ndarray:
        k = np.minimum(np.arange(stages) + 1, stages - 1)
        return (start + width * k[:, None] + np.arange(width)[None, :]).ravel()

    zshift = np.concatenate(
        [shifted(0, n, N + 1), shifted(nx, m, N), shifted(nx + nu, nsb, N) if nsb else np.zeros(0, dtype=int)]
    ).astype(np.intp)
    dyn = next(g for g in groups if g.name == "dynamics")
    yparts = []
    for g in groups:
        if g.name == "initial state":
            # the initial-state multiplier takes the first dynamics block's
            yparts.append(np.arange(dyn.start, dyn.start + n))
        else:
            yparts.append(shifted(g.start, g.width, g.stages))
    return zshift, np.concatenate(yparts).astype(np.intp)
