"""IKQP: the QP against independent references, IK success rates, limits, control, MuJoCo tracking."""

from __future__ import annotations

import ctypes
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest
from scipy.optimize import lsq_linear
from scipy.spatial.transform import Rotation

from shinro_ctrl.controllers.ik_qp import IKQP, IKProblem
from shinro_ctrl.errors import InvalidArgument, NonFiniteError
from shinro_ctrl.kinematics import pose_to_transform
from shinro_ctrl.plants import ArmRobot

N_TARGETS = 200


@pytest.fixture
def arm() -> ArmRobot:
    return ArmRobot()


@pytest.fixture
def ik(arm) -> IKQP:
    return IKQP(arm)


def inside(arm: ArmRobot, q: np.ndarray) -> bool:
    """Exactly inside the joint limits (no tolerance)."""
    return bool(np.all(q >= arm.joint_limits[:, 0]) and np.all(q <= arm.joint_limits[:, 1]))


def pose_errors(arm: ArmRobot, q: np.ndarray, T: np.ndarray) -> tuple[float, float]:
    """Independent error measure: position distance and the scipy rotation angle between frames."""
    Tq, _, _ = arm.forward_kinematics(q)
    pos = float(np.linalg.norm(Tq[:3, 3] - T[:3, 3]))
    ori = float(Rotation.from_matrix(T[:3, :3] @ Tq[:3, :3].T).magnitude())
    return pos, ori


@pytest.fixture(scope="module")
def near_targets() -> list[np.ndarray]:
    """FK of the home pose perturbed by up to ±0.5 rad per joint (reachable, near home)."""
    arm = ArmRobot()
    rng = np.random.default_rng(2024)
    lo, hi = arm.joint_limits.T
    return [arm.forward_kinematics(np.clip(rng.uniform(-0.5, 0.5, 6), lo, hi))[0] for _ in range(N_TARGETS)]


@pytest.fixture(scope="module")
def workspace_targets() -> list[np.ndarray]:
    """FK of uniformly random in-limit configurations (reachable, spread over the workspace)."""
    arm = ArmRobot()
    rng = np.random.default_rng(7)
    lo, hi = arm.joint_limits.T
    return [arm.forward_kinematics(rng.uniform(lo, hi))[0] for _ in range(N_TARGETS)]


# ---------------------------------------------------------------- construction
def test_defaults_work(arm):
    ik = IKQP(arm)
    assert ik.task == "pose" and ik.k == 6 and ik.dt == arm.dt and ik.max_step == 0.5
    np.testing.assert_array_equal(ik.lo, arm.joint_limits[:, 0])
    assert "IKQP" in repr(ik)


@pytest.mark.parametrize(
    ("kw", "word"),
    [
        ({"damping": -1.0}, "damping"),
        ({"velocity_limit": 0.0}, "velocity_limit"),
        ({"velocity_limit": [1.0] * 5}, "velocity_limit"),
        ({"max_step": 0.0}, "max_step"),
        ({"dt": -0.01}, "dt"),
        ({"task": "orientation"}, "task"),
        ({"weights": [1.0] * 3}, "weights"),
        ({"weights": [1, 1, 1, 1, 1, -1]}, "weights"),
        ({"osqp_settings": {"eps_absolute": 1e-3}}, "osqp_settings"),
        ({"control_iters": 0}, "control_iters"),
    ],
)
def test_invalid_options_name_themselves(arm, kw, word):
    with pytest.raises(ValueError, match=word):
        IKQP(arm, **kw)


def test_bad_osqp_setting_value_raises_invalid_argument_silently(arm, capfd):
    capfd.readouterr()
    with pytest.raises(InvalidArgument, match="osqp_settings: eps_abs must be nonnegative"):
        IKQP(arm, osqp_settings={"eps_abs": -1})
    ctypes.CDLL(None).fflush(None)
    assert capfd.readouterr() == ("", "")


def test_invalid_targets_and_joints(ik):
    with pytest.raises(InvalidArgument, match="target"):
        ik.step(np.zeros(6), np.zeros(3))  # a point is only a pose-task target for task="position"
    with pytest.raises(ValueError, match="q"):
        ik.step(np.zeros(5), np.eye(4))
    with pytest.raises(ValueError, match="restarts"):
        ik.solve(np.eye(4), np.zeros(6), restarts=-1)
    with pytest.raises(NonFiniteError, match="T_target"):
        ik.solve(np.full((4, 4), np.nan), np.zeros(6))
    with pytest.raises(NonFiniteError, match="q0"):
        ik.solve(np.eye(4), np.full(6, np.inf))


