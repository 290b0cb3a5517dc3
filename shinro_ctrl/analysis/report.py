"""A self-contained HTML design report: every table of the analysis and its plots embedded as PNG.

One file, no external resources: the plots are base64 ``data:`` URIs, the
style is inline. It holds the pole map (unit circle and constant-ζ contours),
the Bode magnitude and phase of each loop ``L_i`` with its margins marked,
the Nyquist plot of ``L_i`` around −1, the largest singular values of ``S``
and ``T``, the closed-loop response (the linear model and, when given, the
nonlinear run overlaid, states and inputs), and the tables of
:class:`~shinro_ctrl.analysis.design.DesignAnalysis`.

Plots are drawn on :class:`matplotlib.figure.Figure` with the Agg canvas
directly: the library never selects a matplotlib backend.
"""

from __future__ import annotations

import base64
import html
import io
import math
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from shinro_ctrl.analysis._report_tables import _CSS, _num, _table, _tables
from shinro_ctrl.analysis.design import DesignAnalysis
from shinro_ctrl.analysis.margins import _crossings, _siso_response, frequency_grid, loop_statespace, sensitivity_peaks
from shinro_ctrl.analysis.response import closed_loop_response
from shinro_ctrl.plots.units import axis_label, unit_of

if TYPE_CHECKING:
    from shinro_ctrl.engine.model_gap import ModelGap

__all__ = ["model_gap_section", "render_report", "report_figures", "write_report"]

_LIN = "#1f77b4"
_NL = "#d62728"
_GRID = {"color": "0.85", "linewidth": 0.6}
_BOX = {"boxstyle": "round,pad=0.2", "fc": "white", "ec": "none", "alpha": 0.85}


def _state_label(name: str) -> str:
    """``name [unit]``; an LQI integrator ``∫x`` in the unit of ``x`` times seconds."""
    if name.startswith("∫"):
        unit = unit_of(name[1:])
        return axis_label(name, f"{unit} s" if unit else "s")
    return axis_label(name)


def _figure(w: float, h: float) -> Any:
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(w, h), dpi=100, layout="constrained")
    FigureCanvasAgg(fig)
    return fig


def _png(fig: Any) -> str:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=100)
    return base64.b64encode(buf.getvalue()).decode("ascii")


# ------------------------------------------------------------------ figures
def _splane(ax: Any, s_cl: np.ndarray, s_ol: np.ndarray, title: str) -> None:
    pts = np.concatenate([s_cl, s_ol])
    pts = pts[np.isfinite(pts)]
    r = 1.25 * max(1.0, float(np.max(np.abs(pts)))) if pts.size else 1.0
    for zeta in (0.1, 0.3, 0.5, 0.7, 0.9):
        ang = math.acos(zeta)
        style = {"color": "tab:orange" if zeta == 0.3 else "0.6", "lw": 1.2 if zeta == 0.3 else 0.7, "ls": "--"}
        ax.plot([0, -r * math.cos(ang)], [0, r * math.sin(ang)], **style)
        ax.plot([0, -r * math.cos(ang)], [0, -r * math.sin(ang)], **style)
        reach = 0.9 * min(0.95 * r / max(math.cos(ang), 1e-9), 0.7 * r / max(math.sin(ang), 1e-9))
        ax.annotate(f"ζ={zeta:g}", (-reach * math.cos(ang), reach * math.sin(ang)), fontsize=8, color=style["color"])
    th = np.linspace(np.pi / 2, 3 * np.pi / 2, 100)
    for frac in (0.25, 0.5, 0.75, 1.0):
        ax.plot(frac * r / 1.25 * np.cos(th), frac * r / 1.25 * np.sin(th), color="0.85", lw=0.6, ls=":")
    ax.axvline(0, color="k", lw=1.0)
    ax.plot(s_ol.real, s_ol.imag, "x", color="0.3", ms=9, mew=1.6, label="open loop")
    ax.plot(s_cl.real, s_cl.imag, "o", color=_LIN, mfc="none", ms=9, mew=1.8, label="closed loop")
    right = max(0.15 * r, 1.1 * float(np.max(s_ol.real[np.isfinite(s_ol)], initial=0.0)))
    ax.set_xlim(-r, right)
    ax.set_ylim(-0.75 * r, 0.75 * r)
    ax.set_xlabel("Re s [1/s]")
    ax.set_ylabel("Im s [rad/s]")
    ax.set_title(title, fontsize=10)
    ax.grid(True, **_GRID)
    ax.legend(loc="lower left", fontsize=8)


