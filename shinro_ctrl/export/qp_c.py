r"""C of the one exact dense QP solver of the exported MPC controllers: a dual active-set method on the
least-distance problem, as DAQP solves it, with its rows from a table or formed at each step.

A QP ``min ½ zᵀHz + fᵀz s.t. ℓ ≤ A z ≤ h`` (``H`` positive definite) is rewritten with ``H = L Lᵀ`` and
``z = L^{-T} w − H^{-1} f`` as the least-distance problem

.. math::

    \min_w \tfrac12 \lVert w \rVert^2 \quad\text{s.t.}\quad \ell + A H^{-1} f \le M w \le h + A H^{-1} f,
    \qquad M = A L^{-T},

the form DAQP works in. The C solves it with the dual (Goldfarb–Idnani) active-set method
(:func:`ldp_solver_code`): every constraint is written ``a_i w ≤ b_i`` (``a_i = ±M_i``); from a
dual-feasible working set ``W`` (multipliers ``λ ≥ 0``, ``w = −A_Wᵀλ``, ``A_W w = b_W``) it adds the most
violated constraint ``j`` (violation above the primal tolerance, DAQP's ``primal_tol``), raising its
multiplier along ``w ← w − t (I − A_Wᵀ(A_W A_Wᵀ)^{-1}A_W) a_jᵀ`` and dropping a constraint of ``W`` whose
multiplier reaches zero first, until no constraint is violated (optimal) or a violated constraint cannot
be satisfied by any step (infeasible). The Gram matrix ``A_W A_Wᵀ`` (the dual Hessian ``A_W H⁻¹ A_Wᵀ`` of the
working set) is factored by Cholesky after each drop and extended by one row at each addition (``W``
stays linearly independent: a dependent constraint is only ever added after a partial step removed one).
At the end ``λ`` is recomputed on the final working set, so the result is the equality-constrained optimum
of that set to rounding, the same point DAQP returns for a strictly convex QP (the solution is unique; both
stop when no row is violated by more than the same ``primal_tol``).

The method only needs four operations on the rows of ``M``, which a **row provider** defines before the
solver's code (tag ``t``, ``ws`` the workspace):

* ``double @N@_t_rowdot(ws, a, b)``: ``M_a · M_b``;
* ``void @N@_t_wzero(ws)`` and ``void @N@_t_waxpy(ws, a, c)``: set the iterate to ``w = 0``, add ``c M_aᵀ``;
* ``double @N@_t_wrow(ws, a)``: ``M_a w``; ``void @N@_t_scan(ws)``: ``M w`` of every row into ``ws->t_mw``.

Two providers exist, one per kind of QP:

* :func:`gram_table_code` (``LinearMPC``: ``H`` and ``A`` fixed at export): the Gram matrix ``M Mᵀ`` and
  ``M Tᵀ`` (the outputs ``T w``) are ``static const`` tables; the iterate is kept as ``M w`` itself,
  updated by Gram rows, so ``M`` is never needed; the warm start's factor stays valid between steps.
* :func:`block_rows_code` (``NonlinearMPC``: ``H`` and ``A`` new at every step): ``H`` block diagonal
  (``m × m`` blocks, then a diagonal slack weight ``w₂``), ``f`` only on the slacks (``w₁``), and every
  row a dense leading part plus at most one slack entry. Each step factors the blocks, forms
  ``M = A L^{-T}`` row by row, normalized to unit length as DAQP normalizes its rows, and its bounds; the
  iterate is ``w`` itself (``M w`` by dot products); the warm start is refactored.

Everything is sized at export: tables ``static const``, the working set, the Gram factor and the rows in
the workspace; no heap.
"""

from __future__ import annotations

from shinro_ctrl.export.parts import CField

__all__ = ["block_rows_code", "block_rows_fields", "gram_table_code", "gram_table_fields", "ldp_solver_code"]


def _core_fields(mt: int, kmax: int) -> tuple[CField, ...]:
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


