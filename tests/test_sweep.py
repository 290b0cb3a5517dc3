"""Robustness sweeps: executors agree, failures are recorded, files and CLI work."""

from __future__ import annotations

import csv
import ctypes
import json
import math

import numpy as np
import pytest

from shinro_ctrl.errors import ConfigError
from shinro_ctrl.sim import RobotSim
from shinro_ctrl.sim.metrics import METRICS
from shinro_ctrl.sweep import (
    TABLE_METRICS,
    WALL_CLOCK_METRICS,
    draw_samples,
    parse_param,
    parse_params,
    perturbed_sim,
    run_sweep,
)
from shinro_ctrl.sweep.batch import batch_unsupported_reason, lqr_batch_rollout
from tests.cli_runner import cli

CARTPOLE = "cartpole_lqr"
# Around the nominal (cart 0.5 kg, pole 0.1 kg at 0.5 m): heavy carts and long poles defeat the fixed LQR
# (a slow growing oscillation, or a divergence out of the float range).
RANGES = {"plant.cart_mass": (0.2, 4.0), "plant.pole_length": (0.2, 1.4)}


def _same(a: float, b: float, rtol: float) -> bool:
    if math.isnan(a) or math.isnan(b):
        return math.isnan(a) and math.isnan(b)
    if math.isinf(a) or math.isinf(b):
        return a == b
    return abs(a - b) <= rtol * max(abs(a), abs(b)) + 1e-300


def _csv(result, tmp_path, name: str) -> str:
    return result.to_csv(tmp_path / f"{name}.csv").read_text()


def assert_tables_close(a, b, *, rtol: float) -> None:
    """Same parameters, verdicts and errors; every table metric within ``rtol`` (failed runs: both NaN).

    With ``rtol == 0`` the tables must be identical, error messages included;
    otherwise (batch rollout against the per-sample loop) only the presence
    of an error must agree, since the two paths word a divergence differently.
    """
    assert len(a.rows) == len(b.rows)
    assert a.columns() == b.columns()
    for ra, rb in zip(a.rows, b.rows, strict=True):
        assert ra.index == rb.index
        assert ra.params == rb.params
        assert ra.stable == rb.stable, (ra, rb)
        if rtol == 0:
            assert ra.error == rb.error
        assert (ra.error is None) == (rb.error is None), (ra.error, rb.error)
        assert set(ra.metrics) == set(rb.metrics) == set(TABLE_METRICS)
        if rtol and not ra.stable and min(ra.metrics["max_error"], rb.metrics["max_error"]) > 1e3:
            # A run growing without bound (error > 1e3): the batch (numpy arrays) and the per-sample loop
            # (Python floats) round differently in the last bit, and the unstable loop amplifies that into
            # another trajectory (seen: rms 2e8 vs 2e55); only the verdict (compared above) is defined.
            continue
        for m in TABLE_METRICS:
            assert _same(ra.metrics[m], rb.metrics[m], rtol), (ra.index, m, ra.metrics[m], rb.metrics[m])


@pytest.fixture(scope="module")
def dask_cluster():
    """Two single-threaded Dask workers, closed after the module.

    Thread workers in this process (``processes=False``): a process cluster
    re-imports the package in each worker (about 10 s on a busy machine);
    pickling of the jobs is covered by the process-pool sweep.
    """
    distributed = pytest.importorskip("dask.distributed")
    cluster = distributed.LocalCluster(
        n_workers=2, threads_per_worker=1, processes=False, dashboard_address=None, silence_logs=40
    )
    try:
        yield cluster
    finally:
        cluster.close()


# -------------------------------------------------------------------- spec
def test_parse_param():
    assert parse_param("plant.pole_mass=0.05:0.5") == ("plant.pole_mass", (0.05, 0.5))
    assert parse_param("plant.damping=-1e-3:2e-3") == ("plant.damping", (-1e-3, 2e-3))
    assert parse_param("plant.damping=0.1:0.1") == ("plant.damping", (0.1, 0.1))
    with pytest.raises(ConfigError, match="LO must be <= HI"):
        parse_param("plant.pole_mass=0.5:0.05")
    with pytest.raises(ConfigError, match="finite"):
        parse_param("plant.pole_mass=0:inf")
    with pytest.raises(ConfigError, match="finite"):
        parse_param("plant.pole_mass=nan:1")
    with pytest.raises(ConfigError, match="KEY=LO:HI"):
        parse_param("plant.pole_mass")
    with pytest.raises(ConfigError, match="numbers"):
        parse_param("plant.pole_mass=a:b")
    with pytest.raises(ConfigError, match="twice"):
        parse_params(["plant.pole_mass=0:1", "plant.pole_mass=1:2"])


