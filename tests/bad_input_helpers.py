"""What the bad-input tests share: a good scenario to spoil, the one-line check, the real command."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

from shinro_ctrl.cli import main
from shinro_ctrl.resources import regression_dir

GOOD = '[plant]\ntype = "CartPole"\n\n[controller]\ntype = "LQR"\nQ = [10, 1, 100, 1]\nR = [0.1]\n'


def check_one_line_exit_2(argv: list[str], needle: str, capsys) -> None:
    assert main(argv) == 2, argv
    err = capsys.readouterr().err
    assert needle in err, f"{argv}: {err!r}"
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and "Traceback" not in err, err


def cli_subprocess(*args: str, timeout: float = 120, **kw) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "shinro_ctrl.cli", *args], capture_output=True, text=True, timeout=timeout, **kw
    )


def _doc(changes: dict) -> dict:
    doc = {"plant": {"type": "CartPole"}, "controller": {"type": "LQR", "Q": [10, 1, 100, 1], "R": [0.1]}}
    for table, body in changes.items():
        doc.setdefault(table, {}).update(body)
    return doc


def _copy_regression(tmp_path, names=("cartpole_lqr", "double_pendulum_lqr")) -> dict[str, str]:
    for name in names:
        shutil.copy(regression_dir() / f"{name}.toml", tmp_path)
        shutil.copy(regression_dir() / f"{name}.baseline.json", tmp_path)
    return {p.name: p.read_text() for p in tmp_path.glob("*.baseline.json")}


def child_processes() -> dict[int, list[int]]:
    """Parent pid -> its children's pids, read from ``/proc`` (the pool and forkserver tests find workers by it)."""
    children: dict[int, list[int]] = {}
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        children.setdefault(int(fields[1]), []).append(int(stat.parent.name))
    return children
