"""The regression harness: shipped baselines pass, a detuned controller fails, --update heals."""

from __future__ import annotations

import json
import re
import shutil
import subprocess
import sys

import pytest

from shinro_ctrl.regression import compare_metrics, read_baseline, run_regression
from shinro_ctrl.resources import regression_dir
from shinro_ctrl.testing import assert_matches_baseline


def run_cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "shinro_ctrl.cli", *args], capture_output=True, text=True, timeout=600)


def test_shipped_baselines_pass():
    report = run_regression()
    assert report.passed, [(c.scenario, c.metric, c.baseline, c.now) for c in report.failures] + report.missing
    assert len(report.scenarios) >= 6
    assert any("(mujoco)" in s for s in report.scenarios) and any("(standalone)" in s for s in report.scenarios)


@pytest.fixture
def detuned_copy(tmp_path):
    """A copy of the cart-pole regression scenario with R scaled by 1000."""
    src = regression_dir() / "cartpole_lqr.toml"
    shutil.copy(src, tmp_path / "cartpole_detuned.toml")
    shutil.copy(src.with_name("cartpole_lqr.baseline.json"), tmp_path / "cartpole_detuned.baseline.json")
    text = (tmp_path / "cartpole_detuned.toml").read_text()
    r_line = re.search(r"^R = \[(.*)\]$", text, flags=re.M)
    assert r_line, "the regression scenario must carry its R = [...] line"
    scaled = ", ".join(str(float(v) * 1000) for v in r_line.group(1).split(","))
    (tmp_path / "cartpole_detuned.toml").write_text(text.replace(r_line.group(0), f"R = [{scaled}]"))
    return tmp_path


def test_detuned_controller_fails_then_update_passes(detuned_copy):
    res = run_cli("regress", str(detuned_copy))
    assert res.returncode == 1, res.stdout + res.stderr
    assert "cartpole_detuned" in res.stderr and "rms_error" in res.stderr
    assert "FAIL" in res.stdout
    res = run_cli("regress", str(detuned_copy), "--update")
    assert res.returncode == 0, res.stderr
    baseline = json.loads((detuned_copy / "cartpole_detuned.baseline.json").read_text())
    assert baseline["scenario"] == "cartpole_detuned"
    res = run_cli("regress", str(detuned_copy))
    assert res.returncode == 0, res.stdout + res.stderr


def test_missing_baseline_is_reported(tmp_path):
    shutil.copy(regression_dir() / "cartpole_lqr.toml", tmp_path / "x.toml")
    report = run_regression(tmp_path)
    assert not report.passed and report.missing == ["x (standalone)"]


def test_corrupt_baseline_is_a_clear_error(tmp_path):
    (tmp_path / "b.baseline.json").write_text("{ not json")
    with pytest.raises(ValueError, match="not a valid baseline"):
        read_baseline(tmp_path / "b.baseline.json")


def test_tolerances_are_relative_plus_absolute():
    checks = {
        c.metric: c
        for c in compare_metrics(
            "s",
            {"rms_error": 1.0009, "max_error": 1.2},
            {"rms_error": 1.0, "max_error": 1.0},
            {"max_error": {"rel": 0.1, "abs": 0.05}},
        )
    }
    assert checks["rms_error"].passed and not checks["max_error"].passed
    inf = compare_metrics("s", {"settling_time": float("inf")}, {"settling_time": float("inf")})
    assert inf[0].passed


def test_users_fixture_and_assertion(run_scenario, tmp_path):
    result = run_scenario("pendulum_lqr", duration=1.0)
    path = tmp_path / "pendulum.baseline.json"
    with pytest.raises(AssertionError, match="no baseline"):
        assert_matches_baseline(result, path)
    assert_matches_baseline(result, path, update=True)
    assert_matches_baseline(result, path)
    worse = run_scenario({**result.config, "controller": {**result.config["controller"], "R": [100.0]}}, duration=1.0)
    with pytest.raises(AssertionError, match="rms_error"):
        assert_matches_baseline(worse, path)


def test_written_files_get_ordinary_permissions(tmp_path):
    import os
    import stat

    from shinro_ctrl.files import dump_json

    mask = os.umask(0o022)
    try:
        path = dump_json(tmp_path / "m.json", {"a": 1})
    finally:
        os.umask(mask)
    assert stat.S_IMODE(path.stat().st_mode) == 0o644


