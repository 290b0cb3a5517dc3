"""Every example runs (as a newcomer runs it) and says what it promises."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

EXAMPLES = Path(__file__).resolve().parent.parent / "examples"

EXPECT = {
    "quickstart.py": "settled",
    "mpc_mujoco.py": "peak |F| = 3.000 N",
    "ik_circle.py": "joint limits respected",
    "quadrotor_hover.py": "MuJoCo     after 5 s",
}


@pytest.mark.parametrize("script", sorted(EXPECT))
def test_example_runs(script):
    res = subprocess.run([sys.executable, str(EXAMPLES / script)], capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr
    assert EXPECT[script] in res.stdout


def test_examples_are_all_listed():
    assert {p.name for p in EXAMPLES.glob("*.py")} == {*EXPECT, "test_my_controller.py"}


def test_user_regression_test_example_passes():
    res = subprocess.run(
        [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", str(EXAMPLES / "test_my_controller.py")],
        capture_output=True,
        text=True,
        timeout=300,
        cwd=EXAMPLES,
    )
    assert res.returncode == 0, res.stdout + res.stderr
    assert "1 passed" in res.stdout
