"""[sim] excitation: PRBS, chirp and multisine against hand computations, and in both loops."""

from __future__ import annotations

import math
import tomllib

import numpy as np
import pytest

from shinro_ctrl.config import parse_scenario
from shinro_ctrl.errors import ConfigError
from shinro_ctrl.resources import config_path
from shinro_ctrl.sim.excitation import (
    LFSR_TAPS,
    chirp_signal,
    lfsr_bits,
    multisine_design,
    multisine_signal,
    prbs_design,
    prbs_signal,
)
from shinro_ctrl.sim.robot import RobotSim


@pytest.mark.parametrize("order", [2, 3, 5, 8, 10])
def test_lfsr_is_maximal_length(order):
    """Period exactly 2ⁿ − 1 (no shorter one), 2ⁿ⁻¹ ones, two-valued periodic autocorrelation N / −1."""
    N = (1 << order) - 1
    b = lfsr_bits(order, seed=5, count=2 * N).astype(float)
    assert np.array_equal(b[:N], b[N:])
    states = {tuple(b[j : j + order]) for j in range(N)}  # every nonzero n-bit window occurs once per period
    assert len(states) == N
    assert b[:N].sum() == 2 ** (order - 1)
    s = 2 * b[:N] - 1
    acf = np.array([s @ np.roll(s, lag) for lag in range(N)])
    assert acf[0] == N
    assert np.all(acf[1:] == -1)


def test_lfsr_taps_table_orders():
    assert sorted(LFSR_TAPS) == list(range(2, 25))
    assert all(taps[0] == n for n, taps in LFSR_TAPS.items())


def test_prbs_clock_and_period_from_band():
    """dt = 0.01, band [0.5, 10]: c = ⌊0.443/(10·0.01)⌋ = 4 steps, N ≥ 1/(0.5·0.04) = 50 → order 6 (N = 63)."""
    assert prbs_design((0.5, 10.0), 0.01) == (6, 4)
    assert prbs_design((0.5, 50.0), 0.01) == (8, 1)  # c = 1 near Nyquist; N ≥ 200 → 255
    e = prbs_signal(0.3, (0.5, 10.0), 0.01, 2 * 252 + 7, seed=2)
    assert set(np.unique(e)) == {-0.3, 0.3}
    L = 63 * 4
    assert np.array_equal(e[:L], e[L : 2 * L])  # period N c steps
    held = e[:L].reshape(63, 4)
    assert np.all(held == held[:, :1])  # held for c steps
    # the DFT over one period: |X_j| = A √(N+1) |D_j| off the multiples of N, A c at j = 0 (D: the hold kernel)
    X = np.fft.fft(e[:L])
    j = np.arange(L)
    D = np.abs(np.exp(-2j * np.pi * np.outer(j, np.arange(4)) / L).sum(axis=1))
    expect = 0.3 * math.sqrt(64) * D
    expect[0] = 0.3 * 4
    expect[j % 63 == 0] = np.where(j[j % 63 == 0] == 0, 0.3 * 4, 0.3 * D[j % 63 == 0])
    np.testing.assert_allclose(np.abs(X), expect, atol=1e-9)
    # -3 dB of the envelope at 0.443/T_c = 11.1 Hz >= f_hi: within 3 dB below 10 Hz
    f = j / (L * 0.01)
    band = (f > 0) & (f <= 10.0) & (j % 63 != 0)
    assert (np.abs(X[band]) ** 2).min() >= 0.5 * (np.abs(X[1]) ** 2)


def test_prbs_seed_shifts_the_sequence():
    a = prbs_signal(1.0, (0.5, 10.0), 0.01, 252, seed=0)
    b = prbs_signal(1.0, (0.5, 10.0), 0.01, 252, seed=7)
    assert not np.array_equal(a, b)
    assert any(np.array_equal(np.roll(a, s), b) for s in range(0, 252, 4))  # the same m-sequence, shifted


