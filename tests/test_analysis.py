"""Design analysis against independent references: closed forms, python-control, eigenvalue scans."""

from __future__ import annotations

import math

import control
import numpy as np
import pytest

from shinro_ctrl.analysis import (
    analyze_controller,
    bryson,
    loop_margins,
    pole_table,
    step_metrics,
    structure_report,
)
from shinro_ctrl.analysis.design import finite_horizon_gain
from shinro_ctrl.controllers import LQR
from shinro_ctrl.errors import InvalidArgument
from shinro_ctrl.plants import CartPole, Quadrotor

# ------------------------------------------------------------------ margins


def _ss_of_tf(num, den):
    """(A, B, C) of a SISO transfer function; with K = C the loop K (sI − A)⁻¹ B is num/den."""
    sys = control.tf2ss(control.tf(num, den))
    return np.asarray(sys.A), np.asarray(sys.B), np.asarray(sys.C)


def test_first_order_loop_known_crossover():
    # L = 2 / (s + 1): |L| = 1 at ω = √3, phase −60°, so PM = 120°; the phase never reaches −180°.
    A, B, C = np.array([[-1.0]]), np.array([[1.0]]), np.array([[2.0]])
    m = loop_margins((A, B), C, dt=None).channels[0]
    assert m.w_gain_crossover == pytest.approx(math.sqrt(3), rel=1e-9)
    assert m.phase_margin == pytest.approx(120.0, rel=1e-9)
    assert m.gain_margin_low == 0.0 and m.gain_margin_high == math.inf
    _gm, pm, _, _, wgc, _ = control.stability_margins(control.tf([2], [1, 1]))
    assert m.phase_margin == pytest.approx(pm, rel=1e-6)
    assert m.w_gain_crossover == pytest.approx(wgc, rel=1e-6)


def test_third_order_loop_known_gain_margin():
    # L = k / (s + 1)³: phase −180° at ω = √3 where |L| = k / 8, so GM = 8 / k.
    k = 2.0
    A, B, C = _ss_of_tf([k], [1, 3, 3, 1])
    m = loop_margins((A, B), C, dt=None).channels[0]
    assert m.gain_margin_high == pytest.approx(4.0, rel=1e-8)
    assert m.w_phase_crossover == pytest.approx(math.sqrt(3), rel=1e-8)
    gm, pm, _, _wpc, wgc, _ = control.stability_margins(control.tf([k], [1, 3, 3, 1]))
    assert m.gain_margin_high == pytest.approx(gm, rel=1e-6)
    assert m.phase_margin == pytest.approx(pm, rel=1e-6)
    assert m.w_gain_crossover == pytest.approx(wgc, rel=1e-6)


def test_disk_margin_and_peak_match_frequency_sweep():
    # Balanced disk margin α = 1 / max_ω |S − ½| and Ms = max_ω |S|, S = 1 / (1 + L), on a dense grid.
    A, B, C = _ss_of_tf([2.0], [1, 3, 3, 1])
    lm = loop_margins((A, B), C, dt=None)
    w = np.logspace(-3, 3, 200001)
    L = control.tf([2.0], [1, 3, 3, 1])(1j * w)
    S = 1.0 / (1.0 + L)
    assert lm.Ms == pytest.approx(np.abs(S).max(), rel=1e-4)
    assert lm.disk_margin == pytest.approx(1.0 / np.abs(S - 0.5).max(), rel=1e-3)
    c = lm.channels[0]
    assert c.disk_gain_margin[1] <= c.gain_margin_high + 1e-9  # the disk guarantee is within the classical one
    assert c.disk_phase_margin <= c.phase_margin + 1e-9


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_continuous_lqr_double_integrator_guaranteed_margins(seed):
    rng = np.random.default_rng(seed)
    A = np.array([[0.0, 1.0], [0.0, 0.0]])
    B = np.array([[0.0], [1.0]])
    Q = np.diag(rng.uniform(0.1, 10.0, 2))
    R = np.array([[rng.uniform(0.01, 10.0)]])
    K, _, _ = control.lqr(A, B, Q, R)
    m = loop_margins((A, B), K, dt=None).channels[0]
    assert m.gain_margin_low <= 0.5 and m.gain_margin_high == math.inf
    assert m.phase_margin >= 60.0
    # the same from python-control's own margins of L = K (sI − A)⁻¹ B
    _gm, pm, *_ = control.stability_margins(control.ss(A, B, K, 0), returnall=True)
    assert np.all(np.asarray(pm) >= 60.0)
    assert m.phase_margin == pytest.approx(float(np.min(pm)), rel=1e-6)


