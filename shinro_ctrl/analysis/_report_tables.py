"""The HTML tables and style of the design report (see :mod:`shinro_ctrl.analysis.report`)."""

from __future__ import annotations

import html
import math

from shinro_ctrl.analysis.design import DesignAnalysis

_CSS = """
body{font-family:system-ui,-apple-system,Segoe UI,Helvetica,Arial,sans-serif;margin:2em auto;max-width:1000px;
color:#222;line-height:1.4;padding:0 1em}
h1{font-size:1.5em;margin-bottom:.2em}
h2{font-size:1.2em;border-bottom:1px solid #ddd;padding-bottom:.2em;margin-top:1.6em}
table{border-collapse:collapse;margin:.6em 0;font-size:.9em}
th,td{border:1px solid #ccc;padding:.25em .6em;text-align:right;font-variant-numeric:tabular-nums}
th{background:#f3f3f6}td.l,th.l{text-align:left}
.flag{color:#b00;font-weight:600}.ok{color:#060}
.summary{display:flex;flex-wrap:wrap;gap:.8em}.card{border:1px solid #ddd;border-radius:6px;padding:.5em .9em;
background:#fafafc}.card b{display:block;font-size:1.2em}
figure{margin:1em 0}figure img{max-width:100%;height:auto;border:1px solid #eee}figcaption{font-size:.9em;color:#555}
pre{background:#f6f6f6;padding:.6em;overflow-x:auto}
"""


def _num(v: float | None, fmt: str = ".4g") -> str:
    if v is None:
        return "n/a"
    if isinstance(v, float) and math.isnan(v):
        return "–"
    if isinstance(v, float) and math.isinf(v):
        return "∞" if v > 0 else "−∞"
    return format(v, fmt)


def _table(head: list[str], rows: list[list[str]], left: int = 1) -> str:
    th = "".join(f'<th class="l">{h}</th>' if k < left else f"<th>{h}</th>" for k, h in enumerate(head))
    body = []
    for r in rows:
        body.append(
            "<tr>"
            + "".join(f'<td class="l">{c}</td>' if k < left else f"<td>{c}</td>" for k, c in enumerate(r))
            + "</tr>"
        )
    return f"<table><tr>{th}</tr>{''.join(body)}</table>"


def _tables(a: DesignAnalysis) -> str:
    """Every table of the analysis: poles, structure, margins, response metrics, gain."""
    parts = [*_pole_table(a), *_structure_tables(a), *_margin_table(a), *_response_table(a), *_gain_table(a)]
    return "\n".join(parts)


def _pole_table(a: DesignAnalysis) -> list[str]:
    """Closed-loop poles with damping, natural frequency, time constant and flags."""
    e = html.escape
    parts = []
    rows = []
    for r in a.poles.rows:
        p = r.pole
        flags = ", ".join(r.flags)
        rows.append(
            [
                f"{p.real:+.6f} {p.imag:+.6f}j",
                f"{abs(p):.5f}" if a.dt is not None else "",
                f"{r.zeta:.4f}",
                _num(r.wn),
                _num(r.tau),
                f'<span class="flag">{e(flags)}</span>' if flags else '<span class="ok">ok</span>',
            ]
        )
    parts.append("<h2>Closed-loop poles</h2>")
    if a.dt is not None:
        parts.append(f"<p>Continuous equivalents s = ln(z)/dt with dt = {a.dt:g} s; flags: ζ &lt; 0.3 or |z| ≥ 1.</p>")
    parts.append(_table(["pole", "|z|" if a.dt else "", "ζ", "ωn [rad/s]", "τ [s]", "flags"], rows))
    return parts


def _structure_tables(a: DesignAnalysis) -> list[str]:
    """Ranks, Gramian conditions and the PBH test per open-loop mode."""
    e = html.escape
    parts = []
    s = a.structure
    parts.append("<h2>Controllability and observability</h2>")
    meas = f" from the measured states {e(', '.join(a.measured))}" if a.measured else ""
    srows = [
        ["controllability rank", f"{s.controllability_rank} / {s.n}"],
        ["observability rank" + meas, "–" if s.observability_rank is None else f"{s.observability_rank} / {s.n}"],
        [f"Gramian condition, controllability ({e(s.gramian_kind)})", _num(s.gramian_c_cond, ".3g")],
        ["Gramian condition, observability", "–" if s.gramian_o_cond is None else _num(s.gramian_o_cond, ".3g")],
    ]
    parts.append(_table(["", "value"], srows))
    mrows = []
    for md in s.modes:
        lam = md.eigenvalue
        mrows.append(
            [
                f"{lam.real:+.6g} {lam.imag:+.4g}j" + (f" (×{md.multiplicity})" if md.multiplicity > 1 else ""),
                e(md.state),
                "stable" if md.stable else '<span class="flag">unstable</span>',
                f"{md.sigma_c:.2e}",
                "yes" if md.controllable else '<span class="flag">NO</span>',
                "–" if md.sigma_o is None else f"{md.sigma_o:.2e}",
                "–" if md.observable is None else ("yes" if md.observable else '<span class="flag">NO</span>'),
            ]
        )
    parts.append(
        "<p>PBH test per distinct open-loop eigenvalue (×k: repeated k times; σ_min of the balanced "
        "[A − λI, B] and [A − λI; C] relative to their norms):</p>"
    )
    parts.append(
        _table(
            ["λ (open loop)", "dominant state", "", "σ_min [A−λI, B]", "controllable", "σ_min [A−λI; C]", "observable"],
            mrows,
            left=2,
        )
    )
    return parts


