"""MjcfPlant: speed of the exact dynamics and Jacobians, and agreement with MuJoCo.

Prints, for the shipped 7-DOF arm (``panda_like_arm.xml``):

* the time to read the file and build the CasADi expression;
* one evaluation of ``ẋ = f(x, u)``: through the compiled function's buffer
  (the floor), through ``plant.dynamics`` and MuJoCo's ``mj_forward``;
* one exact Jacobian ``(A_c, B_c)`` by ``plant.linearize`` (CasADi, compiled
  once) and, for scale, MuJoCo's ``mjd_transitionFD``;

and, for every shipped MjcfPlant model, the worst relative disagreement
``max |q̈ − qacc| / max(1, |qacc|)`` with MuJoCo's ``mj_forward`` over 1000
random states and inputs (joint limits and contacts off: they are not part
of the smooth dynamics).

With ``adam-robotics`` installed (``pip install "adam-robotics[casadi]"``; not a
dependency of shinro_ctrl) it also builds the same arm's dynamics with adam's
CasADi mass matrix and bias force, plus the armature, damping and gears adam
does not model, and compares exactness and speed.

Run: ``python benchmarks/mjcf_plant.py``.
"""

from __future__ import annotations

import time
from pathlib import Path

import casadi as cs
import mujoco
import numpy as np

from shinro_ctrl.plants import MjcfPlant
from shinro_ctrl.resources import asset_path

MODELS = ("panda_like_arm.xml", "furuta_pendulum.xml", "double_pendulum.xml")
ARM = "panda_like_arm.xml"


def median_us(fn, repeats: int = 7, number: int = 1000) -> float:
    samples = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        for _ in range(number):
            fn()
        samples.append((time.perf_counter() - t0) / number * 1e6)
    return float(np.median(samples))


def smooth_model(path: str | Path) -> mujoco.MjModel:
    m = mujoco.MjModel.from_xml_path(str(path))
    m.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_LIMIT) | int(mujoco.mjtDisableBit.mjDSBL_CONTACT)
    return m


def worst_agreement(f, m: mujoco.MjModel, samples: int = 1000, seed: int = 0) -> float:
    """Worst ``max|q̈ − qacc| / max(1, |qacc|)`` of ``f(x, u) -> q̈`` against ``mj_forward``."""
    d = mujoco.MjData(m)
    rng = np.random.default_rng(seed)
    worst = 0.0
    for _ in range(samples):
        q, v, u = rng.uniform(-2, 2, m.nq), rng.uniform(-3, 3, m.nv), rng.uniform(-1, 1, m.nu)
        d.qpos[:], d.qvel[:], d.ctrl[:] = q, v, u
        mujoco.mj_forward(m, d)
        worst = max(worst, float(np.abs(f(np.r_[q, v], u) - d.qacc).max() / max(1.0, np.abs(d.qacc).max())))
    return worst


def buffer_timer(fun: cs.Function, n: int, m: int):
    """A zero-allocation evaluation of ``fun(x, u)`` (outputs bound to owned arrays)."""
    x, u = np.full(n, 0.1), np.full(m, 0.1)
    outs = [np.zeros(fun.nnz_out(i)) for i in range(fun.n_out())]
    buf, ev = fun.buffer()
    buf.set_arg(0, memoryview(x))
    buf.set_arg(1, memoryview(u))
    for i, o in enumerate(outs):
        buf.set_res(i, memoryview(o))
    return ev, (x, u, outs, buf)  # keep the bound arrays alive with the evaluator


def jacobian_function(f: cs.Function, n: int, m: int) -> cs.Function:
    x, u = cs.SX.sym("x", n), cs.SX.sym("u", m)
    y = f(x, u)
    return cs.Function("J", [x, u], [cs.densify(cs.jacobian(y, x)), cs.densify(cs.jacobian(y, u))])


def adam_dynamics(m: mujoco.MjModel) -> cs.Function:
    """``f(x, u) -> ẋ`` for a fixed-base ``m`` from adam's mass matrix and bias force (joint block)."""
    from adam.casadi import KinDynComputations

    kd = KinDynComputations.from_mujoco_model(m)
    kd.g = np.r_[m.opt.gravity, 0.0, 0.0, 0.0]
    if kd.NDoF != m.nv:
        raise RuntimeError(f"adam sees {kd.NDoF} joints, the model has {m.nv}")
    n = m.nv
    q, v, u = cs.SX.sym("q", n), cs.SX.sym("v", n), cs.SX.sym("u", m.nu)
    H = cs.SX.eye(4)
    M = kd.mass_matrix(H, q)[6:, 6:]  # fixed base: the joint block, base at rest
    h = kd.bias_force(H, q, cs.SX.zeros(6), v)[6:]
    tau = cs.SX.zeros(n)
    for a in range(m.nu):
        tau[int(m.actuator_trnid[a, 0])] += float(m.actuator_gear[a, 0]) * u[a]
    qdd = cs.solve(M + cs.diag(m.dof_armature), tau - m.dof_damping * v - h)
    return cs.Function("f_adam", [cs.vertcat(q, v), u], [cs.vertcat(v, qdd)])


