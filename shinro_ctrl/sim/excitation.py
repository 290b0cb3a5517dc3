r"""Excitation signals added to the controller's input: PRBS, chirp and multisine, for identification experiments.

A scenario asks for one (or a list of) ``[sim] excitation`` tables::

    excitation = { kind = "prbs", input = "torque", amplitude = 0.5, band = [0.2, 20.0], seed = 3 }
    excitation = [{ kind = "multisine", input = 0, amplitude = 1.0, band = [0.5, 10.0] },
                  { kind = "chirp", input = 1, amplitude = 0.3, band = [0.1, 5.0], sweep = "linear" }]

Keys: ``kind`` (``"prbs"``, ``"chirp"``, ``"multisine"``), ``input`` (an input name or index), ``amplitude``
``A > 0`` (the input's unit), ``band = [f_lo, f_hi]`` [Hz] with ``0 < f_lo < f_hi <= 1/(2 dt)`` (Nyquist), and
optionally ``seed`` (a non-negative integer, default the entry's index in the list) and, for the chirp, ``sweep``
(``"log"``, the default, or ``"linear"``).

:class:`RobotSim` holds one :class:`Excitation` and adds its signal ``e_k`` to the controller's output
``c_k = κ(x̂_k, r_k) + e_k`` in both loops (standalone and MuJoCo), before the non-ideal actuator
(:mod:`shinro_ctrl.sim.nonideal`). The recorded input ``SimResult.u`` and the input the estimator is told
about are ``c_k`` (the excitation included): ``result.npz`` of ``run --out`` is identification data as is.
Entries on the same input add up. The whole signal is computed once per run (:meth:`Excitation.reset`); a step
adds one row into a buffer allocated at construction.

Signals, with ``t_k = k dt``, ``k = 0 … T−1``:

**PRBS** (pseudo-random binary sequence). A maximal-length Fibonacci LFSR of order ``n`` (the taps of
:data:`LFSR_TAPS`, each giving the period ``N = 2ⁿ − 1``) produces bits ``b_j`` with the recurrence
``b_{j+n} = ⊕_{t ∈ taps} b_{j+n−t}``; the register starts at ``1 + seed mod N``. The signal holds
``A (2 b_j − 1)`` for ``c`` steps (the clock period ``T_c = c dt``): ``e_k = A (2 b_{⌊k/c⌋} − 1)``. Its power
spectrum has lines at multiples of ``1/(N T_c)`` under the envelope ``sinc²(π f T_c)``, which is 3 dB down at
``f ≈ 0.443/T_c``; hence ``c = max(1, ⌊0.443/(f_hi dt)⌋)`` (flat within 3 dB up to ``f_hi``), and ``n`` the
smallest order in ``[2, 24]`` with ``1/(N T_c) <= f_lo`` (the period ``N T_c >= 1/f_lo``: the lowest line is in
the band). Over one period the bits hold ``2ⁿ⁻¹`` ones and ``2ⁿ⁻¹ − 1`` zeros (mean ``A/N``) and the periodic
autocorrelation of ``2b − 1`` is ``N`` at lag 0 and ``−1`` at every other lag.

**Chirp** (swept sine over the run's duration ``T_s = T dt``, from ``f_lo`` to ``f_hi``),
``e_k = A sin(φ(t_k) + φ₀)`` with

* linear: ``φ(t) = 2π (f_lo t + (f_hi − f_lo) t² / (2 T_s))``, instantaneous frequency
  ``f(t) = f_lo + (f_hi − f_lo) t/T_s``;
* log: ``φ(t) = 2π f_lo T_s (r^{t/T_s} − 1) / ln r``, ``r = f_hi/f_lo``, ``f(t) = f_lo r^{t/T_s}`` (equal time per
  octave);

and ``φ₀ = 2π frac(seed · g)`` (``g`` the golden ratio's fractional part; 0 for seed 0).

**Multisine** (Schroeder-phased, flat amplitude spectrum over the band). The period is ``P = ⌈1/(f_lo dt)⌉``
steps, the fundamental ``f₀ = 1/(P dt) <= f_lo``, and the components are the harmonics ``h`` with
``f_lo <= h f₀ <= f_hi`` (``K`` of them, ``h_1 < … < h_K``), each with unit amplitude and Schroeder's phase
``ψ_j = −π j (j − 1)/K``, which keeps the crest factor low:

    x_k = Σ_j cos(2π h_j f₀ t_k + ψ_j),      e_k = A x_{(k + s) mod P} / max_k |x_k|,

(computed by an inverse FFT: ``P`` samples, ``O(P log P)``), so ``|e| <= A`` with equality at the peak, the
signal repeats every ``P`` steps, and the DFT over one period is nonzero exactly at the ``K`` harmonics in the
band, all of one magnitude. The seed shifts it circularly by ``s = ⌊frac(seed · g) P⌋`` steps (the spectrum's
magnitudes do not change).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from shinro_ctrl.errors import ConfigError, InvalidArgument
from shinro_ctrl.validation import close_match_hint

__all__ = [
    "EXCITATION_KINDS",
    "LFSR_TAPS",
    "Excitation",
    "ExcitationSpec",
    "chirp_signal",
    "lfsr_bits",
    "multisine_design",
    "multisine_signal",
    "parse_excitation",
    "prbs_design",
    "prbs_signal",
]

EXCITATION_KINDS = ("prbs", "chirp", "multisine")
_KEYS = ("kind", "input", "amplitude", "band", "seed", "sweep")
#: Taps of maximal-length Fibonacci LFSRs by order (Xilinx XAPP 052); each gives the period ``2ⁿ − 1``.
LFSR_TAPS: dict[int, tuple[int, ...]] = {
    2: (2, 1),
    3: (3, 2),
    4: (4, 3),
    5: (5, 3),
    6: (6, 5),
    7: (7, 6),
    8: (8, 6, 5, 4),
    9: (9, 5),
    10: (10, 7),
    11: (11, 9),
    12: (12, 6, 4, 1),
    13: (13, 4, 3, 1),
    14: (14, 5, 3, 1),
    15: (15, 14),
    16: (16, 15, 13, 4),
    17: (17, 14),
    18: (18, 11),
    19: (19, 6, 2, 1),
    20: (20, 17),
    21: (21, 19),
    22: (22, 21),
    23: (23, 18),
    24: (24, 23, 22, 17),
}
#: The −3 dB frequency of a PRBS's ``sinc²`` envelope times its clock period.
PRBS_BANDWIDTH = 0.443
_GOLDEN = (math.sqrt(5.0) - 1.0) / 2.0


@dataclass(frozen=True)
class ExcitationSpec:
    """One checked ``[sim] excitation`` entry (module docstring for the signals).

    Attributes:
        kind: ``"prbs"``, ``"chirp"`` or ``"multisine"``.
        input: Index of the input it is added to.
        amplitude: ``A > 0`` [the input's unit].
        band: ``(f_lo, f_hi)`` [Hz].
        seed: Non-negative integer.
        sweep: The chirp's ``"log"`` or ``"linear"`` sweep.
    """

    kind: str
    input: int
    amplitude: float
    band: tuple[float, float]
    seed: int = 0
    sweep: str = "log"


def lfsr_bits(order: int, seed: int, count: int) -> np.ndarray:
    """The first ``count`` output bits ``(count,)`` (uint8) of the maximal-length LFSR of ``order``.

    The register starts at ``1 + seed mod (2ⁿ − 1)``; bit ``j`` is its lowest bit after ``j`` shifts.
    Only one period is generated; longer outputs repeat it.
    """
    if order not in LFSR_TAPS:
        raise InvalidArgument(f"LFSR order must be in [{min(LFSR_TAPS)}, {max(LFSR_TAPS)}], got {order}")
    period = (1 << order) - 1
    shifts = [order - t for t in LFSR_TAPS[order]]
    s = 1 + int(seed) % period
    n = min(int(count), period)
    bits = np.empty(n, dtype=np.uint8)
    top = order - 1
    for j in range(n):
        bits[j] = s & 1
        b = 0
        for sh in shifts:
            b ^= s >> sh
        s = (s >> 1) | ((b & 1) << top)
    if count > period:
        bits = np.resize(bits, int(count))
    return bits


def _check_band(band: tuple[float, float], dt: float) -> tuple[float, float]:
    f_lo, f_hi = float(band[0]), float(band[1])
    nyquist = 0.5 / dt
    if not (math.isfinite(f_lo) and math.isfinite(f_hi) and 0 < f_lo < f_hi):
        raise InvalidArgument(f"'band' must be [f_lo, f_hi] with 0 < f_lo < f_hi [Hz], got [{f_lo:g}, {f_hi:g}]")
    if f_hi > nyquist * (1 + 1e-12):
        raise InvalidArgument(
            f"'band' upper frequency {f_hi:g} Hz is above the Nyquist frequency 1/(2 dt) = {nyquist:g} Hz"
        )
    return f_lo, f_hi


def prbs_design(band: tuple[float, float], dt: float) -> tuple[int, int]:
    """The LFSR order ``n`` and clock period ``c`` [steps] of a PRBS for ``band`` (module docstring).

    Raises:
        InvalidArgument: a band that is not ``0 < f_lo < f_hi <= 1/(2 dt)``, or one so wide that the order would
            exceed 24 (``f_lo`` below ``1/((2²⁴ − 1) c dt)``).
    """
    f_lo, f_hi = _check_band(band, dt)
    clock = max(1, math.floor(PRBS_BANDWIDTH / (f_hi * dt) + 1e-9))
    need = 1.0 / (f_lo * clock * dt)  # N >= 1/(f_lo T_c)
    for order in sorted(LFSR_TAPS):
        if (1 << order) - 1 >= need * (1 - 1e-12):
            return order, clock
    raise InvalidArgument(
        f"'band' [{f_lo:g}, {f_hi:g}] Hz needs a PRBS period of {need:.3g} clock periods; the longest is 2^24 - 1: "
        "raise f_lo or lower f_hi"
    )


def prbs_signal(amplitude: float, band: tuple[float, float], dt: float, steps: int, seed: int = 0) -> np.ndarray:
    """``e_k = A (2 b_{⌊k/c⌋} − 1)``, ``k = 0 … steps−1`` ``(steps,)``."""
    order, clock = prbs_design(band, dt)
    bits = lfsr_bits(order, seed, -(-int(steps) // clock))
    return amplitude * (2.0 * np.repeat(bits, clock)[:steps] - 1.0)


def chirp_signal(
    amplitude: float, band: tuple[float, float], dt: float, steps: int, seed: int = 0, sweep: str = "log"
) -> np.ndarray:
    """``e_k = A sin(φ(t_k) + φ₀)`` sweeping ``band`` over ``steps`` steps ``(steps,)`` (module docstring)."""
    f_lo, f_hi = _check_band(band, dt)
    if sweep not in ("log", "linear"):
        raise InvalidArgument(f"'sweep' must be 'log' or 'linear', got {sweep!r}")
    T = int(steps) * dt
    t = np.arange(int(steps)) * dt
    if sweep == "linear":
        phase = 2 * np.pi * (f_lo * t + (f_hi - f_lo) * t**2 / (2 * T))
    else:
        r = math.log(f_hi / f_lo)
        phase = 2 * np.pi * f_lo * T * np.expm1(r * t / T) / r
    phi0 = 2 * np.pi * ((seed * _GOLDEN) % 1.0)
    return amplitude * np.sin(phase + phi0)


def multisine_design(band: tuple[float, float], dt: float) -> tuple[int, np.ndarray]:
    """The period ``P`` [steps] and the harmonics ``h`` ``(K,)`` of a multisine over ``band`` (module docstring).

    Raises:
        InvalidArgument: a band outside ``(0, 1/(2 dt)]`` or one that holds no harmonic of ``1/(P dt)``.
    """
    f_lo, f_hi = _check_band(band, dt)
    P = math.ceil(1.0 / (f_lo * dt) - 1e-9)
    f0 = 1.0 / (P * dt)
    lo = max(1, math.ceil(f_lo / f0 - 1e-9))
    hi = min(P // 2, math.floor(f_hi / f0 + 1e-9))
    if hi < lo:
        raise InvalidArgument(f"'band' [{f_lo:g}, {f_hi:g}] Hz holds no harmonic of f0 = {f0:g} Hz: widen it")
    return P, np.arange(lo, hi + 1)


def multisine_signal(amplitude: float, band: tuple[float, float], dt: float, steps: int, seed: int = 0) -> np.ndarray:
    """The Schroeder-phased multisine ``(steps,)`` with peak ``A`` (module docstring)."""
    P, h = multisine_design(band, dt)
    K = h.shape[0]
    j = np.arange(1, K + 1)
    psi = -np.pi * j * (j - 1) / K
    spectrum = np.zeros(P // 2 + 1, dtype=complex)
    spectrum[h] = np.exp(1j * psi) * (P / 2.0)  # irfft: x_k = Σ cos(2π h k/P + ψ)
    if P % 2 == 0 and h[-1] == P // 2:
        spectrum[P // 2] *= 2.0  # the Nyquist bin is not doubled by irfft
    x = np.fft.irfft(spectrum, P)
    x *= amplitude / np.abs(x).max()
    shift = math.floor(((seed * _GOLDEN) % 1.0) * P)
    x = np.roll(x, -shift)
    return np.resize(x, int(steps))


def _signal(spec: ExcitationSpec, dt: float, steps: int) -> np.ndarray:
    if spec.kind == "prbs":
        return prbs_signal(spec.amplitude, spec.band, dt, steps, spec.seed)
    if spec.kind == "chirp":
        return chirp_signal(spec.amplitude, spec.band, dt, steps, spec.seed, spec.sweep)
    return multisine_signal(spec.amplitude, spec.band, dt, steps, spec.seed)


class Excitation:
    """The sum of a scenario's excitation signals, added to the controller's output once per step.

    Args:
        specs: The entries (:func:`parse_excitation`).
        input_dim: Inputs ``m``.
        dt: Control step [s].

    Raises:
        InvalidArgument: an entry whose input index is out of range or whose band does not fit ``dt``.
    """

    def __init__(self, specs: Sequence[ExcitationSpec], input_dim: int, dt: float):
        self.specs = tuple(specs)
        self.input_dim, self.dt = int(input_dim), float(dt)
        for s in self.specs:
            if not 0 <= s.input < self.input_dim:
                raise InvalidArgument(f"excitation input index {s.input} is out of range [0, {self.input_dim})")
            if s.kind == "prbs":
                prbs_design(s.band, self.dt)
            elif s.kind == "multisine":
                multisine_design(s.band, self.dt)
            else:
                _check_band(s.band, self.dt)
        self.signal = np.zeros((0, self.input_dim))
        self._out = np.zeros(self.input_dim)

    @classmethod
    def from_config(cls, value: Any, input_names: Sequence[str], dt: float) -> Excitation:
        """From the ``[sim] excitation`` value (a table or a list of tables)."""
        return cls(parse_excitation(value, input_names, dt), len(input_names), dt)

    def reset(self, steps: int) -> np.ndarray:
        """Compute the run's signal ``(steps, m)`` (every entry summed per input) and return it."""
        E = np.zeros((int(steps), self.input_dim))
        for s in self.specs:
            E[:, s.input] += _signal(s, self.dt, int(steps))
        self.signal = E
        return E

    def __call__(self, k: int, u: np.ndarray) -> np.ndarray:
        """``u + e_k`` ``(m,)`` into an internal buffer (overwritten by the next call)."""
        return np.add(u, self.signal[k], out=self._out)


def parse_excitation(
    value: Any, input_names: Sequence[str], dt: float, where: str = "excitation"
) -> list[ExcitationSpec]:
    """Check ``[sim] excitation`` (a table or a list of tables; module docstring) against the plant's inputs.

    Raises:
        ConfigError: one line naming the entry and key: an unknown kind, key or input, a missing key, a
            non-positive amplitude, a band that is not ``0 < f_lo < f_hi <= 1/(2 dt)``, a bad seed or sweep.
    """
    items = value if isinstance(value, list) else [value]
    if not items:
        raise ConfigError(f"{where}: an empty list; give a table or leave the key out")
    names = tuple(input_names)
    out = []
    for idx, t in enumerate(items):
        w = where if len(items) == 1 else f"{where}[{idx}]"
        if not isinstance(t, Mapping):
            example = '{ kind = "prbs", input = 0, amplitude = 1.0, band = [0.1, 10.0] }'
            raise ConfigError(f"{w}: expected a table such as {example}, got {t!r}")
        for k in t:
            if k not in _KEYS:
                hint = close_match_hint(str(k), _KEYS)
                raise ConfigError(f"{w}: unknown key '{k}'{hint} (valid: {', '.join(_KEYS)})")
        for k in ("kind", "input", "amplitude", "band"):
            if k not in t:
                raise ConfigError(f"{w}: missing key '{k}'")
        kind = t["kind"]
        if not isinstance(kind, str) or kind not in EXCITATION_KINDS:
            raise ConfigError(
                f"{w}: unknown kind {kind!r}{close_match_hint(str(kind), EXCITATION_KINDS)} "
                f"(valid: {', '.join(EXCITATION_KINDS)})"
            )
        i = t["input"]
        if isinstance(i, str):
            if i not in names:
                raise ConfigError(f"{w}: unknown input '{i}'{close_match_hint(i, names)} (valid: {', '.join(names)})")
            index = names.index(i)
        elif isinstance(i, int) and not isinstance(i, bool) and 0 <= i < len(names):
            index = i
        else:
            raise ConfigError(f"{w}: 'input' must be an input name ({', '.join(names)}) or an index, got {i!r}")
        a = t["amplitude"]
        if isinstance(a, bool) or not isinstance(a, int | float) or not math.isfinite(a) or a <= 0:
            raise ConfigError(f"{w}: 'amplitude' must be a finite number > 0, got {a!r}")
        band = t["band"]
        if (
            not isinstance(band, list | tuple)
            or len(band) != 2
            or not all(isinstance(b, int | float) and not isinstance(b, bool) for b in band)
        ):
            raise ConfigError(f"{w}: 'band' must be [f_lo, f_hi] in Hz, got {band!r}")
        seed = t.get("seed", idx)
        if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
            raise ConfigError(f"{w}: 'seed' must be a non-negative integer, got {seed!r}")
        sweep = t.get("sweep", "log")
        if "sweep" in t and kind != "chirp":
            raise ConfigError(f"{w}: 'sweep' applies to kind 'chirp' only")
        if sweep not in ("log", "linear"):
            raise ConfigError(f"{w}: 'sweep' must be 'log' or 'linear', got {sweep!r}")
        spec = ExcitationSpec(kind, index, float(a), (float(band[0]), float(band[1])), seed, sweep)
        try:
            Excitation([spec], len(names), dt)
        except InvalidArgument as exc:
            raise ConfigError(f"{w}: {exc}") from None
        out.append(spec)
    return out
