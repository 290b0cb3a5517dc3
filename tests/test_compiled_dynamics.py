"""Exact robot dynamics run compiled: the articulated-body algorithm and the compiled f and Jacobians of MjcfPlant.

References, independent of the code under test:

* forward dynamics: MuJoCo's ``qacc_smooth`` (contacts and limits off: not smooth dynamics) and the other algorithm
  of ``RigidBodyTree.forward_dynamics`` (ABA against RNEA + CRBA + LDLᵀ);
* Jacobians: complex-step differentiation of the scalar algorithms on complex numbers (no CasADi involved), against
  the compiled implicit-differentiation Jacobians (RNEA's reverse-mode derivative times ``M̃⁻¹``).

The forward-dynamics comparisons run the scalar algorithms on floats (nothing compiled); the compiled checks use the
shipped arm and pendulums, which the rest of the suite compiles anyway (one shared cache per session, conftest.py).
"""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from shinro_ctrl.codegen import CompilerUnavailable, cache_dir
from shinro_ctrl.engine.model_tree import read_robot
from shinro_ctrl.errors import NonFiniteError
from shinro_ctrl.multibody import RigidBodyTree
from shinro_ctrl.plants import MjcfPlant
from shinro_ctrl.resources import asset_path

from .thread_helpers import in_threads

SHIPPED = ("panda_like_arm.xml", "furuta_pendulum.xml", "double_pendulum.xml", "cartpole.xml", "inverted_pendulum.xml")
# The models of the generalized forces and states ABA's callers add: fixed tendons, site transmissions (thrusters),
# gravity compensation, actuator activations in the state (assets/gallery/, tests/test_mjcf_features.py)
FEATURES = (
    "gallery/gripper_tendon.xml",
    "gallery/thruster.xml",
    "gallery/gravcomp_arm.xml",
    "gallery/filtered_actuator.xml",
)

# A branched tree for ABA's less travelled paths: slide joints before and after hinges, two joints on one body, a
# welded body, a branch point carrying two subtrees, tilted full inertias, off-axis anchors, qpos0 (ref) offsets,
# armature, damping and a spring, a position servo with a bias.
BRANCHED_XML = """
<mujoco model="branched">
  <compiler angle="radian"/>
  <option timestep="0.002" gravity="0.4 -0.3 -9.81"><flag contact="disable"/></option>
  <worldbody>
    <body name="carriage" pos="0.1 0 0.5" quat="0.96 0.1 0.2 0.1">
      <joint name="rail" type="slide" axis="1 0.2 0" damping="0.3" armature="0.02"/>
      <inertial pos="0.02 -0.01 0.03" mass="2.0" fullinertia="0.03 0.04 0.05 0.001 -0.002 0.003"/>
      <body name="hub" pos="0 0.1 0.05">
        <joint name="yaw" axis="0 0 1" pos="0.01 0 0" ref="0.3" armature="0.01"/>
        <joint name="pitch" axis="0 1 0" pos="0 0.02 0" stiffness="2.0" springref="0.2"/>
        <inertial pos="0.05 0.01 -0.02" mass="0.8" diaginertia="0.004 0.005 0.003" quat="0.9 0.3 0.1 0.2"/>
        <body name="bracket" pos="0.1 0 0">
          <inertial pos="0 0.02 0" mass="0.3" diaginertia="0.001 0.002 0.001"/>
          <body name="left" pos="0.05 0.1 0" quat="0.7 0.7 0 0">
            <joint name="left_hinge" axis="1 0 0" damping="0.05"/>
            <inertial pos="0 0 0.1" mass="0.4" fullinertia="0.002 0.002 0.0005 0.0001 0 0.0002"/>
            <body name="left_tip" pos="0 0 0.2">
              <joint name="left_slide" type="slide" axis="0 0.3 1" ref="0.05"/>
              <inertial pos="0.01 0 0.02" mass="0.1" diaginertia="0.0002 0.0002 0.0001"/>
            </body>
          </body>
          <body name="right" pos="0.05 -0.1 0">
            <joint name="right_hinge" axis="0.2 1 0.1" damping="0.05" armature="0.005"/>
            <inertial pos="0.1 0 0" mass="0.5" diaginertia="0.001 0.003 0.003"/>
          </body>
        </body>
      </body>
    </body>
  </worldbody>
  <actuator>
    <motor name="push" joint="rail" gear="5"/>
    <motor name="turn" joint="yaw"/>
    <position name="servo" joint="pitch" kp="20" kv="1"/>
    <motor name="left" joint="left_hinge" gear="2"/>
    <motor name="right" joint="right_hinge"/>
  </actuator>
</mujoco>
"""


@pytest.fixture(scope="module")
def branched_path(tmp_path_factory):
    path = tmp_path_factory.mktemp("compiled") / "branched.xml"
    path.write_text(BRANCHED_XML)
    return path


