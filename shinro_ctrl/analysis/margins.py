"""Robustness of a state-feedback loop broken at the plant input.

With ``u = −K x`` on ``x_{k+1} = A x_k + B u_k`` the loop broken at the plant
input has the return ratio

    L(z) = K (zI − A)⁻¹ B    (m × m),

so that the loop is ``u = −L u``. Per input channel ``i`` the other channels
stay closed and ``L_i(z) = K_i (zI − A + B_{−i} K_{−i})⁻¹ B_i`` is the SISO
loop seen at that input (loop-at-a-time). This module reports, per channel,

* the classical gain margins (the gain factors below and above 1 at which the
  loop goes unstable) and the phase margin, with their crossover frequencies
  (``control.stability_margins``);
* the disk margin α (``control.disk_margins``, balanced skew σ = 0): the loop
  tolerates any simultaneous gain and phase change ``f`` in the disk
  ``|(f − 1)/(f + 1)| < α/2``, i.e. gains in ``[(2 − α)/(2 + α), (2 + α)/(2 − α)]``
  and phases up to ``2 atan(α/2)``;

* the delay margin: the largest pure delay ``τ`` the loop tolerates,
  ``L_i → L_i e^{−jωτ}`` (``L_i z^{−d}`` when discrete, ``d = τ/dt`` samples).
  A delay rotates ``L_i(jω)`` clockwise by ``ωτ`` and leaves ``|L_i|`` alone,
  so the loop first reaches ``−1`` at a gain crossover ``ω_c`` (``|L_i| = 1``)
  once ``ω_c τ`` equals the clockwise rotation from ``L_i(jω_c)`` to ``−1``,
  ``θ_c = (∠L_i(jω_c) + 180°) mod 360°``. Hence, as MATLAB's ``allmargin``
  ``DelayMargin`` (the reference), ``τ_max = min_c θ_c / ω_c`` [s], and
  ``τ_max / dt`` in samples for a discrete loop: every delay ``< τ_max``
  (every whole number of samples ``< τ_max/dt``) keeps the loop stable.
  With one crossover ``θ_c`` is the phase margin; for ``L(s) = k/s``,
  ``τ_max = (π/2)/k``;

and for the whole MIMO loop the simultaneous disk margin (all channels at
once), the sensitivity peak ``Ms = ‖S‖∞ = max_ω σ̄((I + L(e^{jω dt}))⁻¹)`` and
the complementary peak ``Mt = ‖T‖∞``, ``T = I − S``. Frequencies are in rad/s
(discrete loops up to the Nyquist frequency ``π/dt``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from shinro_ctrl.errors import InvalidArgument
from shinro_ctrl.validation import as_matrix, state_space

__all__ = [
    "ChannelMargins",
    "LoopMargins",
    "delay_margin",
    "frequency_grid",
    "loop_margins",
    "loop_statespace",
    "sensitivity_peaks",
    "simultaneous_disk_margin",
]


@dataclass(frozen=True)
class ChannelMargins:
    """Margins of one input channel (loop-at-a-time).

    Attributes:
        name: Input name.
        gain_margin_low: Largest gain factor below 1 that destabilizes the loop (0 if none).
        gain_margin_high: Smallest gain factor above 1 that destabilizes it (``inf`` if none).
        phase_margin: Smallest phase margin over the gain crossovers [deg] (``inf`` if |L| never crosses 1).
        w_phase_crossover: Frequency of the binding gain margin [rad/s] (nan if none).
        w_gain_crossover: Frequency of the phase margin [rad/s] (nan if none).
        disk_margin: Disk margin α (balanced).
        disk_gain_margin: ``(low, high)`` gain factors it guarantees.
        disk_phase_margin: Phase it guarantees [deg].
        delay_margin: Largest pure delay the loop tolerates [s] (``inf`` if |L| never crosses 1).
        delay_margin_samples: The same in samples of ``dt`` for a discrete loop (None: continuous).
        w_delay_margin: Gain crossover frequency that binds the delay margin [rad/s] (nan if none).
    """

    name: str
    gain_margin_low: float
    gain_margin_high: float
    phase_margin: float
    w_phase_crossover: float
    w_gain_crossover: float
    disk_margin: float
    disk_gain_margin: tuple[float, float]
    disk_phase_margin: float
    delay_margin: float = math.inf
    delay_margin_samples: float | None = None
    w_delay_margin: float = math.nan

    @property
    def gain_margin_db(self) -> tuple[float, float]:
        """``(low, high)`` gain margins in dB (−inf / +inf where unbounded)."""
        return (_db(self.gain_margin_low), _db(self.gain_margin_high))


@dataclass(frozen=True)
class LoopMargins:
    """Result of :func:`loop_margins`.

    Attributes:
        channels: One :class:`ChannelMargins` per input.
        disk_margin: Simultaneous (all channels at once) disk margin α.
        disk_gain_margin: ``(low, high)`` guaranteed simultaneous gain factors.
        disk_phase_margin: Guaranteed simultaneous phase [deg].
        Ms: Sensitivity peak ``‖S‖∞``.
        w_Ms: Frequency of the peak [rad/s].
        Mt: Complementary sensitivity peak ``‖T‖∞``.
        dt: Sampling time [s] (None: continuous).
    """

    channels: tuple[ChannelMargins, ...]
    disk_margin: float
    disk_gain_margin: tuple[float, float]
    disk_phase_margin: float
    Ms: float
    w_Ms: float
    Mt: float
    dt: float | None

    def format(self) -> str:
        """A text table, one row per channel plus the MIMO figures."""
        w = max([10, *(len(c.name) for c in self.channels)])  # names whole (elbow_motor), columns aligned
        head = (
            f"  {'input':{w}s} {'GM low':>9s} {'GM high':>9s} {'ω_pc':>8s} {'PM [°]':>8s} {'ω_gc':>8s} "
            f"{'disk α':>7s} {'disk GM':>15s} {'disk PM':>8s} {'DM [s]':>9s}"
            + (f" {'DM [smp]':>8s}" if self.dt is not None else "")
        )
        lines = [head]
        for c in self.channels:
            lines.append(
                f"  {c.name:{w}s} {_f(c.gain_margin_low):>9s} {_f(c.gain_margin_high):>9s} "
                f"{_f(c.w_phase_crossover):>8s} {_f(c.phase_margin):>8s} {_f(c.w_gain_crossover):>8s} "
                f"{c.disk_margin:7.3f} {_pair(c.disk_gain_margin):>15s} {c.disk_phase_margin:7.1f}° "
                f"{_f(c.delay_margin):>9s}"
                + (f" {_f(c.delay_margin_samples or math.inf):>8s}" if self.dt is not None else "")
            )
        lines.append("  (gain margins as factors: the loop stays stable for input gains in (GM low, GM high))")
        lines.append(
            "  (DM: delay margin, the largest pure delay at that input the loop tolerates"
            + (" [s] and [samples of dt])" if self.dt else " [s])")
        )
        if len(self.channels) > 1:
            lines.append(
                f"  simultaneous disk margin α = {self.disk_margin:.3f}: gains {_pair(self.disk_gain_margin)}, "
                f"phase ±{self.disk_phase_margin:.1f}°"
            )
        lines.append(f"  Ms = ‖S‖∞ = {self.Ms:.4g} at {self.w_Ms:.4g} rad/s, Mt = ‖T‖∞ = {self.Mt:.4g}")
        return "\n".join(lines)


def _db(v: float) -> float:
    if v <= 0:
        return -math.inf
    return 20.0 * math.log10(v) if math.isfinite(v) else math.inf


def _f(v: float) -> str:
    if math.isnan(v):
        return "-"
    if math.isinf(v):
        return "inf"
    return f"{v:.4g}"


def _pair(p: tuple[float, float]) -> str:
    return f"[{_f(p[0])}, {_f(p[1])}]"


def _model_parts(model: Any, dt: float | None) -> tuple[np.ndarray, np.ndarray, float | None, tuple[str, ...]]:
    """``(A, B, dt, input_names)`` from a LinearModel, a python-control StateSpace or an ``(A, B)`` pair."""
    if hasattr(model, "A_c") and hasattr(model, "dt"):  # LinearModel
        names = tuple(getattr(model, "input_names", None) or ())
        return np.asarray(model.A, float), np.asarray(model.B, float), float(model.dt), names
    if hasattr(model, "A") and hasattr(model, "B") and hasattr(model, "ninputs"):  # control.StateSpace
        sdt = model.dt
        d = None if (sdt is None or sdt == 0) else (float(sdt) if sdt is not True else None)
        if sdt is True:
            raise InvalidArgument("loop_margins: the StateSpace has an unspecified sampling time (dt=True)")
        names = tuple(model.input_labels) if hasattr(model, "input_labels") else ()
        return np.asarray(model.A, float), np.asarray(model.B, float), d, names
    if isinstance(model, tuple | list) and len(model) == 2:
        A, B = state_space(*model)
        return A, B, dt, ()
    raise InvalidArgument(
        f"loop_margins: model must be a LinearModel, a control.StateSpace or an (A, B) pair, got {type(model).__name__}"
    )


def loop_statespace(A: np.ndarray, B: np.ndarray, K: np.ndarray, dt: float | None, channel: int | None = None) -> Any:
    """``L(z) = K (zI − A)⁻¹ B`` as a python-control StateSpace; with ``channel`` the SISO loop at that input."""
    import control

    sdt = 0 if dt is None else dt
    if channel is None:
        return control.ss(A, B, K, np.zeros((K.shape[0], B.shape[1])), sdt)
    others = [j for j in range(B.shape[1]) if j != channel]
    Ai = A - B[:, others] @ K[others, :] if others else A
    return control.ss(Ai, B[:, [channel]], K[[channel], :], np.zeros((1, 1)), sdt)


def frequency_grid(dt: float | None, A: np.ndarray, points: int = 1500) -> np.ndarray:
    """Log-spaced frequencies [rad/s] covering the dynamics of ``A``; up to ``π/dt`` when discrete."""
    if dt is not None:
        w_hi = math.pi / dt
        w_lo = min(1e-3, w_hi * 1e-5)
    else:
        lam = np.abs(np.linalg.eigvals(A))
        lam = lam[lam > 0]
        w_hi = 100.0 * max(1.0, float(lam.max()) if lam.size else 1.0)
        w_lo = 1e-3 * min(1.0, float(lam.min()) if lam.size else 1.0)
    w = np.logspace(math.log10(w_lo), math.log10(w_hi), points)
    if dt is not None:
        w[-1] = w_hi * (1.0 - 1e-9)
    return w


def _freq_points(w: np.ndarray, dt: float | None) -> np.ndarray:
    return np.exp(1j * w * dt) if dt is not None else 1j * w


def sensitivity_peaks(
    A: np.ndarray, B: np.ndarray, K: np.ndarray, dt: float | None, w: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Largest singular values of ``S = (I + L)⁻¹`` and ``T = I − S`` on the grid ``w`` ``(F,)``.

    Uses ``S(z) = I − K (zI − A + B K)⁻¹ B``. Returns ``(σ̄(S) (F,), σ̄(T) (F,))``.
    """
    n, m = B.shape
    Acl = A - B @ K
    zs = _freq_points(w, dt)
    M = zs[:, None, None] * np.eye(n)[None] - Acl[None]
    T = K[None] @ np.linalg.solve(M, np.broadcast_to(B.astype(complex), (len(w), n, m)))
    S = np.eye(m)[None] - T
    return np.linalg.svd(S, compute_uv=False)[:, 0], np.linalg.svd(T, compute_uv=False)[:, 0]