@pytest.mark.parametrize("sweep", ["linear", "log"])
def test_chirp_cycles_and_band(sweep):
    """Zero crossings = 2 ∫ f dt: linear T (f0 + f1)/2, log T (f1 − f0)/ln(f1/f0); energy in the band."""
    dt, steps, f0, f1 = 0.001, 10_000, 1.0, 20.0
    e = chirp_signal(0.5, (f0, f1), dt, steps, sweep=sweep)
    T = steps * dt
    cycles = T * (f0 + f1) / 2 if sweep == "linear" else T * (f1 - f0) / math.log(f1 / f0)
    crossings = np.count_nonzero(np.diff(np.signbit(e)))
    assert abs(crossings - 2 * cycles) <= 2
    half = e[: steps // 2]  # up to T/2: linear f goes to (f0+f1)/2; log to √(f0 f1)
    cyc_half = (
        T / 2 * (f0 + (f0 + f1) / 2) / 2 if sweep == "linear" else T * f0 * (math.sqrt(f1 / f0) - 1) / math.log(f1 / f0)
    )
    assert abs(np.count_nonzero(np.diff(np.signbit(half))) - 2 * cyc_half) <= 2
    assert np.abs(e).max() <= 0.5 + 1e-12
    P = np.abs(np.fft.rfft(e)) ** 2
    f = np.fft.rfftfreq(steps, dt)
    assert P[(f >= 0.8 * f0) & (f <= 1.2 * f1)].sum() > 0.95 * P.sum()


def test_multisine_flat_spectrum_in_band():
    """dt = 0.01, band [0.5, 5]: P = 200 steps, f0 = 0.5 Hz, harmonics 1…10, one magnitude, nothing outside."""
    P, h = multisine_design((0.5, 5.0), 0.01)
    assert P == 200
    assert list(h) == list(range(1, 11))
    e = multisine_signal(0.8, (0.5, 5.0), 0.01, 450, seed=3)
    assert np.array_equal(e[:200], e[200:400])
    assert np.abs(e).max() == pytest.approx(0.8)
    X = np.abs(np.fft.rfft(e[:200]))
    inside = np.zeros(X.shape, bool)
    inside[1:11] = True
    assert X[~inside].max() < 1e-9 * X[inside].max()
    np.testing.assert_allclose(X[inside], X[1], rtol=1e-9)
    # Schroeder phases: crest factor (peak / rms) well below the zero-phase one, √(2K) = 4.47
    crest = np.abs(e[:200]).max() / np.sqrt(np.mean(e[:200] ** 2))
    assert crest < 2.0
    # a band off the harmonics: [0.3, 0.9] at dt 0.1 → P = 34, f0 = 0.294, harmonics 2, 3
    P2, h2 = multisine_design((0.3, 0.9), 0.1)
    assert (P2, list(h2)) == (34, [2, 3])


def _pendulum(excitation):
    doc = tomllib.loads(config_path("pendulum_lqr").read_text())
    doc["sim"]["excitation"] = excitation
    doc["sim"]["duration"] = 0.5
    return doc


@pytest.mark.parametrize("engine", ["standalone", "mujoco"])
def test_loop_adds_the_signal_to_the_command(engine):
    """Recorded u_k = κ(x̂_k, r_k) + e_k in both loops, and the plant moves differently for it."""
    exc = [
        {"kind": "prbs", "input": "tau", "amplitude": 0.05, "band": [0.5, 10.0]},
        {"kind": "multisine", "input": 0, "amplitude": 0.02, "band": [1.0, 5.0]},
    ]
    sim = RobotSim.from_config(_pendulum(exc), engine=engine)
    r = sim.run()
    e = prbs_signal(0.05, (0.5, 10.0), 0.01, 50, seed=0) + multisine_signal(0.02, (1.0, 5.0), 0.01, 50, seed=1)
    kappa = np.array([sim.controller(r.x_hat[k], r.ref[k]) for k in range(50)])
    np.testing.assert_allclose(r.u[:, 0] - kappa[:, 0], e, atol=1e-12)
    if engine == "standalone":  # the plant felt it; the resolved scenario reproduces the run
        plain = sim.with_plant({})
        plain.excitation = None
        assert np.abs(plain.run().x - r.x).max() > 1e-4
        again = RobotSim.from_config(sim.resolved_config(), engine=engine).run()
        np.testing.assert_array_equal(again.u, r.u)


@pytest.mark.parametrize(
    ("table", "needle"),
    [
        ({"kind": "prbss", "input": 0, "amplitude": 1, "band": [1, 2]}, "unknown kind 'prbss'; did you mean 'prbs'"),
        ({"kind": "prbs", "input": "torque", "amplitude": 1, "band": [1, 2]}, "unknown input 'torque' (valid: tau)"),
        ({"kind": "prbs", "input": 3, "amplitude": 1, "band": [1, 2]}, "'input' must be an input name"),
        ({"kind": "prbs", "input": 0, "amplitude": 0, "band": [1, 2]}, "'amplitude' must be a finite number > 0"),
        ({"kind": "prbs", "input": 0, "amplitude": 1, "band": [1, 80]}, "above the Nyquist frequency"),
        ({"kind": "chirp", "input": 0, "amplitude": 1, "band": [2, 1]}, "0 < f_lo < f_hi"),
        ({"kind": "prbs", "input": 0, "amplitude": 1, "band": [1]}, "'band' must be [f_lo, f_hi]"),
        ({"kind": "prbs", "input": 0, "amplitude": 1, "band": [1, 2], "sweep": "log"}, "'chirp' only"),
        ({"kind": "chirp", "input": 0, "amplitude": 1, "band": [1, 2], "sweep": "cubic"}, "'log' or 'linear'"),
        ({"kind": "prbs", "input": 0, "amplitude": 1, "band": [1, 2], "seed": -1}, "non-negative integer"),
        ({"kind": "prbs", "input": 0, "amplitude": 1, "bands": [1, 2]}, "unknown key 'bands'"),
        ({"kind": "prbs", "amplitude": 1, "band": [1, 2]}, "missing key 'input'"),
        ({"kind": "prbs", "input": 0, "amplitude": 1, "band": [1e-9, 2]}, "longest is 2^24 - 1"),
        ([], "an empty list"),
    ],
)
def test_bad_excitation_is_one_line(table, needle):
    with pytest.raises(ConfigError) as err:
        parse_scenario(_pendulum(table))
    msg = str(err.value)
    assert needle in msg, msg
    assert "\n" not in msg and "[sim]" in msg
