"""Bad command-line input: one line and exit 2, never a traceback or a hang; Ctrl-C: exit 130 (issue 23 §4, §5)."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from shinro_ctrl.cli import main
from shinro_ctrl.planning import Trajectory

from .bad_input_helpers import child_processes

ROOT = Path(__file__).resolve().parents[1]


def _one_error(capsys, needle: str) -> str:
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), err
    assert needle in lines[0], lines[0]
    return lines[0]


# ------------------------------------------------------------- plan files
def _plan(path: Path) -> Path:
    t = np.linspace(0.0, 1.0, 5)
    x = np.zeros((5, 4))
    return Trajectory(t=t, x=x, u=np.zeros((5, 1)), xdot=np.zeros((5, 4))).save(path)


def _garbage(kind: str, tmp_path: Path) -> Path:
    path = tmp_path / f"{kind}.npz"
    if kind == "text":
        path.write_text("not a plan")
    elif kind == "empty":
        path.write_bytes(b"")
    elif kind == "truncated":
        data = _plan(tmp_path / "whole.npz").read_bytes()
        path.write_bytes(data[: len(data) // 2])
    elif kind == "wrong_keys":
        np.savez(path, a=np.arange(3.0))
    elif kind == "wrong_shapes":
        np.savez(path, t=np.arange(3.0), x=np.arange(3.0), u=np.zeros((3, 1)), xdot=np.zeros(3),
                 method=np.array("trapezoid"), stats=np.zeros(4), status=np.array(""), state_names=np.array([]),
                 input_names=np.array([]))  # fmt: skip
    elif kind == "strings":
        np.savez(path, t=np.array(["a", "b"]), x=np.zeros((2, 4)), u=np.zeros((2, 1)), xdot=np.zeros((2, 4)),
                 method=np.array("trapezoid"), stats=np.zeros(4), status=np.array(""), state_names=np.array([]),
                 input_names=np.array([]))  # fmt: skip
    elif kind == "short_stats":
        np.savez(path, t=np.arange(3.0), x=np.zeros((3, 4)), u=np.zeros((3, 1)), xdot=np.zeros((3, 4)),
                 method=np.array("trapezoid"), stats=np.zeros(2), status=np.array(""), state_names=np.array([]),
                 input_names=np.array([]))  # fmt: skip
    elif kind == "npy":
        path = tmp_path / "array.npy"
        np.save(path, np.zeros(3))
    elif kind == "pickled":
        np.savez(path, t=np.array([{"a": 1}], dtype=object))
    return path


GARBAGE = ["text", "empty", "truncated", "wrong_keys", "wrong_shapes", "strings", "short_stats", "npy", "pickled"]


@pytest.mark.parametrize("kind", GARBAGE)
def test_a_garbage_plan_file_is_one_line(kind, tmp_path, capsys):
    path = _garbage(kind, tmp_path)
    assert main(["run", "cartpole_swingup_mujoco", "--plan", str(path), "--duration", "0.1"]) == 2
    _one_error(capsys, "is not a saved plan")


def test_a_plan_file_that_is_a_folder_or_missing_is_one_line(tmp_path, capsys):
    (tmp_path / "d.npz").mkdir()
    for path, needle in ((tmp_path / "d.npz", "directory"), (tmp_path / "none.npz", "not found")):
        assert main(["run", "cartpole_swingup_mujoco", "--plan", str(path), "--duration", "0.1"]) == 2
        _one_error(capsys, needle)


# --------------------------------------------------------- bounds and values
@pytest.mark.parametrize(
    "args, needle",
    [
        (["--points", "1000000000"], "--points must be an integer in [2, 1,000] (the limit), got 1000000000"),
        (["--points", str(10**22)], "(the limit)"),
        (["--points", "1e22"], "invalid int value"),
        (["--points", "1"], "--points must be an integer in [2, 1,000]"),
        (["--workers", "0"], "--workers must be an integer in [1, 256]"),
        (["--workers", "100000"], "(the limit)"),
    ],
)
def test_tradeoff_counts_are_bounded(args, needle, tmp_path, capsys):
    base = ["design", "lqr", "cartpole_lqr", "--tradeoff", "R=0.1:10", "--out", str(tmp_path / "t")]
    assert main([*base, *args]) == 2
    _one_error(capsys, needle)
    assert not (tmp_path / "t").exists()


def test_run_tradeoff_bounds_its_counts():
    from shinro_ctrl.analysis.tradeoff import run_tradeoff
    from shinro_ctrl.errors import InvalidArgument

    for kw in ({"points": 10**9}, {"points": 1}, {"workers": 10**6}, {"points": True}):
        with pytest.raises(InvalidArgument, match=r"the limit|integer"):
            run_tradeoff("cartpole_lqr", "R", 0.1, 1.0, **kw)


@pytest.mark.parametrize(
    "address", ["tcp://[::1", "tcp://[::1]", "tcp://host", "tcp://:8786", "tcp://h:99999", "[::1:80", "tcp://"]
)
def test_a_malformed_scheduler_address_is_one_line(address, tmp_path, capsys):
    args = ["sweep", "cartpole_lqr", "--param", "plant.cart_mass=0.5:1", "--out", str(tmp_path / "s")]
    assert main([*args, "--scheduler", address]) == 2
    _one_error(capsys, "--scheduler must look like tcp://HOST:PORT")


@pytest.mark.parametrize(
    "vector, needle",
    [
        ("0,,0", "empty entry"),
        (",0", "empty entry"),
        ("0,", "empty entry"),
        ("0, ,0", "empty entry"),
        ("[0,0", "unbalanced bracket"),
        ("0,0]", "unbalanced bracket"),
        ("[]", "empty vector"),
        ("0;0", "not a number"),
        ("nan,0", "not a finite number"),
        ("0,1e400", "not a finite number"),
        ("0,-inf", "not a finite number"),
    ],
)
def test_malformed_vectors_are_refused(vector, needle, capsys):
    assert main(["linearize", "pendulum", f"--x0={vector}"]) == 2
    line = _one_error(capsys, needle)
    assert "--x0" in line
    assert main(["crosscheck", "pendulum", f"--u0={vector}"]) == 2
    _one_error(capsys, needle)


@pytest.mark.parametrize("vector", ["0, 0", "[0.1, 0]", "pi/2 0", " 0.1,0 "])
def test_well_formed_vectors_still_parse(vector, capsys):
    assert main(["linearize", "pendulum", f"--x0={vector}"]) == 0
    capsys.readouterr()


@pytest.mark.parametrize(
    "command", [["run", ""], ["plan", ""], ["run", "  "], ["design", "lqr", ""], ["linearize", ""]]
)
def test_an_empty_scenario_argument_is_refused(command, capsys):
    assert main(command) == 2
    _one_error(capsys, "empty")


def test_run_duration_must_be_whole_steps(capsys):
    assert main(["run", "pendulum_lqr", "--duration", "0.015"]) == 2
    _one_error(capsys, "--duration = 0.015 s is not a whole number of steps of dt = 0.01 s")
    assert main(["run", "pendulum_lqr", "--duration", "0.001"]) == 2
    _one_error(capsys, "shorter than one step")


def test_a_bom_in_a_scenario_is_named(tmp_path, capsys):
    from shinro_ctrl.resources import config_path

    path = tmp_path / "bom.toml"
    path.write_bytes(b"\xef\xbb\xbf" + config_path("pendulum_lqr").read_bytes())
    for cmd in (["run", str(path)], ["design", "lqr", str(path)], ["crosscheck", str(path)]):
        assert main(cmd) == 2
        _one_error(capsys, "byte-order mark (BOM)")


# ------------------------------------------------- scenarios as plant arguments
@pytest.mark.parametrize("command", ["linearize", "crosscheck"])
@pytest.mark.parametrize("config", ["cartpole_lqr", "cartpole_lqr.toml", "regression/cartpole_lqr.toml"])
def test_linearize_and_crosscheck_take_a_scenario_as_run_does(command, config, capsys):
    assert main([command, config]) == 0
    out = capsys.readouterr().out
    assert "CartPole" in out or "cartpole" in out.lower()


def test_a_scenario_with_other_parameters_is_linearized_with_them(tmp_path, capsys):
    from shinro_ctrl.linearization import compare
    from shinro_ctrl.plants import CartPole

    path = tmp_path / "heavy.toml"
    path.write_text(
        '[plant]\ntype = "CartPole"\ncart_mass = 5.0\n[controller]\ntype = "LQR"\nQ = [1, 1, 1, 1]\nR = [1]\n'
    )
    assert main(["linearize", str(path)]) == 0
    out = capsys.readouterr().out
    A = compare(CartPole(cart_mass=5.0), None, None).A_exact  # a B entry depends on the cart mass: so does A
    assert f"{A[1, 2] + 0.0:11.5g}".strip() in out


def test_an_unknown_plant_names_both_kinds(capsys):
    assert main(["linearize", "cartpol_lqr"]) == 2
    _one_error(capsys, "or give a scenario file or shipped scenario name")


# ------------------------------------------------------------- sweep note
def test_the_sweep_notes_when_the_batch_method_overrides_workers(tmp_path, capsys):
    args = ["sweep", "cartpole_lqr", "--param", "plant.cart_mass=0.5:1", "--samples", "2", "--workers", "2"]
    assert main([*args, "--out", str(tmp_path / "s")]) == 0
    out = capsys.readouterr().out
    assert re.search(r"note: --workers 2 asked for, but the 'batch' executor ran in one process", out)
    assert main([*args, "--method", "serial", "--out", str(tmp_path / "s2")]) == 0
    assert "note: --workers 2 asked for, but the 'serial' executor" in capsys.readouterr().out


def test_a_dict_scenario_is_named_by_its_plant_and_controller(tmp_path):
    from shinro_ctrl.plots import run_figure
    from shinro_ctrl.sim import RobotSim
    from shinro_ctrl.sweep import run_sweep

    doc = {
        "plant": {"type": "CartPole"},
        "controller": {"type": "LQR", "Q": [1, 1, 10, 1], "R": [1]},
        "sim": {"duration": 0.2, "initial_state": [0, 0, 0.05, 0]},
    }
    result = RobotSim.from_config(doc).run()
    title = run_figure(result)._suptitle.get_text()
    assert title.startswith("CartPole + LQR") and "<dict>" not in title
    sweep = run_sweep(doc, {"plant.cart_mass": (0.5, 1.0)}, samples=2, progress=False)
    assert sweep.scenario == "CartPole + LQR"


# ------------------------------------------------------------ worker deaths
def _dies_on_point_2(job):
    """A trade-off job whose point 2 kills its own worker (as the OOM killer would)."""
    from shinro_ctrl.analysis.tradeoff import COLUMNS

    if 2 in job.indices:
        os.kill(os.getpid(), signal.SIGKILL)
    return [(i, dict.fromkeys(COLUMNS, float(v)), "") for i, v in zip(job.indices, job.values, strict=True)]


def test_a_killed_tradeoff_worker_names_its_point_and_keeps_the_others():
    import copy

    from shinro_ctrl.analysis.tradeoff import WORKER_DIED, _Job, _run_pool
    from shinro_ctrl.config import load_scenario

    scenario = load_scenario("cartpole_lqr")
    doc = copy.deepcopy(scenario.raw)
    values = [0.1, 0.2, 0.3, 0.4, 0.5]
    jobs = [_Job(doc, str(scenario.path), None, "R", (values[i], values[i + 1]), (i, i + 1)) for i in (0, 2)]
    jobs.append(_Job(doc, str(scenario.path), None, "R", (values[4],), (4,)))
    results, current = _run_pool(_dies_on_point_2, jobs, 2, (doc, str(scenario.path), None))
    by_index = {i: (row, err) for i, row, err in results}
    assert sorted(by_index) == [0, 1, 2, 3, 4]
    assert by_index[2][1] == WORKER_DIED and np.isnan(by_index[2][0]["rms_error"])
    for i in (0, 1, 3, 4):
        assert by_index[i] == ({k: values[i] for k in by_index[i][0]}, "")
    assert np.isfinite(current["rms_error"])


def _pool_workers(pid: int) -> list[int]:
    """The pool's worker processes: children of the forkserver, itself a child of ``pid``."""
    children = child_processes()
    return [w for c in children.get(pid, []) for w in children.get(c, [])]


