"""Equality constraints in MjcfPlant: exact constrained dynamics in the independent coordinates.

References, each independent of shinro_ctrl's code:

* the four-bar (assets/gallery/four_bar.xml): loop closure solved in closed form (circle intersection)
  and the Lagrange equations of three planar rods in absolute angles, written out below, with the
  KKT system solved by numpy;
* the coupled gripper (gripper_equality.xml, gripper_mimic.urdf): the reduced Lagrangian of one
  coordinate with the coupling ``q₂ = c₁ q₁ + c₂ q₁²``, written out below;
* MuJoCo's soft equality solution (``qacc`` of ``mj_forward`` at a state on the constraints);
* central differences of the hand-derived four-bar for the exact Jacobians.
"""

from __future__ import annotations

import numpy as np
import pytest

mujoco = pytest.importorskip("mujoco")

from shinro_ctrl.errors import InvalidArgument  # noqa: E402
from shinro_ctrl.plants import MjcfPlant  # noqa: E402
from shinro_ctrl.resources import asset_path  # noqa: E402

G = 9.81

# ----------------------------------------------------------------------------- the four-bar, by hand
# Numbers of assets/gallery/four_bar.xml: ground pivots A, D in (x, z); link lengths, COM distances, masses and
# inertias about the hinge axis y; the bodies' pose angles at qpos0 (MuJoCo's rotation about +y by phi turns the
# body's x axis into (cos phi, -sin phi) in (x, z)); joint damping.
A_PIVOT, D_PIVOT = np.array([0.0, 0.5]), np.array([0.4, 0.5])
LENGTH = np.array([0.1, 0.35, 0.3])
COM = LENGTH / 2
MASS = np.array([0.2, 0.35, 0.3])
INERTIA = MASS * LENGTH**2 / 12
BETA = np.array([-0.9424777960769379, 0.29037548695805393, 2.0111939080902728])
DAMPING = 0.002
E_REL = np.array([[1.0, 0.0, 0.0], [-1.0, 1.0, 0.0], [0.0, -1.0, 1.0]])  # relative joint angles = E @ absolute


def _e(phi: float) -> np.ndarray:
    return np.array([np.cos(phi), -np.sin(phi)])


def four_bar_closure(theta1: float, dtheta1: float) -> tuple[np.ndarray, np.ndarray]:
    """Absolute angles and rates of the three links for crank angle theta1 (upper branch), in closed form."""
    p1 = BETA[0] + theta1
    B = A_PIVOT + LENGTH[0] * _e(p1)
    r = np.linalg.norm(D_PIVOT - B)
    ex = (D_PIVOT - B) / r
    along = (LENGTH[1] ** 2 - LENGTH[2] ** 2 + r * r) / (2 * r)
    C = B + along * ex + np.sqrt(LENGTH[1] ** 2 - along**2) * np.array([-ex[1], ex[0]])
    p2 = np.arctan2(-(C[1] - B[1]), C[0] - B[0])
    p3 = np.arctan2(-(D_PIVOT[1] - C[1]), D_PIVOT[0] - C[0])
    phi = np.array([p1, p2, p3])
    Gm = _closure_jacobian(phi)
    dphi = np.zeros(3)
    dphi[0] = dtheta1
    dphi[1:] = np.linalg.solve(Gm[:, 1:], -Gm[:, 0] * dtheta1)
    return phi, dphi


def _closure_jacobian(phi: np.ndarray) -> np.ndarray:
    """d/dphi of the loop closure sum_j L_j e(phi_j) + A - D = 0 (2 x 3)."""
    return np.array([-LENGTH * np.sin(phi), -LENGTH * np.cos(phi)])


