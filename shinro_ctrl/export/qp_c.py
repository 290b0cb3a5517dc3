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


def ldp_fields(nz: int, mt: int) -> tuple[CField, ...]:
    """Workspace fields of the solver for ``nz`` variables and ``mt`` constraint rows."""
    k = min(nz, mt)
    return (
        CField("w", nz, "least-distance variable w of the QP"),
        CField("blo", mt, "lower bounds of M w at this step"),
        CField("bhi", mt, "upper bounds of M w at this step"),
        CField("W", k, "working set: constraint rows", ctype="int"),
        CField("Ws", k, "working set: +1 upper bound, -1 lower bound", ctype="int"),
        CField("nW", 0, "size of the working set (kept between steps: the warm start)", ctype="int"),
        CField("lam", k, "multipliers of the working set (>= 0)"),
        CField("gram", k * k, "Gram matrix A_W A_W^T of the working set"),
        CField("chol", k * k, "its Cholesky factor (lower)"),
        CField("r", k, "solve buffer"),
        CField("zd", nz, "step direction"),
        CField("iters", 0, "active-set iterations of the last solve", ctype="int"),
    )


def ldp_solver_code(nz: int, mt: int, *, primal_tol: float, max_iter: int, tag: str = "ctl") -> str:
    """The static C functions of the solver; the caller fills ``ws->{tag}_blo``/``bhi`` and calls
    ``@N@_{tag}_ldp(ws)``, which returns 0 (optimal, ``ws->{tag}_w``), 1 (infeasible) or 2 (iteration limit).

    Reads the table ``@N@_{tag}_M`` (``mt × nz``, row-major).
    """
    k = min(nz, mt)
    t = tag
    return f"""/* ---- exact QP: dual active-set method on the least-distance problem (see README) ---- */
#define @U@_{t.upper()}_NZ {nz}
#define @U@_{t.upper()}_MT {mt}
#define @U@_{t.upper()}_KMAX {k}

static double @N@_{t}_rowdot(int i, const double *v) {{
    const double *a = @N@_{t}_M + (long)i * {nz};
    double s = 0.0;
    int j;
    for (j = 0; j < {nz}; ++j) {{
        s += a[j] * v[j];
    }}
    return s;
}}

static double @N@_{t}_rowrow(int i, int l) {{
    const double *a = @N@_{t}_M + (long)i * {nz};
    const double *b = @N@_{t}_M + (long)l * {nz};
    double s = 0.0;
    int j;
    for (j = 0; j < {nz}; ++j) {{
        s += a[j] * b[j];
    }}
    return s;
}}

/* the signed bound b_i of constraint (row, sign): a_i w <= b_i with a_i = sign * M_row */
static double @N@_{t}_bound(const @N@_workspace *ws, int row, int sign) {{
    return sign > 0 ? ws->{t}_bhi[row] : -ws->{t}_blo[row];
}}

/* Cholesky factor of the Gram matrix of the first k constraints of W; 0 on success */
static int @N@_{t}_factor(@N@_workspace *ws, int k) {{
    int i, j, l;
    double *L = ws->{t}_chol;
    const double *G = ws->{t}_gram;
    for (i = 0; i < k; ++i) {{
        for (j = 0; j <= i; ++j) {{
            double s = G[i * {k} + j];
            for (l = 0; l < j; ++l) {{
                s -= L[i * {k} + l] * L[j * {k} + l];
            }}
            if (i == j) {{
                if (!(s > 1e-14 * (G[i * {k} + i] + 1e-300))) {{
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

/* x = (L L^T)^{{-1}} b for the first k rows (in place in x) */
static void @N@_{t}_cholsolve(const @N@_workspace *ws, int k, double *x) {{
    int i, l;
    const double *L = ws->{t}_chol;
    for (i = 0; i < k; ++i) {{
        double s = x[i];
        for (l = 0; l < i; ++l) {{
            s -= L[i * {k} + l] * x[l];
        }}
        x[i] = s / L[i * {k} + i];
    }}
    for (i = k - 1; i >= 0; --i) {{
        double s = x[i];
        for (l = i + 1; l < k; ++l) {{
            s -= L[l * {k} + i] * x[l];
        }}
        x[i] = s / L[i * {k} + i];
    }}
}}

/* the Gram row of working-set entry p against entries 0..p (symmetric fill); the signs flip the entry when
   one constraint is an upper and the other a lower bound */
static void @N@_{t}_gram_row(double *gram, const int *W, const int *Ws, int p) {{
    int q;
    for (q = 0; q <= p; ++q) {{
        double g = @N@_{t}_rowrow(W[p], W[q]);
        if (Ws[p] != Ws[q]) {{
            g = -g;
        }}
        gram[p * {k} + q] = g;
        gram[q * {k} + p] = g;
    }}
}}

/* w = -A_W^T lam */
static void @N@_{t}_primal(@N@_workspace *ws) {{
    int p, j;
    double *w = ws->{t}_w;
    for (j = 0; j < {nz}; ++j) {{
        w[j] = 0.0;
    }}
    for (p = 0; p < ws->{t}_nW; ++p) {{
        const double *a = @N@_{t}_M + (long)ws->{t}_W[p] * {nz};
        double c = ws->{t}_lam[p] * ws->{t}_Ws[p];
        for (j = 0; j < {nz}; ++j) {{
            w[j] -= c * a[j];
        }}
    }}
}}

/* lam = -(A_W A_W^T)^{{-1}} b_W on the current (factored) working set; 1 if some lam < 0 */
static int @N@_{t}_multipliers(@N@_workspace *ws) {{
    int p, k = ws->{t}_nW, neg = 0;
    for (p = 0; p < k; ++p) {{
        ws->{t}_lam[p] = -@N@_{t}_bound(ws, ws->{t}_W[p], ws->{t}_Ws[p]);
    }}
    @N@_{t}_cholsolve(ws, k, ws->{t}_lam);
    for (p = 0; p < k; ++p) {{
        if (ws->{t}_lam[p] < 0.0) {{
            neg = 1;
        }}
    }}
    return neg;
}}

static int @N@_{t}_ldp(@N@_workspace *ws) {{
    int p, j, it = 0;
    double *w = ws->{t}_w, *zd = ws->{t}_zd, *r = ws->{t}_r;
    /* warm start: the previous working set, if it is dual feasible here */
    if (ws->{t}_nW > 0) {{
        for (p = 0; p < ws->{t}_nW; ++p) {{
            @N@_{t}_gram_row(ws->{t}_gram, ws->{t}_W, ws->{t}_Ws, p);
        }}
        if (@N@_{t}_factor(ws, ws->{t}_nW) != 0 || @N@_{t}_multipliers(ws) != 0) {{
            ws->{t}_nW = 0;
        }}
    }}
    @N@_{t}_primal(ws);
    for (;;) {{
        int jr = -1, js = 0, k;
        double worst = {primal_tol!r}, aw, bj, zz, t1, t2, tstep, lamj = 0.0;
        if (it >= {max_iter}) {{
            ws->{t}_iters = it;
            return 2;
        }}
        for (j = 0; j < {mt}; ++j) {{
            double mw = @N@_{t}_rowdot(j, w);
            if (mw - ws->{t}_bhi[j] > worst) {{
                worst = mw - ws->{t}_bhi[j];
                jr = j;
                js = 1;
            }}
            if (ws->{t}_blo[j] - mw > worst) {{
                worst = ws->{t}_blo[j] - mw;
                jr = j;
                js = -1;
            }}
        }}
        if (jr < 0) {{
            break; /* no constraint violated: optimal */
        }}
        bj = @N@_{t}_bound(ws, jr, js);
        for (;;) {{ /* raise lam_j (partial steps drop blocking constraints) */
            ++it;
            k = ws->{t}_nW;
            for (p = 0; p < k; ++p) {{
                r[p] = ws->{t}_Ws[p] * js * @N@_{t}_rowrow(ws->{t}_W[p], jr);
            }}
            if (k > 0) {{
                @N@_{t}_cholsolve(ws, k, r);
            }}
            {{
                const double *aj = @N@_{t}_M + (long)jr * {nz};
                for (j = 0; j < {nz}; ++j) {{
                    zd[j] = js * aj[j];
                }}
                for (p = 0; p < k; ++p) {{
                    const double *a = @N@_{t}_M + (long)ws->{t}_W[p] * {nz};
                    double c = r[p] * ws->{t}_Ws[p];
                    for (j = 0; j < {nz}; ++j) {{
                        zd[j] -= c * a[j];
                    }}
                }}
                zz = 0.0;
                aw = 0.0;
                for (j = 0; j < {nz}; ++j) {{
                    zz += js * aj[j] * zd[j];
                    aw += js * aj[j] * w[j];
                }}
            }}
            t2 = (zz > 1e-14) ? (aw - bj) / zz : HUGE_VAL;
            t1 = HUGE_VAL;
            {{
                int q = -1;
                for (p = 0; p < k; ++p) {{
                    if (r[p] > 1e-14 && ws->{t}_lam[p] / r[p] < t1) {{
                        t1 = ws->{t}_lam[p] / r[p];
                        q = p;
                    }}
                }}
                if (t1 == HUGE_VAL && t2 == HUGE_VAL) {{
                    ws->{t}_iters = it;
                    ws->{t}_nW = 0;
                    return 1; /* no step satisfies constraint j: infeasible */
                }}
                tstep = t1 < t2 ? t1 : t2;
                for (j = 0; j < {nz}; ++j) {{
                    w[j] -= tstep * zd[j];
                }}
                for (p = 0; p < k; ++p) {{
                    ws->{t}_lam[p] -= tstep * r[p];
                }}
                lamj += tstep;
                if (t1 < t2) {{ /* partial step: drop q, keep raising lam_j */
                    int a, b;
                    for (p = q; p < k - 1; ++p) {{
                        ws->{t}_W[p] = ws->{t}_W[p + 1];
                        ws->{t}_Ws[p] = ws->{t}_Ws[p + 1];
                        ws->{t}_lam[p] = ws->{t}_lam[p + 1];
                    }}
                    for (a = 0; a < k - 1; ++a) {{
                        for (b = 0; b < k - 1; ++b) {{
                            ws->{t}_gram[a * {k} + b] = ws->{t}_gram[(a + (a >= q)) * {k} + b + (b >= q)];
                        }}
                    }}
                    ws->{t}_nW = k - 1;
                    if (k - 1 > 0 && @N@_{t}_factor(ws, k - 1) != 0) {{
                        ws->{t}_iters = it;
                        ws->{t}_nW = 0;
                        return 1;
                    }}
                    if (it >= {max_iter}) {{
                        ws->{t}_iters = it;
                        return 2;
                    }}
                    continue;
                }}
                /* full step: constraint j joins the working set */
                if (k >= {k}) {{
                    ws->{t}_iters = it;
                    ws->{t}_nW = 0;
                    return 1;
                }}
                ws->{t}_W[k] = jr;
                ws->{t}_Ws[k] = js;
                ws->{t}_lam[k] = lamj;
                ws->{t}_nW = k + 1;
                @N@_{t}_gram_row(ws->{t}_gram, ws->{t}_W, ws->{t}_Ws, k);
                if (@N@_{t}_factor(ws, k + 1) != 0) {{
                    ws->{t}_iters = it;
                    ws->{t}_nW = 0;
                    return 1;
                }}
                break;
            }}
        }}
    }}
    /* polish: the multipliers and w of the final working set, from its equations */
    if (ws->{t}_nW > 0) {{
        (void)@N@_{t}_multipliers(ws);
        @N@_{t}_primal(ws);
    }}
    ws->{t}_iters = it;
    return 0;
}}
"""