def _descendants(pid: int) -> list[int]:
    """Process ids below ``pid`` (from /proc)."""
    children = child_processes()
    out, todo = [], [pid]
    while todo:
        for c in children.get(todo.pop(), []):
            out.append(c)
            todo.append(c)
    return out


def _wait_for(predicate, timeout: float = 120.0) -> None:
    """Poll ``predicate`` until it holds (a bounded wait on a condition, not a timed pause)."""
    deadline = time.monotonic() + timeout
    while not predicate():
        assert time.monotonic() < deadline, "condition not reached"
        time.sleep(0.05)


def _cli(*args: str) -> subprocess.Popen:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    return subprocess.Popen(
        [sys.executable, "-c", "from shinro_ctrl._entry import main; main()", *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
        cwd=ROOT,
    )


@pytest.mark.skipif(not Path("/proc").is_dir(), reason="reads /proc to find the worker processes")
def test_a_sweep_worker_killed_mid_run_loses_no_sample(tmp_path):
    proc = _cli("sweep", "cartpole_lqr", "--param", "plant.cart_mass=0.5:1", "--samples", "16", "--workers", "2",
                "--method", "pool", "--out", str(tmp_path / "s"))  # fmt: skip
    try:
        _wait_for(lambda: len(_pool_workers(proc.pid)) >= 2)  # the workers are running samples
        os.kill(_pool_workers(proc.pid)[0], signal.SIGKILL)  # as the OOM killer would
        err = proc.communicate(timeout=300)[1]
    finally:
        proc.kill()
    assert proc.returncode == 0, err
    assert "Traceback" not in err
    rows = (tmp_path / "s" / "sweep.csv").read_text().splitlines()
    assert len(rows) == 17  # every sample has its row


# ----------------------------------------------------------------- Ctrl-C
@pytest.mark.parametrize(
    "start",
    [
        "from shinro_ctrl._entry import main\nmain()\n",  # the console script
        "import runpy\nrunpy.run_module('shinro_ctrl.cli', run_name='__main__')\n",  # python -m shinro_ctrl.cli
    ],
)
@pytest.mark.parametrize("module", ["numpy", "casadi"])
def test_ctrl_c_during_start_up_imports_exits_130_without_a_traceback(start, module):
    # the first import of the module sends this process SIGINT: a real Ctrl-C while the command line loads
    code = (
        "import os, signal, sys\n"
        "class Hook:\n"
        "    def find_spec(self, name, path=None, target=None):\n"
        f"        if name == '{module}':\n"
        "            sys.meta_path.remove(self)\n"
        "            os.kill(os.getpid(), signal.SIGINT)\n"
        "        return None\n"
        "sys.meta_path.insert(0, Hook())\n"
        "sys.argv = ['shinro-ctrl', 'list']\n" + start
    )
    proc = subprocess.run(
        [sys.executable, "-c", code],
        capture_output=True,
        text=True,
        timeout=120,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
    )
    assert proc.returncode == 130, proc.stderr
    assert proc.stderr.strip() == "interrupted" and "plants:" not in proc.stdout


def test_the_console_script_is_the_interrupt_safe_entry():
    import tomllib

    scripts = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["scripts"]
    assert scripts["shinro-ctrl"] == "shinro_ctrl._entry:main"


@pytest.mark.skipif(not Path("/proc").is_dir(), reason="reads /proc to find the worker processes")
def test_ctrl_c_in_a_tradeoff_exits_130_and_no_worker_prints_a_traceback(tmp_path):
    proc = _cli("design", "lqr", "cartpole_lqr", "--tradeoff", "R=0.01:100", "--points", "200", "--workers", "2",
                "--out", str(tmp_path / "t"))  # fmt: skip
    try:
        _wait_for(lambda: len(_pool_workers(proc.pid)) >= 2)  # the workers are running points
        proc.send_signal(signal.SIGINT)
        err = proc.communicate(timeout=120)[1]
    finally:
        proc.kill()
    assert proc.returncode == 130, err
    assert err.strip().splitlines()[-1] == "interrupted" and "Traceback" not in err, err
    assert not (tmp_path / "t").exists()
    _wait_for(lambda: not _descendants(proc.pid))