def _refine_peak(A, B, K, dt, w, values, which: int) -> tuple[float, float]:
    k = int(np.argmax(values))
    lo, hi = w[max(k - 1, 0)], w[min(k + 1, len(w) - 1)]
    fine = np.linspace(lo, hi, 201)
    s, t = sensitivity_peaks(A, B, K, dt, fine)
    v = (s, t)[which]
    j = int(np.argmax(v))
    return float(v[j]), float(fine[j])


def _disk(L: Any, w: np.ndarray) -> tuple[float, tuple[float, float], float]:
    import control

    DM, DGM, DPM = control.disk_margins(L, w, skew=0.0)
    alpha = float(DM)
    # disk_margins reports the gain margin in dB and the phase margin in degrees
    hi = 10 ** (float(DGM) / 20.0) if math.isfinite(float(DGM)) else math.inf
    lo = (2.0 - alpha) / (2.0 + alpha) if alpha < 2.0 else 0.0
    return alpha, (lo, hi), float(DPM)


def _siso_response(Ls: Any, dt: float | None, w: np.ndarray) -> np.ndarray:
    """``L(e^{jω dt})`` (or ``L(jω)``) of a SISO StateSpace on ``w`` ``(F,)``; inf at a pole."""
    A, B, C = (np.asarray(M, dtype=float) for M in (Ls.A, Ls.B, Ls.C))
    n = A.shape[0]
    zs = _freq_points(np.atleast_1d(w), dt)
    M = zs[:, None, None] * np.eye(n)[None] - A[None]
    with np.errstate(all="ignore"):
        try:
            out = (C[None] @ np.linalg.solve(M, np.broadcast_to(B.astype(complex), (len(zs), n, 1))))[:, 0, 0]
        except np.linalg.LinAlgError:
            out = np.array(
                [
                    complex(C @ np.linalg.lstsq(Mk, B, rcond=None)[0])
                    if abs(np.linalg.det(Mk)) > 1e-300
                    else complex(math.inf)
                    for Mk in M
                ]
            )
    return out


