"""What the bad-input tests share: a good scenario to spoil, the one-line check, the real command."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import textwrap
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


# A command process whose imports are done: each `start` forks a child that runs the real entry point
# (shinro_ctrl._entry.main, as `python -m shinro_ctrl.cli` does) and exits through Python's normal shutdown.
_FORKER = textwrap.dedent(
    """
    import importlib, json, os, sys
    from shinro_ctrl._entry import main
    for name in sys.argv[1:]:  # what the commands import (the command line imports lazily), once here
        importlib.import_module(name)
    print(json.dumps({"ready": os.getpid()}), flush=True)

    for line in sys.stdin:
        request = json.loads(line)
        if "argv" in request:
            pid = os.fork()
            if pid == 0:
                null = os.open(os.devnull, os.O_RDWR)
                for fd in (0, 1, 2):
                    os.dup2(null, fd)
                sys.argv = ["shinro-ctrl", *request["argv"]]
                main(request["argv"])  # sys.exit: the child ends here, never back in this loop
            reply = {"pid": pid}
        else:
            reply = {"status": os.waitstatus_to_exitcode(os.waitpid(request["wait"], 0)[1])}
        print(json.dumps(reply), flush=True)
    """
)


class CommandForker:
    """Runs ``shinro-ctrl ARGS`` as processes forked from one that has already imported the command line.

    For the tests that SIGKILL a command at random moments to see what it leaves on disk: a fresh interpreter
    spends most of a short command importing NumPy, CasADi, MuJoCo and Matplotlib, where a kill touches no file;
    a forked child starts at the command itself, so every kill lands in the work and the writes, and costs a
    fraction of a fresh process. The children are real processes of the real entry point (their own pid, their
    own signal delivery); use it as a context manager.
    """

    #: Imported before the first fork: the modules `run` and `regress` load (shinro_ctrl.cli imports lazily).
    PRELOAD = (
        *(f"shinro_ctrl.cli.{m}" for m in ("common", "design", "models", "run", "sets")),
        *(f"shinro_ctrl.{m}" for m in ("config", "controllers", "estimators", "files", "plants", "plots")),
        *(f"shinro_ctrl.{m}" for m in ("regression", "sim")),
        "matplotlib.figure",
        "matplotlib.backends.backend_agg",
        "PIL.PngImagePlugin",
    )

    def __init__(self) -> None:
        self._proc = subprocess.Popen(
            [sys.executable, "-c", _FORKER, *self.PRELOAD],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            text=True,
            env={**os.environ, "MPLBACKEND": "Agg"},
        )
        line = self._proc.stdout.readline()  # the imports are done: the commands' times start at their fork
        assert line, f"the forking process did not start (status {self._proc.wait()})"

    def _ask(self, request: dict) -> dict:
        self._proc.stdin.write(json.dumps(request) + "\n")
        self._proc.stdin.flush()
        line = self._proc.stdout.readline()
        assert line, f"the forking process ended (status {self._proc.wait()})"
        return json.loads(line)

    def start(self, *args: str) -> int:
        """Fork a child running ``shinro-ctrl ARGS`` (in this process's working directory); its pid."""
        return self._ask({"argv": list(args)})["pid"]

    def wait(self, pid: int) -> int:
        """Wait for the child ``pid`` to end; its exit code (negative: the signal that ended it)."""
        return self._ask({"wait": pid})["status"]

    def __enter__(self) -> CommandForker:
        return self

    def __exit__(self, *exc: object) -> None:
        self._proc.stdin.close()
        try:
            self._proc.wait(timeout=60)
        finally:
            self._proc.kill()
            self._proc.stdout.close()


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
