"""Every bad input through every subcommand: one line on stderr, exit status 2, no traceback.

The table is run in-process through ``cli.main`` (the function the console
script calls) to keep it fast; a few cases go through the real command in a
subprocess to prove the wiring. Fault cases (interrupted writes) follow.
"""

from __future__ import annotations

import json
import re
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from shinro_ctrl.cli import main
from shinro_ctrl.resources import regression_dir

GOOD = '[plant]\ntype = "CartPole"\n\n[controller]\ntype = "LQR"\nQ = [10, 1, 100, 1]\nR = [0.1]\n'

# name: (scenario text, a fragment the one-line error must contain)
BAD_SCENARIOS: dict[str, tuple[str, str]] = {
    "malformed_toml": ("[plant\ntype = 1\n", "malformed TOML"),
    "empty_file": ("", "empty scenario"),
    "unknown_table": (GOOD + "[simulation]\nduration = 1\n", "unknown table 'simulation'"),
    "typo_key": (GOOD.replace('"CartPole"', '"CartPole"\npole_lenght = 0.5'), "did you mean 'pole_length'"),
    "wrong_type": (GOOD + "[sim]\nduration = 'long'\n", "'duration' must be a number"),
    "negative_mass": (GOOD.replace('"CartPole"', '"CartPole"\ncart_mass = -1.0'), "cart_mass"),
    "unknown_plant": (GOOD.replace("CartPole", "CartPol"), "unknown plant 'CartPol'"),
    "unknown_controller": (GOOD.replace('"LQR"', '"PID"'), "unknown controller 'PID'"),
    "q_wrong_size": (GOOD.replace("[10, 1, 100, 1]", "[10, 1, 100]"), "Q"),
    "nan_initial_state": (GOOD + "[sim]\ninitial_state = [0, 0, nan, 0]\n", "must be finite"),
    "missing_mjcf": (GOOD + '[engine]\ntype = "mujoco"\nmodel = "no_such_model.xml"\n', "no_such_model.xml"),
    "unknown_joint": (GOOD + '[engine]\ntype = "mujoco"\nmodel = "inverted_pendulum.xml"\n', "unknown"),
    "mpc_negative_horizon": (
        GOOD.replace('type = "LQR"', 'type = "LinearMPC"\nhorizon = -3'),
        "horizon",
    ),
    "initial_state_outside_bounds": (
        '[plant]\ntype = "InvertedPendulum"\nstate_bounds = { min = [-1, -5], max = [1, 5] }\n'
        '[controller]\ntype = "LQR"\nQ = [1, 1]\nR = [1]\n[sim]\ninitial_state = [2.0, 0.0]\n',
        "outside the plant's limits",
    ),
}

COMMANDS = {
    "run": lambda p: ["run", str(p)],
    "design": lambda p: ["design", "lqr", str(p)],
    "sweep": lambda p: [
        "sweep",
        str(p),
        "--param",
        "plant.pole_mass=0.05:0.2",
        "--samples",
        "2",
        "--out",
        str(p.parent / "sw"),
    ],
    "regress": lambda p: ["regress", str(p.parent)],
}


def check_one_line_exit_2(argv: list[str], needle: str, capsys) -> None:
    assert main(argv) == 2, argv
    err = capsys.readouterr().err
    assert needle in err, f"{argv}: {err!r}"
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and "Traceback" not in err, err


@pytest.mark.parametrize("case", sorted(BAD_SCENARIOS))
@pytest.mark.parametrize("command", sorted(COMMANDS))
def test_bad_scenarios_through_every_scenario_command(case, command, tmp_path, capsys):
    text, needle = BAD_SCENARIOS[case]
    if command == "design" and case == "mpc_negative_horizon":
        needle = "horizon"
    path = tmp_path / "cases" / f"{case}.toml"
    path.parent.mkdir()
    path.write_text(text)
    check_one_line_exit_2(COMMANDS[command](path), needle, capsys)


PLANT_COMMAND_CASES = {
    "unknown_plant": (["cartpol"], "did you mean 'cartpole'"),
    "x0_wrong_size": (["cartpole", "--x0", "1,2"], "expected shape (4,)"),
    "x0_not_a_number": (["cartpole", "--x0", "a,b,c,d"], "not a number"),
    "x0_nan": (["cartpole", "--x0", "0,0,nan,0"], "finite"),
    "u0_wrong_size": (["double_pendulum", "--u0", "1"], "expected shape (2,)"),
    "eps_negative": (["cartpole", "--eps", "-1"], "eps"),
}


@pytest.mark.parametrize("case", sorted(PLANT_COMMAND_CASES))
@pytest.mark.parametrize("command", ["linearize", "crosscheck"])
def test_bad_plant_arguments(case, command, capsys):
    args, needle = PLANT_COMMAND_CASES[case]
    check_one_line_exit_2([command, *args], needle, capsys)


OTHER_CASES = {
    "missing_config": (["run", "no_such_scenario.toml"], "no config named 'no_such_scenario.toml'"),
    "negative_duration": (["run", "cartpole_lqr", "--duration", "-1"], "duration"),
    "design_wrong_kind": (["design", "mpc", "cartpole_lqr"], "not LinearMPC"),
    "regress_missing_dir": (["regress", "/no/such/dir"], "no regression folder"),
    "sweep_lo_gt_hi": (
        ["sweep", "cartpole_lqr", "--param", "plant.pole_mass=0.3:0.1", "--samples", "2", "--out", "sw"],
        "0.3",
    ),
    "sweep_unknown_key": (
        ["sweep", "cartpole_lqr", "--param", "plant.pole_mas=0.1:0.3", "--samples", "2", "--out", "sw"],
        "pole_mass",
    ),
    "sweep_bad_range": (
        ["sweep", "cartpole_lqr", "--param", "plant.pole_mass=abc", "--samples", "2", "--out", "sw"],
        "plant.pole_mass",
    ),
    "unknown_command": (["fly"], "invalid choice"),
}