def _pole_map(a: DesignAnalysis) -> Any:
    cl = np.linalg.eigvals(a.A - a.B @ a.K)
    ol = np.linalg.eigvals(a.A)
    if a.dt is None:
        fig = _figure(6.0, 5.0)
        _splane(fig.add_subplot(), cl, ol, "Poles in the s-plane (dotted: constant ωn)")
        return fig
    fig = _figure(10.0, 5.0)
    ax, ax2 = fig.subplots(1, 2)
    th = np.linspace(0, 2 * np.pi, 400)
    ax.plot(np.cos(th), np.sin(th), color="k", lw=1.0)
    for zeta in (0.1, 0.3, 0.5, 0.7, 0.9):
        wd = np.linspace(0, np.pi, 200)  # ωd dt from 0 to π
        sig = zeta / math.sqrt(1 - zeta**2) * wd
        z = np.exp(-sig + 1j * wd)
        style = {"color": "tab:orange" if zeta == 0.3 else "0.6", "lw": 1.2 if zeta == 0.3 else 0.7, "ls": "--"}
        ax.plot(z.real, z.imag, **style)
        ax.plot(z.real, -z.imag, **style)
        ax.annotate(f"ζ={zeta:g}", (z.real[70], z.imag[70]), fontsize=8, color=style["color"])
    for frac in (0.1, 0.2, 0.3, 0.5):  # constant ωn = frac · π/dt
        zeta = np.linspace(0, 1, 100)
        z = np.exp(frac * np.pi * (-zeta + 1j * np.sqrt(1 - zeta**2)))
        ax.plot(z.real, z.imag, color="0.8", lw=0.6, ls=":")
        ax.plot(z.real, -z.imag, color="0.8", lw=0.6, ls=":")
    ax.plot(ol.real, ol.imag, "x", color="0.3", ms=9, mew=1.6, label="open loop A")
    ax.plot(cl.real, cl.imag, "o", color=_LIN, mfc="none", ms=9, mew=1.8, label="closed loop A − BK")
    lim = min(3.0, max(1.1, float(np.max(np.abs(np.concatenate([cl, ol])))) * 1.05))
    ax.set_xlim(-lim, lim)
    ax.set_ylim(-lim, lim)
    ax.set_aspect("equal")
    ax.set_xlabel("Re z")
    ax.set_ylabel("Im z")
    ax.set_title(f"z-plane, dt = {a.dt:g} s (dotted: ωn = 0.1…0.5 π/dt)", fontsize=10)
    ax.grid(True, **_GRID)
    ax.legend(loc="lower left", fontsize=8)
    with np.errstate(divide="ignore"):
        s_cl = np.log(cl.astype(complex)) / a.dt
        s_ol = np.log(ol.astype(complex)) / a.dt
    _splane(ax2, s_cl, s_ol, "Continuous equivalents s = ln(z)/dt (dotted: constant ωn)")
    return fig


