"""The model-gap report (issue 25 item 3): each row against a hand computation or MuJoCo itself.

References: the load torque of a two-link arm of point masses in closed form (gravity and a joint spring at
rest), the actuator torques ``gear·u`` and ``kp·(u − q)`` by hand, margins by hand from the ranges, contacts
against MuJoCo's own ``d.ncon`` / ``d.contact.dist`` and a sphere's height over the floor by hand. Warnings are
checked just above and just below each documented threshold.
"""

from __future__ import annotations

import copy
import math

import mujoco
import numpy as np
import pytest

from shinro_ctrl.cli import main
from shinro_ctrl.engine import MujocoEngine
from shinro_ctrl.engine.model_gap import (
    CLAMP_WARN,
    EQUALITY_WARN,
    FRICTION_WARN,
    LIMIT_WARN,
    GapThresholds,
    engine_model_gap,
    model_gap,
)
from shinro_ctrl.errors import InvalidArgument, NonFiniteError
from shinro_ctrl.plants import MjcfPlant
from shinro_ctrl.resources import asset_path

G = 9.81
L1, L2 = 0.4, 0.3  # link lengths [m]
M1, C1 = 1.0, 0.2  # upper link: point mass [kg] at C1 [m] from the shoulder
M2, C2 = 0.5, 0.15  # lower link: point mass at C2 from the elbow
H, R = 0.5, 0.03  # shoulder height over the floor, radius of the tip sphere [m]
K_SPRING, Q_SPRING = 2.0, 0.1  # elbow spring stiffness [N m/rad] and reference [rad]
GEAR, KP = 10.0, 20.0
LIM1, LIM2 = (-1.5, 1.5), (-2.0, 2.0)
MARGIN2 = 0.25  # the elbow's MuJoCo limit margin [rad]


def arm_xml(frictionloss: bool = True, flags: str = "") -> str:
    """A planar two-link arm over a floor: point masses, a tip sphere that can touch the floor, limits, a spring,
    a motor (ctrlrange, actuatorfrcrange on its joint) and a position servo (ctrlrange, forcerange)."""
    fl1, fl2 = (' frictionloss="0.3"', ' frictionloss="0.05"') if frictionloss else ("", "")
    return f"""
<mujoco model="gap_arm">
  <compiler angle="radian" inertiafromgeom="false"/>
  <option timestep="0.002">{flags}</option>
  <worldbody>
    <geom name="floor" type="plane" size="2 2 0.1"/>
    <body name="upper" pos="0 0 {H}">
      <joint name="shoulder" axis="0 1 0" range="{LIM1[0]} {LIM1[1]}" damping="0.1"
             actuatorfrcrange="-8 8"{fl1}/>
      <inertial pos="{C1} 0 0" mass="{M1}" diaginertia="1e-6 1e-6 1e-6"/>
      <geom type="capsule" fromto="0 0 0 {L1} 0 0" size="0.02" contype="0" conaffinity="0"/>
      <body name="lower" pos="{L1} 0 0">
        <joint name="elbow" axis="0 1 0" range="{LIM2[0]} {LIM2[1]}" margin="{MARGIN2}" stiffness="{K_SPRING}"
               springref="{Q_SPRING}"{fl2}/>
        <inertial pos="{C2} 0 0" mass="{M2}" diaginertia="1e-6 1e-6 1e-6"/>
        <geom type="capsule" fromto="0 0 0 {L2} 0 0" size="0.02" contype="0" conaffinity="0"/>
        <geom name="tip" type="sphere" pos="{L2} 0 0" size="{R}" mass="0"/>
      </body>
    </body>
  </worldbody>
  <actuator>
    <motor name="m_shoulder" joint="shoulder" gear="{GEAR}" ctrlrange="-1 1"/>
    <position name="p_elbow" joint="elbow" kp="{KP}" ctrlrange="-2 2" forcerange="-3 3"/>
  </actuator>
</mujoco>
"""


PENDULUM_XML = """
<mujoco model="gap_pendulum">
  <compiler angle="radian" inertiafromgeom="false"/>
  <worldbody>
    <body name="link" pos="0 0 0.5">
      <joint name="hinge" axis="0 1 0" range="-2 2" damping="0.05"/>
      <inertial pos="0.3 0 0" mass="0.5" diaginertia="1e-6 1e-6 1e-6"/>
    </body>
  </worldbody>
  <actuator>
    <motor name="motor" joint="hinge" gear="1.6" ctrlrange="-1 1"/>
  </actuator>
</mujoco>
"""


