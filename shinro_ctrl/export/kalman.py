r"""C of the linear estimators: :class:`FullState` (``x̂ = y``) and the steady-state :class:`KalmanFilter`.

Steady-state Kalman filter, in deviations ``z = x̂ − x0`` (``[x̂; d̂] − [x0; 0]`` with an input
disturbance), exactly as ``KalmanFilter.update`` computes it: the first update after a reset corrects
only, ``z ← z + M (y − y0 − C z)``; every later one is the fused
``z ← Φ z + Γ (u − u0) + M (y − y0)`` with ``Φ = (I − M C) A``, ``Γ = (I − M C) B``, ``y0 = C x0``.
"""

from __future__ import annotations

import numpy as np

from shinro_ctrl.estimators.full_state import FullState
from shinro_ctrl.estimators.kalman import KalmanFilter
from shinro_ctrl.export.parts import CArray, CField, Part, matvec
from shinro_ctrl.export.registry import ExportContext, register_exporter

__all__ = ["FullStateExporter", "KalmanFilterExporter", "matvec"]


@register_exporter(FullState)
class FullStateExporter:
    """Every state measured: the estimate is the measurement."""

    tag = "est"

    def part(self, obj: object, ctx: ExportContext) -> Part:
        """``x̂ = y``."""
        assert isinstance(obj, FullState)
        n = obj.n
        code = (
            "void @N@_est_reset(@N@_workspace *ws, const double *x_hat0) {\n    (void)ws;\n    (void)x_hat0;\n}\n\n"
            "int @N@_est_update(@N@_workspace *ws, const double *y, const double *u_prev, double *x_hat) {\n"
            "    (void)ws;\n    (void)u_prev;\n"
            f"    memcpy(x_hat, y, {n} * sizeof(double));\n    return @U@_OK;\n}}\n"
        )
        return Part(
            "est",
            "FullState",
            "every state measured; the estimate is the measurement",
            code,
            out_dim=n,
            details="**Estimator (full state)**: the measurement is the whole state; `x̂ = y`.",
        )


