"""Per-step cost of each estimator's ``update(y, u)`` (µs, median of repeats).

For the inverted pendulum (n = 2, angle measured), the cart-pole (n = 4, x and
θ measured) and the quadrotor (n = 12, position and yaw measured): the
steady-state and time-varying Kalman filters, the Kalman filter augmented
with an input disturbance, the Luenberger observer and the EKF (one RK4
step, its exact Jacobians, gain and Joseph covariance in one CasADi buffer
call). ``FullState`` (the identity) is the floor.

Run: ``python benchmarks/estimators.py``.
"""

from __future__ import annotations

import time

import numpy as np

from shinro_ctrl.estimators import FullState
from shinro_ctrl.estimators.kalman import ExtendedKalmanFilter, KalmanFilter
from shinro_ctrl.estimators.luenberger import Luenberger
from shinro_ctrl.plants import CartPole, InvertedPendulum, Quadrotor


def median_us(fn, repeats: int = 7, number: int = 3000) -> float:
    samples = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        for _ in range(number):
            fn()
        samples.append((time.perf_counter() - t0) / number * 1e6)
    return float(np.median(samples))


CASES = [
    (InvertedPendulum(), ["theta"]),
    (CartPole(), ["x", "theta"]),
    (Quadrotor(), ["x", "y", "z", "yaw"]),
]


def estimators(plant, measured):
    m, p, n = plant.input_dim, len(measured), plant.state_dim
    Qn, Rn = np.full(m, 1e-2), np.full(p, 1e-4)
    poles = np.linspace(0.6, 0.8, n)
    yield "FullState", FullState(n), n
    yield "KalmanFilter (steady)", KalmanFilter.from_plant(plant, measured=measured, Qn=Qn, Rn=Rn), p
    yield (
        "KalmanFilter (time-varying)",
        KalmanFilter.from_plant(plant, measured=measured, Qn=Qn, Rn=Rn, steady_state=False),
        p,
    )
    yield (
        "KalmanFilter (+ input dist.)",
        KalmanFilter.from_plant(plant, measured=measured, Qn=Qn, Rn=Rn, disturbance_model="input"),
        p,
    )
    try:
        yield "Luenberger", Luenberger.from_plant(plant, measured=measured, poles=poles), p
    except ValueError as exc:  # repeated poles beyond the measurement count
        print(f"  (Luenberger skipped: {exc})")
    yield "ExtendedKalmanFilter", ExtendedKalmanFilter.from_plant(plant, measured=measured, Qn=Qn, Rn=Rn), p


def main() -> None:
    rng = np.random.default_rng(0)
    print(f"{'plant':18s} {'n':>3s} {'p':>3s} {'estimator':30s} {'update µs':>10s}")
    for plant, measured in CASES:
        x0, u0 = plant.equilibrium()
        for name, est, p in estimators(plant, measured):
            est.reset(x0)
            y = x0[list(est.measured)] + 1e-3 * rng.standard_normal(p) if p < plant.state_dim else x0.copy()
            u = u0 + 1e-3 * rng.standard_normal(plant.input_dim)
            est.update(y, u)
            t = median_us(lambda est=est, y=y, u=u: est.update(y, u))
            print(f"{type(plant).__name__:18s} {plant.state_dim:3d} {p:3d} {name:30s} {t:10.2f}")


if __name__ == "__main__":
    main()