def _stable_gain_interval(A, B, K, i):
    """Gains of input i (others at 1) for which A − B diag(g) K is Schur stable, by eigenvalues and bisection."""

    def stable(g):
        G = np.eye(B.shape[1])
        G[i, i] = g
        return np.max(np.abs(np.linalg.eigvals(A - B @ G @ K))) < 1.0

    def edge(a, b):  # stable at a, unstable at b
        for _ in range(80):
            c = math.sqrt(a * b)
            a, b = (c, b) if stable(c) else (a, c)
        return math.sqrt(a * b)

    lo = edge(1.0, 1e-6) if not stable(1e-6) else 0.0
    hi = edge(1.0, 1e6) if not stable(1e6) else math.inf
    return lo, hi


def test_discrete_cartpole_gain_margins_match_eigenvalue_scan():
    plant = CartPole(cart_mass=0.5, pole_mass=0.1, pole_length=0.5, dt=0.01)
    ctrl = LQR.from_plant(plant, [10, 1, 100, 1], [0.1])
    m = loop_margins(ctrl.model, ctrl.K).channels[0]
    lo, hi = _stable_gain_interval(ctrl.model.A, ctrl.model.B, ctrl.K, 0)
    assert m.gain_margin_low == pytest.approx(lo, rel=1e-6)
    assert m.gain_margin_high == pytest.approx(hi, rel=1e-6)  # at the Nyquist frequency
    assert 0 < m.phase_margin < 180


def test_mimo_quadrotor_loop_at_a_time_matches_eigenvalue_scan():
    plant = Quadrotor(dt=0.01)
    Q = np.ones(12)
    ctrl = LQR.from_plant(plant, Q, np.ones(4))
    lm = loop_margins(ctrl.model, ctrl.K)
    assert len(lm.channels) == 4
    for i, c in enumerate(lm.channels):
        lo, hi = _stable_gain_interval(ctrl.model.A, ctrl.model.B, ctrl.K, i)
        assert c.gain_margin_low == pytest.approx(lo, rel=1e-5, abs=1e-9)
        assert c.gain_margin_high == pytest.approx(hi, rel=1e-5)
    # the simultaneous disk margin can only be smaller than each loop-at-a-time one
    assert lm.disk_margin <= min(c.disk_margin for c in lm.channels) + 1e-9


def test_margins_reject_unstable_loop_and_bad_shapes():
    A, B = np.array([[1.1]]), np.array([[1.0]])
    with pytest.raises(InvalidArgument, match="not stable"):
        loop_margins((A, B), [[0.0]], dt=0.1)
    with pytest.raises(InvalidArgument):
        loop_margins((A, B), [[1.0, 2.0]], dt=0.1)


# -------------------------------------------------------------------- poles


def test_pole_table_second_order_discrete():
    zeta, wn, dt = 0.4, 3.0, 0.05
    s = -zeta * wn + 1j * wn * math.sqrt(1 - zeta**2)
    z = np.exp(np.array([s, s.conjugate(), -2.0]) * dt)
    tab = pole_table(z, dt)
    rows = [r for r in tab.rows if abs(r.pole.imag) > 0]
    for r in rows:
        assert r.zeta == pytest.approx(zeta, rel=1e-12)
        assert r.wn == pytest.approx(wn, rel=1e-12)
        assert r.tau == pytest.approx(1 / (zeta * wn), rel=1e-12)
        assert r.flags == ()
    real = next(r for r in tab.rows if r.pole.imag == 0)
    assert real.zeta == pytest.approx(1.0) and real.tau == pytest.approx(0.5)
    # python-control's damp on the same discrete poles
    wn_c, zeta_c, _ = control.damp(_discrete_with_poles(z, dt), doprint=False)
    assert sorted(np.round(wn_c, 9)) == sorted(np.round([r.wn for r in tab.rows], 9))
    assert sorted(np.round(zeta_c, 9)) == sorted(np.round([r.zeta for r in tab.rows], 9))


def _discrete_with_poles(z, dt):
    poly = np.real(np.poly(z))
    return control.tf([1.0], poly, dt)