def _margin_table(a: DesignAnalysis) -> list[str]:
    """Loop-at-a-time and disk margins per input, with the sensitivity peaks."""
    e = html.escape
    parts = []
    mg = a.margins
    parts.append("<h2>Stability margins (loop broken at the plant input)</h2>")
    crow = []
    for c in mg.channels:
        crow.append(
            [
                e(c.name),
                f"{_num(c.gain_margin_low)} ({_num(c.gain_margin_db[0], '.1f')} dB)",
                f"{_num(c.gain_margin_high)} ({_num(c.gain_margin_db[1], '.1f')} dB)",
                _num(c.w_phase_crossover),
                _num(c.phase_margin, ".1f"),
                _num(c.w_gain_crossover),
                f"{c.disk_margin:.3f}",
                f"[{_num(c.disk_gain_margin[0], '.3g')}, {_num(c.disk_gain_margin[1], '.3g')}]",
                f"±{c.disk_phase_margin:.1f}",
                _num(c.delay_margin, ".4g")
                + ("" if c.delay_margin_samples is None else f" ({_num(c.delay_margin_samples, '.3g')} samples)"),
            ]
        )
    parts.append(
        _table(
            [
                "input",
                "GM low",
                "GM high",
                "ω_pc [rad/s]",
                "PM [°]",
                "ω_gc [rad/s]",
                "disk α",
                "disk gains",
                "disk phase [°]",
                "delay margin [s]",
            ],
            crow,
        )
    )
    parts.append(
        "<p>Gain margins are factors on the input: the loop stays stable for gains in (GM low, GM high), "
        "one loop at a time. The delay margin is the largest pure delay at that input the loop tolerates "
        "(min over the gain crossovers of the phase to −1 over the crossover frequency; MATLAB's allmargin "
        "DelayMargin); in samples of dt for a discrete design. "
        + (
            f"Simultaneous disk margin α = {mg.disk_margin:.3f} (gains [{_num(mg.disk_gain_margin[0], '.3g')}, "
            f"{_num(mg.disk_gain_margin[1], '.3g')}], phase ±{mg.disk_phase_margin:.1f}° on all inputs at once). "
            if len(mg.channels) > 1
            else ""
        )
        + f"Ms = ‖S‖∞ = {mg.Ms:.4g} at {mg.w_Ms:.4g} rad/s; Mt = ‖T‖∞ = {mg.Mt:.4g}.</p>"
    )
    return parts


def _response_table(a: DesignAnalysis) -> list[str]:
    """Rise, overshoot, settling and steady-state error of each linear response."""
    e = html.escape
    parts = []
    parts.append("<h2>Linear closed-loop response metrics</h2>")
    rrows = [
        [e(k), _num(v.rise_time), f"{v.overshoot:.2f}", _num(v.settling_time), _num(v.steady_state_error, ".3g")]
        for k, v in a.responses.items()
    ]
    parts.append(
        _table(["response", "rise 10–90 % [s]", "overshoot [%]", "settling 2 % [s]", "steady-state error"], rrows)
    )
    parts.append(
        "<p>“initial”: the scenario's initial deviation decaying to the operating point (overshoot = swing past it); "
        "“step”: a unit reference step on a tracked state.</p>"
    )
    return parts


def _gain_table(a: DesignAnalysis) -> list[str]:
    """The gain matrix K by input and state."""
    e = html.escape
    parts = []
    parts.append("<h2>Gain K</h2>")
    krows = [[e(a.input_names[i]), *[f"{v:.5g}" for v in a.K[i]]] for i in range(a.K.shape[0])]
    parts.append(_table(["", *map(e, a.state_names)], krows))
    return parts