def four_bar_hand(theta1: float, dtheta1: float, u: float) -> tuple[np.ndarray, np.ndarray]:
    """Joint coordinates [theta; dtheta] (6,) and accelerations ddtheta (3,) from the Lagrange equations + KKT."""
    phi, dphi = four_bar_closure(theta1, dtheta1)
    # lever arms: ell[k][j] = L_j (j < k), COM_k (j == k), 0 (j > k)
    ell = np.array([[LENGTH[j] if j < k else COM[k] if j == k else 0.0 for j in range(3)] for k in range(3)])
    a = np.einsum("k,ki,kj->ij", MASS, ell, ell) + np.diag(INERTIA)
    diff = phi[:, None] - phi[None, :]
    M = a * np.cos(diff)
    coriolis = (a * np.sin(diff)) @ dphi**2
    gravity = G * np.cos(phi) * (MASS @ ell)  # -dV/dphi
    dtheta = E_REL @ dphi
    forces = E_REL.T @ (np.array([u, 0.0, 0.0]) - DAMPING * dtheta)
    Gm = _closure_jacobian(phi)
    gdot = np.array([-(LENGTH * np.cos(phi)) @ dphi**2, (LENGTH * np.sin(phi)) @ dphi**2])
    K = np.block([[M, Gm.T], [Gm, np.zeros((2, 2))]])
    ddphi = np.linalg.solve(K, np.r_[forces - coriolis + gravity, -gdot])[:3]
    theta = E_REL @ phi - BETA
    theta = (theta + np.pi) % (2 * np.pi) - np.pi
    return np.r_[theta, dtheta], E_REL @ ddphi


# -------------------------------------------------------------------------- the gripper, by hand
def gripper_hand(
    q1: float, dq1: float, u: float, *, c1: float, c2: float, tilt: float, kp: float, kv: float, motor: bool
) -> tuple[float, float]:
    """(ddq1, ddq2) of two fingers coupled by q2 = c1 q1 + c2 q1² (reduced Lagrangian in q1).

    Left finger (mass 0.05, armature a1, damping 0.2) slides along the palm's +x, the right one (0.07, a2, 0.5)
    along -x; the palm is tilted by ``tilt`` about y, so gravity pulls m1 g sin(tilt) along +q1 and
    -m2 g sin(tilt) along +q2. Input: a position servo kp (u - q1) - kv dq1, or a motor u.
    """
    m1, m2 = 0.05, 0.07
    a1, a2 = (0.001, 0.002) if not motor else (0.0, 0.0)
    b1, b2 = 0.2, 0.5
    k = c1 + 2 * c2 * q1
    dk = 2 * c2
    mass = m1 + a1 + (m2 + a2) * k**2
    force = (u if motor else kp * (u - q1) - kv * dq1) - b1 * dq1 - b2 * k * k * dq1
    force += G * np.sin(tilt) * (m1 - m2 * k)
    ddq1 = (force - (m2 + a2) * k * dk * dq1**2) / mass
    return ddq1, k * ddq1 + dk * dq1**2


GRIPPER = {"c1": 0.8, "c2": 1.5, "tilt": 0.5, "kp": 100.0, "kv": 2.0, "motor": False}
MIMIC = {"c1": 1.0, "c2": 0.0, "tilt": 0.3, "kp": 0.0, "kv": 0.0, "motor": True}


# ------------------------------------------------------------------------------------- fixtures
@pytest.fixture(scope="module")
def four_bar() -> MjcfPlant:
    return MjcfPlant(asset_path("gallery/four_bar.xml"))


@pytest.fixture(scope="module")
def gripper() -> MjcfPlant:
    return MjcfPlant(asset_path("gallery/gripper_equality.xml"))


FOUR_BAR_STATES = [(0.0, 0.0, 0.0), (0.7, 1.5, 0.4), (-1.3, -3.0, -0.2), (2.5, 0.8, 0.1)]


# ----------------------------------------------------------------------------------------- tests
def test_four_bar_design_coordinates_are_the_crank(four_bar: MjcfPlant) -> None:
    assert four_bar.state_names == ("crank", "crank_dot")
    assert four_bar.input_names == ("crank_motor",)
    cd = four_bar.constraints
    assert cd.rows == (0, 2)  # the loop's y row is identically zero in a planar linkage: dropped as redundant
    assert (cd.independent, cd.dependent) == ((0,), (1, 2))


@pytest.mark.parametrize(("theta1", "dtheta1", "u"), FOUR_BAR_STATES)
def test_four_bar_matches_hand_derived_lagrange(four_bar: MjcfPlant, theta1: float, dtheta1: float, u: float) -> None:
    full_hand, ddtheta_hand = four_bar_hand(theta1, dtheta1, u)
    xdot = four_bar.dynamics([theta1, dtheta1], [u])
    scale = max(1.0, np.abs(ddtheta_hand).max())
    assert np.abs(xdot - [dtheta1, ddtheta_hand[0]]).max() <= 1e-9 * scale
    full = four_bar.constraints.complete(np.array([theta1, dtheta1]))
    assert np.abs(full - full_hand).max() <= 1e-11
    ddq, _ = four_bar.constraints.accelerations(full, np.array([u]))
    assert np.abs(ddq - ddtheta_hand).max() <= 1e-9 * scale


