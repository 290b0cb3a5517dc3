"""Robot files as users bring them (issue 23 §4, §5, §6): MjcfPlant and the CLI on MJCF/URDF files.

The files in ``tests/data/robots/`` are small models written for these tests, each with the feature real
robot files (kinova, Piper, solo12, go1) tripped on: a keyframe and a ``qpos0`` outside a joint range, a
URDF with ``<mimic>`` and friction, an MJCF with frictionloss, a tendon and an equality constraint, a
URDF whose root is meant to float. References are MuJoCo's own computations on the same files.
"""

from __future__ import annotations

import re
import shutil
import warnings
from pathlib import Path

import mujoco
import numpy as np
import pytest

from shinro_ctrl.cli import main
from shinro_ctrl.engine import MujocoEngine
from shinro_ctrl.engine.model_tree import ModelWarning, model_kind
from shinro_ctrl.errors import ConfigError, InvalidArgument
from shinro_ctrl.plants import MjcfPlant, plant_class
from shinro_ctrl.resources import asset_path

DATA = Path(__file__).parent / "data" / "robots"
#: MuJoCo's "XML contains a 'NaN'" is a ModelWarning; the tests of NaN files check the error, not that note.
QUIET_NAN = pytest.mark.filterwarnings("ignore:MuJoCo, loading:shinro_ctrl.engine.warnings.ModelWarning")


def _one_error_line(capsys: pytest.CaptureFixture[str], argv: list[str]) -> str:
    """Run the CLI, expect exit 2 and exactly one ``error:`` line on stderr; return it."""
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: "), err
    return err[0]


# ------------------------------------------------------------- operating point
def test_default_operating_point_is_the_first_keyframe_held_by_gravity_compensation():
    path = DATA / "arm_keyframe.xml"
    plant = MjcfPlant(path)
    x0, u0 = plant.equilibrium()
    np.testing.assert_array_equal(x0, [0.3, -0.6, 1.2, 0, 0, 0])  # the keyframe "ready"
    m = mujoco.MjModel.from_xml_path(str(path))
    d = mujoco.MjData(m)
    mujoco.mj_resetDataKeyframe(m, d, 0)
    mujoco.mj_forward(m, d)
    np.testing.assert_allclose(m.actuator_gear[:, 0] * u0, d.qfrc_bias, rtol=1e-10, atol=1e-12)


def test_without_a_keyframe_qpos0_is_moved_inside_the_ranges(tmp_path):
    text = (DATA / "arm_keyframe.xml").read_text()
    path = tmp_path / "arm_no_key.xml"
    path.write_text(re.sub(r"<keyframe>.*</keyframe>", "", text, flags=re.S))
    plant = MjcfPlant(path)
    x0, u0 = plant.equilibrium()
    # qpos0 = 0 for every joint; only the elbow's range [0.4, 2.6] excludes it: 1 % of the width inside
    np.testing.assert_allclose(x0, [0, 0, 0.4 + 0.01 * 2.2, 0, 0, 0], rtol=0, atol=1e-15)
    # MuJoCo at that pose: no joint limit is active, and u0 holds it (the standalone hold is reachable)
    m = mujoco.MjModel.from_xml_path(str(path))
    d = mujoco.MjData(m)
    d.qpos[:] = x0[:3]
    mujoco.mj_forward(m, d)
    assert d.nefc == 0
    np.testing.assert_allclose(m.actuator_gear[:, 0] * u0, d.qfrc_bias, rtol=1e-10, atol=1e-12)
    engine = MujocoEngine.for_plant(plant)
    plant.physics_engine(engine)
    plant.set_state(x0)
    for _ in range(200):
        plant.step(u0)
    np.testing.assert_allclose(plant.get_state(), x0, atol=1e-9)