def test_atomic_write_to_a_device_writes_through(tmp_path):
    import os

    from shinro_ctrl.files import atomic_write

    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    fd = os.open(fifo, os.O_RDONLY | os.O_NONBLOCK)  # a reader, so the writer does not block
    try:
        atomic_write(fifo, lambda f: f.write("hello"))
        assert os.read(fd, 100) == b"hello"
    finally:
        os.close(fd)
    assert not fifo.is_file() and fifo.exists()  # still a pipe, not replaced by a regular file


def test_a_scenario_that_fails_to_run_is_a_failed_row_not_an_abort(tmp_path):
    shutil.copy(regression_dir() / "cartpole_lqr.toml", tmp_path / "a_good.toml")
    shutil.copy(regression_dir() / "cartpole_lqr.baseline.json", tmp_path / "a_good.baseline.json")
    # hard |x| <= 1 cm with |F| <= 3 N from 0.3 rad cannot be met: MPCInfeasible while running
    (tmp_path / "b_infeasible.toml").write_text(
        '[plant]\ntype = "CartPole"\ndt = 0.02\n[controller]\ntype = "LinearMPC"\nhorizon = 20\n'
        "Q = [10, 1, 100, 1]\nR = [0.1]\nu_min = [-3.0]\nu_max = [3.0]\n"
        "x_min = [-0.01, -inf, -inf, -inf]\nx_max = [0.01, inf, inf, inf]\n"
        "[sim]\nduration = 1.0\ninitial_state = [0.0, 0.0, 0.3, 0.0]\n"
    )
    report = run_regression(tmp_path)
    assert "MPCInfeasible" in report.errors["b_infeasible (standalone)"] and not report.passed
    assert {c.scenario for c in report.checks} == {"a_good (standalone)"}
    res = run_cli("regress", str(tmp_path))
    assert res.returncode == 1 and "b_infeasible" in res.stderr and "FAILED to run" in res.stdout


# ------------------------------------------------------------ file safety (issue 14, items 1, 3-6, 23)
KILL_AFTER_COMMIT = """
import os, sys
from pathlib import Path
from shinro_ctrl import files
real_replace = os.replace
def die_after_commit(src, dst):
    real_replace(src, dst)
    if ".shinro-journal." in str(dst):
        os._exit(9)  # like SIGKILL: the set is committed, no target renamed, no clean-up runs
files.os.replace = die_after_commit
d = Path(sys.argv[1])
files.atomic_write_set({d / "a.baseline.json": "new a", d / "b.baseline.json": "new b"}, d)
"""


def test_update_killed_after_its_commit_point_is_completed_by_the_next_run(tmp_path):
    from shinro_ctrl import files

    for name in ("a", "b"):
        (tmp_path / f"{name}.baseline.json").write_text(f"old {name}")
    res = subprocess.run([sys.executable, "-c", KILL_AFTER_COMMIT, str(tmp_path)], capture_output=True, text=True)
    assert res.returncode == 9, res.stderr
    assert [(tmp_path / f"{n}.baseline.json").read_text() for n in "ab"] == ["old a", "old b"]  # nothing renamed
    assert files.recover_journals(tmp_path) == 1  # what the next regress does first: the set is completed
    assert [(tmp_path / f"{n}.baseline.json").read_text() for n in "ab"] == ["new a", "new b"]
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]


def test_failed_write_leaves_every_baseline_and_no_temporary(tmp_path):
    from shinro_ctrl import files

    a, b = tmp_path / "a.json", tmp_path / "sub" / "b.json"
    a.write_text("old a")
    (tmp_path / "sub").write_text("a file where the folder should be")
    with pytest.raises(OSError) as info:
        files.atomic_write_set({a: "new a", b: "new b"}, tmp_path)
    assert str(b) in str(info.value)
    assert a.read_text() == "old a" and sorted(p.name for p in tmp_path.iterdir()) == ["a.json", "sub"]


def test_regress_update_of_the_shipped_folder_named_explicitly_is_allowed_but_not_implicit():
    from shinro_ctrl.errors import InvalidArgument

    with pytest.raises(InvalidArgument, match="shipped baselines"):
        run_regression(update=True)


def test_report_hints_name_the_folder(tmp_path):
    from shinro_ctrl.regression import format_report

    shutil.copy(regression_dir() / "cartpole_lqr.toml", tmp_path)
    report = run_regression(tmp_path)
    assert report.missing and f"shinro-ctrl regress {tmp_path} --update" in format_report(report)


