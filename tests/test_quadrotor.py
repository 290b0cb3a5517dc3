"""Quadrotor: dynamics, exact Jacobians and MuJoCo agreement against independent references.

The references here are written from scratch: the rotation matrix is the
product of elementary rotations, and the Euler-rate map comes from composing
the three elementary angular velocities (checked in turn against the
definition ``[ω]× = Rᵀ Ṙ`` by complex-step differentiation of ``R``). None of
it reuses the plant's closed-form ``W(φ, θ)``.
"""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest
import scipy.linalg

from shinro_ctrl.controllers import LQR
from shinro_ctrl.engine import MujocoEngine
from shinro_ctrl.errors import ConfigError, NonFiniteError
from shinro_ctrl.plants.quadrotor import Quadrotor, quat_to_zyx_euler, zyx_euler_to_quat

H_CS = 1e-30  # complex-step size: no subtractive cancellation, so any tiny step works


# ----------------------------------------------------------------- references
def rot_x(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def rot_y(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def rot_z(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def rotation(eta):
    """Body-to-world rotation of ZYX Euler angles ``[roll, pitch, yaw]``."""
    return rot_z(eta[2]) @ rot_y(eta[1]) @ rot_x(eta[0])


def body_rate_matrix(eta):
    """``E`` with ``ω_body = E(η) η̇``: each elementary rate, carried into the body frame."""
    Rx, Ry = rot_x(eta[0]), rot_y(eta[1])
    ex, ey, ez = np.eye(3)
    return np.column_stack([ex, Rx.T @ ey, Rx.T @ Ry.T @ ez])


def f_ref(x, u, m, inertia, g):
    """Independent rigid-body quadrotor (numpy; accepts complex arrays)."""
    eta, v, w = x[3:6], x[6:9], x[9:12]
    T, tau = u[0], u[1:4]
    I = np.asarray(inertia)
    eta_dot = np.linalg.solve(body_rate_matrix(eta), w)
    v_dot = rotation(eta) @ np.array([0, 0, T]) / m - np.array([0, 0, g])
    w_dot = (tau - np.cross(w, I * w)) / I
    return np.concatenate([v, eta_dot, v_dot, w_dot])


def complex_step_jacobians(f, x, u):
    """``(∂f/∂x, ∂f/∂u)`` by complex step, exact to rounding."""
    z = np.concatenate([x, u]).astype(complex)
    n = x.shape[0]
    cols = []
    for k in range(z.shape[0]):
        zk = z.copy()
        zk[k] += 1j * H_CS
        cols.append(f(zk[:n], zk[n:]).imag / H_CS)
    J = np.column_stack(cols)
    return J[:, :n], J[:, n:]


def random_state(rng, pitch_max=1.2):
    x = np.empty(12)
    x[0:3] = rng.uniform(-2, 2, 3)
    x[3] = rng.uniform(-np.pi, np.pi)
    x[4] = rng.uniform(-pitch_max, pitch_max)
    x[5] = rng.uniform(-np.pi, np.pi)
    x[6:9] = rng.normal(size=3)
    x[9:12] = rng.normal(size=3) * 2.0
    return x


@pytest.fixture
def quad(rng):
    """A quadrotor with random but physical parameters."""
    Ixx, Iyy = rng.uniform(2e-3, 6e-3, 2)
    Izz = rng.uniform(max(Ixx, Iyy), Ixx + Iyy)
    return Quadrotor(mass=rng.uniform(0.3, 1.5), inertia=(Ixx, Iyy, Izz), gravity=9.81)


def ref_args(q):
    p = q.params()
    return p["mass"], tuple(p["inertia"]), p["gravity"]


# ------------------------------------------------------------ the references
def test_reference_rate_matrix_is_the_definition(rng):
    """``E`` columns equal ``vee(Rᵀ ∂R/∂η_k)`` (complex-step derivative of R)."""
    for _ in range(5):
        eta = random_state(rng)[3:6]
        for k in range(3):
            e = eta.astype(complex)
            e[k] += 1j * H_CS
            dR = rotation(e).imag / H_CS
            S = rotation(eta).T @ dR
            np.testing.assert_allclose(S, -S.T, atol=1e-14)
            np.testing.assert_allclose([S[2, 1], S[0, 2], S[1, 0]], body_rate_matrix(eta)[:, k], atol=1e-14)


# --------------------------------------------------------------- dynamics
def test_dynamics_match_independent_rigid_body(quad, rng):
    args = ref_args(quad)
    for _ in range(20):
        x, u = random_state(rng), quad.hover_input() + rng.normal(size=4) * [2, 0.05, 0.05, 0.05]
        np.testing.assert_allclose(quad.dynamics(x, u), f_ref(x, u, *args), rtol=1e-12, atol=1e-12)


def test_batch_and_per_instance_parameters(quad, rng):
    X = np.array([random_state(rng) for _ in range(6)])
    U = quad.hover_input() + rng.normal(size=(6, 4)) * 0.1
    single = np.array([quad.dynamics(x, u) for x, u in zip(X, U, strict=True)])
    np.testing.assert_allclose(quad.dynamics(X, U), single, rtol=1e-13, atol=1e-13)
    masses = rng.uniform(0.3, 1.5, 6)
    batch = quad.dynamics(X, U, params={"mass": masses})
    for i in range(6):
        _, inertia, g = ref_args(quad)
        np.testing.assert_allclose(batch[i], f_ref(X[i], U[i], masses[i], inertia, g), rtol=1e-12, atol=1e-12)


def test_symbolic_exposes_parameters(quad, rng):
    fp = quad.symbolic(params=True)
    assert fp.name() == "f" and fp.name_in() == ["x", "u", "p"]
    assert quad.param_names == ("mass", "Ixx", "Iyy", "Izz", "gravity")
    m, (Ixx, Iyy, Izz), g = ref_args(quad)
    assert quad.dynamics_params() == {"mass": m, "Ixx": Ixx, "Iyy": Iyy, "Izz": Izz, "gravity": g}
    p = np.array([m, Ixx, Iyy, Izz, g])
    x, u = random_state(rng), quad.hover_input()
    np.testing.assert_allclose(np.array(fp(x, u, p)).ravel(), quad.dynamics(x, u), atol=1e-12)


def test_hover_is_an_equilibrium(quad):
    x0, u0 = quad.equilibrium()
    m, _, g = ref_args(quad)
    np.testing.assert_array_equal(x0, np.zeros(12))
    np.testing.assert_allclose(u0, [m * g, 0, 0, 0])
    np.testing.assert_allclose(quad.hover_input(), u0)
    np.testing.assert_allclose(quad.dynamics(x0, u0), 0.0, atol=1e-14)
    # Any position and yaw hovers too.
    x1 = x0.copy()
    x1[[0, 1, 2, 5]] = [1.0, -2.0, 3.0, 2.5]
    np.testing.assert_allclose(quad.dynamics(x1, u0), 0.0, atol=1e-14)


# -------------------------------------------------------------- Jacobians
def test_exact_jacobians_match_complex_step(quad, rng):
    args = ref_args(quad)
    worst = 0.0
    for _ in range(10):
        x, u = random_state(rng), quad.hover_input() + rng.normal(size=4) * [1, 0.05, 0.05, 0.05]
        A, B = quad.linearize(x, u, method="exact")
        A_cs, B_cs = complex_step_jacobians(lambda X, U: f_ref(X, U, *args), x, u)
        J, J_cs = np.hstack([A, B]), np.hstack([A_cs, B_cs])
        worst = max(worst, np.abs(J - J_cs).max() / np.abs(J_cs).max())
        np.testing.assert_allclose(J, J_cs, rtol=1e-9, atol=1e-9 * np.abs(J_cs).max())
    assert worst <= 1e-9


def test_fd_jacobians_agree_loosely(quad, rng):
    for _ in range(5):
        x, u = random_state(rng, pitch_max=1.0), quad.hover_input()
        Ae, Be = quad.linearize(x, u, method="exact")
        Af, Bf = quad.linearize(x, u, method="fd", eps=1e-6)
        scale = max(np.abs(Ae).max(), np.abs(Be).max())
        np.testing.assert_allclose(Af, Ae, atol=1e-6 * scale)
        np.testing.assert_allclose(Bf, Be, atol=1e-6 * scale)


def test_hover_linearization_closed_form():
    q = Quadrotor(mass=0.8, inertia=(4e-3, 5e-3, 7e-3), gravity=9.81)
    A, B = q.linearize()
    A_ref = np.zeros((12, 12))
    A_ref[0:3, 6:9] = np.eye(3)
    A_ref[3:6, 9:12] = np.eye(3)
    A_ref[6, 4] = 9.81  # pitch tilts thrust toward +x
    A_ref[7, 3] = -9.81  # roll tilts thrust toward -y
    B_ref = np.zeros((12, 4))
    B_ref[8, 0] = 1 / 0.8
    B_ref[9:12, 1:4] = np.diag([1 / 4e-3, 1 / 5e-3, 1 / 7e-3])
    np.testing.assert_allclose(A, A_ref, atol=1e-14)
    np.testing.assert_allclose(B, B_ref, atol=1e-12)


# ---------------------------------------------------------------- the step
def test_standalone_step_is_semi_implicit_euler(quad, rng):
    args = ref_args(quad)
    x, u = random_state(rng, pitch_max=1.0), quad.hover_input() + rng.normal(size=4) * 0.01
    quad.set_state(x)
    dt = quad.dt
    xd = f_ref(x, u, *args)
    v_new = x[6:] + dt * xd[6:]
    mid = np.concatenate([x[:6], v_new])
    expected = np.concatenate([x[:6] + dt * f_ref(mid, u, *args)[:6], v_new])
    np.testing.assert_allclose(quad.step(u), expected, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(quad.get_state(), expected, rtol=1e-12, atol=1e-12)


def test_hover_holds_and_free_fall(quad):
    x0, u0 = quad.equilibrium()
    quad.set_state(x0)
    for _ in range(100):
        x = quad.step(u0)
    np.testing.assert_allclose(x, 0.0, atol=1e-12)
    for _ in range(100):
        x = quad.step([0, 0, 0, 0])
    # Semi-implicit Euler of free fall: z_N = -g dt² N (N + 1) / 2.
    N, dt, g = 100, quad.dt, quad.params()["gravity"]
    np.testing.assert_allclose(x[2], -g * dt**2 * N * (N + 1) / 2, rtol=1e-12)
    np.testing.assert_allclose(x[8], -g * dt * N, rtol=1e-12)


# ------------------------------------------------------------- conversions
def test_quaternion_euler_round_trip(rng):
    for _ in range(50):
        eta = random_state(rng, pitch_max=1.5)[3:6]
        q = zyx_euler_to_quat(*eta)
        assert abs(np.linalg.norm(q) - 1) < 1e-14
        np.testing.assert_allclose(quat_to_zyx_euler(q), eta, atol=1e-12)
        np.testing.assert_allclose(quat_to_zyx_euler(-q), eta, atol=1e-12)
        R = np.zeros(9)
        mujoco.mju_quat2Mat(R, q)
        np.testing.assert_allclose(R.reshape(3, 3), rotation(eta), atol=1e-14)


# ------------------------------------------------------------------ mixer
@pytest.mark.parametrize("layout", ["+", "x"])
def test_mixer_from_rotor_forces(layout, rng):
    L, k = 0.2, 0.02
    q = Quadrotor(arm_length=L, rotor_layout=layout, yaw_moment_coefficient=k)
    pos = q.rotor_positions()
    np.testing.assert_allclose(np.linalg.norm(pos, axis=1), L)
    f = rng.uniform(0.5, 2.0, 4)
    # Independent: torque is Σ r_i × (0, 0, f_i) plus the rotors' drag moments.
    drag = np.array([0.0, 0.0, k * (f[0] - f[1] + f[2] - f[3])])
    tau = sum(np.cross(pos[i], [0, 0, f[i]]) for i in range(4)) + drag
    np.testing.assert_allclose(q.rotor_thrusts_to_input(f), [f.sum(), *tau], atol=1e-14)
    np.testing.assert_allclose(q.input_to_rotor_thrusts(q.rotor_thrusts_to_input(f)), f, atol=1e-12)
    np.testing.assert_allclose(q.input_to_rotor_thrusts(q.hover_input()), q.hover_input()[0] / 4, atol=1e-12)
    if layout == "+":
        np.testing.assert_allclose(pos[0], [L, 0, 0], atol=1e-15)
    else:
        np.testing.assert_allclose(pos[0], [L / np.sqrt(2), L / np.sqrt(2), 0], atol=1e-15)


def test_mixer_without_yaw_moment_is_not_invertible():
    q = Quadrotor(yaw_moment_coefficient=0.0)
    with pytest.raises(ValueError, match="yaw_moment_coefficient"):
        q.input_to_rotor_thrusts(q.hover_input())


# -------------------------------------------------------------- validation
@pytest.mark.parametrize(
    "kwargs,name",
    [
        ({"mass": 0.0}, "mass"),
        ({"mass": -1.0}, "mass"),
        ({"inertia": (1e-3, 1e-3)}, "inertia"),
        ({"inertia": (1e-3, -1e-3, 1e-3)}, "inertia"),
        ({"inertia": (1e-3, 1e-3, 5e-3)}, "inertia"),  # violates Izz <= Ixx + Iyy
        ({"inertia": "heavy"}, "inertia"),
        ({"arm_length": 0.0}, "arm_length"),
        ({"gravity": -9.81}, "gravity"),
        ({"dt": 0.0}, "dt"),
        ({"rotor_layout": "h"}, "rotor_layout"),
        ({"yaw_moment_coefficient": -0.1}, "yaw_moment_coefficient"),
    ],
)
def test_invalid_arguments_name_the_argument(kwargs, name):
    with pytest.raises(ValueError, match=name):
        Quadrotor(**kwargs)


def test_from_config_and_input_checks():
    q = Quadrotor.from_config({"type": "Quadrotor", "mass": 0.7, "inertia": [4e-3, 4e-3, 6e-3]})
    assert q.params()["mass"] == 0.7 and q.dynamics_params()["Izz"] == 6e-3
    # params() holds constructor arguments: a config rebuilt from it gives the same plant.
    q2 = Quadrotor.from_config({"type": "Quadrotor", **q.params(), "dt": q.dt})
    assert repr(q2) == repr(q) and q2.params() == q.params()
    with pytest.raises(ConfigError, match="did you mean 'mass'"):
        Quadrotor.from_config({"mas": 0.7})
    with pytest.raises(ValueError, match=r"\(4,\)"):
        q.step([1.0, 0.0, 0.0])
    with pytest.raises(NonFiniteError):
        q.step([np.nan, 0, 0, 0])


# ------------------------------------------------------------------ MuJoCo
def test_mujoco_free_joint_velocity_convention():
    """qvel[0:3] is the world-frame linear velocity, qvel[3:6] the body-frame angular velocity."""
    q = Quadrotor(gravity=0.0, dt=1e-3)
    engine = MujocoEngine.for_plant(q)
    m, d = engine.model, engine.data
    yaw90 = zyx_euler_to_quat(0.0, 0.0, np.pi / 2)  # body x points along world y
    d.qpos[:] = [0, 0, 0, *yaw90]
    d.qvel[:] = [1.0, 0, 0, 1.0, 0, 0]
    mujoco.mj_step(m, d)
    # Linear: moved along world x (not body x = world y).
    np.testing.assert_allclose(d.qpos[:3], [1e-3, 0, 0], atol=1e-15)
    # Angular: rotated about body x, i.e. about world y.
    rotvec_world = np.zeros(3)
    mujoco.mju_subQuat(rotvec_world, d.qpos[3:7], yaw90)  # in yaw90's local frame
    np.testing.assert_allclose(rotvec_world, [1e-3, 0, 0], atol=1e-15)
    R = rotation([0, 0, np.pi / 2])
    np.testing.assert_allclose(R @ rotvec_world, [0, 1e-3, 0], atol=1e-15)
    # Same through the plant: a body roll rate at yaw 90° increases the roll angle.
    q.physics_engine(engine)
    q.set_state([0, 0, 0, 0, 0, np.pi / 2, 1.0, 0, 0, 1.0, 0, 0])
    x = q.step([0, 0, 0, 0])
    np.testing.assert_allclose(x[[0, 1, 3, 4, 5]], [1e-3, 0, 1e-3, 0, np.pi / 2], atol=1e-12)


def test_mujoco_model_matches_parameters(quad, rng):
    engine = MujocoEngine.for_plant(quad)
    m = engine.model
    b = m.body("quadrotor").id
    mass, inertia, g = ref_args(quad)
    assert m.body_mass[b] == pytest.approx(mass)
    np.testing.assert_allclose(m.body_inertia[b], inertia)
    np.testing.assert_allclose(m.body_ipos[b], 0.0)
    np.testing.assert_allclose(m.opt.gravity, [0, 0, -g])
    assert m.opt.timestep == pytest.approx(quad.dt)
    assert not m.actuator_ctrllimited.any()
    assert not (m.geom_contype.any() or m.geom_conaffinity.any())
    # Accelerations equal the analytic model at random states and inputs.
    quad.physics_engine(engine)
    for _ in range(5):
        x, u = random_state(rng), quad.hover_input() + rng.normal(size=4) * [1, 0.05, 0.05, 0.05]
        quad.set_state(x)
        quad.engine_apply(engine, u)
        engine.forward()
        np.testing.assert_allclose(quad.get_state(), x, atol=1e-12)
        np.testing.assert_allclose(engine.data.qacc, quad.dynamics(x, u)[6:], rtol=1e-10, atol=1e-10)


def semi_implicit(A_c, B_c, h):
    """Discrete model of MuJoCo's Euler step ``v⁺ = v + h a``, ``q⁺ = q + h q̇(q, v⁺)`` for ``x = [q, v]``."""
    n = A_c.shape[0] // 2
    Aqq, Aqv, Avq, Avv = A_c[:n, :n], A_c[:n, n:], A_c[n:, :n], A_c[n:, n:]
    Bq, Bv = B_c[:n], B_c[n:]
    I = np.eye(n)
    Av = np.hstack([h * Avq, I + h * Avv])
    Aq = np.hstack([I + h * Aqq, np.zeros((n, n))]) + h * Aqv @ Av
    Bv_d = h * Bv
    Bq_d = h * Bq + h * Aqv @ Bv_d
    return np.vstack([Aq, Av]), np.vstack([Bq_d, Bv_d])


@pytest.mark.parametrize("yaw", [0.0, 1.1])
def test_hover_linearization_matches_mjd_transition_fd(yaw):
    q = Quadrotor(mass=0.7, inertia=(4e-3, 5e-3, 8e-3), dt=0.002)
    engine = MujocoEngine.for_plant(q)
    q.physics_engine(engine)
    x0, u0 = q.equilibrium()
    x0[[0, 1, 2, 5]] = [0.3, -0.2, 1.0, yaw]
    q.set_state(x0)
    q.engine_apply(engine, u0)
    A_mj, B_mj = engine.transition_jacobians(eps=1e-6, centered=True)
    T, perm = q.engine_state_map()
    np.testing.assert_array_equal(T, np.eye(12))
    np.testing.assert_array_equal(perm, np.arange(12))
    A_mj, B_mj = T @ A_mj @ np.linalg.inv(T), T @ B_mj
    A_c, B_c = q.linearize(x0, u0)
    A_d, B_d = semi_implicit(A_c, B_c, q.dt)
    # At any hover yaw the body-frame rotation tangent equals the Euler
    # perturbation to first order (E(0, 0, ψ) = I), so T = I and the tilt rows
    # of A see the yawed directions in both models.
    np.testing.assert_allclose(A_d, A_mj, atol=1e-8)
    np.testing.assert_allclose(B_d, B_mj, atol=1e-8 * np.abs(B_d).max())


def test_standalone_and_mujoco_agree_near_hover(rng):
    dt = 1e-3
    x0 = np.zeros(12)
    x0[0:3] = [0.1, -0.2, 1.0]
    x0[3:6] = [0.05, -0.04, 0.3]
    x0[6:9] = [0.1, -0.05, 0.05]
    x0[9:12] = [0.1, -0.2, 0.3]
    standalone = Quadrotor(dt=dt)
    sim = Quadrotor(dt=dt)
    sim.physics_engine(MujocoEngine.for_plant(sim))
    standalone.set_state(x0)
    sim.set_state(x0)
    np.testing.assert_allclose(sim.get_state(), x0, atol=1e-14)
    u_hover = standalone.hover_input()
    err = 0.0
    for k in range(200):  # 0.2 s
        u = u_hover + np.array([0.2 * np.sin(20 * k * dt), 2e-4, -1e-4, 3e-4 * np.cos(30 * k * dt)])
        a, b = standalone.step(u), sim.step(u)
        err = max(err, np.abs(a - b).max())
    # Both are first-order semi-implicit schemes of the same ODE (MuJoCo integrates
    # the quaternion on SO(3), the plant the Euler angles): they differ by O(dt).
    assert err < 5e-5, err
    drift = np.abs(a - x0).max()
    assert drift > 100 * err  # the test would notice a real disagreement


# -------------------------------------------------------------- hover LQR
def hover_lqr(q):
    Q = np.diag([10, 10, 10, 2, 2, 2, 1, 1, 1, 0.1, 0.1, 0.1])
    R = np.diag([0.5, 200.0, 200.0, 200.0])
    ctrl = LQR.from_plant(q, Q, R)
    A, B = q.get_model(discretization="step")  # from_plant's default model
    P = scipy.linalg.solve_discrete_are(A, B, Q, R)
    K = np.linalg.solve(R + B.T @ P @ B, B.T @ P @ A)
    np.testing.assert_allclose(ctrl.K, K, rtol=1e-8, atol=1e-10)
    return ctrl


@pytest.mark.parametrize("engine", [False, True], ids=["standalone", "mujoco"])
def test_hover_lqr_recovers_from_offset(engine):
    q = Quadrotor(dt=0.01)
    if engine:
        q.physics_engine(MujocoEngine.for_plant(q))
    ctrl = hover_lqr(q)
    x0 = np.zeros(12)
    x0[0:3] = [0.5, -0.5, 0.5]
    x0[3:6] = [0.3, -0.3, 0.3]
    q.set_state(x0)
    x = q.get_state()
    for _ in range(600):  # 6 s
        x = q.step(ctrl(x))
    assert np.abs(x[0:6]).max() < 1e-2, x
    assert np.abs(x[6:12]).max() < 1e-2, x


# ------------------------------------------------------------------ gimbal lock
@pytest.mark.parametrize("pitch", [math.pi / 2, -math.pi / 2, math.pi / 2 - 5e-4, 3 * math.pi / 2, -math.pi / 2 + 1e-9])
def test_gimbal_lock_is_refused_in_dynamics_linearize_and_step(pitch):
    q = Quadrotor()
    x = np.zeros(12)
    x[4] = pitch
    u = q.hover_input()
    for call in (
        lambda: q.dynamics(x, u),
        lambda: q.dynamics(np.stack([np.zeros(12), x]), np.stack([u, u])),
        lambda: q.linearize(x, u),
        lambda: q.linearize(x, u, method="fd"),
        lambda: q.get_model(x, u),
        lambda: q.get_model(x, u, discretization="step"),
        lambda: q.engine_state_map(x),
    ):
        with pytest.raises(NonFiniteError, match="gimbal lock"):
            call()
    q.state = x
    with pytest.raises(NonFiniteError, match="gimbal lock"):
        q.step(u)


def test_just_outside_the_gimbal_lock_margin_the_model_is_finite():
    q = Quadrotor()
    x = np.zeros(12)
    x[4] = math.pi / 2 - 2e-3  # |cos| = 2e-3 > GIMBAL_COS_MIN
    A, B = q.linearize(x, q.hover_input())
    assert np.all(np.isfinite(A)) and np.all(np.isfinite(B)) and np.all(np.isfinite(q.dynamics(x, q.hover_input())))


def test_gimbal_lock_on_the_command_line_is_one_line_exit_2(capsys):
    from shinro_ctrl.cli import main

    x0 = ",".join(["0"] * 4 + [repr(math.pi / 2)] + ["0"] * 7)
    for cmd in ("linearize", "crosscheck"):
        assert main([cmd, "quadrotor", "--x0", x0]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "gimbal lock" in err[0]
