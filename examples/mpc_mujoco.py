"""Constrained MPC in MuJoCo: keep the cart-pole up with |F| <= 3 N and |x| <= 0.6 m.

The MPC is designed on the exact linearization; the closed loop runs on the
matched MuJoCo model. Every input stays inside its bound and the cart comes
close to, but never past, the end of its track.

Run: ``python examples/mpc_mujoco.py``
"""

from __future__ import annotations

import numpy as np

from shinro_ctrl.controllers import LinearMPC
from shinro_ctrl.engine import MujocoEngine
from shinro_ctrl.plants import CartPole


def main() -> None:
    plant = CartPole(dt=0.02)
    mpc = LinearMPC.from_plant(
        plant,
        Q=[10, 1, 100, 1],
        R=[0.1],
        horizon=50,
        u_min=[-3.0],
        u_max=[3.0],
        x_min=[-0.6, -np.inf, -np.inf, -np.inf],
        x_max=[0.6, np.inf, np.inf, np.inf],
    )
    print(mpc.describe().splitlines()[1])

    plant.physics_engine(MujocoEngine.for_plant(plant))
    plant.set_state([0.0, 0.0, 0.3, 0.0])
    peak_x, peak_u, times = 0.0, 0.0, []
    for _ in range(250):
        u = mpc(plant.get_state())
        times.append(mpc.last.call_time_s)
        peak_u = max(peak_u, abs(float(u[0])))
        x = plant.step(u)
        peak_x = max(peak_x, abs(float(x[0])))
    print(f"after 5 s in MuJoCo: state {np.round(plant.get_state(), 4)}")
    print(f"peak |F| = {peak_u:.3f} N (bound 3), peak |x| = {peak_x:.3f} m (bound 0.6)")
    print(f"median MPC call {1e3 * np.median(times):.3f} ms, last solve: {mpc.last.status}, {mpc.last.iterations} it")


if __name__ == "__main__":
    main()