def test_an_operating_point_outside_a_joint_range_is_refused_naming_the_joint(tmp_path, capsys):
    path = DATA / "arm_keyframe.xml"
    with pytest.raises(InvalidArgument, match=r"x0 puts a joint outside the joint range: 'elbow' = 0 \(range \[0.4"):
        MjcfPlant(path, x0=[0, 0, 0, 0, 0, 0])
    with pytest.raises(InvalidArgument, match=r"joints outside the joint range: 'shoulder_yaw' = 4 .*'elbow' = 3"):
        MjcfPlant(path, x0=[4, 0, 3, 0, 0, 0])
    bad_key = tmp_path / "bad_key.xml"
    bad_key.write_text((DATA / "arm_keyframe.xml").read_text().replace('qpos="0.3 -0.6 1.2"', 'qpos="0.3 -0.6 0"'))
    with pytest.raises(InvalidArgument, match=r"keyframe 'ready' puts a joint outside the joint range: 'elbow' = 0"):
        MjcfPlant(bad_key)
    scenario = tmp_path / "s.toml"
    scenario.write_text(
        f'[plant]\ntype = "{path}"\n[controller]\ntype = "LQR"\n'
        "[sim]\nduration = 0.1\ninitial_state = [0.0, 0.0, 3.0, 0.0, 0.0, 0.0]\n"
    )
    line = _one_error_line(capsys, ["run", str(scenario)])
    assert "elbow = 3" in line and "outside" in line
    from shinro_ctrl.config import load_scenario

    with pytest.raises(ConfigError, match="elbow = 3"):
        load_scenario(scenario)


# ------------------------------------------------------- what real files carry, at once
def test_urdf_mimic_and_friction_both_load(capsys):
    # <mimic>: a joint coupling modelled exactly (tests/test_mjcf_constraints.py); <dynamics friction>: recorded,
    # MuJoCo-loop only (tests/test_mjcf_features.py)
    path = DATA / "gripper_mimic.urdf"
    plant = MjcfPlant(path)
    assert plant.constraints is not None
    assert "finger_right_joint" not in plant.state_names and "finger_left_joint" in plant.state_names
    friction = {j.name: j.frictionloss for j in plant.tree.joints}
    assert friction["wrist_roll"] > 0 and friction["finger_left_joint"] > 0
    assert np.isfinite(plant.dynamics(*plant.equilibrium())).all()


def _piper_variant(tmp_path: Path, *edits: tuple[str, str]) -> Path:
    text = (DATA / "piper_like.xml").read_text()
    for old, new in edits:
        assert old in text
        text = text.replace(old, new)
    out = tmp_path / "piper_variant.xml"
    out.write_text(text)
    return out


def test_mjcf_frictionloss_tendon_gravcomp_and_equality_together_match_mujoco(tmp_path):
    # piper_like as it comes loads: the coupling exact, the tendon's spring in the dynamics, frictionloss recorded
    plant = MjcfPlant(DATA / "piper_like.xml")
    assert plant.input_names == ("m1", "m2", "m3", "u3")
    assert plant.constraints is not None and len(plant.state_names) == 8
    # a tendon that the coupling stretches (length q_a + q_b) and gravity compensation: both act in the KKT system
    path = _piper_variant(
        tmp_path, ('coef="-1"', 'coef="1"'), ('<body name="link2" pos', '<body name="link2" gravcomp="0.5" pos')
    )
    plant = MjcfPlant(path)
    m = mujoco.MjModel.from_xml_path(plant.model_path)
    m.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_FRICTIONLOSS)  # frictionloss acts in MuJoCo's loop only
    m.eq_solimp[:, :2] = 0.99999
    data = mujoco.MjData(m)
    rng = np.random.default_rng(3)
    x = np.r_[0.3, 1.0, -0.8, 0.02, rng.normal(size=4) * 0.3]
    u = rng.normal(size=4) * 0.5
    full = plant.constraints.complete(x)
    data.qpos[:], data.qvel[:] = full[: m.nq], full[m.nq :]
    data.ctrl[:] = u
    mujoco.mj_forward(m, data)
    exact, _ = plant.constraints.accelerations(full, u)
    assert np.abs(data.efc_pos).max() <= 1e-12  # on MuJoCo's constraint manifold
    assert np.abs(data.qfrc_spring).max() > 0.1 and np.abs(data.qfrc_gravcomp).max() > 0.1  # both forces act
    gap = np.abs(data.qacc - exact).max()
    assert gap <= 1e-3 * np.abs(exact).max()  # within MuJoCo's softness
    m.tendon_stiffness[:] = 0.0
    m.body_gravcomp[:] = 0.0
    mujoco.mj_forward(m, data)
    assert np.abs(data.qacc - exact).max() > 100 * gap  # without the two forces MuJoCo is far off
    assert np.allclose(plant.dynamics(x, u)[4:], exact[list(plant.constraints.independent)])


