"""Quadrotor hover: LQR on the exact linearization, recovered in both loops.

The 12-state rigid-body model is linearized at hover by CasADi, an LQR is
designed on it, and the same gain recovers hover from a 0.5 m / 0.3 rad offset
in the plant's own integration and in MuJoCo.

Run: ``python examples/quadrotor_hover.py``
"""

from __future__ import annotations

import numpy as np

from shinro_ctrl.controllers import LQR
from shinro_ctrl.engine import MujocoEngine
from shinro_ctrl.plants import Quadrotor

np.set_printoptions(precision=3, suppress=True)


def fly(plant: Quadrotor, lqr: LQR, x_init: np.ndarray, seconds: float) -> np.ndarray:
    plant.set_state(x_init)
    for _ in range(round(seconds / plant.dt)):
        plant.step(lqr(plant.get_state()))
    return plant.get_state()


def main() -> None:
    plant = Quadrotor(mass=0.5, inertia=(3e-3, 3e-3, 5e-3), dt=0.01)
    print("hover input [thrust, tau_x, tau_y, tau_z] =", plant.hover_input())
    lqr = LQR.from_plant(plant, Q=[10, 10, 10, 2, 2, 2, 1, 1, 1, 0.1, 0.1, 0.1], R=[1, 10, 10, 10])
    print("slowest closed-loop pole |λ| =", np.abs(lqr.poles).max().round(4))

    x_init = np.array([0.5, -0.5, 0.5, 0.3, -0.3, 0.3, 0, 0, 0, 0, 0, 0])
    print("\nstandalone after 5 s:", fly(plant, lqr, x_init, 5.0)[:6])

    engine = MujocoEngine.for_plant(plant)
    plant.physics_engine(engine)
    print("MuJoCo     after 5 s:", fly(plant, lqr, x_init, 5.0)[:6])


if __name__ == "__main__":
    main()