def _bode(a: DesignAnalysis, w: np.ndarray) -> Any:
    m = a.B.shape[1]
    fig = _figure(7.6, 2.2 + 2.6 * m)
    axes = fig.subplots(2 * m, 1, sharex=True, squeeze=False)[:, 0]
    for i in range(m):
        Li = loop_statespace(a.A, a.B, a.K, a.dt, i)
        Lw = _siso_response(Li, a.dt, w)
        mag = 20 * np.log10(np.abs(Lw))
        ph = np.degrees(np.unwrap(np.angle(Lw)))
        c = a.margins.channels[i]
        axm, axp = axes[2 * i], axes[2 * i + 1]
        axm.semilogx(w, mag, color=_LIN, lw=1.6)
        axm.axhline(0, color="k", lw=0.8)
        fin = mag[np.isfinite(mag)]
        if fin.size:  # an integrator makes |L| huge at low frequency: keep the crossover region readable
            axm.set_ylim(max(float(fin.min()) - 10.0, -80.0), min(float(fin.max()) + 10.0, 60.0))
        axm.set_ylabel("|L| [dB]")
        axm.set_title(f"Loop at input '{c.name}': L = K (zI − A)⁻¹ B, other inputs closed", fontsize=10)
        # wrap the phase so that −180° lies in view near the crossovers
        shift = 360.0 * np.round((np.median(ph) + 180.0) / 360.0)
        ph = ph - shift
        axp.semilogx(w, ph, color=_LIN, lw=1.6)
        axp.set_ylabel("∠L [deg]")
        for k in range(-3, 3):
            if ph.min() - 30 < -180 + 360 * k < ph.max() + 30:
                axp.axhline(-180 + 360 * k, color="k", lw=0.8, ls="--")
        if math.isfinite(c.w_gain_crossover):
            axm.axvline(c.w_gain_crossover, color="tab:green", lw=1.0, ls=":")
            axp.axvline(c.w_gain_crossover, color="tab:green", lw=1.0, ls=":")
            left = c.w_gain_crossover > math.sqrt(w[0] * w[-1]) * 10
            axp.annotate(
                f"PM = {c.phase_margin:.1f}° at {c.w_gain_crossover:.3g} rad/s",
                (c.w_gain_crossover, float(np.interp(c.w_gain_crossover, w, ph))),
                xytext=(-30 if left else 8, -40),
                ha="right" if left else "left",
                textcoords="offset points",
                bbox=_BOX,
                fontsize=8,
                color="tab:green",
                arrowprops={"arrowstyle": "->", "color": "tab:green"},
            )
        Li_ = loop_statespace(a.A, a.B, a.K, a.dt, i)
        crit, _ = _crossings(Li_, a.dt, w)
        for g, f in crit:
            if f <= 0 or not (w[0] <= f <= w[-1] * 1.0001):
                continue
            axm.axvline(f, color="tab:red", lw=1.0, ls=":")
            left = f > math.sqrt(w[0] * w[-1]) * 10
            axm.annotate(
                f"GM ×{g:.3g} ({20 * math.log10(g):+.1f} dB) at {f:.3g} rad/s",
                (f, -20 * math.log10(g)),
                xytext=(-12 if left else 8, 14),
                ha="right" if left else "left",
                textcoords="offset points",
                bbox=_BOX,
                fontsize=8,
                color="tab:red",
                arrowprops={"arrowstyle": "->", "color": "tab:red"},
            )
        for ax in (axm, axp):
            ax.grid(True, which="both", **_GRID)
            if a.dt is not None:
                ax.axvline(math.pi / a.dt, color="0.5", lw=0.8)
    axes[-1].set_xlabel("ω [rad/s]" + ("  (grey line: Nyquist π/dt)" if a.dt is not None else ""))
    return fig


def _nyquist(a: DesignAnalysis, w: np.ndarray) -> Any:
    m = a.B.shape[1]
    cols = min(m, 2)
    rows = math.ceil(m / cols)
    fig = _figure(5.2 * cols, 4.8 * rows)
    axes = np.atleast_1d(fig.subplots(rows, cols, squeeze=False).ravel())
    for i in range(m):
        ax = axes[i]
        Li = loop_statespace(a.A, a.B, a.K, a.dt, i)
        Lw = _siso_response(Li, a.dt, w)
        ok = np.isfinite(Lw)
        ax.plot(Lw.real[ok], Lw.imag[ok], color=_LIN, lw=1.5, label="L(z), |z| = 1, ω > 0" if a.dt else "L(jω), ω > 0")
        ax.plot(Lw.real[ok], -Lw.imag[ok], color=_LIN, lw=1.0, ls="--", label="ω < 0")
        th = np.linspace(0, 2 * np.pi, 300)
        ax.plot(np.cos(th), np.sin(th), color="0.7", lw=0.8)
        c = a.margins.channels[i]
        alpha = c.disk_margin
        if 0 < alpha < 2:  # the balanced disk: L stays outside the image of the disk of size α around −1
            lo, hi = c.disk_gain_margin
            cen = -0.5 * (1 / lo + 1 / hi) if math.isfinite(hi) and lo > 0 else None
            if cen is not None:
                rad = 0.5 * abs(1 / lo - 1 / hi)
                ax.fill(
                    cen + rad * np.cos(th),
                    rad * np.sin(th),
                    color="tab:orange",
                    alpha=0.15,
                    lw=0,
                    label="disk-margin region (L avoids it)",
                )
        ax.plot([-1], [0], "+", color="tab:red", ms=14, mew=2)
        ax.set_xlim(-3.5, 2.0)
        ax.set_ylim(-2.75, 2.75)
        ax.set_aspect("equal")
        ax.grid(True, **_GRID)
        ax.set_title(f"Nyquist of L at '{c.name}' (zoomed on −1)", fontsize=10)
        ax.set_xlabel("Re L")
        ax.set_ylabel("Im L")
        ax.legend(loc="upper right", fontsize=7)
        ax.annotate(f"disk margin α = {alpha:.3f}", (0.02, 0.03), xycoords="axes fraction", fontsize=8)
    for j in range(m, len(axes)):
        axes[j].set_visible(False)
    return fig


