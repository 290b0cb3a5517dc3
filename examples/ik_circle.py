"""IK-QP: the 6-DOF arm draws a 10 cm circle, holding its orientation, in MuJoCo.

Each control step solves one differential-IK QP (OSQP, set up once and
updated in place) for joint targets that respect joint limits and velocity
limits; MuJoCo's position servos follow them. The error is the servo lag.

Run: ``python examples/ik_circle.py``
"""

from __future__ import annotations

import numpy as np

from shinro_ctrl.controllers import IKQP
from shinro_ctrl.engine import MujocoEngine
from shinro_ctrl.plants import ArmRobot
from shinro_ctrl.sim import Reference


def main() -> None:
    arm = ArmRobot()  # the shipped UR5-like arm, home pose q = 0
    T_home, _, _ = arm.forward_kinematics(np.zeros(arm.num_dof))
    print("home end-effector position:", np.round(T_home[:3, 3], 4))
    print("Jacobian condition number at home:", round(float(np.linalg.cond(arm.jacobian(np.zeros(6)))), 2))

    arm.physics_engine(MujocoEngine.for_plant(arm))
    ik = IKQP.from_plant(arm, velocity_limit=np.pi, damping=1e-4)
    circle = Reference({"kind": "circle", "radius": 0.1, "frequency": 0.5, "axes": [1, 2]}, arm.get_state())

    errors, lo, hi = [], arm.joint_limits[:, 0], arm.joint_limits[:, 1]
    for k in range(round(4.0 / arm.dt)):
        t = k * arm.dt
        twist = ik(arm.get_state(), np.array([circle(t), circle(t + arm.dt)]))
        q = arm.step(twist)
        assert np.all(q >= lo) and np.all(q <= hi)
        errors.append(np.linalg.norm(arm.get_state()[:3] - circle(t + arm.dt)[:3]))
    errors = np.array(errors)
    print(
        f"4 s of a 0.1 m / 0.5 Hz circle: RMS error {1e3 * np.sqrt(np.mean(errors**2)):.2f} mm, "
        f"max {1e3 * errors.max():.2f} mm, joint limits respected"
    )


if __name__ == "__main__":
    main()
