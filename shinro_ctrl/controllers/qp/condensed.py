r"""The condensed (input-only) MPC QP around a pre-stabilizing feedback, solved by DAQP.

The model and the cost are those of :class:`~shinro_ctrl.controllers.mpc.LinearMPC`
in deviation variables ``e_k = x_k − x_0``, ``δu_k = u_k − u_0`` (``(x_0, u_0)`` the operating point):

.. math::

    e_{k+1} = A e_k + B\,\delta u_k + d, \qquad
    J = \tfrac12 \sum_{k=0}^{N-1} \big[\lVert e_k - \rho_k \rVert_Q^2 + \lVert \delta u_k - \nu \rVert_R^2\big]
        + \tfrac12 \lVert e_N - \rho_N \rVert_{Q_f}^2 + \sum_{k=1}^{N} \big(w_1 \mathbf 1^\top s_k
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
terminal cost (``Qf = P``) it is exactly ``I_N ⊗ (R + BᵀPB)`` — the cost is
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
ahead) are kept out of the QP: no plan changes them, so a violated one is
reported (:attr:`CondensedQP.dropped_rows`), never declared infeasible.

Everything above is built once per model. A call computes ``e_0``, ``F e_0``,
``E e_0`` into preallocated buffers, hands them to one :class:`daqp.Model`
(workspace, Cholesky factor of ``H`` and ``G H^{-1/2}`` kept; the working set
of the previous solve is the warm start) and solves. DAQP's dual active-set
method returns the exact optimum of the QP (up to rounding) or an
infeasibility flag; :meth:`CondensedQP.explain_infeasibility` then names the
constraint group and stage from an elastic LP's Farkas certificate.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any

import daqp
import numpy as np
from numpy.typing import ArrayLike

from shinro_ctrl.concurrency import CallGuard
from shinro_ctrl.controllers.qp.condensed_build import INF as _INF
from shinro_ctrl.controllers.qp.condensed_build import (
    CondensedMatrices,
    DenseRowGroup,
    build_condensed,
    check_matrix,
    condensed_size,
    prestabilizing_gain,
)
from shinro_ctrl.controllers.qp.condensed_infeasibility import DenseQP, explain_infeasibility
from shinro_ctrl.controllers.qp.options import MPCOptions
from shinro_ctrl.errors import InvalidArgument

__all__ = [
    "DAQP_STATUS",
    "DEFAULT_DAQP_SETTINGS",
    "MAX_DENSE_SIZE",
    "CondensedMatrices",
    "CondensedQP",
    "DenseQP",
    "DenseRowGroup",
    "DenseSolveInfo",
    "condensed_size",
    "fixed_rows_note",
    "prestabilizing_gain",
]

#: DAQP's exit flags (``daqp/include/constants.h``).
DAQP_STATUS: dict[int, str] = {
    2: "solved (soft constraints violated)",
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

#: Matrix-vector products on the per-call path with more entries than this use a plain loop
#: (``einsum``) instead of BLAS: multithreaded OpenBLAS gemv on a busy machine stalled calls
#: for ~50 ms at N = 400 (threads waiting for cores), while one thread needs ~0.3 ms.
_BLAS_MAX = 1 << 17


def fixed_rows_note(parts: list[str]) -> str:
    """The sentence reported in ``MPCSolution.dropped_rows`` for bounds no input can move (empty: none)."""
    if not parts:
        return ""
    return (
        "; ".join(parts) + " (no input reaches that stage yet, e.g. a position one explicit-Euler step ahead: "
        "the bound is left out of this step, the plan keeps it from the next stage on)"
    )


def _mv(M: np.ndarray, v: np.ndarray, out: np.ndarray) -> np.ndarray:
    """``out = M @ v`` on one thread (BLAS for small ``M``, an einsum loop for large)."""
    if M.size > _BLAS_MAX:
        return np.einsum("ij,j->i", M, v, out=out)
    return np.matmul(M, v, out=out)


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


class CondensedQP:
    r"""The condensed MPC QP of one linear model, built once and solved per state by DAQP.

    Holds the model's :class:`~.condensed_build.CondensedMatrices` (built once)
    and its own per-call buffers and one :class:`daqp.Model`.

    Args:
        A: Discrete state matrix ``(n, n)``.
        B: Discrete input matrix ``(n, m)``.
        Q: Stage state weight ``(n, n)``, symmetric PSD.
        R: Stage input weight ``(m, m)``, symmetric positive definite.
        Qf: Terminal weight ``(n, n)``, symmetric PSD.
        horizon: ``N >= 1``.
        K: Pre-stabilizing gain ``(m, n)``; default :func:`prestabilizing_gain`
            of ``(A, B, Q, R)``.
        options: The :class:`~.options.MPCOptions` (operating point ``x0``/``u0``,
            offset, bounds, soft weights, names; resolved here when not yet).
            The rate bounds' ``u_{−1}`` is the ``u_prev`` passed to :meth:`solve`.
        settings: Overrides of :data:`DEFAULT_DAQP_SETTINGS` (any key DAQP's
            ``Model.settings`` knows).
        **kwargs: Fields of :class:`~.options.MPCOptions` (override ``options``).

    Attributes:
        n, m, N: Sizes.
        K: The pre-stabilizing gain ``(m, n)``.
        options: The resolved options.
        matrices: The :class:`~.condensed_build.CondensedMatrices`.
        H: Hessian ``(nz, nz)`` (slacks first).
        F: ``∂f/∂e_0`` ``(nz, n)``.
        G: Constraint rows ``(rows, nz)`` (unscaled; fixed rows included).
        E: ``(rows, n)``: the bounds of row ``r`` are ``ℓ_r − E_r e_0``, ``h_r − E_r e_0``.
        groups: The :class:`DenseRowGroup` blocks of ``G``, by name.
        cond_H: Condition number of the Hessian's input block.
        n_var: ``nz`` (slacks + ``N m``).
        n_slack: Number of slacks ``ns``.
        dropped_rows: The bounds no input can move that the latest state violates
            (predicted values; empty when none): left out, not infeasible.
        z: The latest solution ``(nz,)`` (DAQP's array; None before a solve).
        lam: Its multipliers ``(ns + rows kept,)`` (scaled rows).

    Threads: one object serves one thread; :meth:`solve` entered while
    another thread is inside it raises :class:`~shinro_ctrl.errors.ConcurrentUse`
    (``LinearMPC`` serializes its calls with a lock).

    Raises:
        InvalidArgument: wrong shapes, NaN bounds, a problem larger than
            :data:`MAX_DENSE_SIZE`, DAQP rejecting the set-up or a setting.
    """

    def __init__(
        self,
        A: ArrayLike,
        B: ArrayLike,
        Q: ArrayLike,
        R: ArrayLike,
        Qf: ArrayLike,
        horizon: int,
        *,
        K: ArrayLike | None = None,
        options: MPCOptions | None = None,
        settings: dict[str, Any] | None = None,
        **kwargs: Any,
    ):
        B_ = np.asarray(B, dtype=float)
        if B_.ndim != 2:
            raise InvalidArgument(f"B: expected (n, m) but found {B_.shape}")
        n, m = B_.shape
        N = int(horizon)
        if N < 1:
            raise InvalidArgument(f"horizon must be >= 1, got {horizon!r}")
        self.n, self.m, self.N = n, m, N
        self.A = check_matrix("A", A, (n, n))
        self.B = check_matrix("B", B_, (n, m))
        self.Q = check_matrix("Q", Q, (n, n))
        self.R = check_matrix("R", R, (m, m))
        self.Qf = check_matrix("Qf", Qf, (n, n))
        self.K = prestabilizing_gain(self.A, self.B, self.Q, self.R) if K is None else check_matrix("K", K, (m, n))
        opts = options if options is not None else MPCOptions()
        if kwargs:
            opts = dataclasses.replace(opts, **kwargs)  # TypeError names a misspelt option
        opts = self.options = opts.resolve(n, m)
        fin = np.isfinite
        xb = np.flatnonzero(fin(opts.x_min) | fin(opts.x_max))
        ub = np.flatnonzero(fin(opts.u_min) | fin(opts.u_max))
        rb = np.zeros(0, dtype=int) if opts.du_max is None else np.flatnonzero(fin(opts.du_max))
        self._rb = rb
        w = xb.size
        ns = N * w if opts.soft else 0
        nv = N * m
        rows = N * ub.size + N * rb.size + N * w * (2 if opts.soft else 1)
        size = condensed_size(n, m, N, u_rows=ub.size, rate_rows=rb.size, x_rows=w, soft=opts.soft)
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
        mat = self.matrices = build_condensed(self.A, self.B, self.Q, self.R, self.Qf, N, self.K, opts, (ub, rb, xb))
        self.H, self.F, self.G, self.E, self.cond_H = mat.H, mat.F, mat.G, mat.E, mat.cond_H
        self.groups: dict[str, DenseRowGroup] = {g.name: g for g in mat.groups}
        self._buffers()
        self._setup()
        self.set_reference()

    def _buffers(self) -> None:
        """Preallocated per-call buffers (bounds, gradient, KKT residual, plan)."""
        n, N, mat = self.n, self.N, self.matrices
        ns, nv, nz = self.n_slack, N * self.m, self.n_var
        mk = mat.kept.size
        self._mtot = ns + mk
        self._e0 = np.zeros(n)
        self._f = np.zeros(nz)
        self._f[:ns] = self.options.soft_weight_l1
        self._fv = self._f[ns:]
        self._fr = np.zeros(nv)  # reference + offset part of f on v
        self._bu = np.empty(self._mtot)
        self._bl = np.empty(self._mtot)
        self._bu[:ns] = _INF
        self._bl[:ns] = 0.0
        self._bu_g = self._bu[ns:]
        self._bl_g = self._bl[ns:]
        self._tmp = np.empty(mk)
        self._tmp_f = np.empty(2 * mat.fixed.size)
        self._fviol = np.empty(2 * mat.fixed.size, dtype=bool)
        self._zl = np.zeros(nz + mk)
        self._rb_buf = np.zeros(nz + 3 * mk + 2 * ns)
        self._gz = np.empty(mk)
        self._lp = np.empty(mk)
        self._ev = np.zeros(n + nv)
        self._nX = (N + 1) * n
        self.X: np.ndarray | None = None
        self.U: np.ndarray | None = None
        self._sense0 = np.zeros(self._mtot, dtype=np.intc)
        self.z: np.ndarray | None = None
        self.lam: np.ndarray | None = None
        self._w_lin = np.zeros(n)
        self._c0 = 0.0
        self.dropped_rows = ""
        self._busy = CallGuard("CondensedQP.solve")  # a second thread inside solve() is refused

    def _setup(self) -> None:
        # A throwaway state-independent set-up (bounds at e0 = 0, no u_prev); every solve updates them.
        self._fill(np.zeros(self.n), None)
        self._model = daqp.Model()
        self._model.settings = self._settings
        bad = [k for k in self._settings if k not in self._model.settings]
        if bad:
            raise InvalidArgument(f"unknown DAQP setting '{bad[0]}'; valid settings: {', '.join(self._model.settings)}")
        flag, _ = self._model.setup(self.H, self._f, self.matrices.Gk, self._bu, self._bl, self._sense0.copy())
        if flag < 0:
            raise InvalidArgument(f"DAQP rejected the condensed MPC problem (setup exit flag {flag})")
        self._model.settings = self._settings
        self._fresh = True

    @property
    def settings(self) -> dict[str, Any]:
        """The DAQP settings in use (defaults merged with the overrides; a copy)."""
        return dict(self._settings)

    # ============================================================ per call
    def set_reference(self, ref: np.ndarray | None = None, u_ref: np.ndarray | None = None) -> None:
        """Set the references (absolute units) the next solves track; ``None`` = the operating point.

        Args:
            ref: State reference ``(n,)`` or trajectory ``(N + 1, n)``.
            u_ref: Input reference ``(m,)``.
        """
        n, m, N, mat = self.n, self.m, self.N, self.matrices
        x0, u0 = self.options.x0, self.options.u0
        fr = mat.f_d.copy()
        rho = np.zeros((N + 1) * n)
        if ref is not None:
            r = np.asarray(ref, dtype=float)
            if r.shape == (n,):
                fr += mat.Grho_const @ (r - x0)
                rho = np.tile(r - x0, N + 1)
            else:
                rho = (r.reshape(N + 1, n) - x0).ravel()
                fr -= mat.QSv.T @ rho
        nu = np.zeros(N * m)
        if u_ref is not None:
            nu1 = np.asarray(u_ref, dtype=float) - u0
            fr += mat.Gnu @ nu1
            nu = np.tile(nu1, N)
        self._fr[:] = fr
        # const(e0) = ½‖Sx e0 + c − ρ‖²_Q̄ + ½‖Ux e0 + c_u − ν̄‖²_R̄ = ½ e0ᵀWe0 + wᵀe0 + c0
        dx = mat.c - rho
        du = mat.cu - nu
        self._w_lin = mat.QSx.T @ dx + mat.RUx.T @ du
        Qb_dx = dx.reshape(N + 1, n).copy()
        Qb_dx[:N] = Qb_dx[:N] @ self.Q.T
        Qb_dx[N] = self.Qf @ Qb_dx[N]
        Rb_du = (du.reshape(N, m) @ self.R.T).ravel()
        self._c0 = 0.5 * (float(dx @ Qb_dx.ravel()) + float(du @ Rb_du))

    def _fill(self, e0: np.ndarray, u_prev_dev: np.ndarray | None) -> None:
        """Write ``f`` and the bound vectors for ``e0`` (and the previous input) into the buffers."""
        mat = self.matrices
        _mv(mat.Fv, e0, self._fv)
        np.add(self._fv, self._fr, out=self._fv)
        _mv(mat.Ek, e0, self._tmp)
        np.subtract(mat.hi_k, self._tmp, out=self._bu_g)
        np.subtract(mat.lo_k, self._tmp, out=self._bl_g)
        if mat.rate0_k is not None:
            ix = mat.rate0_k
            if u_prev_dev is None:
                self._bu[ix] = _INF
                self._bl[ix] = -_INF
            else:
                shift = u_prev_dev[self._rb] * mat.rate0_scale
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
        busy = self._busy
        if not busy.acquire(False):
            raise busy.refused()
        try:
            return self._solve(x, u_prev)
        finally:
            busy.release()

    def _solve(self, x: np.ndarray, u_prev: np.ndarray | None) -> DenseSolveInfo:
        mat, x0 = self.matrices, self.options.x0
        e0 = self._e0
        np.subtract(x, x0, out=e0)
        self._fill(e0, None if u_prev is None else u_prev - self.options.u0)
        self.z = self.lam = self.X = self.U = None
        self.dropped_rows = ""
        if mat.fixed.size:
            # bounds no input can move at their stage (x_1's position under explicit Euler): not in the QP;
            # violated ones are reported, not declared infeasible (nothing the plan does changes them)
            _mv(mat.Ef2, e0, self._tmp_f)
            if np.greater(self._tmp_f, mat.bf2, out=self._fviol).any():
                self.dropped_rows = self._describe_fixed(e0)
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
        XU = _mv(mat.PM, ev, np.empty(mat.PM.shape[0]))
        XU += mat.pc
        self.X = XU[: self._nX].reshape(self.N + 1, self.n)
        self.U = XU[self._nX :].reshape(self.N, self.m)
        objective = fval + 0.5 * float(e0 @ mat.W @ e0) + float(self._w_lin @ e0) + self._c0
        return DenseSolveInfo(
            DAQP_STATUS[flag],
            flag,
            info["iterations"],
            int(np.count_nonzero(lam)),
            self.kkt_residual(),
            info["solve_time"],
            objective,
        )

    def _describe_fixed(self, e0: np.ndarray) -> str:
        """The violated bounds among the rows no input moves (hard state bounds), with their predicted values."""
        mat, opts, parts = self.matrices, self.options, []
        bounded = np.flatnonzero(np.isfinite(opts.x_min) | np.isfinite(opts.x_max))
        for row in mat.fixed:
            value = float(mat.E[row] @ e0)  # deviation minus the offset's constant part
            if mat.lo[row] - 1e-9 <= value <= mat.hi[row] + 1e-9:
                continue
            group = next(g for g in mat.groups if g.start <= row < g.stop)
            stage, label = group.locate(int(row))
            i = bounded[(int(row) - group.start) % group.width]
            shift = opts.x_max[i] - mat.hi[row] if np.isfinite(opts.x_max[i]) else opts.x_min[i] - mat.lo[row]
            parts.append(f"{label} at stage {stage}: predicted {value + shift:.4g} whatever the input")
        return fixed_rows_note(parts)

    def kkt_residual(self) -> float:
        """KKT residual of the latest solution (see :class:`DenseSolveInfo`); NaN without one.

        One buffer holds every term that must vanish or be <= 0 at an exact
        optimum (``|Hz + f + Gᵀλ|``, ``g_iᵀz − h_i``, ``ℓ_i − g_iᵀz``, the
        complementarity products ``λ⁺_i (h_i − g_iᵀz) + λ⁻_i (ℓ_i − g_iᵀz)``,
        ``−s``, ``−λ_s s``); the residual is its largest entry (at least 0).
        """
        z, lam, mat = self.z, self.lam, self.matrices
        if z is None or lam is None:
            return math.nan
        ns, nz, mk = self.n_slack, self.n_var, mat.kept.size
        zl, rb = self._zl, self._rb_buf
        zl[:nz] = z
        zl[nz:] = lam[ns:]
        stat = rb[:nz]
        _mv(mat.HG, zl, stat)
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
            _mv(mat.Gk, z, gz)
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

    def problem(self, x: ArrayLike, u_prev: ArrayLike | None = None) -> DenseQP:
        """The condensed QP for state ``x`` (fresh arrays, unscaled rows; nothing is solved)."""
        mat, opts = self.matrices, self.options
        e0 = np.asarray(x, dtype=float) - opts.x0
        ns, nz = self.n_slack, self.n_var
        f = np.empty(nz)
        f[:ns] = opts.soft_weight_l1
        f[ns:] = mat.F[ns:] @ e0 + self._fr
        Ee = mat.E @ e0
        lo, hi = mat.lo - Ee, mat.hi - Ee
        lo[mat.fixed], hi[mat.fixed] = -np.inf, np.inf  # rows no input moves are not part of the QP
        if mat.rate0 is not None:
            sl = mat.rate0
            if u_prev is None:
                lo[sl], hi[sl] = -np.inf, np.inf
            else:
                d = (np.asarray(u_prev, dtype=float) - opts.u0)[self._rb]
                lo[sl] += d
                hi[sl] += d
        Aall = np.vstack([np.eye(ns, nz), mat.G])
        lower = np.concatenate([np.zeros(ns), lo])
        upper = np.concatenate([np.full(ns, np.inf), hi])
        const = 0.5 * float(e0 @ mat.W @ e0) + float(self._w_lin @ e0) + self._c0
        return DenseQP(self.H.copy(), f, Aall, lower, upper, const)

    def explain_infeasibility(self, x: ArrayLike, u_prev: ArrayLike | None = None) -> str | None:
        """Name the constraint group and stage that make the QP at ``x`` infeasible (an elastic LP's certificate).

        See :func:`~.condensed_infeasibility.explain_infeasibility`; None when
        the LP finds the problem feasible (the failure was numerical).
        """
        return explain_infeasibility(self.problem(x, u_prev), self.n_slack, self.matrices.groups)

    def describe(self) -> str:
        """One line: sizes, conditioning and the rows kept."""
        return (
            f"condensed QP (DAQP): {self.n_var} variables ({self.n_slack} slacks), {self.G.shape[0]} rows "
            f"({self.matrices.fixed.size} fixed), cond(H_v) = {self.cond_H:.3g}"
        )
