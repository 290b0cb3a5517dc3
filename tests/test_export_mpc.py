"""C export of LinearMPC (issue 27): the exported exact QP solver reproduces the Python controller's DAQP solve.

Each module-scoped fixture records a scenario once, writes its folder, builds it with gcc (``-O1``, untimed) and
replays the recording in C. The reference is the Python controller on its DAQP backend (DAQP's own dual
active-set code, not ours): every recorded step must agree to 1e-9; the recordings are checked to contain
steps with active bounds and changes of the optimal active set (read from DAQP's multipliers).
"""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest

from shinro_ctrl.errors import ExportError
from shinro_ctrl.export import pipeline
from shinro_ctrl.export.assemble import assemble
from shinro_ctrl.export.build import build_and_verify
from shinro_ctrl.resources import config_path

pytestmark = pytest.mark.skipif(shutil.which("gcc") is None or shutil.which("make") is None, reason="needs gcc")


def _build(tmp: Path, config: str | Path, name: str):
    unit, recordings, _, clamped, sim = pipeline.prepare(config, name)
    out = tmp / name
    out.mkdir()
    for fname, text in assemble(unit, recordings).items():
        (out / fname).write_text(text, encoding="utf-8")
    return build_and_verify(out, name, cflags="-O1", time_step=False), recordings, clamped, sim, out


def _active_sets(sim, recordings) -> tuple[int, int]:
    """Replay the Python controller on the recorded states: (steps with an active constraint, active-set changes)."""
    ctrl = sim.controller
    n_active = changes = 0
    for rec in recordings:
        ctrl.reset()
        prev = None
        for y, r in zip(rec.y, rec.ref, strict=True):
            ctrl(y, r)  # full-state feedback: the measurement is the state
            act = frozenset(np.flatnonzero(ctrl.dense.lam))
            n_active += bool(act)
            changes += prev is not None and act != prev
            prev = act
    return n_active, changes


@pytest.fixture(scope="module")
def cartpole(tmp_path_factory):
    """Cart-pole LinearMPC N = 50, |F| <= 3 N, |x| <= 0.6 m, recorded in both loops (1,000 steps)."""
    return _build(tmp_path_factory.mktemp("mpc"), config_path("cartpole_mpc_mujoco.toml"), "cp_mpc")


def test_cartpole_mpc_c_equals_python_on_both_loops_with_active_bounds(cartpole):
    res, recordings, clamped, sim, _ = cartpole
    assert res.ok, res.summary()
    assert res.steps >= 1000 and {"standalone", "mujoco"} <= {r.label for r in recordings}
    assert res.max_rel_err <= 1e-9 and res.disagreements == 0 and res.errors == 0
    assert clamped > 0 and res.clamped > 0  # the input bound is reached, and C flags it
    n_active, changes = _active_sets(sim, recordings)
    assert n_active >= 20 and changes >= 10, (n_active, changes)


def test_exported_mpc_uses_no_heap_and_static_sizes(cartpole):
    res, _, _, _, out = cartpole
    assert res.heap == ()
    src = (out / "cp_mpc_ctl.c").read_text()
    for word in ("malloc", "calloc", "realloc", "free("):
        assert word not in src
    assert "static const double cp_mpc_ctl_gram[10000]" in src  # 100 rows: input and cart bounds over N = 50


def test_quadrotor_mpc_soft_bounds_offset_free_with_augmented_kalman_filter(tmp_path, monkeypatch):
    """The quadrotor MPC of configs/quadrotor_mpc_mujoco.toml (soft tilt bounds; horizon 15: 30 slacks) as the
    offset-free controller of configs/quadrotor_wind_mpc_mujoco.toml (u = clip(v - d_hat), d_hat from the exported
    augmented Kalman filter), in wind, toward a set-point high enough that the thrust bound binds; a short recording."""
    text = config_path("quadrotor_wind_mpc_mujoco.toml").read_text().replace("duration = 8.0", "duration = 0.5")
    text = text.replace("horizon = 30", "horizon = 15")  # half the horizon: a quarter of the Gram table
    soft = (
        "x_min = [-inf, -inf, -inf, -0.5, -0.5, -inf, -inf, -inf, -inf, -inf, -inf, -inf]\n"
        "x_max = [inf, inf, inf, 0.5, 0.5, inf, inf, inf, inf, inf, inf, inf]\nsoft = true\n"
    )
    text = text.replace('\ndisturbance_model = "input"', "\n" + soft + 'disturbance_model = "input"')
    text = text.replace("time = 1.0", "time = 0.1").replace("value = [0, 0, 1.0,", "value = [0, 0, 3.0,")
    cfg = tmp_path / "quad.toml"
    cfg.write_text(text)
    monkeypatch.setattr(pipeline, "MIN_STEPS", 100)
    res, recordings, clamped, sim, _ = _build(tmp_path, cfg, "quad")
    ctrl = sim.controller
    assert ctrl.disturbance_model == "input" and ctrl.soft and ctrl.dense.n_slack == 30 and clamped > 0
    assert res.ok and res.max_rel_err <= 1e-9 and res.errors == 0, res.summary()
    assert {"standalone", "mujoco"} <= {r.label for r in recordings}


