"""Contacts on a free-joint base: the quadruped on its four point feet (tangent-space constrained dynamics).

References are independent of the code under test: the KKT system assembled from MuJoCo's own mass matrix,
smooth forces, ``mj_jac`` and ``mj_jacDot``; and central differences on the manifold (``q ⊕ h eₖ``).
"""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np
import pytest

from shinro_ctrl.engine.model_tree import read_contact_frames, read_model_tree
from shinro_ctrl.multibody.configuration import integrate
from shinro_ctrl.multibody.constraints import ConstrainedDynamics, Constraint
from shinro_ctrl.multibody.contacts import contact_constraints
from shinro_ctrl.multibody.rigid_body import RigidBodyTree
from shinro_ctrl.plants.mjcf import MjcfPlant
from shinro_ctrl.sim import RobotSim

ASSET = Path(__file__).resolve().parent.parent / "assets" / "quadruped.xml"
FEET = ("FL_foot", "FR_foot", "RL_foot", "RR_foot")
CONFIG = Path(__file__).resolve().parent.parent / "configs" / "quadruped_stand_lqr_mujoco.toml"


@pytest.fixture(scope="module")
def quadruped():
    model = mujoco.MjModel.from_xml_path(str(ASSET))
    plant = MjcfPlant(str(ASSET), contacts=list(FEET))
    return model, plant.tree, plant.constraints, plant


def _random_state(cd: ConstrainedDynamics, rng: np.random.Generator) -> np.ndarray:
    x = np.concatenate(
        [cd.q_ref[list(cd.independent_q)] + 0.05 * rng.standard_normal(cd.ni), rng.standard_normal(cd.ni)]
    )
    return cd.complete(x)


def test_independent_directions_are_joints_and_the_base_follows(quadruped):
    model, _, cd, _ = quadruped
    assert cd.nq == model.nq and cd.nv == model.nv and cd.ni == model.nv - 12
    assert set(range(6)) <= set(cd.dependent)  # the free joint's six tangent directions are dependent


def test_constrained_accelerations_match_a_kkt_of_mujocos_own_terms(quadruped):
    model, _, cd, _ = quadruped
    data = mujoco.MjData(model)
    rng = np.random.default_rng(7)
    nv = model.nv
    for _ in range(3):
        full = _random_state(cd, rng)
        q, v = full[: model.nq], full[model.nq :]
        u = 5.0 * rng.standard_normal(model.nu)
        data.qpos[:], data.qvel[:], data.ctrl[:] = q, v, u
        mujoco.mj_forward(model, data)
        M = np.zeros((nv, nv))
        col = np.zeros(nv)
        for k in range(nv):  # MuJoCo's own mass matrix (armature included), column by column
            mujoco.mj_mulM(model, data, col, np.eye(nv)[k].copy())
            M[:, k] = col
        J, Jdot = np.zeros((12, nv)), np.zeros((12, nv))
        for k, foot in enumerate(FEET):
            g = model.geom(foot)
            point = data.geom_xpos[g.id]
            jr = np.zeros((3, nv))
            mujoco.mj_jac(model, data, J[3 * k : 3 * k + 3], jr, point, g.bodyid[0])
            mujoco.mj_jacDot(model, data, Jdot[3 * k : 3 * k + 3], jr, point, g.bodyid[0])
        kkt = np.block([[M, J.T], [J, np.zeros((12, 12))]])
        ref = np.linalg.lstsq(kkt, np.concatenate([data.qfrc_smooth, -Jdot @ v]), rcond=None)[0][:nv]
        qdd, _ = cd.accelerations(full, u)
        assert np.abs(J @ v).max() < 1e-9  # the state is on the constraint (velocity level)
        np.testing.assert_allclose(qdd, ref, atol=1e-9 * max(1.0, np.abs(ref).max()))


def test_tangent_jacobians_match_central_differences_on_the_manifold(quadruped):
    _, tree, cd, _ = quadruped
    rng = np.random.default_rng(3)
    full = _random_state(cd, rng)
    q = full[: cd.nq]
    phi0, J = cd.constraint_jacobian(q)
    assert np.abs(phi0).max() < 1e-9
    h = 1e-6
    fd = np.zeros_like(J)
    for k in range(cd.nv):
        e = np.zeros(cd.nv)
        e[k] = h
        fd[:, k] = (
            cd.constraint_jacobian(integrate(tree, q, e))[0] - cd.constraint_jacobian(integrate(tree, q, -e))[0]
        ) / (2 * h)
    np.testing.assert_allclose(J, fd, atol=1e-8)
    # the reduced dynamics' A, B against central differences of xdot (completion on the manifold inside)
    x, u = cd.reduce(full), rng.standard_normal(12)
    A, B = cd.jacobians(x, u)
    h = 1e-5
    Afd = np.column_stack([(cd.xdot(x + h * e, u) - cd.xdot(x - h * e, u)) / (2 * h) for e in np.eye(x.size)])
    Bfd = np.column_stack([(cd.xdot(x, u + h * e) - cd.xdot(x, u - h * e)) / (2 * h) for e in np.eye(u.size)])
    np.testing.assert_allclose(A, Afd, atol=1e-5 * max(1.0, np.abs(A).max()))
    np.testing.assert_allclose(B, Bfd, atol=1e-6 * max(1.0, np.abs(B).max()))