def test_four_bar_exact_jacobians_match_central_differences_of_the_hand_model(four_bar: MjcfPlant) -> None:
    def f(x: np.ndarray, u: np.ndarray) -> np.ndarray:
        return np.array([x[1], four_bar_hand(x[0], x[1], u[0])[1][0]])

    h = 1e-6
    for x, u in ((np.array([0.0, 0.0]), None), (np.array([0.9, -2.0]), np.array([0.3]))):
        u = four_bar.equilibrium()[1] if u is None else u
        A, B = four_bar.linearize(x, u)
        A_fd = np.column_stack([(f(x + h * e, u) - f(x - h * e, u)) / (2 * h) for e in np.eye(2)])
        B_fd = ((f(x, u + h) - f(x, u - h)) / (2 * h))[:, None]
        assert np.abs(A - A_fd).max() <= 1e-6 * max(1.0, np.abs(A).max())
        assert np.abs(B - B_fd).max() <= 1e-6 * max(1.0, np.abs(B).max())


def test_symbolic_dynamics_equal_the_exact_ones_near_the_reference(four_bar: MjcfPlant) -> None:
    f = four_bar.symbolic()
    for x, u in ((np.array([0.3, 1.0]), 0.1), (np.array([-0.5, -2.0]), -0.3)):
        assert np.abs(np.asarray(f(x, u)).ravel() - four_bar.dynamics(x, [u])).max() <= 1e-10


@pytest.mark.parametrize("q1", [0.0, 0.02, 0.04])
@pytest.mark.parametrize(("dq1", "u"), [(0.0, 0.0), (0.3, 0.03), (-0.5, -0.01)])
def test_coupled_gripper_matches_hand_derived_reduced_model(
    gripper: MjcfPlant, q1: float, dq1: float, u: float
) -> None:
    assert gripper.state_names == ("left", "left_dot")
    ddq1, ddq2 = gripper_hand(q1, dq1, u, **GRIPPER)
    xdot = gripper.dynamics([q1, dq1], [u])
    assert np.abs(xdot - [dq1, ddq1]).max() <= 1e-9 * max(1.0, abs(ddq1))
    full = gripper.constraints.complete(np.array([q1, dq1]))
    assert full[1] == pytest.approx(0.8 * q1 + 1.5 * q1**2, abs=1e-14)
    ddq, _ = gripper.constraints.accelerations(full, np.array([u]))
    assert np.abs(ddq - [ddq1, ddq2]).max() <= 1e-9 * max(1.0, abs(ddq1))


def test_urdf_mimic_becomes_a_coupling_driven_by_the_leader() -> None:
    plant = MjcfPlant(asset_path("gallery/gripper_mimic.urdf"))
    assert plant.input_names == ("left",)  # no motor on the mimic joint: its leader drives it
    assert plant.state_names == ("left", "left_dot")
    assert "<mimic> on joint 'right'" in plant.constraints.constraints[0].label
    for q1, dq1, u in ((0.01, 0.2, 0.5), (0.03, -0.4, -0.1)):
        ddq1, _ = gripper_hand(q1, dq1, u, **MIMIC)
        # MuJoCo writes its URDF translation with 6 significant digits (the joint origins' rpy): ~1e-7 relative
        assert plant.dynamics([q1, dq1], [u])[1] == pytest.approx(ddq1, rel=1e-6)


