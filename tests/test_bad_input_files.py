"""File safety: nothing the user owns is lost or mixed up; interrupted writes leave the old file or the new one."""

from __future__ import annotations

import json
import os
import random
import shutil
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from shinro_ctrl.cli import main
from shinro_ctrl.resources import regression_dir

from .bad_input_helpers import GOOD, CommandForker, _copy_regression, check_one_line_exit_2

# ----------------------------------------------------------------- fault cases
KILL_MID_WRITE = textwrap.dedent(
    """
    import os, signal, sys
    import shinro_ctrl.files as files
    calls = {"n": 0}
    real_fsync = os.fsync

    def fsync_then_die(fd):
        real_fsync(fd)
        calls["n"] += 1
        if calls["n"] == int(sys.argv[2]):
            os.kill(os.getpid(), signal.SIGKILL)  # the temporary file is complete, the rename has not happened

    files.os.fsync = fsync_then_die
    from shinro_ctrl.cli import main
    sys.exit(main(["regress", sys.argv[1], "--update"]))
    """
)


@pytest.mark.parametrize("kill_at", [1, 2])
def test_interrupted_regress_update_leaves_baselines_intact(tmp_path, kill_at):
    for name in ("cartpole_lqr", "double_pendulum_lqr"):
        shutil.copy(regression_dir() / f"{name}.toml", tmp_path)
        # stale baselines, so an update would change them
        (tmp_path / f"{name}.baseline.json").write_text(json.dumps({"format": 1, "metrics": {"rms_error": 123.0}}))
    before = {p.name: p.read_text() for p in tmp_path.glob("*.baseline.json")}
    res = subprocess.run(
        [sys.executable, "-c", KILL_MID_WRITE, str(tmp_path), str(kill_at)], capture_output=True, text=True, timeout=300
    )
    assert res.returncode == -9, res.stderr  # really killed
    changed = 0
    for path in tmp_path.glob("*.baseline.json"):
        data = json.loads(path.read_text())  # every baseline parses: old or complete new, never half-written
        changed += data != json.loads(before[path.name])
    assert changed == 0  # killed before the set's commit point: every baseline is the previous one
    # a later run is not confused by the orphaned temporary file and completes the update
    assert main(["regress", str(tmp_path), "--update"]) == 0
    assert main(["regress", str(tmp_path)]) == 0
    assert not [p for p in Path(tmp_path).iterdir() if p.name.startswith(".") and p.suffix == ".tmp"]


# ------------------------------------------------------------------------------------ FILE SAFETY
def test_run_out_refuses_a_folder_holding_the_input_scenario(tmp_path, capsys):
    # item 2: the user's scenario (with its comments) is never overwritten
    scenario = tmp_path / "scenario.toml"
    text = "# my tuned cart-pole\n" + GOOD
    scenario.write_text(text)
    assert main(["run", str(scenario), "--out", str(tmp_path), "--duration", "0.1"]) == 2
    assert "input" in capsys.readouterr().err
    assert scenario.read_text() == text
    other = tmp_path / "mine.toml"
    other.write_text(text)
    assert main(["run", str(other), "--out", str(tmp_path), "--duration", "0.1"]) == 2
    assert "input" in capsys.readouterr().err
    assert main(["run", "--out", str(tmp_path), "--duration", "0.1"]) == 2  # not the input, but the user's file
    assert "not a run output" in capsys.readouterr().err
    assert other.read_text() == text and sorted(p.name for p in tmp_path.iterdir()) == ["mine.toml", "scenario.toml"]


def test_plan_checks_its_outputs_before_solving(tmp_path, capsys):
    # plan --out / --plot go through run's output checks: no input or foreign file overwritten, nothing solved first
    from shinro_ctrl.resources import shipped_config

    scenario = tmp_path / "swing.toml"
    scenario.write_text(shipped_config("cartpole_swingup_mujoco.toml").read_text())
    (tmp_path / "o").mkdir()
    (tmp_path / "o" / "swing_plan.npz").write_text("my notes")
    cases = [
        (["--plot", str(scenario)], "is the input file"),
        (["--out", str(scenario)], "is not a folder"),
        (["--out", str(tmp_path / "o")], "is not an NPZ file"),
        (["--out", str(tmp_path / "p"), "--plot", str(tmp_path / "p" / "swing_plan.npz")], "is the plan file"),
    ]
    for extra, needle in cases:
        assert main(["plan", str(scenario), *extra]) == 2
        out, err = capsys.readouterr()
        assert needle in err and "solve time" not in out, err
    assert (tmp_path / "o" / "swing_plan.npz").read_text() == "my notes"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["o", "swing.toml"]


