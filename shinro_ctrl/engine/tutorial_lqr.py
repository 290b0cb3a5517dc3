r"""The MuJoCo LQR-tutorial recipe for a standing legged robot: the baseline the exact contact-constrained LQR is
compared with, and the push-recovery test both are measured by.

The recipe (MuJoCo's ``LQR.ipynb`` tutorial, which balances its humanoid on one leg), on the full MuJoCo model
with its soft contacts:

1. **Standing point** (:func:`standing_point`): from the keyframe, shift the base height over a fine grid
   (±1 mm), and at each height run ``mj_inverse`` with ``qacc = 0``: the generalized force
   ``qfrc_inverse`` that holds the robot still given the contact forces MuJoCo computes at that penetration.
   Keep the height whose vertical base force is smallest (the contacts carry the weight), then the control
   ``u₀ = pinv(Mᵀ_act) qfrc₀``: the least-squares actuator controls producing that force (``M_act`` the
   actuator moment matrix ``(nu, nv)``; the free joint's residual cannot be produced and is left out).
2. **Linearization** (:func:`transition_fd_lqr`): ``A, B`` of one ``mj_step`` at ``(qpos₀, u₀)`` by
   ``mjd_transitionFD`` (central differences, ``eps = 1e-6``), in MuJoCo's tangent coordinates
   ``[dq (nv); qvel (nv)]``.
3. **Cost**: ``Q = blkdiag(w_b J_bᵀ J_b + Q_joint, 0)`` where ``J_b`` ``(2, nv)`` is the horizontal Jacobian of the
   centre of mass minus that of the support centre (the mean of the feet): the balance cost keeps the centre of
   mass over the feet; ``Q_joint`` weights the actuated joints (``w_j``) and the base rotation (``w_rot``); the
   velocity block is zero as in the tutorial (the Riccati solution damps it through the dynamics).
   ``R = I``. ``K`` from the discrete algebraic Riccati equation (scipy's ``solve_discrete_are``).
4. **Control**: ``u = u₀ − K [mj_differentiatePos(qpos₀, qpos); qvel]`` every step.

:func:`push_recovery` then finds, by bisection, the largest sideways push (a constant world-frame force on a
body for ``duration`` seconds) a policy recovers from in MuJoCo: after the push the trunk must return within
``height_tol`` of its initial height and ``angle_tol`` of its initial orientation and come to rest
(``‖v_trunk‖ < speed_tol``) by the end of the run. It takes a policy factory, so that any controller (the
recipe's, or one designed on a contact-constrained plant) is measured the same way.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import mujoco
import numpy as np

from shinro_ctrl.engine.core import MujocoEngine
from shinro_ctrl.errors import InvalidArgument

__all__ = [
    "Policy",
    "PushRecovery",
    "StandingPoint",
    "TransitionFdLqr",
    "push_recovery",
    "simulate_push",
    "standing_point",
    "transition_fd_lqr",
]

#: A feedback law in MuJoCo's coordinates: ``(qpos (nq,), qvel (nv,)) -> ctrl (nu,)``.
Policy = Callable[[np.ndarray, np.ndarray], np.ndarray]


@dataclass(frozen=True)
class StandingPoint:
    """The tutorial's standing point.

    Attributes:
        qpos: ``(nq,)`` the keyframe with the base height adjusted so that the contacts carry the weight.
        ctrl: ``(nu,)`` the least-squares controls holding it.
        qfrc: ``(nv,)`` the generalized force ``mj_inverse`` asks for there.
        residual: ``‖qfrc − M_actᵀ ctrl‖`` [N, N m]: what the actuators cannot produce (the free joint's part).
        height_offset: The base height shift from the keyframe [m].
    """

    qpos: np.ndarray
    ctrl: np.ndarray
    qfrc: np.ndarray
    residual: float
    height_offset: float


def _moment(m: mujoco.MjModel, d: mujoco.MjData) -> np.ndarray:
    """The dense actuator moment matrix ``(nu, nv)`` at the current ``mj_forward``."""
    dense = np.zeros((m.nu, m.nv))
    mujoco.mju_sparse2dense(dense, d.actuator_moment, d.moment_rownnz, d.moment_rowadr, d.moment_colind)
    return dense


def _free_adr(m: mujoco.MjModel) -> tuple[int, int, int]:
    """``(qpos address, dof address, body)`` of the first free joint."""
    for j in range(m.njnt):
        if int(m.jnt_type[j]) == int(mujoco.mjtJoint.mjJNT_FREE):
            return int(m.jnt_qposadr[j]), int(m.jnt_dofadr[j]), int(m.jnt_bodyid[j])
    raise InvalidArgument("the tutorial recipe needs a floating-base model (a free joint); this model has none")


def standing_point(engine: MujocoEngine, keyframe: str = "stand", *, span: float = 5e-3) -> StandingPoint:
    """Step 1 of the recipe: the base height and controls at which the robot stands still (see the module doc).

    Args:
        engine: The robot's engine (its data is overwritten).
        keyframe: The standing keyframe's name.
        span: Half-width of the height grid [m] (2001 heights).

    Raises:
        InvalidArgument: no free joint, or no such keyframe (the valid names are listed).
    """
    m, d = engine.model, engine.data
    qadr, _, _ = _free_adr(m)
    keys = [m.key(i).name for i in range(m.nkey)]
    if keyframe not in keys:
        raise InvalidArgument(f"no keyframe '{keyframe}' (valid: {', '.join(keys) or 'none'})")
    key = keys.index(keyframe)
    offsets = np.linspace(-span, span, 2001)
    vertical = np.empty_like(offsets)
    for i, dz in enumerate(offsets):
        mujoco.mj_resetDataKeyframe(m, d, key)
        d.qpos[qadr + 2] += dz
        mujoco.mj_forward(m, d)
        d.qacc[:] = 0.0
        mujoco.mj_inverse(m, d)
        vertical[i] = d.qfrc_inverse[2]
    best = float(offsets[int(np.argmin(np.abs(vertical)))])
    mujoco.mj_resetDataKeyframe(m, d, key)
    d.qpos[qadr + 2] += best
    mujoco.mj_forward(m, d)
    d.qacc[:] = 0.0
    mujoco.mj_inverse(m, d)
    qfrc = d.qfrc_inverse.copy()
    moment = _moment(m, d)
    ctrl = np.linalg.lstsq(moment.T, qfrc, rcond=None)[0]
    return StandingPoint(d.qpos.copy(), ctrl, qfrc, float(np.linalg.norm(qfrc - moment.T @ ctrl)), best)


@dataclass
class TransitionFdLqr:
    """The recipe's controller: ``u = u₀ − K [mj_differentiatePos(qpos₀, qpos); qvel]``, clipped to ``ctrlrange``.

    Attributes:
        model: The ``MjModel`` it was designed on (for ``mj_differentiatePos``).
        point: The standing point.
        K: ``(nu, 2 nv)`` gain.
        A, B: The ``mjd_transitionFD`` Jacobians it was designed from.
    """

    model: mujoco.MjModel
    point: StandingPoint
    K: np.ndarray
    A: np.ndarray
    B: np.ndarray

    def __post_init__(self) -> None:
        self._dq = np.zeros(self.model.nv)
        self._dx = np.zeros(2 * self.model.nv)
        lo, hi = self.model.actuator_ctrlrange.T
        limited = self.model.actuator_ctrllimited.astype(bool)
        self._lo = np.where(limited, lo, -np.inf)
        self._hi = np.where(limited, hi, np.inf)

    def __call__(self, qpos: np.ndarray, qvel: np.ndarray) -> np.ndarray:
        """The control ``(nu,)`` at ``(qpos, qvel)``."""
        mujoco.mj_differentiatePos(self.model, self._dq, 1.0, self.point.qpos, qpos)
        nv = self.model.nv
        self._dx[:nv] = self._dq
        self._dx[nv:] = qvel
        return np.clip(self.point.ctrl - self.K @ self._dx, self._lo, self._hi)


def transition_fd_lqr(
    engine: MujocoEngine,
    feet: Sequence[str],
    *,
    keyframe: str = "stand",
    balance_weight: float = 1000.0,
    joint_weight: float = 3.0,
    rotation_weight: float = 10.0,
) -> TransitionFdLqr:
    """The MuJoCo-tutorial LQR of a standing robot (steps 1-3 of the module doc).

    Args:
        engine: The robot's engine (its data is overwritten; left at the standing point).
        feet: Names of the sites (or bodies) whose mean is the support centre.
        keyframe: The standing keyframe.
        balance_weight: ``w_b``, weight of the centre of mass's horizontal offset from the support centre.
        joint_weight: ``w_j``, weight of each actuated joint's deviation.
        rotation_weight: ``w_rot``, weight of the base rotation (the three angular tangent coordinates).

    Raises:
        InvalidArgument: no free joint, an unknown keyframe, an unknown foot name (valid names listed).
    """
    from scipy.linalg import solve_discrete_are

    m, d = engine.model, engine.data
    _, dadr, base = _free_adr(m)
    sites = [m.site(i).name for i in range(m.nsite)]
    bodies = [m.body(i).name for i in range(m.nbody)]
    for name in feet:
        if name not in sites and name not in bodies:
            raise InvalidArgument(f"unknown foot '{name}': give sites or bodies (sites: {', '.join(sites)})")
    point = standing_point(engine, keyframe)
    d.qpos[:] = point.qpos
    d.qvel[:] = 0.0
    d.ctrl[:] = point.ctrl
    mujoco.mj_forward(m, d)
    nv, nu = m.nv, m.nu
    A = np.zeros((2 * nv + m.na, 2 * nv + m.na))
    B = np.zeros((2 * nv + m.na, nu))
    mujoco.mjd_transitionFD(m, d, 1e-6, True, A, B, None, None)
    # balance: the centre of mass's horizontal offset from the support centre
    jac_com = np.zeros((3, nv))
    mujoco.mj_jacSubtreeCom(m, d, jac_com, base)
    jac_feet = np.zeros((3, nv))
    for name in feet:
        jac = np.zeros((3, nv))
        if name in sites:
            mujoco.mj_jacSite(m, d, jac, None, m.site(name).id)
        else:
            mujoco.mj_jacBody(m, d, jac, None, m.body(name).id)
        jac_feet += jac / len(feet)
    J_b = (jac_com - jac_feet)[:2]
    Q_pos = balance_weight * J_b.T @ J_b
    actuated = sorted({int(m.jnt_dofadr[m.actuator_trnid[a, 0]]) for a in range(nu)})
    Q_pos[actuated, actuated] += joint_weight
    for i in range(dadr + 3, dadr + 6):
        Q_pos[i, i] += rotation_weight
    Q = np.zeros((2 * nv, 2 * nv))
    Q[:nv, :nv] = Q_pos
    Q += 1e-9 * np.eye(2 * nv)  # the base position is unobservable in the cost; keep Q positive definite
    R = np.eye(nu)
    A2, B2 = A[: 2 * nv, : 2 * nv], B[: 2 * nv]
    P = solve_discrete_are(A2, B2, Q, R)
    K = np.linalg.solve(R + B2.T @ P @ B2, B2.T @ P @ A2)
    return TransitionFdLqr(m, point, K, A2, B2)


@dataclass(frozen=True)
class PushRecovery:
    """The result of :func:`push_recovery`.

    Attributes:
        largest_force: The largest push [N] recovered from (0.0: not even the smallest tried).
        first_failure: The smallest push tried that was not recovered from [N] (``inf``: none failed).
        design_time: Wall-clock time of the policy factory [s].
        trials: ``[(force, recovered)]`` in the order tried.
    """

    largest_force: float
    first_failure: float
    design_time: float
    trials: tuple[tuple[float, bool], ...]


def simulate_push(
    engine: MujocoEngine,
    policy: Policy,
    start: tuple[np.ndarray, np.ndarray],
    *,
    body: str,
    force: Sequence[float],
    push_time: float = 0.2,
    duration: float = 0.1,
    settle: float = 2.0,
    height_tol: float = 0.05,
    angle_tol: float = 0.15,
    speed_tol: float = 0.05,
    monitor: Callable[[], None] | None = None,
) -> bool:
    """Run ``policy`` in MuJoCo from ``start = (qpos, qvel)``, push ``body`` with the world ``force`` [N] over
    ``[push_time, push_time + duration)``, and say whether the robot recovered by ``push_time + duration +
    settle``: trunk (the free joint's body) within ``height_tol`` [m] of its initial height and ``angle_tol``
    [rad] of its initial orientation, and its linear speed below ``speed_tol`` [m/s]. A diverged simulation
    counts as a fall. ``monitor`` (e.g. the engine's :meth:`~shinro_ctrl.engine.MujocoEngine.balance_monitor`)
    is called at the start and after every step, with the body poses of the new state.
    """
    m, d = engine.model, engine.data
    _, dadr, base = _free_adr(m)
    b = m.body(body).id
    mujoco.mj_resetData(m, d)
    d.qpos[:], d.qvel[:] = start
    mujoco.mj_forward(m, d)
    z0, q0 = float(d.xpos[base, 2]), d.xquat[base].copy()
    dt = m.opt.timestep
    n_on, n_off = round(push_time / dt), round((push_time + duration) / dt)
    steps = round((push_time + duration + settle) / dt)
    F = np.asarray(force, dtype=float)
    if monitor is not None:
        monitor()
    for k in range(steps):
        d.xfrc_applied[b, :3] = F if n_on <= k < n_off else 0.0
        d.ctrl[:] = policy(d.qpos, d.qvel)
        mujoco.mj_step(m, d)
        if monitor is not None:
            mujoco.mj_kinematics(m, d)
            monitor()
        if not (np.all(np.isfinite(d.qpos)) and abs(d.qpos[2] - start[0][2]) < 1.0):
            d.xfrc_applied[:] = 0.0
            return False
    d.xfrc_applied[:] = 0.0
    mujoco.mj_kinematics(m, d)
    angle = 2.0 * math.acos(min(1.0, abs(float(np.dot(q0, d.xquat[base])))))
    speed = float(np.linalg.norm(d.qvel[dadr : dadr + 3]))
    return abs(float(d.xpos[base, 2]) - z0) < height_tol and angle < angle_tol and speed < speed_tol


def push_recovery(
    engine: MujocoEngine,
    factory: Callable[[MujocoEngine], tuple[Policy, tuple[np.ndarray, np.ndarray]]],
    *,
    body: str,
    direction: Sequence[float] = (0.0, 1.0, 0.0),
    duration: float = 0.1,
    high: float = 400.0,
    resolution: float = 1.0,
    **simulate: float,
) -> PushRecovery:
    """The largest push along ``direction`` (for ``duration`` s on ``body``) a policy recovers from, by bisection.

    Args:
        engine: The robot's engine.
        factory: ``factory(engine) -> (policy, (qpos₀, qvel₀))``: designs the controller (timed: the design
            time) and gives the state to start from (its standing point).
        body: The pushed body (the trunk).
        direction: World direction of the push (normalized).
        duration: Push length [s].
        high: Upper end of the search [N] (a push this large is tried first; if recovered, it is the answer).
        resolution: Stop when the bracket is narrower [N].
        **simulate: Passed to :func:`simulate_push` (``push_time``, ``settle``, tolerances).

    Returns:
        The :class:`PushRecovery`; bisection assumes that recovering from a push implies recovering from any
        smaller one along the same direction.
    """
    t0 = time.perf_counter()
    policy, start = factory(engine)
    design = time.perf_counter() - t0
    u = np.asarray(direction, dtype=float)
    u = u / np.linalg.norm(u)
    trials: list[tuple[float, bool]] = []

    def ok(f: float) -> bool:
        r = simulate_push(engine, policy, start, body=body, force=f * u, duration=duration, **simulate)
        trials.append((f, r))
        return r

    if not ok(0.0):
        return PushRecovery(0.0, 0.0, design, tuple(trials))
    if ok(high):
        return PushRecovery(high, math.inf, design, tuple(trials))
    lo, hi = 0.0, high
    while hi - lo > resolution:
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if ok(mid) else (lo, mid)
    return PushRecovery(lo, hi, design, tuple(trials))
