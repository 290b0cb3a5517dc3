r"""A serial-link arm driven in Cartesian space: FK, three Jacobians, IK, MuJoCo mode.

Kinematics: :class:`~shinro_ctrl.kinematics.SerialChain` (core) holds the
chain ``T_i = T_{i-1} Trans(o_i) Rot(a_i, q_i)``, its numeric and CasADi FK,
the geometric, exact and finite-difference Jacobians and the compiled
evaluator the IK solvers use; the arm owns one as :attr:`ArmRobot.chain`.

Plant model. The state is the end-effector pose ``[x, y, z, roll, pitch,
yaw]`` (m, ZYX Euler rad) and the input a twist ``[vx, vy, vz, roll_rate,
pitch_rate, yaw_rate]`` (m/s, rad/s): ``xdot = u``, so ``get_model()`` is
``A = I_6``, ``B = dt I_6``. :meth:`ArmRobot.step` integrates the twist into a
target pose, solves IK for it and commands the joints.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import TYPE_CHECKING, Protocol

import casadi as cs
import numpy as np

from shinro_ctrl.backend import ArrayBackend
from shinro_ctrl.errors import ConfigError, InvalidArgument, SimulationDiverged
from shinro_ctrl.kinematics import (
    IKResult,
    KinematicsBuffer,
    SerialChain,
    damped_least_squares,
    euler_zyx_from_matrix,
    euler_zyx_to_matrix,
    pose_to_transform,
    so3_log,
    so3_log_flat,
)
from shinro_ctrl.plants._arm6 import ARM6, ARM6_AXES, ARM6_BODIES, ARM6_JOINTS, shipped_arm6
from shinro_ctrl.plants._arm_config import with_engine_limits
from shinro_ctrl.plants.base import MjcfPatch, Plant, split_config
from shinro_ctrl.validation import as_matrix, as_vector, check_positive

if TYPE_CHECKING:
    from collections.abc import Callable, Mapping

    from numpy.typing import ArrayLike

    from shinro_ctrl.plants.standalone import Engine

__all__ = ["ARM6", "ARM6_JOINTS", "ARM6_SITE", "ArmIK", "ArmRobot", "shipped_arm6"]

_AXES = ("x", "y", "z")
ARM6_SITE = "ee_site"


class ArmIK(Protocol):
    """An IK solver an arm can step with (e.g. :class:`~shinro_ctrl.controllers.ik_qp.IKQP`).

    ``track(q, T) -> q⁺`` moves the joints ``q (n,)`` towards the pose ``T (4, 4)`` within one
    control step; an optional ``solve(T, q, tol=, restarts=, seed=)`` returns an
    :class:`~shinro_ctrl.kinematics.IKResult` (used by :meth:`ArmRobot.set_state`).
    """

    def track(self, q: np.ndarray, target: np.ndarray) -> np.ndarray: ...


#: The shipped MJCF arm (``assets/arm6.xml``): its joints, axes and the body of each joint.
class ArmRobot(Plant):
    """Serial-link arm with forward kinematics, Jacobians and inverse kinematics.

    Standalone, :meth:`step` solves IK on the analytic kinematics and sets the
    joints; with a MuJoCo engine attached (:meth:`physics_engine`) it sends
    the IK joint targets to the position actuators, steps the engine and
    reads the pose back. IK in :meth:`step` uses :attr:`ik` when one is set
    (an :class:`~shinro_ctrl.controllers.ik_qp.IKQP`: limit- and
    velocity-aware), else the damped pseudoinverse of
    :meth:`inverse_kinematics` (standalone) or :meth:`engine_ik` (engine).

    ``ArmRobot()`` without geometry is the shipped arm :data:`ARM6` (a Python
    constant, also in ``configs/arm6.toml``, matched to ``assets/arm6.xml``; UR5
    link lengths, axes ``z y y y z x``).

    Args:
        num_dof: Number of joints ``n`` (>= 1).
        dt: Control step [s], > 0.
        joint_limits: ``(n, 2)`` rows ``[min, max]`` [rad], ``min <= max``.
        joint_offsets: ``(n, 3)`` link offsets ``o_i`` [m], each in the parent joint's frame.
        rot_axes: ``n`` axis letters, each ``"x"``, ``"y"`` or ``"z"`` (a string such as
            ``"zyyyzx"`` works too). ``joint_limits``, ``joint_offsets`` and ``rot_axes`` are
            given together, or all omitted for the shipped arm.
        joint_names: ``n`` unique joint names (default ``joint_0`` …, or the shipped arm's
            names); in engine mode they name the MJCF joints (and their position actuators).
        ee_body_name: In engine mode, the MJCF body whose frame is the end effector. Default:
            the site ``ee_site`` when the model has one, else the last body.
        backend: The seed's array backend keyword; accepted, not used (numbers are numpy arrays).
        ee_offset: ``(3,)`` end-effector offset [m] in the last joint's frame (default zero).
        ik: The IK :meth:`step` uses, given at construction: None (the damped
            pseudoinverse), an :class:`ArmIK` (anything with ``track(q, T)``), or a
            factory ``arm -> ArmIK`` called with this arm once it is built (how a
            scenario gives the arm its ``IKQP`` controller: ``ArmRobot(ik=IKQP)``).

    Attributes:
        num_dof: ``n``.
        joint_limits: ``(n, 2)`` array [rad].
        joint_offsets: ``(n, 3)`` array [m].
        axes: Tuple of the ``n`` axis letters.
        joint_names: Tuple of the ``n`` joint names.
        ee_offset: ``(3,)`` array [m].
        chain: The :class:`~shinro_ctrl.kinematics.SerialChain` (FK, Jacobians).
        dt: Control step [s].
        ik: The IK solver :meth:`step` uses (see the ``ik`` argument), or None for the
            damped pseudoinverse.

    Raises:
        InvalidArgument: a wrong shape (the message names the argument), ``dt <= 0``, a limit
            with ``min > max``, or an axis letter other than x, y, z (a ``ValueError``).
        NonFiniteError: a limit or offset is NaN or infinite.
    """

    aliases = ("arm6",)
    state_names = ("x", "y", "z", "roll", "pitch", "yaw")
    input_names = ("vx", "vy", "vz", "roll_rate", "pitch_rate", "yaw_rate")
    param_names = ()
    asset = "arm6.xml"
    #: Scenario metrics track the end-effector position [m] (Euler angles wrap and mix units).
    tracked_states = ("x", "y", "z")
    takes_ik = True

    def __init__(
        self,
        num_dof: int = 6,
        dt: float = 0.002,
        joint_limits: ArrayLike | None = None,
        joint_offsets: ArrayLike | None = None,
        rot_axes: Sequence[str] | None = None,
        joint_names: Sequence[str] | None = None,
        ee_body_name: str | None = None,
        backend: ArrayBackend | None = None,
        ee_offset: ArrayLike | None = None,
        ik: ArmIK | Callable[[ArmRobot], ArmIK] | None = None,
    ):
        if isinstance(num_dof, bool) or not isinstance(num_dof, int | np.integer) or num_dof < 1:
            raise InvalidArgument(f"num_dof must be a positive integer, got {num_dof!r}")
        n = self.num_dof = int(num_dof)
        geometry = {"joint_limits": joint_limits, "joint_offsets": joint_offsets, "rot_axes": rot_axes}
        if all(v is None for v in geometry.values()):
            if n != 6:
                raise InvalidArgument(
                    f"num_dof = {n} needs joint_limits, joint_offsets and rot_axes "
                    "(without them the arm is the shipped 6-joint arm6)"
                )
            shipped = shipped_arm6()
            joint_limits, joint_offsets, rot_axes = (shipped[k] for k in geometry)
            if joint_names is None:
                joint_names = shipped["joint_names"]
        else:
            missing = [k for k, v in geometry.items() if v is None]
            if missing:
                raise InvalidArgument(f"{missing[0]} is required when any of {', '.join(geometry)} is given")
        check_positive("dt", dt)
        limits = as_matrix("joint_limits", joint_limits, (n, 2))
        bad = np.flatnonzero(limits[:, 0] > limits[:, 1])
        if bad.size:
            i = int(bad[0])
            raise InvalidArgument(
                f"joint_limits: row {i} has min > max ({limits[i, 0]:g} > {limits[i, 1]:g}); rows are [min, max]"
            )
        self.joint_limits = limits
        self.joint_offsets = as_matrix("joint_offsets", joint_offsets, (n, 3))
        axes = tuple(rot_axes)
        if len(axes) != n:
            raise InvalidArgument(f"rot_axes: expected {n} axes but found {len(axes)}")
        for i, a in enumerate(axes):
            if a not in _AXES:
                raise InvalidArgument(f"rot_axes[{i}] must be one of 'x', 'y', 'z', got {a!r}")
        self.axes = axes
        if joint_names is None:
            names = tuple(f"joint_{i}" for i in range(n))
        else:
            if isinstance(joint_names, str):
                raise InvalidArgument(f"joint_names must be a list of {n} names, got the string {joint_names!r}")
            names = tuple(joint_names)
            if len(names) != n:
                raise InvalidArgument(f"joint_names: expected {n} names but found {len(names)}")
            if not all(isinstance(s, str) and s for s in names) or len(set(names)) != n:
                raise InvalidArgument(f"joint_names must be {n} unique non-empty strings, got {list(names)}")
        self.joint_names = names
        if ee_body_name is not None and not isinstance(ee_body_name, str):
            raise InvalidArgument(f"ee_body_name must be a string or None, got {ee_body_name!r}")
        self.ee_body_name = ee_body_name
        self.ee_offset = np.zeros(3) if ee_offset is None else as_vector("ee_offset", ee_offset, 3)
        self._init(dt=dt, params={}, backend=backend)

        self._lo = self.joint_limits[:, 0].copy()
        self._hi = self.joint_limits[:, 1].copy()
        self.chain = SerialChain(self.joint_offsets, self.axes, self.ee_offset)
        self._offsets = self.chain.offsets
        self._q = np.clip(np.zeros(n), self._lo, self._hi)  # home pose (q = 0 where the limits allow)
        self._q_cmd = self._q.copy()
        self._ee_frame: tuple[str, str] | None = None
        self._dofs: list[int] = []
        self.state = self._pose_of(self._q)
        if ik is None or callable(getattr(ik, "track", None)):
            self.ik: ArmIK | None = ik
        elif callable(ik):
            self.ik = ik(self)
            if not callable(getattr(self.ik, "track", None)):
                raise InvalidArgument(f"ik: the factory returned {type(self.ik).__name__}, which has no track(q, T)")
        else:
            raise InvalidArgument(f"ik must be None, an IK solver with track(q, T) or a factory, got {ik!r}")

    # ------------------------------------------------------------ dynamics
    def equations(self, bk, x, u, p):
        """Cartesian kinematic model: the pose moves with the commanded twist, ``xdot = u``."""
        return bk.stack(bk.unpack(u, 6))

    def equilibrium(self) -> tuple[np.ndarray, np.ndarray]:
        """The home pose (FK at ``q = 0`` clipped to the limits) and zero twist."""
        return self._pose_of(np.clip(np.zeros(self.num_dof), self._lo, self._hi)), np.zeros(6)

    # ---------------------------------------------------------- kinematics
    def _joints(self, q: ArrayLike, name: str = "q") -> np.ndarray:
        return as_vector(name, q, self.num_dof)

    def forward_kinematics(self, joint_angles: ArrayLike) -> tuple[np.ndarray, list[np.ndarray], list[np.ndarray]]:
        """End-effector transform and the joints' world positions and axes.

        Args:
            joint_angles: Joint angles ``(n,)`` [rad].

        Returns:
            ``(T_ee, positions, axes)``: ``T_ee (4, 4)``; ``positions``, a list of ``n``
            joint origins ``(3,)`` [m]; ``axes``, a list of ``n`` unit world axes ``(3,)``.
        """
        return self.chain.fk(self._joints(joint_angles, "joint_angles"))

    def ee_pose(self, q: ArrayLike) -> np.ndarray:
        """End-effector pose ``[x, y, z, roll, pitch, yaw]`` (6,) at joints ``q (n,)``."""
        return self._pose_of(self._joints(q))

    def _pose_of(self, q: np.ndarray) -> np.ndarray:
        p, R, _ = self._kinematics()(q)
        return np.concatenate([p, euler_zyx_from_matrix(R)])

    def jacobian(self, q: ArrayLike, method: str = "geometric", eps: float = 1e-6) -> np.ndarray:
        r"""World-frame end-effector Jacobian ``J (6, n)``, position rows first.

        ``[v; ω] = J q̇`` with ``v`` the EE linear velocity [m/s] and ``ω`` the world angular
        velocity [rad/s].

        Args:
            q: Joint angles ``(n,)`` [rad].
            method: ``"geometric"`` (axes × lever arms, the fast default: the formula of
                :meth:`SerialChain.geometric_columns` compiled once with CasADi, a few µs), ``"exact"``
                (CasADi derivative of the symbolic FK; angular rows
                :math:`\mathrm{vee}(\partial R/\partial q_i\, R^\top)`) or ``"fd"`` (central
                differences of the FK with step ``eps``; angular rows from the log map).
            eps: Finite-difference step [rad] (``"fd"`` only).
        """
        q = self._joints(q)
        if method == "geometric":
            return self._kinematics()(q)[2].copy()
        if method == "exact":
            return self.chain.exact_jacobian(q)
        if method == "fd":
            return self.chain.fd_jacobian(q, check_positive("eps", eps))
        raise InvalidArgument(f"unknown Jacobian method {method!r}; valid: exact, fd, geometric")

    def _symbolic_chain(self) -> tuple:
        """``(q, p (3, 1), R (3, 3), J_geometric (6, n))`` as CasADi SX (see :meth:`SerialChain.symbolic`)."""
        return self.chain.symbolic()

    def symbolic_fk(self) -> cs.Function:
        """The FK as a CasADi ``Function`` named ``"fk"``: ``q (n,) -> (p (3,), R (3, 3))``."""
        return self.chain.symbolic_fk()

    def _kinematics(self) -> KinematicsBuffer:
        """Compiled evaluator of ``(p, R, J)`` at a joint vector (the IK hot path)."""
        return self.chain.evaluator()

    # ------------------------------------------------------------------ IK
    def inverse_kinematics(
        self,
        target_pose: ArrayLike,
        max_iters: int = 100,
        q_init: ArrayLike | None = None,
        tol: float = 1e-4,
        max_step: float = 0.2,
        *,
        lam: float = 1e-3,
        full_output: bool = False,
    ) -> np.ndarray | IKResult:
        r"""Damped-pseudoinverse IK on the analytic kinematics (the seed's solver, made robust).

        Each iteration takes :math:`\Delta q = J^\top (J J^\top + \lambda^2 I)^{-1} e` with
        ``e = [p_t − p; log(R_t Rᵀ)]`` (world-frame rotation vector, robust near pitch ±90°
        and at a rotation of π), clamps every component to ``±max_step`` and clips ``q`` to
        the joint limits. It stops when both errors are below ``tol``.

        Args:
            target_pose: Target end-effector transform ``(4, 4)``.
            max_iters: Maximum iterations.
            q_init: Start ``(n,)`` [rad]; default the current joints.
            tol: Convergence tolerance on the position [m] and orientation [rad] errors.
            max_step: Largest joint change per iteration [rad].
            lam: Damping ``λ`` of the least-squares solve.
            full_output: Return an :class:`~shinro_ctrl.kinematics.IKResult` instead of ``q``.

        Returns:
            Joint angles ``(n,)`` inside the limits (the last iterate, converged or not), or the
            :class:`IKResult` when ``full_output``.
        """
        Tt = as_matrix("target_pose", target_pose, (4, 4))
        q = self._q.copy() if q_init is None else np.clip(self._joints(q_init, "q_init"), self._lo, self._hi)
        check_positive("max_step", max_step)
        kin = self._kinematics()
        pt = Tt[:3, 3].copy()
        Rt = Tt[:3, :3].copy()
        errs = [0.0, 0.0]

        def error_jacobian(q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            p, R, J = kin(q)
            e = np.concatenate([pt - p, so3_log_flat((Rt @ R.T).ravel().tolist())])
            errs[0], errs[1] = math.hypot(*e[:3]), math.hypot(*e[3:])  # hypot: no overflow for far targets
            return e, J

        with np.errstate(over="ignore", invalid="ignore"):  # a target far out of reach: checked below
            q, it, _, J = damped_least_squares(
                error_jacobian,
                q,
                self._lo,
                self._hi,
                max_iters=max_iters,
                max_step=max_step,
                lam=lam,
                converged=lambda e: errs[0] < tol and errs[1] < tol,
            )
        if not np.isfinite(q).all():
            raise SimulationDiverged(f"ArmRobot IK toward a non-finite or overflowing target ended at q = {q}")
        if not full_output:
            return q
        return IKResult(q, errs[0] < tol and errs[1] < tol, it, errs[0], errs[1], J.copy(), 1)

    # -------------------------------------------------------------- joints
    @property
    def q(self) -> np.ndarray:
        """Current joint angles ``(n,)`` [rad] (measured from the engine in engine mode)."""
        if self._engine is not None:
            self._q = self._read_joints()
        return self._q.copy()

    joint_positions = q

    @property
    def q_cmd(self) -> np.ndarray:
        """Last commanded joint targets ``(n,)`` [rad] (equal to :attr:`q` standalone)."""
        return self._q_cmd.copy()

    def limit_violation(self) -> float:
        """Depth [rad] of the last step's contact with a joint limit (0 when none).

        The larger of how far the last IK solution was past a limit before it was clipped
        (the clamp of :meth:`step`) and how far the current joints are outside their limits.
        """
        q = self.q
        return float(max(self._contact, np.max(self._lo - q), np.max(q - self._hi)))

    def set_joint_positions(self, q: ArrayLike) -> None:
        """Place the arm at joints ``q (n,)`` [rad] (engine: at rest, actuators holding ``q``).

        Raises:
            InvalidArgument: wrong shape or outside the joint limits.
        """
        q = self._joints(q)
        out = np.flatnonzero((q < self._lo) | (q > self._hi))
        if out.size:
            i = int(out[0])
            raise InvalidArgument(
                f"joint '{self.joint_names[i]}' = {q[i]:g} rad is outside its limits [{self._lo[i]:g}, {self._hi[i]:g}]"
            )
        self._q = q.copy()
        self._q_cmd = q.copy()
        if self._engine is not None:
            for name, v in zip(self.joint_names, q.tolist(), strict=True):
                self._engine.set_joint_qpos(name, v)
                self._engine.set_joint_vel(name, 0.0)
                self._engine.set_joint_ctrl(name, v)
            self._engine.forward()
            self._x = self._engine_pose()
        else:
            self.state = self._pose_of(q)

    # ---------------------------------------------------------------- step
    def step(self, u: ArrayLike) -> np.ndarray:
        """Move the end effector by the twist ``u`` for one step ``dt``.

        The twist is integrated into a target pose ``x + dt u`` from the current (in engine
        mode, measured) pose, Euler angles with their rates, as the seed does. IK turns the
        target into joint targets: :attr:`ik` (``ik.track``, from the last commanded joints)
        when set, else the damped pseudoinverse (standalone: :meth:`inverse_kinematics`
        from the last commanded joints; engine: :meth:`engine_ik` from the measured ones).
        Standalone, the joints are set (clipped to the limits) and the state becomes their
        FK pose; with an engine, the targets go to the position actuators, the engine steps
        ``dt`` and the state is read back. Because the target is relative to the measured
        pose, the servo lag slows an open-loop twist in engine mode; a feedback controller
        (such as ``IKQP.__call__``) computes its twist from that same measured pose and
        closes the gap.

        Args:
            u: Twist ``(6,)`` ``[vx, vy, vz, roll_rate, pitch_rate, yaw_rate]`` [m/s, rad/s].

        Returns:
            Joint angles ``(n,)`` [rad] after the step (measured in engine mode).

        Raises:
            InvalidArgument: ``u`` has the wrong shape.
            NonFiniteError: ``u`` holds NaN or inf.
            ConcurrentUse: another thread is stepping this arm.
        """
        u = self._input(u)
        with self._step_guard:  # one thread at a time (Plant's class docstring)
            return self._step(u)

    def _step(self, u: np.ndarray) -> np.ndarray:
        x = self.get_state()
        target = x + self.dt * u
        if self._engine is not None:
            if self.ik is not None:
                q_cmd = self.ik.track(self._q_cmd, pose_to_transform(target))
            else:
                # A tolerance well below one step's motion (the seed's 1e-3 m would ignore a
                # twist of less than 1e-3 / dt m/s).
                q_cmd = self.engine_ik(target[:3], target_euler=target[3:], tol=1e-7)
            q_cmd = self._clamp(q_cmd, target)
            for name, v in zip(self.joint_names, q_cmd.tolist(), strict=True):
                self._engine.set_joint_ctrl(name, v)
            self._engine.step()
            self._q_cmd = q_cmd
            self._q = self._read_joints()
            self._x = self._engine_pose()
            return self._q.copy()
        T = pose_to_transform(target)
        if self.ik is not None:
            q = self.ik.track(self._q_cmd, T)
        else:
            # a tolerance well below one step's motion (the default 1e-4 would ignore a twist below 1e-4 / dt)
            q = self.inverse_kinematics(T, q_init=self._q_cmd, tol=1e-9)
        q = self._clamp(q, target)
        self._q = q
        self._q_cmd = q.copy()
        self.state = self._pose_of(q)
        return q.copy()

    def _clamp(self, q: np.ndarray, target: np.ndarray) -> np.ndarray:
        """``q`` clipped to the joint limits, and the step's contact with a limit kept for :meth:`limit_violation`.

        A contact is a step whose joints end on a limit short of the target pose (the IK clips
        inside its iterations): its depth is the distance [m + rad] to the target pose
        ``(6,)`` left by the limit (or how far ``q`` was outside, when larger).
        """
        outside = float(max(0.0, np.max(self._lo - q), np.max(q - self._hi)))
        q = np.clip(q, self._lo, self._hi)
        self._contact = outside
        if np.any((q <= self._lo) | (q >= self._hi)):
            with np.errstate(all="ignore"):  # a target far out of range: no numpy warning
                e = target - self._pose_of(q)
                e[3:] = np.angle(np.exp(1j * e[3:]))  # Euler angles wrap
            short = math.hypot(*e.tolist())  # hypot: no overflow
            if math.isfinite(short) and short > 1e-9:
                self._contact = max(outside, short)
        return q

    def get_state(self) -> np.ndarray:
        """End-effector pose ``[x, y, z, roll, pitch, yaw]`` (6,) (read from MuJoCo in engine mode)."""
        if self._engine is not None:
            self._x = self._engine_pose()
        return self._x.copy()

    def set_state(self, x: ArrayLike) -> None:
        """Move the arm to the end-effector pose ``x (6,)`` by IK (from the current joints).

        Uses :attr:`ik` (its ``solve`` with restarts) when set, else the damped
        pseudoinverse with 500 iterations.

        Raises:
            InvalidArgument: wrong shape, or the pose is not reached to 1e-6 (unreachable).
        """
        x = as_vector("ArmRobot state", x, 6)
        T = pose_to_transform(x)
        if self.ik is not None and hasattr(self.ik, "solve"):
            res = self.ik.solve(T, self._q_cmd, tol=1e-8, restarts=20, seed=0)
        else:
            res = self.inverse_kinematics(T, q_init=self._q_cmd, max_iters=500, tol=1e-8, full_output=True)
        if not (res.pos_err < 1e-6 and res.ori_err < 1e-6):
            raise InvalidArgument(
                f"pose {np.array2string(x, precision=4)} is not reachable within the joint limits "
                f"(closest: {res.pos_err:.3g} m, {res.ori_err:.3g} rad away)"
            )
        self.set_joint_positions(res.q)

    def mjcf_patch(self) -> MjcfPatch:
        """Match ``assets/arm6.xml`` to this arm: link offsets (body positions), visuals, ``dt``.

        Raises:
            InvalidArgument: the arm is not the shipped 6-joint layout (axes ``z y y y z x`` and the
                joint names of :data:`ARM6_JOINTS`), or has a non-zero ``ee_offset``.
        """
        if self.axes != ARM6_AXES or self.joint_names != ARM6_JOINTS or np.any(self.ee_offset != 0.0):
            raise InvalidArgument(
                "arm6.xml models a 6-joint arm with axes z y y y z x, joints "
                f"{', '.join(ARM6_JOINTS)} and no ee_offset; this arm has axes {' '.join(self.axes)}, "
                f"joints {', '.join(self.joint_names)} and ee_offset {self.ee_offset.tolist()}"
            )
        body_pos = {b: tuple(o) for b, o in zip(ARM6_BODIES, self._offsets, strict=True)}
        fromto = {f"{b}_geom": (0.0, 0.0, 0.0, *self._offsets[i + 1]) for i, b in enumerate(ARM6_BODIES[:-1])}
        return MjcfPatch(asset=self.asset, timestep=self.dt, body_pos=body_pos, geom_fromto=fromto)

    # -------------------------------------------------------------- engine
    def engine_ik(
        self,
        target_ee: ArrayLike,
        target_euler: ArrayLike | None = None,
        max_iters: int = 20,
        lam: float = 0.01,
        max_dq: float = 0.5,
        *,
        tol: float = 1e-3,
    ) -> np.ndarray:
        r"""Damped-least-squares IK on the MuJoCo engine's end-effector Jacobian.

        Iterates :math:`\Delta q = J^\top (J J^\top + \lambda^2 I)^{-1} e` with the engine's
        Jacobian and pose, ``Δq`` clamped to ``±max_dq`` and ``q`` clipped to the limits.
        Without ``target_euler`` only the position is solved (3 rows); with it the full pose
        (world-frame log-map orientation error). The engine's joint state is restored
        afterwards: the arm reaches the result through its actuators, not by a jump.

        Args:
            target_ee: Target position ``(3,)`` [m].
            target_euler: Optional target ZYX Euler angles ``(3,)`` [rad].
            max_iters: Maximum iterations.
            lam: Damping ``λ``.
            max_dq: Largest joint change per iteration [rad].
            tol: Stop when the error norm is below this.

        Returns:
            Joint angles ``(n,)`` inside the limits.

        Raises:
            RuntimeError: no engine is attached.
        """
        engine = self._engine
        if engine is None:
            raise RuntimeError("engine_ik needs a physics engine: call physics_engine(engine) first")
        pt = as_vector("target_ee", target_ee, 3)
        Rt = None if target_euler is None else euler_zyx_to_matrix(as_vector("target_euler", target_euler, 3))
        rows = 3 if Rt is None else 6
        saved = [(engine.get_joint_qpos(n), engine.get_joint_vel(n)) for n in self.joint_names]
        q = self._read_joints()

        def error_jacobian(q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            for name, v in zip(self.joint_names, q.tolist(), strict=True):
                engine.set_joint_qpos(name, v)
            engine.forward()
            p, R = self._engine_ee()
            e = pt - p if Rt is None else np.concatenate([pt - p, so3_log(Rt @ R.T)])
            return e, self._engine_jacobian()[:rows]

        try:
            # max_iters + 1 steps at most: this loop has always stepped once more than it was asked to
            q = damped_least_squares(
                error_jacobian,
                q,
                self._lo,
                self._hi,
                max_iters=max_iters + 1,
                max_step=max_dq,
                lam=lam,
                converged=lambda e: np.linalg.norm(e) < tol,
            )[0]
        finally:
            for name, (qp, qv) in zip(self.joint_names, saved, strict=True):
                engine.set_joint_qpos(name, qp)
                engine.set_joint_vel(name, qv)
            engine.forward()
        return q

    def physics_engine(self, engine: Engine | None) -> None:
        """Attach a MuJoCo engine (or detach with None).

        On attach the end-effector frame is resolved (``ee_body_name``, else the site
        ``ee_site``, else the last body), every joint name is checked against the model,
        and joints and pose are read from the engine; the commanded targets start at the
        measured joints. On detach the arm keeps its last joints and its state becomes
        their FK pose.

        Raises:
            UnknownName: a joint or the end-effector body is missing from the model (the
                message lists the valid names; a ``KeyError``).
        """
        if engine is None:
            self._engine = None
            self._ee_frame = None
            self._sim = self._standalone
            self.state = self._pose_of(self._q)
            return
        if self.ee_body_name is not None:
            frame = ("body", self.ee_body_name)
        elif ARM6_SITE in getattr(engine, "site_names", ()):
            frame = ("site", ARM6_SITE)
        else:
            frame = ("body", engine.body_names[-1])
        model = engine.model
        dofs = []
        for name in self.joint_names:
            engine.get_joint_qpos(name)  # KeyError listing the joints if missing
            dofs.append(int(model.jnt_dofadr[model.joint(name).id]))
        self._engine = engine
        self._sim = engine
        self._ee_frame = frame
        self._dofs = dofs
        engine.forward()
        self._engine_ee()  # KeyError for an unknown ee_body_name
        self._q = self._read_joints()
        self._q_cmd = self._q.copy()
        self._x = self._engine_pose()

    def engine_read(self, engine: Engine) -> np.ndarray:
        """The end-effector pose ``(6,)`` measured in the engine."""
        return self._engine_pose()

    def engine_write(self, engine: Engine, x: np.ndarray) -> None:
        """Place the arm at the pose ``x (6,)`` by IK (see :meth:`set_state`)."""
        self.set_state(x)

    def _read_joints(self) -> np.ndarray:
        e = self._engine
        return np.array([e.get_joint_qpos(n) for n in self.joint_names])

    def _engine_ee(self) -> tuple[np.ndarray, np.ndarray]:
        """End-effector ``(p (3,), R (3, 3))`` from the engine."""
        kind, name = self._ee_frame
        get = self._engine.get_site_pose if kind == "site" else self._engine.get_body_pose
        p, euler = get(name)
        return p, euler_zyx_to_matrix(euler)

    def _engine_pose(self) -> np.ndarray:
        kind, name = self._ee_frame
        get = self._engine.get_site_pose if kind == "site" else self._engine.get_body_pose
        p, euler = get(name)
        return np.concatenate([p, euler])

    def _engine_jacobian(self) -> np.ndarray:
        kind, name = self._ee_frame
        get = self._engine.get_site_jacobian if kind == "site" else self._engine.get_body_jacobian
        return get(name)[:, self._dofs]

    # -------------------------------------------------------------- config
    @classmethod
    def from_config(
        cls,
        config: Mapping[str, object] | object,
        backend: ArrayBackend | None = None,
        *,
        engine: Engine | None = None,
        ik: ArmIK | Callable[[ArmRobot], ArmIK] | None = None,
    ) -> ArmRobot:
        """Build the arm from a ``[plant]`` mapping (or dataclass) of constructor arguments.

        Omitted keys take the constructor defaults (no geometry: the shipped arm). With an
        engine, omitted ``joint_limits`` come from the MJCF joint ranges
        (``engine.get_joint_limits``); limits given in the config as well must agree with them.
        With an engine and neither ``joint_offsets`` nor ``rot_axes`` (e.g. ``{}`` or
        ``{"dt": 0.002}``), the geometry and joint names are the shipped arm's
        (:func:`shipped_arm6`) and only the limits come from the model.

        The seed's form is accepted too: a mapping carrying a runtime-injected ``engine`` and
        ``joint_groups`` (group name -> joint names), with ``joint_group`` naming the arm's group.

        Args:
            config: The ``[plant]`` table.
            backend: The seed's array backend; accepted, not used.
            engine: Optional MuJoCo engine to attach.
            ik: The arm's IK (see the constructor).

        Raises:
            ConfigError: unknown key, invalid value (e.g. ``joint_offsets`` without
                ``joint_limits`` standalone), a joint missing from the model, or config limits
                that disagree with the MJCF.
        """
        cfg, runtime = split_config(config)
        engine = runtime.get("engine", engine)
        group = cfg.pop("joint_group", None)
        if group is not None:
            groups = runtime.get("joint_groups") or {}
            if group not in groups:
                raise ConfigError(
                    f"[plant] ArmRobot: joint_group '{group}' is not among the joint_groups {list(groups)}"
                )
            cfg.setdefault("joint_names", list(groups[group]))
        if engine is not None:
            cfg = with_engine_limits(cfg, engine)
        return super().from_config(cfg, engine=engine, ik=ik)

    def __repr__(self) -> str:
        mode = "standalone" if self._engine is None else "engine"
        return f"ArmRobot(num_dof={self.num_dof}, axes={''.join(self.axes)!r}, dt={self.dt:g}, {mode})"