@pytest.mark.parametrize("case", sorted(OTHER_CASES))
def test_other_user_errors(case, capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    args, needle = OTHER_CASES[case]
    check_one_line_exit_2(args, needle, capsys)


def test_regress_with_empty_dir(tmp_path, capsys):
    check_one_line_exit_2(["regress", str(tmp_path)], "no regression scenarios", capsys)


@pytest.mark.parametrize("case", ["typo_key", "missing_mjcf", "unknown_joint"])
def test_real_command_prints_one_line(case, tmp_path):
    text, needle = BAD_SCENARIOS[case]
    path = tmp_path / f"{case}.toml"
    path.write_text(text)
    res = subprocess.run(
        [sys.executable, "-m", "shinro_ctrl.cli", "run", str(path)], capture_output=True, text=True, timeout=120
    )
    assert res.returncode == 2 and needle in res.stderr
    assert len(res.stderr.strip().splitlines()) == 1 and "Traceback" not in res.stderr


def test_debug_flag_shows_the_traceback(tmp_path):
    path = tmp_path / "typo.toml"
    path.write_text(BAD_SCENARIOS["typo_key"][0])
    res = subprocess.run(
        [sys.executable, "-m", "shinro_ctrl.cli", "--debug", "run", str(path)],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert res.returncode != 0 and "Traceback" in res.stderr and "ConfigError" in res.stderr


# ----------------------------------------------------------------- fault cases
KILL_MID_WRITE = textwrap.dedent(
    """
    import os, signal, sys
    import shinro_ctrl.files as files
    calls = {"n": 0}
    real_fsync = os.fsync

    def fsync_then_die(fd):
        real_fsync(fd)
        calls["n"] += 1
        if calls["n"] == int(sys.argv[2]):
            os.kill(os.getpid(), signal.SIGKILL)  # the temporary file is complete, the rename has not happened

    files.os.fsync = fsync_then_die
    from shinro_ctrl.cli import main
    sys.exit(main(["regress", sys.argv[1], "--update"]))
    """
)


@pytest.mark.parametrize("kill_at", [1, 2])
def test_interrupted_regress_update_leaves_baselines_intact(tmp_path, kill_at):
    for name in ("cartpole_lqr", "double_pendulum_lqr"):
        shutil.copy(regression_dir() / f"{name}.toml", tmp_path)
        # stale baselines, so an update would change them
        (tmp_path / f"{name}.baseline.json").write_text(json.dumps({"format": 1, "metrics": {"rms_error": 123.0}}))
    before = {p.name: p.read_text() for p in tmp_path.glob("*.baseline.json")}
    res = subprocess.run(
        [sys.executable, "-c", KILL_MID_WRITE, str(tmp_path), str(kill_at)], capture_output=True, text=True, timeout=300
    )
    assert res.returncode == -9, res.stderr  # really killed
    changed = 0
    for path in tmp_path.glob("*.baseline.json"):
        data = json.loads(path.read_text())  # every baseline parses: old or complete new, never half-written
        changed += data != json.loads(before[path.name])
    assert changed == 0  # killed before the set's commit point: every baseline is the previous one
    # a later run is not confused by the orphaned temporary file and completes the update
    assert main(["regress", str(tmp_path), "--update"]) == 0
    assert main(["regress", str(tmp_path)]) == 0
    assert not [p for p in Path(tmp_path).iterdir() if p.name.startswith(".") and p.suffix == ".tmp"]


# =====================================================================================================
# By kind: TYPES (strict TOML types in every table), OVERFLOW (sizes, durations, huge values),
# INTERRUPTION (SIGINT / SIGKILL) and FILE SAFETY (nothing the user owns is lost or mixed up).
# =====================================================================================================
import os  # noqa: E402
import random  # noqa: E402
import signal  # noqa: E402
import time  # noqa: E402
from datetime import date, datetime  # noqa: E402

from hypothesis import HealthCheck, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

from shinro_ctrl.config import parse_scenario  # noqa: E402
from shinro_ctrl.errors import ConfigError, ShinroError  # noqa: E402


def cli_subprocess(*args: str, timeout: float = 120, **kw) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "shinro_ctrl.cli", *args], capture_output=True, text=True, timeout=timeout, **kw
    )