def test_pole_table_flags():
    dt = 0.01
    s_low = -0.1 * 5 + 1j * 5 * math.sqrt(1 - 0.01)
    tab = pole_table([np.exp(s_low * dt), np.exp(s_low.conjugate() * dt), 1.0, 1.02], dt)
    flags = {round(abs(r.pole), 6): r.flags for r in tab.rows}
    assert "unstable" in flags[1.0] and "unstable" in flags[1.02]
    assert any("ζ" in f for r in tab.rows if r.pole.imag != 0 for f in r.flags)
    assert not tab.stable
    assert tab.zeta_min < 0.3
    cont = pole_table([-1 + 1j, -1 - 1j, 0.5])
    by_pole = {r.pole: r for r in cont.rows}
    assert by_pole[-1 + 1j].zeta == pytest.approx(math.sqrt(0.5)) and by_pole[-1 + 1j].wn == pytest.approx(math.sqrt(2))
    assert "unstable" in by_pole[0.5].flags and by_pole[0.5].zeta == -1.0


# ---------------------------------------------------------------- structure


def test_structure_names_uncontrollable_and_unobservable_modes():
    A = np.diag([1.5, 0.5, 0.2])
    B = np.array([[1.0], [0.0], [1.0]])  # the 0.5 mode ('speed') is not reachable
    C = np.array([[1.0, 1.0, 0.0]])  # the 0.2 mode ('drift') is not seen
    rep = structure_report(A, B, C, state_names=["angle", "speed", "drift"])
    assert rep.controllability_rank == 2 and rep.observability_rank == 2
    assert [m.state for m in rep.uncontrollable] == ["speed"]
    assert rep.uncontrollable[0].eigenvalue == pytest.approx(0.5)
    assert [m.state for m in rep.unobservable] == ["drift"]
    assert rep.stabilizable  # the uncontrollable mode is stable
    text = rep.format()
    assert "uncontrollable mode" in text and "'speed'" in text and "unobservable mode" in text
    # the unstable mode unreachable: not stabilizable
    bad = structure_report(np.diag([1.5, 0.5]), np.array([[0.0], [1.0]]))
    assert not bad.stabilizable and bad.controllability_rank == 1


@pytest.mark.parametrize("discrete", [True, False])
def test_gramian_condition_matches_defining_sum(discrete):
    # control.gram needs slycot (not installed): the reference is the Gramian's definition,
    # Σ_k A^k B Bᵀ (Aᵀ)^k (discrete) or ∫_0^T e^{At} B Bᵀ e^{Aᵀt} dt for a long T (continuous, Simpson's
    # rule), against the Lyapunov solvers the library uses.
    import scipy.linalg

    rng = np.random.default_rng(3)
    n = 4
    M = rng.standard_normal((n, n))
    if discrete:
        A = 0.8 * M / np.max(np.abs(np.linalg.eigvals(M)))
    else:
        A = M - (np.max(np.linalg.eigvals(M).real) + 1.0) * np.eye(n)
    B = rng.standard_normal((n, 2))
    C = rng.standard_normal((1, n))

    def reference(A, B):
        if discrete:
            W, Ak = np.zeros((n, n)), np.eye(n)
            for _ in range(400):
                W += Ak @ B @ B.T @ Ak.T
                Ak = A @ Ak
            return W
        # composite Simpson rule on [0, 30] with the exact transition Φ(h) = e^{Ah}
        h, N = 0.005, 6000
        Phi, P = scipy.linalg.expm(A * h), np.eye(n)
        W = np.zeros((n, n))
        for k in range(N + 1):
            w = 1 if k in (0, N) else (4 if k % 2 else 2)
            PB = P @ B
            W += w * (PB @ PB.T)
            P = Phi @ P
        return W * h / 3

    rep = structure_report(A, B, C, discrete=discrete)
    assert rep.gramian_kind == "infinite-horizon"
    assert rep.gramian_c_cond == pytest.approx(np.linalg.cond(reference(A, B)), rel=1e-6)
    assert rep.gramian_o_cond == pytest.approx(np.linalg.cond(reference(A.T, C.T)), rel=1e-6)
    # an unstable A gets the finite-horizon Gramian of 100 steps
    unstable = structure_report(np.array([[1.1, 0.0], [0.0, 0.5]]), np.array([[1.0], [1.0]]))
    assert unstable.gramian_kind == "finite-horizon, 100 steps"