def hand_load(q1: float, q2: float) -> np.ndarray:
    """``qfrc_bias − qfrc_passive`` at rest: gravity (a point rotated about +y by q goes to z = −r sin q) and the
    elbow spring ``−k (q2 − q_s)``."""
    # V = −g [M1 C1 sin q1 + M2 (L1 sin q1 + C2 sin(q1 + q2))] (heights relative to the shoulder); bias = ∂V/∂q
    c1, c12 = math.cos(q1), math.cos(q1 + q2)
    dV1 = -G * (M1 * C1 * c1 + M2 * (L1 * c1 + C2 * c12))
    dV2 = -G * M2 * C2 * c12
    return np.array([dV1, dV2 + K_SPRING * (q2 - Q_SPRING)])


def tip_height(q1: float, q2: float) -> float:
    return H - L1 * math.sin(q1) - L2 * math.sin(q1 + q2)


def margin(v: float, lo: float, hi: float) -> float:
    return min(v - lo, hi - v) / (hi - lo)


@pytest.fixture(scope="module")
def arm() -> mujoco.MjModel:
    return mujoco.MjModel.from_xml_string(arm_xml())


@pytest.fixture(scope="module")
def arm_file(tmp_path_factory) -> str:
    """The arm as a file (MjcfPlant loads it: friction loss stays out of its smooth model)."""
    path = tmp_path_factory.mktemp("gap") / "gap_arm.xml"
    path.write_text(arm_xml())
    return str(path)


def x_at(q1: float, q2: float) -> np.ndarray:
    return np.array([q1, q2, 0.0, 0.0])


def effects(gap, level: str | None = None) -> list[str]:
    return [w.effect for w in gap.warnings if level is None or w.level == level]


# -------------------------------------------------------------------- rows
def test_joint_rows_match_the_closed_form(arm):
    rng = np.random.default_rng(7)
    for _ in range(3):
        q1, q2 = rng.uniform(-1.0, 1.0), rng.uniform(-1.5, 1.5)
        u = np.array([rng.uniform(-0.9, 0.9), rng.uniform(-1.0, 1.0)])
        gap = model_gap(arm, x_at(q1, q2), u)
        shoulder, elbow = gap.dofs
        np.testing.assert_allclose([shoulder.load, elbow.load], hand_load(q1, q2), rtol=1e-10, atol=1e-12)
        np.testing.assert_allclose([shoulder.actuator, elbow.actuator], [GEAR * u[0], KP * (u[1] - q2)], rtol=1e-12)
        assert shoulder.range == LIM1 and elbow.range == LIM2 and elbow.mujoco_margin == MARGIN2
        assert shoulder.limit_margin == pytest.approx(margin(q1, *LIM1), rel=1e-12)
        assert elbow.limit_distance == pytest.approx(min(q2 - LIM2[0], LIM2[1] - q2), rel=1e-12)
        assert shoulder.frictionloss == 0.3 and elbow.frictionloss == 0.05
        load = hand_load(q1, q2)
        assert shoulder.friction_ratio == pytest.approx(0.3 / abs(load[0]), rel=1e-9)
        assert elbow.friction_to_actuator == pytest.approx(0.05 / abs(KP * (u[1] - q2)), rel=1e-9)
        assert elbow.friction_holds == (abs(load[1]) <= 0.05)
        assert shoulder.actfrc_range == (-8.0, 8.0)
        assert shoulder.actfrc_margin == pytest.approx(margin(GEAR * u[0], -8, 8), rel=1e-12)