# ---------------------------------------------------------------- the QP itself
def test_build_qp_matches_the_formula(arm, ik, rng):
    for _ in range(10):
        q = rng.uniform(-1, 1, 6)
        T = arm.forward_kinematics(q + rng.uniform(-0.3, 0.3, 6))[0]
        prob = ik.build_qp(q, T)
        assert isinstance(prob, IKProblem)
        Tq, _, _ = arm.forward_kinematics(q)
        e = np.concatenate(
            [T[:3, 3] - Tq[:3, 3], Rotation.from_matrix(T[:3, :3] @ Tq[:3, :3].T).as_rotvec()]
        )  # world-frame rotation vector, independent of our log map
        J = arm.jacobian(q, "exact")
        W = np.diag(ik.weights)
        np.testing.assert_allclose(prob.J, J, atol=1e-12)
        np.testing.assert_allclose(prob.error, e, atol=1e-12)
        np.testing.assert_allclose(prob.P, J.T @ W @ J + ik.damping * np.eye(6), atol=1e-12)
        np.testing.assert_allclose(prob.c, -J.T @ W @ e, atol=1e-12)
        np.testing.assert_array_equal(prob.A, np.eye(6))
        np.testing.assert_allclose(prob.l, np.maximum(arm.joint_limits[:, 0] - q, -ik.max_step))
        np.testing.assert_allclose(prob.u, np.minimum(arm.joint_limits[:, 1] - q, ik.max_step))
        # the compiled upper triangle the solver receives is the same matrix
        n = 6
        Pu = np.zeros((n, n))
        idx = 0
        for j in range(n):
            for i in range(j + 1):
                Pu[i, j] = Pu[j, i] = ik.kernel.Hu[idx]
                idx += 1
        np.testing.assert_allclose(Pu, prob.P, atol=1e-12)


def test_step_solves_the_qp(arm, ik, rng):
    """One OSQP object, updated in place, against scipy's bounded least squares on the same QP."""
    solver = ik.kernel.qp.solver
    sw = np.sqrt(ik.weights)
    active = 0
    for trial in range(30):
        q = rng.uniform(arm.joint_limits[:, 0], arm.joint_limits[:, 1])
        q[1] = arm.joint_limits[1, 1] if trial % 3 == 0 else q[1]  # a joint at its limit
        T = arm.forward_kinematics(rng.uniform(arm.joint_limits[:, 0], arm.joint_limits[:, 1]))[0]
        prob = ik.build_qp(q, T)
        dq = ik.step(q, T)
        A = np.vstack([sw[:, None] * prob.J, np.sqrt(ik.damping) * np.eye(6)])
        b = np.concatenate([sw * prob.error, np.zeros(6)])
        res = lsq_linear(A, b, bounds=(prob.l, prob.u), method="bvls", tol=1e-14, max_iter=1000)
        assert res.success  # BVLS's default max_iter (the number of variables) can stop it short
        ref = res.x
        np.testing.assert_allclose(dq, ref, atol=2e-3)

        cost_dq = 0.5 * dq @ prob.P @ dq + prob.c @ dq
        cost_ref = 0.5 * ref @ prob.P @ ref + prob.c @ ref
        assert cost_dq <= cost_ref + 1e-5 * (1 + abs(cost_ref))
        assert np.all(np.abs(dq) <= ik.max_step) and inside(arm, q + dq)
        active += int(np.any(np.isclose(np.abs(ref), ik.max_step)) or np.any(np.isclose(q + ref, arm.joint_limits.T)))
    assert active >= 10  # the bounds were exercised
    assert ik.kernel.qp.solver is solver


def test_step_never_leaves_the_limits(arm, ik):
    lo, hi = arm.joint_limits.T
    q = np.zeros(6)
    q[2] = hi[2]  # elbow at its upper limit
    far = pose_to_transform([0.0, 0.0, -0.4, 0.0, 0.0, 0.0])  # wants the arm folded down
    for _ in range(50):
        dq = ik.step(q, far)
        q = q + dq
        assert np.all(q >= lo) and np.all(q <= hi)
        assert np.all(np.abs(dq) <= ik.max_step)


# ---------------------------------------------------------------- IK success rates
def _run(targets, solve):
    ok, its, results = 0, [], []
    for T in targets:
        res = solve(T)
        results.append(res)
        ok += int(res.converged and res.pos_err < 1e-3 and res.ori_err < 1e-2)
        its.append(res.iterations)
    return ok / len(targets), float(np.median(its)), results


def test_solve_from_home_reaches_nearby_targets(arm, ik, near_targets):
    home = np.zeros(6)
    rate, med, results = _run(near_targets, lambda T: ik.solve(T, home))
    for T, res in zip(near_targets, results, strict=True):
        assert inside(arm, res.q)
        if res.converged:  # the reported errors are the real ones
            pos, ori = pose_errors(arm, res.q, T)
            assert pos < 1e-4 + 1e-12 and ori < 1e-4 + 1e-9
    dls_rate, dls_med, dls = _run(near_targets, lambda T: arm.inverse_kinematics(T, q_init=home, full_output=True))
    assert all(inside(arm, r.q) for r in dls)
    print(f"\nnear home: IKQP {rate:.1%} (median {med:g} it), DLS {dls_rate:.1%} (median {dls_med:g} it)")
    assert rate >= 0.99


