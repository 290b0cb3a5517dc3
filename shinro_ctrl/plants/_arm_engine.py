"""Engine mode of :class:`~shinro_ctrl.plants.armrobot.ArmRobot`: attaching MuJoCo, reading the end effector, engine IK.

A mixin of ``ArmRobot`` (it uses the arm's joints, limits and ``_engine``); the
engine is duck-typed, as everywhere in the plants.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from shinro_ctrl.kinematics import damped_least_squares, euler_zyx_to_matrix, so3_log
from shinro_ctrl.validation import as_vector

__all__ = ["ARM6_SITE", "ArmEngineMode"]

ARM6_SITE = "ee_site"


class ArmEngineMode:
    """``physics_engine``, ``engine_ik`` and the engine reads of an arm (see :class:`ArmRobot`)."""

    joint_names: tuple[str, ...]
    ee_body_name: str | None
    _engine: Any
    _lo: np.ndarray
    _hi: np.ndarray

    def engine_ik(
        self,
        target_ee: Any,
        target_euler: Any = None,
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

    def physics_engine(self, engine: Any) -> None:
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
        self._ee_frame = frame
        self._dofs = dofs
        engine.forward()
        self._engine_ee()  # KeyError for an unknown ee_body_name
        self._q = self._read_joints()
        self._q_cmd = self._q.copy()
        self.state = self._engine_pose()

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
