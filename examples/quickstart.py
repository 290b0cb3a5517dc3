"""Quick start: linearize the cart-pole two ways, design an LQR, balance it.

Run with ``python examples/quickstart.py`` (``make demo`` does).
"""

from __future__ import annotations

import numpy as np

from shinro_ctrl.controllers import LQR
from shinro_ctrl.linearization import compare
from shinro_ctrl.plants import CartPole

np.set_printoptions(precision=5, suppress=True)


def main() -> None:
    plant = CartPole(dt=0.01)

    # 1. Exact (CasADi) and finite-difference linearization at the upright equilibrium.
    cmp = compare(plant)
    print("A exact:\n", cmp.A_exact, "\nB exact:", cmp.B_exact.ravel())
    print("A finite differences:\n", cmp.A_fd, "\nB finite differences:", cmp.B_fd.ravel())
    print(f"max |exact - fd| = {cmp.max_abs_error:.2e}\n")

    # 2. Discrete LQR on the Euler-discretized model.
    lqr = LQR.from_plant(plant, Q=[10, 1, 100, 1], R=[0.1])
    print("LQR gain K =", lqr.K.ravel())
    print("closed-loop poles |λ| =", np.abs(lqr.poles))

    # 3. Standalone closed loop from a 0.2 rad tilt.
    x0 = np.array([0.0, 0.0, 0.2, 0.0])
    plant.set_state(x0)
    settled_at = None
    peak_force = 0.0
    for k in range(1, 601):
        u = lqr(plant.get_state())
        peak_force = max(peak_force, abs(float(u[0])))
        x = plant.step(u)
        if settled_at is None and abs(x[2]) < 0.01 and abs(x[0]) < 0.02:
            settled_at = k * plant.dt
        elif abs(x[2]) >= 0.01 or abs(x[0]) >= 0.02:
            settled_at = None
    print(f"\nfrom theta = 0.2 rad: final state {plant.get_state()}")
    print(f"settled (|theta| < 0.01 rad, |x| < 2 cm) at t = {settled_at} s, peak |F| = {peak_force:.2f} N")
    print(f"predicted LQR cost ½ x0ᵀ S x0 = {lqr.cost_to_go(x0):.4f}")


if __name__ == "__main__":
    main()