def test_actuator_rows_match_the_hand_clamps(arm):
    q2 = 0.3
    u = np.array([0.5, 0.2])  # the servo asks kp (u − q) = −2 N m: inside forcerange
    a_m, a_p = model_gap(arm, x_at(0.2, q2), u).actuators
    assert (a_m.ctrlrange, a_m.forcerange, a_m.force_margin) == ((-1.0, 1.0), None, None)
    assert a_m.ctrl_margin == pytest.approx(0.25) and a_m.force == pytest.approx(0.5)
    assert a_p.ctrl_margin == pytest.approx(margin(0.2, -2, 2)) and a_p.forcerange == (-3.0, 3.0)
    assert a_p.force == pytest.approx(KP * (0.2 - q2)) and a_p.force_margin == pytest.approx(margin(-2.0, -3, 3))
    # beyond forcerange: the smooth force stays, MuJoCo applies the clamped one (its own actuator_force)
    u = np.array([0.5, -0.1])
    gap = model_gap(arm, x_at(0.2, q2), u)
    a_p = gap.actuators[1]
    assert a_p.force == pytest.approx(KP * (-0.1 - q2)) and a_p.applied_force == pytest.approx(-3.0)
    assert a_p.force_margin < 0 and ("error", "clamp") in [(w.level, w.effect) for w in gap.warnings]
    d = mujoco.MjData(arm)
    d.qpos[:] = [0.2, q2]
    d.ctrl[:] = u
    mujoco.mj_forward(arm, d)
    assert d.actuator_force[1] == pytest.approx(a_p.applied_force)


def test_contacts_against_mujoco_and_the_tip_height(arm):
    q1 = math.asin((H - 0.025) / (L1 + L2))  # tip 0.025 m over the floor: penetration R − 0.025 = 5 mm
    gap = model_gap(arm, x_at(q1, 0.0), [0.0, 0.0])
    d = mujoco.MjData(arm)
    d.qpos[:] = [q1, 0.0]
    mujoco.mj_forward(arm, d)
    assert gap.n_contacts == d.ncon == 1
    assert [c.dist for c in gap.contacts] == pytest.approx(list(d.contact.dist[: d.ncon]), abs=1e-12)
    assert gap.contacts[0].dist == pytest.approx(tip_height(q1, 0.0) - R, abs=1e-12)
    assert gap.max_penetration == pytest.approx(0.005, abs=1e-12)
    assert {gap.contacts[0].geom1, gap.contacts[0].geom2} == {"floor", "tip"}
    assert "contact" in effects(gap) and "floor – tip" in gap.format()
    free = model_gap(arm, x_at(0.2, 0.0), [0.0, 0.0])  # tip 0.36 m over the floor
    assert free.n_contacts == 0 and "contact" not in effects(free)
    near = copy.copy(arm)
    near.geom_margin[:] = 0.05  # a contact 2 cm away is active within the margin: no penetration
    q1 = math.asin((H - R - 0.02) / (L1 + L2))
    gap = model_gap(near, x_at(q1, 0.0), [0.0, 0.0])
    assert gap.n_contacts == 1 and gap.contacts[0].dist == pytest.approx(0.02) and gap.max_penetration == 0.0


def test_effects_the_model_switches_off_are_not_reported():
    m = mujoco.MjModel.from_xml_string(
        arm_xml(flags='<flag contact="disable" frictionloss="disable" limit="disable"/>')
    )
    q1 = math.asin((H - 0.025) / (L1 + L2))
    gap = model_gap(m, x_at(q1, 1.99), [0.0, 0.0])
    assert gap.contacts == () and set(gap.disabled) == {"contact", "frictionloss", "limit"}
    assert all(d.frictionloss == 0.0 and d.range is None for d in gap.dofs)
    assert not {"contact", "friction", "limit"} & set(effects(gap))


LOCKED_XML = """
<mujoco><compiler angle="radian"/><option timestep="0.001"/>
  <worldbody>
    <body pos="0 0 1"><joint name="hinge" axis="0 1 0" damping="0.5"/>
      <inertial pos="0.3 0 0" mass="1" diaginertia="0.01 0.01 0.01"/></body>
  </worldbody>
  <equality>
    <joint name="lock" joint1="hinge" polycoef="0 0 0 0 0" solimp="0.95 0.95 0.001" solref="{tc} 1"/>
  </equality>
</mujoco>
"""
PINNED_XML = """
<mujoco><compiler angle="radian"/><option timestep="0.001"/>
  <worldbody>
    <body name="a" pos="0 0 1"><joint axis="0 1 0" damping="0.3"/>
      <inertial pos="0.2 0 0" mass="1" diaginertia="0.01 0.01 0.01"/>
      <body name="b" pos="0.4 0 0"><joint axis="0 1 0" damping="0.3"/>
        <inertial pos="0.15 0 -0.1" mass="0.6" diaginertia="0.005 0.005 0.005"/></body>
    </body>
  </worldbody>
  <equality><connect name="pin" body1="b" body2="world" anchor="0.3 0 0.2" solimp="0.99 0.99 0.001"/></equality>
</mujoco>
"""