@pytest.mark.parametrize("option", ["--plot", "--video"])
def test_plot_onto_the_input_file_is_refused(option, tmp_path, capsys):
    scenario = tmp_path / "mine.toml"
    scenario.write_text(GOOD)
    target = scenario if option == "--plot" else tmp_path / "notes.gif"
    if option == "--video":
        target.write_text("my notes, not a GIF")
    before = target.read_text()
    assert main(["run", str(scenario), option, str(target), "--duration", "0.1"]) == 2
    err = capsys.readouterr()
    assert "running" not in err.out and ("input" in err.err or "not a GIF" in err.err), err
    assert target.read_text() == before


def test_output_errors_name_the_users_path_before_any_work(tmp_path, capsys):
    (tmp_path / "afile").write_text("a file where a folder is needed")
    target = tmp_path / "afile" / "x.png"
    assert main(["run", "--plot", str(target), "--duration", "0.1"]) == 2
    out, err = capsys.readouterr()
    assert str(target) in err and ".tmp" not in err and "running" not in out, err


def test_atomic_write_errors_name_the_target_not_the_temporary(tmp_path):
    from shinro_ctrl.files import atomic_write

    target = tmp_path / "a" / "b.json"
    (tmp_path / "a").write_text("a file where a folder is needed")
    with pytest.raises(OSError) as info:
        atomic_write(target, lambda f: f.write("x"))
    assert str(target) in str(info.value) and ".tmp" not in str(info.value)


def test_regress_update_validates_every_scenario_before_writing(tmp_path, capsys):
    # item 4: a malformed scenario anywhere in the folder: nothing is written
    before = _copy_regression(tmp_path)
    for p in tmp_path.glob("*.baseline.json"):
        data = json.loads(p.read_text())
        data["metrics"]["rms_error"] = 123.0
        p.write_text(json.dumps(data))
    before = {p.name: p.read_text() for p in tmp_path.glob("*.baseline.json")}
    (tmp_path / "zz_broken.toml").write_text(GOOD.replace("R = [0.1]", "R = ['x']"))
    assert main(["regress", str(tmp_path), "--update"]) == 2
    assert "zz_broken" in capsys.readouterr().err
    assert {p.name: p.read_text() for p in tmp_path.glob("*.baseline.json")} == before


def test_regress_update_writes_nothing_when_a_run_fails(tmp_path, capsys):
    before = _copy_regression(tmp_path, ("cartpole_lqr",))
    (tmp_path / "zz_infeasible.toml").write_text(  # hard state bounds the initial state violates: MPCInfeasible
        GOOD.replace(
            'type = "LQR"',
            'type = "LinearMPC"\nhorizon = 5\nu_min = [-1]\nu_max = [1]\n'
            "x_min = [-1, -1, -0.01, -1]\nx_max = [1, 1, 0.01, 1]",
        )
        + "[sim]\nduration = 0.5\ninitial_state = [0, 0, 0.5, 0]\n"
    )
    assert main(["regress", str(tmp_path), "--update"]) == 1
    out = capsys.readouterr().out
    assert "no baseline written" in out and "zz_infeasible" in out
    assert {p.name: p.read_text() for p in tmp_path.glob("*.baseline.json")} == before


def test_regress_without_a_folder_never_updates_the_shipped_baselines(capsys):
    # item 1: following the hint literally must not rewrite the installed package's baselines
    before = {p.name: p.read_bytes() for p in regression_dir().glob("*.baseline.json")}
    check_one_line_exit_2(["regress", "--update"], "name", capsys)
    assert {p.name: p.read_bytes() for p in regression_dir().glob("*.baseline.json")} == before


def test_missing_baseline_hint_names_the_folder(tmp_path, capsys):
    shutil.copy(regression_dir() / "cartpole_lqr.toml", tmp_path)
    assert main(["regress", str(tmp_path)]) == 1
    out, err = capsys.readouterr()
    assert f"regress {tmp_path} --update" in out and f"regress {tmp_path} --update" in err
    assert "regress --update" not in out


