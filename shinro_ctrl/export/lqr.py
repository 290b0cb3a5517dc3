r"""C of :class:`~shinro_ctrl.controllers.lqr.LQR` and its integral action (LQI), as the Python step computes them.

``u = u0 − K (x̂ − r)``; with integral action ``u −= K_i z``; then saturation ``clip(u, u_min, u_max)``
and the integrators' clamped update ``z_j += dt (x̂_j − r_j)`` unless the increment would push a
saturated input further out (``controllers/lqi.py``).
"""

from __future__ import annotations

import numpy as np

from shinro_ctrl.controllers.lqr import LQR
from shinro_ctrl.errors import ExportError
from shinro_ctrl.export.parts import CArray, CField, Part
from shinro_ctrl.export.registry import ExportContext, register_exporter

__all__ = ["LQRExporter", "saturation_code"]


def saturation_code(u_min: np.ndarray, u_max: np.ndarray, var: str = "u", tag: str = "ctl") -> str:
    """C that clips ``var`` to the part's tables ``u_lo``/``u_hi`` (``np.clip``) and ORs INPUT_CLAMPED in ``status``.

    ``np.clip(u, lo, hi)`` is ``min(max(u, lo), hi)``; the entries without a finite bound are skipped at export.
    """
    lines = []
    for i in range(u_min.shape[0]):
        if np.isfinite(u_min[i]):
            lines.append(
                f"    if ({var}[{i}] < @N@_{tag}_u_lo[{i}]) {{ {var}[{i}] = @N@_{tag}_u_lo[{i}]; "
                f"status |= @U@_INPUT_CLAMPED; }}"
            )
        if np.isfinite(u_max[i]):
            lines.append(
                f"    if ({var}[{i}] > @N@_{tag}_u_hi[{i}]) {{ {var}[{i}] = @N@_{tag}_u_hi[{i}]; "
                f"status |= @U@_INPUT_CLAMPED; }}"
            )
    return "\n".join(lines)


def bound_tables(u_min: np.ndarray, u_max: np.ndarray) -> tuple[CArray, ...]:
    """The saturation bounds as tables ``u_lo``, ``u_hi`` (±inf where none)."""
    return (
        CArray("u_lo", np.asarray(u_min, dtype=float), "lower input bounds"),
        CArray("u_hi", np.asarray(u_max, dtype=float), "upper input bounds"),
    )


def has_bounds(u_min: np.ndarray | None, u_max: np.ndarray | None) -> bool:
    """Whether any bound is finite."""
    return u_min is not None and bool(np.any(np.isfinite(u_min)) or np.any(np.isfinite(u_max)))


@register_exporter(LQR)
class LQRExporter:
    """LQR, with or without integral action and saturation."""

    tag = "ctl"

    def part(self, obj: object, ctx: ExportContext) -> Part:
        """The controller part of ``obj`` (an :class:`LQR`)."""
        assert isinstance(obj, LQR)
        if obj.feedforward:
            raise ExportError(
                "cannot export an LQR with feedforward: its input needs the reference's next sample, and the "
                "exported step takes a set-point reference; set feedforward = false"
            )
        n, m = obj.state_dim, obj.input_dim
        lqi = obj.integral_action
        sat = has_bounds(obj.u_min, obj.u_max)
        tables = [
            CArray("K", obj.K, "state-feedback gain K (m x n)"),
            CArray("u0", obj.u0, "operating-point input u0"),
        ]
        fields: list[CField] = []
        if sat:
            tables.extend(bound_tables(obj.u_min, obj.u_max))
        body = [
            f"    for (i = 0; i < {m}; ++i) {{",
            "        double s = 0.0;",
            f"        for (j = 0; j < {n}; ++j) {{",
            f"            s += @N@_ctl_K[i * {n} + j] * (x_hat[j] - ref[j]);",
            "        }",
            "        u[i] = @N@_ctl_u0[i] - s;",
            "    }",
        ]
        reset = "    (void)ws;"
        law = "u = u0 − K (x̂ − r)"
        if lqi is not None:
            q = len(lqi.indices)
            tables.extend(
                [
                    CArray("Ki", lqi.K_i, "integrator gain K_i (m x q)"),
                    CArray("idx", np.asarray(lqi.indices), "integrated state indices", ctype="int"),
                    CArray("dt", np.array([lqi.dt]), "integration step [s]"),
                ]
            )
            fields.append(CField("z", q, "integrators of the tracking errors [state unit * s]"))
            reset = f"    memset(ws->ctl_z, 0, {q} * sizeof(double));"
            law = "u = u0 − K (x̂ − r) − K_i z, integrators z clamped while saturated (anti-windup)"
            body += [
                f"    for (i = 0; i < {m}; ++i) {{",
                "        double s = 0.0;",
                f"        for (j = 0; j < {q}; ++j) {{",
                f"            s += @N@_ctl_Ki[i * {q} + j] * ws->ctl_z[j];",
                "        }",
                "        u[i] -= s;",
                "    }",
                f"    for (j = 0; j < {q}; ++j) {{",
                "        dz[j] = @N@_ctl_dt[0] * (x_hat[@N@_ctl_idx[j]] - ref[@N@_ctl_idx[j]]);",
                "    }",
            ]
            if sat:
                body += [
                    f"    memcpy(v, u, {m} * sizeof(double));",
                    saturation_code(obj.u_min, obj.u_max),
                    "    /* anti-windup: freeze integrator j when its increment pushes a saturated input outward */",
                    f"    for (j = 0; j < {q}; ++j) {{",
                    "        int frozen = 0;",
                    f"        for (i = 0; i < {m}; ++i) {{",
                    "            double over = (v[i] > u[i]) ? 1.0 : ((v[i] < u[i]) ? -1.0 : 0.0);",
                    f"            if (-(@N@_ctl_Ki[i * {q} + j] * dz[j]) * over > 0.0) {{",
                    "                frozen = 1;",
                    "            }",
                    "        }",
                    "        ws->ctl_z[j] += frozen ? 0.0 : dz[j];",
                    "    }",
                ]
            else:
                body += [f"    for (j = 0; j < {q}; ++j) {{", "        ws->ctl_z[j] += dz[j];", "    }"]
            decl = f"    int i, j, status = @U@_OK;\n    double dz[{q}];" + (f"\n    double v[{m}];" if sat else "")
        else:
            if sat:
                body.append(saturation_code(obj.u_min, obj.u_max))
            body.insert(0, "    (void)ws;")
            decl = "    int i, j, status = @U@_OK;"
        if sat:
            law += "; saturated to [u_min, u_max]"
        code = (
            "void @N@_ctl_reset(@N@_workspace *ws) {\n" + reset + "\n}\n\n"
            "int @N@_ctl_step(@N@_workspace *ws, const double *x_hat, const double *ref, double *u) {\n"
            + decl
            + "\n"
            + "\n".join(body)
            + "\n    return status;\n}\n"
        )
        kind = "LQR with integral action (LQI)" if lqi is not None else "LQR"
        details = (
            f"**Controller ({kind})**: `{law}`, with the gain designed in Python (`K` {m}×{n}"
            + (f", `K_i` {m}×{len(lqi.indices)}" if lqi is not None else "")
            + ") written in `"
            + ctx.name
            + "_ctl.c` to 17 significant digits."
        )
        return Part("ctl", kind, law, code, tuple(tables), tuple(fields), details=details)