def _crossings(Ls: Any, dt: float | None, w: np.ndarray) -> tuple[list[tuple[float, float]], list[tuple[float, float]]]:
    """Critical gains ``(k, ω)`` (phase crossovers, where ``k L = −1``) and phase margins ``(|pm| [deg], ω)``.

    Candidates come from ``control.stability_margins`` and from sign changes of
    ``Im L`` and ``|L| − 1`` on the grid (refined by Brent's method), plus the
    real endpoints ω = 0 and, when discrete, the Nyquist frequency π/dt (where
    ``stability_margins`` can miss a crossing). Every candidate is verified by
    evaluating ``L`` there, which drops the spurious crossings polynomial root
    finding reports near poles on the stability boundary (the cart's integrator).
    """
    import control
    import scipy.optimize

    def L(x: float) -> complex:
        return complex(_siso_response(Ls, dt, np.array([x]))[0])

    Lw = _siso_response(Ls, dt, w)
    phase_w: list[float] = []
    gain_w: list[float] = []
    for k in range(len(w) - 1):
        a, b = Lw[k], Lw[k + 1]
        if not (np.isfinite(a) and np.isfinite(b)):
            continue
        if a.imag * b.imag < 0 and (a.real < 0 or b.real < 0):
            phase_w.append(scipy.optimize.brentq(lambda x: L(x).imag, w[k], w[k + 1], xtol=1e-12))
        if (abs(a) - 1.0) * (abs(b) - 1.0) < 0:
            gain_w.append(scipy.optimize.brentq(lambda x: abs(L(x)) - 1.0, w[k], w[k + 1], xtol=1e-12))
    try:
        with np.errstate(all="ignore"):
            _gm, _pm, _sm, wpc, wgc, _wms = control.stability_margins(Ls, returnall=True)
        phase_w += [float(x) for x in np.atleast_1d(wpc) if np.isfinite(x)]
        gain_w += [float(x) for x in np.atleast_1d(wgc) if np.isfinite(x)]
    except (ValueError, np.linalg.LinAlgError, ZeroDivisionError):  # the grid search above still stands
        pass
    ends = [0.0] + ([math.pi / dt] if dt is not None else [])
    crit: list[tuple[float, float]] = []
    for x in [*phase_w, *ends]:
        v = L(x)
        if np.isfinite(v) and v.real < 0 and abs(v.imag) <= 1e-6 * max(abs(v), 1e-300):
            crit.append((1.0 / abs(v), x))
    pms: list[tuple[float, float]] = []
    for x in gain_w:
        v = L(x)
        if np.isfinite(v) and abs(abs(v) - 1.0) <= 1e-6:
            ph = math.degrees(math.atan2(v.imag, v.real)) + 180.0  # rotation that puts L on −1
            ph = (ph + 180.0) % 360.0 - 180.0
            pms.append((abs(ph), x))
    return _dedupe(crit), _dedupe(pms)


