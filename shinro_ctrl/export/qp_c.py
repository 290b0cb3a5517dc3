r"""C of an exact dense QP solver for the exported MPC controllers: a dual active-set method on the
least-distance problem, as DAQP solves it.

The condensed MPC QP ``min ½ zᵀHz + fᵀz s.t. ℓ ≤ A z ≤ h`` (``H`` positive definite, built once) is
rewritten at export time with ``H = L Lᵀ`` and ``z = L^{-T} w − H^{-1} f`` as the least-distance problem

.. math::

    \min_w \tfrac12 \lVert w \rVert^2 \quad\text{s.t.}\quad \ell + A H^{-1} f \le M w \le h + A H^{-1} f,
    \qquad M = A L^{-T},

the form DAQP works in. The C solves it with the dual (Goldfarb–Idnani) active-set method: every
constraint is written ``a_i w ≤ b_i`` (``a_i = ±M_i``); from a dual-feasible working set ``W``
(multipliers ``λ ≥ 0``, ``w = −A_Wᵀλ``, ``A_W w = b_W``) it adds the most violated constraint ``j``
(violation above the primal tolerance, DAQP's ``primal_tol``), raising its multiplier along
``w ← w − t (I − A_Wᵀ(A_W A_Wᵀ)^{-1}A_W) a_jᵀ`` and dropping a constraint of ``W`` whose multiplier
reaches zero first, until no constraint is violated (optimal) or a violated constraint cannot be
satisfied by any step (infeasible). The Gram matrix ``A_W A_Wᵀ`` is factored by Cholesky after each
change of ``W`` (``W`` stays linearly independent: a dependent constraint is only ever added after a
partial step removed one). At the end ``λ`` and ``w`` are recomputed on the final working set, so the
result is the equality-constrained optimum of that set to rounding, the same point DAQP returns for a
strictly convex QP (the solution is unique; both stop when no row is violated by more than the same
``primal_tol``).

Warm start as the Python controller's DAQP model: the working set of the previous step is tried first;
when its multipliers are not all ``≥ 0`` (or its Gram matrix is singular) the solve starts from the empty
set. Everything is sized at export: ``M`` a ``static const`` table, the working set, the Gram matrix and
its factor in the workspace; no heap.
"""

from __future__ import annotations

from shinro_ctrl.export.parts import CField

__all__ = ["ldp_fields", "ldp_solver_code"]


def ldp_fields(mt: int, m: int, kmax: int) -> tuple[CField, ...]:
    """Workspace fields of the solver for ``mt`` constraint rows, ``m`` outputs, at most ``kmax`` active."""
    k = kmax
    return (
        CField("mw", mt, "M w: the constraint rows at the current iterate"),
        CField("blo", mt, "lower bounds of M w at this step"),
        CField("bhi", mt, "upper bounds of M w at this step"),
        CField("W", k, "working set: constraint rows", ctype="int"),
        CField("Ws", k, "working set: +1 upper bound, -1 lower bound", ctype="int"),
        CField("nW", 0, "size of the working set (kept between steps: the warm start)", ctype="int"),
        CField("lam", k, "multipliers of the working set (>= 0)"),
        CField("chol", k * k, "Cholesky factor (lower) of the working set's Gram matrix A_W A_W^T"),
        CField("y", k, "solve buffer"),
        CField("r", k, "solve buffer"),
        CField("iters", 0, "active-set iterations of the last solve", ctype="int"),
    )


