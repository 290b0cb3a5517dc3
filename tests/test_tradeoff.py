"""LQR weight trade-off: monotone in R on the cart-pole, one CSV row per point, same table serial or pooled."""

from __future__ import annotations

import csv
import json
import math

import numpy as np
import pytest

from shinro_ctrl.analysis.tradeoff import COLUMNS, parse_tradeoff, run_tradeoff
from shinro_ctrl.cli import main
from shinro_ctrl.errors import InvalidArgument


@pytest.fixture(scope="module")
def pooled(tmp_path_factory):
    out = tmp_path_factory.mktemp("tradeoff")
    return run_tradeoff("cartpole_lqr.toml", "R", 1e-2, 1e2, points=5, workers=2, out=out), out


def test_cheaper_input_tracks_better(pooled):
    res, _ = pooled
    rms, peak = res.column("rms_error"), res.column("max_abs_input")
    assert not any(res.errors)
    # values increase: as R decreases (walking the table backwards) RMS is non-increasing, peak input non-decreasing
    assert np.all(np.diff(rms) >= -1e-12 * rms[:-1])
    assert np.all(np.diff(peak) <= 1e-12 * peak[:-1])
    assert rms[0] < rms[-1] and peak[0] > peak[-1]  # and it really moves
    assert np.all(res.column("zeta_min") > 0) and np.all(res.column("disk_margin") > 0)


def test_outputs_one_row_per_point(pooled):
    res, out = pooled
    with open(out / "tradeoff.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == 5
    assert list(rows[0]) == ["R", *COLUMNS, "error"]
    np.testing.assert_allclose([float(r["R"]) for r in rows], np.logspace(-2, 2, 5))
    data = json.loads((out / "tradeoff.json").read_text())
    assert len(data["rows"]) == 5 and data["current"]["R"] == 1.0
    assert (out / "tradeoff.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    # the scenario's own design (R x 1) lies between the 1e-0.x neighbours of the sweep
    assert res.column("rms_error")[1] <= res.current["rms_error"] <= res.column("rms_error")[3]


def test_serial_equals_pool(pooled):
    res, _ = pooled
    serial = run_tradeoff("cartpole_lqr.toml", "R", 1e-2, 1e2, points=5, workers=1)
    for c in COLUMNS:
        np.testing.assert_array_equal(serial.column(c), res.column(c))


def test_q_entry_by_state_name_and_mujoco_loop():
    res = run_tradeoff("cartpole_lqr.toml", "Q.theta", 10.0, 1000.0, points=2, workers=1, engine="mujoco")
    assert res.engine == "mujoco" and res.current_value == 100.0
    assert np.all(np.isfinite(res.column("rms_error")))
    # a heavier angle weight brings the pole back faster: the pole error dominates the RMS
    assert res.column("rise_time")[1] < res.column("rise_time")[0]


@pytest.mark.parametrize("text", ["R", "R=1:0.1", "R=0:1", "S=1:2", "Q[x]=1:2", "R=a:b", "R=1:inf"])
def test_parse_rejects(text):
    with pytest.raises(InvalidArgument):
        parse_tradeoff(text)


def test_bad_keys_fail_before_work(tmp_path):
    with pytest.raises(InvalidArgument, match="unknown state"):
        run_tradeoff("cartpole_lqr.toml", "Q.thetta", 1, 2, points=2, workers=1)
    with pytest.raises(InvalidArgument, match="out of range"):
        run_tradeoff("cartpole_lqr.toml", "R[3]", 1, 2, points=2, workers=1)
    with pytest.raises(InvalidArgument, match="points"):
        run_tradeoff("cartpole_lqr.toml", "R", 1, 2, points=1, workers=1)


@pytest.mark.parametrize(
    "argv, message",
    [
        (["design", "lqr", "cartpole_lqr.toml", "--tradeoff", "R=1:10"], "--out"),
        (["design", "lqr", "cartpole_lqr.toml", "--tradeoff", "R=10:1", "--out", "x"], "LO < HI"),
        (["design", "mpc", "cartpole_mpc.toml", "--tradeoff", "R=1:10", "--out", "x"], "design lqr"),
    ],
)
def test_cli_errors_are_one_line(argv, message, capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert message in err and len(err.splitlines()) == 1
    assert not (tmp_path / "x").exists()


def test_extreme_weights_give_finite_rows():
    # a very cheap input still has a stabilizing Riccati solution: finite rows, empty error column
    res = run_tradeoff("cartpole_lqr.toml", "R", 1e-6, 1e-5, points=2, workers=1)
    assert all(e == "" for e in res.errors)
    assert all(math.isfinite(v) for v in res.column("disk_margin"))