def test_draw_samples_seeded_uniform_and_grid():
    ranges = {"a": (0.0, 1.0), "b": (-2.0, 2.0)}
    mc = draw_samples(ranges, 50, seed=7)
    assert mc.shape == (50, 2)
    np.testing.assert_array_equal(mc, draw_samples(ranges, 50, seed=7))
    assert not np.array_equal(mc, draw_samples(ranges, 50, seed=8))
    assert mc[:, 0].min() >= 0 and mc[:, 0].max() < 1 and mc[:, 1].min() >= -2 and mc[:, 1].max() < 2
    grid = draw_samples(ranges, 3, grid=True)
    np.testing.assert_allclose(grid[:, 0], [0, 0, 0, 0.5, 0.5, 0.5, 1, 1, 1])
    np.testing.assert_allclose(grid[:, 1], [-2, 0, 2] * 3)


def test_bad_specs_raise_config_error():
    with pytest.raises(ConfigError, match=r"did you mean 'plant\.pole_mass'"):
        run_sweep(CARTPOLE, {"plant.pole_mas": (0.1, 0.2)}, samples=2)
    with pytest.raises(ConfigError, match=r"only \[plant\] parameters.*valid: plant\.cart_mass"):
        run_sweep(CARTPOLE, {"controller.R": (0.1, 0.2)}, samples=2)
    with pytest.raises(ConfigError, match="LO must be <= HI"):
        run_sweep(CARTPOLE, {"plant.pole_mass": (0.2, 0.1)}, samples=2)
    with pytest.raises(ConfigError, match="finite"):
        run_sweep(CARTPOLE, {"plant.pole_mass": (0.1, math.nan)}, samples=2)
    with pytest.raises(ConfigError, match="samples"):
        run_sweep(CARTPOLE, {"plant.pole_mass": (0.1, 0.2)}, samples=0)
    with pytest.raises(ConfigError, match="unknown sweep method"):
        run_sweep(CARTPOLE, {"plant.pole_mass": (0.1, 0.2)}, samples=2, method="threads")


# --------------------------------------------------------------- executors
def test_pool_dask_serial_and_batch_give_the_same_table(dask_cluster, tmp_path):
    kw = {"samples": 12, "seed": 3, "duration": 3.0}
    serial = run_sweep(CARTPOLE, RANGES, method="serial", **kw)
    pool = run_sweep(CARTPOLE, RANGES, method="pool", workers=2, **kw)
    dask = run_sweep(CARTPOLE, RANGES, scheduler=dask_cluster.scheduler_address, **kw)
    batch = run_sweep(CARTPOLE, RANGES, method="auto", **kw)
    assert (serial.method, pool.method, dask.method, batch.method) == ("serial", "pool", "dask", "batch")
    assert pool.workers == 2 and dask.workers == 2
    # The range really holds both kinds of plants, and a divergence that raised.
    assert 0 < serial.stable.sum() < len(serial.rows)
    assert any(r.error for r in serial.rows)
    assert any(not r.stable and r.error is None for r in serial.rows)
    # Per-sample executors run the same code on the same rows: identical tables, the CSV files byte for byte.
    assert_tables_close(pool, serial, rtol=0)
    assert_tables_close(dask, serial, rtol=0)
    assert _csv(pool, tmp_path, "pool") == _csv(serial, tmp_path, "serial") == _csv(dask, tmp_path, "dask")
    assert json.dumps(pool.to_dict()["rows"]) == json.dumps(serial.to_dict()["rows"])
    # Wall-clock timing is kept beside the table, per sample and as the sweep's median.
    ran = [r for r in serial.rows if r.error is None]
    assert all(r.timing["solve_time_median_s"] > 0 for r in ran)
    assert all("solve_time_median_s" not in r.metrics for r in serial.rows)
    assert serial.timings["solve_time_median_s"] > 0
    # The vectorized rollout agrees to floating-point tolerance.
    assert_tables_close(batch, serial, rtol=1e-9)


