"""What real robot files revealed (issue 25, benchmarks/real_robot_files.md), each on a model file written here.

References are MuJoCo's own: ``mjd_transitionFD`` on the file itself (clamps off) and ``qacc_smooth``.
"""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np
import pytest

from shinro_ctrl.crosscheck import crosscheck
from shinro_ctrl.plants import MjcfPlant

EDGE = Path(__file__).parent / "data" / "robots" / "tendon_range_edge.xml"


@pytest.fixture(scope="module")
def edge_plant() -> MjcfPlant:
    return MjcfPlant(EDGE)


def _file_jacobian_B(x0: np.ndarray, u0: np.ndarray) -> np.ndarray:
    """Continuous ``∂[q̇; q̈]/∂u`` of the file by central differences of MuJoCo's ``qacc_smooth`` (no clamp)."""
    m = mujoco.MjModel.from_xml_path(str(EDGE))
    m.actuator_ctrllimited[:] = 0
    d = mujoco.MjData(m)
    nq = m.nq
    d.qpos[:], d.qvel[:] = x0[:nq], x0[nq:]
    cols = []
    for e in np.eye(len(u0)) * 1e-6:
        acc = []
        for s in (1.0, -1.0):
            d.ctrl[:] = u0 + s * e
            mujoco.mj_forward(m, d)
            acc.append(d.qacc_smooth.copy())
        cols.append(np.concatenate([np.zeros(nq), (acc[0] - acc[1]) / 2e-6]))
    return np.column_stack(cols)


@pytest.mark.parametrize("past_edge", [0.0, 1.5e-10], ids=["on the edge", "a rounding error past it"])
def test_crosscheck_differentiates_an_input_at_its_ctrlrange_edge(edge_plant, past_edge):
    # The Piper file's equilibrium input of its gripper tendon came out 1.5e-10 above its ctrlrange [-0.08, 0]:
    # MuJoCo's mjd_transitionFD nudges a control only inside ctrlrange while ctrllimited (mjDSBL_CLAMPCTRL or
    # not), so the matched twin's B had a zero column and crosscheck reported a relative error of 1.
    x0, _ = edge_plant.equilibrium()
    u0 = np.array([0.0, past_edge])
    B_ref = _file_jacobian_B(x0, u0)
    assert np.abs(B_ref[:, 1]).max() > 100  # the tendon drives both fingers: the column the twin lost
    result = crosscheck(edge_plant, x0, u0)
    np.testing.assert_allclose(result.B_exact, B_ref, rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(result.B_mujoco, B_ref, rtol=1e-5, atol=1e-5)
    assert result.mujoco_max_rel_error < 1e-5


def test_crosscheck_of_a_constrained_file_says_why_in_one_line(capsys):
    # The Panda-with-hand, Robotiq 2F-85, xArm7 and ARX L5 files are constrained (finger couplings, four-bars):
    # the CLI printed "MjcfPlant has no MuJoCo state map to cross-check against" and nothing about the cause.
    from shinro_ctrl.cli import main
    from shinro_ctrl.resources import asset_path

    assert main(["crosscheck", str(asset_path("gallery/gripper_equality.xml"))]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: "), err
    assert "independent coordinates" in err[0] and "equality constraints" in err[0], err[0]


@pytest.mark.parametrize(
    ("fingers", "level", "says"),
    [(1.5e-10, "warning", "on its edge"), (0.0, "warning", "0.0% of the range"), (1e-3, "error", "MuJoCo clamps it")],
)
def test_model_gap_tells_a_rounding_error_past_a_ctrlrange_from_a_clamped_input(edge_plant, fingers, level, says):
    # Piper's equilibrium input sat 1.5e-10 past its gripper's ctrlrange [-0.08, 0] (its file's 2e-8 quaternion
    # tilts): model_gap reported it as an error, "outside the range: MuJoCo clamps it", like an input 1e-3 past.
    x0, _ = edge_plant.equilibrium()
    gap = edge_plant.model_gap(x0, np.array([0.0, fingers]))
    clamp = [w for w in gap.warnings if w.effect == "clamp" and "'fingers'" in w.message]
    assert len(clamp) == 1 and clamp[0].level == level and says in clamp[0].message, clamp