# ------------------------------------------------------------------------------------------- TYPES
TYPE_CASES = {
    # item 7: a string or boolean where a boolean or number is meant, named by key
    "discrete_string": ({"controller": {"discrete": "false"}}, "'discrete' must be a boolean"),
    "feedforward_string": ({"controller": {"feedforward": "false"}}, "'feedforward' must be a boolean"),
    "dt_boolean": ({"plant": {"dt": True}}, "'dt' must be a number"),
    "mass_boolean": ({"plant": {"pole_mass": False}}, "'pole_mass' must be a number"),
    "Q_strings": ({"controller": {"Q": ["10", "1", "100", "1"]}}, "'Q' must be a number or an array of numbers"),
    "R_boolean": ({"controller": {"R": [True]}}, "'R'"),
    "Q_ragged": ({"controller": {"Q": [[1, 0], [0, 1, 2], [0], [1]]}}, "'Q' is ragged"),
    "Q_table": ({"controller": {"Q": {"a": "b"}}}, "'Q.a' must be a number"),
    "x0_string": ({"controller": {"x0": "0,0,0,0"}}, "'x0'"),
    "duration_bool": ({"sim": {"duration": True}}, "'duration' must be a number"),
    "duration_date": ({"sim": {"duration": date(2020, 1, 1)}}, "'duration' must be a number, got date-time"),
    "seed_float": ({"sim": {"seed": 1.5}}, "'seed' must be an integer"),
    "track_numbers": ({"sim": {"track": [1, 2]}}, "'track'"),
    "substeps_float": ({"engine": {"type": "mujoco", "substeps": 2.0}}, "'substeps' must be an integer"),
    "model_number": ({"engine": {"type": "mujoco", "model": 3}}, "'model' must be a string"),
    "reference_kind_number": ({"sim": {"reference": {"kind": 1}}}, "'kind' must be a string"),
    "reference_kind_array": ({"sim": {"reference": {"kind": ["step"]}}}, "'kind' must be a string"),
    "plant_type_number": ({"plant": {"type": 5}}, "'type' must be a string"),
    "regression_tol_string": ({"regression": {"rms_error": {"rel": "0.1"}}}, "rms_error.rel"),
    "method_boolean": ({"controller": {"method": True}}, "'method' must be a string"),
    # options a controller forwards (**options, e.g. LinearMPC's MPCOptions) are typed too
    "mpc_u_min_boolean": (
        {"controller": {"type": "LinearMPC", "horizon": 5, "u_min": [True], "u_max": [1]}},
        "'u_min' must be a number or an array of numbers",
    ),
    "mpc_soft_string": (
        {"controller": {"type": "LinearMPC", "horizon": 5, "u_min": [-1], "u_max": [1], "soft": "yes"}},
        "'soft' must be a boolean",
    ),
    "mpc_solver_number": (
        {"controller": {"type": "LinearMPC", "horizon": 5, "u_min": [-1], "u_max": [1], "solver": 1}},
        "'solver' must be a string",
    ),
}
OSQP_TYPE_CASES = {
    "eps_abs_string": ({"eps_abs": "x"}, "'eps_abs' must be a number"),
    "max_iter_list": ({"max_iter": [1]}, "'max_iter' must be an integer"),
    "max_iter_float": ({"max_iter": 10.5}, "'max_iter' must be an integer"),
    "polishing_string": ({"polishing": "yes"}, "'polishing' must be a boolean"),
}


@pytest.mark.parametrize("case", sorted(OSQP_TYPE_CASES))
def test_osqp_settings_types_name_the_setting(case):
    from shinro_ctrl.sim import RobotSim

    settings, needle = OSQP_TYPE_CASES[case]
    doc = _doc(
        {"controller": {"type": "LinearMPC", "horizon": 5, "u_min": [-1], "u_max": [1], "osqp_settings": settings}}
    )
    with pytest.raises(ShinroError, match=needle):
        RobotSim(parse_scenario(doc))


def _doc(changes: dict) -> dict:
    doc = {"plant": {"type": "CartPole"}, "controller": {"type": "LQR", "Q": [10, 1, 100, 1], "R": [0.1]}}
    for table, body in changes.items():
        doc.setdefault(table, {}).update(body)
    return doc


@pytest.mark.parametrize("case", sorted(TYPE_CASES))
def test_types_strict_in_every_table(case):
    changes, needle = TYPE_CASES[case]
    with pytest.raises(ConfigError) as info:
        parse_scenario(_doc(changes))
    assert needle in str(info.value), str(info.value)


@pytest.mark.parametrize("case", ["discrete_string", "dt_boolean", "Q_strings", "Q_ragged"])
def test_types_through_the_cli(case, tmp_path, capsys):
    from shinro_ctrl.files import dump_toml

    changes, needle = TYPE_CASES[case]
    path = tmp_path / f"{case}.toml"
    path.write_text(dump_toml(_doc(changes)))
    check_one_line_exit_2(["design", "lqr", str(path)], needle, capsys)


# every TOML value type (string, integer, float, boolean, date-time, array, table) in every key of every table
TOML_VALUES = st.recursive(
    st.one_of(
        st.text(max_size=8),
        st.integers(min_value=-(2**63), max_value=2**63 - 1),
        st.floats(allow_nan=True, allow_infinity=True),
        st.booleans(),
        st.dates(),
        st.datetimes(min_value=datetime(1900, 1, 1)),
    ),
    lambda children: st.lists(children, max_size=5) | st.dictionaries(st.text(max_size=5), children, max_size=3),
    max_leaves=12,
)
TABLE_KEYS = {
    "plant": ["cart_mass", "pole_mass", "pole_length", "damping", "gravity", "dt", "track_limits", "type"],
    "controller": ["Q", "R", "x0", "u0", "discrete", "discretization", "method", "u_min", "u_max", "feedforward"],
    "engine": ["type", "model", "substeps"],
    "sim": ["duration", "initial_state", "reference", "track", "settle_tol", "measurement_noise", "seed"],
    "sim.reference": ["kind", "value", "time", "initial", "final", "radius", "frequency", "axes", "points"],
    "regression": ["rms_error", "settling_time"],
}
MPC_KEYS = ["horizon", "x_min", "x_max", "du_max", "soft", "soft_weight_l1", "terminal_cost", "osqp_settings"]


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    table=st.sampled_from(sorted(TABLE_KEYS)),
    data=st.data(),
    value=TOML_VALUES,
)
def test_property_any_toml_value_anywhere_is_accepted_or_a_config_error(table, data, value):
    """Whatever value of whatever TOML type lands in whatever key: a scenario, or a ShinroError naming the key."""
    from shinro_ctrl.sim import RobotSim

    key = data.draw(st.sampled_from(TABLE_KEYS[table]))
    doc = _doc({})
    if table == "sim.reference":
        doc["sim"] = {"reference": {"kind": "step", "time": 0.5, key: value}}
    elif table == "engine":
        doc["engine"] = {"type": "mujoco", key: value}
    else:
        doc.setdefault(table, {})[key] = value
    try:
        scenario = parse_scenario(doc)
    except ConfigError as exc:
        assert "Traceback" not in str(exc) and str(exc).strip()
        return
    try:  # a scenario that parses is one that builds, or fails with the project's error
        RobotSim(scenario)
    except ShinroError:
        pass