@pytest.mark.parametrize(
    ("config", "ranges"),
    [
        ("pendulum_lqr", {"plant.mass": (0.05, 1.5), "plant.damping": (0.0, 0.05)}),
        ("double_pendulum_lqr", {"plant.mass_bottom": (0.05, 0.2), "plant.length_top": (0.4, 0.6)}),
    ],
)
def test_batch_matches_the_per_sample_loop_for_the_pendulum_family(config, ranges):
    kw = {"samples": 6, "seed": 1, "duration": 1.0}
    batch = run_sweep(config, ranges, method="batch", **kw)
    serial = run_sweep(config, ranges, method="serial", **kw)
    assert batch.method == "batch" and not batch.notes
    assert_tables_close(batch, serial, rtol=1e-9)


def test_batch_rollout_isolates_non_finite_rows():
    sim = RobotSim.from_config(CARTPOLE)
    p = sim.plant.params()
    params = {k: np.full(3, v) for k, v in p.items()}
    params["pole_length"] = np.array([0.5, 50.0, 0.5])  # the middle instance falls and diverges
    params["cart_mass"] = np.array([0.5, 0.5, 0.6])
    roll = lqr_batch_rollout(
        sim.plant, sim.controller, params=params, x0=sim.initial_state, ref=np.zeros(4), steps=1500, tracked=[0, 2]
    )
    assert roll.finite.tolist() == [True, False, True]
    assert roll.diverged_step[1] > 0 and roll.diverged_step[0] == roll.diverged_step[2] == -1
    assert math.isnan(roll.metrics["rms_error"][1])
    nominal = sim.run(15.0).metrics
    assert roll.metrics["rms_error"][0] == pytest.approx(nominal["rms_error"], rel=1e-9)
    assert np.isfinite(roll.metrics["rms_error"][2])


def test_batch_not_supported_reasons():
    quad = RobotSim.from_config("quadrotor_lqr")
    assert "Quadrotor" in batch_unsupported_reason(quad.plant, quad.controller)
    res = run_sweep("quadrotor_lqr", {"plant.mass": (0.45, 0.55)}, samples=2, method="batch", duration=0.2)
    assert res.method == "serial"
    assert res.notes and "batch rollout not used" in res.notes[0]


# -------------------------------------------------------------- failures
def test_invalid_and_unstable_samples_are_recorded_not_fatal(tmp_path):
    # pole_mass -0.3 and 0 are invalid (the constructor rejects them); heavy carts are destabilized.
    ranges = {"plant.pole_mass": (-0.3, 0.3), "plant.cart_mass": (0.5, 4.0)}
    for method in ("serial", "batch"):
        res = run_sweep(CARTPOLE, ranges, samples=3, grid=True, method=method, duration=3.0, out=tmp_path / method)
        assert res.method == method and len(res.rows) == 9
        bad = [r for r in res.rows if r.params["plant.pole_mass"] <= 0]
        assert len(bad) == 6
        for r in bad:
            assert not r.stable
            assert r.error.startswith("ConfigError: [plant] CartPole: pole_mass must be positive")
            assert all(math.isnan(v) for v in r.metrics.values())
        good = [r for r in res.rows if r.params["plant.pole_mass"] > 0]
        nominalish = [r for r in good if r.params["plant.cart_mass"] == 0.5]
        heavy = [r for r in good if r.params["plant.cart_mass"] == 4.0]
        assert all(r.stable and r.error is None for r in nominalish)
        assert all(not r.stable for r in heavy)
        assert all(r.metrics["final_error"] >= res.stable_tol or r.error for r in heavy)


