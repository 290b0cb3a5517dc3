"""Overflow and sizes: every size the user controls is bounded, huge values are one line, finite or our error."""

from __future__ import annotations

import pytest

from shinro_ctrl.cli import main
from shinro_ctrl.errors import ShinroError

from .bad_input_helpers import GOOD, check_one_line_exit_2

# ---------------------------------------------------------------------------------------- OVERFLOW
OVERFLOW_CASES = {
    # item 13: every size the user controls is bounded, and the message says the limit
    "substeps_huge": (GOOD + "[engine]\nsubsteps = 100000000\n", ["run"], "limit of 1,000"),
    "num_dof_huge": ('[plant]\ntype = "ArmRobot"\nnum_dof = 100000\n[controller]\ntype = "IKQP"\n', ["run"], "limit"),
    "horizon_huge": (
        GOOD.replace('type = "LQR"', 'type = "LinearMPC"\nhorizon = 10000000\nu_min = [-1]\nu_max = [1]'),
        ["design", "mpc"],
        "horizon",
    ),
    # item 14: overflowing values are one line
    "duration_huge": (GOOD + "[sim]\nduration = 1e300\n", ["run"], "limited to"),
    "seed_negative": (GOOD + "[sim]\nseed = -1\n", ["run"], "'seed' must be a non-negative integer"),
    "deep_nesting": (GOOD.replace("R = [0.1]", "R = " + "[" * 3000 + "]" * 3000), ["run"], "nested too deeply"),
    "deep_nesting_small": (GOOD.replace("R = [0.1]", "R = [[[[[[0.1]]]]]]"), ["run"], "nested more than"),
    "Q_huge": (
        GOOD.replace("[10, 1, 100, 1]", "[1e308, 1e308, 1e308, 1e308]"),
        ["design", "lqr"],
        "Q: entries up to 1e+308 are too large for the design's arithmetic",
    ),
    "horizon_over_limit": (
        GOOD.replace('type = "LQR"', 'type = "LinearMPC"\nhorizon = 99999\nu_min = [-1]\nu_max = [1]'),
        ["run"],
        "exceeds the limit of 10,000",
    ),
    "gravity_huge": (GOOD.replace('"CartPole"', '"CartPole"\ngravity = 1e308'), ["design", "lqr"], "overflows"),
    "Q_not_detectable": (GOOD.replace("[10, 1, 100, 1]", "[0, 0, 0, 0]"), ["design", "lqr"], "not detectable"),
    "Q_zero_on_cart": (GOOD.replace("[10, 1, 100, 1]", "[0, 1, 100, 1]"), ["run"], "mostly state 'x'"),
}