def settled_violation(m: mujoco.MjModel, steps: int) -> float:
    """MuJoCo's own answer: the equality's violation once the held model has settled."""
    d = mujoco.MjData(m)
    for _ in range(steps):
        mujoco.mj_step(m, d)
    assert np.abs(d.qvel).max() < 1e-8  # settled
    return float(np.abs(d.efc_pos[: d.nefc]).max())


def test_soft_equality_sag_against_mujocos_settled_state():
    # a pendulum locked horizontal by a joint equality: exact for a constant impedance
    m = mujoco.MjModel.from_xml_string(LOCKED_XML.format(tc=0.02))
    (lock,) = model_gap(m, [0.0, 0.0], []).equalities
    assert (lock.name, lock.kind, lock.violation) == ("lock", "joint", 0.0)
    assert lock.sag == pytest.approx(settled_violation(m, 2000), rel=1e-6)
    # a two-link chain pinned to the world by a connect: first order in the sag (the chain moves by it)
    m = mujoco.MjModel.from_xml_string(PINNED_XML)
    (pin,) = model_gap(m, np.zeros(4), []).equalities
    assert pin.kind == "connect" and pin.sag == pytest.approx(settled_violation(m, 1000), rel=1e-2)
    # warnings: a softer lock sags above the threshold; x0 off the constraint
    soft = model_gap(mujoco.MjModel.from_xml_string(LOCKED_XML.format(tc=0.05)), [0.0, 0.0], [])
    assert soft.equalities[0].sag > EQUALITY_WARN > lock.sag and "equality" in effects(soft)
    assert "equality" not in effects(model_gap(m, np.zeros(4), []))
    off = model_gap(mujoco.MjModel.from_xml_string(LOCKED_XML.format(tc=0.02)), [0.01, 0.0], [])
    assert off.equalities[0].violation == pytest.approx(0.01) and "violates equality 'lock'" in off.format()


TENDON_XML = """
<mujoco><compiler angle="radian"/>
  <worldbody>
    <body name="a"><joint name="za" type="slide" axis="0 0 1"/>
      <inertial pos="0 0 0" mass="1" diaginertia="0.01 0.01 0.01"/></body>
    <body name="b" pos="1 0 0"><joint name="zb" type="slide" axis="0 0 1"/>
      <inertial pos="0 0 0" mass="2" diaginertia="0.01 0.01 0.01"/></body>
  </worldbody>
  <tendon>
    <fixed name="sum" frictionloss="{fl}" range="-0.1 0.5">
      <joint joint="za" coef="1"/><joint joint="zb" coef="1"/>
    </fixed>
  </tendon>
</mujoco>
"""


def test_tendon_friction_and_range_against_the_hand_load():
    # the tendon force that holds L = za + zb still under gravity: both masses would fall at g, so
    # L'' = −2g + f (1/1 + 1/2) = 0 gives f = 4g/3
    f_load = 4 * G / 3
    for fl, warns, holds in ((0.07 * f_load, False, False), (0.15 * f_load, True, False), (1.1 * f_load, True, True)):
        m = mujoco.MjModel.from_xml_string(TENDON_XML.format(fl=fl))
        (tendon,) = model_gap(m, [0.2, 0.1, 0.0, 0.0], []).tendons
        assert tendon.load == pytest.approx(f_load, rel=1e-12) and tendon.length == pytest.approx(0.3)
        assert tendon.friction_ratio == pytest.approx(fl / f_load) and tendon.friction_holds == holds
        assert tendon.limit_margin == pytest.approx(margin(0.3, -0.1, 0.5))
        gap = model_gap(m, [0.2, 0.1, 0.0, 0.0], [])
        assert ("friction" in effects(gap)) == warns and "limit" not in effects(gap)
    near = model_gap(m, [0.2, 0.28, 0.0, 0.0], [])  # L = 0.48: 3.3 % of the range from its top
    assert next(w.message for w in near.warnings if w.effect == "limit").startswith("tendon 'sum' at 0.48")
    assert model_gap(m, [0.3, 0.3, 0.0, 0.0], []).errors  # L = 0.6: outside


