"""Contact-constrained MjcfPlant (issue 26 items 3, 6): exact constrained dynamics, equilibrium, bad input.

References are independent of shinro_ctrl's multibody code: a hand-derived inverted pendulum on a point
foot (closed form), and the KKT system assembled from MuJoCo's own mass matrix, bias forces, point
Jacobians and their time derivatives (``mj_fullM``, ``qfrc_bias``, ``mj_jac``, ``mj_jacDot``).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import mujoco
import numpy as np
import pytest

from shinro_ctrl.errors import InvalidArgument, UnknownName
from shinro_ctrl.multibody.contacts import EquilibriumNotFound, standing_equilibrium
from shinro_ctrl.plants.mjcf import MjcfPlant

from .bad_input_helpers import check_one_line_exit_2

BIPED = Path(__file__).parent / "data" / "planar_biped_contacts.xml"

# an inverted pendulum: a planar floating body (x, z, pitch) standing on a point foot l below its centre of mass
M_BODY, I_YY, L_FOOT, G = 3.0, 0.07, 0.6, 9.81
PENDULUM = f"""
<mujoco model="point_foot_pendulum">
  <compiler angle="radian"/>
  <option timestep="0.002" gravity="0 0 -{G}"/>
  <worldbody>
    <geom name="floor" type="plane" size="2 2 0.1"/>
    <body name="body" pos="0 0 {L_FOOT}">
      <joint name="x" type="slide" axis="1 0 0"/>
      <joint name="z" type="slide" axis="0 0 1"/>
      <joint name="pitch" type="hinge" axis="0 1 0"/>
      <inertial pos="0 0 0" mass="{M_BODY}" diaginertia="0.05 {I_YY} 0.03"/>
      <geom name="foot" type="sphere" size="0.02" pos="0 0 -{L_FOOT}"/>
    </body>
  </worldbody>
  <actuator><motor name="tau" joint="pitch"/></actuator>
  <keyframe><key qpos="0.3 0 0.2"/></keyframe>
</mujoco>
"""


@pytest.fixture(scope="module")
def pendulum(tmp_path_factory):
    path = tmp_path_factory.mktemp("contacts") / "pendulum.xml"
    path.write_text(PENDULUM)
    return MjcfPlant(path, contacts=["foot"])


@pytest.fixture(scope="module")
def biped():
    return MjcfPlant(BIPED, contacts=["lfoot", "rfoot"])


def test_pendulum_on_a_point_foot_matches_the_closed_form(pendulum):
    """Foot held: (I + m l²) θ̈ = m g l sin θ + τ, ẍ = l(cos θ θ̈ − sin θ θ̇²), z̈ = −l(sin θ θ̈ + cos θ θ̇²)."""
    cd = pendulum.constraints
    assert [pendulum.joint_names[i] for i in cd.independent] == ["pitch"]
    for theta, thetad, tau in ((0.2, 0.0, 0.0), (-0.4, 1.3, 2.5), (0.9, -2.0, -4.0)):
        full = cd.complete(np.array([theta, thetad]))
        qdd, _ = cd.accelerations(full, np.array([tau]))
        tdd = (M_BODY * G * L_FOOT * np.sin(theta) + tau) / (I_YY + M_BODY * L_FOOT**2)
        xdd = L_FOOT * (np.cos(theta) * tdd - np.sin(theta) * thetad**2)
        zdd = -L_FOOT * (np.sin(theta) * tdd + np.cos(theta) * thetad**2)
        np.testing.assert_allclose(qdd, [xdd, zdd, tdd], rtol=0, atol=1e-9)
        np.testing.assert_allclose(
            pendulum.dynamics(np.array([theta, thetad]), np.array([tau])), [thetad, tdd], atol=1e-9
        )
        # the floor's force on the foot: m a_com − m g
        f = pendulum.contact_forces(np.array([theta, thetad]), np.array([tau]))["foot"]
        np.testing.assert_allclose(f, [M_BODY * xdd, 0.0, M_BODY * (zdd + G)], atol=1e-9)
    # the foot stays where the keyframe put it
    q = cd.complete(np.array([-0.3, 0.0]))[:3]
    foot = [q[0] - L_FOOT * np.sin(-0.3), L_FOOT + q[1] - L_FOOT * np.cos(-0.3)]  # the keyframe: x 0.3, pitch 0.2
    np.testing.assert_allclose(foot, [0.3 - L_FOOT * np.sin(0.2), L_FOOT - L_FOOT * np.cos(0.2)], atol=1e-12)


def _mujoco_kkt(path: Path, full: np.ndarray, u: np.ndarray, feet: list[str]) -> np.ndarray:
    """q̈ of M q̈ + c = τ + Jᵀλ, J q̈ + J̇ q̇ = 0 from MuJoCo's own terms (minimum-norm for redundant rows)."""
    m = mujoco.MjModel.from_xml_path(str(path))
    d = mujoco.MjData(m)
    m.opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_CONTACT
    d.qpos[:], d.qvel[:], d.ctrl[:] = full[: m.nq], full[m.nq :], u
    mujoco.mj_forward(m, d)
    M = np.zeros((m.nv, m.nv))
    for k in range(m.nv):
        col = np.zeros(m.nv)
        mujoco.mj_mulM(m, d, col, np.eye(m.nv)[k])
        M[:, k] = col
    rows, rhs = [], []
    for name in feet:
        g = m.geom(name).id
        jp, jd = np.zeros((3, m.nv)), np.zeros((3, m.nv))
        mujoco.mj_jac(m, d, jp, None, d.geom_xpos[g], m.geom_bodyid[g])
        mujoco.mj_jacDot(m, d, jd, None, d.geom_xpos[g], m.geom_bodyid[g])
        rows.append(jp)
        rhs.append(-jd @ d.qvel)
    J, b = np.vstack(rows), np.concatenate(rhs)
    K = np.block([[M, -J.T], [J, np.zeros((len(J), len(J)))]])
    sol = np.linalg.lstsq(K, np.r_[d.qfrc_actuator - d.qfrc_bias, b], rcond=None)[0]
    return sol[: m.nv]