def test_stable_tol_is_the_rule():
    kw = {"samples": 3, "grid": True, "duration": 3.0, "method": "batch"}
    loose = run_sweep(CARTPOLE, {"plant.cart_mass": (0.5, 0.5)}, stable_tol=1.0, **kw)
    assert loose.stable_tol == 1.0 and loose.stable.all()
    final = loose.rows[0].metrics["final_error"]
    strict = run_sweep(CARTPOLE, {"plant.cart_mass": (0.5, 0.5)}, stable_tol=final / 2, **kw)
    assert not strict.stable.any()
    default = run_sweep(CARTPOLE, {"plant.cart_mass": (0.5, 0.5)}, **kw)
    assert default.stable_tol == pytest.approx(10 * 0.01)


# -------------------------------------------------------------- MuJoCo loop
def test_mujoco_sweep_rebuilds_the_engine_for_each_plant(capfd, tmp_path, monkeypatch):
    mujoco = pytest.importorskip("mujoco")
    from shinro_ctrl.engine import take_warning_messages

    monkeypatch.chdir(tmp_path)
    nominal = RobotSim.from_config("cartpole_lqr_mujoco")
    sim = perturbed_sim(nominal, {"pole_mass": 0.3})
    assert sim.controller is nominal.controller
    assert sim.engine is not nominal.engine and nominal.plant.params()["pole_mass"] == 0.1
    assert sim.engine.model.body("pole").mass[0] == pytest.approx(0.3, rel=1e-6)
    assert nominal.engine.model.body("pole").mass[0] == pytest.approx(0.1, rel=1e-6)
    res = run_sweep("cartpole_lqr_mujoco", {"plant.pole_length": (0.5, 1.3)}, samples=2, grid=True, duration=3.0)
    assert res.loop == "mujoco" and res.method == "serial"
    ok, diverged = res.rows
    assert ok.stable and ok.error is None
    assert not diverged.stable and diverged.error.startswith("SimulationDiverged: cartpole_lqr_mujoco (mujoco) at t =")
    # MuJoCo's own warning text is quoted in the table, never printed (the engine records it).
    assert 'MuJoCo: "Nan, Inf or huge value' in diverged.error
    ctypes.CDLL(None).fflush(None)
    out, err = capfd.readouterr()
    assert "WARNING" not in out and "WARNING" not in err
    handler = mujoco.get_mju_user_warning()  # still the engine's: a warning is recorded, not printed
    take_warning_messages()
    handler("probe  warning")
    assert take_warning_messages() == ["probe warning"]
    assert not (tmp_path / "MUJOCO_LOG.TXT").exists()