def _mujoco_feet(model: mujoco.MjModel, data: mujoco.MjData) -> np.ndarray:
    """MuJoCo's point Jacobians ``(12, nv)`` of the four foot centres (``mj_jac``)."""
    J = np.zeros((12, model.nv))
    for k, foot in enumerate(FEET):
        g = model.geom(foot)
        mujoco.mj_jac(model, data, J[3 * k : 3 * k + 3], None, data.geom_xpos[g.id], g.bodyid[0])
    return J


def test_standing_equilibrium_balances_mujocos_forces_inside_the_cones_and_ranges(quadruped):
    model, _, cd, plant = quadruped
    eq = plant.standing_equilibrium()
    data = mujoco.MjData(model)
    data.qpos[:], data.ctrl[:] = eq.q, eq.u
    mujoco.mj_forward(model, data)
    lam = np.concatenate([eq.forces[f] for f in FEET])
    # static balance with MuJoCo's own terms: qfrc_smooth + Jᵀλ = 0 (the free base's six rows included)
    balance = data.qfrc_smooth + _mujoco_feet(model, data).T @ lam
    assert np.abs(balance).max() < 1e-7 * 9.81 * model.body_mass.sum()
    np.testing.assert_allclose(lam[2::3].sum(), 9.81 * model.body_mass.sum(), rtol=1e-9)  # the weight
    for f in FEET:  # inside the friction cones (exact cone, with a margin)
        w = eq.forces[f]
        assert w[2] > 0.0 and np.hypot(w[0], w[1]) < 0.9 * w[2]
        assert eq.friction_margin[f] > 0.0
    lo, hi = plant.input_bounds()
    assert np.all(eq.u >= lo) and np.all(eq.u <= hi)
    np.testing.assert_allclose(plant.equilibrium()[1], eq.u)  # the plant's u0
    assert np.abs(cd.xdot(plant.equilibrium()[0], eq.u)).max() < 1e-9  # and it is an equilibrium


def test_quadruped_stand_lqr_holds_and_recovers_from_a_push_in_mujoco():
    """The shipped scenario: LQR on the contact-constrained model, MuJoCo's own contacts, 30 N for 0.1 s sideways."""
    result = RobotSim.from_config(str(CONFIG)).run(progress=False)
    m = result.metrics
    push = np.asarray(result.disturbance)
    assert np.abs(push).max() >= 30.0  # the push was applied
    assert m["stable"] and m["trunk_height_error"] < 0.02 and m["trunk_orientation_error"] < 0.1
    assert m["foot_slip"] < 0.03 and m["friction_cone_fraction"] == 1.0
    assert m["final_error"] < 0.05


TRIPOD_WITH_COUPLING = """
<mujoco>
  <worldbody>
    <body name="base" pos="0 0 0.1">
      <freejoint name="root"/>
      <geom name="body" type="box" size="0.2 0.2 0.05" mass="2"/>
      <geom name="f1" type="sphere" size="0.02" pos="0.2 0 -0.05" mass="0.1"/>
      <geom name="f2" type="sphere" size="0.02" pos="-0.1 0.15 -0.05" mass="0.1"/>
      <geom name="f3" type="sphere" size="0.02" pos="-0.1 -0.15 -0.05" mass="0.1"/>
      <body name="arm" pos="0 0 0.05">
        <joint name="h1" axis="0 1 0"/>
        <geom type="capsule" fromto="0 0 0 0.2 0 0" size="0.02" mass="0.3"/>
        <body name="hand" pos="0.2 0 0">
          <joint name="h2" axis="0 1 0"/>
          <geom type="capsule" fromto="0 0 0 0.15 0 0" size="0.02" mass="0.2"/>
        </body>
      </body>
    </body>
  </worldbody>
  <actuator><motor joint="h1"/></actuator>
</mujoco>
"""


def test_a_joint_coupling_behind_a_free_root_reads_its_joints_qpos_entries(tmp_path):
    """``h2 = ½ h1`` on a base held by three point feet: the coupling reads ``qpos[jnt_qposadr]``, not ``qpos[j]``."""
    path = tmp_path / "tripod.xml"
    path.write_text(TRIPOD_WITH_COUPLING)
    model = mujoco.MjModel.from_xml_path(str(path))
    tree = read_model_tree(str(path))
    rb = RigidBodyTree(tree)
    frames = read_contact_frames(str(path))
    j1, j2 = model.joint("h1").id, model.joint("h2").id
    q0 = model.qpos0.copy()
    coupling = Constraint("joint", label="h2 = h1 / 2", joint1=j2, joint2=j1, polycoef=(0.0, 0.5, 0.0, 0.0, 0.0))
    cons = [coupling, *contact_constraints(rb, [frames[f] for f in ("f1", "f2", "f3")], q0)]
    cd = ConstrainedDynamics(rb, cons, active=(0,), q_ref=q0)
    a1, a2 = model.jnt_qposadr[j1], model.jnt_qposadr[j2]
    d1, d2 = model.jnt_dofadr[j1], model.jnt_dofadr[j2]
    assert cd.independent == (d1,)
    full = cd.complete(np.array([0.3, -0.7]))
    q, v = full[: model.nq], full[model.nq :]
    assert q[a2] == pytest.approx(0.5 * q[a1], abs=1e-12) and v[d2] == pytest.approx(0.5 * v[d1], abs=1e-12)
    np.testing.assert_allclose(q[:7], q0[:7], atol=1e-12)  # the base stays on its three feet
    np.testing.assert_allclose(v[:6], 0.0, atol=1e-12)