def test_equality_with_activation_dynamics_is_refused_in_one_line(tmp_path, capsys):
    path = _piper_variant(
        tmp_path,
        (
            '<motor name="m2" joint="j2" gear="20"/>',
            '<general name="m2" joint="j2" gear="20" dyntype="filter" dynprm="0.05"/>',
        ),
    )
    with pytest.raises(InvalidArgument, match=r"activation dynamics on actuators 'm2' \(filter\) with equality"):
        MjcfPlant(path)
    line = _one_error_line(capsys, ["linearize", str(path)])
    assert "'m2' (filter)" in line and "equality" in line


def test_unnamed_elements_are_named_by_what_they_sit_on(tmp_path):
    path = tmp_path / "unnamed.xml"
    path.write_text(
        """<mujoco><worldbody><body name="arm"><joint name="h" type="hinge" frictionloss="1"/><geom size="0.1"/>
        <body><joint type="ball" stiffness="1"/><geom size="0.1"/></body></body></worldbody>
        <actuator><general joint="h" dyntype="integrator"/><motor joint="h" armature="0.1"/></actuator></mujoco>"""
    )
    with pytest.raises(InvalidArgument) as info:
        MjcfPlant(path)
    msg = str(info.value)
    assert "stiffness on ball joint #1 (of body #2 (child of 'arm'))" in msg
    assert "armature on actuator #1 (on joint 'h')" in msg


# ------------------------------------------------------------- floating base
def test_a_urdf_root_meant_to_float_is_said_to_be_welded(tmp_path, capsys):
    path = DATA / "quadruped.urdf"
    with pytest.warns(ModelWarning, match=r"welds the URDF's root link 'trunk' \(1.2 kg, with 4 moving branches"):
        plant = MjcfPlant(path)
    assert plant.state_dim == 8
    assert main(["linearize", str(path)]) == 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("warning: 'quadruped.urdf': MuJoCo welds"), err
    # a fixed arm (one moving chain from its root) gets no such note
    path = DATA / "gripper_mimic.urdf"
    arm = path.read_text().replace('friction="0.02"', "").replace('friction="0.5"', "")
    arm = re.sub(r"<mimic[^>]*/>", "", arm)
    (tmp_path / "arm.urdf").write_text(arm)
    with warnings.catch_warnings():
        warnings.simplefilter("error", ModelWarning)
        assert MjcfPlant(tmp_path / "arm.urdf").state_dim == 6


# ------------------------------------------------------------- invalid numbers
PEND = """<mujoco model="pend"><compiler angle="radian" inertiafromgeom="false"/>
  <option timestep="{timestep}" gravity="{gravity}"><flag contact="disable"/></option>
  <worldbody><body name="pole" pos="{bpos}">
    <joint name="hinge" type="hinge" axis="{axis}" damping="{damping}" stiffness="{stiffness}" range="-1 1"/>
    <inertial pos="0 0 0.5" mass="{mass}" diaginertia="1e-4 1e-4 1e-4"/></body></worldbody>
  <actuator><general name="m" joint="hinge" gear="{gear}" gainprm="{gain}" biasprm="{bias}" biastype="affine"/>
  </actuator>{key}</mujoco>"""
