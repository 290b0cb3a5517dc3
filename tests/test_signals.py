"""Ctrl-C (SIGINT to the whole process group, as a terminal sends it) ends every command with exit 130 and the one
line ``interrupted``: no traceback, no ``error:`` line, never death by the signal (issue 23 §4).

Real ``python -m shinro_ctrl.cli`` subprocesses in their own session; the signal is sent when a marker shows the
moment under test has come (an IPOPT iteration in IPOPT's log, the "running" line, the forkserver or the pool
workers in /proc), never after a timed pause.
"""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import time
import tomllib
from collections.abc import Callable
from pathlib import Path

import pytest

from shinro_ctrl.resources import shipped_config

from .bad_input_helpers import child_processes

ROOT = Path(__file__).resolve().parents[1]

pytestmark = pytest.mark.skipif(not Path("/proc").is_dir(), reason="process groups and /proc (Linux)")


def _start(args: list[str], cwd: Path, *, pythonpath: tuple[Path, ...] = ()) -> subprocess.Popen:
    env = {
        **os.environ,
        "PYTHONPATH": os.pathsep.join(str(p) for p in (*pythonpath, ROOT)),
        "PYTHONUNBUFFERED": "1",
        "MPLBACKEND": "Agg",
    }
    return subprocess.Popen(
        [sys.executable, "-m", "shinro_ctrl.cli", *args],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
        cwd=cwd,
        start_new_session=True,  # its own process group: the Ctrl-C below reaches the command and its workers only
    )


def _wait_for(proc: subprocess.Popen, predicate: Callable[[], bool], timeout: float = 120.0) -> None:
    """Poll ``predicate`` until it holds (a bounded wait on a condition, not a timed pause)."""
    deadline = time.monotonic() + timeout
    while not predicate():
        assert proc.poll() is None, f"the command ended first: {proc.communicate()}"
        assert time.monotonic() < deadline, "marker not reached"
        time.sleep(0.02)


def _ctrl_c(proc: subprocess.Popen) -> tuple[str, str]:
    """SIGINT to the command's process group; its output once it has ended."""
    try:
        os.killpg(proc.pid, signal.SIGINT)
        out, err = proc.communicate(timeout=120)
    finally:
        try:
            os.killpg(proc.pid, signal.SIGKILL)  # any stray worker
        except ProcessLookupError:
            pass
        proc.kill()
    return out, err


def _assert_interrupted(proc: subprocess.Popen, err: str) -> None:
    assert proc.returncode == 130, (proc.returncode, err)
    assert "Traceback" not in err and "error:" not in err, err
    assert err.strip() == "interrupted", err


def _forkserver(pid: int) -> list[int]:
    """The command's forkserver process (a child), once the pool starts it."""
    found = []
    for child in child_processes().get(pid, []):
        try:
            if b"forkserver" in Path(f"/proc/{child}/cmdline").read_bytes():
                found.append(child)
        except OSError:
            continue
    return found


def _pool_workers(pid: int) -> list[int]:
    """The pool's worker processes: children of the forkserver, itself a child of ``pid``."""
    children = child_processes()
    return [w for c in children.get(pid, []) for w in children.get(c, [])]


# ------------------------------------------------------------------------------------------- IPOPT
_ITERATION = re.compile(r"^\s*\d+\s+[-+0-9.]+e[-+]\d+\s", re.MULTILINE)


def test_ctrl_c_inside_the_ipopt_solve_of_plan_exits_130(tmp_path):
    # CasADi swallows the KeyboardInterrupt inside IPOPT ("NonIpopt_Exception_Thrown"): was exit 2 "error: ..."
    doc = tomllib.loads(shipped_config("cartpole_swingup_mujoco").read_text())
    knots = doc["plan"]["knots"]
    text = shipped_config("cartpole_swingup_mujoco").read_text().replace(f"knots = {knots}\n", "knots = 400\n")
    assert "knots = 400" in text  # a solve of several seconds
    (tmp_path / "slow.toml").write_text(text)
    # IPOPT reads ipopt.opt from the working directory: its iteration log is the marker that it is solving
    (tmp_path / "ipopt.opt").write_text("output_file ipopt.log\nfile_print_level 5\n")
    log = tmp_path / "ipopt.log"
    proc = _start(["plan", "slow.toml", "--out", "o"], tmp_path)
    _wait_for(proc, lambda: log.exists() and _ITERATION.search(log.read_text(errors="replace")) is not None)
    out, err = _ctrl_c(proc)
    _assert_interrupted(proc, err)
    assert "NonIpopt" not in err and "saved" not in out
    assert not (tmp_path / "o").exists()


# ------------------------------------------------------------------------------------------- run
def test_ctrl_c_in_a_long_mujoco_run_exits_130(tmp_path):
    proc = _start(["run", "cartpole_lqr_mujoco", "--duration", "120"], tmp_path)
    _wait_for(proc, lambda: proc.stdout.readline().startswith("running"))  # the loop is under way
    out, err = _ctrl_c(proc)
    _assert_interrupted(proc, err)
    assert "rms_error" not in out


