"""Every bad input through every subcommand: one line on stderr, exit status 2, no traceback.

The table is run in-process through ``cli.main`` (the function the console
script calls) to keep it fast; a few cases go through the real command in a
subprocess to prove the wiring.
"""

from __future__ import annotations

import subprocess
import sys

import pytest

from shinro_ctrl.cli import main

from .bad_input_helpers import GOOD, check_one_line_exit_2

# name: (scenario text, a fragment the one-line error must contain)
BAD_SCENARIOS: dict[str, tuple[str, str]] = {
    "malformed_toml": ("[plant\ntype = 1\n", "malformed TOML"),
    "empty_file": ("", "empty scenario"),
    "unknown_table": (GOOD + "[simulation]\nduration = 1\n", "unknown table 'simulation'"),
    "typo_key": (GOOD.replace('"CartPole"', '"CartPole"\npole_lenght = 0.5'), "did you mean 'pole_length'"),
    "wrong_type": (GOOD + "[sim]\nduration = 'long'\n", "'duration' must be a number"),
    "negative_mass": (GOOD.replace('"CartPole"', '"CartPole"\ncart_mass = -1.0'), "cart_mass"),
    "unknown_plant": (GOOD.replace("CartPole", "CartPol"), "unknown plant type 'CartPol'"),
    "unknown_controller": (GOOD.replace('"LQR"', '"PID"'), "unknown controller type 'PID'"),
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


def test_numeric_overflow_inside_the_command_is_one_line(monkeypatch, capsys):
    import shinro_ctrl.cli.models as models  # the module of the list command (its parser and handler)

    def overflow(args):
        raise OverflowError("(34, 'Numerical result out of range')")

    monkeypatch.setattr(models, "cmd_list", overflow)
    check_one_line_exit_2(["list"], "numeric overflow", capsys)


def test_warnings_are_not_printed_before_the_error_line(tmp_path, capsys):
    # item 15: a huge dt warns while the model is built, then the design fails: the error line stands alone
    path = tmp_path / "huge_dt.toml"
    path.write_text(GOOD.replace('"CartPole"', '"CartPole"\ndt = 1e6').replace("[10, 1, 100, 1]", "[1e300, 1, 1, 1]"))
    assert main(["design", "lqr", str(path)]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and err.startswith("error: "), err
