"""Grey-box identification of the cart-pole: speed, calibration of the 95 % intervals, estimation errors, and the
LQR designed on the identified model against the true model's regression baseline.

Data: the true cart-pole (cart 0.7 kg, pole 0.15 kg at 0.42 m, hinge damping 0.02 N m s/rad) in MuJoCo, held up
by an LQR designed on the *prior* model (CartPole() defaults: 0.5, 0.1, 0.5, 0), a seeded five-tone multisine
(±1.5 N per tone) added to the force, 100 Hz; the cart position and the pole angle measured with Gaussian noise.
The estimator knows the priors only.

1. Speed (goal: 4 parameters from 10 s at 100 Hz <= 1 s), median of ``--repeats`` runs, wall and CPU, beside a
   peer: scipy's ``least_squares`` (trust-region reflective, finite-difference Jacobian) on the same problem
   (the same shooting segments, parameters and segment starts as unknowns, residuals by simulating the segments).
2. Calibration: the true values inside the 95 % intervals over ``--seeds`` seeds (goal >= 90 %), the
   estimation errors (mean and spread of ``estimate - truth``, and of the z-scores ``error / std error``).
3. Regression: the scenario configs/regression/cartpole_lqr_mujoco.toml with the true parameters sets the
   baseline; the LQR designed on the identified model runs on the true plant; metrics compared with the
   scenario's tolerances, at two noise levels.

Run: ``python benchmarks/identification.py [--seeds 50] [--repeats 5]``.
"""

from __future__ import annotations

import argparse
import copy
import time

import numpy as np
from scipy.optimize import least_squares

from shinro_ctrl.config import load_scenario
from shinro_ctrl.controllers import LQR
from shinro_ctrl.engine import MujocoEngine
from shinro_ctrl.identification import experiment, identify
from shinro_ctrl.plants import CartPole
from shinro_ctrl.regression import compare_metrics
from shinro_ctrl.sim import RobotSim

TRUE = {"cart_mass": 0.7, "pole_mass": 0.15, "pole_length": 0.42, "damping": 0.02}
GOAL_S = 1.0
REGRESSION = "configs/regression/cartpole_lqr_mujoco.toml"


def mujoco_data(seed: int, duration: float = 10.0, noise: float = 2e-3):
    """(t, u, y (x, theta)) from the true cart-pole in MuJoCo under the prior model's LQR plus a multisine."""
    plant = CartPole(**TRUE)
    plant.physics_engine(MujocoEngine.for_plant(plant))
    ctrl = LQR.from_plant(CartPole(), Q=[10, 1, 100, 1], R=[0.1])
    rng = np.random.default_rng(seed)
    steps = round(duration / plant.dt)
    t = np.arange(steps + 1) * plant.dt
    freqs = np.array([0.3, 0.7, 1.3, 2.1, 3.4])
    phase = rng.uniform(0.0, 2 * np.pi, freqs.size)
    plant.set_state([0.0, 0.0, 0.05, 0.0])
    X, U = [plant.get_state()], []
    for k in range(steps):
        u = ctrl(X[-1], np.zeros(4)) + 1.5 * np.sin(2 * np.pi * freqs * t[k] + phase).sum()
        U.append(u)
        plant.step(u)
        X.append(plant.get_state())
    X, U = np.array(X), np.array(U).reshape(steps, 1)
    y = X[:, [0, 2]] + rng.normal(0.0, noise, (steps + 1, 2))
    return t, U, y


def ours(t, u, y):
    t0, c0 = time.perf_counter(), time.process_time()
    result = identify(CartPole(), experiment(t, u, y, ("x", "theta"), ("force",)), list(TRUE))
    return result, time.perf_counter() - t0, time.process_time() - c0