# --------------------------------------------------------------- thresholds
def test_friction_warns_above_its_threshold_only(arm):
    m = copy.copy(arm)  # a copy: the module's model keeps its friction loss
    q1, q2 = 0.3, 0.4
    load = hand_load(q1, q2)
    for ratio, warns in ((0.9 * FRICTION_WARN, False), (1.1 * FRICTION_WARN, True)):
        m.dof_frictionloss[:] = ratio * np.abs(load)
        gap = model_gap(m, x_at(q1, q2), [0.0, 0.0])
        assert gap.dofs[0].friction_ratio == pytest.approx(ratio, rel=1e-9)
        assert effects(gap).count("friction") == (2 if warns else 0)
        assert not any(d.friction_holds for d in gap.dofs)
    m.dof_frictionloss[:] = [1.01 * abs(load[0]), 0.0]  # friction alone holds the shoulder: a dead band
    gap = model_gap(m, x_at(q1, q2), [0.0, 0.0])
    assert gap.dofs[0].friction_holds and not gap.dofs[1].friction_holds and gap.dofs[1].friction_ratio is None
    assert "friction alone holds it" in gap.format()


def test_clamp_warnings_fire_above_and_not_below_the_threshold(arm):
    inside = 1.0 - 2 * (CLAMP_WARN + 0.01)  # 11 % of the range [-1, 1] from the top
    near = 1.0 - 2 * (CLAMP_WARN - 0.01)  # 9 %
    x = x_at(0.2, 0.0)
    assert "clamp" not in effects(model_gap(arm, x, [0.5 * inside, 0.0]))
    gap = model_gap(arm, x, [0.5 * near + 0.5, 0.0])  # ctrl 0.95 (2.5 %): motor torque 9.5 beyond actuatorfrcrange 8
    messages = [w.message for w in gap.warnings if w.effect == "clamp"]
    assert any("ctrlrange" in s and "m_shoulder" in s for s in messages)
    assert any("actuatorfrcrange" in s for s in messages) and gap.errors  # 9.5 N m outside [-8, 8]
    gap = model_gap(arm, x, [near * 0.8, 0.0])  # torque 7.4: within 10 % of 8 (3.75 %), ctrl 0.74 (13 %) fine
    assert [w.level for w in gap.warnings if w.effect == "clamp"] == ["warning"]
    assert "actuatorfrcrange" in next(w.message for w in gap.warnings if w.effect == "clamp")
    gap = model_gap(arm, x, [1.2, 0.0])
    assert any(w.level == "error" and "ctrlrange" in w.message for w in gap.warnings)
    assert gap.warnings[0].level == "error"  # errors first


def test_limit_warnings_fire_above_and_not_below_the_threshold(arm):
    width = LIM1[1] - LIM1[0]
    below = LIM1[1] - (LIMIT_WARN - 0.005) * width
    above = LIM1[1] - (LIMIT_WARN + 0.005) * width
    assert "limit" in effects(model_gap(arm, x_at(below, 0.0), [0, 0]))
    assert "limit" not in effects(model_gap(arm, x_at(above, 0.0), [0, 0]))
    # the elbow: 7.5 % of its range from the limit but inside its MuJoCo margin (0.22 < 0.25 rad): active
    gap = model_gap(arm, x_at(0.0, LIM2[1] - 0.22), [0, 0])
    assert [w for w in gap.warnings if w.effect == "limit" and "active" in w.message]
    assert "limit" not in effects(model_gap(arm, x_at(0.0, LIM2[1] - 0.3), [0, 0]))
    gap = model_gap(arm, x_at(1.6, 0.0), [0, 0])
    assert gap.dofs[0].limit_margin < 0 and ("error", "limit") in [(w.level, w.effect) for w in gap.warnings]
    loose = model_gap(arm, x_at(below, 0.0), [0, 0], thresholds=GapThresholds(limit=0.01))
    assert "limit" not in effects(loose)


def test_bad_input_is_refused(arm):
    with pytest.raises(InvalidArgument, match="x0"):
        model_gap(arm, [0.0, 0.0, 0.0], [0.0, 0.0])
    with pytest.raises(InvalidArgument, match="u0"):
        model_gap(arm, x_at(0, 0), [0.0])
    with pytest.raises(NonFiniteError):
        model_gap(arm, [0.0, math.nan, 0.0, 0.0], [0.0, 0.0])
    with pytest.raises(InvalidArgument, match="friction"):
        GapThresholds(friction=-0.1)