@register_exporter(KalmanFilter)
class KalmanFilterExporter:
    """The steady-state Kalman filter (with or without the input-disturbance state)."""

    tag = "est"

    def part(self, obj: object, ctx: ExportContext) -> Part:
        """The filter's update in deviations from its operating point (see the module docstring)."""
        assert isinstance(obj, KalmanFilter)
        if not obj.steady_state:
            return _time_varying(obj, ctx)
        n, m, p, N = obj.n, obj.m, obj.p, obj.n_aug
        ImC = np.eye(N) - obj.M @ obj.C
        Phi, Gam = ImC @ obj.A, ImC @ obj.B  # as KalmanFilter._steady_gain forms them
        xoff = np.zeros(N)
        xoff[:n] = obj.x0
        yoff = obj.C[:, :n] @ obj.x0
        tables = (
            CArray("Phi", Phi, "(I - M C) A"),
            CArray("Gam", Gam, "(I - M C) B"),
            CArray("M", obj.M, "filter (innovation) gain M"),
            CArray("C", obj.C, "measurement matrix C"),
            CArray("xoff", xoff, "operating point [x0; 0]"),
            CArray("yoff", yoff, "measurement at the operating point, C x0"),
            CArray("u0", obj.u0, "operating-point input u0"),
        )
        fields = (
            CField("z", N, "estimate in deviations from the operating point"),
            CField("first", 0, "1 until the first update after a reset (which corrects only)", ctype="int"),
        )
        code = (
            "void @N@_est_reset(@N@_workspace *ws, const double *x_hat0) {\n"
            "    int i;\n"
            f"    for (i = 0; i < {N}; ++i) {{\n"
            f"        ws->est_z[i] = (i < {n} ? x_hat0[i] : 0.0) - @N@_est_xoff[i];\n"
            "    }\n"
            "    ws->est_first = 1;\n"
            "}\n\n"
            "int @N@_est_update(@N@_workspace *ws, const double *y, const double *u_prev, double *x_hat) {\n"
            "    int i, j;\n"
            f"    double nu[{p}], zbar[{N}], du[{m}];\n"
            "    if (ws->est_first) {\n"
            "        ws->est_first = 0;\n"
            f"        memcpy(zbar, ws->est_z, {N} * sizeof(double));\n"
            f"        for (i = 0; i < {p}; ++i) {{\n"
            "            nu[i] = y[i] - @N@_est_yoff[i];\n"
            "        }\n"
            + _indent(matvec("nu", "@N@_est_C", "zbar", p, N, op="-="))
            + _indent(matvec("ws->est_z", "@N@_est_M", "nu", N, p))
            + f"        for (i = 0; i < {N}; ++i) {{\n"
            "            ws->est_z[i] += zbar[i];\n"
            "        }\n"
            "    } else {\n"
            f"        for (i = 0; i < {p}; ++i) {{\n"
            "            nu[i] = y[i] - @N@_est_yoff[i];\n"
            "        }\n"
            f"        for (i = 0; i < {m}; ++i) {{\n"
            "            du[i] = u_prev[i] - @N@_est_u0[i];\n"
            "        }\n"
            + _indent(matvec("zbar", "@N@_est_Phi", "ws->est_z", N, N))
            + _indent(matvec("zbar", "@N@_est_Gam", "du", N, m, op="+="))
            + _indent(matvec("zbar", "@N@_est_M", "nu", N, p, op="+="))
            + f"        memcpy(ws->est_z, zbar, {N} * sizeof(double));\n"
            "    }\n"
            f"    for (i = 0; i < {N}; ++i) {{\n"
            "        x_hat[i] = ws->est_z[i] + @N@_est_xoff[i];\n"
            "    }\n"
            "    return @U@_OK;\n"
            "}\n"
        )
        dist = " with an input-disturbance state" if obj.disturbance_model is not None else ""
        summary = f"steady-state Kalman filter{dist}, {p} measurements"
        details = (
            f"**Estimator (steady-state Kalman filter{dist})**: in deviations `z = x̂ − x0`, the first update after "
            "a reset corrects only, `z ← z + M (y − C x0 − C z)`; every later one is "
            "`z ← (I − M C)(A z + B (u_prev − u0)) + M (y − C x0)`."
        )
        return Part("est", "KalmanFilter", summary, code, tables, fields, out_dim=N, details=details)


_TV_HELPERS = """/* out (r x c) = a (r x k) b (k x c); with bt, b is given as (c x k) and used transposed. */
static void @N@_est_mul(const double *a, const double *b, double *out, int r, int k, int c, int bt) {
    int i, j, l;
    for (i = 0; i < r; ++i) {
        for (j = 0; j < c; ++j) {
            double s = 0.0;
            for (l = 0; l < k; ++l) {
                s += a[i * k + l] * (bt ? b[j * k + l] : b[l * c + j]);
            }
            out[i * c + j] = s;
        }
    }
}

/* Solve s x = b in place (s: p x p, overwritten by its LU factors with partial pivoting; b: p x q). */
static int @N@_est_solve(double *s, double *b, int p, int q) {
    int i, j, k, piv;
    for (k = 0; k < p; ++k) {
        double big = fabs(s[k * p + k]);
        piv = k;
        for (i = k + 1; i < p; ++i) {
            if (fabs(s[i * p + k]) > big) {
                big = fabs(s[i * p + k]);
                piv = i;
            }
        }
        if (!(big > 0.0)) {
            return 1;
        }
        if (piv != k) {
            for (j = 0; j < p; ++j) {
                double t = s[k * p + j];
                s[k * p + j] = s[piv * p + j];
                s[piv * p + j] = t;
            }
            for (j = 0; j < q; ++j) {
                double t = b[k * q + j];
                b[k * q + j] = b[piv * q + j];
                b[piv * q + j] = t;
            }
        }
        for (i = k + 1; i < p; ++i) {
            double f = s[i * p + k] / s[k * p + k];
            for (j = k + 1; j < p; ++j) {
                s[i * p + j] -= f * s[k * p + j];
            }
            for (j = 0; j < q; ++j) {
                b[i * q + j] -= f * b[k * q + j];
            }
        }
    }
    for (k = p - 1; k >= 0; --k) {
        for (j = 0; j < q; ++j) {
            double t = b[k * q + j];
            for (i = k + 1; i < p; ++i) {
                t -= s[k * p + i] * b[i * q + j];
            }
            b[k * q + j] = t / s[k * p + k];
        }
    }
    return 0;
}
"""