def test_baseline_symlink_is_written_through(tmp_path):
    # item 5: the link stays a link and its target gets the new value
    _copy_regression(tmp_path, ("cartpole_lqr",))
    store = tmp_path / "store"
    store.mkdir()
    real = store / "cartpole.json"
    real.write_text(json.dumps({"format": 1, "metrics": {"rms_error": 123.0}}))
    link = tmp_path / "cartpole_lqr.baseline.json"
    link.unlink()
    link.symlink_to(real)
    assert main(["regress", str(tmp_path), "--update"]) == 0
    assert link.is_symlink() and os.readlink(link) == str(real)
    assert json.loads(real.read_text())["metrics"]["rms_error"] != 123.0
    assert main(["regress", str(tmp_path)]) == 0


@pytest.mark.parametrize("fmt", [2, "1", None, True])
def test_baseline_with_an_unknown_format_is_refused(fmt, tmp_path, capsys):
    _copy_regression(tmp_path, ("cartpole_lqr",))
    path = tmp_path / "cartpole_lqr.baseline.json"
    data = json.loads(path.read_text())
    data["format"] = fmt
    path.write_text(json.dumps(data))
    check_one_line_exit_2(["regress", str(tmp_path)], "format", capsys)


HOLD_TEMP = textwrap.dedent(
    """
    import sys, time
    from pathlib import Path
    from shinro_ctrl.files import atomic_write

    def hold(f):  # a writer in flight: its locked temporary exists until the write returns
        print(next(Path(sys.argv[1]).glob(".cartpole_lqr.baseline.json.*.tmp")), flush=True)
        time.sleep(60)

    atomic_write(Path(sys.argv[1]) / "cartpole_lqr.baseline.json", hold)
    """
)


def test_cleanup_never_deletes_a_live_writers_temporary(tmp_path):
    # item 6: a concurrent update's in-flight temporary is locked; only a dead writer's is stale
    from shinro_ctrl.files import remove_stale_temps

    proc = subprocess.Popen([sys.executable, "-c", HOLD_TEMP, str(tmp_path)], stdout=subprocess.PIPE, text=True)
    try:
        live = Path(proc.stdout.readline().strip())
        dead = tmp_path / ".cartpole_lqr.baseline.json.dead1234.tmp"
        dead.write_text("orphan of a killed update")
        removed = remove_stale_temps(tmp_path, ".*.baseline.json.*.tmp")
        assert live.exists() and not dead.exists() and removed == [dead]
    finally:
        proc.kill()
        proc.wait()
    assert remove_stale_temps(tmp_path, ".*.baseline.json.*.tmp") == [live] and not live.exists()


def test_two_concurrent_updates_on_one_folder(tmp_path):
    _copy_regression(tmp_path, ("cartpole_lqr",))
    procs = [
        subprocess.Popen(
            [sys.executable, "-m", "shinro_ctrl.cli", "regress", str(tmp_path), "--update"],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        for _ in range(2)
    ]
    for proc in procs:
        _, err = proc.communicate(timeout=300)
        assert proc.returncode == 0, err
    assert main(["regress", str(tmp_path)]) == 0
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]


def _run_folder_state(d: Path) -> str | None:
    """'complete' (manifest lists exactly the files, sizes match, each file loads), or None if empty/absent."""
    import numpy as np

    from shinro_ctrl.files import RUN_MANIFEST

    if not d.exists():
        return None
    manifest = json.loads((d / RUN_MANIFEST).read_text())
    names = sorted(p.name for p in d.iterdir() if p.name != RUN_MANIFEST)
    assert names == sorted(manifest["files"]) == sorted(manifest["expected"]), (names, manifest)
    for name, size in manifest["files"].items():
        assert (d / name).stat().st_size == size
    with np.load(d / "result.npz") as z:
        steps = len(z["t"])
    metrics = json.loads((d / "metrics.json").read_text())
    assert metrics["scenario"] and (d / "run.png").read_bytes()[:4] == b"\x89PNG"
    return f"{steps} steps"