# ---------------------------------------------------------------- the plant
def test_mjcf_plant_model_gap_at_its_operating_point(arm_file):
    plant = MjcfPlant(arm_file)
    x0, u0 = plant.equilibrium()  # u0: the torques that hold the arm at x0
    gap = plant.model_gap()
    np.testing.assert_array_equal(gap.x0, x0)
    np.testing.assert_array_equal(gap.u0, u0)
    assert gap.model == plant.source_path
    np.testing.assert_allclose([d.actuator for d in gap.dofs], [d.load for d in gap.dofs], rtol=1e-9)
    np.testing.assert_allclose([d.load for d in gap.dofs], hand_load(*x0[:2]), rtol=1e-10)
    load = hand_load(*x0[:2])
    assert [d.frictionloss for d in gap.dofs] == [0.3, 0.05]
    assert [d.friction_ratio for d in gap.dofs] == pytest.approx([0.3 / abs(load[0]), 0.05 / abs(load[1])])
    one = MjcfPlant(arm_file, actuators=["p_elbow"])  # the motor is not an input: its control is 0
    q1 = math.asin((H - 0.025) / (L1 + L2))
    gap = one.model_gap([q1, 0, 0, 0], [0.3])
    assert [a.ctrl for a in gap.actuators] == [0.0, 0.3] and gap.n_contacts == 1
    with pytest.raises(InvalidArgument, match="x0"):
        plant.model_gap([0.0, 0.0], u0)
    with pytest.raises(InvalidArgument, match="u0"):
        one.model_gap(x0, [0.0, 0.0])


def test_activations_are_part_of_the_state():
    # a filter actuator's force is its activation (gain 1), not its control: x = [qpos; qvel; act]
    plant = MjcfPlant(asset_path("gallery/filtered_actuator.xml"))
    x0, u0 = plant.equilibrium()
    x = x0.copy()
    x[6] = 3.0  # the shoulder motor's activation
    gap = plant.model_gap(x, u0)
    assert gap.x0.shape == (9,) and gap.actuators[0].force == pytest.approx(3.0)
    assert gap.actuators[0].ctrl == u0[0] and gap.dofs[0].actuator == pytest.approx(3.0)
    # the wrist's integrator activation (its set-point) is clamped to actrange [-2, 2] in MuJoCo only
    for act, warns in ((1.9, True), (1.5, False)):
        x[8] = act
        wrist = plant.model_gap(x, u0).actuators[2]
        assert (wrist.act, wrist.actrange) == (act, (-2.0, 2.0))
        assert wrist.act_margin == pytest.approx(margin(act, -2, 2))
        assert any("actrange" in w.message for w in plant.model_gap(x, u0).warnings) == warns


def test_crosscheck_and_design_print_the_report(arm_file, tmp_path, capsys):
    q1 = math.asin((H - 0.025) / (L1 + L2))
    assert main(["crosscheck", arm_file, "--x0", f"{q1},0,0,0", "--u0", "0.95,0"]) == 0
    out = capsys.readouterr().out
    assert "model gap at the operating point" in out and "floor – tip" in out
    assert "warning: actuator 'm_shoulder': u0 = 0.95" in out
    elbow = next(line.split() for line in out.splitlines() if line.startswith("    elbow "))
    assert elbow[-2:] == ["0.05", f"{0.05 / abs(hand_load(q1, 0.0)[1]):.1%}"]  # frictionloss, friction/load
    # design: a one-joint arm (one input keeps the margin analysis cheap) held near its motor's clamp
    model = tmp_path / "pendulum.xml"
    model.write_text(PENDULUM_XML)
    scenario = tmp_path / "pendulum.toml"
    u0 = -0.5 * G * 0.3 * math.cos(0.3) / 1.6  # gravity torque at q = 0.3 over the gear: 6 % from the clamp
    for loop in ("standalone", "mujoco"):  # the file itself, or the model the scenario's MuJoCo loop runs
        scenario.write_text(
            f'[plant]\ntype = "MjcfPlant"\nmodel = "{model}"\nx0 = [0.3, 0]\n[engine]\ntype = "{loop}"\n'
            '[controller]\ntype = "LQR"\nQ = [10, 1]\nR = [1]\n[sim]\nduration = 0.2\n'
        )
        assert main(["design", "lqr", str(scenario)]) == 0
        out = capsys.readouterr().out
        assert "model gap at the operating point" in out and "contacts at x0: none" in out
        assert f"warning: actuator 'motor': u0 = {u0:.4g} against ctrlrange [-1, 1]" in out
    # a built-in plant in its MuJoCo loop: the report of its MuJoCo twin (no file of the user's)
    scenario.write_text(
        '[plant]\ntype = "InvertedPendulum"\n[engine]\ntype = "mujoco"\n'
        '[controller]\ntype = "LQR"\nQ = [10, 1]\nR = [1]\n[sim]\nduration = 0.2\n'
    )
    assert main(["design", "lqr", str(scenario)]) == 0
    out = capsys.readouterr().out
    assert "model gap at the operating point" in out and "inverted_pendulum.xml" not in out.split("model gap")[0]


