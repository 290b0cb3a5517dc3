r"""C of the :class:`~shinro_ctrl.controllers.tvlqr.TVLQR`: its gain schedule and plan as tables, the step index in
the workspace.

Step ``k < H``: ``u = u_ref[k] − K[k] (x̂ − x_ref[k])``, saturated; from ``k = H`` on the goal's LQR as the
Python step calls it (without a reference): ``u = (u0 + K x0) − K x̂``, with its own saturation
(status ``PLAN_FINISHED``). The reference given to ``set_reference`` is not used: the plan is the reference.
"""

from __future__ import annotations

import numpy as np

from shinro_ctrl.controllers.tvlqr import TVLQR
from shinro_ctrl.errors import ExportError
from shinro_ctrl.export.lqr import has_bounds
from shinro_ctrl.export.parts import CArray, CField, Part
from shinro_ctrl.export.registry import ExportContext, register_exporter

__all__ = ["TVLQRExporter"]


def _clip(lo: np.ndarray, hi: np.ndarray, lo_name: str, hi_name: str) -> str:
    out = []
    for i in range(lo.shape[0]):
        if np.isfinite(lo[i]):
            out.append(f"    if (u[{i}] < {lo_name}[{i}]) {{ u[{i}] = {lo_name}[{i}]; status |= @U@_INPUT_CLAMPED; }}")
        if np.isfinite(hi[i]):
            out.append(f"    if (u[{i}] > {hi_name}[{i}]) {{ u[{i}] = {hi_name}[{i}]; status |= @U@_INPUT_CLAMPED; }}")
    return "\n".join(out)


@register_exporter(TVLQR)
class TVLQRExporter:
    """Time-varying LQR along a plan, then the goal's LQR."""

    tag = "ctl"

    def part(self, obj: object, ctx: ExportContext) -> Part:
        """The schedule ``K (H, m, n)``, the plan ``x_ref (H, n)``, ``u_ref (H, m)`` and the final LQR."""
        assert isinstance(obj, TVLQR)
        fin = obj.final
        if fin.integral_action is not None:
            raise ExportError("cannot export a TVLQR whose final LQR has integral action")
        H, n, m = obj.horizon, obj.state_dim, obj.input_dim
        sat, fsat = has_bounds(obj.u_min, obj.u_max), has_bounds(fin.u_min, fin.u_max)
        tables = [
            CArray("K", np.asarray(obj.K), "gain schedule K[k] (H x m x n)"),
            CArray("xr", np.asarray(obj.x_ref), "planned states x_ref[k] (H x n)"),
            CArray("ur", np.asarray(obj.u_ref), "planned inputs u_ref[k] (H x m)"),
            CArray("Kf", fin.K, "the goal LQR's gain (m x n)"),
            CArray("x0u", fin.u0 + fin.K @ fin.x0, "the goal LQR's u0 + K x0"),
        ]
        if sat:
            tables += [CArray("u_lo", obj.u_min, "lower input bounds"), CArray("u_hi", obj.u_max, "upper input bounds")]
        if fsat:
            tables += [
                CArray("f_lo", fin.u_min, "the goal LQR's lower bounds"),
                CArray("f_hi", fin.u_max, "the goal LQR's upper bounds"),
            ]
        code = f"""void @N@_ctl_reset(@N@_workspace *ws) {{
    ws->ctl_k = 0;
}}

int @N@_ctl_step(@N@_workspace *ws, const double *x_hat, const double *ref, double *u) {{
    int i, j, status = @U@_OK;
    long k = ws->ctl_k;
    (void)ref;
    if (k < {H}) {{
        ws->ctl_k = k + 1;
        for (i = 0; i < {m}; ++i) {{
            double s = 0.0;
            for (j = 0; j < {n}; ++j) {{
                s += @N@_ctl_K[(k * {m} + i) * {n} + j] * (x_hat[j] - @N@_ctl_xr[k * {n} + j]);
            }}
            u[i] = @N@_ctl_ur[k * {m} + i] - s;
        }}
{_clip(obj.u_min, obj.u_max, "@N@_ctl_u_lo", "@N@_ctl_u_hi") if sat else ""}
        return status;
    }}
    for (i = 0; i < {m}; ++i) {{
        double s = 0.0;
        for (j = 0; j < {n}; ++j) {{
            s += @N@_ctl_Kf[i * {n} + j] * x_hat[j];
        }}
        u[i] = @N@_ctl_x0u[i] - s;
    }}
{_clip(fin.u_min, fin.u_max, "@N@_ctl_f_lo", "@N@_ctl_f_hi") if fsat else ""}
    return status | @U@_PLAN_FINISHED;
}}
"""
        fields = (CField("k", 0, "index of the next step along the plan", ctype="long"),)
        details = (
            f"**Controller (TVLQR)**: along the plan ({H} steps of {obj.dt:g} s), step k applies "
            "`u = u_ref[k] − K[k] (x̂ − x_ref[k])`, saturated; after the plan, the goal's LQR "
            "`u = u0 − K (x̂ − x0)` (status `PLAN_FINISHED`). `reset` restarts the plan; the reference is not used "
            "(the plan is the reference)."
        )
        return Part(
            "ctl",
            "TVLQR",
            f"time-varying LQR along a {H}-step plan, then the goal's LQR",
            code,
            tuple(tables),
            fields,
            details=details,
        )