def test_rank_robust_on_ill_conditioned_euler_model():
    # Euler at dt = 0.01: the raw Kalman matrix of the 12-state quadrotor is numerically rank-deficient,
    # the staircase iteration still finds the full rank (the continuous pair is controllable).
    lm = Quadrotor(dt=0.01).linear_model()
    rep = structure_report(lm.A, lm.B)
    assert rep.controllability_rank == 12
    assert structure_report(lm.A_c, lm.B_c, discrete=False).controllability_rank == 12


# ------------------------------------------------------------- bryson, step


def test_bryson_formula():
    Q, R = bryson([0.5, 1, 0.2, math.inf], [5])
    np.testing.assert_allclose(np.diag(Q), [4.0, 1.0, 25.0, 0.0])
    np.testing.assert_allclose(R, [[0.04]])
    assert np.count_nonzero(Q - np.diag(np.diag(Q))) == 0
    for bad in ([0.0], [-1.0], [math.nan], []):
        with pytest.raises(InvalidArgument):
            bryson(bad, [1.0])
    with pytest.raises(InvalidArgument, match="finite"):
        bryson([1.0], [math.inf])


@pytest.mark.parametrize("zeta", [0.2, 0.5, 0.9])
def test_step_metrics_match_control_step_info(zeta):
    wn = 2.0
    sys = control.tf([wn**2], [1, 2 * zeta * wn, wn**2])
    t = np.linspace(0, 40, 40001)  # long enough that y[-1] is the final value to 1e-6
    resp = control.step_response(sys, t)
    y = np.squeeze(resp.outputs)
    ref = control.step_info(y, t)
    m = step_metrics(t, y, target=1.0)
    dt = t[1] - t[0]
    assert m.rise_time == pytest.approx(ref["RiseTime"], abs=2 * dt)
    assert m.overshoot == pytest.approx(ref["Overshoot"], abs=1e-3)
    assert m.settling_time == pytest.approx(ref["SettlingTime"], abs=2 * dt)
    assert m.peak_time == pytest.approx(ref["PeakTime"], abs=dt)
    assert m.steady_state_error == pytest.approx(1.0 - y[-1])
    # closed form of the overshoot of a second-order step
    assert m.overshoot == pytest.approx(100 * math.exp(-math.pi * zeta / math.sqrt(1 - zeta**2)), rel=1e-3)


def test_step_metrics_initial_condition_and_errors():
    t = np.linspace(0, 10, 10001)
    y = 0.2 * np.exp(-t) * np.cos(3 * t)  # decays from 0.2 to 0, swinging past zero
    m = step_metrics(t, y, final=0.0, target=0.0)
    swing = -y.min() / 0.2 * 100
    assert m.overshoot == pytest.approx(swing, rel=1e-9)
    with pytest.raises(InvalidArgument, match="no step"):
        step_metrics(t, np.zeros_like(t))
    with pytest.raises(InvalidArgument):
        step_metrics(t, y[:-1])


# ------------------------------------------------------------ interop, MPC


def test_statespace_names_and_matrices():
    plant = CartPole(dt=0.02)
    sys = plant.statespace(measured=["x", "theta"])
    lm = plant.linear_model()
    np.testing.assert_array_equal(sys.A, lm.A)
    np.testing.assert_array_equal(sys.B, lm.B)
    assert sys.dt == 0.02
    assert list(sys.state_labels) == list(plant.state_names)
    assert list(sys.input_labels) == list(plant.input_names)
    assert list(sys.output_labels) == ["x", "theta"]
    np.testing.assert_array_equal(sys.C, np.eye(4)[[0, 2]])
    cont = plant.statespace(discrete=False)
    assert cont.dt == 0 and np.array_equal(cont.A, lm.A_c)
    with pytest.raises(InvalidArgument, match="did you mean"):
        plant.statespace(measured=["thetta"])


def test_finite_horizon_gain_tends_to_lqr_and_matches_mpc_first_move():
    from shinro_ctrl.controllers import LinearMPC

    plant = CartPole(dt=0.02)
    Q, R = np.diag([10.0, 1, 100, 1]), np.array([[0.1]])
    lqr = LQR.from_plant(plant, Q, R)
    A, B = lqr.model.A, lqr.model.B
    # with the DARE terminal cost the finite-horizon gain is the LQR gain for any N
    np.testing.assert_allclose(finite_horizon_gain(A, B, Q, R, lqr.S, 5), lqr.K, rtol=1e-9)
    # with Qf = Q it converges to it as N grows
    assert np.abs(finite_horizon_gain(A, B, Q, R, Q, 400) - lqr.K).max() < 1e-6 * np.abs(lqr.K).max()
    mpc = LinearMPC.from_plant(
        plant, Q, R, horizon=60, terminal_cost="Q", osqp_settings={"eps_abs": 1e-9, "eps_rel": 1e-9}
    )
    an = analyze_controller(mpc)
    x = np.array([0.0, 0.0, 0.01, 0.0])
    np.testing.assert_allclose(mpc(x), -an.K @ x, rtol=1e-4, atol=1e-7)