def delay_margin(Ls: Any, dt: float | None, crossovers: Any) -> tuple[float, float]:
    """``(τ_max [s], ω [rad/s])``: the delay margin of a SISO loop and the gain crossover that binds it.

    ``τ_max = min_c ((∠L(jω_c) + 180°) mod 360°) / ω_c`` over the gain crossovers ``ω_c`` (module
    docstring); ``(inf, nan)`` without a crossover at ``ω > 0``.

    Args:
        Ls: SISO loop (a python-control StateSpace).
        dt: Sampling time [s] (None: continuous).
        crossovers: Gain crossover frequencies [rad/s] (``|L| = 1``).
    """
    best = (math.inf, math.nan)
    ws = np.asarray([x for x in np.atleast_1d(crossovers) if x > 0], dtype=float)
    if not ws.size:
        return best
    for x, v in zip(ws, _siso_response(Ls, dt, ws), strict=True):
        theta = math.radians((math.degrees(math.atan2(v.imag, v.real)) + 180.0) % 360.0)
        if theta / x < best[0]:
            best = (float(theta / x), float(x))
    return best


def _dedupe(pairs: list[tuple[float, float]]) -> list[tuple[float, float]]:
    out: list[tuple[float, float]] = []
    for v, x in sorted(pairs, key=lambda p: p[1]):
        if not out or abs(x - out[-1][1]) > 1e-6 * max(1.0, abs(x)):
            out.append((v, x))
    return out