def test_solve_with_restarts_covers_the_workspace(arm, ik, workspace_targets):
    home = np.zeros(6)
    rate, med, results = _run(workspace_targets, lambda T: ik.solve(T, home, restarts=20, seed=1))
    assert all(inside(arm, r.q) for r in results)
    for T, res in zip(workspace_targets, results, strict=True):
        pos, ori = pose_errors(arm, res.q, T)
        assert pos == pytest.approx(res.pos_err, abs=1e-9) and ori == pytest.approx(res.ori_err, abs=1e-7)
    local_rate, _, _ = _run(workspace_targets, lambda T: ik.solve(T, home))
    dls_rate, dls_med, dls = _run(workspace_targets, lambda T: arm.inverse_kinematics(T, q_init=home, full_output=True))
    assert all(inside(arm, r.q) for r in dls)
    print(
        f"\nworkspace: IKQP+20 restarts {rate:.1%} (median {med:g} it), IKQP local {local_rate:.1%}, "
        f"DLS local {dls_rate:.1%} (median {dls_med:g} it)"
    )
    assert rate >= 0.99


def test_restarts_are_reproducible(arm, ik, workspace_targets):
    T = workspace_targets[0]
    a = ik.solve(T, np.zeros(6), restarts=5, seed=3, max_iters=5)
    b = ik.solve(T, np.zeros(6), restarts=5, seed=3, max_iters=5)
    np.testing.assert_allclose(a.q, b.q, rtol=0, atol=1e-12)  # the warm start is reset: same path
    assert a.attempts == b.attempts == 6 and not a.converged  # 5 iterations are never enough here


@pytest.mark.parametrize(
    "pose",
    [
        [2.0, 0.0, 0.5, 0.0, 0.0, 0.0],  # beyond the reach
        [0.0, 0.0, -3.0, 0.5, 0.5, 0.5],  # far below the base
        [0.0, 0.1, 0.1, np.pi, 0.0, 0.0],  # inside the base, flipped
    ],
)
def test_unreachable_targets_fail_gracefully(arm, ik, pose):
    T = pose_to_transform(pose)
    res = ik.solve(T, np.zeros(6), restarts=3, seed=0)
    assert not res.converged
    assert inside(arm, res.q)
    pos, _ = pose_errors(arm, res.q, T)
    assert pos == pytest.approx(res.pos_err, abs=1e-9)
    assert res.attempts == 4
    np.testing.assert_allclose(res.jacobian, arm.jacobian(res.q), atol=1e-12)
    assert res.cond == pytest.approx(np.linalg.cond(arm.jacobian(res.q)), rel=1e-9)


def test_position_task(arm, rng):
    ik = IKQP(arm, task="position")
    assert ik.build_qp(np.zeros(6), np.eye(4)).J.shape == (3, 6)
    for _ in range(20):
        p = arm.forward_kinematics(np.clip(rng.uniform(-0.8, 0.8, 6), *arm.joint_limits.T))[0][:3, 3]
        res = ik.solve(p, np.zeros(6))
        assert res.converged and inside(arm, res.q)
        np.testing.assert_allclose(arm.forward_kinematics(res.q)[0][:3, 3], p, atol=1e-4)


# ---------------------------------------------------------------- control
def test_track_respects_velocity_and_joint_limits(arm):
    ik = IKQP(arm, velocity_limit=np.full(6, 1.0))
    q = np.zeros(6)
    T = pose_to_transform([0.1, 0.4, 0.3, 1.0, -0.5, 0.3])
    for _ in range(100):
        q_new = ik.track(q, T)
        assert np.all(np.abs(q_new - q) <= 1.0 * arm.dt + 1e-15)
        assert inside(arm, q_new)
        assert ik.last is not None and ik.last.iterations <= ik.control_iters
        np.testing.assert_array_equal(ik.last.q, q_new)
        q = q_new


def test_controller_returns_a_twist_the_arm_executes(arm):
    ik = IKQP.from_plant(arm)
    assert arm.ik is None  # the controller never changes the plant; the caller installs the IK
    arm.ik = ik
    ik.reset()
    x = arm.get_state()
    np.testing.assert_array_equal(ik(x, None), np.zeros(6))
    ref = x + np.array([0.05, -0.03, 0.02, 0.1, 0.0, -0.1])
    for _ in range(400):
        x = arm.get_state()
        u = ik(x, np.array([ref, ref]))  # preview rows: the second one is the target
        q_target = ik.last.q
        q = arm.step(u)
        np.testing.assert_allclose(q, q_target, atol=1e-9)
        assert np.all(np.abs(ik.last.dq) <= ik.velocity_limit * ik.dt + 1e-15)
    np.testing.assert_allclose(arm.get_state(), ref, atol=1e-6)