def test_random_kills_of_run_out_leave_one_complete_run(tmp_path):
    # item 3: SIGKILL at random points (seeded) of `run --out`: the folder holds the previous run or the new one.
    # The commands are forked after the imports (CommandForker): every kill lands in the run or the writes (a kill
    # in the imports touched no file), at a quarter of a fresh interpreter's cost.
    out = tmp_path / "out"
    assert main(["run", "--out", str(out), "--duration", "0.2"]) == 0
    states = {_run_folder_state(out)}
    with CommandForker() as forker:
        t0 = time.perf_counter()
        pid = forker.start("run", "--out", str(out), "--duration", "0.4")
        assert forker.wait(pid) == 0
        full = time.perf_counter() - t0
        states.add(_run_folder_state(out))
        rng = random.Random(14)
        for k in range(4):  # seeded random kill times over the whole command (run, plot, writes)
            duration = ("0.2", "0.4", "0.3")[k % 3]
            pid = forker.start("run", "--out", str(out), "--duration", duration)
            time.sleep(rng.uniform(0.1, 1.0) * full)
            os.kill(pid, signal.SIGKILL)
            forker.wait(pid)
            state = _run_folder_state(out)
            assert state is not None
            states.add(state)
    assert states <= {"21 steps", "41 steps", "31 steps"}
    assert main(["run", "--out", str(out), "--duration", "0.2"]) == 0  # cleans up the orphans of the kills
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]
    assert _run_folder_state(out) == "21 steps"


def test_random_kills_of_regress_update_leave_one_complete_set(tmp_path):
    from shinro_ctrl.files import recover_journals

    _copy_regression(tmp_path)
    stale = {}
    for p in tmp_path.glob("*.baseline.json"):
        data = json.loads(p.read_text())
        data["metrics"]["rms_error"] = 123.0
        p.write_text(json.dumps(data))
        stale[p.name] = p.read_text()
    with CommandForker() as forker:  # forked after the imports: each kill lands in the work (see the run test)
        t0 = time.perf_counter()
        assert forker.wait(forker.start("regress", str(tmp_path / "cartpole_lqr.toml"))) == 1
        full = 1.5 * (time.perf_counter() - t0)
        rng = random.Random(13)
        for _ in range(4):
            pid = forker.start("regress", str(tmp_path), "--update")
            time.sleep(rng.uniform(0.1, 1.2) * full)
            os.kill(pid, signal.SIGKILL)
            forker.wait(pid)
            recover_journals(tmp_path)  # what the next regress does first: a set killed after its commit completes
            now = {p.name: p.read_text() for p in tmp_path.glob("*.baseline.json")}
            is_old = [now[n] == stale[n] for n in stale]
            assert all(is_old) or not any(is_old), is_old  # all previous or all new, never mixed
            if not any(is_old):
                for p in tmp_path.glob("*.baseline.json"):  # make the next kill meaningful again
                    p.write_text(stale[p.name])
    assert main(["regress", str(tmp_path), "--update"]) == 0
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]


@pytest.mark.parametrize(
    "name,content", [("notes.txt", "my notes"), ("photo.jpg", "\xff\xd8\xff jpeg"), ("x.png", "text")]
)
def test_plot_never_overwrites_a_file_that_is_not_a_png(name, content, tmp_path, capsys, monkeypatch):
    # item 2 with other inputs: whatever the name, only an earlier PNG is replaced
    monkeypatch.chdir(tmp_path)
    target = tmp_path / name
    target.write_text(content)
    # a name with an extension no plot is written in (.txt, .jpg) is refused for it, before any work
    needle = "not a PNG file" if name.endswith(".png") else f"--plot '{name}': a plot is written as .png, .pdf, .svg"
    for args in (["run", "--plot", name, "--duration", "0.1"], ["crosscheck", "pendulum", "--plot", name]):
        assert main(args) == 2
        out, err = capsys.readouterr()
        assert needle in err and "running" not in out, err
    assert target.read_text() == content


def test_update_refuses_a_baseline_that_is_a_folder_before_writing_any(tmp_path, capsys):
    _copy_regression(tmp_path)
    before = {p.name: p.read_text() for p in tmp_path.glob("*.baseline.json")}
    (tmp_path / "double_pendulum_lqr.baseline.json").unlink()
    (tmp_path / "double_pendulum_lqr.baseline.json").mkdir()
    assert main(["regress", str(tmp_path), "--update"]) == 2
    assert "directory" in capsys.readouterr().err
    assert (tmp_path / "cartpole_lqr.baseline.json").read_text() == before["cartpole_lqr.baseline.json"]
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # no journal, no temporaries