def ldp_solver_code(mt: int, kmax: int, *, primal_tol: float, max_iter: int, refactor: bool, tag: str = "ctl") -> str:
    """The static C functions of the solver (module docstring), after a row provider's.

    The caller fills ``ws->{tag}_blo``/``bhi`` (and the provider's rows) and calls ``@N@_{tag}_ldp(ws)``,
    which returns 0 (optimal), 1 (infeasible) or 2 (iteration limit), the multipliers of the final working
    set in ``ws->{tag}_lam`` and its iterate in the provider's representation. The working set left in
    the workspace is the next call's start (``refactor``: its Gram matrix changed, factor it first).
    """
    k = kmax
    t = tag
    start = (
        f"""    if (ws->{t}_nW > 0 && @N@_{t}_factor(ws) != 0) {{ /* the rows changed: factor the start's Gram matrix */
        ws->{t}_nW = 0;
    }}
"""
        if refactor
        else "    /* the previous working set: its Cholesky factor is still valid (the Gram matrix is constant) */\n"
    )
    return f"""/* ---- exact QP: dual active-set method on the least-distance problem (export/qp_c.py) ---- */
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
            double s = @N@_{t}_rowdot(ws, ws->{t}_W[i], ws->{t}_W[j]);
            if (ws->{t}_Ws[i] != ws->{t}_Ws[j]) {{
                s = -s;
            }}
            for (l = 0; l < j; ++l) {{
                s -= L[i * {k} + l] * L[j * {k} + l];
            }}
            if (i == j) {{
                if (!(s > 1e-12 * @N@_{t}_rowdot(ws, ws->{t}_W[i], ws->{t}_W[i]))) {{
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

/* the iterate w = -A_W^T lam */
static void @N@_{t}_primal(@N@_workspace *ws) {{
    int p;
    @N@_{t}_wzero(ws);
    for (p = 0; p < ws->{t}_nW; ++p) {{
        @N@_{t}_waxpy(ws, ws->{t}_W[p], ws->{t}_Ws[p] > 0 ? -ws->{t}_lam[p] : ws->{t}_lam[p]);
    }}
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

static int @N@_{t}_ldp(@N@_workspace *ws) {{
    int p, i, it = 0, rc = 0;
    double *mw = ws->{t}_mw, *y = ws->{t}_y, *r = ws->{t}_r;
{start}    while (ws->{t}_nW > 0) {{ /* drop every negative multiplier of the start, refactor, repeat */
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
    @N@_{t}_primal(ws);
    for (;;) {{
        int jr = -1, js = 0, k;
        double worst = {primal_tol!r}, bj, lamj = 0.0;
        @N@_{t}_scan(ws);
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
            double zz, t1 = HUGE_VAL, t2 = HUGE_VAL, step, gjj = @N@_{t}_rowdot(ws, jr, jr);
            int q = -1;
            if (++it > {max_iter}) {{
                rc = 2;
                break;
            }}
            k = ws->{t}_nW;
            for (p = 0; p < k; ++p) {{
                double g = @N@_{t}_rowdot(ws, jr, ws->{t}_W[p]);
                y[p] = (ws->{t}_Ws[p] == js) ? g : -g;
            }}
            @N@_{t}_forward(ws, k, y);
            zz = gjj;
            for (p = 0; p < k; ++p) {{
                zz -= y[p] * y[p];
                r[p] = y[p];
            }}
            @N@_{t}_backward(ws, k, r);
            if (zz > 1e-12 * gjj) {{
                t2 = (js * @N@_{t}_wrow(ws, jr) - bj) / zz;
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
            /* w -= step (I - A_W^T G_W^-1 A_W) a_j^T */
            @N@_{t}_waxpy(ws, jr, -step * js);
            for (p = 0; p < k; ++p) {{
                @N@_{t}_waxpy(ws, ws->{t}_W[p], step * r[p] * ws->{t}_Ws[p]);
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
    if (ws->{t}_nW > 0) {{ /* polish: the final working set's own equations */
        @N@_{t}_multipliers(ws);
        @N@_{t}_primal(ws);
    }}
    return rc;
}}
"""