def ldp_solver_code(mt: int, m: int, kmax: int, *, primal_tol: float, max_iter: int, tag: str = "ctl") -> str:
    """The static C functions of the solver (module docstring).

    The caller fills ``ws->{tag}_blo``/``bhi`` and calls ``@N@_{tag}_ldp(ws, out)``, which returns 0
    (optimal), 1 (infeasible) or 2 (iteration limit) and adds ``T w`` (``m`` values) to ``out``.
    Reads the tables ``@N@_{tag}_gram`` (``mt × mt``: ``M Mᵀ``, row-major) and ``@N@_{tag}_TM``
    (``mt × m``: ``M Tᵀ``), so ``M`` itself is never needed: with ``w = −A_Wᵀλ`` every quantity of
    the method is a combination of Gram rows.
    """
    k = kmax
    t = tag
    return f"""/* ---- exact QP: dual active-set method on the least-distance problem (see README) ---- */
#define @N@_{t}_G(i, j) (@N@_{t}_gram[(long)(i) * {mt} + (j)])

/* the signed bound b of constraint (row, sign): sign * M_row w <= b */
static double @N@_{t}_bound(const @N@_workspace *ws, int row, int sign) {{
    return sign > 0 ? ws->{t}_bhi[row] : -ws->{t}_blo[row];
}}

/* Cholesky factor of the working set's Gram matrix, from scratch; 0 on success */
static int @N@_{t}_factor(@N@_workspace *ws) {{
    int i, j, l, k = ws->{t}_nW;
    double *L = ws->{t}_chol;
    for (i = 0; i < k; ++i) {{
        for (j = 0; j <= i; ++j) {{
            double s = @N@_{t}_G(ws->{t}_W[i], ws->{t}_W[j]);
            if (ws->{t}_Ws[i] != ws->{t}_Ws[j]) {{
                s = -s;
            }}
            for (l = 0; l < j; ++l) {{
                s -= L[i * {k} + l] * L[j * {k} + l];
            }}
            if (i == j) {{
                if (!(s > 1e-12 * @N@_{t}_G(ws->{t}_W[i], ws->{t}_W[i]))) {{
                    return 1;
                }}
                L[i * {k} + i] = sqrt(s);
            }} else {{
                L[i * {k} + j] = s / L[j * {k} + j];
            }}
        }}
    }}
    return 0;
}}

/* y = L^-1 b (forward), then x = L^-T y (backward), first k rows */
static void @N@_{t}_forward(const @N@_workspace *ws, int k, double *y) {{
    int i, l;
    const double *L = ws->{t}_chol;
    for (i = 0; i < k; ++i) {{
        double s = y[i];
        for (l = 0; l < i; ++l) {{
            s -= L[i * {k} + l] * y[l];
        }}
        y[i] = s / L[i * {k} + i];
    }}
}}

static void @N@_{t}_backward(const @N@_workspace *ws, int k, double *x) {{
    int i, l;
    const double *L = ws->{t}_chol;
    for (i = k - 1; i >= 0; --i) {{
        double s = x[i];
        for (l = i + 1; l < k; ++l) {{
            s -= L[l * {k} + i] * x[l];
        }}
        x[i] = s / L[i * {k} + i];
    }}
}}

/* lam = -(A_W A_W^T)^-1 b_W on the factored working set */
static void @N@_{t}_multipliers(@N@_workspace *ws) {{
    int p, k = ws->{t}_nW;
    for (p = 0; p < k; ++p) {{
        ws->{t}_lam[p] = -@N@_{t}_bound(ws, ws->{t}_W[p], ws->{t}_Ws[p]);
    }}
    @N@_{t}_forward(ws, k, ws->{t}_lam);
    @N@_{t}_backward(ws, k, ws->{t}_lam);
}}

/* drop working-set entry q */
static void @N@_{t}_drop(@N@_workspace *ws, int q) {{
    int p;
    for (p = q; p < ws->{t}_nW - 1; ++p) {{
        ws->{t}_W[p] = ws->{t}_W[p + 1];
        ws->{t}_Ws[p] = ws->{t}_Ws[p + 1];
        ws->{t}_lam[p] = ws->{t}_lam[p + 1];
    }}
    ws->{t}_nW -= 1;
}}

/* M w = -sum_p lam_p s_p Gram[W_p, :] */
static void @N@_{t}_rows(@N@_workspace *ws) {{
    int i, p;
    double *mw = ws->{t}_mw;
    for (i = 0; i < {mt}; ++i) {{
        mw[i] = 0.0;
    }}
    for (p = 0; p < ws->{t}_nW; ++p) {{
        const double *g = @N@_{t}_gram + (long)ws->{t}_W[p] * {mt};
        double c = ws->{t}_Ws[p] > 0 ? -ws->{t}_lam[p] : ws->{t}_lam[p];
        for (i = 0; i < {mt}; ++i) {{
            mw[i] += c * g[i];
        }}
    }}
}}

static int @N@_{t}_ldp(@N@_workspace *ws, double *out) {{
    int p, i, it = 0, rc = 0;
    double *mw = ws->{t}_mw, *y = ws->{t}_y, *r = ws->{t}_r;
    /* warm start: the previous working set (its Cholesky factor is still valid: the Gram matrix is constant),
       less the constraints whose multipliers are negative at this step's bounds */
    while (ws->{t}_nW > 0) {{ /* drop every negative multiplier, refactor, repeat */
        int kept = 0;
        @N@_{t}_multipliers(ws);
        for (p = 0; p < ws->{t}_nW; ++p) {{
            if (ws->{t}_lam[p] >= -1e-12) {{ /* DAQP's dual tolerance: a rounding-level negative is zero */
                ws->{t}_lam[kept] = ws->{t}_lam[p] > 0.0 ? ws->{t}_lam[p] : 0.0;
                ws->{t}_W[kept] = ws->{t}_W[p];
                ws->{t}_Ws[kept] = ws->{t}_Ws[p];
                ++kept;
            }}
        }}
        if (kept == ws->{t}_nW) {{
            break;
        }}
        ws->{t}_nW = kept;
        if (kept > 0 && @N@_{t}_factor(ws) != 0) {{
            ws->{t}_nW = 0;
        }}
    }}
    @N@_{t}_rows(ws);
    for (;;) {{
        int jr = -1, js = 0, k;
        double worst = {primal_tol!r}, bj, lamj = 0.0;
        for (i = 0; i < {mt}; ++i) {{
            if (mw[i] - ws->{t}_bhi[i] > worst) {{
                worst = mw[i] - ws->{t}_bhi[i];
                jr = i;
                js = 1;
            }}
            if (ws->{t}_blo[i] - mw[i] > worst) {{
                worst = ws->{t}_blo[i] - mw[i];
                jr = i;
                js = -1;
            }}
        }}
        if (jr < 0) {{
            break; /* no constraint violated: optimal */
        }}
        bj = @N@_{t}_bound(ws, jr, js);
        for (;;) {{ /* raise lam_j; a partial step drops the blocking constraint */
            const double *gj = @N@_{t}_gram + (long)jr * {mt};
            double zz, t1 = HUGE_VAL, t2 = HUGE_VAL, step;
            int q = -1;
            if (++it > {max_iter}) {{
                rc = 2;
                break;
            }}
            k = ws->{t}_nW;
            for (p = 0; p < k; ++p) {{
                double g = gj[ws->{t}_W[p]];
                y[p] = (ws->{t}_Ws[p] == js) ? g : -g;
            }}
            @N@_{t}_forward(ws, k, y);
            zz = gj[jr];
            for (p = 0; p < k; ++p) {{
                zz -= y[p] * y[p];
                r[p] = y[p];
            }}
            @N@_{t}_backward(ws, k, r);
            if (zz > 1e-12 * gj[jr]) {{
                t2 = (js * mw[jr] - bj) / zz;
            }}
            for (p = 0; p < k; ++p) {{
                if (r[p] > 1e-14 && ws->{t}_lam[p] / r[p] < t1) {{
                    t1 = ws->{t}_lam[p] / r[p];
                    q = p;
                }}
            }}
            if (t1 == HUGE_VAL && t2 == HUGE_VAL) {{
                rc = 1; /* no step satisfies constraint j: infeasible */
                break;
            }}
            step = t1 < t2 ? t1 : t2;
            /* M w -= step * M (I - A_W^T G_W^-1 A_W) a_j^T, in Gram rows */
            for (i = 0; i < {mt}; ++i) {{
                mw[i] -= step * js * gj[i];
            }}
            for (p = 0; p < k; ++p) {{
                const double *g = @N@_{t}_gram + (long)ws->{t}_W[p] * {mt};
                double c = step * r[p] * ws->{t}_Ws[p];
                for (i = 0; i < {mt}; ++i) {{
                    mw[i] += c * g[i];
                }}
                ws->{t}_lam[p] -= step * r[p];
            }}
            lamj += step;
            if (t1 < t2) {{
                @N@_{t}_drop(ws, q);
                if (@N@_{t}_factor(ws) != 0) {{
                    rc = 1;
                    break;
                }}
                continue;
            }}
            if (k >= {k}) {{
                rc = 1;
                break;
            }}
            /* constraint j joins: its Cholesky row is y and sqrt(zz) */
            for (p = 0; p < k; ++p) {{
                ws->{t}_chol[k * {k} + p] = y[p];
            }}
            ws->{t}_chol[k * {k} + k] = sqrt(zz);
            ws->{t}_W[k] = jr;
            ws->{t}_Ws[k] = js;
            ws->{t}_lam[k] = lamj;
            ws->{t}_nW = k + 1;
            break;
        }}
        if (rc != 0) {{
            break;
        }}
    }}
    ws->{t}_iters = it;
    if (rc == 1) {{
        ws->{t}_nW = 0;
        return 1;
    }}
    /* polish: the multipliers of the final working set from its own equations */
    if (ws->{t}_nW > 0) {{
        @N@_{t}_multipliers(ws);
    }}
    /* T w = -sum_p lam_p s_p T M_{{W_p}}^T */
    for (p = 0; p < ws->{t}_nW; ++p) {{
        const double *tm = @N@_{t}_TM + (long)ws->{t}_W[p] * {m};
        double c = ws->{t}_Ws[p] > 0 ? -ws->{t}_lam[p] : ws->{t}_lam[p];
        for (i = 0; i < {m}; ++i) {{
            out[i] += c * tm[i];
        }}
    }}
    return rc;
}}
"""
