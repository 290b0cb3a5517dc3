"""C export (issue 27): the exported folders build with gcc, use no heap, and reproduce the Python controller.

Each module-scoped fixture exports one scenario once (``-O1``, untimed) and the tests read that folder. The
reference is the Python controller's own closed-loop recording in both loops; the test program compares
every recorded step to 1e-9.
"""

from __future__ import annotations

import filecmp
import shutil
import subprocess
import tomllib
from pathlib import Path

import numpy as np
import pytest

from shinro_ctrl.errors import ExportError, InvalidArgument, NonFiniteError
from shinro_ctrl.export.build import heap_symbols, make
from shinro_ctrl.export.pipeline import export_scenario
from shinro_ctrl.resources import config_path

pytestmark = pytest.mark.skipif(shutil.which("gcc") is None or shutil.which("make") is None, reason="needs gcc")


def _export(tmp_path_factory: pytest.TempPathFactory, config: str | Path, **kw: object):
    out = tmp_path_factory.mktemp("export") / Path(str(config)).stem
    return export_scenario(config, out, cflags="-O1", time_step=False, **kw)


@pytest.fixture(scope="module")
def lqr(tmp_path_factory):
    """The regression cart-pole LQR, exported once (``regress`` holds its exported run to the Python baseline)."""
    return _export(tmp_path_factory, config_path("regression/cartpole_lqr.toml"))


def _verified(rep, loops=("standalone", "mujoco")) -> None:
    b = rep.build
    assert b is not None and b.ok, b.summary()
    assert b.steps >= 1000 and set(loops) <= set(rep.steps) and b.steps == sum(rep.steps.values())
    assert b.max_rel_err <= 1e-9 and b.disagreements == 0 and b.errors == 0 and not b.heap


def test_cartpole_lqr_exports_a_complete_folder_that_reproduces_python(lqr):
    _verified(lqr)
    names = set(lqr.files)
    for f in ("cartpole_lqr.h", "cartpole_lqr.c", "cartpole_lqr_test.c", "cartpole_lqr_data.txt", "Makefile"):
        assert f in names
    assert {"CMakeLists.txt", "README.md", "export.json", "scenario.toml"} <= names
    header = (lqr.out / "cartpole_lqr.h").read_text()
    for api in (
        "cartpole_lqr_workspace;",
        "int cartpole_lqr_init(",
        "int cartpole_lqr_reset(",
        "int cartpole_lqr_set_reference(",
        "int cartpole_lqr_step(",
        "CARTPOLE_LQR_INPUT_CLAMPED",
        "CARTPOLE_LQR_NONFINITE_MEASUREMENT",
    ):
        assert api in header, api
    # the gain is in the C to the last bit: parse the table back
    text = (lqr.out / "cartpole_lqr_ctl.c").read_text()
    body = text.split("cartpole_lqr_ctl_K[4] = {", 1)[1].split("}", 1)[0]
    from shinro_ctrl.sim import RobotSim

    K = RobotSim.from_config(config_path("regression/cartpole_lqr.toml")).controller.K
    assert np.array_equal(np.array([float(v) for v in body.replace("\n", " ").split(",")]), K.reshape(-1))


def test_reexport_is_byte_identical_no_heap_and_a_changed_scenario_leaves_stale_data_refused(lqr, tmp_path):
    again = export_scenario(config_path("regression/cartpole_lqr.toml"), tmp_path / "again", verify=False)
    cmp = filecmp.dircmp(lqr.out, again.out)
    assert sorted(cmp.same_files) == sorted(lqr.files) and not cmp.diff_files and not cmp.left_only
    for f in lqr.files:
        assert (lqr.out / f).read_bytes() == (again.out / f).read_bytes(), f
    manifest = (lqr.out / "export.json").read_text()
    assert '"casadi"' in manifest and '"numpy"' in manifest and '"sha256"' in manifest
    # the scenario changes (another R), is exported again: its data in the old folder is refused as stale
    doc = tmp_path / "changed.toml"
    doc.write_text(config_path("regression/cartpole_lqr.toml").read_text().replace("R = [0.1]", "R = [0.2]"))
    changed = export_scenario(doc, tmp_path / "changed", name="cartpole_lqr", verify=False)
    work = tmp_path / "stale"
    shutil.copytree(lqr.out, work)
    make(work, "all", cflags="-O1")
    objs = sorted(p for p in work.glob("*.o"))  # the controller's objects (the test program links to an executable)
    assert len(objs) == 3 and heap_symbols(objs) == ()
    assert "malloc" in heap_symbols([work / "cartpole_lqr_test"])  # the test program may use the heap: nm sees it
    shutil.copy(changed.out / "cartpole_lqr_data.txt", work / "cartpole_lqr_data.txt")
    proc = subprocess.run(["./cartpole_lqr_test", "cartpole_lqr_data.txt"], cwd=work, capture_output=True, text=True)
    assert proc.returncode == 2 and "stale" in proc.stderr
    shutil.copy(lqr.out / "cartpole_lqr_data.txt", work / "cartpole_lqr_data.txt")  # its own data passes
    assert subprocess.run(["./cartpole_lqr_test", "cartpole_lqr_data.txt"], cwd=work).returncode == 0