# --------------------------------------------------------------------------- MuJoCo's soft solution
# MuJoCo's equality is soft: at a state on the constraints (position and velocity residuals ~1e-16, so its
# reference acceleration is just the -J̇q̇ term) the constraint force solves (A + R) f = -J a_smooth - J̇q̇ with
# A = J M⁻¹ Jᵀ and R = (1 - d)/d · (diagonal approximation of A), d = solimp's impedance. Its qacc therefore differs
# from the exact (R = 0) one by a relative O((1 - d)/d) of the constraint's effect |qacc_smooth - qacc_exact|,
# times a conditioning factor of A: measured 1-3 for the four-bar, gripper and connect, ~100 for the site weld
# (six rows on seven joints, one nearly redundant). With d = 0.9999 (MuJoCo's largest) we accept 200 (1 - d)/d
# = 2e-2 of that effect; a wrong or missing constraint row changes qacc by O(100 %) of it. And the gap must
# shrink at least 5-fold when 1 - d shrinks 10-fold: it is the softness, not a modelling error.
SOFT_D = 0.9999

WELD_XML = """<mujoco><option gravity="0 0 -9.81"/><worldbody>
<body name="a1" pos="0 0 1"><joint name="ja1" axis="0 1 0"/>
 <inertial pos="0.2 0 0" mass="1" diaginertia="0.01 0.02 0.03"/>
 <body name="a2" pos="0.4 0 0" euler="0 30 0"><joint name="ja2" axis="0 1 0"/>
  <inertial pos="0.1 0.05 0" mass="0.5" diaginertia="0.01 0.02 0.01"/>
  <body name="a3" pos="0.3 0 0"><joint name="ja3" axis="0 0 1"/><joint name="sa3" type="slide" axis="1 0 0"/>
   <inertial pos="0.1 0 0.02" mass="0.3" diaginertia="0.003 0.002 0.001"/>
   <site name="sa" pos="0.2 0.01 0" euler="10 20 30"/></body></body></body>
<body name="b1" pos="0.6 0 0.5"><joint name="jb1" axis="0 1 0"/><joint name="jb2" axis="1 0 0"/>
 <joint name="jb3" type="slide" axis="0 0 1"/><inertial pos="0 0 0.1" mass="0.7" diaginertia="0.01 0.01 0.01"/>
 <site name="sb" pos="0.1 0 0.2" euler="-5 3 40"/></body>
</worldbody><equality>{}</equality>
<actuator><motor name="m1" joint="ja1"/><motor name="m2" joint="jb1"/></actuator></mujoco>"""

SPATIAL = {
    "body_weld": '<weld name="w" body1="a3" body2="b1" anchor="0.1 0.2 0.3"/>',
    "site_weld": '<weld name="w" site1="sa" site2="sb"/>',
    "site_connect": '<connect name="c" site1="sa" site2="sb"/>',
    "weld_no_torque": '<weld name="w" body1="a3" body2="b1" torquescale="0"/>',
}


def _soft_gap(plant: MjcfPlant, x: np.ndarray, u: np.ndarray, d: float) -> tuple[float, float, float]:
    """(|qacc_mujoco - qacc_exact|, |qacc_smooth - qacc_exact|, max |efc_pos|) at the completed state."""
    m = mujoco.MjModel.from_xml_path(plant.model_path)
    m.eq_solimp[:, :2] = d
    data = mujoco.MjData(m)
    full = plant.constraints.complete(x)
    data.qpos[:], data.qvel[:] = full[: m.nq], full[m.nq :]
    data.ctrl[list(plant.active_actuators)] = u
    mujoco.mj_forward(m, data)
    exact, _ = plant.constraints.accelerations(full, u)
    return (
        float(np.abs(data.qacc - exact).max()),
        float(np.abs(data.qacc_smooth - exact).max()),
        float(np.abs(data.efc_pos).max()),
    )


@pytest.fixture(scope="module")
def spatial_plants(tmp_path_factory: pytest.TempPathFactory) -> dict[str, MjcfPlant]:
    folder = tmp_path_factory.mktemp("eq")
    out = {}
    for name, eq in SPATIAL.items():
        path = folder / f"{name}.xml"
        path.write_text(WELD_XML.format(eq))
        out[name] = MjcfPlant(path, x0=None)
    return out