# ------------------------------------------------------------ undefined metrics
def _saturated_cartpole(tmp_path):
    """The regression cart-pole with |u| <= 1: the pole falls, the error never settles nor reaches 10 %."""
    text = (regression_dir() / "cartpole_lqr.toml").read_text()
    (tmp_path / "sat.toml").write_text(text.replace("R = [0.1]", "R = [0.1]\nu_min = [-1.0]\nu_max = [1.0]"))
    return tmp_path / "sat.toml"


def _finite_or_none(metrics):
    import math

    return all(v is None or isinstance(v, bool) or math.isfinite(v) for v in metrics.values())


def test_undefined_metrics_are_none_in_the_run_the_baseline_and_the_comparison(tmp_path):
    from shinro_ctrl.sim import RobotSim, format_metrics

    path = _saturated_cartpole(tmp_path)
    result = RobotSim.from_config(path).run(progress=False)
    assert result.metrics["settling_time"] is None and result.metrics["rise_time"] is None
    assert _finite_or_none(result.metrics), result.metrics
    text = format_metrics(result.metrics)
    assert "never" in next(line for line in text.splitlines() if "settling_time" in line)
    assert "nan" not in text.lower()
    # the baseline stores null, and the run passes against its own baseline (it failed forever with NaN)
    report = run_regression(path, update=True)
    assert report.updated and not report.errors
    stored = json.loads((tmp_path / "sat.baseline.json").read_text())["metrics"]
    assert stored["settling_time"] is None and stored["rise_time"] is None
    assert "NaN" not in (tmp_path / "sat.baseline.json").read_text()
    assert "Infinity" not in (tmp_path / "sat.baseline.json").read_text()
    report = run_regression(path)
    assert report.passed, [c.describe() for c in report.failures]


@pytest.mark.parametrize(
    "now,base,ok,needle",
    [
        (None, None, True, ""),
        (None, 1.5, False, "never happens in this run but is 1.5 in the baseline"),
        (1.5, None, False, "never happened in the baseline but is 1.5 in this run"),
        (1.5, 1.5, True, ""),
    ],
)
def test_none_matches_only_none(now, base, ok, needle):
    (check,) = compare_metrics("s", {"settling_time": now}, {"settling_time": base})
    assert check.passed is ok
    assert needle in check.describe()


def test_baselines_refuse_nan_and_infinity_but_read_the_old_never(tmp_path):
    from shinro_ctrl.errors import ConfigError

    p = tmp_path / "b.baseline.json"
    p.write_text(json.dumps({"format": 1, "metrics": {"settling_time": "inf", "rms_error": 1.0}}))
    assert read_baseline(p) == {"settling_time": None, "rms_error": 1.0}
    for bad in ('"inf"', "NaN", "Infinity", '"-inf"'):
        p.write_text('{"format": 1, "metrics": {"rms_error": ' + bad + "}}")
        with pytest.raises(ConfigError, match="finite number or null"):
            read_baseline(p)


def test_empty_and_event_free_responses_give_none_not_nan():
    import numpy as np

    from shinro_ctrl.analysis import step_metrics
    from shinro_ctrl.sim import compute_metrics

    # a single sample: no input, no controller call
    m = compute_metrics(np.zeros(1), np.ones((1, 2)), np.zeros((0, 1)), np.zeros((1, 2)), tracked=[0, 1])
    assert m["max_abs_input"] is None and m["solve_time_median_s"] is None and _finite_or_none(m)
    # a response that moves away from its target: neither 10 % nor 90 % is reached, nor the band
    t = np.linspace(0.0, 1.0, 11)
    s = step_metrics(t, 1.0 + t, initial=1.0, final=0.0, target=0.0)
    assert s.rise_time is None and s.settling_time is None
    # 10 % reached but not 90 %: rise time undefined (was inf - finite = inf, or inf - inf = NaN)
    s = step_metrics(t, 1.0 - 0.5 * t, initial=1.0, final=0.0, target=0.0)
    assert s.rise_time is None and s.overshoot == 0.0