def with_world_fixed_base(path: Path) -> Path:
    """A copy of the arm whose first link hangs from a jointless base body (adam takes the root body as base)."""
    text = path.read_text()
    text = text.replace(
        '<body name="link1" pos="0 0 0.333">',
        '<body name="base"><inertial pos="0 0 0.05" mass="4" diaginertia="0.01 0.01 0.01"/>'
        '<body name="link1" pos="0 0 0.333">',
        1,
    ).replace("  </worldbody>", "  </body></worldbody>", 1)
    out = Path("/tmp") / "shinro_bench_panda_based.xml"
    out.write_text(text)
    return out


def main() -> None:
    path = asset_path(ARM)
    t0 = time.perf_counter()
    plant = MjcfPlant(path)
    t_build = time.perf_counter() - t0
    n, m = plant.state_dim, plant.input_dim
    f = plant.symbolic()
    J = jacobian_function(f, n, m)
    ev_f, keep_f = buffer_timer(f, n, m)
    ev_j, keep_j = buffer_timer(J, n, m)
    x, u = plant.equilibrium()
    x = x + 0.05
    mj = smooth_model(path)
    d = mujoco.MjData(mj)
    d.qpos[:], d.qvel[:], d.ctrl[:] = x[: mj.nq], x[mj.nq :], u
    A = np.zeros((2 * mj.nv, 2 * mj.nv))
    B = np.zeros((2 * mj.nv, mj.nu))

    print(
        f"{ARM}: n = {n} states, m = {m} inputs; SX: f {f.n_instructions()} instructions, Jacobian {J.n_instructions()}"
    )
    print(f"  read + build the expression (first MjcfPlant of this file): {t_build * 1e3:8.1f} ms")
    print(f"  dynamics  f(x, u), compiled function buffer:   {median_us(ev_f):8.1f} µs")
    print(f"  dynamics  plant.dynamics(x, u):                 {median_us(lambda: plant.dynamics(x, u)):8.1f} µs")
    print(f"  dynamics  MuJoCo mj_forward (reference):        {median_us(lambda: mujoco.mj_forward(mj, d)):8.1f} µs")
    print(f"  Jacobian  exact (A_c, B_c), buffer:             {median_us(ev_j):8.1f} µs")
    print(f"  Jacobian  exact plant.linearize(x, u):          {median_us(lambda: plant.linearize(x, u)):8.1f} µs")
    t_fd = median_us(lambda: mujoco.mjd_transitionFD(mj, d, 1e-6, True, A, B, None, None), number=200)
    print(f"  Jacobian  MuJoCo mjd_transitionFD (reference):  {t_fd:8.1f} µs")
    del keep_f, keep_j

    print("\nworst max|q̈ − qacc| / max(1, |qacc|) against MuJoCo mj_forward, 1000 random states and inputs:")
    for name in MODELS:
        p = MjcfPlant(name)
        nq = p.state_dim // 2
        worst = worst_agreement(lambda x, u, p=p, nq=nq: p.dynamics(x, u)[nq:], smooth_model(asset_path(name)))
        print(f"  {name:22s} {worst:9.2e}")

    try:
        import adam  # noqa: F401
    except ImportError:
        print("\nadam-robotics not installed: comparison skipped (pip install 'adam-robotics[casadi]')")
        return
    print("\nadam-robotics (CasADi backend) against shinro_ctrl.multibody on the same arm:")
    try:
        adam_dynamics(mujoco.MjModel.from_xml_path(str(path)))
        print("  the shipped asset: adam sees all 7 joints")
    except RuntimeError as exc:
        print(f"  the shipped asset: {exc} (adam takes the first body as its floating base and drops its joint)")
    based = with_world_fixed_base(path)
    mb = smooth_model(based)
    t0 = time.perf_counter()
    fa = adam_dynamics(mb)
    t_adam = time.perf_counter() - t0
    own = MjcfPlant(based)
    fo = own.symbolic()
    nv = mb.nv
    wa = worst_agreement(lambda x, u: np.asarray(fa(x, u)).ravel()[nv:], mb)
    wo = worst_agreement(lambda x, u: own.dynamics(x, u)[nv:], mb)
    Ja, Jo = jacobian_function(fa, n, m), jacobian_function(fo, n, m)
    ev = {k: buffer_timer(fun, n, m) for k, fun in (("fa", fa), ("fo", fo), ("Ja", Ja), ("Jo", Jo))}
    print("  arm with a jointless base body (so adam keeps joint1):")
    print(f"  {'':28s}{'adam':>12s}{'own':>12s}")
    print(f"  {'worst vs mj_forward (1000)':28s}{wa:12.2e}{wo:12.2e}")
    print(f"  {'SX instructions f':28s}{fa.n_instructions():12d}{fo.n_instructions():12d}")
    print(f"  {'SX instructions Jacobian':28s}{Ja.n_instructions():12d}{Jo.n_instructions():12d}")
    print(f"  {'f(x, u) µs (buffer)':28s}{median_us(ev['fa'][0]):12.1f}{median_us(ev['fo'][0]):12.1f}")
    print(f"  {'Jacobian µs (buffer)':28s}{median_us(ev['Ja'][0]):12.1f}{median_us(ev['Jo'][0]):12.1f}")
    print(f"  {'build ms':28s}{t_adam * 1e3:12.1f}{'(above)':>12s}")


if __name__ == "__main__":
    main()