def _circle(x0: np.ndarray, t: float) -> np.ndarray:
    """Vertical circle (y-z plane), radius 0.1 m, 0.5 Hz, through x0 at t = 0, orientation held."""
    a = 2 * np.pi * 0.5 * t
    r = x0.copy()
    r[1] += 0.1 * np.sin(a)
    r[2] += 0.1 * (np.cos(a) - 1.0)
    return r


def test_mujoco_circle_tracking():
    engine_mod = pytest.importorskip("shinro_ctrl.engine")
    arm = ArmRobot()
    engine = engine_mod.MujocoEngine.for_plant(arm)
    arm.physics_engine(engine)
    ik = IKQP.from_plant(arm)
    x0 = arm.get_state()
    steps = round(4.0 / arm.dt)
    pos_err = np.empty(steps)
    ori_err = np.empty(steps)
    for k in range(steps):
        r = _circle(x0, (k + 1) * arm.dt)  # the pose wanted at the end of this step
        q = arm.step(ik(arm.get_state(), r))
        assert inside(arm, q) and inside(arm, arm.q_cmd)
        x = arm.get_state()
        pos_err[k] = np.linalg.norm(x[:3] - r[:3])
        ori_err[k] = np.abs(x[3:] - r[3:]).max()
    rms = float(np.sqrt(np.mean(pos_err**2)))
    print(f"\nMuJoCo circle: RMS {rms * 1e3:.2f} mm, max {pos_err.max() * 1e3:.2f} mm, ori max {ori_err.max():.4f} rad")
    assert rms < 5e-3
    assert ori_err.max() < 0.02
    assert engine.time == pytest.approx(4.0)


def test_standalone_scenario_runs():
    sim_mod = pytest.importorskip("shinro_ctrl.sim")
    sim = sim_mod.RobotSim.from_config("arm_ikqp")
    res = sim.run(duration=0.5)
    assert res.metrics["rms_error"] < 1e-4
    assert res.metrics["constraint_violations"] == 0


def test_threads_one_ikqp_shared_by_four_threads_equals_a_serial_run(arm, near_targets):
    """Thread policy: IKQP serializes its kernel's buffers, so 4 threads x 1,000 solves on one object equal serial.

    ``solve`` resets the warm start first, so its answer depends only on its arguments (to 1e-8: OSQP's
    factorization and adaptive rho keep a trace of the previous solve); without the lock the threads overwrite each
    other's kinematics buffers and QP data mid-iteration.
    """
    ik = IKQP(arm)
    rng = np.random.default_rng(99)
    lo, hi = arm.joint_limits.T
    jobs = [
        [(near_targets[int(i)], np.clip(rng.uniform(-0.5, 0.5, 6), lo, hi)) for i in rng.integers(0, N_TARGETS, 1000)]
        for _ in range(4)
    ]

    def run(batch):
        out = []
        for T, q0 in batch:
            res = ik.solve(T, q0, max_iters=20)
            out.append(np.concatenate([res.q, [res.iterations, res.pos_err, res.ori_err]]))
            out.append(ik.build_qp(q0, T).c)
        return out

    serial = [run(batch) for batch in jobs]
    with ThreadPoolExecutor(4) as pool:
        threaded = list(pool.map(run, jobs))
    for a, b in zip(serial, threaded, strict=True):
        for ra, rb in zip(a, b, strict=True):
            np.testing.assert_allclose(ra, rb, rtol=0, atol=1e-8)


@pytest.mark.parametrize("far", [1e6 * 1.001, 1e300, -1e200])
@pytest.mark.parametrize("form", ["pose", "transform"])
@pytest.mark.parametrize("method", ["solve", "track", "step", "build_qp"])
def test_a_target_beyond_any_reach_is_refused_in_one_line(ik, arm, far, form, method):
    """A reference of absurd size (a circle of radius 1e300 m) was a LinAlgError from inside the QP."""
    pose = np.array([0.3, far, 0.4, 0.0, 0.0, 0.0])
    target = pose if form == "pose" else pose_to_transform(pose)
    with pytest.raises(InvalidArgument, match=r"farther than 1e\+06 m from the base"):
        if method == "solve":
            ik.solve(target, np.zeros(6))
        else:
            getattr(ik, method)(np.zeros(6), target)


def test_a_far_but_bounded_target_is_tracked_without_error(ik, arm):
    """1e5 m is unreachable but allowed: the closest configuration, finite."""
    q = ik.track(np.zeros(6), np.array([1e5, 0.0, 0.4, 0.0, 0.0, 0.0]))
    assert np.all(np.isfinite(q))
