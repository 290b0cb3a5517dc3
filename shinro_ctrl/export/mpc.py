r"""C of the :class:`~shinro_ctrl.controllers.mpc.LinearMPC`: the condensed QP of its DAQP backend, solved exactly.

The exported controller solves the same QP as the Python controller's DAQP backend
(``controllers/qp/condensed.py``): inputs around the DARE's pre-stabilizing feedback, slacks first,
rows scaled to unit norm, the rows no input can move left out. Everything that depends only on the
model is folded at export time into tables (``%.17g``): with ``e₀ = x̂ − x₀`` and ``ρ = r − x₀``
(the set-point given to ``set_reference``),

* the gradient ``f = F_z e₀ + G_z ρ + f_c`` (``f_c``: the slacks' L1 weight, the offset's and a
  constant ``u_ref``'s terms),
* the least-distance form of :mod:`~shinro_ctrl.export.qp_c` (``H = LLᵀ``, ``M = A L^{-T}``): the
  bounds of ``M w`` are ``ℓ − E e₀ + A H^{-1} f``, i.e. ``ℓ + D_e e₀ + D_r ρ + d_c``,
* the first input of the plan, ``u = T_e e₀ + T_r ρ + T_w w + t_c`` (``z = L^{-T}w − H^{-1}f`` and the
  plan's first row ``U₀ = PM_{u₀} (e₀, v) + pc_{u₀}`` combined).

A step computes the bounds (the first stage's rate rows moved by the previously applied input, or
left out before the first input as Python does after a reset), solves the least-distance QP from the
previous working set, maps ``w`` to ``u`` and clips it to the rate and input bounds
(``clip_input``). Offset-free (``disturbance_model = "input"``, ``controllers/offset_free.py``): the
estimate is ``[x̂; d̂]`` and the input ``clip(v − d̂, u_min, u_max)``, ``v`` the MPC's. What is not
exported is refused in one line: the OSQP backend, ``fallback = "shift"``.
"""

from __future__ import annotations

import numpy as np
import scipy.linalg as sla

from shinro_ctrl.controllers.mpc import LinearMPC
from shinro_ctrl.errors import ExportError
from shinro_ctrl.export.parts import CArray, CField, Part, matvec
from shinro_ctrl.export.qp_c import gram_table_code, gram_table_fields, ldp_solver_code
from shinro_ctrl.export.registry import ExportContext, register_exporter

__all__ = ["MAX_ITER", "MAX_ROWS", "LinearMPCExporter", "MPCTables"]

#: Active-set iterations per step before the exported solver gives up (status SOLVER_MAX_ITER).
MAX_ITER = 1000