# ------------------------------------------------------------------------------------------- table provider
def gram_table_fields(mt: int, kmax: int) -> tuple[CField, ...]:
    """Workspace fields of the solver on table rows: ``mt`` rows, at most ``kmax`` active."""
    return _core_fields(mt, kmax)


def gram_table_code(mt: int, m: int, tag: str = "ctl") -> str:
    """The table row provider (module docstring) and ``@N@_{tag}_output(ws, out)``: ``out += T w``.

    Reads the tables ``@N@_{tag}_gram`` (``mt × mt``: ``M Mᵀ``, row-major) and ``@N@_{tag}_TM`` (``mt × m``:
    ``M Tᵀ``): with ``w = −A_Wᵀλ`` every quantity of the method is a combination of Gram rows.
    """
    t = tag
    return f"""/* ---- rows of the least-distance QP from the export-time Gram table: the iterate kept as M w ---- */
static double @N@_{t}_rowdot(const @N@_workspace *ws, int a, int b) {{
    (void)ws;
    return @N@_{t}_gram[(long)a * {mt} + b];
}}

static void @N@_{t}_wzero(@N@_workspace *ws) {{
    memset(ws->{t}_mw, 0, {mt} * sizeof(double));
}}

/* M w += c M M_a^T (a Gram row) */
static void @N@_{t}_waxpy(@N@_workspace *ws, int a, double c) {{
    int i;
    const double *g = @N@_{t}_gram + (long)a * {mt};
    double *mw = ws->{t}_mw;
    for (i = 0; i < {mt}; ++i) {{
        mw[i] += c * g[i];
    }}
}}

static double @N@_{t}_wrow(const @N@_workspace *ws, int a) {{
    return ws->{t}_mw[a];
}}

static void @N@_{t}_scan(@N@_workspace *ws) {{
    (void)ws;
}}

/* out += T w = -sum_p lam_p s_p T M_(W_p)^T */
static void @N@_{t}_output(const @N@_workspace *ws, double *out) {{
    int p, i;
    for (p = 0; p < ws->{t}_nW; ++p) {{
        const double *tm = @N@_{t}_TM + (long)ws->{t}_W[p] * {m};
        double c = ws->{t}_Ws[p] > 0 ? -ws->{t}_lam[p] : ws->{t}_lam[p];
        for (i = 0; i < {m}; ++i) {{
            out[i] += c * tm[i];
        }}
    }}
}}
"""


