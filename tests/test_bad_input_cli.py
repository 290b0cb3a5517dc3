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


# ------------------------------------------------- issue 23 (cli red-team): folders, empty paths, formats, ranges
FOLDER_COMMANDS = {
    "run": lambda f: ["run", f],
    "design_lqr": lambda f: ["design", "lqr", f],
    "design_mpc": lambda f: ["design", "mpc", f],
    "plan": lambda f: ["plan", f],
    "sweep": lambda f: ["sweep", f, "--param", "plant.pole_mass=0.05:0.2", "--samples", "2", "--out", "sw"],
    "linearize": lambda f: ["linearize", f],
    "crosscheck": lambda f: ["crosscheck", f],
}


@pytest.mark.parametrize("folder", [".", "..", "sub", "sub/", "ABS"])
@pytest.mark.parametrize("command", sorted(FOLDER_COMMANDS))
def test_a_folder_as_the_scenario_or_model_is_one_line(command, folder, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "sub").mkdir()
    folder = str(tmp_path / "sub") if folder == "ABS" else folder
    check_one_line_exit_2(FOLDER_COMMANDS[command](folder), f"'{folder}' is a folder, not a", capsys)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["sub"]  # nothing written (no sw/ either)


def test_resources_refuse_folders_and_empty_names_as_files(tmp_path, monkeypatch):
    from shinro_ctrl.resources import asset_path, config_path, shipped_asset, shipped_config

    monkeypatch.chdir(tmp_path)
    (tmp_path / "m.xml").mkdir()
    for find, name in ((config_path, "."), (config_path, tmp_path), (asset_path, "m.xml"), (asset_path, "..")):
        with pytest.raises(IsADirectoryError, match="is a folder, not a"):
            find(name)
    with pytest.raises(IsADirectoryError, match="'regression' is a folder of shipped configs"):
        shipped_config("regression")
    for find in (config_path, asset_path, shipped_config, shipped_asset):
        with pytest.raises(FileNotFoundError, match="name is empty"):
            find("")
    assert config_path("regression/cartpole_lqr").name == "cartpole_lqr.toml"  # a shipped file below a folder


# (argv before the path, the option, argv after it): every path option of every command
EMPTY_PATH_CASES = {
    "run_out": (["run", "cartpole_lqr", "--out"], "--out", []),
    "run_plot": (["run", "cartpole_lqr", "--plot"], "--plot", []),
    "run_video": (["run", "cartpole_lqr", "--video"], "--video", []),
    "run_plan": (["run", "cartpole_swingup_mujoco", "--plan"], "--plan", []),
    "plan_out": (["plan", "cartpole_swingup_mujoco", "--out"], "--out", []),
    "plan_plot": (["plan", "cartpole_swingup_mujoco", "--plot"], "--plot", []),
    "linearize_plot": (["linearize", "cartpole", "--eps-sweep", "--plot"], "--plot", []),
    "crosscheck_plot": (["crosscheck", "cartpole", "--plot"], "--plot", []),
    "design_report": (["design", "lqr", "cartpole_lqr", "--report"], "--report", []),
    "design_out": (["design", "lqr", "cartpole_lqr", "--tradeoff", "R=0.1:1", "--out"], "--out", []),
    "sweep_out": (["sweep", "cartpole_lqr", "--param", "plant.pole_mass=0.05:0.2", "--out"], "--out", []),
    "regress_dir": (["regress"], "DIR", []),
}