def _sigma(a: DesignAnalysis, w: np.ndarray) -> Any:
    fig = _figure(7.6, 3.6)
    ax = fig.add_subplot()
    s, t = sensitivity_peaks(a.A, a.B, a.K, a.dt, w)
    ax.semilogx(w, 20 * np.log10(s), color=_LIN, lw=1.6, label="σ̄(S), S = (I + L)⁻¹")
    ax.semilogx(w, 20 * np.log10(t), color="tab:purple", lw=1.6, label="σ̄(T), T = I − S")
    ax.axhline(0, color="k", lw=0.8)
    mg = a.margins
    ax.plot([mg.w_Ms], [20 * math.log10(mg.Ms)], "o", color=_LIN)
    ax.annotate(
        f"Ms = {mg.Ms:.3g} ({20 * math.log10(mg.Ms):.1f} dB)",
        (mg.w_Ms, 20 * math.log10(mg.Ms)),
        xytext=(-150, -30),
        textcoords="offset points",
        bbox=_BOX,
        fontsize=8,
        arrowprops={"arrowstyle": "->"},
    )
    ax.set_ylim(max(-80.0, ax.get_ylim()[0]), max(10.0, 20 * math.log10(max(mg.Ms, mg.Mt)) + 8))
    if a.dt is not None:
        ax.axvline(math.pi / a.dt, color="0.5", lw=0.8)
    ax.set_xlabel("ω [rad/s]")
    ax.set_ylabel("singular value [dB]")
    ax.set_title("Largest singular values of S and T at the plant input")
    ax.grid(True, which="both", **_GRID)
    ax.legend(fontsize=8)
    return fig


def _responses(a: DesignAnalysis, nonlinear: Any, x_ref: Any, u_min: Any, u_max: Any) -> Any:
    n, m = a.B.shape
    x0 = a.x0 if a.x0 is not None else np.zeros(n)
    u0 = a.u0 if a.u0 is not None else np.zeros(m)
    if nonlinear is not None and a.dt is not None:
        t_nl, x_nl, u_nl = (np.asarray(v, dtype=float) for v in nonlinear)
        t = t_nl
        d0 = np.zeros(n)
        d0[: x_nl.shape[1]] = x_nl[0] - x0[: x_nl.shape[1]]  # integrators (LQI) start empty
        dX = closed_loop_response(a.A, a.B, a.K, d0, len(t) - 1)
    else:
        t_nl = x_nl = u_nl = None
        t = a.t
        dX = a.x_lin - x0
    x_lin = dX + x0
    u_lin = u0 - dX @ a.K.T
    panels = n + m
    cols = 2
    rows = math.ceil(panels / cols)
    fig = _figure(9.6, 2.1 * rows + 0.6)
    axes = fig.subplots(rows, cols, sharex=True, squeeze=False).ravel()
    for i in range(n):
        ax = axes[i]
        ax.plot(t, x_lin[:, i], color=_LIN, lw=1.6, label="linear model")
        if x_nl is not None and i < x_nl.shape[1]:
            ax.plot(t_nl, x_nl[:, i], color=_NL, lw=1.2, ls="--", label="nonlinear (standalone)")
        if x_ref is not None and i < np.shape(x_ref)[1]:
            ax.plot(
                t_nl if t_nl is not None else t, np.asarray(x_ref)[:, i], color="0.5", lw=0.8, ls=":", label="reference"
            )
        ax.set_ylabel(_state_label(a.state_names[i]))
        ax.grid(True, **_GRID)
    for j in range(m):
        ax = axes[n + j]
        ax.step(t[:-1], u_lin[:-1, j], where="post", color=_LIN, lw=1.6, label="linear model")
        if u_nl is not None:
            ax.step(t_nl[:-1], u_nl[:, j], where="post", color=_NL, lw=1.2, ls="--", label="nonlinear (standalone)")
        for b in (u_min, u_max):
            if b is not None and np.isfinite(np.asarray(b, dtype=float)[j]):
                ax.axhline(float(np.asarray(b)[j]), color="k", lw=0.8, ls="-.")
        ax.set_ylabel(axis_label(a.input_names[j], is_input=True) + " (input)")
        ax.grid(True, **_GRID)
    for k in range(panels, len(axes)):
        axes[k].set_visible(False)
    for ax in axes[max(0, panels - cols) : panels]:
        ax.set_xlabel("t [s]")
        ax.tick_params(labelbottom=True)
    axes[0].legend(fontsize=8, loc="best")
    fig.suptitle("Closed-loop response from the scenario's initial state", fontsize=11)
    return fig


