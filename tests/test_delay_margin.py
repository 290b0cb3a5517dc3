"""The delay margin per input loop: closed forms, python-control's phase margin and crossover, the eigenvalues of the
delay-augmented loop, and the simulated loop just below and just above the margin (both loops)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from shinro_ctrl.analysis import loop_margins
from shinro_ctrl.cli import main
from shinro_ctrl.errors import SimulationDiverged
from shinro_ctrl.sim import RobotSim


@pytest.mark.parametrize("k", [0.5, 2.0, 40.0])
def test_continuous_integrator_loop_has_delay_margin_pi_over_2k(k):
    """``L(s) = k/s`` crosses |L| = 1 at ω = k with phase −90°: τ_max = (π/2)/k."""
    c = loop_margins((np.zeros((1, 1)), np.ones((1, 1))), [[k]], dt=None).channels[0]
    assert c.delay_margin == pytest.approx(math.pi / (2 * k), rel=1e-9)
    assert c.w_delay_margin == pytest.approx(k, rel=1e-9)
    assert c.delay_margin_samples is None


# python-control's disk margin evaluates the integrator's transfer function at its pole z = 1
@pytest.mark.filterwarnings("ignore:divide by zero:RuntimeWarning", "ignore:invalid value:RuntimeWarning")
@pytest.mark.parametrize(("k", "dt"), [(10.0, 0.01), (3.0, 0.1)])
def test_discrete_integrator_loop_matches_its_closed_form_in_samples(k, dt):
    """``L(z) = k dt/(z − 1)``: |e^{jθ} − 1| = 2 sin(θ/2) = k dt at θ = ω dt, and ∠L = −(π + θ)/2, so the
    clockwise rotation to −1 is π/2 − θ/2 and the margin is (π/2 − θ/2)/θ samples."""
    theta = 2 * math.asin(k * dt / 2)
    c = loop_margins((np.ones((1, 1)), dt * np.ones((1, 1))), [[k]], dt=dt).channels[0]
    assert c.delay_margin_samples == pytest.approx((math.pi / 2 - theta / 2) / theta, rel=1e-9)
    assert c.delay_margin == pytest.approx(c.delay_margin_samples * dt, rel=1e-12)
    assert c.w_delay_margin == pytest.approx(theta / dt, rel=1e-9)


@pytest.fixture(scope="module")
def pendulum():
    return RobotSim.from_config("pendulum_lqr.toml")


@pytest.fixture(scope="module")
def double_pendulum():
    return RobotSim.from_config("double_pendulum_lqr.toml")


def test_siso_delay_margin_is_python_controls_phase_margin_over_its_crossover(pendulum):
    import control

    ctrl = pendulum.controller
    L = control.ss(ctrl.A, ctrl.B, ctrl.K, 0.0, pendulum.plant.dt)
    _gm, pm, _sm, _wpc, wgc, _wms = control.stability_margins(L)
    c = loop_margins((ctrl.A, ctrl.B), ctrl.K, dt=pendulum.plant.dt).channels[0]
    assert c.delay_margin == pytest.approx(math.radians(pm) / wgc, rel=1e-6)
    assert c.delay_margin_samples == pytest.approx(math.radians(pm) / wgc / pendulum.plant.dt, rel=1e-6)


def test_with_several_gain_crossovers_the_margin_is_the_least_phase_over_frequency():
    """A lightly damped resonance gives three crossovers (python-control's ``returnall``): the delay margin is the
    minimum of ``(PM_c mod 360°) / ω_c`` over them."""
    import control

    L = control.tf([0.3 * 4, 0.3 * 0.2 * 4], [1, 0.2, 4, 0])  # 1.2 (s + 0.2) / (s (s² + 0.2 s + 4))
    sys = control.ss(L)
    _gm, pm, _sm, _wpc, wgc, _wms = control.stability_margins(L, returnall=True)
    assert len(wgc) == 3
    expected = min(math.radians(p % 360.0) / w for p, w in zip(pm, wgc, strict=True))
    c = loop_margins((sys.A, sys.B), sys.C, dt=None).channels[0]
    assert c.delay_margin == pytest.approx(expected, rel=1e-6)


def _delayed_loop_radius(A, B, K, channel, d):
    """Spectral radius of ``x⁺ = A x + B u_applied`` with input ``channel`` applied ``d`` steps late (the others
    on time): the state carries the FIFO ``[u_{k−1}, …, u_{k−d}]`` of that input."""
    n, m = B.shape
    others = [j for j in range(m) if j != channel]
    Acl = A - B[:, others] @ K[others]
    N = n + d
    M = np.zeros((N, N))
    M[:n, :n] = Acl
    if d == 0:
        M[:n, :n] -= np.outer(B[:, channel], K[channel])
    else:
        M[:n, n + d - 1] = B[:, channel]
        M[n, :n] = -K[channel]
        for j in range(1, d):
            M[n + j, n + j - 1] = 1.0
    return float(np.max(np.abs(np.linalg.eigvals(M))))


@pytest.mark.parametrize("which", ["pendulum", "double_pendulum"])
def test_whole_samples_below_the_margin_are_stable_and_the_next_is_not(which, request):
    """Independent of the frequency response: eigenvalues of the loop with the delay as a FIFO in its state, per
    input with the other inputs closed (loop-at-a-time)."""
    sim = request.getfixturevalue(which)
    ctrl = sim.controller
    A, B, K = np.asarray(ctrl.A), np.asarray(ctrl.B), np.asarray(ctrl.K)
    for i, c in enumerate(loop_margins((A, B), K, dt=sim.plant.dt).channels):
        below = math.floor(c.delay_margin_samples)
        assert 0.05 < c.delay_margin_samples - below < 0.95, "a margin this close to a whole sample tests nothing"
        assert _delayed_loop_radius(A, B, K, i, below) < 1.0
        assert _delayed_loop_radius(A, B, K, i, below + 1) > 1.0


def _run_with_delay(steps: int, loop: str, where: str):
    """The pendulum LQR from 0.05 rad for 1 s with the input (or the measurement) ``steps`` steps late."""
    doc = {
        "plant": {"type": "InvertedPendulum", "mass": 0.1, "length": 0.5, "damping": 0.01, "dt": 0.01},
        "controller": {"type": "LQR", "Q": [10, 1], "R": [0.1]},
        "sim": {"duration": 1.0, "initial_state": [0.05, 0.0], where: {"delay": steps * 0.01}},
    }
    if loop == "mujoco":
        doc["engine"] = {"type": "mujoco"}
    return RobotSim.from_config(doc).run()


@pytest.mark.parametrize(
    ("loop", "where"), [("standalone", "actuator"), ("mujoco", "actuator"), ("standalone", "sensor")]
)
def test_a_delay_just_below_the_margin_holds_the_pendulum_and_one_just_above_does_not(loop, where, pendulum):
    """Margin 1.6 samples: 1 step late settles (ρ ≈ 0.97 per step), 2 steps late falls (ρ ≈ 1.05) within 1 s."""
    dm = loop_margins((pendulum.controller.A, pendulum.controller.B), pendulum.controller.K, dt=0.01).channels[0]
    below = math.floor(dm.delay_margin_samples)
    assert below == 1
    ok = _run_with_delay(below, loop, where)
    assert ok.metrics["stable"] and abs(ok.x[-1, 0]) < 5e-3
    try:
        bad = _run_with_delay(below + 1, loop, where)
    except SimulationDiverged:
        return
    assert not bad.metrics["stable"]
    assert np.max(np.abs(bad.x[-20:, 0])) > 0.25  # an oscillation grown fivefold from 0.05 rad


def test_design_prints_the_margin_and_the_scenarios_loop_delay_against_it(tmp_path, capsys, pendulum):
    c = loop_margins((pendulum.controller.A, pendulum.controller.B), pendulum.controller.K, dt=0.01).channels[0]
    path = tmp_path / "late.toml"
    path.write_text(
        '[plant]\ntype = "InvertedPendulum"\nmass = 0.1\nlength = 0.5\ndamping = 0.01\ndt = 0.01\n'
        '[controller]\ntype = "LQR"\nQ = [10, 1]\nR = [0.1]\n'
        "[sim]\nactuator = { delay = 0.01 }\nsensor = { delay = [0.01, 0.0] }\n"
    )
    assert main(["design", "lqr", str(path)]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert any("DM [s] DM [smp]" in line for line in lines)
    row = next(line for line in lines if line.strip().startswith("tau "))
    assert row.split()[-2:] == [f"{c.delay_margin:.4g}", f"{c.delay_margin_samples:.4g}"]
    assert lines[-1].startswith("  tau: at most 0.02 s (2 steps) of 0.01599 s (OUTSIDE")