# --------------------------------------------------------------- outputs
def test_files_csv_json_png(tmp_path):
    res = run_sweep(CARTPOLE, RANGES, samples=10, seed=5, duration=2.0, out=tmp_path, progress=False)
    assert set(res.files) == {"csv", "json", "png"}
    with open(tmp_path / "sweep.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == 10
    assert list(rows[0]) == ["index", *RANGES, *TABLE_METRICS, "stable", "error"]
    assert set(TABLE_METRICS) | set(WALL_CLOCK_METRICS) == set(METRICS) and "solve_time_median_s" not in rows[0]
    for row, r in zip(rows, res.rows, strict=True):
        assert float(row["plant.cart_mass"]) == r.params["plant.cart_mass"]  # repr round-trips
        assert row["stable"] == ("yes" if r.stable else "no")
        assert row["error"] == (r.error or "")
    doc = json.loads((tmp_path / "sweep.json").read_text())
    assert doc["seed"] == 5 and doc["method"] == "batch" and len(doc["rows"]) == 10
    assert doc["ranges"] == {k: list(v) for k, v in RANGES.items()}
    assert "final_error <" in doc["stable_rule"]
    assert all(set(r["metrics"]) == set(TABLE_METRICS) for r in doc["rows"])
    per_sample = doc["timings"]["per_sample"]["solve_time_median_s"]
    expected = [r.timing["solve_time_median_s"] for r in res.rows]
    assert per_sample == [None if math.isnan(v) else v for v in expected]  # JSON null for a failed run
    np.testing.assert_array_equal(res.metric_values("solve_time_median_s"), expected)
    assert (tmp_path / "sweep.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    one = run_sweep(CARTPOLE, {"plant.pole_length": (0.2, 1.4)}, samples=8, grid=True, duration=2.0)
    assert one.plot(tmp_path / "one.png").stat().st_size > 0
    assert "stable" in one.summary()


def test_progress_callback_reaches_the_total():
    seen = []
    run_sweep(CARTPOLE, RANGES, samples=5, duration=0.5, method="serial", progress=lambda d, n: seen.append((d, n)))
    assert seen[-1] == (5, 5)


# ------------------------------------------------------------------- CLI
_cli = cli  # the command in process (tests.cli_runner): same status and output, no interpreter start-up each


def test_cli_writes_table_json_and_plot(tmp_path):
    out = tmp_path / "sw"
    proc = _cli(
        "sweep", CARTPOLE, "--param", "plant.pole_mass=0.05:0.5", "--param", "plant.cart_mass=0.3:3",
        "--samples", "8", "--seed", "2", "--out", str(out),
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    assert "8 samples" in proc.stdout and "stable:" in proc.stdout
    for name in ("sweep.csv", "sweep.json", "sweep.png"):
        assert (out / name).stat().st_size > 0


@pytest.mark.parametrize(
    ("param", "expected"),
    [
        ("plant.pole_mass=0.5:0.1", "LO must be <= HI"),
        ("plant.pole_mas=0.1:0.5", "did you mean 'plant.pole_mass'"),
        ("sim.duration=1:2", "only [plant] parameters"),
        ("plant.pole_mass=-1:-0.5", "holds no valid plant value: [plant] CartPole: pole_mass must be positive"),
        ("plant.pole_mass=0:0", "holds no valid plant value: [plant] CartPole: pole_mass must be positive"),
        ("plant.cart_mass=-3:-2", "holds no valid plant value: [plant] CartPole: cart_mass must be positive"),
    ],
)
def test_cli_bad_sweeps_exit_2_with_one_line(tmp_path, param, expected):
    proc = _cli("sweep", CARTPOLE, "--param", param, "--samples", "2", "--out", str(tmp_path))
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and expected in lines[0], proc.stderr


def test_controllers_with_memory_do_not_carry_state_between_samples():
    # LinearMPC keeps OSQP state (adaptive rho) across solves; each sample must start afresh,
    # or a row would depend on which rows its worker ran before it.
    kw = {"grid": True, "duration": 0.5, "method": "serial"}  # the heavy carts: certified infeasible at ~0.4 s
    together = run_sweep("cartpole_mpc", {"plant.cart_mass": (0.2, 6.0)}, samples=3, **kw)
    assert any(r.error and "MPCInfeasible" in r.error for r in together.rows)
    for row in together.rows:
        v = row.params["plant.cart_mass"]
        alone = run_sweep("cartpole_mpc", {"plant.cart_mass": (v, v)}, samples=1, **kw)
        assert alone.rows[0].error == row.error
        for m in TABLE_METRICS:
            assert _same(alone.rows[0].metrics[m], row.metrics[m], 0.0), m


@pytest.mark.parametrize("key", ["plant.pole_mass", "plant.cart_mass", "plant.pole_length"])
def test_a_range_with_no_valid_value_is_refused_before_any_sample_runs(key):
    with pytest.raises(ConfigError, match=rf"sweep range {key} = -1:-0.1 holds no valid plant value"):
        run_sweep("cartpole_lqr", {key: (-1.0, -0.1)}, samples=2, method="serial")


def test_a_range_with_one_invalid_end_runs_and_notes_it():
    res = run_sweep("cartpole_lqr", {"plant.pole_mass": (0.0, 0.3)}, samples=2, grid=True, method="serial", duration=1)
    assert "plant.pole_mass = 0 is not a valid plant value: samples there are recorded as invalid" in res.notes
    assert [r.error is not None for r in res.rows] == [True, False]


def test_a_constant_parameter_sweeps_one_value_without_a_warning(tmp_path):
    """LO = HI is a valid (degenerate) range: every sample has that value and the plot keeps automatic limits."""
    proc = _cli("sweep", CARTPOLE, "--param", "plant.pole_mass=0.2:0.2", "--samples", "2", "--out", str(tmp_path / "s"))
    assert proc.returncode == 0 and "warning" not in proc.stderr, proc.stderr
    rows = list(csv.DictReader((tmp_path / "s" / "sweep.csv").open()))
    assert [float(r["plant.pole_mass"]) for r in rows] == [0.2, 0.2]