@pytest.mark.parametrize(
    ("extra", "why"),
    [('solver = "osqp"', "backend"), ('fallback = "shift"', "fallback")],
)
def test_unexported_mpc_options_are_refused_in_one_line(tmp_path, extra, why):
    text = config_path("cartpole_mpc.toml").read_text().replace("horizon = 50", f"horizon = 10\n{extra}")
    cfg = tmp_path / "cp.toml"
    cfg.write_text(text)
    with pytest.raises(ExportError, match=why) as err:
        pipeline.prepare(cfg, "cp")
    assert "\n" not in str(err.value)


def test_rate_bounds_terminal_cost_input_reference_and_slacks(tmp_path, monkeypatch):
    """du bounds (the first stage's rows move with the previous input), terminal cost Q (a dense Hessian), an input
    reference, and soft cart bounds the loop must violate (slacks), in one short recording of both loops."""
    extra = 'du_max = [0.2]\nterminal_cost = "Q"\nu_ref = [0.2]\nsoft = true\nsoft_weight_l1 = 50.0'
    text = config_path("cartpole_mpc.toml").read_text().replace("horizon = 50", f"horizon = 25\n{extra}")
    text = text.replace("duration = 6.0", "duration = 1.2").replace("x_max = [0.6", "x_max = [0.05")
    cfg = tmp_path / "cp_var.toml"
    cfg.write_text(text)
    monkeypatch.setattr(pipeline, "MIN_STEPS", 120)
    res, recordings, _, sim, _ = _build(tmp_path, cfg, "cp_var")
    assert res.ok and res.max_rel_err <= 1e-9 and res.errors == 0, res.summary()
    n_active, changes = _active_sets(sim, recordings)
    assert n_active > 0 and changes > 0, (n_active, changes)
    ctrl, rec, binding = sim.controller, recordings[0], 0
    ctrl.reset()
    for y, r in zip(rec.y, rec.ref, strict=True):
        ctrl(y, r)
        binding += np.max(np.abs(np.diff(ctrl.last.inputs[:, 0]))) >= 0.2 - 1e-9  # the plan rides the rate bound
    assert binding >= 5
    assert max(r.y[:, 0].max() for r in recordings) > 0.05 + 1e-3  # the soft cart bound is violated: slacks > 0


def test_loaded_mpc_matches_python_and_reports_infeasibility_as_python_does(cartpole):
    """The folder through ``export.load`` (ctypes): the same input as Python at a bound-active state, and
    ``MPCInfeasible`` where the Python controller raises it (status QP_INFEASIBLE, the previous input held)."""
    from shinro_ctrl.errors import MPCInfeasible
    from shinro_ctrl.export import load

    _, _, _, sim, out = cartpole
    py, c = sim.controller, load(out)
    py.reset()
    c.reset()
    x = np.array([0.1, 0.0, 0.3, 0.0])  # the force bound is active here
    ref = np.zeros(4)
    u_py, u_c = py(x, ref), c(x, ref)
    assert abs(u_py[0]) == pytest.approx(3.0) and u_c == pytest.approx(u_py, rel=1e-9, abs=1e-12)
    bad = np.array([0.5, 3.0, 0.0, 0.0])  # 3 m/s toward the 0.6 m bound: no force within 3 N stops the cart
    with pytest.raises(MPCInfeasible):
        py(bad, ref)
    with pytest.raises(MPCInfeasible, match="QP is infeasible"):
        c(bad, ref)
    assert c.last_status & 128