def test_sil_load_runs_the_exported_code_and_regress_holds_it_to_the_python_baseline(lqr, tmp_path):
    from shinro_ctrl.export import load
    from shinro_ctrl.regression import run_regression
    from shinro_ctrl.sim import RobotSim

    src = config_path("regression/cartpole_lqr.toml")
    folder = lqr.out
    doc = tomllib.loads(src.read_text())
    py = RobotSim.from_config(doc).run()
    doc["controller"] = {"type": "Exported", "path": str(folder)}
    sil = RobotSim.from_config(doc).run()
    for key, value in py.metrics.items():
        if key != "solve_time_median_s" and isinstance(value, float):
            assert sil.metrics[key] == pytest.approx(value, rel=1e-9, abs=1e-12), key
    reg = tmp_path / "regdir"
    reg.mkdir()
    text = src.read_text().replace(
        'type = "LQR"\nQ = [10, 1, 100, 1]\nR = [0.1]', f'type = "Exported"\npath = "{folder}"'
    )
    (reg / "cartpole_lqr.toml").write_text(text)
    shutil.copy(src.with_name("cartpole_lqr.baseline.json"), reg / "cartpole_lqr.baseline.json")
    report = run_regression(reg, progress=False)
    assert report.checks and not report.failures
    ctrl = load(lqr.out)
    with pytest.raises(NonFiniteError, match="non-finite measurement"):
        ctrl(np.array([0.0, np.nan, 0.0, 0.0]), np.zeros(4))


def test_lqg_with_a_kalman_filter_takes_the_measurement(tmp_path_factory):
    rep = _export(tmp_path_factory, config_path("cartpole_lqg.toml"))
    _verified(rep)
    assert "#define CARTPOLE_LQG_NY 2" in (rep.out / "cartpole_lqg.h").read_text()


def test_time_varying_kalman_filter_solves_for_its_gain_each_step(tmp_path_factory, tmp_path):
    scen = tmp_path / "lqg_tv.toml"
    scen.write_text(
        config_path("cartpole_lqg.toml")
        .read_text()
        .replace('type = "KalmanFilter"', 'type = "KalmanFilter"\nsteady_state = false\nP0 = [0.01, 0.01, 0.1, 0.1]')
    )
    rep = _export(tmp_path_factory, scen)
    _verified(rep)
    assert "lqg_tv_est_solve" in (rep.out / "lqg_tv_est.c").read_text()


def test_lqi_with_saturation_and_anti_windup_agrees_where_bounds_are_active(tmp_path_factory):
    rep = _export(tmp_path_factory, config_path("cartpole_lqi_disturbance_mujoco.toml"))
    _verified(rep)
    assert rep.clamped_steps > 0 and rep.build.clamped == rep.clamped_steps


def test_a_compensator_with_an_unstable_mode_is_diagnosed_not_blamed_on_the_c(tmp_path):
    # LQI behind a Kalman filter: the compensator's own dynamics (filter + integrator + gain, without the plant)
    # have a mode outside the unit circle, so an open-loop replay amplifies a 1e-15 change beyond 1e-9
    from shinro_ctrl.export.pipeline import record_run, replay_drift
    from shinro_ctrl.sim import RobotSim

    scen = tmp_path / "lqi_kf.toml"
    scen.write_text(
        config_path("cartpole_lqi_disturbance_mujoco.toml").read_text()
        + '\nmeasured = ["x", "theta"]\nsensor_noise = [0.002, 0.002]\nseed = 4\n\n[estimator]\ntype = "KalmanFilter"\n'
    )
    sim = RobotSim.from_config(scen, engine="standalone")
    recordings = [record_run(sim, 800, "standalone")]
    c, e = sim.controller, sim.estimator
    lqi, ImC = c.integral_action, np.eye(4) - e.M @ e.C
    comp = np.block([[ImC @ (e.A - e.B @ c.K), -ImC @ e.B @ lqi.K_i], [lqi.dt * np.eye(4)[[0]], np.eye(1)]])
    assert np.max(np.abs(np.linalg.eigvals(comp))) > 1.01  # independent: the compensator is unstable
    assert replay_drift(sim, recordings) > 1e-9


def test_ekf_with_lqr_uses_casadi_generated_code(tmp_path_factory):
    # the shipped EKF scenario (the quadrotor EKF, whose generated code takes gcc ~15 s, is in benchmarks/export.py)
    rep = _export(tmp_path_factory, config_path("pendulum_ekf_mujoco.toml"))
    _verified(rep)
    src = (rep.out / "pendulum_ekf_mujoco_ekf.c").read_text()
    assert "CasADi" in src and "pendulum_ekf_mujoco_ekf_update" in src


def test_tvlqr_swing_up_exports_its_schedule(tmp_path_factory):
    rep = _export(tmp_path_factory, config_path("cartpole_swingup_mujoco.toml"))
    _verified(rep)
    assert rep.clamped_steps > 0


def test_bad_input_is_one_line(lqr, tmp_path, capsys):
    from shinro_ctrl.cli import main
    from shinro_ctrl.export import load

    with pytest.raises(InvalidArgument, match="--name: expected a C identifier"):
        export_scenario(config_path("regression/cartpole_lqr.toml"), tmp_path / "x", name="int")
    keep = tmp_path / "mine"
    keep.mkdir()
    (keep / "notes.txt").write_text("mine")
    assert main(["export", "cartpole_lqr.toml", "--out", str(keep)]) == 2
    err = capsys.readouterr().err
    assert "not an exported folder: refusing" in err and len(err.strip().splitlines()) == 1
    assert (keep / "notes.txt").read_text() == "mine"
    doc = tmp_path / "ff.toml"
    doc.write_text(config_path("cartpole_lqr.toml").read_text().replace("R = [0.1]", "R = [0.1]\nfeedforward = true"))
    with pytest.raises(ExportError, match="cannot export an LQR with feedforward") as info:
        export_scenario(doc, tmp_path / "y")
    assert "\n" not in str(info.value) and not (tmp_path / "y").exists()
    with pytest.raises(ExportError, match="not an exported folder"):
        load(keep)