@pytest.mark.parametrize("case", sorted(OVERFLOW_CASES))
def test_overflow_and_sizes_are_one_line(case, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    text, command, needle = OVERFLOW_CASES[case]
    path = tmp_path / f"{case}.toml"
    path.write_text(text)
    check_one_line_exit_2([*command, str(path)], needle, capsys)


OVERFLOW_ARGS = {
    "duration_inf": (["run", "--duration", "inf"], "--duration must be a positive finite"),
    "duration_overflow": (["run", "--duration", "1e400"], "--duration must be a positive finite"),
    "duration_nan": (["run", "--duration", "nan"], "--duration"),
    "eps_huge": (["linearize", "pendulum", "--eps", "1e300"], "--eps must be a finite step"),
    "eps_inf": (["crosscheck", "pendulum", "--eps", "inf"], "--eps"),
    "sweep_seed_negative": (
        ["sweep", "cartpole_lqr", "--param", "plant.pole_mass=0.1:0.2", "--samples", "2", "--seed", "-1", "--out", "o"],
        "--seed must be a non-negative",
    ),
    "sweep_samples_huge": (
        ["sweep", "cartpole_lqr", "--param", "plant.pole_mass=0.1:0.2", "--samples", "10000000000", "--out", "o"],
        "--samples must be an integer in",
    ),
    "sweep_workers_zero": (
        ["sweep", "cartpole_lqr", "--param", "plant.pole_mass=0.1:0.2", "--workers", "0", "--out", "o"],
        "--workers",
    ),
    "sweep_stable_tol_inf": (
        ["sweep", "cartpole_lqr", "--param", "plant.pole_mass=0.1:0.2", "--stable-tol", "inf", "--out", "o"],
        "--stable-tol",
    ),
    "dask_unreachable": (
        ["sweep", "cartpole_lqr", "--param", "plant.pole_mass=0:1", "--scheduler", "tcp://127.0.0.1:9", "--out", "o"],
        "cannot reach the Dask scheduler",
    ),
    "sweep_range_huge": (
        ["sweep", "cartpole_lqr", "--param", "plant.pole_mass=-1e308:1e308", "--out", "o"],
        "values are limited to",
    ),
    "dask_malformed": (
        ["sweep", "cartpole_lqr", "--param", "plant.pole_mass=0.1:0.2", "--scheduler", "tcp://:x", "--out", "o"],
        "--scheduler must look like",
    ),
}


@pytest.mark.parametrize("case", sorted(OVERFLOW_ARGS))
def test_overflowing_arguments_are_checked_before_any_work(case, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    args, needle = OVERFLOW_ARGS[case]
    assert main(args) == 2
    out, err = capsys.readouterr()
    assert needle in err and len(err.strip().splitlines()) == 1, err
    assert "running" not in out and not (tmp_path / "o").exists()  # item 21: nothing done before the check


def test_huge_but_finite_errors_give_finite_metrics_and_never_means_never(capsys):
    # item 9: squares of 1e200 overflow; the metrics are computed on scaled errors (closed form: rms = 1e200)
    import numpy as np

    from shinro_ctrl.sim import compute_metrics, format_metrics

    t = np.arange(4) * 0.1
    x = np.tile([3e200, 4e200], (4, 1))
    m = compute_metrics(t, x, np.zeros((3, 1)), np.zeros((4, 2)), tracked=[0, 1])
    assert m["rms_error"] == pytest.approx(5e200) and m["max_error"] == pytest.approx(5e200)
    text = format_metrics({"rms_error": float("inf"), "settling_time": float("inf")})
    assert "never" in text.splitlines()[1] and "never" not in text.splitlines()[0]


@pytest.mark.parametrize("big", [1e308, -1e308, 1e200])
@pytest.mark.parametrize("name", ["ArmRobot", "CartPole", "DoublePendulum", "HolonomicMobileRobot", "Quadrotor"])
def test_a_huge_input_to_step_is_finite_or_our_error_and_never_a_numpy_warning(name, big):
    """Overflow inside a step (wheel speeds, IK toward a target out of reach, dynamics) is reported, not warned."""
    import warnings

    import numpy as np

    from shinro_ctrl.plants import plant_class

    plant = plant_class(name)()
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a RuntimeWarning from numpy fails the test
        try:
            for _ in range(3):
                plant.step(np.full(plant.input_dim, big))
        except ShinroError:
            return
    assert np.isfinite(plant.get_state()).all()


def _linear_designs():
    import numpy as np

    from shinro_ctrl.controllers import LQR, LinearMPC
    from shinro_ctrl.estimators.kalman import KalmanFilter
    from shinro_ctrl.estimators.luenberger import Luenberger

    C = np.array([[1.0, 0.0]])
    return {
        "LQR": lambda A, B: LQR(A, B, np.eye(2), np.eye(1)),
        "LinearMPC": lambda A, B: LinearMPC(A, B, np.eye(2), np.eye(1), 10),
        "KalmanFilter": lambda A, B: KalmanFilter(A, B, C, np.eye(1), np.eye(1)),
        "Luenberger": lambda A, B: Luenberger(A, B, C, [0.5, 0.6]),
    }


@pytest.mark.parametrize("kind", ["LQR", "LinearMPC", "KalmanFilter", "Luenberger"])
@pytest.mark.parametrize(("where", "value"), [("A", -2e298), ("A", 1e101), ("B", 3e200)])
def test_a_model_too_large_for_the_design_arithmetic_is_named(kind, where, value):
    """Finite but huge model entries (an MJCF with gravity 1e300) are refused naming the entry, not by a numpy
    'Array must not contain infs or NaNs' from inside the Riccati or PBH arithmetic."""
    import numpy as np

    from shinro_ctrl.errors import NonFiniteError

    A = np.array([[1.0, 0.01], [0.1, 1.0]])
    B = np.array([[0.0], [0.01]])
    (A if where == "A" else B)[1, 0] = value
    with pytest.raises(NonFiniteError, match=rf"{where}\[1, 0\] = .* is too large for a design"):
        _linear_designs()[kind](A, B)


@pytest.mark.parametrize("kind", ["LQR", "LinearMPC", "KalmanFilter", "Luenberger"])
def test_a_large_but_workable_model_is_designed(kind):
    """1e8 entries (a stiff joint) stay within the arithmetic: designed, not refused."""
    import numpy as np

    A = np.array([[1.0, 1e-4], [-1e8 * 1e-4, 1.0]])
    B = np.array([[0.0], [1e-4]])
    _linear_designs()[kind](A, B)


@pytest.mark.parametrize(
    "M",
    [[[1e308, 0], [0, 1e308]], [[1e308, 1e308], [-1e308, 1e308]], [[-1.7e308, 1e308], [1e308, 1e308]]],
    ids=["huge diagonal", "huge asymmetric", "huge indefinite"],
)
def test_huge_weights_are_checked_without_a_numpy_overflow_warning(M):
    """The symmetry check and the symmetrization work on halves: no RuntimeWarning (the fuzz test found one)."""
    import warnings

    import numpy as np

    from shinro_ctrl.errors import InvalidArgument
    from shinro_ctrl.validation import weight_matrix

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        try:
            W = weight_matrix("Q", np.array(M, dtype=float), 2)
        except InvalidArgument as exc:
            assert str(exc).startswith("Q must be") or "too large for the design" in str(exc)
        else:
            assert np.all(np.isfinite(W))