def test_analyze_cartpole_lqr():
    plant = CartPole(cart_mass=0.5, pole_mass=0.1, pole_length=0.5, dt=0.01)
    ctrl = LQR.from_plant(plant, [10, 1, 100, 1], [0.1])
    a = analyze_controller(
        ctrl,
        x_init=[0, 0, 0.2, 0],
        measured=["x", "theta"],
        tracked=["x"],
        state_names=plant.state_names,
        input_names=plant.input_names,
    )
    assert a.zeta_min == pytest.approx(min(r.zeta for r in pole_table(ctrl.poles, 0.01).rows))
    assert a.structure.controllable and a.structure.observable
    assert set(a.responses) == {"initial: theta", "step: x"}
    assert a.responses["step: x"].steady_state_error == pytest.approx(0.0, abs=1e-9)
    # the linear response is the closed-loop recursion itself
    Acl = ctrl.model.A - ctrl.model.B @ ctrl.K
    np.testing.assert_allclose(a.x_lin[1], Acl @ np.array([0, 0, 0.2, 0]), rtol=1e-12)
    text = a.format()
    for word in ("ζ_min", "controllability rank 4/4", "GM low", "Ms = ", "step: x"):
        assert word in text


# ------------------------------------------------- scenario keys, run metrics


def test_bryson_scenario_keys():
    from shinro_ctrl.config import parse_scenario
    from shinro_ctrl.errors import ConfigError
    from shinro_ctrl.sim import RobotSim

    doc = {
        "plant": {"type": "CartPole"},
        "controller": {"type": "LQR", "Q": {"bryson": [0.5, 1, 0.2, math.inf]}, "R": {"bryson": [5]}},
    }
    sim = RobotSim.from_config(doc)
    Q, R = bryson([0.5, 1, 0.2, math.inf], [5])
    ref = LQR.from_plant(sim.plant, Q, R)
    np.testing.assert_allclose(sim.controller.K, ref.K, rtol=1e-12)
    for bad, msg in (
        ({"bryson": [0, 1, 1, 1]}, "positive"),
        ({"brysn": [1, 1, 1, 1]}, "only 'bryson'"),
        ({"bryson": [1, 1]}, "4 values"),
    ):
        doc["controller"]["Q"] = bad
        with pytest.raises(ConfigError, match=msg):
            parse_scenario(doc)
    doc["controller"]["Q"] = [1, 1, 1, 1]
    doc["controller"]["R"] = {"bryson": [math.inf]}
    with pytest.raises(ConfigError, match="finite"):
        parse_scenario(doc)


def test_run_metrics_overshoot_and_rise_time():
    from shinro_ctrl.sim import RobotSim, response_metrics

    res = RobotSim.from_config("cartpole_lqr.toml").run()
    # the angle (largest initial error, 0.2 rad) decays to 0 and swings past it
    i = res.state_names.index("theta")
    ref = step_metrics(res.t, res.x[:, i], final=0.0, target=0.0)
    assert res.metrics["overshoot"] == pytest.approx(ref.overshoot) and res.metrics["overshoot"] > 0
    assert res.metrics["rise_time"] == pytest.approx(ref.rise_time)
    # a moving reference has no step response; a step of the reference is measured from the step
    t = np.arange(201) * 0.01
    x = np.zeros((201, 1))
    r = np.zeros((201, 1))
    assert response_metrics(t, x, np.sin(t)[:, None]) == {}
    r[100:] = 1.0
    x[100:, 0] = 1 - np.exp(-(t[100:] - 1.0) / 0.1)
    m = response_metrics(t, x, r)
    assert m["overshoot"] == 0.0 and m["rise_time"] == pytest.approx(0.1 * math.log(9), abs=0.011)