GOOD = {
    "timestep": "0.01",
    "gravity": "0 0 -9.81",
    "bpos": "0 0 0",
    "axis": "0 1 0",
    "damping": "0.01",
    "stiffness": "0",
    "mass": "0.1",
    "gear": "1",
    "gain": "1",
    "bias": "0 0 0",
    "key": "",
}


@QUIET_NAN
@pytest.mark.parametrize(
    ("key", "value", "needle"),
    [
        ("gravity", "0 0 nan", "<option gravity> = [0, 0, nan]"),
        ("gravity", "inf 0 -9.81", "<option gravity>"),
        ("timestep", "0", "<option timestep> = 0"),
        ("timestep", "nan", "<option timestep> = nan"),
        ("mass", "inf", "body 'pole' mass = inf"),
        ("bpos", "0 0 nan", "body 'pole' pos"),
        ("axis", "0 1 inf", "joint 'hinge' axis"),
        ("damping", "nan", "joint 'hinge' damping = nan"),
        ("stiffness", "-inf", "joint 'hinge' stiffness = -inf"),
        ("gear", "inf", "actuator 'm' gear (0: the actuator moves nothing) = inf"),
        ("gear", "0", "actuator 'm' gear (0: the actuator moves nothing) = 0"),
        ("gain", "nan", "actuator 'm' gainprm"),
        ("bias", "0 nan 0", "actuator 'm' biasprm"),
        ("key", '<keyframe><key name="k" qpos="nan"/></keyframe>', "keyframe 'k' qpos"),
    ],
)
def test_invalid_numbers_are_refused_in_one_line(tmp_path, capsys, key, value, needle):
    path = tmp_path / "pend.xml"
    path.write_text(PEND.format(**{**GOOD, key: value}))
    mujoco.MjModel.from_xml_path(str(path))  # MuJoCo itself accepts the file
    with pytest.raises(InvalidArgument, match="invalid numbers") as info:
        MjcfPlant(path)
    assert needle in str(info.value)
    for cmd in ("linearize", "crosscheck"):
        line = _one_error_line(capsys, [cmd, str(path)])
        assert needle in line


@QUIET_NAN
def test_non_finite_numbers_that_break_mujocos_compiler_are_named(tmp_path, capsys):
    path = tmp_path / "pend.xml"
    path.write_text(PEND.format(**GOOD).replace('<inertial pos="0 0 0.5"', '<inertial pos="0 0 nan"'))
    with pytest.raises(ValueError):
        mujoco.MjModel.from_xml_path(str(path))  # MuJoCo's own message is about what the NaN broke
    line = _one_error_line(capsys, ["linearize", str(path)])
    assert "holds non-finite numbers: body 'pole' inertial pos = [0, 0, nan]" in line
    urdf = tmp_path / "one.urdf"
    urdf.write_text(URDF_LINK.format(inertial=INERTIAL.format(mass="nan", ixx="1e-4", ixy="0"), origin="0 0 0"))
    line = _one_error_line(capsys, ["crosscheck", str(urdf)])
    assert f"URDF '{urdf}' holds non-finite numbers: link 'l1' mass = nan" in line


@QUIET_NAN
def test_every_invalid_number_is_listed_at_once(tmp_path):
    path = tmp_path / "pend.xml"
    path.write_text(PEND.format(**{**GOOD, "gravity": "0 0 nan", "damping": "inf", "gear": "nan"}))
    with pytest.raises(InvalidArgument) as info:
        MjcfPlant(path)
    msg = str(info.value)
    assert "<option gravity>" in msg and "joint 'hinge' damping = inf" in msg
    assert "actuator 'm' gear (0: the actuator moves nothing) = nan" in msg


