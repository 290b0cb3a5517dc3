"""The shinro-ctrl command, run as a user runs it (subprocess)."""

from __future__ import annotations

import subprocess
import sys

import pytest

from shinro_ctrl.cli import main


def run_cli(*args: str, timeout: float = 120) -> subprocess.CompletedProcess:
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
    res = subprocess.run(
        [sys.executable, "-m", "shinro_ctrl.cli", "run"], capture_output=True, text=True, timeout=120, cwd=tmp_path
    )
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
    res = subprocess.run(
        [sys.executable, "-m", "shinro_ctrl.cli", "run", "--duration", "0.2", "--plot", "p.png"],
        capture_output=True,
        text=True,
        timeout=120,
        cwd=tmp_path,
    )
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
