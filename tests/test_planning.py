"""Trajectory optimization: defects, order of accuracy, bounds, failures, files, the [plan] table and the CLI."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from shinro_ctrl.config import parse_scenario
from shinro_ctrl.errors import ConfigError, InvalidArgument, PlanningFailed
from shinro_ctrl.planning import METHODS, Trajectory, TrajectoryOptimizer
from shinro_ctrl.plants import CartPole, InvertedPendulum

INF = np.inf
X_MIN = [-1.0, -INF, -INF, -INF]
X_MAX = [1.0, INF, INF, INF]
START = np.array([0.0, 0.0, np.pi, 0.0])
GOAL = np.zeros(4)
SWINGUP_COST = {"time": 1.0, "effort": 10.0}


@pytest.fixture(scope="module")
def plant() -> CartPole:
    return CartPole()


@pytest.fixture(scope="module")
def optimizers(plant):
    """One optimizer per method and knot count, each built once (the NLP is re-solved, never rebuilt)."""
    return {
        (meth, N): TrajectoryOptimizer(plant, knots=N, method=meth, u_min=[-5], u_max=[5], x_min=X_MIN, x_max=X_MAX)
        for meth in METHODS
        for N in (31, 61)
    }


@pytest.fixture(scope="module")
def swingups(optimizers):
    """Free-time swing-ups (the issue's problem) on 61 knots, per method."""
    return {meth: optimizers[meth, 61].solve(START, GOAL, duration=(0.5, 5.0), cost=SWINGUP_COST) for meth in METHODS}


@pytest.fixture(scope="module")
def fixed_time_pairs(optimizers):
    """Fixed-time (2.5 s) swing-ups on 31 and 61 knots; the fine one starts from the coarse one (same optimum)."""
    out = {}
    for meth in METHODS:
        coarse = optimizers[meth, 31].solve(START, GOAL, duration=2.5, cost="effort")
        fine = optimizers[meth, 61].solve(START, GOAL, duration=2.5, cost="effort", initial_guess=coarse)
        out[meth] = (coarse, fine)
    return out


def _defects(plant, traj: Trajectory, substeps: int = 1) -> np.ndarray:
    """The transcription's defects recomputed in numpy from the plant's numeric dynamics, ``(N - 1, n)``."""
    x, u, h = traj.x, traj.u, np.diff(traj.t)[:, None]
    f = plant.dynamics
    if traj.method == "trapezoid":
        return x[1:] - x[:-1] - h / 2 * (f(x[:-1], u[:-1]) + f(x[1:], u[1:]))
    if traj.method == "hermite_simpson":
        fa, fb = f(x[:-1], u[:-1]), f(x[1:], u[1:])
        xc = (x[:-1] + x[1:]) / 2 + h / 8 * (fa - fb)
        fc = f(xc, (u[:-1] + u[1:]) / 2)
        return x[1:] - x[:-1] - h / 6 * (fa + 4 * fc + fb)
    xk = x[:-1].copy()
    s = h / substeps
    for _ in range(substeps):
        k1 = f(xk, u[:-1])
        k2 = f(xk + s / 2 * k1, u[:-1])
        k3 = f(xk + s / 2 * k2, u[:-1])
        k4 = f(xk + s * k3, u[:-1])
        xk = xk + s / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    return x[1:] - xk


def _integrate(plant, traj: Trajectory) -> np.ndarray:
    """The plant integrated by scipy (rtol 1e-10) under ``traj.u_at`` from each knot over its interval.

    Returns the states reached at knots ``1 … N−1`` ``(N − 1, n)``: their distance to ``x[1:]`` is the
    transcription's local error, ``O(h^(p+1))`` for a method of order ``p``. (An open-loop run through the
    whole swing-up would amplify it by the instability of the upright pole, not measure the method.)
    """
    xs = []
    for k in range(traj.knots - 1):
        a, b = traj.t[k], traj.t[k + 1]
        mid = 0.5 * (a + b)  # held inputs: the interval's value (u_at is right-continuous at knots)

        def rhs(t, x, a=a, b=b, mid=mid):
            tt = mid if traj.method == "multiple_shooting" else min(max(t, a), b)
            return plant.dynamics(x, traj.u_at(tt))

        sol = solve_ivp(rhs, (a, b), traj.x[k], method="DOP853", rtol=1e-10, atol=1e-12)
        xs.append(sol.y[:, -1])
    return np.array(xs)


@pytest.mark.parametrize("method", METHODS)
def test_swingup_converges_with_small_defect(plant, swingups, method):
    traj = swingups[method]
    assert traj.status == "Solve_Succeeded"
    assert traj.max_defect <= 1e-6
    assert np.abs(_defects(plant, traj)).max() <= 1e-6  # recomputed independently in numpy
    np.testing.assert_allclose(traj.x[0], START, atol=1e-12)
    np.testing.assert_allclose(traj.x[-1], GOAL, atol=1e-12)
    assert 0.5 <= traj.duration <= 5.0
    # objective = T + 10 ∫ F² dt, recomputed by Gauss-Legendre quadrature of the input interpolant per interval
    nodes, weights = np.polynomial.legendre.leggauss(4)
    effort = 0.0
    for a, b in zip(traj.t[:-1], traj.t[1:], strict=True):
        ts = 0.5 * (a + b) + 0.5 * (b - a) * nodes
        effort += 0.5 * (b - a) * weights @ traj.u_at(ts)[:, 0] ** 2
    assert traj.objective == pytest.approx(traj.duration + 10 * effort, rel=1e-6)


@pytest.mark.parametrize("method", METHODS)
def test_bounds_hold_at_every_knot(swingups, method):
    traj = swingups[method]
    assert np.all(np.abs(traj.u) <= 5.0)
    assert np.all(np.abs(traj.x[:, 0]) <= 1.0)


def test_active_state_bound_holds_exactly(plant):
    """With |x| <= 0.5 the cart must use the whole track: the bound is reached and never exceeded."""
    opt = TrajectoryOptimizer(
        plant,
        knots=41,
        method="trapezoid",
        u_min=[-5],
        u_max=[5],
        x_min=[-0.5, -INF, -INF, -INF],
        x_max=[0.5] + [INF] * 3,
    )
    traj = opt.solve(START, GOAL, duration=(0.5, 6.0), cost=SWINGUP_COST)
    assert np.abs(traj.x[:, 0]).max() <= 0.5
    assert np.abs(traj.x[:, 0]).max() >= 0.5 - 1e-6
    assert np.all(np.abs(traj.u) <= 5.0)


@pytest.mark.parametrize(("method", "order"), [("hermite_simpson", 4), ("trapezoid", 2), ("multiple_shooting", 4)])
def test_integration_reproduces_states_to_the_method_order(plant, fixed_time_pairs, method, order):
    errors = []
    for traj in fixed_time_pairs[method]:
        assert traj.max_defect <= 1e-6
        errors.append(np.abs(_integrate(plant, traj) - traj.x[1:]).max())
    coarse, fine = errors
    assert fine < {2: 0.05, 4: 1e-3}[order]  # at 61 knots
    # halving h divides the local error by about 2**(order + 1); ask for at least 2**order
    assert coarse / fine > 2**order, (coarse, fine)


@pytest.mark.parametrize("method", METHODS)
def test_interpolants_agree_with_the_dynamics_between_knots(plant, fixed_time_pairs, method):
    """x_at between knots is close to the integrated plant: its residual falls with h as well."""
    res = []
    for traj in fixed_time_pairs[method]:
        xs = _integrate(plant, traj)
        k = np.arange(traj.knots - 1)
        tm = 0.5 * (traj.t[k] + traj.t[k + 1])
        # one step from each knot's integrated state to the midpoint
        xm = np.array(
            [
                solve_ivp(
                    lambda t, x, k=k, traj=traj: plant.dynamics(x, traj.u_at(min(t, traj.t[k + 1] - 1e-12))),
                    (traj.t[k], tm[k]),
                    traj.x[k],
                    rtol=1e-10,
                    atol=1e-12,
                ).y[:, -1]
                for k in range(traj.knots - 1)
            ]
        )
        res.append(np.abs(traj.x_at(tm) - xm).max())
        np.testing.assert_allclose(traj.x_at(traj.t), traj.x, atol=1e-12)
        np.testing.assert_allclose(traj.u_at(traj.t[:-1]), traj.u[:-1], atol=1e-12)
        assert xs.shape == traj.x[1:].shape
    assert res[1] < res[0] / 3


def test_resolve_reuses_the_nlp(optimizers):
    opt = optimizers["trapezoid", 31]
    solver = opt.solver
    a = opt.solve(START, GOAL, duration=2.5, cost="effort")
    b = opt.solve(START, GOAL, duration=2.5, cost="effort")
    assert opt.solver is solver
    np.testing.assert_allclose(a.x, b.x, atol=1e-12)
    c = opt.solve(START, [0.2, 0, 0, 0], duration=3.0, cost={"effort": 2.0})  # new goal, duration and weights
    np.testing.assert_allclose(c.x[-1], [0.2, 0, 0, 0], atol=1e-12)
    assert c.duration == pytest.approx(3.0)


def test_impossible_bounds_raise_planning_failed_naming_the_constraint(plant):
    opt = TrajectoryOptimizer(
        plant, knots=21, method="trapezoid", u_min=[-0.05], u_max=[0.05], x_min=X_MIN, x_max=X_MAX
    )
    with pytest.raises(PlanningFailed) as err:
        opt.solve(START, GOAL, duration=(0.5, 1.0), cost="effort")
    msg = str(err.value)
    assert "IPOPT status" in msg
    assert "worst constraint: dynamics defect of" in msg
    assert any(name in msg for name in plant.state_names)
    assert "force bound" in msg


def test_goal_outside_the_bounds_names_the_bound(plant):
    opt = TrajectoryOptimizer(plant, knots=11, method="trapezoid", x_min=X_MIN, x_max=X_MAX)
    with pytest.raises(PlanningFailed, match=r"x_goal x = 2 violates the bound x_min/x_max \[-1, 1\]"):
        opt.solve(START, [2.0, 0, 0, 0], duration=2.0)


def test_bad_arguments(plant):
    with pytest.raises(InvalidArgument, match="did you mean 'trapezoid'"):
        TrajectoryOptimizer(plant, knots=11, method="trapezoidal")
    with pytest.raises(InvalidArgument, match="knots"):
        TrajectoryOptimizer(plant, knots=2)
    opt = TrajectoryOptimizer(plant, knots=11, method="trapezoid")
    with pytest.raises(InvalidArgument, match="duration"):
        opt.solve(START, GOAL, duration=(2.0, 1.0))
    with pytest.raises(InvalidArgument, match="did you mean 'effort'"):
        opt.solve(START, GOAL, cost={"efort": 1.0})
    with pytest.raises(InvalidArgument, match="x_start"):
        opt.solve([0, 0], GOAL)
    with pytest.raises(InvalidArgument, match=r"ipopt: .*Invalid options"):
        TrajectoryOptimizer(plant, knots=11, ipopt={"linear_solver": "no_such_solver"})
    with pytest.raises(InvalidArgument, match="Invalid_Option"):  # a valid name, but HSL is not installed
        TrajectoryOptimizer(plant, knots=11, ipopt={"linear_solver": "ma27"}).solve(START, GOAL)


def test_save_load_round_trip_and_plot(swingups, tmp_path):
    for meth, traj in swingups.items():
        path = traj.save(tmp_path / f"{meth}.npz")
        back = Trajectory.load(path)
        ts = np.linspace(-0.1, traj.duration + 0.1, 57)
        np.testing.assert_array_equal(back.x_at(ts), traj.x_at(ts))
        np.testing.assert_array_equal(back.u_at(ts), traj.u_at(ts))
        assert (back.method, back.iterations, back.objective, back.max_defect) == (
            traj.method,
            traj.iterations,
            traj.objective,
            traj.max_defect,
        )
        assert back.state_names == traj.state_names
    png = swingups["trapezoid"].plot(tmp_path / "plan.png")
    assert png.stat().st_size > 1000
    (tmp_path / "junk.npz").write_bytes(b"not a zip")
    with pytest.raises(InvalidArgument, match="not a saved plan"):
        Trajectory.load(tmp_path / "junk.npz")


# ------------------------------------------------------------------ scenarios
def _doc(**plan):
    base = {
        "start": [0.0, 0.0, float(np.pi), 0.0],
        "goal": [0.0, 0.0, 0.0, 0.0],
        "knots": 31,
        "method": "trapezoid",
    }
    base.update(plan)
    return {
        "plant": {"type": "CartPole"},
        "controller": {"type": "TVLQR", "Q": [10, 1, 10, 1], "R": [0.1]},
        "plan": base,
    }


def test_plan_table_is_strict():
    sc = parse_scenario(_doc())
    assert sc.plan["knots"] == 31
    assert sc.controller.options["plan"] == sc.plan
    assert sc.sim.initial_state == sc.plan["start"]
    with pytest.raises(ConfigError, match=r"\[plan\] unknown key 'knot'.*did you mean 'knots'"):
        parse_scenario(_doc(knot=31))
    with pytest.raises(ConfigError, match=r"\[plan\].*'bounds': unknown key 'umax'.*did you mean 'u_max'"):
        parse_scenario(_doc(bounds={"umax": [5]}))
    with pytest.raises(ConfigError, match=r"\[plan\] 'start' must be a list of 4 numbers"):
        parse_scenario(_doc(start=[0, 0]))
    with pytest.raises(ConfigError, match=r"\[plan\].*did you mean 'hermite_simpson'"):
        parse_scenario(_doc(method="hermite-simpson"))
    doc = _doc()
    del doc["plan"]
    with pytest.raises(ConfigError, match=r"missing table \[plan\]"):
        parse_scenario(doc)
    doc = _doc()
    doc["controller"] = {"type": "LQR", "Q": [10, 1, 10, 1], "R": [0.1]}
    with pytest.raises(ConfigError, match="takes no plan"):
        parse_scenario(doc)


def test_shipped_swingup_scenarios_parse():
    from shinro_ctrl.config import load_scenario

    for name in ("cartpole_swingup_mujoco", "double_pendulum_swingup_mujoco", "quadrotor_point_to_point_mujoco"):
        sc = load_scenario(name)
        assert sc.controller.type == "TVLQR"
        assert sc.plan is not None and sc.engine is not None


def test_cli_plan_writes_and_run_loads_the_plan(tmp_path, capsys):
    from shinro_ctrl.cli import main

    scenario = tmp_path / "swing.toml"
    scenario.write_text(
        """
[plant]
type = "CartPole"

[controller]
type = "TVLQR"
Q = [10, 1, 10, 1]
R = [0.1]

[plan]
start = [0.0, 0.0, 3.141592653589793, 0.0]
goal = [0.0, 0.0, 0.0, 0.0]
knots = 41
method = "trapezoid"
duration = [0.5, 5.0]
cost = { time = 1.0, effort = 10.0 }
bounds = { u_min = [-5.0], u_max = [5.0], x_min = [-1.0, -inf, -inf, -inf], x_max = [1.0, inf, inf, inf] }

[sim]
duration = 6.0
track = ["x", "theta"]
"""
    )
    assert main(["plan", str(scenario), "--out", str(tmp_path), "--plot", str(tmp_path / "plan.png")]) == 0
    out = capsys.readouterr().out
    for word in ("solve time", "iterations", "objective", "max defect", "Solve_Succeeded"):
        assert word in out
    saved = tmp_path / "swing_plan.npz"
    traj = Trajectory.load(saved)
    assert traj.method == "trapezoid" and traj.knots == 41
    assert main(["run", str(scenario), "--plan", str(saved), "--out", str(tmp_path / "run")]) == 0
    out = capsys.readouterr().out
    assert f"objective {traj.objective:.6g}" in out  # the loaded plan, not a new one
    from shinro_ctrl.config import load_scenario
    from shinro_ctrl.planning import with_plan_file
    from shinro_ctrl.sim import RobotSim

    sim = RobotSim(with_plan_file(load_scenario(scenario), saved))
    assert sim.controller.trajectory.objective == traj.objective
    np.testing.assert_array_equal(sim.controller.u_max, [5.0])  # the plan's bounds still saturate the controller
    assert main(["plan", str(tmp_path / "missing.toml")]) == 2
    capsys.readouterr()
    assert traj.origin == {
        "plant": "CartPole",
        "params": {k: float(v) for k, v in CartPole().params().items()},
        "dt": CartPole().dt,
        "bounds": {
            "u_min": [-5.0],
            "u_max": [5.0],
            "x_min": [-1.0, "-inf", "-inf", "-inf"],
            "x_max": [1.0] + 3 * ["inf"],
        },
    }
    # the same plan on another plant, other parameters, another dt or other bounds is refused, naming the mismatch
    text = scenario.read_text()
    other = tmp_path / "other.toml"
    variants = {
        'type = "CartPole"\ncart_mass = 5.0': "params.cart_mass = 0.5 in the plan, 5.0 in the scenario",
        'type = "CartPole"\npole_length = 0.7': "params.pole_length",
        'type = "CartPole"\ndt = 0.02': "dt = 0.01 in the plan, 0.02 in the scenario",
    }
    for plant, needle in variants.items():
        other.write_text(text.replace('type = "CartPole"', plant))
        assert main(["run", str(other), "--plan", str(saved), "--duration", "0.1"]) == 2
        err = capsys.readouterr().err.strip()
        assert needle in err and len(err.splitlines()) == 1, err
    other.write_text(text.replace("u_min = [-5.0], u_max = [5.0]", "u_min = [-20.0], u_max = [20.0]"))
    assert main(["run", str(other), "--plan", str(saved), "--duration", "0.1"]) == 2
    assert "bounds.u_max = [5.0] in the plan, [20.0] in the scenario" in capsys.readouterr().err


def test_a_plan_without_its_origin_is_refused(swingups, tmp_path):
    from shinro_ctrl.planning import check_origin, plan_origin

    path = swingups["trapezoid"].save(tmp_path / "old.npz")  # solved by the optimizer directly: no origin
    with pytest.raises(InvalidArgument, match="does not record the plant"):
        check_origin(Trajectory.load(path), plan_origin(CartPole(), {}), path)
    traj = Trajectory.load(path)
    traj.origin = plan_origin(CartPole(), {})
    check_origin(traj, plan_origin(CartPole(), {}), path)  # the same plant: accepted
    with pytest.raises(InvalidArgument, match="was solved for a CartPole, the scenario's plant is a InvertedPendulum"):
        check_origin(traj, plan_origin(InvertedPendulum(), {}), path)


def test_plan_plot_labels_axes_with_units_like_run_plots(swingups, tmp_path, monkeypatch):
    import matplotlib.pyplot as plt

    figures = []
    monkeypatch.setattr(plt, "close", figures.append)  # keep the figure Trajectory.plot closes, to read its labels
    swingups["trapezoid"].plot(tmp_path / "plan.png")
    monkeypatch.undo()
    labels = [ax.get_ylabel() for ax in figures[0].axes]
    plt.close(figures[0])
    assert labels == ["x [m]", "x_dot [m/s]", "theta [rad]", "theta_dot [rad/s]", "force [N]"]


def test_ipopt_is_quiet_unless_verbose(plant, capfd):
    quiet = TrajectoryOptimizer(plant, knots=11, method="trapezoid")
    quiet.solve(START, [0.2, 0, np.pi, 0], duration=2.0)
    out, err = capfd.readouterr()
    assert out == "" and err == ""
    loud = TrajectoryOptimizer(plant, knots=11, method="trapezoid", verbose=True)
    loud.solve(START, [0.2, 0, np.pi, 0], duration=2.0)
    assert "EXIT: Optimal Solution Found" in capfd.readouterr().out