_HOOK = """
import ctypes, os, signal, sys

class _Hook:
    def find_spec(self, name, path=None, target=None):
        if name == {module!r}:
            sys.meta_path.remove(self)
            # A Ctrl-C while an extension module runs Python code through PyRun_String during its import
            # (MuJoCo's does): CPython then keeps its "unhandled KeyboardInterrupt" flag set.
            run = ctypes.pythonapi.PyRun_String
            run.argtypes = [ctypes.c_char_p, ctypes.c_int, ctypes.py_object, ctypes.py_object]
            run.restype = ctypes.py_object
            scope = {{"os": os, "signal": signal}}
            run(b"os.killpg(os.getpgid(0), signal.SIGINT)\\ndone = True\\n", 257, scope, scope)
        return None

sys.meta_path.insert(0, _Hook())
"""


@pytest.mark.parametrize("module", ["mujoco", "casadi"])
def test_ctrl_c_inside_code_an_extension_runs_at_import_exits_130_not_by_the_signal(tmp_path, module):
    # was: "interrupted", then python -m killed itself by SIGINT (status -2) after its clean exit 130
    hook = tmp_path / "hook"
    hook.mkdir()
    (hook / "sitecustomize.py").write_text(_HOOK.format(module=module))
    proc = _start(["run", "cartpole_lqr_mujoco", "--duration", "120"], tmp_path, pythonpath=(hook,))
    out, err = proc.communicate(timeout=120)
    _assert_interrupted(proc, err)
    assert "running" not in out


_AT_EXIT = """
import atexit, sys

def _last_moments():
    print("shutting down", flush=True)
    sys.stdin.readline()  # until the test has sent its Ctrl-C and closed our stdin

atexit.register(_last_moments)
"""


def test_ctrl_c_while_python_shuts_down_after_the_command_is_ignored(tmp_path):
    # a Ctrl-C after the command has finished, while Python shuts down: was a traceback (atexit) or death by
    # SIGINT with status -2 and nothing printed (CPython restores SIGINT's default action while finalizing)
    hook = tmp_path / "hook"
    hook.mkdir()
    (hook / "sitecustomize.py").write_text(_AT_EXIT)
    proc = _start(["run", "cartpole_lqr", "--duration", "1"], tmp_path, pythonpath=(hook,))
    lines: list[str] = []
    _wait_for(proc, lambda: lines.append(proc.stdout.readline()) or lines[-1].startswith("shutting down"))
    try:
        os.killpg(proc.pid, signal.SIGINT)
        err = proc.communicate(input="\n", timeout=120)[1]  # and our stdin closed
    finally:
        proc.kill()
    assert proc.returncode == 0, (proc.returncode, err)  # the command had finished: its status stands
    assert "Traceback" not in err and "error:" not in err and "KeyboardInterrupt" not in err, err
    assert any(line.lstrip().startswith("rms_error") for line in lines)


# ------------------------------------------------------------------------------------------- pools
TRADEOFF = ["design", "lqr", "cartpole_lqr", "--tradeoff", "R=1e-3:1e2", "--points", "200", "--workers", "2"]
SWEEP = ["sweep", "cartpole_lqr", "--param", "plant.pole_mass=0.05:0.5", "--samples", "400", "--workers", "2"]


def _preloading(pid: int) -> bool:
    """True once the forkserver has loaded NumPy's C extension: its preload is under way (SciPy, CasADi next)."""
    for server in _forkserver(pid):
        try:
            if "_multiarray_umath" in Path(f"/proc/{server}/maps").read_text():
                return True
        except OSError:
            continue
    return False


@pytest.mark.parametrize(
    ("command", "moment"),
    [
        # the forkserver imports its preload list (was: its KeyboardInterrupt traceback from SciPy's import)
        ([*TRADEOFF, "--out", "t"], "preloading"),
        # the forkserver has just started, Python itself still starting up (was: it died of the signal and the
        # parent's next submit failed with an EOFError traceback, exit 1)
        ([*SWEEP, "--method", "pool", "--out", "t"], "starting"),
    ],
    ids=["tradeoff-forkserver-preloading", "sweep-forkserver-starting"],
)
def test_ctrl_c_with_pool_workers_exits_130_and_no_worker_prints(tmp_path, command, moment):
    proc = _start(command, tmp_path)
    if moment == "starting":
        _wait_for(proc, lambda: bool(_forkserver(proc.pid)))
    else:
        _wait_for(proc, lambda: _preloading(proc.pid))
    err = _ctrl_c(proc)[1]
    _assert_interrupted(proc, err)
    assert not (tmp_path / "t").exists()


def test_ctrl_c_while_sweep_workers_run_exits_130(tmp_path):
    proc = _start([*SWEEP, "--method", "pool", "--out", "t"], tmp_path)
    _wait_for(proc, lambda: len(_pool_workers(proc.pid)) >= 2)  # the workers run samples
    err = _ctrl_c(proc)[1]
    _assert_interrupted(proc, err)
    assert not (tmp_path / "t").exists()