class MPCTables:
    """The export-time tables of one :class:`LinearMPC` (see the module docstring for the formulas).

    Attributes:
        n, m, nz, ns, mt: States, inputs, QP variables, slacks, constraint rows (slack bounds included).
        M: ``(mt, nz)`` rows of the least-distance problem.
        lo, hi: ``(mt,)`` constant parts of the row bounds (±inf where none).
        De, Dr: ``(mt, n)`` the bounds' dependence on ``e₀`` and ``ρ``; dc ``(mt,)`` the rest.
        Te, Tr, Tw: ``(m, n)``, ``(m, n)``, ``(m, nz)``; tc ``(m,)``: the first input.
        rate_rows, rate_idx, rate_scale: the first stage's rate rows, their input index and row scale.
        primal_tol: DAQP's primal tolerance (the same stopping rule).
    """

    def __init__(self, ctrl: LinearMPC):
        dq = ctrl.dense
        assert dq is not None
        mat, opts = dq.matrices, ctrl.options
        n, m, N = ctrl.n, ctrl.m, ctrl.N
        ns, nz = dq.n_slack, dq.n_var
        nv = N * m
        mk = mat.kept.size
        self.n, self.m, self.nz, self.ns, self.mt = n, m, nz, ns, ns + mk
        A = np.vstack([np.eye(ns, nz), mat.Gk]) if ns else np.asarray(mat.Gk, dtype=float).reshape(mk, nz)
        E = np.vstack([np.zeros((ns, n)), mat.Ek]) if ns else np.asarray(mat.Ek, dtype=float).reshape(mk, n)
        self.lo = np.concatenate([np.zeros(ns), mat.lo_k])
        self.hi = np.concatenate([np.full(ns, np.inf), mat.hi_k])
        H = np.asarray(dq.H, dtype=float)
        L = np.linalg.cholesky(H)
        LinvT = sla.solve_triangular(L, np.eye(nz), lower=True).T
        Hinv = LinvT @ LinvT.T
        Fz = np.zeros((nz, n))
        Fz[ns:] = mat.Fv
        Gz = np.zeros((nz, n))
        Gz[ns:] = mat.Grho_const
        fc = np.zeros(nz)
        fc[:ns] = opts.soft_weight_l1
        fc[ns:] = mat.f_d
        if ctrl.u_ref is not None:
            fc[ns:] += mat.Gnu @ (np.asarray(ctrl.u_ref, dtype=float) - opts.u0)
        AHi = A @ Hinv
        self.M = A @ LinvT
        self.De = -E + AHi @ Fz
        self.Dr = AHi @ Gz
        self.dc = AHi @ fc
        nX = (N + 1) * n
        PMu = mat.PM[nX : nX + m]
        PMe, PMv = PMu[:, :n], PMu[:, n:]
        Sel = np.zeros((nv, nz))
        Sel[:, ns:] = np.eye(nv)
        PS = PMv @ Sel
        self.Tw = PS @ LinvT
        self.Te = PMe - PS @ Hinv @ Fz
        self.Tr = -PS @ Hinv @ Gz
        self.tc = mat.pc[nX : nX + m] - PS @ Hinv @ fc
        if mat.rate0_k is not None and mat.rate0_k.size:
            self.rate_rows = np.asarray(mat.rate0_k, dtype=int)
            rb = np.flatnonzero(np.isfinite(opts.du_max))
            self.rate_idx = rb.astype(int)
            self.rate_scale = np.asarray(mat.rate0_scale, dtype=float)
        else:
            self.rate_rows = self.rate_idx = np.zeros(0, dtype=int)
            self.rate_scale = np.zeros(0)
        self.primal_tol = float(dq.settings["primal_tol"])


#: Largest number of constraint rows exported (the Gram table holds mt² doubles: 2,000 rows are 32 MB).
MAX_ROWS = 2000


def _check(ctrl: LinearMPC, ctx: ExportContext) -> None:
    if ctrl.solver != "daqp" or ctrl.dense is None:
        raise ExportError(
            f"cannot export a LinearMPC on the '{ctrl.solver}' backend: the exported C solves the condensed QP "
            "exactly, as the DAQP backend does; set solver = 'daqp' (the condensed QP must fit, see choose_solver)"
        )
    if ctx.x_hat_dim != ctrl.n and not (ctrl.disturbance_model == "input" and ctx.x_hat_dim == ctrl.n + ctrl.m):
        raise ExportError(
            f"cannot export this LinearMPC: its estimator hands it {ctx.x_hat_dim} values, and the exported MPC "
            f"takes the state ({ctrl.n}) or, offset-free with disturbance_model = 'input', [x; d] ({ctrl.n + ctrl.m})"
        )
    if ctrl.fallback is not None:
        raise ExportError(
            "cannot export a LinearMPC with fallback = 'shift': the exported step reports an infeasible QP "
            "(status QP_INFEASIBLE, previous input held) instead; remove the fallback"
        )