# ------------------------------------------------------------------------------------- per-step block rows
def block_rows_fields(mt: int, nd: int, ns: int, nb: int, kmax: int) -> tuple[CField, ...]:
    """Workspace fields of the solver on rows formed each step (:func:`block_rows_code`)."""
    nz = nd + ns
    return (
        *_core_fields(mt, kmax),
        CField("Hb", nb * nb * (nd // nb), "the Hessian's diagonal blocks (nd/nb blocks of nb x nb), row-major"),
        CField("Lb", nb * nb * (nd // nb), "their Cholesky factors (lower)"),
        CField("Md", mt * nd, "rows: their dense leading part, in z (A) and then in w (M, normalized)"),
        CField("len", mt, "rows: the length of the dense part", ctype="int"),
        CField("sidx", mt, "rows: the slack column (-1: none)", ctype="int"),
        CField("sval", mt, "rows: the slack entry (in z, then in w normalized)"),
        CField("zlo", mt, "rows: lower bounds in z (-INFINITY: none)"),
        CField("zhi", mt, "rows: upper bounds in z (INFINITY: none)"),
        CField("nrm", mt, "rows: |A_i L^-T| (the normalization)"),
        CField("w", max(nz, 1), "the least-distance variable w"),
        CField("z", max(nz, 1), "the QP's solution z"),
    )


def block_rows_code(mt: int, nd: int, ns: int, nb: int, w1: float, w2: float, tag: str = "ctl") -> str:
    """The per-step row provider (module docstring) and its setup and recovery.

    The QP's variables are ``z = (d (nd), s (ns))``; ``H = blockdiag(H_1 … H_{nd/nb}, w₂ I)`` with the blocks in
    ``ws->{tag}_Hb``; ``f = (0, w₁ 1)``. Row ``i`` of ``A`` is ``ws->{tag}_Md[i, :len_i]`` (zero after) plus
    ``sval_i`` at slack ``sidx_i``, with bounds ``zlo``/``zhi``. ``@N@_{tag}_setup(ws)`` (0, or 1 when a block
    is not positive definite) factors the blocks and turns every row into its normalized row of ``M`` and its
    bounds (in place); after :func:`ldp_solver_code`'s ``ldp``, ``@N@_{tag}_recover(ws)`` writes
    ``z = L^{-T} w − H^{-1} f`` to ``ws->{tag}_z``.
    """
    t = tag
    nz = nd + ns
    isq = 1.0 / w2**0.5
    nblk = nd // nb
    slack_axpy = slack_dot = ""
    if ns:  # (without slacks no row has a slack entry: no code that could index past w)
        slack_axpy = f"""    if (ws->{t}_sidx[a] >= 0) {{
        ws->{t}_w[{nd} + ws->{t}_sidx[a]] += c * ws->{t}_sval[a];
    }}
"""
        slack_dot = f"""    if (ws->{t}_sidx[a] >= 0) {{
        s += ws->{t}_sval[a] * ws->{t}_w[{nd} + ws->{t}_sidx[a]];
    }}
"""
    return f"""/* ---- rows of the least-distance QP formed each step: H block diagonal, one slack entry per row ---- */
/* a . b over len entries, in four partial sums (independent chains: the compiler may overlap them) */
static double @N@_{t}_dot(const double *a, const double *b, int len) {{
    double s0 = 0.0, s1 = 0.0, s2 = 0.0, s3 = 0.0;
    int i = 0;
    for (; i + 4 <= len; i += 4) {{
        s0 += a[i] * b[i];
        s1 += a[i + 1] * b[i + 1];
        s2 += a[i + 2] * b[i + 2];
        s3 += a[i + 3] * b[i + 3];
    }}
    for (; i < len; ++i) {{
        s0 += a[i] * b[i];
    }}
    return (s0 + s1) + (s2 + s3);
}}

static double @N@_{t}_rowdot(const @N@_workspace *ws, int a, int b) {{
    int len = ws->{t}_len[a] < ws->{t}_len[b] ? ws->{t}_len[a] : ws->{t}_len[b];
    double s = @N@_{t}_dot(ws->{t}_Md + (long)a * {nd}, ws->{t}_Md + (long)b * {nd}, len);
    if (ws->{t}_sidx[a] >= 0 && ws->{t}_sidx[a] == ws->{t}_sidx[b]) {{
        s += ws->{t}_sval[a] * ws->{t}_sval[b];
    }}
    return s;
}}

static void @N@_{t}_wzero(@N@_workspace *ws) {{
    memset(ws->{t}_w, 0, {max(nz, 1)} * sizeof(double));
}}

/* w += c M_a^T */
static void @N@_{t}_waxpy(@N@_workspace *ws, int a, double c) {{
    int l, len = ws->{t}_len[a];
    const double *ra = ws->{t}_Md + (long)a * {nd};
    for (l = 0; l < len; ++l) {{
        ws->{t}_w[l] += c * ra[l];
    }}
{slack_axpy}}}

static double @N@_{t}_wrow(const @N@_workspace *ws, int a) {{
    double s = @N@_{t}_dot(ws->{t}_Md + (long)a * {nd}, ws->{t}_w, ws->{t}_len[a]);
{slack_dot}    return s;
}}

/* M w of the rows with a finite bound (the others are never violated) */
static void @N@_{t}_scan(@N@_workspace *ws) {{
    int i;
    for (i = 0; i < {mt}; ++i) {{
        ws->{t}_mw[i] = (isinf(ws->{t}_blo[i]) && isinf(ws->{t}_bhi[i])) ? 0.0 : @N@_{t}_wrow(ws, i);
    }}
}}

/* factor the blocks; rows A_i -> M_i = A_i L^-T / |A_i L^-T|, bounds (b + A_i H^-1 f) / |A_i L^-T|; 0 on success */
static int @N@_{t}_setup(@N@_workspace *ws) {{
    int b, i, j, l, r;
    for (b = 0; b < {nblk}; ++b) {{
        const double *H = ws->{t}_Hb + b * {nb * nb};
        double *L = ws->{t}_Lb + b * {nb * nb};
        for (i = 0; i < {nb}; ++i) {{
            for (j = 0; j <= i; ++j) {{
                double s = H[i * {nb} + j];
                for (l = 0; l < j; ++l) {{
                    s -= L[i * {nb} + l] * L[j * {nb} + l];
                }}
                if (i == j) {{
                    if (!(s > 0.0)) {{
                        return 1;
                    }}
                    L[i * {nb} + i] = sqrt(s);
                }} else {{
                    L[i * {nb} + j] = s / L[j * {nb} + j];
                }}
            }}
        }}
    }}
    for (r = 0; r < {mt}; ++r) {{
        double *row = ws->{t}_Md + (long)r * {nd}, nrm = 0.0, inv, hf = 0.0;
        int len = ws->{t}_len[r];
        for (b = 0; b * {nb} < len; ++b) {{ /* (L_b^-1 a_b^T)^T, block by block */
            const double *L = ws->{t}_Lb + b * {nb * nb};
            double *a = row + b * {nb};
            for (i = 0; i < {nb}; ++i) {{
                double s = a[i];
                for (l = 0; l < i; ++l) {{
                    s -= L[i * {nb} + l] * a[l];
                }}
                a[i] = s / L[i * {nb} + i];
            }}
        }}
        if (ws->{t}_sidx[r] >= 0) {{
            hf = ws->{t}_sval[r] * {w1 / w2!r}; /* A_i H^-1 f: only the slack has a linear cost */
            ws->{t}_sval[r] *= {isq!r};
            nrm = ws->{t}_sval[r] * ws->{t}_sval[r];
        }}
        nrm = sqrt(nrm + @N@_{t}_dot(row, row, len));
        if (!(nrm > 0.0)) {{
            nrm = 1.0;
        }}
        inv = 1.0 / nrm;
        for (l = 0; l < len; ++l) {{
            row[l] *= inv;
        }}
        ws->{t}_sval[r] *= inv;
        ws->{t}_nrm[r] = nrm;
        ws->{t}_blo[r] = (ws->{t}_zlo[r] + hf) * inv;
        ws->{t}_bhi[r] = (ws->{t}_zhi[r] + hf) * inv;
    }}
    return 0;
}}

/* z = L^-T w - H^-1 f */
static void @N@_{t}_recover(@N@_workspace *ws) {{
    int b, i, l;
    for (b = 0; b < {nblk}; ++b) {{
        const double *L = ws->{t}_Lb + b * {nb * nb};
        const double *w = ws->{t}_w + b * {nb};
        double *z = ws->{t}_z + b * {nb};
        for (i = {nb} - 1; i >= 0; --i) {{
            double s = w[i];
            for (l = i + 1; l < {nb}; ++l) {{
                s -= L[l * {nb} + i] * z[l];
            }}
            z[i] = s / L[i * {nb} + i];
        }}
    }}
    for (i = {nd}; i < {nz}; ++i) {{
        ws->{t}_z[i] = {isq!r} * ws->{t}_w[i] - {w1 / w2!r};
    }}
}}
"""