def report_figures(
    analysis: DesignAnalysis,
    *,
    nonlinear: Any = None,
    x_ref: Any = None,
    u_min: Any = None,
    u_max: Any = None,
) -> dict[str, Any]:
    """The report's figures (matplotlib ``Figure`` objects, Agg canvas), by caption."""
    w = frequency_grid(analysis.dt, analysis.A, 1200)
    return {
        "Pole map": _pole_map(analysis),
        "Bode plot of the loop at each input": _bode(analysis, w),
        "Nyquist plot of the loop at each input": _nyquist(analysis, w),
        "Sensitivity and complementary sensitivity": _sigma(analysis, w),
        "Closed-loop response: linear model and nonlinear run": _responses(analysis, nonlinear, x_ref, u_min, u_max),
    }


def render_report(
    analysis: DesignAnalysis,
    *,
    title: str = "Design report",
    description: str = "",
    nonlinear: Any = None,
    x_ref: Any = None,
    u_min: Any = None,
    u_max: Any = None,
    model_gap: ModelGap | None = None,
) -> str:
    """The report as one HTML string (see :func:`write_report`)."""
    e = html.escape
    a = analysis
    figs = report_figures(a, nonlinear=nonlinear, x_ref=x_ref, u_min=u_min, u_max=u_max)
    lo, hi = a.poles.wn_range
    cards = [
        ("ζ_min", f"{a.poles.zeta_min:.3f}"),
        ("ωn [rad/s]", f"{_num(lo)} – {_num(hi)}"),
        ("disk margin α", f"{a.margins.disk_margin:.3f}"),
        ("min PM [°]", _num(min(c.phase_margin for c in a.margins.channels), ".1f")),
        ("min delay margin [s]", _num(min(c.delay_margin for c in a.margins.channels), ".3g")),
        ("Ms", f"{a.margins.Ms:.3g}"),
        ("controllable", "yes" if a.structure.controllable else "NO"),
    ]
    out = [
        "<!DOCTYPE html>",
        '<html lang="en"><head><meta charset="utf-8"><meta name="generator" content="shinro-ctrl">',
        f"<title>{e(title)}</title><style>{_CSS}</style></head><body>",
        f"<h1>{e(title)}</h1>",
        f"<p>{e(description)}</p>" if description else "",
        '<div class="summary">' + "".join(f'<div class="card">{e(k)}<b>{e(v)}</b></div>' for k, v in cards) + "</div>",
    ]
    for caption, fig in figs.items():
        out.append(
            f'<figure><img alt="{e(caption)}" src="data:image/png;base64,{_png(fig)}">'
            f"<figcaption>{e(caption)}</figcaption></figure>"
        )
        if caption == "Pole map":
            out.append(_tables(a))
    if model_gap is not None:
        out.append(model_gap_section(model_gap))
    out.append("</body></html>")
    return "\n".join(out)


def write_report(path: str | Path, analysis: DesignAnalysis, **kwargs: Any) -> Path:
    """Write the self-contained HTML report to ``path`` (atomically; parent folders created).

    Args:
        path: Output ``.html`` file.
        analysis: A :class:`~shinro_ctrl.analysis.design.DesignAnalysis`.
        **kwargs: ``title``, ``description``, ``nonlinear=(t (T+1,), x (T+1, n), u (T, m))``
            of a nonlinear run to overlay, its ``x_ref (T+1, n)``, ``u_min``/``u_max (m,)``;
            ``model_gap``: a :class:`~shinro_ctrl.engine.model_gap.ModelGap` for a "Model gap" section
            (what the smooth design model leaves out of the model file at the operating point).

    Returns:
        The path written.
    """
    from shinro_ctrl.files import write_output

    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    text = render_report(analysis, **kwargs)
    write_output(
        p, lambda f: f.write(text), what="report", kind="HTML report"
    )  # only over a report of ours (the meta tag)
    return p


# ------------------------------------------------------------------ model gap
def _pct(v: float | None) -> str:
    return "—" if v is None else ("−∞" if math.isinf(v) else f"{100 * v:.1f} %")