def _smooth_mujoco(path) -> tuple[mujoco.MjModel, mujoco.MjData]:
    m = mujoco.MjModel.from_xml_path(str(path))
    m.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_LIMIT) | int(mujoco.mjtDisableBit.mjDSBL_CONTACT)
    m.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_EULERDAMP)
    # the clamps act in MuJoCo's loop only (the smooth model leaves them out by design)
    m.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_CLAMPCTRL)
    m.actuator_forcelimited[:] = 0
    m.jnt_actfrclimited[:] = 0
    return m, mujoco.MjData(m)


def _arm6_without_gravcomp(tmp_path) -> str:
    """The shipped 6-DOF arm (another kinematics than the Panda-like one) without its gravcomp, if present."""
    path = tmp_path / "arm6_plain.xml"
    text = asset_path("arm6.xml").read_text().replace('gravcomp="1"', 'gravcomp="0"')
    path.write_text(text.replace('file="', f'file="{asset_path("arm6.xml").parent}/'))
    return str(path)


def _rel(a: np.ndarray, ref: np.ndarray) -> float:
    return float(np.abs(a - ref).max() / max(1.0, np.abs(ref).max()))


@pytest.mark.parametrize("name", (*SHIPPED, *FEATURES, "arm6", "branched"))
def test_aba_equals_rnea_crba_and_mujoco_qacc_smooth(name, branched_path, tmp_path):
    if name == "branched":
        path = str(branched_path)
    else:
        path = _arm6_without_gravcomp(tmp_path) if name == "arm6" else str(asset_path(name))
    tree = read_robot(path).tree
    aba, crba = RigidBodyTree(tree, "aba"), RigidBodyTree(tree, "crba")
    assert aba.algorithm == "aba"
    m, d = _smooth_mujoco(read_robot(path).path)
    n, every = tree.nq, tuple(range(tree.nu))
    rng = np.random.default_rng(2024)
    worst = [0.0, 0.0]
    for _ in range(10):
        x = np.r_[rng.uniform(-2.5, 2.5, n), rng.uniform(-3, 3, n), rng.uniform(-1, 1, tree.na)]
        u = rng.uniform(-2, 2, tree.nu)
        qdd = aba.xdot_numpy(x, u, every)[n : 2 * n]
        d.qpos[:], d.qvel[:], d.act[:], d.ctrl[:] = x[:n], x[n : 2 * n], x[2 * n :], u
        mujoco.mj_forward(m, d)
        worst[0] = max(worst[0], _rel(qdd, crba.xdot_numpy(x, u, every)[n : 2 * n]))
        worst[1] = max(worst[1], _rel(qdd, d.qacc_smooth))
    assert worst[0] <= 1e-12, f"ABA vs RNEA/CRBA/LDL: {worst[0]:.1e}"
    assert worst[1] <= 1e-12, f"ABA vs MuJoCo qacc_smooth: {worst[1]:.1e}"


def test_an_unknown_forward_dynamics_algorithm_is_refused():
    tree = read_robot(asset_path("double_pendulum.xml")).tree
    with pytest.raises(ValueError, match="unknown forward-dynamics algorithm 'featherstone'; valid: aba, crba"):
        RigidBodyTree(tree, "featherstone")


def test_inverse_dynamics_inverts_forward_dynamics(branched_path):
    rb = RigidBodyTree(read_robot(branched_path).tree)
    rng = np.random.default_rng(5)
    q, qd, tau = rng.uniform(-1, 1, (3, rb.nq))
    qdd = rb.forward_dynamics(list(q), list(qd), list(tau))
    np.testing.assert_allclose(rb.inverse_dynamics(list(q), list(qd), qdd), tau, rtol=0, atol=1e-12)


@pytest.fixture(scope="module")
def panda() -> MjcfPlant:
    return MjcfPlant("panda_like_arm.xml")


def test_the_arm_runs_compiled_code_from_the_cache(panda):
    panda.linearize()
    assert all(f.is_a("External") for f in panda.compiled_functions())  # machine code, not CasADi's VM
    names = {p.name.split("_")[1] for p in cache_dir().glob("mjcf_*.so")}
    assert {"f", "jac"} <= names  # in the session's cache folder (conftest.py)


@pytest.mark.parametrize(
    "name", ("panda_like_arm.xml", "furuta_pendulum.xml", "cartpole.xml", "gallery/thruster.xml", *FEATURES[2:])
)
def test_compiled_f_and_jacobians_equal_the_scalar_algorithms_and_complex_step(name):
    plant = MjcfPlant(name)
    rb, n, nq = plant.rigid_body_tree, plant.state_dim, plant.tree.nq
    x0, u0 = plant.equilibrium()
    rng = np.random.default_rng(3)
    for _ in range(2):
        x = x0 + np.r_[rng.uniform(-1, 1, nq), rng.uniform(-2, 2, nq), rng.uniform(-1, 1, plant.tree.na)]
        u = u0 + rng.uniform(-0.5, 0.5, plant.input_dim)
        f_ref = rb.xdot_numpy(x, u, plant.active_actuators)
        assert _rel(plant.dynamics(x, u), f_ref) <= 1e-13
        A, B = plant.linearize(x, u)
        h = 1e-30
        Ac = np.column_stack([rb.xdot_numpy(x + 1j * h * e, u, plant.active_actuators).imag / h for e in np.eye(n)])
        Bc = np.column_stack(
            [rb.xdot_numpy(x.astype(complex), u + 1j * h * e, plant.active_actuators).imag / h for e in np.eye(u.size)]
        )
        assert _rel(np.hstack([A, B]), np.hstack([Ac, Bc])) <= 1e-12