def _disk_from_alpha(alpha: float) -> tuple[float, tuple[float, float], float]:
    if alpha >= 2.0:
        return alpha, (0.0, math.inf), 180.0
    return alpha, ((2.0 - alpha) / (2.0 + alpha), (2.0 + alpha) / (2.0 - alpha)), math.degrees(2 * math.atan(alpha / 2))


def _mu_upper(M: np.ndarray, x0: np.ndarray) -> tuple[float, np.ndarray]:
    """``min_d σ̄(D M D⁻¹)``, ``D = diag(e^{x})`` (convex in ``x``): an upper bound of μ for a diagonal complex Δ."""
    import scipy.optimize

    def f(x: np.ndarray) -> float:
        d = np.exp(np.concatenate([[0.0], x]))
        return float(np.linalg.svd(d[:, None] * M / d[None, :], compute_uv=False)[0])

    res = scipy.optimize.minimize(f, x0, method="Nelder-Mead", options={"xatol": 1e-6, "fatol": 1e-10, "maxiter": 400})
    return float(min(res.fun, f(np.zeros_like(x0)))), res.x


def simultaneous_disk_margin(
    A: np.ndarray, B: np.ndarray, K: np.ndarray, dt: float | None, w: np.ndarray
) -> tuple[float, tuple[float, float], float]:
    """Balanced disk margin with independent perturbations on every input at once.

    ``α = 1 / max_ω μ_Δ(S − I/2)`` for a diagonal complex ``Δ``, with μ bounded
    from above by the optimal diagonal scaling ``min_D σ̄(D (S − I/2) D⁻¹)``.
    The bound is exact for up to three inputs and conservative beyond
    (python-control's ``disk_margins`` computes μ with slycot, which this
    project does not install). Returns ``(α, (gain low, gain high), phase [deg])``.
    """
    n, m = B.shape
    Acl = A - B @ K
    zs = _freq_points(w, dt)
    Mz = zs[:, None, None] * np.eye(n)[None] - Acl[None]
    T = K[None] @ np.linalg.solve(Mz, np.broadcast_to(B.astype(complex), (len(w), n, m)))
    M = 0.5 * np.eye(m)[None] - T  # S − I/2 = I/2 − T
    coarse = np.linalg.svd(M, compute_uv=False)[:, 0]  # unstructured bound, for ranking the frequencies
    order = np.argsort(coarse)[::-1]
    best, x = 0.0, np.zeros(m - 1)
    for k in order:
        if coarse[k] <= best:  # σ̄ bounds μ from above: nothing left can beat the best found
            break
        val, x = _mu_upper(M[k], x)
        best = max(best, val)
    return _disk_from_alpha(1.0 / best if best > 0 else math.inf)