def _range(r: tuple[float, float] | None) -> str:
    return "—" if r is None else f"[{r[0]:.4g}, {r[1]:.4g}]"


def model_gap_section(gap: ModelGap) -> str:
    """The HTML "Model gap" section of the design report: the warnings, then the joint, actuator and contact rows
    of a :class:`~shinro_ctrl.engine.model_gap.ModelGap` (what the smooth design model leaves out)."""
    e = html.escape
    t = gap.thresholds
    parts = [
        "<h2>Model gap: what the smooth design model leaves out</h2>",
        f"<p>Measured by MuJoCo on {e(gap.model)} at the operating point. Warnings: friction loss above "
        f"{t.friction:.0%} of the joint's load torque τ<sub>load</sub> = qfrc_bias − qfrc_passive, u0 or its force "
        f"within {t.clamp:.0%} of a clamp, any contact, a joint within {t.limit:.0%} of a limit, a soft equality "
        f"sagging by more than {t.equality:g} (m or rad).</p>",
    ]
    if gap.warnings:
        items = "".join(
            f'<li><span class="flag">{e(w.level)}</span>: {e(w.message)}</li>'
            if w.level == "error"
            else f"<li>{e(w.level)}: {e(w.message)}</li>"
            for w in gap.warnings
        )
        parts.append(f"<ul>{items}</ul>")
    else:
        parts.append('<p class="ok">No effect above its threshold.</p>')
    rows = []
    for d in gap.dofs:
        ratio = d.friction_ratio
        fr = "—" if ratio is None else ("∞" if math.isinf(ratio) else f"{100 * ratio:.1f} %")
        rows.append(
            [
                e(d.name),
                _num(d.q),
                _range(d.range),
                _pct(d.limit_margin),
                _num(d.load),
                _num(d.actuator),
                _num(d.frictionloss) if d.frictionloss else "—",
                fr + (' <span class="flag">holds</span>' if d.friction_holds else ""),
            ]
        )
    head = ["joint", "q", "range", "limit margin", "load τ", "actuator τ at u0", "frictionloss", "friction / load"]
    parts.append(_table(head, rows))
    rows = [
        [
            e(a.name),
            _num(a.ctrl),
            _range(a.ctrlrange),
            _pct(a.ctrl_margin),
            _num(a.force),
            _range(a.forcerange),
            _pct(a.force_margin),
            _num(a.applied_force),
        ]
        for a in gap.actuators
    ]
    head = ["actuator", "u0", "ctrlrange", "margin", "force (smooth)", "forcerange", "margin", "force MuJoCo applies"]
    if any(a.act is not None for a in gap.actuators):  # activation dynamics: MuJoCo clamps act to actrange
        head += ["activation", "actrange", "margin"]
        for r, a in zip(rows, gap.actuators, strict=True):
            r += [_num(a.act), _range(a.actrange), _pct(a.act_margin)]
    parts.append(_table(head, rows))
    if gap.contacts:
        rows = [[e(c.geom1), e(c.geom2), _num(c.dist)] for c in gap.contacts]
        parts.append(
            f"<p>{gap.n_contacts} contact(s) at x0, max penetration {_num(gap.max_penetration)} m "
            "(the design model has none):</p>"
        )
        parts.append(_table(["geom", "geom", "distance [m]"], rows, left=2))
    else:
        parts.append("<p>No contacts at x0.</p>")
    if gap.tendons:
        rows = [
            [
                e(g.name),
                _num(g.length),
                _range(g.range),
                _pct(g.limit_margin),
                _num(g.load),
                _num(g.frictionloss) if g.frictionloss else "—",
                "—" if g.friction_ratio is None else _pct(g.friction_ratio),
            ]
            for g in gap.tendons
        ]
        parts.append("<p>Tendons with friction loss or a range (MuJoCo only):</p>")
        parts.append(
            _table(["tendon", "length", "range", "limit margin", "load", "frictionloss", "friction / load"], rows)
        )
    if gap.equalities:
        rows = [[e(q.name), e(q.kind), _num(q.violation, ".3g"), _num(q.sag, ".3g")] for q in gap.equalities]
        parts.append("<p>Equality constraints: exact in the design model, soft in MuJoCo (solref/solimp):</p>")
        parts.append(_table(["equality", "type", "violation at x0", "static sag under the load"], rows))
    return "\n".join(parts)