def peer(t, u, y, segment: int):
    """scipy least_squares on the same multiple-shooting-by-segments output-error problem (FD Jacobian)."""
    plant = CartPole()
    F = plant.symbolic_step()
    names = list(plant.dynamics_params())
    base = np.array(list(plant.dynamics_params().values()))
    idx = [names.index(k) for k in TRUE]
    N = len(t)
    starts = list(range(0, N - 1, segment))
    sims = {s: F.mapaccum(min(segment, N - 1 - s)) for s in starts}
    sd = np.std(y, axis=0)

    def residual(w):
        p = base.copy()
        p[idx] = w[:4]
        res = []
        for j, s in enumerate(starts):
            x0 = w[4 + 4 * j : 8 + 4 * j]
            L = min(segment, N - 1 - s)
            traj = np.asarray(sims[s](x0, u[s : s + L].T, p)).T
            pred = np.vstack([x0, traj])[:, [0, 2]]
            res.append(((y[s : s + L + 1] - pred) / sd).ravel())
        return np.concatenate(res)

    w0 = [*(CartPole().dynamics_params()[k] for k in TRUE)]
    for s in starts:
        w0 += [y[s, 0], 0.0, y[s, 1], 0.0]
    lo = np.r_[1e-6, 1e-6, 1e-6, 0.0, np.full(4 * len(starts), -np.inf)]  # masses, length > 0; damping >= 0
    t0, c0 = time.perf_counter(), time.process_time()
    sol = least_squares(residual, np.array(w0), bounds=(lo, np.inf), method="trf", x_scale="jac")
    return sol.x[:4], time.perf_counter() - t0, time.process_time() - c0, sol.nfev


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", type=int, default=50)
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args()

    print("1. speed: cart-pole, 4 parameters, 10 s at 100 Hz, x and theta measured (2 mm / 2 mrad noise)")
    t, u, y = mujoco_data(0)
    runs = [ours(t, u, y) for _ in range(args.repeats)]
    result = runs[0][0]
    wall, cpu = np.median([r[1] for r in runs]), np.median([r[2] for r in runs])
    print(f"   shinro identify : wall {wall:.3f} s, CPU {cpu:.3f} s (median of {args.repeats}; goal <= {GOAL_S} s)")
    print(f"     {result.iterations} IPOPT iterations, segments of {result.segment} samples")
    p_runs = [peer(t, u, y, result.segment) for _ in range(max(1, args.repeats // 2))]
    pw, pc = np.median([r[1] for r in p_runs]), np.median([r[2] for r in p_runs])
    pe = p_runs[0][0]
    print(f"   scipy least_squares (same problem, FD Jacobian): wall {pw:.3f} s, CPU {pc:.3f} s, {p_runs[0][3]} evals")
    print("   estimates (ours / scipy / truth):")
    for i, k in enumerate(TRUE):
        print(f"     {k:<12} {result.estimate[k]:.5f} / {pe[i]:.5f} / {TRUE[k]}")

    print(f"\n2. calibration over {args.seeds} seeds (10 s each)")
    inside, err, z, times = [], [], [], []
    for seed in range(args.seeds):
        t, u, y = mujoco_data(1000 + seed)
        r, _, c = ours(t, u, y)
        times.append(c)
        inside.append([r.interval[k][0] <= v <= r.interval[k][1] for k, v in TRUE.items()])
        err.append([r.estimate[k] - v for k, v in TRUE.items()])
        z.append([(r.estimate[k] - v) / r.std_error[k] for k, v in TRUE.items()])
    inside, err, z = np.array(inside), np.array(err), np.array(z)
    print(f"   true value inside the 95 % interval: {100 * inside.mean():.1f} % of {inside.size} (goal >= 90 %)")
    for i, k in enumerate(TRUE):
        print(
            f"     {k:<12} coverage {100 * inside[:, i].mean():5.1f} %   error mean {err[:, i].mean():+.2e} "
            f"sd {err[:, i].std():.2e} ({100 * err[:, i].std() / TRUE[k]:.2f} %)   z-score sd {z[:, i].std():.2f}"
        )
    print(f"   CPU per identification: median {np.median(times):.3f} s")

    print("\n3. LQR on the identified model vs the true model's baseline (the scenario's tolerances)")
    scenario = load_scenario(REGRESSION)
    truth_doc = copy.deepcopy(scenario.raw)
    truth_doc["plant"].update(TRUE)
    baseline = RobotSim.from_config(truth_doc).run().metrics
    for noise in (2e-3, 2e-4):
        t, u, y = mujoco_data(0, noise=noise)
        r, _, _ = ours(t, u, y)
        doc = copy.deepcopy(scenario.raw)
        doc["plant"].update(r.estimate)
        now = RobotSim.from_config(doc).with_plant(TRUE).run().metrics
        checks = compare_metrics("identified", now, baseline, scenario.regression)
        worst = max(
            (abs(c.now / c.baseline - 1) for c in checks if isinstance(c.baseline, float) and c.baseline),
            default=0.0,
        )
        failed = [c.metric for c in checks if not c.passed]
        print(
            f"   noise {noise:g}: {'meets' if not failed else 'misses'} the baseline "
            f"(largest relative metric difference {worst:.2e}{'; off: ' + ', '.join(failed) if failed else ''})"
        )
    prior_now = RobotSim.from_config(scenario.raw).with_plant(TRUE).run().metrics
    off = [c.metric for c in compare_metrics("prior", prior_now, baseline, scenario.regression) if not c.passed]
    print(f"   the prior model's LQR: off in {', '.join(off) or 'nothing'}")


if __name__ == "__main__":
    main()