def _time_varying(obj: KalmanFilter, ctx: ExportContext) -> Part:
    """The time-varying filter: covariance propagated from ``P0``, the gain from a solve each step (LU with partial
    pivoting, as ``numpy.linalg.solve``)."""
    from shinro_ctrl.validation import weight_matrix

    n, m, p, N = obj.n, obj.m, obj.p, obj.n_aug
    P0 = np.eye(N) if ctx.initial_covariance is None else weight_matrix("P0", ctx.initial_covariance, N)
    xoff = np.zeros(N)
    xoff[:n] = obj.x0
    tables = (
        CArray("A", obj.A, "state matrix A"),
        CArray("B", obj.B, "input matrix B"),
        CArray("C", obj.C, "measurement matrix C"),
        CArray("Qw", obj.Qw, "process-noise covariance G Qn G^T"),
        CArray("Rn", obj.Rn, "sensor-noise covariance Rn"),
        CArray("P0", P0, "initial covariance P0"),
        CArray("xoff", xoff, "operating point [x0; 0]"),
        CArray("yoff", obj.C[:, :n] @ obj.x0, "measurement at the operating point, C x0"),
        CArray("u0", obj.u0, "operating-point input u0"),
    )
    fields = (
        CField("z", N, "estimate in deviations from the operating point"),
        CField("P", N * N, "covariance of the estimate"),
        CField("Pm", N * N, "a-priori covariance"),
        CField("T", N * N, "scratch"),
        CField("ImC", N * N, "I - M C"),
        CField("S", p * p, "innovation covariance (LU factors after the solve)"),
        CField("X", p * N, "M^T"),
        CField("MR", N * p, "M Rn"),
        CField("first", 0, "1 until the first update after a reset (which corrects only)", ctype="int"),
    )
    code = (
        _TV_HELPERS
        + f"""
void @N@_est_reset(@N@_workspace *ws, const double *x_hat0) {{
    int i;
    for (i = 0; i < {N}; ++i) {{
        ws->est_z[i] = (i < {n} ? x_hat0[i] : 0.0) - @N@_est_xoff[i];
    }}
    memcpy(ws->est_P, @N@_est_P0, {N * N} * sizeof(double));
    ws->est_first = 1;
}}

int @N@_est_update(@N@_workspace *ws, const double *y, const double *u_prev, double *x_hat) {{
    int i, j;
    double zbar[{N}], du[{m}], nu[{p}];
    if (ws->est_first) {{
        ws->est_first = 0;
        memcpy(zbar, ws->est_z, {N} * sizeof(double));
        memcpy(ws->est_Pm, ws->est_P, {N * N} * sizeof(double));
    }} else {{
        for (i = 0; i < {m}; ++i) {{
            du[i] = u_prev[i] - @N@_est_u0[i];
        }}
        @N@_est_mul(@N@_est_A, ws->est_z, zbar, {N}, {N}, 1, 0);
        for (i = 0; i < {N}; ++i) {{
            double s = 0.0;
            for (j = 0; j < {m}; ++j) {{
                s += @N@_est_B[i * {m} + j] * du[j];
            }}
            zbar[i] += s;
        }}
        @N@_est_mul(@N@_est_A, ws->est_P, ws->est_T, {N}, {N}, {N}, 0);
        @N@_est_mul(ws->est_T, @N@_est_A, ws->est_Pm, {N}, {N}, {N}, 1);
        for (i = 0; i < {N * N}; ++i) {{
            ws->est_Pm[i] += @N@_est_Qw[i];
        }}
    }}
    /* S = C Pm C^T + Rn; M^T = S^-1 (C Pm) */
    @N@_est_mul(@N@_est_C, ws->est_Pm, ws->est_X, {p}, {N}, {N}, 0);
    @N@_est_mul(ws->est_X, @N@_est_C, ws->est_S, {p}, {N}, {p}, 1);
    for (i = 0; i < {p * p}; ++i) {{
        ws->est_S[i] += @N@_est_Rn[i];
    }}
    if (@N@_est_solve(ws->est_S, ws->est_X, {p}, {N}) != 0) {{
        return @U@_NONFINITE_RESULT;
    }}
    /* ImC = I - M C, P = ImC Pm ImC^T + M Rn M^T */
    for (i = 0; i < {N}; ++i) {{
        for (j = 0; j < {N}; ++j) {{
            double s = 0.0;
            int k;
            for (k = 0; k < {p}; ++k) {{
                s += ws->est_X[k * {N} + i] * @N@_est_C[k * {N} + j];
            }}
            ws->est_ImC[i * {N} + j] = (i == j ? 1.0 : 0.0) - s;
        }}
    }}
    @N@_est_mul(ws->est_ImC, ws->est_Pm, ws->est_T, {N}, {N}, {N}, 0);
    @N@_est_mul(ws->est_T, ws->est_ImC, ws->est_P, {N}, {N}, {N}, 1);
    for (i = 0; i < {N}; ++i) {{
        for (j = 0; j < {p}; ++j) {{
            double s = 0.0;
            int k;
            for (k = 0; k < {p}; ++k) {{
                s += ws->est_X[k * {N} + i] * @N@_est_Rn[k * {p} + j];
            }}
            ws->est_MR[i * {p} + j] = s;
        }}
    }}
    for (i = 0; i < {N}; ++i) {{
        for (j = 0; j < {N}; ++j) {{
            double s = 0.0;
            int k;
            for (k = 0; k < {p}; ++k) {{
                s += ws->est_MR[i * {p} + k] * ws->est_X[k * {N} + j];
            }}
            ws->est_P[i * {N} + j] += s;
        }}
    }}
    /* z = zbar + M (y - C x0 - C zbar) */
    for (i = 0; i < {p}; ++i) {{
        double s = 0.0;
        for (j = 0; j < {N}; ++j) {{
            s += @N@_est_C[i * {N} + j] * zbar[j];
        }}
        nu[i] = (y[i] - @N@_est_yoff[i]) - s;
    }}
    for (i = 0; i < {N}; ++i) {{
        double s = 0.0;
        for (j = 0; j < {p}; ++j) {{
            s += ws->est_X[j * {N} + i] * nu[j];
        }}
        ws->est_z[i] = zbar[i] + s;
        x_hat[i] = ws->est_z[i] + @N@_est_xoff[i];
    }}
    return @U@_OK;
}}
"""
    )
    dist = " with an input-disturbance state" if obj.disturbance_model is not None else ""
    details = (
        f"**Estimator (time-varying Kalman filter{dist})**: in deviations `z = x̂ − x0`: predict "
        "`z̄ = A z + B (u_prev − u0)`, `P⁻ = A P Aᵀ + G Qn Gᵀ` (skipped on the first update after a reset, which starts "
        "from `P0`), gain `M = P⁻ Cᵀ (C P⁻ Cᵀ + Rn)⁻¹` (LU with partial pivoting), Joseph-form "
        "`P = (I − M C) P⁻ (I − M C)ᵀ + M Rn Mᵀ`, correct `z = z̄ + M (y − C x0 − C z̄)`."
    )
    return Part(
        "est",
        "KalmanFilter",
        f"time-varying Kalman filter{dist}, {p} measurements",
        code,
        tables,
        fields,
        out_dim=N,
        details=details,
    )


def _indent(code: str) -> str:
    return "".join("    " + line + "\n" if line else "\n" for line in code.splitlines())