def test_an_actuator_subset_shares_the_arms_library_and_gets_its_columns(panda):
    sub = MjcfPlant("panda_like_arm.xml", actuators=["motor5", "motor2"])
    x0, _ = panda.equilibrium()
    rng = np.random.default_rng(9)
    x = x0 + rng.uniform(-0.5, 0.5, x0.size)
    u_sub = rng.uniform(-0.2, 0.2, 2)
    u_all = np.zeros(panda.input_dim)
    u_all[[4, 1]] = u_sub
    A, B = sub.linearize(x, u_sub)
    Af, Bf = panda.linearize(x, u_all)
    np.testing.assert_array_equal(A, Af)
    np.testing.assert_array_equal(B, Bf[:, [4, 1]])
    np.testing.assert_array_equal(sub.dynamics(x, u_sub), panda.dynamics(x, u_all))
    # the very same compiled functions (one library per model, whatever the actuator selection)
    assert all(a is b for a, b in zip(sub.compiled_functions(), panda.compiled_functions(), strict=True))
    assert all(f.is_a("External") for f in sub.compiled_functions())


def test_threads_linearizing_a_fresh_plant_at_once_get_the_serial_results():
    """The first linearize builds the Jacobian function under a lock; then every thread evaluates in its own buffer."""
    plant = MjcfPlant("double_pendulum.xml")
    x0, u0 = plant.equilibrium()
    rng = np.random.default_rng(4)
    X = x0 + rng.uniform(-1, 1, (4, 50, x0.size))

    def work(t: int) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
        return [(*plant.linearize(x, u0), plant.dynamics(x, u0)) for x in X[t]]

    results = in_threads(work, range(4))
    serial = MjcfPlant("double_pendulum.xml")
    for t in range(4):
        for x, (A, B, f) in zip(X[t], results[t], strict=True):
            As, Bs = serial.linearize(x, u0)
            np.testing.assert_array_equal(A, As)
            np.testing.assert_array_equal(B, Bs)
            np.testing.assert_array_equal(f, serial.dynamics(x, u0))


def test_the_fast_paths_give_the_general_paths_results_and_errors(panda):
    """float64 arrays take the compiled fast path; lists, ints and NaN take the general path: same answers."""
    x0, u0 = panda.equilibrium()
    A, B = panda.linearize(x0, u0)
    A2, B2 = panda.linearize(list(x0), list(u0))
    np.testing.assert_array_equal(A, A2)
    np.testing.assert_array_equal(B, B2)
    np.testing.assert_array_equal(panda.dynamics(x0, u0), panda.dynamics(list(x0), list(u0)))
    xi = np.zeros(x0.size, dtype=int)
    np.testing.assert_array_equal(panda.dynamics(xi, u0), panda.dynamics(xi.astype(float), u0))
    bad = x0.copy()
    bad[3] = np.nan
    with pytest.raises(NonFiniteError, match="x0 must be finite"):
        panda.linearize(bad, u0)
    with pytest.raises(NonFiniteError, match=r"x holds NaN or inf \(in joint4\)"):
        panda.dynamics(bad, u0)
    with pytest.raises(NonFiniteError, match="u holds NaN or inf"):
        panda.dynamics(x0, np.full(u0.size, np.inf))


def test_without_a_compiler_the_plant_runs_on_casadis_vm_with_one_warning(tmp_path, monkeypatch):
    """A model never compiled, no compiler: same results from the virtual machine, one CompilerUnavailable line."""
    copy = tmp_path / "pendulum_copy.xml"
    copy.write_text(asset_path("double_pendulum.xml").read_text())
    monkeypatch.setenv("SHINRO_CTRL_CACHE", str(tmp_path / "cache"))
    monkeypatch.setenv("CC", str(tmp_path / "no-such-cc"))
    with pytest.warns(CompilerUnavailable) as record:
        vm = MjcfPlant(copy)
        x0, u0 = vm.equilibrium()
        A, B = vm.linearize(x0 + 0.1, u0)
    assert len(record) == 1 and "no-such-cc" in str(record[0].message)
    assert not any(f.is_a("External") for f in vm.compiled_functions())
    monkeypatch.undo()
    ref = MjcfPlant("double_pendulum.xml")
    assert all(f.is_a("External") for f in ref.compiled_functions())
    Ar, Br = ref.linearize(x0 + 0.1, u0)
    assert _rel(np.hstack([A, B]), np.hstack([Ar, Br])) <= 1e-14
    assert _rel(vm.dynamics(x0 + 0.1, u0), ref.dynamics(x0 + 0.1, u0)) <= 1e-15
