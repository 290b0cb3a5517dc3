"""C export of NonlinearMPC (issue 27): the exported real-time iteration reproduces the Python RTI step by step.

The module fixture records the bound-active part of the cart-pole swing-up (configs/cartpole_nmpc_swingup_mujoco.toml,
N = 40, soft cart bounds, |F| <= 40 N: its first 1.4 s, 28 steps per loop) in both loops, writes the folder, builds it
with gcc (``-O0``, untimed) and replays the recording in C. The reference is the Python controller (its stage function
in CasADi's virtual machine, its Riccati step compiled, its bound-active QP in DAQP): every recorded step must agree to
1e-9, with the force bound active on recorded steps. The window holds the three standalone steps (12, 25, 27) where the
exported C of the condensed QP (condition number 1e8-1e9) disagreed with Python by up to 1.4e-8: that code fails here.
"""

from __future__ import annotations

import shutil

import numpy as np
import pytest

from shinro_ctrl.controllers.nmpc import NonlinearMPC
from shinro_ctrl.errors import ExportError
from shinro_ctrl.export import pipeline
from shinro_ctrl.export.assemble import assemble
from shinro_ctrl.export.build import build_and_verify
from shinro_ctrl.export.nmpc import NonlinearMPCExporter
from shinro_ctrl.export.registry import ExportContext
from shinro_ctrl.plants import CartPole
from shinro_ctrl.resources import config_path

pytestmark = pytest.mark.skipif(shutil.which("gcc") is None or shutil.which("make") is None, reason="needs gcc")


@pytest.fixture(scope="module")
def swingup(tmp_path_factory):
    """The swing-up's first 1.4 s (the pole leaves the hanging position on the force bound), both loops."""
    tmp = tmp_path_factory.mktemp("nmpc")
    text = config_path("cartpole_nmpc_swingup_mujoco.toml").read_text().replace("duration = 8.0", "duration = 1.4")
    cfg = tmp / "cp_nmpc.toml"
    cfg.write_text(text)
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(pipeline, "MIN_STEPS", 56)
        unit, recordings, _, clamped, sim = pipeline.prepare(cfg, "cp_nmpc")
    out = tmp / "cp_nmpc"
    out.mkdir()
    for fname, text in assemble(unit, recordings).items():
        (out / fname).write_text(text, encoding="utf-8")
    res = build_and_verify(out, "cp_nmpc", cflags="-O0", time_step=False)
    return res, recordings, clamped, sim, out


def test_nmpc_rti_c_equals_python_on_both_loops_with_active_bounds(swingup):
    res, recordings, clamped, _, _ = swingup
    assert {"standalone", "mujoco"} <= {r.label for r in recordings}
    assert res.ok, res.summary()
    assert res.steps == 56 and res.max_rel_err <= 1e-9 and res.disagreements == 0 and res.errors == 0
    # the force bound is reached, and C flags the same steps (on the bound to the QP's rounding, as the C's flag)
    u = np.concatenate([r.u for r in recordings])
    on = np.abs(np.abs(u) - 40.0) <= 1e-9 * 41.0
    assert clamped > 0 and res.clamped == int(np.count_nonzero(on)) >= clamped
    assert res.heap == ()


def test_stage_c_is_casadis_and_the_controller_holds_no_heap(swingup):
    _, _, _, _, out = swingup
    stage = (out / "cp_nmpc_nmpc.c").read_text()
    assert "cp_nmpc_nmpc_stage" in stage  # CasADi's CodeGenerator output of the RTI's own stage function
    ctl = (out / "cp_nmpc_ctl.c").read_text()
    for word in ("malloc", "calloc", "realloc", "free("):
        assert word not in ctl and word not in stage


@pytest.mark.parametrize(
    ("options", "why"),
    [({"iterations": 3}, "iterations"), ({"solver": "osqp"}, "solver"), ({"cold_start": "sqp"}, "cold_start")],
)
def test_unexported_nmpc_options_are_refused_in_one_line(options, why):
    plant = CartPole()
    ctrl = NonlinearMPC.from_plant(plant, [1, 1, 1, 1], [1], horizon=3, **options)
    ctx = ExportContext("cp", plant, ctrl, None, plant.state_dim, None, np.zeros(4), np.zeros(4))  # type: ignore[arg-type]
    with pytest.raises(ExportError, match=why) as err:
        NonlinearMPCExporter().part(ctrl, ctx)
    assert "\n" not in str(err.value)
