"""The shinro-ctrl command, run as a user runs it (subprocess)."""

from __future__ import annotations

import subprocess
import sys

import pytest


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
