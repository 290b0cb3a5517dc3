"""The shinro-ctrl command, run as a user runs it.

Most tests run the command in this process (``cli_runner.cli``: same status, stdout and stderr, without a second
of interpreter start-up each); the ones about the process itself (the ``python -m`` entry point's exit status, a
closed pipe, a child's environment for the video) start a real subprocess.
"""

from __future__ import annotations

import subprocess
import sys

import pytest

from shinro_ctrl.cli import main
from tests.cli_runner import cli as run_cli


def cli_subprocess(*args: str, timeout: float = 120) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "shinro_ctrl.cli", *args], capture_output=True, text=True, timeout=timeout
    )


@pytest.mark.parametrize("plant", ["pendulum", "cartpole", "double_pendulum"])
def test_linearize_prints_exact_and_fd(plant):
    res = run_cli("linearize", plant)
    assert res.returncode == 0, res.stderr
    assert "A exact (CasADi)" in res.stdout and "finite diff" in res.stdout
    err = float(res.stdout.split("max |exact - fd| = ")[1].split()[0])
    assert err < 1e-5


def test_linearize_at_operating_point_with_pi():
    res = run_cli("linearize", "double_pendulum", "--x0", "pi,pi,0,0")
    assert res.returncode == 0, res.stderr
    assert "39.24" in res.stdout  # (m1+m2) g / (m1 l1) at the upright equilibrium


@pytest.mark.parametrize(
    "args,needle",
    [
        (["linearize", "cartpol"], "did you mean 'cartpole'"),
        (["linearize", "cartpole", "--x0", "1,2"], "expected shape (4,)"),
        (["linearize", "cartpole", "--x0", "a,b,c,d"], "not a number"),
        (["nonsense"], "invalid choice"),
    ],
)
def test_user_errors_are_one_line_exit_2(args, needle):
    res = run_cli(*args)
    assert res.returncode == 2
    assert needle in res.stderr
    assert len(res.stderr.strip().splitlines()) == 1
    assert "Traceback" not in res.stderr


@pytest.mark.parametrize(
    "args,needle",
    [
        (["linearize", "cartpol"], "did you mean 'cartpole'"),  # our error, through the entry point's exit status
        (["nonsense"], "invalid choice"),  # argparse's
    ],
)
def test_user_errors_exit_the_process_with_2_and_one_line(args, needle):
    res = cli_subprocess(*args)
    assert res.returncode == 2
    assert needle in res.stderr
    assert len(res.stderr.strip().splitlines()) == 1
    assert "Traceback" not in res.stderr


@pytest.mark.parametrize("plant", ["cartpole", "double_pendulum"])
def test_crosscheck_prints_three_linearizations(plant):
    res = run_cli("crosscheck", plant)
    assert res.returncode == 0, res.stderr
    assert "exact (CasADi)" in res.stdout and "MuJoCo" in res.stdout and "finite differences" in res.stdout


def test_linearize_eps_sweep_and_crosscheck_plots(tmp_path):
    res = run_cli("linearize", "cartpole", "--x0", "0.1,0.2,0.3,0.4", "--eps-sweep", "--plot", str(tmp_path / "e.png"))
    assert res.returncode == 0, res.stderr
    assert "best eps" in res.stdout and (tmp_path / "e.png").read_bytes()[:4] == b"\x89PNG"
    res = run_cli("crosscheck", "double_pendulum", "--x0", "pi,pi,0,0", "--plot", str(tmp_path / "c.png"))
    assert res.returncode == 0, res.stderr
    assert (tmp_path / "c.png").read_bytes()[:4] == b"\x89PNG"


def test_run_with_engine_override(tmp_path):
    res = run_cli("run", "cartpole_lqr", "--engine", "mujoco", "--duration", "0.5", "--plot", str(tmp_path / "p.png"))
    assert res.returncode == 0, res.stderr
    assert "(mujoco)" in res.stdout