@register_exporter(LinearMPC)
class LinearMPCExporter:
    """LinearMPC on its DAQP (condensed) backend: the exact QP in C."""

    tag = "ctl"

    def part(self, obj: object, ctx: ExportContext) -> Part:
        """Tables, workspace and C of ``obj`` (a :class:`LinearMPC`)."""
        assert isinstance(obj, LinearMPC)
        _check(obj, ctx)
        t = MPCTables(obj)
        if t.mt > MAX_ROWS:
            raise ExportError(
                f"cannot export this LinearMPC: its condensed QP has {t.mt} constraint rows and the exported solver "
                f"holds their Gram matrix as a table (at most {MAX_ROWS} rows); shorten the horizon"
            )
        n, m, nz, mt = t.n, t.m, t.nz, t.mt
        opts = obj.options
        tables = [
            CArray("x0", opts.x0, "operating state x0"),
            CArray("u_lo", obj.u_min, "lower input bounds"),
            CArray("u_hi", obj.u_max, "upper input bounds"),
            CArray("Te", t.Te, "first input: dependence on e0 = x - x0 (m x n)"),
            CArray("Tr", t.Tr, "first input: dependence on rho = r - x0 (m x n)"),
            CArray("tc", t.tc, "first input: constant part (m)"),
        ]
        fields = [
            CField("e0", n, "e0 = x_hat - x0"),
            CField("rho", n, "rho = r - x0"),
            CField("uprev", m, "the input the MPC applied last (rate bounds of the first move)"),
            CField("has_uprev", 0, "whether uprev holds an input (0 after reset)", ctype="int"),
        ]
        solve = ""
        if mt:
            tables += [
                CArray("gram", t.M @ t.M.T, "Gram matrix M M^T of the least-distance QP's rows (mt x mt)"),
                CArray("TM", t.M @ t.Tw.T, "first input per unit multiplier: M T_w^T (mt x m)"),
                CArray("lo", t.lo, "constant lower row bounds (mt)"),
                CArray("hi", t.hi, "constant upper row bounds (mt)"),
                CArray("De", t.De, "row bounds: dependence on e0 (mt x n)"),
                CArray("Dr", t.Dr, "row bounds: dependence on rho (mt x n)"),
                CArray("dc", t.dc, "row bounds: constant shift A H^-1 f_c (mt)"),
            ]
            fields += gram_table_fields(mt, min(nz, mt))
            nr = int(t.rate_rows.size)
            if nr:
                tables += [
                    CArray("rrow", t.rate_rows, "rows of the first stage's rate bounds", ctype="int"),
                    CArray("ridx", t.rate_idx, "their input index", ctype="int"),
                    CArray("rsc", t.rate_scale, "their row scale"),
                ]
            rate = (
                f"""    for (i = 0; i < {nr}; ++i) {{
        int row = @N@_ctl_rrow[i];
        if (ws->ctl_has_uprev) {{
            double sh = (ws->ctl_uprev[@N@_ctl_ridx[i]] - @N@_ctl_u0[@N@_ctl_ridx[i]]) * @N@_ctl_rsc[i];
            ws->ctl_blo[row] += sh;
            ws->ctl_bhi[row] += sh;
        }} else {{
            ws->ctl_blo[row] = -INFINITY;
            ws->ctl_bhi[row] = INFINITY;
        }}
    }}
"""
                if nr
                else ""
            )
            if nr:
                tables.append(CArray("u0", opts.u0, "operating input u0"))
            solve = (
                f"""    for (i = 0; i < {mt}; ++i) {{
        double s = @N@_ctl_dc[i];
        for (j = 0; j < {n}; ++j) {{
            s += @N@_ctl_De[i * {n} + j] * ws->ctl_e0[j] + @N@_ctl_Dr[i * {n} + j] * ws->ctl_rho[j];
        }}
        ws->ctl_blo[i] = @N@_ctl_lo[i] + s;
        ws->ctl_bhi[i] = @N@_ctl_hi[i] + s;
    }}
"""
                + rate
                + """    rc = @N@_ctl_ldp(ws);
    if (rc == 1) {
        return @U@_QP_INFEASIBLE;
    }
    if (rc == 2) {
        status |= @U@_SOLVER_MAX_ITER;
    }
    @N@_ctl_output(ws, u);
"""
            )
        du = obj.du_max
        clip = []
        if du is not None:
            tables.append(CArray("du", du, "rate bounds du_max"))
            clip += [
                "    if (ws->ctl_has_uprev) {",
                f"        for (i = 0; i < {m}; ++i) {{",
                "            double hi = ws->ctl_uprev[i] + @N@_ctl_du[i], lo = ws->ctl_uprev[i] - @N@_ctl_du[i];",
                "            if (u[i] > hi) { u[i] = hi; }",
                "            if (u[i] < lo) { u[i] = lo; }",
                "        }",
                "    }",
            ]
        clip += [
            f"    for (i = 0; i < {m}; ++i) {{",
            "        if (u[i] > @N@_ctl_u_hi[i]) { u[i] = @N@_ctl_u_hi[i]; }",
            "        if (u[i] < @N@_ctl_u_lo[i]) { u[i] = @N@_ctl_u_lo[i]; }",
            "        if (u[i] <= @N@_ctl_u_lo[i] + 1e-9 * (1.0 + fabs(@N@_ctl_u_lo[i])) ||",
            "            u[i] >= @N@_ctl_u_hi[i] - 1e-9 * (1.0 + fabs(@N@_ctl_u_hi[i]))) {",
            "            status |= @U@_INPUT_CLAMPED; /* on a bound (to the QP's primal tolerance) */",
            "        }",
            "    }",
        ]
        # offset-free (controllers/offset_free.py): u = clip(v - d_hat, u_min, u_max), v the MPC's input (its own
        # previous input for the rate bounds stays v, as Python's)
        offset_free = (
            f"    status &= ~@U@_INPUT_CLAMPED;\n    for (i = 0; i < {m}; ++i) {{\n"
            f"        u[i] -= x_hat[{n} + i];\n"
            "        if (u[i] > @N@_ctl_u_hi[i]) { u[i] = @N@_ctl_u_hi[i]; }\n"
            "        if (u[i] < @N@_ctl_u_lo[i]) { u[i] = @N@_ctl_u_lo[i]; }\n"
            "        if (u[i] <= @N@_ctl_u_lo[i] + 1e-9 * (1.0 + fabs(@N@_ctl_u_lo[i])) ||\n"
            "            u[i] >= @N@_ctl_u_hi[i] - 1e-9 * (1.0 + fabs(@N@_ctl_u_hi[i]))) {\n"
            "            status |= @U@_INPUT_CLAMPED;\n"
            "        }\n    }\n"
        )
        code = (
            (
                gram_table_code(mt, m)
                + ldp_solver_code(mt, min(nz, mt), primal_tol=t.primal_tol, max_iter=MAX_ITER, refactor=False)
                if mt
                else ""
            )
            + "\nvoid @N@_ctl_reset(@N@_workspace *ws) {\n    ws->ctl_has_uprev = 0;\n"
            + ("    ws->ctl_nW = 0;\n" if mt else "")
            + "}\n\n"
            + "int @N@_ctl_step(@N@_workspace *ws, const double *x_hat, const double *ref, double *u) {\n"
            + "    int i, j, status = @U@_OK;\n"
            + ("    int rc;\n" if mt else "")
            + f"    for (i = 0; i < {n}; ++i) {{\n"
            + "        ws->ctl_e0[i] = x_hat[i] - @N@_ctl_x0[i];\n"
            + "        ws->ctl_rho[i] = ref[i] - @N@_ctl_x0[i];\n"
            + "    }\n"
            + f"    for (i = 0; i < {m}; ++i) {{\n        u[i] = @N@_ctl_tc[i];\n    }}\n"
            + matvec("u", "@N@_ctl_Te", "ws->ctl_e0", m, n, op="+=")
            + matvec("u", "@N@_ctl_Tr", "ws->ctl_rho", m, n, op="+=")
            + solve
            + "\n".join(clip)
            + f"\n    memcpy(ws->ctl_uprev, u, {m} * sizeof(double));\n"
            + "    ws->ctl_has_uprev = 1;\n"
            + (offset_free if ctx.x_hat_dim == n + m else "")
            + "    return status;\n}\n"
        )
        summary = (
            f"linear MPC, horizon {obj.N}: the condensed QP ({nz} variables, {mt} rows) solved exactly by a dual "
            "active-set method, warm-started from the previous working set"
        )
        details = (
            f"**Controller (LinearMPC, N = {obj.N})**: each step solves the condensed QP of the Python controller's "
            f"DAQP backend ({nz} variables, {t.ns} of them slacks, {mt} constraint rows) exactly, in its "
            "least-distance form `min ½‖w‖² s.t. ℓ(x̂, r) ≤ M w ≤ h(x̂, r)`, by a dual (Goldfarb–Idnani) active-set "
            "method warm-started from the previous step's working set (DAQP's algorithm and stopping rule, "
            f"primal tolerance {t.primal_tol:g}); the first input of the plan is clipped to the rate and input "
            "bounds. An infeasible QP returns `QP_INFEASIBLE` and holds the previous input."
        )
        return Part("ctl", "LinearMPC", summary, code, tuple(tables), tuple(fields), details=details)