# ------------------------------------------------------------ the stable flag
def test_every_run_is_flagged_stable_or_not_and_regress_fails_a_run_that_lost_it(tmp_path):
    from shinro_ctrl.regression import format_report
    from shinro_ctrl.sim import RobotSim, format_metrics

    good = RobotSim.from_config(regression_dir() / "cartpole_lqr.toml").run(progress=False)
    assert good.metrics["stable"] is True
    path = _saturated_cartpole(tmp_path)  # the pole falls: final error 13
    bad = RobotSim.from_config(path).run(progress=False)
    assert bad.metrics["stable"] is False and bad.metrics["final_error"] > 1.0
    assert any(line.split() == ["stable", "no"] for line in format_metrics(bad.metrics).splitlines())
    # a baseline recorded from the stable run fails the falling one, with one line naming the flag
    (tmp_path / "sat.baseline.json").write_text(baseline_text_of(good, "sat"))
    report = run_regression(path)
    flag = [c for c in report.failures if c.metric == "stable"]
    assert len(flag) == 1 and flag[0].baseline is True and flag[0].now is False
    lines = [line for line in format_report(report).splitlines() if line.startswith("FAIL") and "stable" in line]
    assert len(lines) == 1 and "the baseline run was stable, this run is not" in lines[0]


def baseline_text_of(result, name):
    from shinro_ctrl.regression import baseline_text

    result.scenario = name
    return baseline_text(result)


def test_a_diverging_acrobot_is_not_stable():
    # the reported case: an acrobot LQR that ends hundreds of radians away without a flag
    from shinro_ctrl.sim import RobotSim

    up = [3.141592653589793, 3.141592653589793, 0.0, 0.0]
    doc = {
        "plant": {"type": "DoublePendulum", "dt": 0.01},
        "controller": {
            "type": "LQR",
            "Q": [100, 100, 1, 1],
            "R": [1, 1],
            "x0": up,
            "u_min": [-0.05, -0.05],
            "u_max": [0.05, 0.05],
        },
        "sim": {"duration": 3.0, "initial_state": [up[0] + 0.3, up[1], 0.0, 0.0]},
    }
    result = RobotSim.from_config(doc).run(progress=False)
    assert result.metrics["final_error"] > 0.5 and result.metrics["stable"] is False


def test_the_sweep_summary_counts_the_unstable_samples():
    from shinro_ctrl.sweep import SweepResult, SweepRow

    rows = [
        SweepRow(0, {"plant.m": 1.0}, {"final_error": 0.0}, True),
        SweepRow(1, {"plant.m": 2.0}, {"final_error": 5.0}, False),
        SweepRow(2, {"plant.m": 3.0}, {}, False, error="SimulationDiverged: x"),
    ]
    res = SweepResult("s", "standalone", {"plant.m": (1.0, 3.0)}, rows, "serial", 1, 0, 3, True, 0.1)
    assert "stable: 1/3" in res.summary() and "unstable: 2 (1 raised)" in res.summary()


# ------------------------------------------------------------ the metric registry
def test_every_metric_of_a_run_is_in_the_one_registry_and_every_list_reads_it():
    import math

    from shinro_ctrl import config, regression, sweep
    from shinro_ctrl.sim import RobotSim
    from shinro_ctrl.sim import metrics as reg

    result = RobotSim.from_config(regression_dir() / "cartpole_lqg.toml").run(progress=False)
    for name, value in result.metrics.items():
        base = (
            name
            if name in reg.METRIC_REGISTRY
            else next(m for m in (*reg.OUTPUT_FEEDBACK_METRICS, *reg.PER_INPUT_METRICS) if name.startswith(m))
        )
        kind = reg.METRIC_REGISTRY[base].kind
        if kind == "flag":
            assert isinstance(value, bool), name
        elif kind == "count":
            assert isinstance(value, int) and not isinstance(value, bool), name
        else:
            assert value is None or (isinstance(value, float) and math.isfinite(value)), (name, value)
    assert set(reg.METRICS) | set(reg.RESPONSE_METRICS) | set(reg.FLAG_METRICS) | set(
        reg.OUTPUT_FEEDBACK_METRICS
    ) | set(reg.PER_INPUT_METRICS) | set(reg.BALANCE_METRICS) == set(reg.METRIC_REGISTRY)
    assert not hasattr(config, "METRICS")  # one registry: the scenario layer does not re-export it
    assert sweep.WALL_CLOCK_METRICS is reg.WALL_CLOCK_METRICS
    assert set(sweep.TABLE_METRICS) == set(reg.METRICS) - set(reg.WALL_CLOCK_METRICS)
    assert regression.WALL_CLOCK_METRICS is reg.WALL_CLOCK_METRICS
    assert reg.NEVER_METRICS == ("settling_time", "rise_time") and reg.FLAG_METRICS == ("stable",)
    # the printed units come from the registry
    text = reg.format_metrics({"settling_time": 1.0, "overshoot": 2.0, "constraint_violations": 3})
    assert text.splitlines()[0].endswith(" s") and text.splitlines()[1].endswith(" %")
    assert text.splitlines()[2].endswith("3")
