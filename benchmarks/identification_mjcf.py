"""Model-file identification of a 7-DOF arm (assets/panda_like_arm.xml): speed, accuracy, and a peer.

Data (not timed): the true arm is the file with every link's mass scaled by a seeded factor in [0.85, 1.15] and
its centre of mass moved by up to 1 cm; MuJoCo runs it for ``--seconds`` (20) at its 500 Hz, the joints driven
around the "home" pose by a PD on a seeded multisine reference (one per joint, 0.2-2 Hz, 0.15 rad) with gravity
and Coriolis feed-forward (MuJoCo's ``qfrc_bias``) and a PRBS on every motor (``shinro_ctrl.sim.excitation``);
Gaussian noise on the measured positions (1e-4 rad) and velocities (1e-3 rad/s). The joints stay inside their
ranges (no limit forces; checked).

Timed: :func:`shinro_ctrl.identification.mjcf.identify_model_file` of the seven links' 70 inertial parameters
(``body:link1`` … ``body:link7``), median of ``--repeats`` runs after one that builds the regressor (goal: <= 3 s).
Peer, if importable: Pinocchio's ``computeJointTorqueRegressor`` on the same filtered samples (q, q̇, q̈ from our
filter) and ``numpy.linalg.lstsq`` — ordinary least squares only (no consistency, no uncertainty).

Run: ``python benchmarks/identification_mjcf.py [--seconds 20] [--repeats 3]``.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import mujoco
import numpy as np

from shinro_ctrl.identification import Experiment
from shinro_ctrl.identification.mjcf import identify_model_file, lowpass_kernel, regressor_data
from shinro_ctrl.identification.regressor import InertialRegressor, parse_param_names
from shinro_ctrl.plants import MjcfPlant
from shinro_ctrl.resources import asset_path
from shinro_ctrl.sim.excitation import multisine_signal, prbs_signal

GOAL_S = 3.0
LINKS = [f"link{i}" for i in range(1, 8)]


def make_data(seconds: float, seed: int = 0) -> tuple[Experiment, dict[str, float], MjcfPlant, str]:
    path = str(asset_path("panda_like_arm.xml"))
    plant = MjcfPlant(model=path)
    spec = mujoco.MjSpec.from_file(path)
    rng = np.random.default_rng(seed)
    truth = {}
    for name in LINKS:
        b = spec.body(name)
        b.mass = b.mass * rng.uniform(0.85, 1.15)
        b.ipos = np.asarray(b.ipos) + rng.uniform(-0.01, 0.01, 3)
        truth[f"{name}.mass"] = float(b.mass)
        for axis, v in zip("xyz", b.ipos, strict=True):
            truth[f"{name}.com_{axis}"] = float(v)
    m = spec.compile()
    truth_xml = spec.to_xml()
    d = mujoco.MjData(m)
    mujoco.mj_resetDataKeyframe(m, d, 0)
    dt = m.opt.timestep
    N = round(seconds / dt)
    q0 = d.qpos.copy()
    ref = np.stack([0.15 * multisine_signal(1.0, (0.2, 2.0), dt, N, seed=j) for j in range(7)], axis=1) + q0
    gear = m.actuator_gear[:, 0]
    prbs = np.stack([prbs_signal(0.05 if j < 4 else 0.02, (0.2, 20.0), dt, N, seed=j) for j in range(7)], axis=1)
    kp, kd = np.r_[[400.0] * 4, [100.0] * 3], np.r_[[40.0] * 4, [10.0] * 3]
    U = np.empty((N, 7))
    Y = np.empty((N + 1, 14))
    Y[0] = np.r_[d.qpos, d.qvel]
    for k in range(N):
        tau = kp * (ref[k] - d.qpos) - kd * d.qvel + d.qfrc_bias
        U[k] = tau / gear + prbs[k]
        d.ctrl[:] = U[k]
        mujoco.mj_step(m, d)
        if d.nefc:
            raise RuntimeError(f"a joint reached its limit at t = {k * dt:.3f} s")
        Y[k + 1] = np.r_[d.qpos, d.qvel]
    Y += rng.normal(size=Y.shape) * np.r_[[1e-4] * 7, [1e-3] * 7]
    exp = Experiment(
        t=np.arange(N + 1) * dt, u=U, y=Y, outputs=tuple(plant.state_names), inputs=tuple(plant.input_names)
    )
    return exp, truth, plant, truth_xml


def pinocchio_peer(exp: Experiment, cutoff: float, plant: MjcfPlant) -> tuple[float, float, float] | None:
    """Seconds for Pinocchio's regressor over the same filtered samples and an OLS solve of the joint torques
    ``gear u − b q̇ − a q̈`` (the file's gears, dampings, armatures): (wall, CPU, relative torque residual of the
    solve); None: Pinocchio not installed."""
    try:
        import pinocchio as pin
    except ImportError:
        return None
    spec = mujoco.MjSpec.from_file(str(asset_path("panda_like_arm.xml")))
    for body in spec.bodies:  # Pinocchio's MJCF reader takes quaternions as written; MuJoCo normalizes them
        q = np.asarray(body.quat, dtype=float)
        body.quat = q / np.linalg.norm(q)
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "panda_like_arm.xml"
        path.write_text(spec.to_xml())
        model = pin.buildModelFromMJCF(str(path))
    data = model.createData()
    fs = 1.0 / exp.dt
    h = lowpass_kernel(fs, cutoff)
    q = np.stack([np.convolve(c, h, mode="same") for c in exp.y[:, :7].T], axis=1)
    qd = np.stack([np.convolve(c, h, mode="same") for c in exp.y[:, 7:].T], axis=1)
    qdd = np.gradient(qd, exp.dt, axis=0)
    u = np.vstack([exp.u[:1], 0.5 * (exp.u[:-1] + exp.u[1:]), exp.u[-1:]])
    u = np.stack([np.convolve(c, h, mode="same") for c in u.T], axis=1)
    joints = plant.tree.joints
    gear = np.array([a.gear for a in plant.tree.actuators])
    tau = gear * u - np.array([j.damping for j in joints]) * qd - np.array([j.armature for j in joints]) * qdd
    cut = h.shape[0] // 2 + 1
    t0, c0 = time.perf_counter(), time.process_time()
    rows = [pin.computeJointTorqueRegressor(model, data, q[k], qd[k], qdd[k]) for k in range(cut, q.shape[0] - cut)]
    A = np.concatenate(rows)
    b = tau[cut : q.shape[0] - cut].reshape(-1)
    sol = np.linalg.lstsq(A, b, rcond=None)[0]
    elapsed, cpu = time.perf_counter() - t0, time.process_time() - c0
    return elapsed, cpu, float(np.linalg.norm(A @ sol - b) / np.linalg.norm(b))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=20.0)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--cutoff", type=float, default=25.0)
    args = ap.parse_args()
    exp, truth, plant, truth_xml = make_data(args.seconds)
    params = [f"body:{b}" for b in LINKS]
    t0 = time.perf_counter()
    r = identify_model_file(plant, exp, params, cutoff=args.cutoff)
    first = time.perf_counter() - t0
    walls, cpus = [], []
    for _ in range(args.repeats):
        t0, c0 = time.perf_counter(), time.process_time()
        r = identify_model_file(plant, exp, params, cutoff=args.cutoff)
        walls.append(time.perf_counter() - t0)
        cpus.append(time.process_time() - c0)
    res = r.result
    print(f"7-DOF arm, {len(params) * 10} inertial parameters, {exp.samples} samples at {1 / exp.dt:g} Hz")
    print(
        f"identify_model_file: first run {first:.2f} s (regressor built), then median wall "
        f"{np.median(walls):.2f} s, CPU {np.median(cpus):.2f} s over {args.repeats} runs (goal <= {GOAL_S} s)"
    )
    print(
        f"physically consistent: {r.consistent()} (barrier needed: {r.constrained}); "
        f"determined directions of π: {r.rank} of {len(r.pi)}; "
        f"reported parameters individually determined: {len(res.params) - len(res.held)} of {len(res.params)}"
    )
    # the torques the identified, prior and true inertials predict on the data (independent: the true file's π)
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "truth.xml"
        path.write_text(truth_xml)
        spec = parse_param_names(params, [b.name for b in plant.tree.bodies], [j.name for j in plant.tree.joints])
        pi_true = InertialRegressor(MjcfPlant(model=str(path)), spec).pi_prior
    Y, yy, _, _ = regressor_data(plant, exp, InertialRegressor(plant, spec), cutoff=args.cutoff)
    ours = float(np.linalg.norm(Y @ r.pi - yy) / np.linalg.norm(yy))
    tau = Y @ pi_true
    for label, pi in (("prior (the file)", r.pi_prior), ("identified", r.pi)):
        err = np.sqrt(np.mean((Y @ pi - tau) ** 2, axis=0)) / np.sqrt(np.mean(tau**2, axis=0))
        print(
            f"inertial torques of the {label} vs the truth, relative RMS per joint: "
            + " ".join(f"{100 * e:.2f}%" for e in err)
        )
    inside = [k for k in truth if k in res.params and k not in res.held]
    cover = sum(res.interval[k][0] <= truth[k] <= res.interval[k][1] for k in inside)
    print(f"true masses/COMs among the determined parameters: {cover} of {len(inside)} inside their 95 % intervals")
    for k in inside[:8]:
        print(f"  {k:14s} true {truth[k]:+.5f}  est {res.estimate[k]:+.5f} ± {1.96 * res.std_error[k]:.5f}")
    peer = pinocchio_peer(exp, args.cutoff, plant)
    if peer is None:
        print("peer: pinocchio not installed")
    else:
        print(
            f"peer: pinocchio computeJointTorqueRegressor + lstsq (OLS, unconstrained) on the same samples: "
            f"{peer[0]:.2f} s wall, {peer[1]:.2f} s CPU; relative torque residual {100 * peer[2]:.2f} % "
            f"(ours, consistent, undetermined directions at the prior: {100 * ours:.2f} %)"
        )


if __name__ == "__main__":
    main()