def test_magnitudes_that_overflow_are_refused_not_linalg_errors(tmp_path, capsys):
    path = tmp_path / "pend.xml"
    path.write_text(PEND.format(**{**GOOD, "mass": "1e308"}))
    line = _one_error_line(capsys, ["linearize", str(path)])
    assert "overflow" in line


URDF_LINK = """<?xml version="1.0"?>
<robot name="one"><link name="base"/><link name="l1">{inertial}</link>
  <joint name="j1" type="revolute"><parent link="base"/><child link="l1"/><origin xyz="{origin}"/>
    <axis xyz="0 1 0"/><limit lower="-3" upper="3" effort="10" velocity="10"/></joint></robot>"""
INERTIAL = (
    '<inertial><origin xyz="0 0 0.5"/><mass value="{mass}"/>'
    '<inertia ixx="{ixx}" iyy="1e-4" izz="1e-4" ixy="{ixy}" ixz="0" iyz="0"/></inertial>'
)


@QUIET_NAN
@pytest.mark.parametrize(
    ("inertial", "origin", "needle"),
    [
        (INERTIAL.format(mass="0", ixx="1e-4", ixy="0"), "0 0 0", "link 'l1': mass and inertia"),
        (INERTIAL.format(mass="-1", ixx="1e-4", ixy="0"), "0 0 0", "link 'l1': mass and inertia"),
        ("", "0 0 0", "give link 'l1' an <inertial>"),
        (INERTIAL.format(mass="0.1", ixx="1", ixy="5"), "0 0 0", "<inertia> of link 'l1' must be positive definite"),
        (INERTIAL.format(mass="0.1", ixx="1e-4", ixy="0"), "0 0 nan", "the <origin> of the joint into link 'l1'"),
    ],
)
def test_urdf_with_a_bad_link_is_refused_naming_the_link_and_the_users_file(tmp_path, capsys, inertial, origin, needle):
    path = tmp_path / "one.urdf"
    path.write_text(URDF_LINK.format(inertial=inertial, origin=origin))
    with pytest.raises(InvalidArgument) as info:
        MjcfPlant(path)
    assert needle in str(info.value) and str(path) in str(info.value)
    assert "shinro_ctrl_urdf" not in str(info.value)
    for cmd in ("linearize", "crosscheck"):
        line = _one_error_line(capsys, [cmd, str(path)])
        assert needle in line


# ------------------------------------------------------------- names and kinds
FURUTA = asset_path("furuta_pendulum.xml")
URDF_OK = URDF_LINK.format(inertial=INERTIAL.format(mass="0.1", ixx="1e-4", ixy="0"), origin="0 0 0")


@pytest.mark.parametrize("name", ["f.mjcf", "F.XML", "f.Xml", "f.MJCF", "furuta_model"])
def test_mjcf_under_any_name_works_in_every_command(tmp_path, capsys, monkeypatch, name):
    monkeypatch.chdir(tmp_path)  # `run` writes its default plot under ./out
    path = tmp_path / name
    shutil.copy(FURUTA, path)
    assert model_kind(path) == "mjcf" and plant_class(str(path)) is MjcfPlant
    for cmd in ("linearize", "crosscheck"):
        assert main([cmd, str(path)]) == 0, capsys.readouterr().err
        captured = capsys.readouterr()
        assert captured.err == ""
    scenario = tmp_path / "s.toml"
    scenario.write_text(
        f'[plant]\ntype = "MjcfPlant"\nmodel = "{name}"\ndt = 0.005\n[engine]\ntype = "mujoco"\n'
        '[controller]\ntype = "LQR"\nQ = [5, 50, 0.5, 1]\nR = [200]\n[sim]\nduration = 0.2\n'
        "initial_state = [0.0, 0.05, 0.0, 0.0]\n"
    )
    assert main(["run", str(scenario)]) == 0, capsys.readouterr().err