@pytest.mark.parametrize("which", ["four_bar", "gripper", *SPATIAL])
def test_matches_mujoco_soft_equality_within_its_softness(
    which: str, four_bar: MjcfPlant, gripper: MjcfPlant, spatial_plants: dict[str, MjcfPlant]
) -> None:
    plant = {"four_bar": four_bar, "gripper": gripper, **spatial_plants}[which]
    rng = np.random.default_rng(7)
    x = np.r_[0.01 + 0.02 * rng.random(plant.constraints.ni), rng.normal(size=plant.constraints.ni) * 0.5]
    if which == "four_bar":
        x = np.array([0.7, 1.5])
    if which == "gripper":  # MuJoCo's joint coupling has no curvature term -P''(q2) dq2² (its aref is 0 for it):
        x[1] = 0.0  # with a nonlinear P its soft solution differs from the exact one by that term when moving
    u = rng.normal(size=plant.input_dim) * 0.2
    gap, effect, residual = _soft_gap(plant, x, u, SOFT_D)
    assert residual <= 1e-12  # MuJoCo's own constraint residual vanishes at our configuration: the same manifold
    assert effect > 1e-3  # the constraint does act here
    assert gap <= 200 * (1 - SOFT_D) / SOFT_D * effect
    softer, _, _ = _soft_gap(plant, x, u, 0.999)
    assert softer / gap > 5.0


def test_mujocos_joint_coupling_leaves_out_the_curvature_term(gripper: MjcfPlant) -> None:
    # moving, the exact coupling accelerates q2 by k q̈1 + P''(q1) q̇1²; MuJoCo's soft solution only by ≈ k q̈1
    x, u = np.array([0.02, 0.5]), np.array([0.01])
    m = mujoco.MjModel.from_xml_path(gripper.model_path)
    m.eq_solimp[:, :2] = SOFT_D
    data = mujoco.MjData(m)
    full = gripper.constraints.complete(x)
    data.qpos[:], data.qvel[:], data.ctrl[:] = full[:2], full[2:], u
    mujoco.mj_forward(m, data)
    k, curvature = 0.8 + 2 * 1.5 * x[0], 2 * 1.5 * x[1] ** 2
    exact, _ = gripper.constraints.accelerations(full, u)
    assert exact[1] - k * exact[0] == pytest.approx(curvature, rel=1e-9)
    assert abs(data.qacc[1] - k * data.qacc[0]) <= 1e-2 * curvature


def test_free_coordinates_match_the_rank_of_mujocos_constraint_jacobian(
    spatial_plants: dict[str, MjcfPlant],
) -> None:
    rng = np.random.default_rng(3)
    for plant in spatial_plants.values():
        cd = plant.constraints
        m = mujoco.MjModel.from_xml_path(plant.model_path)
        data = mujoco.MjData(m)
        full = cd.complete(np.r_[cd.q_ref[list(cd.independent)] + 0.1 * rng.normal(size=cd.ni), np.zeros(cd.ni)])
        data.qpos[:] = full[: m.nq]
        mujoco.mj_forward(m, data)
        J = data.efc_J.reshape(data.nefc, m.nv)
        assert cd.ni == m.nv - np.linalg.matrix_rank(J, tol=1e-9 * np.abs(J).max())
        assert np.abs(data.efc_pos).max() <= 1e-12


def test_redundant_rows_are_dropped_and_change_nothing(four_bar: MjcfPlant, tmp_path) -> None:
    # the loop closed twice at the same point: six rows of rank 2 (a zero row each, and a duplicate)
    text = asset_path("gallery/four_bar.xml").read_text()
    twice = _variant(
        tmp_path, text, "</equality>", '<connect body1="rocker" body2="world" anchor="0.3 0 0"/></equality>'
    )
    plant = MjcfPlant(twice)
    assert len(plant.constraints.rows) == 2 and plant.state_names == four_bar.state_names
    for x, u in ((np.array([0.7, 1.5]), [0.4]), (np.array([-1.3, -3.0]), [-0.2])):
        assert np.abs(plant.dynamics(x, u) - four_bar.dynamics(x, u)).max() <= 1e-12 * 200
        A, B = plant.linearize(x, u)
        A0, B0 = four_bar.linearize(x, u)
        assert np.abs(A - A0).max() <= 1e-9 and np.abs(B - B0).max() <= 1e-9