def test_run_without_config_runs_the_embedded_demo(tmp_path):
    res = run_cli("run", cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    assert "cartpole_lqr (standalone)" in res.stdout and "rms_error" in res.stdout
    plot = res.stdout.split("plot: ")[1].strip()
    assert (tmp_path / plot).read_bytes()[:4] == b"\x89PNG"


def test_run_with_config_plot_and_out(tmp_path):
    png = tmp_path / "p.png"
    res = run_cli("run", "pendulum_lqr", "--duration", "1", "--plot", str(png), "--out", str(tmp_path / "o"))
    assert res.returncode == 0, res.stderr
    assert png.read_bytes()[:4] == b"\x89PNG" and png.stat().st_size > 10_000
    assert {p.name for p in (tmp_path / "o").iterdir()} >= {"result.npz", "metrics.json", "scenario.toml"}


def test_design_lqr_prints_gain_poles_and_cost():
    res = run_cli("design", "lqr", "cartpole_lqr")
    assert res.returncode == 0, res.stderr
    assert "K =" in res.stdout and "closed-loop poles" in res.stdout and "predicted cost" in res.stdout


def test_list_shows_plants_controllers_scenarios():
    res = run_cli("list")
    assert res.returncode == 0, res.stderr
    for word in ("CartPole", "LQR", "LinearMPC", "cartpole_lqr.toml"):
        assert word in res.stdout


def test_missing_config_file_exits_2():
    res = run_cli("run", "no_such_scenario.toml")
    assert res.returncode == 2 and "no config named" in res.stderr and "cartpole_lqr.toml" in res.stderr


def test_default_scenario_ignores_a_same_named_file_in_cwd(tmp_path):
    (tmp_path / "cartpole_lqr.toml").write_text(
        '[plant]\ntype = "InvertedPendulum"\n[controller]\ntype = "LQR"\nQ=[1,1]\nR=[1]\n'
    )
    res = run_cli("run", "--duration", "0.2", "--plot", "p.png", cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    assert "CartPole + LQR" in res.stdout


def test_pi_over_zero_and_debug_after_the_subcommand(capsys):
    assert main(["linearize", "pendulum", "--x0", "pi/0,0"]) == 2
    assert "division by zero" in capsys.readouterr().err
    with pytest.raises(Exception, match="did you mean"):
        main(["linearize", "cartpol", "--debug"])  # --debug anywhere: the real exception propagates


def test_eps_sweep_at_the_default_point_moves_off_the_equilibrium(capsys):
    assert main(["linearize", "cartpole", "--eps-sweep"]) == 0
    out = capsys.readouterr().out
    best = float(out.split("best eps = ")[1].split(";")[0])
    assert "off the equilibrium" in out and 1e-8 < best < 1e-3


# ------------------------------------------------------------ papercuts (issue 14, items 16-24)
@pytest.mark.parametrize(
    "args,expected",
    [
        (["linearize", "pendulum", "--x0", "-0.1,0"], "'theta': -0.1"),
        (["linearize", "pendulum", "--x0", "-pi,0", "--u0", "-0.5"], "'tau': -0.5"),
        (["linearize", "cartpole", "--x0", "-1e-3,0,-0.2,0"], "'theta': -0.2"),
        (["crosscheck", "cartpole", "--x0", "-0.1,0,0,0"], "x0 = [-0.1, 0, 0, 0]"),
    ],
)
def test_negative_vectors_work_as_written(args, expected, capsys):
    # item 16: argparse took '-0.1,0' for an option
    assert main(args) == 0
    assert expected in capsys.readouterr().out


def test_design_lqr_continuous_is_labelled_continuous(tmp_path, capsys):
    # item 17: a continuous design printed "euler discretization ... dt = 0.01 s"
    path = tmp_path / "c.toml"
    path.write_text(
        '[plant]\ntype = "CartPole"\n[controller]\ntype = "LQR"\nQ = [10, 1, 100, 1]\nR = [0.1]\ndiscrete = false\n'
    )
    assert main(["design", "lqr", str(path)]) == 0
    out = capsys.readouterr().out
    assert "continuous-time" in out and "euler" not in out and "|p|" not in out and "Re p = -" in out


def test_crosscheck_accepts_a_scenario_and_lists_only_supported_plants(tmp_path, capsys):
    # item 18: the scenario's plant parameters are the ones checked; unsupported plants are not offered
    path = tmp_path / "heavy.toml"
    path.write_text(
        '[plant]\ntype = "CartPole"\npole_mass = 0.7\npole_length = 0.9\n'
        '[controller]\ntype = "LQR"\nQ = [1, 1, 1, 1]\nR = [1]\n'
    )
    assert main(["crosscheck", str(path)]) == 0
    out = capsys.readouterr().out
    assert "pole_mass=0.7" in out and "pole_length=0.9" in out
    for plant in ("holonomic", "arm6"):
        assert main(["crosscheck", plant]) == 2
        err = capsys.readouterr().err
        assert "crosscheck supports" in err and len(err.strip().splitlines()) == 1
    res = run_cli("crosscheck", "--help")
    assert "holonomic" not in res.stdout and "arm6" not in res.stdout and "scenario file" in res.stdout


def test_sweep_says_which_executor_ran_and_why(tmp_path, capsys):
    # item 19: --workers 2 on a standalone scenario ran the batch path on one worker silently
    out = tmp_path / "sw"
    args = ["sweep", "cartpole_lqr", "--param", "plant.pole_mass=0.05:0.5", "--samples", "4", "--workers", "2"]
    assert main([*args, "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "batch, 1 worker" in text and "--workers 2" in text and "--method pool" in text
    assert sorted(p.name for p in out.iterdir()) == [".shinro-run.json", "sweep.csv", "sweep.json", "sweep.png"]


@pytest.mark.parametrize(
    "args,needle",
    [
        (["linearize", "pendulum", "--plot", "x.png"], "--plot goes with --eps-sweep"),
        (["run", "--duration", "-1"], "--duration"),
        (["run", "--duration", "0"], "--duration"),
        (["run", "--engine", "both", "--video", "v.gif"], "--video renders one loop"),
    ],
)
def test_arguments_are_validated_before_any_work(args, needle, tmp_path, monkeypatch, capsys):
    # item 21: nothing printed ("running ... -1 s") or written before the error
    monkeypatch.chdir(tmp_path)
    assert main(args) == 2
    out, err = capsys.readouterr()
    assert out == "" and needle in err and not list(tmp_path.iterdir())


def test_broken_pipe_exits_quietly():
    # item 22: `shinro-ctrl list | head -1` ended with "error: [Errno 32] Broken pipe"
    proc = subprocess.Popen(
        [sys.executable, "-m", "shinro_ctrl.cli", "list"], stdout=subprocess.PIPE, stderr=subprocess.PIPE
    )
    proc.stdout.read(10)
    proc.stdout.close()  # the reader leaves, like `head`
    err = proc.stderr.read().decode()
    proc.wait(timeout=60)
    assert err == "" and proc.returncode in (0, 141), (proc.returncode, err)


def test_regress_accepts_a_single_scenario_file(tmp_path, capsys):
    # item 23
    import shutil

    from shinro_ctrl.resources import regression_dir

    for name in ("cartpole_lqr.toml", "cartpole_lqr.baseline.json", "double_pendulum_lqr.toml"):
        shutil.copy(regression_dir() / name, tmp_path)
    assert main(["regress", str(tmp_path / "cartpole_lqr.toml")]) == 0
    out = capsys.readouterr().out
    assert "cartpole_lqr (standalone)" in out and "double_pendulum" not in out and "1 scenario runs" in out


def test_makefile_demo_installs_runtime_only_and_test_the_dev_extra():
    # item 24: `make -n` (dry run) shows what each target would install on a fresh clone
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    if not (root / "Makefile").exists():
        pytest.skip("no Makefile in an installed package")
    env = {"PATH": "/usr/bin:/bin", "HOME": "/tmp"}
    demo = subprocess.run(["make", "-n", "-B", "demo"], cwd=root, capture_output=True, text=True, env=env).stdout
    test = subprocess.run(["make", "-n", "-B", "test"], cwd=root, capture_output=True, text=True, env=env).stdout
    assert "pip install --quiet --no-compile -e ." in demo and "[dev]" not in demo and "shinro-ctrl run" in demo
    assert 'pip install --quiet --no-compile -e ".[dev]"' in test and "pytest" in test
    assert "compileall" in demo and "compileall" in test  # pip's byte-compile, done on every core
    assert "make test" in (root / ".ci" / "run").read_text()


# -------------------------------------------------------------------- plots (items 25-28)
def _result(name: str, duration: float | None = None):
    from shinro_ctrl.sim import RobotSim

    return RobotSim.from_config(name).run(duration)


def test_run_plot_has_units_legend_outside_settling_band(tmp_path):
    # item 25
    from shinro_ctrl.plots import run_figure

    fig = run_figure(_result("cartpole_lqr", 3.0))
    labels = [ax.get_ylabel() for ax in fig.axes]
    assert labels == ["x [m]", "x_dot [m/s]", "theta [rad]", "theta_dot [rad/s]", "force [N]"]
    assert any("settling band" in t.get_text() for leg in fig.legends for t in leg.get_texts())
    fig.canvas.draw()
    renderer = fig.canvas.get_renderer()
    legend_box = fig.legends[0].get_window_extent(renderer)
    for ax in fig.axes:  # the legend covers no data axes
        assert not legend_box.overlaps(ax.get_window_extent(renderer))
    assert any(
        c.__class__.__name__ == "FillBetweenPolyCollection" or "Poly" in c.__class__.__name__
        for c in fig.axes[0].collections
    )


def test_quadrotor_plot_is_grouped_into_at_most_six_rows():
    from shinro_ctrl.plots import MAX_ROWS, run_figure

    fig = run_figure(_result("quadrotor_lqr", 0.5))
    labels = [ax.get_ylabel() for ax in fig.axes if ax.get_ylabel()]
    assert len(labels) <= MAX_ROWS
    assert labels == [
        "position [m]",
        "attitude [rad]",
        "velocity [m/s]",
        "angular rate [rad/s]",
        "thrust [N]",
        "inputs [N m]",
    ]


def test_planar_task_gets_an_xy_panel():
    from shinro_ctrl.plots import run_figure

    fig = run_figure(_result("holonomic_mujoco", 4.0))
    xy = [ax for ax in fig.axes if ax.get_title().endswith("path")]
    assert len(xy) == 1 and xy[0].get_xlabel() == "x [m]" and xy[0].get_ylabel() == "y [m]"


def test_run_engine_both_overlays_the_two_loops(tmp_path, capsys):
    # item 26
    out = tmp_path / "both"
    assert main(["run", "pendulum_lqr_mujoco", "--engine", "both", "--duration", "1", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "standalone" in text and "mujoco" in text and "difference" in text
    assert {p.name for p in out.iterdir()} == {".shinro-run.json", "standalone", "mujoco", "run.png"}
    from shinro_ctrl.plots import run_figure

    a, b = _result("pendulum_lqr", 1.0), _result("pendulum_lqr_mujoco", 1.0)
    fig = run_figure(a, compare=b)
    assert "vs" in fig._suptitle.get_text() and "Δ" in fig._suptitle.get_text()
    assert len(fig.axes[0].lines) >= 3  # both loops and the reference


def test_sweep_plot_failed_strip_data_range_and_2d_map(tmp_path):
    # item 27
    from shinro_ctrl.plots import sweep_figure
    from shinro_ctrl.sweep import run_sweep

    one = run_sweep("cartpole_mpc", {"plant.pole_mass": (0.05, 5.0)}, samples=12, duration=0.5, method="serial")
    fig = sweep_figure(one)
    main_ax, strip = fig.axes[0], fig.axes[1]
    failed = sum(r.error is not None for r in one.rows)
    assert len(strip.collections[0].get_offsets()) == failed
    finite = one.metric_values(one.metric)[[r.error is None for r in one.rows]]
    lo, hi = main_ax.get_ylim()
    assert lo <= finite.min() and hi >= finite.max() and hi < 10 * finite.max() + 1
    assert strip.get_xlabel() == "plant.pole_mass [kg]"
    two = run_sweep(
        "cartpole_lqr", {"plant.pole_mass": (0.05, 3.0), "plant.pole_length": (0.1, 2.0)}, samples=4, grid=True
    )
    fig = sweep_figure(two)
    assert fig.axes[0].get_title() == "stability map"
    assert fig.axes[0].get_xlabel() == "plant.pole_mass [kg]" and fig.axes[0].get_ylabel() == "plant.pole_length [m]"


def test_crosscheck_heatmap_diverging_centred_labelled():
    # item 28
    from shinro_ctrl.crosscheck import crosscheck
    from shinro_ctrl.plants import CartPole, Quadrotor
    from shinro_ctrl.plots.linearization import crosscheck_figure

    fig = crosscheck_figure(crosscheck(CartPole()))
    images = [ax.images[0] for ax in fig.axes if ax.images]
    assert len(images) == 3
    for im in images:
        assert im.get_cmap().name.startswith("RdBu") and im.norm.vmin == -im.norm.vmax
    ax = fig.axes[0]
    assert [t.get_text() for t in ax.get_xticklabels()] == ["x", "x_dot", "theta", "theta_dot", "force"]
    assert len(ax.texts) > 0  # 5 columns: numbers readable
    big = crosscheck_figure(crosscheck(Quadrotor()))
    assert all(len(a.texts) == 0 for a in big.axes if a.images)  # 16 columns: no unreadable numbers


def test_video_reports_playback_rate_and_render_time_separately(tmp_path):
    # item 20: "ms/frame" mixed render time with playback; the GIF's own frame duration is the playback rate
    import os
    import re

    from PIL import Image

    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY", "MUJOCO_GL")}
    res = subprocess.run(
        [
            sys.executable,
            "-m",
            "shinro_ctrl.cli",
            "run",
            "pendulum_lqr_mujoco",
            "--duration",
            "0.6",
            "--video",
            "v.gif",
        ],
        capture_output=True,
        text=True,
        timeout=300,
        cwd=tmp_path,
        env=env,
    )
    assert res.returncode == 0, res.stderr
    m = re.search(r"\((\d+) frames at ([\d.]+) frames/s, ([\d.]+) s of playback; rendered in ([\d.]+) s\)", res.stdout)
    assert m and "ms/frame" not in res.stdout, res.stdout
    frames, fps, playback = int(m.group(1)), float(m.group(2)), float(m.group(3))
    with Image.open(tmp_path / "v.gif") as im:
        assert im.n_frames == frames
        assert fps == pytest.approx(1000.0 / im.info["duration"], rel=0.01)
    assert playback == pytest.approx(frames / fps, abs=0.01)