@pytest.mark.parametrize("name", ["robot.xml", "ROBOT.URDF", "robot"])
def test_urdf_under_any_name_is_recognized_by_content(tmp_path, capsys, name):
    path = tmp_path / name
    path.write_text(URDF_OK)
    assert model_kind(path) == "urdf"
    plant = MjcfPlant(path)
    assert plant.input_names == ("j1",)  # the URDF's motor: it was read as a URDF, whatever its name
    for cmd in ("linearize", "crosscheck"):
        assert main([cmd, str(path)]) == 0
        assert capsys.readouterr().err == ""


def test_includes_and_meshes_resolve_beside_a_file_with_an_odd_suffix(tmp_path, capsys):
    (tmp_path / "parts").mkdir()
    (tmp_path / "meshes").mkdir()
    (tmp_path / "meshes" / "tip.obj").write_text(
        "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 2 3\nf 1 2 4\nf 1 3 4\nf 2 3 4\n"
    )
    (tmp_path / "parts" / "link.xml").write_text(
        '<mujoco><body name="b2" pos="0 0 -0.5"><joint name="j2" type="hinge" axis="0 1 0"/>'
        '<geom type="mesh" mesh="tip" mass="0.2"/></body></mujoco>'
    )
    path = tmp_path / "robot.MJCF"
    path.write_text(
        '<mujoco model="inc"><compiler meshdir="meshes"/><asset><mesh name="tip" file="tip.obj"/></asset>'
        '<worldbody><body name="b1"><joint name="j1" type="hinge" axis="0 1 0"/><geom size="0.1" mass="1"/>'
        '<include file="parts/link.xml"/></body></worldbody><actuator><motor joint="j1"/><motor joint="j2"/>'
        "</actuator></mujoco>"
    )
    plant = MjcfPlant(path)
    assert plant.joint_names == ("j1", "j2")
    assert main(["crosscheck", str(path)]) == 0
    assert capsys.readouterr().err == ""


@pytest.mark.parametrize(
    ("content", "needle"),
    [
        ("", "is empty"),
        ("<robot_not><a/></robot_not>", "its root element is <robot_not>"),
        ("not xml at all", "not a valid XML file"),
        ("<mujoco><worldbody>", "not a valid XML file"),
        (b"\x00\x01\xff\xfegarbage", "is not UTF-8 text: byte 0xff on line 1"),
        ("<mujoco>\n<!-- caf\xe9 -->\n</mujoco>".encode("latin-1"), "is not UTF-8 text: byte 0xe9 on line 2"),
    ],
)
def test_files_that_are_not_models_are_refused_in_one_line(tmp_path, capsys, content, needle):
    path = tmp_path / "thing.xml"
    if isinstance(content, bytes):
        path.write_bytes(content)
    else:
        path.write_text(content)
    for cmd in ("linearize", "crosscheck"):
        line = _one_error_line(capsys, [cmd, str(path)])
        assert needle in line and "thing.xml" in line


# ------------------------------------------------------------- MuJoCo's warnings
def test_mujocos_own_warnings_do_not_leak_as_stray_lines(tmp_path, capfd):
    # a NaN MuJoCo warns about but the model does not use (the control range of an unclamped actuator)
    path = tmp_path / "quiet.xml"
    path.write_text(
        FURUTA.read_text().replace("<motor ", '<motor ctrlrange="-1 nan" ctrllimited="false" ', 1), encoding="utf-8"
    )
    mujoco.MjModel.from_xml_path(str(path))  # MuJoCo prints its own WARNING line here, before our handler...
    capfd.readouterr()
    with pytest.warns(ModelWarning, match=r"MuJoCo, loading 'quiet.xml': XML contains a 'NaN'"):
        MjcfPlant(path)
    out, err = capfd.readouterr()
    assert "WARNING" not in out + err  # ...and never through shinro_ctrl
    assert main(["crosscheck", str(path)]) == 0
    out, err = capfd.readouterr()
    assert "WARNING" not in out
    lines = err.strip().splitlines()
    assert lines and all(ln.startswith("warning: MuJoCo, loading 'quiet.xml'") for ln in lines), lines