ESTIMATOR_KEYS = ["type", "Qn", "Rn", "Qn_on", "steady_state", "discretization", "initial_estimate", "P0"]
PLAN_KEYS = ["start", "goal", "knots", "method", "duration", "cost", "bounds", "substeps", "file"]


@settings(max_examples=100, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(key=st.sampled_from(ESTIMATOR_KEYS), value=TOML_VALUES)
def test_property_estimator_table_of_any_type(key, value):
    from shinro_ctrl.sim import RobotSim

    doc = _doc({"sim": {"measured": ["x", "theta"]}})
    doc["estimator"] = {"type": "KalmanFilter", key: value}
    try:
        RobotSim(parse_scenario(doc))
    except ShinroError:
        pass


@settings(max_examples=100, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(key=st.sampled_from(PLAN_KEYS), value=TOML_VALUES)
def test_property_plan_table_of_any_type(key, value):
    # parsed only: a plan that parses is solved by trajectory optimization, too slow for a property test
    doc = _doc({"controller": {"type": "TVLQR", "Q": [10, 1, 100, 1], "R": [0.1]}})
    doc["plan"] = {"start": [0, 0, 0.2, 0], "goal": [0, 0, 0, 0], key: value}
    try:
        parse_scenario(doc)
    except ConfigError:
        pass


@settings(max_examples=100, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(key=st.sampled_from(MPC_KEYS), value=TOML_VALUES)
def test_property_mpc_options_of_any_type(key, value):
    from shinro_ctrl.sim import RobotSim

    doc = _doc({"controller": {"type": "LinearMPC", "horizon": 5, "u_min": [-10], "u_max": [10], key: value}})
    try:
        RobotSim(parse_scenario(doc))
    except ShinroError:
        pass


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
        "Q: its eigenvalues cannot be computed",
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


def test_numeric_overflow_inside_the_command_is_one_line(monkeypatch, capsys):
    import shinro_ctrl.cli as cli

    def overflow(args):
        raise OverflowError("(34, 'Numerical result out of range')")

    monkeypatch.setattr(cli, "cmd_list", overflow)
    check_one_line_exit_2(["list"], "numeric overflow", capsys)


def test_warnings_are_not_printed_before_the_error_line(tmp_path, capsys):
    # item 15: a huge dt warns while the model is built, then the design fails: the error line stands alone
    path = tmp_path / "huge_dt.toml"
    path.write_text(GOOD.replace('"CartPole"', '"CartPole"\ndt = 1e6').replace("[10, 1, 100, 1]", "[1e300, 1, 1, 1]"))
    assert main(["design", "lqr", str(path)]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and err.startswith("error: "), err


# ------------------------------------------------------------------------------------ FILE SAFETY
def test_run_out_refuses_a_folder_holding_the_input_scenario(tmp_path, capsys):
    # item 2: the user's scenario (with its comments) is never overwritten
    scenario = tmp_path / "scenario.toml"
    text = "# my tuned cart-pole\n" + GOOD
    scenario.write_text(text)
    assert main(["run", str(scenario), "--out", str(tmp_path), "--duration", "0.1"]) == 2
    assert "input" in capsys.readouterr().err
    assert scenario.read_text() == text
    other = tmp_path / "mine.toml"
    other.write_text(text)
    assert main(["run", str(other), "--out", str(tmp_path), "--duration", "0.1"]) == 2
    assert "input" in capsys.readouterr().err
    assert main(["run", "--out", str(tmp_path), "--duration", "0.1"]) == 2  # not the input, but the user's file
    assert "not a run output" in capsys.readouterr().err
    assert other.read_text() == text and sorted(p.name for p in tmp_path.iterdir()) == ["mine.toml", "scenario.toml"]


def test_plan_checks_its_outputs_before_solving(tmp_path, capsys):
    # plan --out / --plot go through run's output checks: no input or foreign file overwritten, nothing solved first
    from shinro_ctrl.resources import shipped_config

    scenario = tmp_path / "swing.toml"
    scenario.write_text(shipped_config("cartpole_swingup_mujoco.toml").read_text())
    (tmp_path / "o").mkdir()
    (tmp_path / "o" / "swing_plan.npz").write_text("my notes")
    cases = [
        (["--plot", str(scenario)], "is the input file"),
        (["--out", str(scenario)], "is not a folder"),
        (["--out", str(tmp_path / "o")], "is not an NPZ file"),
        (["--out", str(tmp_path / "p"), "--plot", str(tmp_path / "p" / "swing_plan.npz")], "is the plan file"),
    ]
    for extra, needle in cases:
        assert main(["plan", str(scenario), *extra]) == 2
        out, err = capsys.readouterr()
        assert needle in err and "solve time" not in out, err
    assert (tmp_path / "o" / "swing_plan.npz").read_text() == "my notes"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["o", "swing.toml"]


@pytest.mark.parametrize("option", ["--plot", "--video"])
def test_plot_onto_the_input_file_is_refused(option, tmp_path, capsys):
    scenario = tmp_path / "mine.toml"
    scenario.write_text(GOOD)
    target = scenario if option == "--plot" else tmp_path / "notes.gif"
    if option == "--video":
        target.write_text("my notes, not a GIF")
    before = target.read_text()
    assert main(["run", str(scenario), option, str(target), "--duration", "0.1"]) == 2
    err = capsys.readouterr()
    assert "running" not in err.out and ("input" in err.err or "not a GIF" in err.err), err
    assert target.read_text() == before


def test_output_errors_name_the_users_path_before_any_work(tmp_path, capsys):
    (tmp_path / "afile").write_text("a file where a folder is needed")
    target = tmp_path / "afile" / "x.png"
    assert main(["run", "--plot", str(target), "--duration", "0.1"]) == 2
    out, err = capsys.readouterr()
    assert str(target) in err and ".tmp" not in err and "running" not in out, err


def test_atomic_write_errors_name_the_target_not_the_temporary(tmp_path):
    from shinro_ctrl.files import atomic_write

    target = tmp_path / "a" / "b.json"
    (tmp_path / "a").write_text("a file where a folder is needed")
    with pytest.raises(OSError) as info:
        atomic_write(target, lambda f: f.write("x"))
    assert str(target) in str(info.value) and ".tmp" not in str(info.value)


def _copy_regression(tmp_path, names=("cartpole_lqr", "double_pendulum_lqr")) -> dict[str, str]:
    for name in names:
        shutil.copy(regression_dir() / f"{name}.toml", tmp_path)
        shutil.copy(regression_dir() / f"{name}.baseline.json", tmp_path)
    return {p.name: p.read_text() for p in tmp_path.glob("*.baseline.json")}


def test_regress_update_validates_every_scenario_before_writing(tmp_path, capsys):
    # item 4: a malformed scenario anywhere in the folder: nothing is written
    before = _copy_regression(tmp_path)
    for p in tmp_path.glob("*.baseline.json"):
        data = json.loads(p.read_text())
        data["metrics"]["rms_error"] = 123.0
        p.write_text(json.dumps(data))
    before = {p.name: p.read_text() for p in tmp_path.glob("*.baseline.json")}
    (tmp_path / "zz_broken.toml").write_text(GOOD.replace("R = [0.1]", "R = ['x']"))
    assert main(["regress", str(tmp_path), "--update"]) == 2
    assert "zz_broken" in capsys.readouterr().err
    assert {p.name: p.read_text() for p in tmp_path.glob("*.baseline.json")} == before


def test_regress_update_writes_nothing_when_a_run_fails(tmp_path, capsys):
    before = _copy_regression(tmp_path, ("cartpole_lqr",))
    (tmp_path / "zz_infeasible.toml").write_text(  # hard state bounds the initial state violates: MPCInfeasible
        GOOD.replace(
            'type = "LQR"',
            'type = "LinearMPC"\nhorizon = 5\nu_min = [-1]\nu_max = [1]\n'
            "x_min = [-1, -1, -0.01, -1]\nx_max = [1, 1, 0.01, 1]",
        )
        + "[sim]\nduration = 0.5\ninitial_state = [0, 0, 0.5, 0]\n"
    )
    assert main(["regress", str(tmp_path), "--update"]) == 1
    out = capsys.readouterr().out
    assert "no baseline written" in out and "zz_infeasible" in out
    assert {p.name: p.read_text() for p in tmp_path.glob("*.baseline.json")} == before


def test_regress_without_a_folder_never_updates_the_shipped_baselines(capsys):
    # item 1: following the hint literally must not rewrite the installed package's baselines
    before = {p.name: p.read_bytes() for p in regression_dir().glob("*.baseline.json")}
    check_one_line_exit_2(["regress", "--update"], "name", capsys)
    assert {p.name: p.read_bytes() for p in regression_dir().glob("*.baseline.json")} == before


def test_missing_baseline_hint_names_the_folder(tmp_path, capsys):
    shutil.copy(regression_dir() / "cartpole_lqr.toml", tmp_path)
    assert main(["regress", str(tmp_path)]) == 1
    out, err = capsys.readouterr()
    assert f"regress {tmp_path} --update" in out and f"regress {tmp_path} --update" in err
    assert "regress --update" not in out


def test_baseline_symlink_is_written_through(tmp_path):
    # item 5: the link stays a link and its target gets the new value
    _copy_regression(tmp_path, ("cartpole_lqr",))
    store = tmp_path / "store"
    store.mkdir()
    real = store / "cartpole.json"
    real.write_text(json.dumps({"format": 1, "metrics": {"rms_error": 123.0}}))
    link = tmp_path / "cartpole_lqr.baseline.json"
    link.unlink()
    link.symlink_to(real)
    assert main(["regress", str(tmp_path), "--update"]) == 0
    assert link.is_symlink() and os.readlink(link) == str(real)
    assert json.loads(real.read_text())["metrics"]["rms_error"] != 123.0
    assert main(["regress", str(tmp_path)]) == 0


@pytest.mark.parametrize("fmt", [2, "1", None, True])
def test_baseline_with_an_unknown_format_is_refused(fmt, tmp_path, capsys):
    _copy_regression(tmp_path, ("cartpole_lqr",))
    path = tmp_path / "cartpole_lqr.baseline.json"
    data = json.loads(path.read_text())
    data["format"] = fmt
    path.write_text(json.dumps(data))
    check_one_line_exit_2(["regress", str(tmp_path)], "format", capsys)


HOLD_TEMP = textwrap.dedent(
    """
    import sys, time
    from pathlib import Path
    from shinro_ctrl.files import _locked_tempfile
    fd, tmp = _locked_tempfile(Path(sys.argv[1]), ".cartpole_lqr.baseline.json.")
    print(tmp, flush=True)
    time.sleep(60)
    """
)


def test_cleanup_never_deletes_a_live_writers_temporary(tmp_path):
    # item 6: a concurrent update's in-flight temporary is locked; only a dead writer's is stale
    from shinro_ctrl.files import remove_stale_temps

    proc = subprocess.Popen([sys.executable, "-c", HOLD_TEMP, str(tmp_path)], stdout=subprocess.PIPE, text=True)
    try:
        live = Path(proc.stdout.readline().strip())
        dead = tmp_path / ".cartpole_lqr.baseline.json.dead1234.tmp"
        dead.write_text("orphan of a killed update")
        removed = remove_stale_temps(tmp_path, ".*.baseline.json.*.tmp")
        assert live.exists() and not dead.exists() and removed == [dead]
    finally:
        proc.kill()
        proc.wait()
    assert remove_stale_temps(tmp_path, ".*.baseline.json.*.tmp") == [live] and not live.exists()


def test_two_concurrent_updates_on_one_folder(tmp_path):
    _copy_regression(tmp_path, ("cartpole_lqr",))
    procs = [
        subprocess.Popen(
            [sys.executable, "-m", "shinro_ctrl.cli", "regress", str(tmp_path), "--update"],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        for _ in range(2)
    ]
    for proc in procs:
        _, err = proc.communicate(timeout=300)
        assert proc.returncode == 0, err
    assert main(["regress", str(tmp_path)]) == 0
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]


def _run_folder_state(d: Path) -> str | None:
    """'complete' (manifest lists exactly the files, sizes match, each file loads), or None if empty/absent."""
    import numpy as np

    from shinro_ctrl.files import RUN_MANIFEST

    if not d.exists():
        return None
    manifest = json.loads((d / RUN_MANIFEST).read_text())
    names = sorted(p.name for p in d.iterdir() if p.name != RUN_MANIFEST)
    assert names == sorted(manifest["files"]) == sorted(manifest["expected"]), (names, manifest)
    for name, size in manifest["files"].items():
        assert (d / name).stat().st_size == size
    with np.load(d / "result.npz") as z:
        steps = len(z["t"])
    metrics = json.loads((d / "metrics.json").read_text())
    assert metrics["scenario"] and (d / "run.png").read_bytes()[:4] == b"\x89PNG"
    return f"{steps} steps"


def test_random_kills_of_run_out_leave_one_complete_run(tmp_path):
    # item 3: SIGKILL at random points (seeded) of `run --out`: the folder holds the previous run or the new one
    out = tmp_path / "out"
    assert main(["run", "--out", str(out), "--duration", "0.2"]) == 0
    states = {_run_folder_state(out)}
    t0 = time.perf_counter()
    ok = cli_subprocess("run", "--out", str(out), "--duration", "0.4")
    full = time.perf_counter() - t0
    assert ok.returncode == 0, ok.stderr
    states.add(_run_folder_state(out))
    rng = random.Random(14)
    for k in range(4):  # seeded random kill times over the whole command (imports, run, writes)
        duration = ("0.2", "0.4", "0.3")[k % 3]
        proc = subprocess.Popen(
            [sys.executable, "-m", "shinro_ctrl.cli", "run", "--out", str(out), "--duration", duration],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
        time.sleep(rng.uniform(0.3, 1.0) * full)
        proc.send_signal(signal.SIGKILL)
        proc.wait()
        state = _run_folder_state(out)
        assert state is not None
        states.add(state)
    assert states <= {"21 steps", "41 steps", "31 steps"}
    assert main(["run", "--out", str(out), "--duration", "0.2"]) == 0  # cleans up the orphans of the kills
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]
    assert _run_folder_state(out) == "21 steps"


def test_random_kills_of_regress_update_leave_one_complete_set(tmp_path):
    from shinro_ctrl.files import recover_journals

    _copy_regression(tmp_path)
    stale = {}
    for p in tmp_path.glob("*.baseline.json"):
        data = json.loads(p.read_text())
        data["metrics"]["rms_error"] = 123.0
        p.write_text(json.dumps(data))
        stale[p.name] = p.read_text()
    t0 = time.perf_counter()
    assert cli_subprocess("regress", str(tmp_path / "cartpole_lqr.toml")).returncode == 1
    full = 1.5 * (time.perf_counter() - t0)
    rng = random.Random(13)
    for _ in range(4):
        proc = subprocess.Popen(
            [sys.executable, "-m", "shinro_ctrl.cli", "regress", str(tmp_path), "--update"],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
        time.sleep(rng.uniform(0.2, 1.2) * full)
        proc.send_signal(signal.SIGKILL)
        proc.wait()
        recover_journals(tmp_path)  # what the next regress does first: a set killed after its commit completes
        now = {p.name: p.read_text() for p in tmp_path.glob("*.baseline.json")}
        is_old = [now[n] == stale[n] for n in stale]
        assert all(is_old) or not any(is_old), is_old  # all previous or all new, never mixed
        if not any(is_old):
            for p in tmp_path.glob("*.baseline.json"):  # make the next kill meaningful again
                p.write_text(stale[p.name])
    assert main(["regress", str(tmp_path), "--update"]) == 0
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]


# ----------------------------------------------------------------------------------- INTERRUPTION
INTERRUPT_CASES = {
    "run_mpc": ["run", "quadrotor_mpc_mujoco", "--duration", "100"],
    "sweep_pool": [
        "sweep",
        "cartpole_lqr",
        "--param",
        "plant.pole_mass=0.05:0.5",
        "--samples",
        "4000",
        "--workers",
        "2",
        "--method",
        "pool",
        "--out",
        "OUT",
    ],
    "regress_update": ["regress", "REG", "--update"],
}


@pytest.mark.parametrize("case", sorted(INTERRUPT_CASES))
def test_ctrl_c_ends_the_command_with_exit_130(case, tmp_path):
    # item 12: SIGINT (Ctrl-C) mid-work ends every command with 130, never "infeasible" or a failed sample
    _copy_regression(tmp_path)
    long_mpc = (regression_dir() / "cartpole_mpc.toml").read_text().replace("duration = 5.0", "duration = 10000.0")
    (tmp_path / "zz_long_mpc.toml").write_text(long_mpc)  # the MPC still solving when Ctrl-C arrives (DAQP: ~1 s/400 s)
    before = {p.name: p.read_text() for p in tmp_path.glob("*.baseline.json")}
    args = [a.replace("OUT", str(tmp_path / "sw")).replace("REG", str(tmp_path)) for a in INTERRUPT_CASES[case]]
    proc = subprocess.Popen(
        [sys.executable, "-m", "shinro_ctrl.cli", *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    if case == "run_mpc":
        assert proc.stdout.readline().startswith("running")  # the MPC loop is under way
        time.sleep(1.0)
    else:
        time.sleep(6.0)
    proc.send_signal(signal.SIGINT)
    t0 = time.perf_counter()
    out, err = proc.communicate(timeout=60)
    stopped_in = time.perf_counter() - t0
    assert proc.returncode == 130, (out, err)
    assert "interrupted" in err and "infeasible" not in (out + err).lower() and "Traceback" not in err, err
    assert stopped_in < 30  # workers stop promptly (a generous bound: this is not a timing test)
    assert {p.name: p.read_text() for p in tmp_path.glob("*.baseline.json")} == before
    assert not (tmp_path / "sw").exists()


# ------------------------------------------------------------------ API: no silent wrong answer
def _api_cases():
    import numpy as np

    from shinro_ctrl.controllers import IKQP, LQR, LinearMPC
    from shinro_ctrl.engine import MujocoEngine
    from shinro_ctrl.plants import CartPole, InvertedPendulum
    from shinro_ctrl.sim import RobotSim, compute_metrics
    from shinro_ctrl.sweep.batch import lqr_batch_rollout

    huge = np.array([1e300, 1e300, 1e300, 1e300])
    return {
        # item 8: Q = 0 leaves the cart's integrator on the unit circle
        "lqr_q_zero": (lambda: LQR.from_plant(CartPole(), [0, 0, 0, 0], [1]), "NotStabilizable", "not detectable"),
        "lqr_q_zero_continuous": (
            lambda: LQR.from_plant(CartPole(), [0, 1, 1, 1], [1], discrete=False),
            "NotStabilizable",
            "mostly state 'x'",
        ),
        # item 9: finite or an error saying what overflowed
        "linearize_huge_state": (lambda: CartPole().linearize(huge, [0.0]), "NonFiniteError", "overflows"),
        "linearize_huge_eps": (
            lambda: CartPole().linearize(None, None, method="fd", eps=1e300),
            "NonFiniteError",
            "eps = 1e+300",
        ),
        "fd_eps_below_resolution": (
            lambda: CartPole().linearize([1e12, 0, 0, 0], [0], method="fd"),
            "InvalidArgument",
            "below float64's resolution",
        ),
        "zoh_huge_dt": (lambda: CartPole(dt=1e6).get_model(discretization="zoh"), "NonFiniteError", "dt = 1e+06"),
        "rk4_huge_dt": (lambda: CartPole(dt=1e80).get_model(discretization="rk4"), "NonFiniteError", "rk4"),
        "dynamics_overflow": (
            lambda: CartPole().dynamics([0, 0, 1e308, 1e308], [1e308]),
            "NonFiniteError",
            "overflows float64",
        ),
        "mpc_huge_state": (
            lambda: LinearMPC.from_plant(CartPole(), [1, 1, 1, 1], [1], horizon=10, u_min=[-1], u_max=[1])(
                np.array([0, 0, 1e14, 0])
            ),
            "NonFiniteError",
            "numeric range",
        ),
        # item 10: complex numbers are an error, not truncated with a warning
        "lqr_complex_Q": (
            lambda: LQR.from_plant(CartPole(), np.diag([1 + 1j, 1, 1, 1]), [1]),
            "InvalidArgument",
            "real",
        ),
        "lqr_complex_R": (
            lambda: LQR.from_plant(CartPole(), [1, 1, 1, 1], np.array([[1 + 0j]])),
            "InvalidArgument",
            "real",
        ),
        "complex_x0": (lambda: CartPole().linearize(np.array([0, 0, 1j, 0]), [0]), "InvalidArgument", "real"),
        # item 11: an engine built for another plant is refused, naming the parameter
        "engine_other_dt": (
            lambda: CartPole(dt=0.02).physics_engine(MujocoEngine.for_plant(CartPole(dt=0.01))),
            "InvalidArgument",
            "dt",
        ),
        "engine_other_mass": (
            lambda: CartPole(pole_mass=0.3).physics_engine(MujocoEngine.for_plant(CartPole())),
            "InvalidArgument",
            "mass of body 'pole'",
        ),
        "engine_other_damping": (
            lambda: CartPole(damping=0.5).physics_engine(MujocoEngine.for_plant(CartPole())),
            "InvalidArgument",
            "damping",
        ),
        "engine_other_type": (
            lambda: InvertedPendulum().physics_engine(MujocoEngine.for_plant(CartPole())),
            "InvalidArgument",
            "CartPole, not InvertedPendulum",
        ),
        # item 14: the project's errors, never numpy/AttributeError/TypeError
        "batch_shapes": (
            lambda: CartPole().dynamics(np.zeros((5, 4)), np.zeros((3, 1))),
            "InvalidArgument",
            "batch shapes",
        ),
        "param_string": (lambda: CartPole(pole_mass="0.1"), "InvalidArgument", "pole_mass"),
        "param_bool": (lambda: CartPole(dt=True), "InvalidArgument", "dt"),
        "for_plant_name": (lambda: MujocoEngine.for_plant("cartpole"), "InvalidArgument", "plant instance"),
        "from_config_none": (lambda: RobotSim.from_config(None), "InvalidArgument", "NoneType"),
        "ikqp_non_arm": (lambda: IKQP(CartPole()), "InvalidArgument", "arm plant"),
        "metrics_overflow": (
            lambda: compute_metrics(
                np.arange(3) * 0.1,
                np.array([[1e308], [-1e308], [1e308]]),
                np.zeros((2, 1)),
                np.array([[-1e308], [1e308], [-1e308]]),
                tracked=[0],
            ),
            "NonFiniteError",
            "metrics overflow",
        ),
        "batch_rollout_shapes": (
            lambda: lqr_batch_rollout(
                CartPole(),
                LQR.from_plant(CartPole(), [1, 1, 1, 1], [1]),
                params={"pole_mass": np.full(5, 0.1)},
                x0=np.zeros((3, 4)),
                ref=np.zeros(4),
                steps=3,
                tracked=[0],
            ),
            "InvalidArgument",
            "for 5 instances",
        ),
    }


@pytest.mark.parametrize("case", sorted(_api_cases()))
def test_api_raises_the_projects_error(case):
    import warnings

    fn, kind, needle = _api_cases()[case]
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a warning (ComplexWarning, overflow) is not an answer either
        with pytest.raises(ShinroError) as info:
            fn()
    assert type(info.value).__name__ == kind and needle in str(info.value), (type(info.value), str(info.value))


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


@pytest.mark.parametrize(
    "name,content", [("notes.txt", "my notes"), ("photo.jpg", "\xff\xd8\xff jpeg"), ("x.png", "text")]
)
def test_plot_never_overwrites_a_file_that_is_not_a_png(name, content, tmp_path, capsys, monkeypatch):
    # item 2 with other inputs: whatever the name, only an earlier PNG is replaced
    monkeypatch.chdir(tmp_path)
    target = tmp_path / name
    target.write_text(content)
    for args in (["run", "--plot", name, "--duration", "0.1"], ["crosscheck", "pendulum", "--plot", name]):
        assert main(args) == 2
        out, err = capsys.readouterr()
        assert "not a PNG file" in err and "running" not in out
    assert target.read_text() == content


def test_update_refuses_a_baseline_that_is_a_folder_before_writing_any(tmp_path, capsys):
    _copy_regression(tmp_path)
    before = {p.name: p.read_text() for p in tmp_path.glob("*.baseline.json")}
    (tmp_path / "double_pendulum_lqr.baseline.json").unlink()
    (tmp_path / "double_pendulum_lqr.baseline.json").mkdir()
    assert main(["regress", str(tmp_path), "--update"]) == 2
    assert "directory" in capsys.readouterr().err
    assert (tmp_path / "cartpole_lqr.baseline.json").read_text() == before["cartpole_lqr.baseline.json"]
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # no journal, no temporaries


@pytest.mark.parametrize(
    "changes,where",
    [
        ({"engine": {"type": "mujoco", "model": "0"}}, "[engine] model"),
        ({"engine": {"type": "mujoco", "model": "no_such_dir/robot.xml"}}, "[engine] model"),
        ({"plant": {"type": "MjcfPlant", "model": "no_such_robot.xml"}}, "[plant] MjcfPlant"),
        ({"plant": {"type": "no_such_robot.urdf"}}, "[plant] MjcfPlant"),
        (
            {
                "controller": {"type": "TVLQR", "Q": [1, 1, 1, 1], "R": [1]},
                "plan": {"file": "no_such_plan.npz"},
            },
            "plan file not found",
        ),
        (
            {"controller": {"type": "TVLQR", "Q": [1, 1, 1, 1], "R": [1]}, "plan": {"file": "."}},
            "is a directory",
        ),
    ],
    ids=["engine_model", "engine_model_dir", "plant_model", "plant_model_shorthand", "plan_file", "plan_dir"],
)
def test_a_missing_file_a_scenario_names_is_a_config_error_naming_the_key(changes, where, tmp_path, monkeypatch):
    """Through the Python API too (not only the CLI, which treats OSError as a user error): the project's error."""
    from shinro_ctrl.sim import RobotSim

    monkeypatch.chdir(tmp_path)
    doc = {**_doc({}), **changes}
    with pytest.raises(ConfigError, match=re.escape(where)):
        RobotSim.from_config(doc)


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