@pytest.mark.parametrize("empty", ["", "  "])
@pytest.mark.parametrize("case", sorted(EMPTY_PATH_CASES))
def test_an_empty_path_is_refused_naming_its_option(case, empty, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    before, option, after = EMPTY_PATH_CASES[case]
    check_one_line_exit_2([*before, empty, *after], f"argument {option}: empty path", capsys)
    assert not list(tmp_path.iterdir())  # nothing written, not even out/ or '.'


def test_every_path_option_refuses_an_empty_path():
    """Structural: each path argument of each command goes through the one type that refuses an empty path."""
    import argparse

    from shinro_ctrl.cli import build_parser
    from shinro_ctrl.cli.common import path_arg

    parser = build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    seen = set()
    for name, p in sub.choices.items():
        for action in p._actions:
            if action.dest in ("out", "plot", "video", "report", "plan", "dir"):
                assert action.type is path_arg, f"{name} {action.option_strings or action.dest}"
                seen.add((name, action.dest))
    assert {("run", "out"), ("run", "plot"), ("run", "video"), ("run", "plan"), ("plan", "plot")} <= seen
    assert {("design", "report"), ("design", "out"), ("sweep", "out"), ("regress", "dir")} <= seen
    assert {("linearize", "plot"), ("crosscheck", "plot")} <= seen


PLOT_COMMANDS = {
    "run": ["run", "cartpole_lqr", "--duration", "0.1", "--plot"],
    "run_both": ["run", "cartpole_lqr", "--engine", "both", "--duration", "0.1", "--plot"],
    "plan": ["plan", "cartpole_swingup_mujoco", "--out", "o", "--plot"],
    "linearize": ["linearize", "cartpole", "--eps-sweep", "--plot"],
    "crosscheck": ["crosscheck", "cartpole", "--plot"],
}


@pytest.mark.parametrize("name", ["r.csv", "r.jpg", "r.txt", "r", "r.png.bak"])
@pytest.mark.parametrize("command", sorted(PLOT_COMMANDS))
def test_a_plot_name_we_do_not_write_is_refused(command, name, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    check_one_line_exit_2(
        [*PLOT_COMMANDS[command], name], f"--plot '{name}': a plot is written as .png, .pdf, .svg", capsys
    )
    assert not list(tmp_path.iterdir())


def test_a_plot_inside_out_with_a_wrong_extension_is_refused(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    check_one_line_exit_2(["run", "cartpole_lqr", "--out", "o", "--plot", "o/r.csv"], "--plot 'o/r.csv'", capsys)
    assert not list(tmp_path.iterdir())


def _is_format(path, fmt: str) -> bool:
    data = path.read_bytes()
    if fmt == "png":
        return data.startswith(b"\x89PNG\r\n\x1a\n")
    if fmt == "pdf":
        return data.startswith(b"%PDF-") and data.rstrip().endswith(b"%%EOF")
    import xml.etree.ElementTree as ET

    return data.startswith(b"<?xml") and ET.fromstring(data).tag == "{http://www.w3.org/2000/svg}svg"


@pytest.mark.parametrize("fmt", ["png", "pdf", "svg", "SVG"])
def test_each_plot_format_is_written_as_named_and_replaced_on_a_second_run(fmt, tmp_path, capsys):
    from shinro_ctrl.files import written_by_us

    plot = tmp_path / f"c.{fmt}"
    assert main(["crosscheck", "cartpole", "--plot", str(plot)]) == 0
    assert _is_format(plot, fmt.lower()) and written_by_us(plot)
    first = plot.stat().st_ino
    assert main(["crosscheck", "pendulum", "--plot", str(plot)]) == 0  # our own file: replaced (atomically)
    assert _is_format(plot, fmt.lower()) and written_by_us(plot) and plot.stat().st_ino != first
    capsys.readouterr()


@pytest.mark.parametrize("fmt", ["png", "pdf", "svg"])
def test_a_users_plot_file_of_each_format_is_never_replaced(fmt, tmp_path, capsys):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure()
    FigureCanvasAgg(fig)
    fig.add_subplot().plot([0, 1], [1, 0])
    plot = tmp_path / f"mine.{fmt}"
    fig.savefig(plot, format=fmt)  # matplotlib's own metadata: the user's file, not ours
    before = plot.read_bytes()
    check_one_line_exit_2(["crosscheck", "cartpole", "--plot", str(plot)], "refusing to overwrite it", capsys)
    check_one_line_exit_2(["run", "cartpole_lqr", "--duration", "0.1", "--plot", str(plot)], "--plot", capsys)
    assert plot.read_bytes() == before


def test_the_svg_marker_is_matched_in_the_metadata_only(tmp_path):
    from shinro_ctrl.files import written_by_us

    svg = '<?xml version="1.0"?>\n<svg xmlns="http://www.w3.org/2000/svg"><text>{}</text></svg>\n'
    for i, body in enumerate(("shinro-ctrl", "<dc:title>shinro-ctrl</dc:title>", "")):
        p = tmp_path / f"{i}.svg"
        p.write_text(svg.format(body))
        assert not written_by_us(p), body


@pytest.mark.parametrize("eps", ["1e-300", "1e-13", "0.5", "1", "inf", "nan", "0"])
@pytest.mark.parametrize("command", ["linearize", "crosscheck"])
def test_eps_outside_a_sane_range_is_refused(command, eps, capsys):
    check_one_line_exit_2([command, "cartpole", f"--eps={eps}"], "--eps must be a finite step in [1e-12, 0.1]", capsys)


@pytest.mark.parametrize("eps", ["1e-12", "0.1"])
def test_eps_at_the_ends_of_the_range_is_accepted(eps, capsys):
    assert main(["linearize", "cartpole", f"--eps={eps}"]) == 0
    assert f"eps={float(eps):g}" in capsys.readouterr().out


@pytest.mark.parametrize(
    ("args", "needles"),
    [
        (["crosscheck", "cartpole", "--u0=1e308"], ("state x = [0.0, 0.0, 0.0, 0.0]", "input u = [1e+308]")),
        (["crosscheck", "pendulum", "--u0=1e308"], ("state x = ", "input u = [1e+308]")),
        (["linearize", "cartpole", "--u0=1e308"], ("state x0 = ", "input u0 = [1e+308]")),
        (["linearize", "cartpole", "--x0=0,0,1e308,1e308"], ("state x0 = [0.0, 0.0, 1e+308, 1e+308]", "input u0")),
    ],
)
def test_an_overflow_names_the_state_and_the_input(args, needles, capsys):
    assert main(args) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and all(n in err for n in needles), err


def test_dynamics_overflow_names_state_and_input():
    from shinro_ctrl.errors import NonFiniteError
    from shinro_ctrl.plants import CartPole, DoublePendulum

    for plant, x, u in ((CartPole(), [0, 0, 0, 0], [1e308]), (DoublePendulum(), [0, 0, 1e200, 1e200], [0, 0])):
        with pytest.raises(NonFiniteError, match=r"overflows float64 at state x = \[.*\], input u = \["):
            plant.dynamics(x, u)


@pytest.mark.parametrize(
    ("duration", "needle"),
    [
        ("1e308", "--duration = 1e+308 s is too long"),
        ("1.7e308", "--duration = 1.7e+308 s is too long"),
        ("1e300", "limited to 10,000,000 steps"),
        ("1e6", "limited to 10,000,000 steps"),
    ],
)
@pytest.mark.parametrize("engine", ["standalone", "both"])
def test_a_huge_duration_names_duration(duration, needle, engine, capsys):
    check_one_line_exit_2(["run", "cartpole_lqr", "--engine", engine, f"--duration={duration}"], needle, capsys)
    assert not capsys.readouterr().out  # refused before anything is printed


def test_a_huge_scenario_duration_names_the_key(tmp_path, capsys):
    path = tmp_path / "long.toml"
    path.write_text(GOOD + "[sim]\nduration = 1e308\n")
    for argv in (["run", str(path)], ["design", "lqr", str(path)]):
        check_one_line_exit_2(argv, "'duration' = 1e+308 s is too long", capsys)


def test_whole_steps_refuses_non_finite_step_counts():
    from shinro_ctrl.config import whole_steps
    from shinro_ctrl.errors import ConfigError

    assert whole_steps(1.0, 0.01, "d") == 100
    for duration, dt in ((1e308, 0.01), (1e300, 1e-300), (float("inf"), 0.01), (float("nan"), 0.01)):
        with pytest.raises(ConfigError, match=r"^d "):
            whole_steps(duration, dt, "d")


@pytest.mark.parametrize(
    "address",
    [
        "",
        " ",
        "tcp://",
        "tcp://host",
        "host",
        "host:99999",
        "host:0",
        "http://host:8786",
        "a b:1",
        "tcp://[::1",
        "tcp://host:8786/path",
        "tcp://:8786",
    ],
)
def test_a_bad_scheduler_address_is_refused_up_front(address, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    argv = ["sweep", "cartpole_lqr", "--out", "sw", "--samples", "2", "--param", "plant.pole_mass=0.05:0.5"]
    check_one_line_exit_2([*argv, "--scheduler", address], "--scheduler must look like tcp://HOST:PORT", capsys)
    assert not list(tmp_path.iterdir())


def test_the_out_folder_refusal_names_out_and_the_plot_inside_it(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "d").mkdir()
    (tmp_path / "d" / "mine.png").write_bytes(b"\x89PNG\r\n\x1a\nthe user's own")
    argv = ["run", "cartpole_lqr", "--duration", "0.5", "--out", "d"]
    check_one_line_exit_2([*argv, "--plot", "d/mine.png"], "--out folder 'd' holds files", capsys)
    check_one_line_exit_2([*argv, "--plot", "d/mine.png"], "--plot 'd/mine.png' is inside it", capsys)
    check_one_line_exit_2(argv, "--out folder 'd'", capsys)
    sweep = ["sweep", "cartpole_lqr", "--out", "d", "--samples", "2", "--param", "plant.pole_mass=0.05:0.5"]
    check_one_line_exit_2(sweep, "--out folder 'd'", capsys)
    tradeoff = ["design", "lqr", "cartpole_lqr", "--tradeoff", "R=0.1:1", "--points", "2", "--out", "d"]
    check_one_line_exit_2(tradeoff, "--out folder 'd'", capsys)
    assert (tmp_path / "d" / "mine.png").read_bytes().endswith(b"the user's own")