# ----------------------------------------------------------------------------------- closed loop
def test_lqr_designed_on_the_four_bar_holds_it_in_mujoco() -> None:
    from shinro_ctrl.sim import RobotSim

    sim = RobotSim.from_config(
        {
            "plant": {"type": "MjcfPlant", "model": str(asset_path("gallery/four_bar.xml"))},
            "engine": {"type": "mujoco"},
            "controller": {"type": "LQR", "Q": [100, 1], "R": [1]},
            "sim": {"duration": 0.6, "initial_state": [0.1, 0.0]},
        }
    )
    result = sim.run()
    assert result.metrics["stable"]
    assert abs(result.x[-1, 0]) < 2e-3  # from 0.1 rad; the open loop is unstable (A[1, 0] > 0)
    A, _ = sim.plant.linearize()
    assert A[1, 0] > 0
    # MuJoCo's soft loop stays closed: its constraint residual is small
    assert np.abs(sim.engine.data.efc_pos).max() < 1e-4


# ------------------------------------------------------------------------------------- bad input
def test_x0_violating_the_loop_is_refused_naming_it() -> None:
    path = asset_path("gallery/four_bar.xml")
    with pytest.raises(InvalidArgument, match=r"violates equality 'loop' \(connecting body 'rocker'"):
        MjcfPlant(path, x0=[0.5, 0.0, 0.0, 0.0, 0.0, 0.0])
    with pytest.raises(InvalidArgument, match="velocities violate equality 'loop'"):
        MjcfPlant(path, x0=[0.0, 0.0, 0.0, 1.0, 0.0, 0.0])
    plant = MjcfPlant(path, x0=[0.2, 0.0])  # the design state: completed
    assert plant.equilibrium()[0] == pytest.approx([0.2, 0.0])


def test_keyframe_is_projected_onto_the_constraints(tmp_path) -> None:
    text = asset_path("gallery/four_bar.xml").read_text()
    keyed = _variant(
        tmp_path,
        text,
        "</mujoco>",
        '<keyframe><key name="home" qpos="0.3 -0.38 0.092" qvel="0.5 0 0"/></keyframe></mujoco>',
    )
    plant = MjcfPlant(keyed)
    x0, _ = plant.equilibrium()
    assert x0[0] == pytest.approx(0.3, abs=2e-3) and x0[1] != 0.0  # nearest configuration and velocities on the loop
    full = plant.constraints.complete(x0)
    assert plant.constraints.residuals(full[:3]).max() <= 1e-12
    assert np.abs(full[:3] - [0.3, -0.38, 0.092]).max() < 5e-3


def _variant(tmp_path, text: str, old: str, new: str) -> str:
    assert old in text
    path = tmp_path / "variant.xml"
    path.write_text(text.replace(old, new))
    return str(path)


def test_inactive_tendon_and_unsatisfiable_equalities_are_refused_by_name(tmp_path) -> None:
    text = asset_path("gallery/four_bar.xml").read_text()
    inactive = _variant(tmp_path, text, '<connect name="loop"', '<connect active="false" name="loop"')
    with pytest.raises(InvalidArgument, match="inactive equality constraint 'loop'"):
        MjcfPlant(inactive)
    tendon = _variant(
        tmp_path,
        text,
        "</equality>",
        '<tendon tendon1="t"/></equality><tendon><fixed name="t"><joint joint="crank" coef="1"/></fixed></tendon>',
    )
    with pytest.raises(InvalidArgument, match="tendon equality constraint coupling tendon 't'"):
        MjcfPlant(tendon)
    far = _variant(
        tmp_path,
        text,
        '<connect name="loop" body1="rocker" body2="world" anchor="0.3 0 0"',
        '<connect name="loop" site1="tip" site2="far"',
    )
    far_path = tmp_path / "far.xml"
    far_path.write_text(
        open(far)
        .read()
        .replace('<geom fromto="0 0 0 0.3 0 0"/>', '<geom fromto="0 0 0 0.3 0 0"/><site name="tip" pos="0.3 0 0"/>')
        .replace('<geom name="ground_link"', '<site name="far" pos="3 0 0.5"/><geom name="ground_link"')
    )
    with pytest.raises(
        InvalidArgument,
        match=r"far.xml.*violates equality 'loop' \(connecting site 'tip' to site 'far'\) .* no configuration near it",
    ):
        MjcfPlant(far_path)
    locked = _variant(tmp_path, text, "</equality>", '<weld body1="rocker" body2="world"/></equality>')
    with pytest.raises(InvalidArgument, match="leave no free motion"):
        MjcfPlant(locked)