def test_lqi_loop_includes_the_integrators():
    plant = CartPole(cart_mass=0.5, pole_mass=0.1, pole_length=0.5, dt=0.01)
    ctrl = LQR.from_plant(plant, [10, 1, 100, 1, 5], [0.1], integral=["x"])
    a = analyze_controller(
        ctrl,
        x_init=[0, 0, 0.2, 0],
        measured=["x", "theta"],
        tracked=["x"],
        state_names=plant.state_names,
        input_names=plant.input_names,
    )
    assert a.state_names[-1] == "∫x" and a.A.shape == (5, 5) and a.structure.observable
    # the augmented loop built here from the documented LQI form: z⁺ = z + dt x, u = −K x − K_i z
    A, B = ctrl.model.A, ctrl.model.B
    A_aug = np.block([[A, np.zeros((4, 1))], [0.01 * np.eye(4)[[0]], np.eye(1)]])
    B_aug = np.vstack([B, np.zeros((1, 1))])
    K_aug = np.hstack([ctrl.K, ctrl.K_i])
    np.testing.assert_allclose(
        np.sort_complex(np.linalg.eigvals(A_aug - B_aug @ K_aug)),
        np.sort_complex(np.array([r.pole for r in a.poles.rows])),
        atol=1e-12,
    )
    lo, hi = _stable_gain_interval(A_aug, B_aug, K_aug, 0)
    c = a.margins.channels[0]
    assert c.gain_margin_low == pytest.approx(lo, rel=1e-6) and c.gain_margin_high == pytest.approx(hi, rel=1e-6)
    assert a.responses["step: x"].steady_state_error == pytest.approx(0.0, abs=1e-9)  # integral action


# ------------------------------------------------------------ design metrics (issue 23.3)
def test_a_slow_response_is_followed_until_it_settles_as_python_control_measures_it():
    # the cart's mode is slow (Q_x = 1e-4): it settles after ~390 s, far past 8 τ capped at 20,000 steps
    plant = CartPole(dt=0.01)
    ctrl = LQR.from_plant(plant, [1e-4, 1, 100, 1], [1.0])
    s = analyze_controller(ctrl, tracked=["x"], state_names=plant.state_names).responses["step: x"]
    A, B = ctrl.model.A, ctrl.model.B
    loop = control.ss(A - B @ ctrl.K, B @ ctrl.K[:, [0]], np.eye(4)[[0]], 0, 0.01)
    # the reference simulated for 800 s, twice the settling time (2000 s gave the same times, at 2.5 times the cost)
    ref = control.step_info(loop, T=np.arange(0, 800, 0.01), SettlingTimeThreshold=0.02, RiseTimeLimits=(0.1, 0.9))
    assert s.settling_time == pytest.approx(ref["SettlingTime"], abs=0.05)
    assert s.rise_time == pytest.approx(ref["RiseTime"], abs=0.05)
    # at least the scenario's duration: the plotted response spans it
    a = analyze_controller(ctrl, x_init=[0, 0, 0.1, 0], duration=30.0, state_names=plant.state_names)
    assert a.t[-1] >= 30.0


def test_a_step_an_underactuated_plant_cannot_hold_has_no_steady_state_error():
    from shinro_ctrl.plants import DoublePendulum

    # an acrobot (elbow torque only) balanced upright: a shoulder held at an offset is no equilibrium
    dp = DoublePendulum(dt=0.01)
    up = np.array([np.pi, np.pi, 0.0, 0.0])
    A_c, B_c = dp.linearize(up, [0.0, 0.0])
    acrobot = LQR(A_c, B_c[:, [1]], [100, 100, 1, 1], [1.0], discrete=False, x0=up)
    a = analyze_controller(acrobot, tracked=["theta_1", "theta_2"], state_names=dp.state_names)
    # the independent reference: no elbow torque holds the nonlinear plant at the shoulder offset
    x_off = up + np.array([0.01, 0.0, 0.0, 0.0])
    taus = np.linspace(-5.0, 5.0, 2001)
    assert min(np.abs(dp.dynamics(x_off, [0.0, tau])).max() for tau in taus) > 0.1
    for name in ("theta_1", "theta_2"):
        r = a.responses[f"step: {name}"]
        assert r.steady_state_error is None and r.settling_time is not None
    line = next(row for row in a.format().splitlines() if "step: theta_1" in row)
    assert line.split()[-1] == "n/a"
    # a holdable step keeps its number: the cart-pole's x
    plant = CartPole(dt=0.01)
    ctrl = LQR.from_plant(plant, [10, 1, 100, 1], [0.1])
    b = analyze_controller(ctrl, tracked=["x"], state_names=plant.state_names)
    assert b.responses["step: x"].steady_state_error == pytest.approx(0.0, abs=1e-9)