def test_engine_model_gap_reads_the_engines_state_and_leaves_it(arm_file):
    engine = MujocoEngine(arm_file)
    x, u = np.array([0.4, -0.3, 0.2, 0.1]), np.array([0.3, -0.5])
    engine.set_state_vector(x)
    engine.set_ctrl(u)
    gap = engine_model_gap(engine)
    ref = model_gap(mujoco.MjModel.from_xml_path(arm_file), x, u)
    assert (gap.dofs, gap.actuators, gap.contacts, gap.warnings) == (
        ref.dofs,
        ref.actuators,
        ref.contacts,
        ref.warnings,
    )
    np.testing.assert_array_equal(engine.get_state_vector(), x)
    np.testing.assert_array_equal(engine.data.ctrl, u)


def test_free_joint_dofs_are_named_by_axis():
    m = mujoco.MjModel.from_xml_string(
        '<mujoco><worldbody><body name="b"><freejoint name="root"/><geom size="0.1" mass="2"/>'
        '<body><joint name="neck" type="ball"/><geom size="0.05" pos="0 0 0.2" mass="1"/></body></body>'
        "</worldbody></mujoco>"
    )
    x = np.r_[0, 0, 1, 1, 0, 0, 0, 1, 0, 0, 0, np.zeros(m.nv)]
    gap = model_gap(m, x, np.zeros(0))
    assert [d.name for d in gap.dofs] == [
        *(f"root.{a}" for a in ("x", "y", "z", "wx", "wy", "wz")),
        "neck.wx",
        "neck.wy",
        "neck.wz",
    ]
    assert gap.dofs[2].load == pytest.approx(3 * G) and all(d.q is None and d.range is None for d in gap.dofs)


def test_the_html_report_section(arm):
    from shinro_ctrl.analysis.report import model_gap_section

    q1 = math.asin((H - 0.025) / (L1 + L2))
    gap = model_gap(arm, x_at(q1, 0.0), [1.2, 0.0])
    page = model_gap_section(gap)
    assert page.startswith("<h2>Model gap") and page.count("<table>") == 3  # joints, actuators, contacts
    for name in ("shoulder", "elbow", "m_shoulder", "p_elbow", "floor", "tip"):
        assert f">{name}</td>" in page
    assert page.count("<li>") == len(gap.warnings) and '<span class="flag">error</span>' in page
    quiet = model_gap_section(model_gap(arm, x_at(0.2, 0.0), [0.0, 0.0]))
    assert "No contacts at x0" in quiet and quiet.count("<table>") == 2
    locked = model_gap_section(model_gap(mujoco.MjModel.from_xml_string(LOCKED_XML.format(tc=0.02)), [0, 0], []))
    assert "static sag under the load" in locked and ">lock</td>" in locked
    tendon = model_gap_section(model_gap(mujoco.MjModel.from_xml_string(TENDON_XML.format(fl=2)), [0, 0, 0, 0], []))
    assert ">sum</td>" in tendon and "Tendons with friction loss" in tendon


def test_crosscheck_with_a_bad_x0_is_one_line(arm_file, capsys):
    assert main(["crosscheck", arm_file, "--x0", "0.1,0,0"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "x0" in err and "Traceback" not in err
