"""Holonomic mobile base on omni wheels: kinematic pose integration and wheel speeds."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING

import numpy as np

from shinro_ctrl.backend import ArrayBackend
from shinro_ctrl.errors import InvalidArgument, SimulationDiverged
from shinro_ctrl.plants.base import MjcfPatch, Plant, split_config
from shinro_ctrl.validation import as_vector, check_positive

if TYPE_CHECKING:
    from numpy.typing import ArrayLike

    from shinro_ctrl.plants.standalone import Engine

__all__ = ["HolonomicMobileRobot"]


class HolonomicMobileRobot(Plant):
    r"""An ``n``-wheel omni-wheel base, commanded by its world-frame velocity.

    State ``[x, y, theta]`` (world position [m] and heading [rad]), input
    ``u = [vx, vy, omega]`` (world-frame velocity [m/s] and yaw rate [rad/s]).
    The model is kinematic: ``xdot = u``, so the linearization is
    ``A_c = 0``, ``B_c = I₃`` and the Euler-discrete model is
    ``A = I₃, B = dt I₃`` at every operating point.

    Wheel ``i`` sits at angle ``a_i = gamma + 2π i / n`` from the body x axis,
    at distance ``R`` from the centre, and rolls along ``(sin a_i, −cos a_i)``
    (its axle points radially outward). A body-frame twist
    ``[v_bx, v_by, ω]`` drives the wheels at

    .. math::

        \omega_{\text{wheels}} = \frac{1}{r} A_{\text{kin}}
            \begin{bmatrix} v_{bx} \\ v_{by} \\ \omega \end{bmatrix},
        \qquad (A_{\text{kin}})_i = [\sin a_i,\; -\cos a_i,\; -R],

    the rolling direction dotted with the wheel's contact-point velocity,
    divided by the wheel radius ``r``. :meth:`step` rotates the world command
    into the body frame with the heading *before* the step,
    ``v_b = Rz(θ)ᵀ [vx, vy]``, returns the wheel speeds and integrates the
    pose ``x ← x + dt u`` (the heading is not wrapped).

    In engine mode the plant's pose stays the source of truth: the MuJoCo
    base (``assets/holonomic_base.xml``) is a free-floating chassis pinned to
    that pose after every engine step, and each drive joint turns by its
    wheel speed times ``dt`` so the wheels visibly roll.

    Args:
        num_wheels: Number of wheels ``n`` (>= 3 for a holonomic base).
        radius_robots: Centre-to-wheel distance ``R`` [m], > 0.
        gamma: Angle of wheel 0 from the body x axis [rad].
        radius_wheels: Wheel radius ``r`` [m], > 0.
        dt: Step [s], > 0.
        drive_joints: MuJoCo hinge joint of each wheel, in wheel order
            (length ``n``); default ``wheel_0 … wheel_{n-1}`` as in the shipped
            asset; an empty list turns the visual wheel rolling off.
        backend: Array backend kept for API compatibility (numpy).

    Attributes:
        A_kinematics: ``A_kin`` ``(n, 3)`` (without the ``1/r``).
        A_pinv_kin: Its Moore–Penrose pseudoinverse ``(3, n)``: the least-squares
            body twist ``r A_pinv_kin ω_wheels`` of measured wheel speeds.
        wheel_angles: ``a_i`` ``(n,)`` [rad].

    Raises:
        ValueError: a malformed argument (named in the message).
    """

    aliases = ("holonomic",)
    state_names = ("x", "y", "theta")
    input_names = ("vx", "vy", "omega")
    param_names = ("radius_robots", "gamma", "radius_wheels")
    asset = "holonomic_base.xml"
    #: Names in the MJCF asset.
    free_joint = "root"
    #: The number of wheels in the shipped asset.
    asset_wheels = 3
    #: Height [m] of the chassis frame (the free joint's z) when pinned: on the floor.
    base_height = 0.0

    def __init__(
        self,
        num_wheels: int = 3,
        radius_robots: float = 0.15,
        gamma: float = 0.0,
        radius_wheels: float = 0.04,
        dt: float = 0.01,
        drive_joints: Sequence[str] | None = None,
        backend: ArrayBackend | None = None,
    ):
        if isinstance(num_wheels, bool) or not isinstance(num_wheels, (int, np.integer)) or num_wheels < 3:
            raise InvalidArgument(f"num_wheels must be an integer >= 3 (a holonomic base), got {num_wheels!r}")
        self.n = int(num_wheels)
        self.R = check_positive("radius_robots", radius_robots)
        try:
            self.gamma = float(gamma)
        except (TypeError, ValueError):
            raise InvalidArgument(f"gamma must be a number (rad), got {gamma!r}") from None
        if not math.isfinite(self.gamma):
            raise InvalidArgument(f"gamma must be finite, got {gamma!r}")
        self.r = check_positive("radius_wheels", radius_wheels)
        if drive_joints is None:
            joints = [f"wheel_{i}" for i in range(self.n)]
        elif isinstance(drive_joints, str) or not all(isinstance(j, str) for j in drive_joints):
            raise InvalidArgument(f"drive_joints must be a list of joint names, got {drive_joints!r}")
        else:
            joints = list(drive_joints)
            if joints and len(joints) != self.n:
                raise InvalidArgument(
                    f"drive_joints: expected {self.n} names (one per wheel) or none, but found {len(joints)}"
                )
        self.drive_joints: list[str] = joints
        self._init(
            dt=dt,
            params={"radius_robots": self.R, "gamma": self.gamma, "radius_wheels": self.r},
            backend=backend,
        )
        self.wheel_angles = self.gamma + 2.0 * math.pi * np.arange(self.n) / self.n
        self.A_kinematics, self.A_pinv_kin = self._build_kinematics()
        self._pending_wheel_delta: np.ndarray | None = None

    def _build_kinematics(self) -> tuple[np.ndarray, np.ndarray]:
        a = self.wheel_angles
        A = np.column_stack([np.sin(a), -np.cos(a), np.full(self.n, -self.R)])
        return A, np.linalg.pinv(A)

    # ------------------------------------------------------------ dynamics
    def equations(self, bk, x, u, p):
        vx, vy, omega = bk.unpack(u, 3)
        return bk.stack([vx, vy, omega])

    def integrate(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        """Exact for the kinematic model: ``x + dt u``."""
        return x + self.dt * u

    # ---------------------------------------------------------- kinematics
    @staticmethod
    def _world_to_body(u: np.ndarray, theta: float) -> np.ndarray:
        c, s = math.cos(theta), math.sin(theta)
        return np.array([c * u[0] + s * u[1], -s * u[0] + c * u[1], u[2]])

    def wheel_speeds(self, u_world: ArrayLike, theta: float | None = None) -> np.ndarray:
        """Wheel speeds ``(n,)`` [rad/s] for a world-frame command at heading ``theta``.

        Args:
            u_world: ``[vx, vy, omega]`` ``(3,)`` in the world frame.
            theta: Heading [rad]; default the current state's.

        Returns:
            ``(1/r) A_kin Rz(θ)ᵀ u_world``.
        """
        u = as_vector("HolonomicMobileRobot input u", u_world, 3)
        th = float(self.state[2]) if theta is None else float(theta)
        return self.A_kinematics @ self._world_to_body(u, th) / self.r

    def body_twist(self, wheel_speeds: ArrayLike) -> np.ndarray:
        """Least-squares body twist ``[v_bx, v_by, ω]`` ``(3,)`` of wheel speeds ``(n,)`` [rad/s].

        ``r A_pinv_kin ω_wheels``: the exact inverse of :meth:`wheel_speeds`
        (in the body frame) for any consistent set of wheel speeds.
        """
        return self.r * (self.A_pinv_kin @ as_vector("wheel_speeds", wheel_speeds, self.n))

    # ------------------------------------------------------------------ step
    def step(self, u_world: ArrayLike) -> np.ndarray:
        """Advance one step with the world-frame command held; return the wheel speeds.

        The command is rotated into the body frame with the heading before the
        step, mapped to wheel speeds, and the pose integrates ``x ← x + dt u``.

        With an engine attached the same happens, then ``engine.step()`` and
        :meth:`post_engine_step`: a simulation loop calls only ``plant.step(u)``
        for every plant, so the step itself must pin the MuJoCo chassis to the
        new pose and roll the wheels, or the engine's base would fall or drift
        away from the plant's pose. (Calling :meth:`post_engine_step` again
        afterwards is harmless: it re-pins the same pose and the wheel
        rotation is applied only once.)

        Args:
            u_world: ``[vx, vy, omega]`` ``(3,)`` [m/s, m/s, rad/s] in the world frame.

        Returns:
            Wheel speeds ``(n,)`` [rad/s].

        Raises:
            ValueError: ``u_world`` has the wrong shape.
            NonFiniteError: ``u_world`` holds NaN or inf.
        """
        u = self._input(u_world)
        with self._step_guard:  # one thread at a time (Plant's class docstring)
            return self._step(u)

    def _step(self, u: np.ndarray) -> np.ndarray:
        with np.errstate(over="ignore", invalid="ignore"):  # overflow is reported below, not warned about
            speeds = self.A_kinematics @ self._world_to_body(u, float(self._x[2])) / self.r
        if not np.isfinite(speeds).all():
            raise SimulationDiverged(
                f"HolonomicMobileRobot wheel speeds overflowed for the command {u} (wheel radius {self.r:g} m)"
            )
        pose = self._standalone  # the pose is the plant's own in both modes
        with np.errstate(over="ignore", invalid="ignore"):
            pose.apply(self, u)
            pose.step()
        self._x = pose.read(self)
        if self._engine is not None:
            self._pending_wheel_delta = speeds * self.dt
            self._engine.step()
            self.post_engine_step(self._engine)
        return speeds

    def set_pose(self, x: float, y: float, theta: float) -> None:
        """Set the pose ``[x, y, theta]`` [m, m, rad] (and pin the engine's base to it)."""
        self.set_state([x, y, theta])

    def get_state(self) -> np.ndarray:
        """The pose ``[x, y, theta]`` ``(3,)``; the plant's pose is the source of truth in both modes."""
        return self.state.copy()

    def set_state(self, x: ArrayLike) -> None:
        """Set the pose ``(3,)`` (and pin the engine's base to it)."""
        self.state = as_vector("HolonomicMobileRobot state", x, 3).copy()
        if self._engine is not None:
            self._pin(self._engine)

    def limit_violation(self) -> float:
        """0: the base has no state limits."""
        return 0.0

    # -------------------------------------------------------------- engine
    def physics_engine(self, engine: Engine | None) -> None:
        """Attach a physics engine (or detach with None).

        The plant keeps its pose (in its own standalone engine, :attr:`simulation`, in both
        modes) and the engine's base is pinned to it; every drive joint must exist in the
        engine's model (a ``KeyError`` from the engine lists the valid names otherwise).
        """
        self._pending_wheel_delta = None
        if engine is not None:
            for name in self.drive_joints:
                engine.get_joint_qpos(name)
            self._engine = engine
            self._pin(engine)
        else:
            self._engine = None

    def post_engine_step(self, engine: Engine) -> None:
        """Reconcile the engine's floating chassis with the plant's pose after ``engine.step()``.

        Writes ``(x, y, theta)`` into the free joint with the chassis upright
        and all six floating-base velocities zero (the chassis follows the
        kinematic model, not contact dynamics), then turns each drive joint by
        its pending wheel rotation ``speed · dt`` (consumed once per step).
        A no-op for a model without a free joint.

        Args:
            engine: The physics engine stepping the world.
        """
        if not engine.has_free_joint:
            return
        deltas, self._pending_wheel_delta = self._pending_wheel_delta, None
        if deltas is not None:
            for name, delta in zip(self.drive_joints, deltas.tolist(), strict=False):
                engine.set_joint_qpos(name, engine.get_joint_qpos(name) + delta)
        self._pin(engine)

    def _pin(self, engine: Engine) -> None:
        if engine.has_free_joint:
            x, y, theta = self._x.tolist()
            engine.pin_free_base(x, y, self.base_height, yaw=theta)

    @classmethod
    def from_config(
        cls,
        config: Mapping[str, object] | object,
        backend: ArrayBackend | None = None,
        *,
        engine: Engine | None = None,
        **extra: object,
    ) -> HolonomicMobileRobot:
        """:meth:`Plant.from_config`; without ``drive_joints``, a runtime ``joint_groups["drive_joints"]`` names them.

        (The seed's contract: the config may carry the model's joint groups and an engine.)
        """
        kwargs, runtime = split_config(config)
        groups = runtime.get("joint_groups") or {}
        if kwargs.get("drive_joints") is None and isinstance(groups, Mapping) and groups.get("drive_joints"):
            kwargs["drive_joints"] = list(groups["drive_joints"])
        return super().from_config(kwargs, engine=runtime.get("engine", engine), **extra)

    def mjcf_patch(self) -> MjcfPatch:
        """Step and, for the shipped 3-wheel asset, wheel placement and size.

        Wheel body ``wheel_link_i`` moves to ``(R cos a_i, R sin a_i, r)``; its
        cylinder ``wheel_geom_i`` gets radius ``r`` and lies along the radial
        axle ``(cos a_i, sin a_i, 0)``; the rim mark ``wheel_mark_i`` scales
        with ``r``. The hinge axes in the asset are those of ``gamma = 0``:
        for another ``gamma`` the visual rolling turns about a slightly wrong
        axis (the pose, which is what the engine mode is for, is unaffected).
        """
        body_pos: dict[str, tuple[float, float, float]] = {}
        geom_fromto: dict[str, tuple[float, ...]] = {}
        geom_size: dict[str, tuple[float, ...]] = {}
        if self.n == self.asset_wheels:
            half = 0.4 * self.r
            for i, a in enumerate(self.wheel_angles.tolist()):
                c, s = math.cos(a), math.sin(a)
                body_pos[f"wheel_link_{i}"] = (self.R * c, self.R * s, self.r)
                geom_fromto[f"wheel_geom_{i}"] = (-half * c, -half * s, 0.0, half * c, half * s, 0.0)
                geom_size[f"wheel_geom_{i}"] = (self.r,)
                geom_fromto[f"wheel_mark_{i}"] = (0.0, 0.0, 0.5 * self.r, 0.0, 0.0, 0.8 * self.r)
        return MjcfPatch(
            asset=self.asset,
            timestep=self.dt,
            body_pos=body_pos,
            geom_fromto=geom_fromto,
            geom_size=geom_size,
        )

    def engine_read(self, engine: Engine) -> np.ndarray:
        """The plant's own pose ``(3,)`` (the engine's base follows it)."""
        return self._x.copy()

    def engine_write(self, engine: Engine, x: np.ndarray) -> None:
        """Pin the engine's base to the plant's pose."""
        self._pin(engine)

    def engine_apply(self, engine: Engine, u: np.ndarray) -> None:
        """Nothing to actuate: the base is kinematic (see :meth:`step`)."""

    def __repr__(self) -> str:
        return (
            f"HolonomicMobileRobot(num_wheels={self.n}, radius_robots={self.R:g}, gamma={self.gamma:g}, "
            f"radius_wheels={self.r:g}, dt={self.dt:g})"
        )
