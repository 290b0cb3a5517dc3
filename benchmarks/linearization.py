"""Exact (CasADi, compiled once) vs central finite-difference linearization.

Prints, per plant, the median time of one linearization by each method and
their maximum disagreement. For the cart-pole it also checks the exact path
against the hand-derived closed form at the upright equilibrium.

Run: ``python benchmarks/linearization.py`` (``make bench`` runs all benchmarks).
"""

from __future__ import annotations

import time

import numpy as np

from shinro_ctrl.plants import PLANTS


def median_us(fn, repeats: int = 7, number: int = 2000) -> float:
    samples = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        for _ in range(number):
            fn()
        samples.append((time.perf_counter() - t0) / number * 1e6)
    return float(np.median(samples))


def operating_point(plant, rng):
    x0, u0 = plant.equilibrium()
    return x0 + 0.1 * rng.standard_normal(x0.shape), u0 + 0.1 * rng.standard_normal(u0.shape)


def main() -> None:
    rng = np.random.default_rng(0)
    print(f"{'plant':18s} {'n':>3s} {'exact µs':>9s} {'fd µs':>9s} {'speed-up':>9s} {'max|exact-fd|':>14s}")
    for name, cls in PLANTS.items():
        plant = cls()
        x0, u0 = operating_point(plant, rng)
        plant.linearize(x0, u0)  # compile once
        t_exact = median_us(lambda p=plant, x=x0, u=u0: p.linearize(x, u, method="exact"))
        t_fd = median_us(lambda p=plant, x=x0, u=u0: p.linearize(x, u, method="fd"), number=500)
        Ae, Be = plant.linearize(x0, u0)
        Af, Bf = plant.linearize(x0, u0, method="fd")
        err = max(np.abs(Ae - Af).max(), np.abs(Be - Bf).max())
        print(f"{name:18s} {plant.state_dim:3d} {t_exact:9.2f} {t_fd:9.2f} {t_fd / t_exact:8.1f}x {err:14.2e}")

    # Independent reference: the cart-pole closed form at the upright equilibrium.
    from shinro_ctrl.plants import CartPole

    M, m, l, g = 0.5, 0.1, 0.5, 9.81
    A, B = CartPole(cart_mass=M, pole_mass=m, pole_length=l, gravity=g).linearize()
    A_ref = np.array([[0, 1, 0, 0], [0, 0, -m * g / M, 0], [0, 0, 0, 1], [0, 0, (M + m) * g / (M * l), 0]])
    B_ref = np.array([[0], [1 / M], [0], [-1 / (M * l)]])
    Af, Bf = CartPole().linearize(method="fd")
    print(
        "cart-pole vs closed form: exact "
        f"{max(np.abs(A - A_ref).max(), np.abs(B - B_ref).max()):.1e}, "
        f"fd {max(np.abs(Af - A_ref).max(), np.abs(Bf - B_ref).max()):.1e}"
    )


if __name__ == "__main__":
    main()
