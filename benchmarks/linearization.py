"""Exact (CasADi, compiled once) vs central finite-difference linearization.

Prints, per plant, the median time of one linearization by each method and
their maximum disagreement. For the cart-pole it also checks the exact path
against the hand-derived closed form at the upright equilibrium. For the
12-state quadrotor it measures both methods against a complex-step reference
(exact to rounding) at random states.

Run: ``python benchmarks/linearization.py`` (``make bench`` runs all benchmarks).
"""

from __future__ import annotations

import time

import numpy as np

from shinro_ctrl.backend import NumpyBackend
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
    print(f"{'plant':20s} {'n':>3s} {'exact µs':>9s} {'fd µs':>9s} {'speed-up':>9s} {'max|exact-fd|':>14s}")
    for name, cls in PLANTS.items():
        plant = cls()
        x0, u0 = operating_point(plant, rng)
        plant.linearize(x0, u0)  # compile once
        t_exact = median_us(lambda p=plant, x=x0, u=u0: p.linearize(x, u, method="exact"))
        t_fd = median_us(lambda p=plant, x=x0, u=u0: p.linearize(x, u, method="fd"), number=500)
        Ae, Be = plant.linearize(x0, u0)
        Af, Bf = plant.linearize(x0, u0, method="fd")
        err = max(np.abs(Ae - Af).max(), np.abs(Be - Bf).max())
        print(f"{name:20s} {plant.state_dim:3d} {t_exact:9.2f} {t_fd:9.2f} {t_fd / t_exact:8.1f}x {err:14.2e}")

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
    quadrotor_vs_complex_step(rng)


class _ComplexBackend(NumpyBackend):
    """NumpyBackend that keeps complex numbers (for complex-step differentiation)."""

    def unpack(self, v, n):
        v = np.asarray(v)
        return tuple(v[..., i] for i in range(n))

    def stack(self, items):
        return np.stack(np.broadcast_arrays(*[np.asarray(i) for i in items]), axis=-1)


def complex_step(plant, x0, u0, h: float = 1e-30):
    """``[A_c, B_c]`` by complex step on the plant's one dynamics definition (no cancellation)."""
    n, m = plant.state_dim, plant.input_dim
    Z = np.repeat(np.concatenate([x0, u0])[None, :].astype(complex), n + m, axis=0)
    Z[np.arange(n + m), np.arange(n + m)] += 1j * h
    F = plant.equations(_ComplexBackend(), Z[:, :n], Z[:, n:], plant.dynamics_params())
    return (F.imag / h).T


def quadrotor_vs_complex_step(rng) -> None:
    from shinro_ctrl.plants import Quadrotor

    plant = Quadrotor()
    err_exact, err_fd, abs_exact, abs_fd = 0.0, 0.0, 0.0, 0.0
    for _ in range(20):
        x0 = np.concatenate([rng.uniform(-2, 2, 3), rng.uniform(-1.2, 1.2, 3), rng.normal(size=6)])
        u0 = plant.hover_input() + 0.1 * rng.standard_normal(4)
        J_ref = complex_step(plant, x0, u0)
        scale = np.abs(J_ref).max()
        d_exact = np.abs(np.hstack(plant.linearize(x0, u0)) - J_ref).max()
        d_fd = np.abs(np.hstack(plant.linearize(x0, u0, method="fd")) - J_ref).max()
        abs_exact, abs_fd = max(abs_exact, d_exact), max(abs_fd, d_fd)
        err_exact, err_fd = max(err_exact, d_exact / scale), max(err_fd, d_fd / scale)
    t_exact = median_us(lambda: plant.linearize(x0, u0, method="exact"))
    t_fd = median_us(lambda: plant.linearize(x0, u0, method="fd"), number=500)
    print("quadrotor (12 states, 20 random states) against a complex-step reference:")
    print(f"  max |err|:           exact {abs_exact:.1e}, fd {abs_fd:.1e}")
    print(f"  max |err| / max |J|: exact {err_exact:.1e}, fd {err_fd:.1e}")
    print(f"  time: exact {t_exact:.1f} µs, fd {t_fd:.1f} µs ({t_fd / t_exact:.1f}x)")


if __name__ == "__main__":
    main()