def test_biped_constrained_accelerations_match_mujocos_kkt(biped):
    """Two point feet on a planar biped: 6 contact rows of rank 4 (the y rows vanish), handled; q̈ to 1e-9."""
    cd = biped.constraints
    assert len(cd.rows) == 4 and cd.ni == 3
    rng = np.random.default_rng(3)
    x0, u0 = biped.equilibrium()
    for _ in range(3):
        x = x0 + np.r_[0.1 * rng.standard_normal(3), rng.standard_normal(3)]
        u = u0 + 5 * rng.standard_normal(4)
        full = cd.complete(x)
        qdd, _ = cd.accelerations(full, u)
        np.testing.assert_allclose(qdd, _mujoco_kkt(BIPED, full, u, ["lfoot", "rfoot"]), rtol=0, atol=1e-9)


def test_biped_tangent_jacobians_match_central_differences(biped):
    x0, u0 = biped.equilibrium()
    rng = np.random.default_rng(5)
    x = x0 + np.r_[0.05 * rng.standard_normal(3), 0.5 * rng.standard_normal(3)]
    u = u0 + rng.standard_normal(4)
    A, B = biped.linearize(x, u)
    h = 1e-6
    Afd = np.column_stack([(biped.dynamics(x + h * e, u) - biped.dynamics(x - h * e, u)) / (2 * h) for e in np.eye(6)])
    Bfd = np.column_stack([(biped.dynamics(x, u + h * e) - biped.dynamics(x, u - h * e)) / (2 * h) for e in np.eye(4)])
    np.testing.assert_allclose(A, Afd, rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(B, Bfd, rtol=1e-6, atol=1e-6)


def test_standing_equilibrium_is_static_inside_the_cones_and_ranges(biped):
    eq = biped.standing_equilibrium()
    lo, hi = biped.input_bounds()
    assert np.all(eq.u >= lo) and np.all(eq.u <= hi)
    for f in biped.contacts:
        w = eq.forces[f.name]
        assert w[2] > 0 and np.hypot(w[0], w[1]) <= f.friction * w[2] + 1e-9
        assert eq.friction_margin[f.name] >= 0
    # the operating input is the equilibrium's, and it holds the robot still: ẋ = 0
    x0, u0 = biped.equilibrium()
    np.testing.assert_allclose(u0, eq.u)
    np.testing.assert_allclose(biped.dynamics(x0, u0), 0.0, atol=1e-5)
    # the total vertical force carries the weight (MuJoCo's masses)
    m = mujoco.MjModel.from_xml_path(str(BIPED))
    weight = 9.81 * float(m.body_mass.sum())
    assert sum(w[2] for w in eq.forces.values()) == pytest.approx(weight, rel=1e-9)


def test_equilibrium_failures_name_the_constraint(biped, tmp_path):
    cd, q = biped.constraints, biped.constraints.q_ref
    lo, hi = biped.input_bounds()
    # both feet ahead of the trunk: the centre of mass behind the support needs a foot pulled down (f_z < 0)
    behind = tmp_path / "behind.xml"
    behind.write_text(BIPED.read_text().replace('qpos="0 0 0 -0.5 0.7 0.3 0.5"', 'qpos="0 0 0 -0.6 0.2 -0.9 0.3"'))
    with pytest.raises(EquilibriumNotFound, match="does not exist: friction") as info:
        MjcfPlant(behind, contacts=["lfoot", "rfoot"])
    assert info.value.failure == "friction"
    # the same contacts on a floor without friction still hold it (vertical forces suffice): not a friction failure
    slippery = [dataclasses.replace(f, friction=0.0) for f in biped.contacts]
    eq = standing_equilibrium(cd, slippery, q, biped.active_actuators, (lo, hi))
    assert all(abs(w[0]) < 1e-6 for w in eq.forces.values())
    with pytest.raises(EquilibriumNotFound, match="torque") as info:
        standing_equilibrium(cd, biped.contacts, q, biped.active_actuators, (lo / 80, hi / 80))
    assert info.value.failure == "torque"


def test_posture_failure_on_one_point_foot():
    """One point foot: nothing can hold the centre of mass ahead of it (the robot pivots about the foot)."""
    with pytest.raises(EquilibriumNotFound, match="posture") as info:
        MjcfPlant(BIPED, contacts=["lfoot"])
    assert info.value.failure == "posture" and "\n" not in str(info.value)


def test_redundant_weld_beside_a_point_on_the_same_foot():
    """A welded sole beside a point contact on the same shin: 9 rows, rank 5 (3 planar weld rows + 2 point rows)."""
    welded = MjcfPlant(BIPED, contacts=["rsole", "lfoot"])
    both = MjcfPlant(BIPED, contacts=["rsole", "rfoot", "lfoot"])
    assert len(both.constraints.rows) == len(welded.constraints.rows) == 5
    x, u = welded.equilibrium()
    full = welded.constraints.complete(x + 0.1)  # moving: the same motion from either set of rows
    qdd_w, _ = welded.constraints.accelerations(full, u + 1.0)
    qdd_b, _ = both.constraints.accelerations(full, u + 1.0)
    np.testing.assert_allclose(qdd_b, qdd_w, atol=1e-9)
    forces = both.contact_forces(both.constraints.reduce(full), u)
    assert set(forces) == {"rsole", "rfoot", "lfoot"} and forces["rsole"].shape == (6,)


def test_bad_contacts():
    with pytest.raises(UnknownName, match=r"unknown contact 'lfot' \(did you mean 'lfoot'\?\).*rfoot \(geom\)"):
        MjcfPlant(BIPED, contacts=["lfot"])
    with pytest.raises(InvalidArgument, match=r"no free motion: .*contact 'trunk' \(flat, body\)"):
        MjcfPlant(BIPED, contacts=["trunk", "lfoot", "rfoot"])
    with pytest.raises(InvalidArgument, match="fixed to the world body"):
        MjcfPlant(BIPED, contacts=["floor"])
    with pytest.raises(InvalidArgument, match="twice"):
        MjcfPlant(BIPED, contacts=["lfoot", "lfoot"])
    with pytest.raises(InvalidArgument, match="list of geom"):
        MjcfPlant(BIPED, contacts="lfoot")


def test_a_free_base_on_one_point_foot_is_refused_in_one_line(tmp_path):
    """One point foot cannot fix a free base's rotation (enough contacts: tests/test_contacts_floating.py)."""
    path = tmp_path / "free.xml"
    path.write_text(
        '<mujoco><worldbody><body name="b"><freejoint name="root"/><geom name="s" type="sphere" size="0.1"/>'
        '<body name="leg" pos="0 0 -0.2"><joint name="hip" axis="0 1 0"/><geom name="foot" type="sphere" '
        'size="0.05"/></body></body></worldbody><actuator><motor joint="hip"/></actuator></mujoco>'
    )
    with pytest.raises(InvalidArgument, match=r"leave 1 rotation\(s\) of a ball or free joint free") as info:
        MjcfPlant(path, contacts=["foot"])
    assert "\n" not in str(info.value)


@pytest.mark.parametrize(
    ("contacts", "needle"),
    [
        ('["lfot"]', "unknown contact 'lfot'"),
        ('["trunk", "lfoot", "rfoot"]', "no free motion"),
        ('["lfoot"]', "posture"),
    ],
)
def test_bad_contacts_from_a_scenario_exit_2(contacts, needle, tmp_path, capsys):
    path = tmp_path / "biped.toml"
    path.write_text(
        f'[plant]\ntype = "MjcfPlant"\nmodel = "{BIPED}"\ncontacts = {contacts}\n\n'
        '[controller]\ntype = "LQR"\nQ = [1, 1, 1, 1, 1, 1]\nR = [1, 1, 1, 1]\n'
    )
    check_one_line_exit_2(["design", "lqr", str(path)], needle, capsys)
