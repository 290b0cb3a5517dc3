r"""C of the linear estimators: :class:`FullState` (``x̂ = y``) and the steady-state :class:`KalmanFilter`.

Steady-state Kalman filter, in deviations ``z = x̂ − x0`` (``[x̂; d̂] − [x0; 0]`` with an input
disturbance), exactly as ``KalmanFilter.update`` computes it: the first update after a reset corrects
only, ``z ← z + M (y − y0 − C z)``; every later one is the fused
``z ← Φ z + Γ (u − u0) + M (y − y0)`` with ``Φ = (I − M C) A``, ``Γ = (I − M C) B``, ``y0 = C x0``.
"""

from __future__ import annotations

import numpy as np

from shinro_ctrl.errors import ExportError
from shinro_ctrl.estimators.full_state import FullState
from shinro_ctrl.estimators.kalman import KalmanFilter
from shinro_ctrl.export.parts import CArray, CField, Part
from shinro_ctrl.export.registry import ExportContext, register_exporter

__all__ = ["FullStateExporter", "KalmanFilterExporter", "matvec"]


def matvec(out: str, table: str, vec: str, rows: int, cols: int, *, op: str = "=") -> str:
    """C loop ``out[i] op Σ_j table[i, j] vec[j]`` (the sum accumulated from 0 in index order)."""
    return (
        f"    for (i = 0; i < {rows}; ++i) {{\n"
        "        double s = 0.0;\n"
        f"        for (j = 0; j < {cols}; ++j) {{\n"
        f"            s += {table}[i * {cols} + j] * {vec}[j];\n"
        "        }\n"
        f"        {out}[i] {op} s;\n"
        "    }\n"
    )


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
            raise ExportError(
                "cannot export a time-varying KalmanFilter (steady_state = false): its covariance update needs a "
                "matrix solve per step that the export does not generate; use the steady-state filter"
            )
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


def _indent(code: str) -> str:
    return "".join("    " + line + "\n" if line else "\n" for line in code.splitlines())