def loop_margins(
    model: Any, K: Any, *, dt: float | None = None, input_names: Any = None, omega: Any = None
) -> LoopMargins:
    """Gain, phase and disk margins and sensitivity peaks of ``u = −K x`` broken at the plant input.

    Args:
        model: A :class:`~shinro_ctrl.linearization.LinearModel` (its discrete
            ``A, B, dt``), a python-control ``StateSpace`` (``A, B, dt``; dt = 0
            continuous), or an ``(A, B)`` pair with ``dt`` (None: continuous).
        K: Gain ``(m, n)``.
        dt: Sampling time [s] for an ``(A, B)`` pair.
        input_names: Names ``(m,)`` of the inputs (default ``u[i]``).
        omega: Frequency grid [rad/s] for the disk margins and peaks (default
            :func:`frequency_grid`).

    Returns:
        A :class:`LoopMargins`.

    Raises:
        InvalidArgument: wrong shapes, or a closed loop ``A − B K`` that is not
            stable (margins of an unstable loop are meaningless).
    """

    A, B, dt, names = _model_parts(model, dt)
    n, m = B.shape
    K = as_matrix("K", np.atleast_2d(np.asarray(K, dtype=float)), (m, n))
    if input_names is not None:
        names = tuple(str(s) for s in input_names)
    if len(names) != m:
        names = tuple(f"u[{i}]" for i in range(m))
    lam = np.linalg.eigvals(A - B @ K)
    if (dt is not None and np.max(np.abs(lam)) >= 1.0) or (dt is None and np.max(lam.real) >= 0.0):
        raise InvalidArgument(
            f"loop_margins: the closed loop A − B K is not stable (spectral radius {np.max(np.abs(lam)):.6g}); "
            "margins are defined for a stabilizing K"
        )
    w = frequency_grid(dt, A) if omega is None else np.asarray(omega, dtype=float)
    channels = []
    for i in range(m):
        Li = loop_statespace(A, B, K, dt, i)
        crit, pms = _crossings(Li, dt, w)
        low = max(((g, f) for g, f in crit if g < 1.0), default=(0.0, math.nan))
        high = min(((g, f) for g, f in crit if g > 1.0), default=(math.inf, math.nan))
        binding = low if (high[0] == math.inf or (low[0] > 0 and abs(_db(low[0])) < abs(_db(high[0])))) else high
        pmv, wg = min(pms, default=(math.inf, math.nan))
        alpha, dgm, dpm = _disk(Li, w)
        dm, w_dm = delay_margin(Li, dt, [x for _, x in pms])
        channels.append(
            ChannelMargins(
                names[i],
                float(low[0]),
                float(high[0]),
                pmv,
                float(binding[1]),
                wg,
                alpha,
                dgm,
                dpm,
                dm,
                None if dt is None else dm / dt,
                w_dm,
            )
        )
    if m > 1:
        alpha, dgm, dpm = simultaneous_disk_margin(A, B, K, dt, w)
    else:
        alpha, dgm, dpm = channels[0].disk_margin, channels[0].disk_gain_margin, channels[0].disk_phase_margin
    s, t = sensitivity_peaks(A, B, K, dt, w)
    Ms, w_Ms = _refine_peak(A, B, K, dt, w, s, 0)
    Mt, _ = _refine_peak(A, B, K, dt, w, t, 1)
    return LoopMargins(tuple(channels), alpha, dgm, dpm, Ms, w_Ms, Mt, dt)
