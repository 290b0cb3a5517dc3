"""Exact robot dynamics compiled: MjcfPlant's f and (A, B) beside MuJoCo and Pinocchio, in one run.

For a 7-DOF arm (``panda_like_arm.xml``), a 6-DOF arm (``arm6.xml``, its per-body gravity compensation set to 0 when
MjcfPlant does not model it) and a 2-DOF pendulum (``double_pendulum.xml``), prints:

* ``f``: ``ẋ = f(x, u)`` through the compiled function's buffer (the floor), through ``plant.dynamics`` (the public
  call: validation and a copy), and MuJoCo's ``mj_forward``;
* ``(A, B)``: the exact continuous Jacobians through the compiled buffer and through ``plant.linearize``; CasADi's VM
  on ``cs.jacobian`` of the same ``f`` (the path before compilation); MuJoCo's finite-difference
  ``mjd_transitionFD`` (centred and forward; discrete-time, for scale) and Pinocchio's analytical
  ``computeABADerivatives`` (and its ``aba``), after checking that Pinocchio's accelerations and derivatives agree
  with ours (Pinocchio's ``aba`` holds the applied torque fixed: our Jacobians add ``M̃⁻¹ ∂τ/∂(q, q̇, u)``);
* the first build including compilation and a cached load, each in a fresh process (construct the plant, then one
  ``linearize``; imports excluded), wall and CPU time (CPU includes the compiler's child processes).

Timings: per call, median of 2,000 calls after 200 warm-up calls, repeated 3 times, the minimum of the medians (the
machine is shared and noisy; the median discards preemptions). Needs ``pin`` (the ``bench`` extra).

Run: ``python benchmarks/compiled_dynamics.py``.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import textwrap
from pathlib import Path

import casadi as cs
import mujoco
import numpy as np
import pinocchio as pin
from _timing import CALLS, REPEATS, WARMUP, per_call_us  # benchmarks/_timing.py

from shinro_ctrl.codegen import default_flags
from shinro_ctrl.linearization import ExactJacobian
from shinro_ctrl.plants import MjcfPlant
from shinro_ctrl.resources import asset_path


def median_us(fn) -> float:
    """The median per-call time [µs] (:func:`_timing.per_call_us`: min over REPEATS of the median of CALLS calls)."""
    return per_call_us(fn)[0]


def model_path(name: str, folder: Path) -> str:
    """The shipped model; for arm6, a copy without gravcomp when MjcfPlant refuses it."""
    path = asset_path(name)
    if name != "arm6.xml":
        return str(path)
    try:
        MjcfPlant(path)
        return str(path)
    except Exception:
        out = folder / "arm6_no_gravcomp.xml"
        out.write_text(path.read_text().replace('gravcomp="1"', 'gravcomp="0"'))
        return str(out)


BUILD = textwrap.dedent(
    """
    import json, resource, sys, time
    from shinro_ctrl.plants import MjcfPlant
    import shinro_ctrl.engine.model_tree  # imports (MuJoCo, CasADi) excluded from the timing
    def cpu():
        s, c = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
        return s.ru_utime + s.ru_stime + c.ru_utime + c.ru_stime
    t0, c0 = time.perf_counter(), cpu()
    plant = MjcfPlant(sys.argv[1])
    plant.linearize()
    print(json.dumps({"wall": time.perf_counter() - t0, "cpu": cpu() - c0}))
    """
)


def build_times(path: str) -> tuple[dict, dict]:
    """First build (empty cache) and cached load, each in a fresh process."""
    with tempfile.TemporaryDirectory() as cache:
        env = {**os.environ, "SHINRO_CTRL_CACHE": cache, "PYTHONPATH": os.pathsep.join(sys.path)}
        out = []
        for _ in range(2):
            proc = subprocess.run([sys.executable, "-c", BUILD, path], env=env, capture_output=True, text=True)
            if proc.returncode:
                raise RuntimeError(proc.stderr)
            out.append(json.loads(proc.stdout.strip().splitlines()[-1]))
        return out[0], out[1]


def check_pinocchio(plant: MjcfPlant, model: pin.Model, data: pin.Data, x: np.ndarray, u: np.ndarray) -> float:
    """Worst relative disagreement of Pinocchio's aba and computeABADerivatives with our f and (A, B)."""
    n = plant.state_dim // 2
    rb, act = plant.rigid_body_tree, plant.active_actuators
    q, v = x[:n], x[n:]
    tau = np.array(rb.generalized_forces(list(q), list(v), list(u), act), dtype=float)
    h = 1e-30  # ∂τ/∂(q, v, u) by complex step of the applied forces
    z = np.r_[x, u]
    dtau = np.column_stack(
        [
            np.array(
                rb.generalized_forces(list(zc[:n]), list(zc[n : 2 * n]), list(zc[2 * n :]), act), dtype=complex
            ).imag
            / h
            for zc in (z + 1j * h * e for e in np.eye(z.size))
        ]
    )
    pin.computeABADerivatives(model, data, q, v, tau)
    minv = np.triu(data.Minv) + np.triu(data.Minv, 1).T
    bottom = np.hstack([data.ddq_dq, data.ddq_dv, np.zeros((n, u.size))]) + minv @ dtau
    A, B = plant.linearize(x, u)
    ours = np.hstack([A[n:], B[n:]])
    qdd_pin = pin.aba(model, data, q, v, tau)
    err_f = np.abs(qdd_pin - plant.dynamics(x, u)[n:]).max() / max(1.0, np.abs(qdd_pin).max())
    err_j = np.abs(ours - bottom).max() / max(1.0, np.abs(bottom).max())
    return float(max(err_f, err_j))


def bench_model(name: str, folder: Path) -> dict:
    path = model_path(name, folder)
    first, cached = build_times(path)
    plant = MjcfPlant(path)
    n, m = plant.state_dim, plant.input_dim
    x0, u0 = plant.equilibrium()
    rng = np.random.default_rng(0)
    x = x0 + np.r_[rng.uniform(-0.3, 0.3, n // 2), rng.uniform(-0.5, 0.5, n // 2)]
    u = u0 + rng.uniform(-0.05, 0.05, m)
    plant.linearize(x, u)  # build and load before timing

    # MuJoCo on the same file (the file's own options; contacts are off in these models)
    mm = mujoco.MjModel.from_xml_path(plant.model_path)
    md = mujoco.MjData(mm)
    md.qpos[:], md.qvel[:] = x[: n // 2], x[n // 2 :]
    md.ctrl[list(plant.active_actuators)] = u
    mujoco.mj_forward(mm, md)
    Ad, Bd = np.zeros((n, n)), np.zeros((n, mm.nu))

    # Pinocchio on the same MJCF
    pm = pin.buildModelFromMJCF(plant.model_path)
    pd = pm.createData()
    agree = check_pinocchio(plant, pm, pd, x, u)
    q, v = x[: n // 2].copy(), x[n // 2 :].copy()
    tau = np.array(plant.rigid_body_tree.generalized_forces(list(q), list(v), list(u), plant.active_actuators))

    # the compiled functions' own buffers: the floor below plant.dynamics / plant.linearize
    f_sym = plant.symbolic()
    lib_f, lib_j = plant.compiled_functions()
    assert lib_f.is_a("External") and lib_j.is_a("External"), "not compiled: is a C compiler installed?"
    xb, ub, yb = x.copy(), np.zeros(lib_f.size1_in(1)), np.zeros(n)
    ub[list(plant.active_actuators)] = u
    fb, f_run = lib_f.buffer()
    fb.set_arg(0, memoryview(xb))
    fb.set_arg(1, memoryview(ub))
    fb.set_res(0, memoryview(yb))
    fs = np.zeros(1)
    fb.set_res(1, memoryview(fs))
    Ab, Bb = np.zeros(n * n), np.zeros(n * ub.size)
    jb, j_run = lib_j.buffer()
    jb.set_arg(0, memoryview(xb))
    jb.set_arg(1, memoryview(ub))
    jb.set_res(0, memoryview(Ab))
    jb.set_res(1, memoryview(Bb))
    sb = np.zeros(1)
    jb.set_res(2, memoryview(sb))
    f_run()
    j_run()
    A, _ = plant.linearize(x, u)
    assert np.abs(Ab.reshape(n, n) - A).max() <= 1e-12 * max(1.0, np.abs(A).max())
    assert np.abs(yb - plant.dynamics(x, u)).max() <= 1e-12 * max(1.0, np.abs(yb).max())
    vm = ExactJacobian(
        cs.Function("f", [*f_sym.sx_in(), cs.SX.sym("p", 0)], [f_sym(*f_sym.sx_in())], ["x", "u", "p"], ["xdot"]),
        np.zeros(0),
    )

    rows = {
        "f: compiled (buffer)": median_us(f_run),
        "f: plant.dynamics": median_us(lambda: plant.dynamics(x, u)),
        "f: MuJoCo mj_forward": median_us(lambda: mujoco.mj_forward(mm, md)),
        "f: Pinocchio aba": median_us(lambda: pin.aba(pm, pd, q, v, tau)),
        "(A,B): compiled (buffer)": median_us(j_run),
        "(A,B): plant.linearize": median_us(lambda: plant.linearize(x, u)),
        "(A,B): CasADi VM, cs.jacobian of f": median_us(lambda: vm(x, u)),
        "(A,B): MuJoCo mjd_transitionFD centred": median_us(
            lambda: mujoco.mjd_transitionFD(mm, md, 1e-6, True, Ad, Bd, None, None)
        ),
        "(A,B): MuJoCo mjd_transitionFD forward": median_us(
            lambda: mujoco.mjd_transitionFD(mm, md, 1e-6, False, Ad, Bd, None, None)
        ),
        "(A,B): Pinocchio computeABADerivatives": median_us(lambda: pin.computeABADerivatives(pm, pd, q, v, tau)),
    }
    return {"name": name, "path": path, "nq": n // 2, "rows": rows, "first": first, "cached": cached, "agree": agree}


def main() -> None:
    print(
        f"compiled with {' '.join(default_flags())}; CasADi {cs.__version__}, MuJoCo {mujoco.__version__}, "
        f"Pinocchio {pin.__version__}; load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores"
    )
    print(f"per call: median of {CALLS} calls after {WARMUP} warm-up, min over {REPEATS} repeats [µs]\n")
    with tempfile.TemporaryDirectory() as tmp:
        results = [bench_model(name, Path(tmp)) for name in ("panda_like_arm.xml", "arm6.xml", "double_pendulum.xml")]
    labels = list(results[0]["rows"])
    head = f"{'':42s}" + "".join(f"{r['name'].split('.')[0] + ' (' + str(r['nq']) + ' DOF)':>24s}" for r in results)
    print(head)
    for label in labels:
        print(f"{label:42s}" + "".join(f"{r['rows'][label]:24.2f}" for r in results))
    for key, what in (("first", "first build incl. compile [s]"), ("cached", "cached load [ms]")):
        scale = 1.0 if key == "first" else 1e3
        cells = "".join(f"{r[key]['wall'] * scale:11.2f} (cpu {r[key]['cpu'] * scale:6.2f})" for r in results)
        print(f"{what:42s}{cells}")
    print()
    for r in results:
        rows = r["rows"]
        fdc, fdf = rows["(A,B): MuJoCo mjd_transitionFD centred"], rows["(A,B): MuJoCo mjd_transitionFD forward"]
        pin_j, mjf = rows["(A,B): Pinocchio computeABADerivatives"], rows["f: MuJoCo mj_forward"]
        print(f"{r['name']}: Pinocchio agreement {r['agree']:.1e}")
        for how, jab, f in (
            ("compiled buffer", rows["(A,B): compiled (buffer)"], rows["f: compiled (buffer)"]),
            ("plant.linearize/dynamics", rows["(A,B): plant.linearize"], rows["f: plant.dynamics"]),
        ):
            print(
                f"  {how:25s}: (A,B) {fdc / jab:5.1f}x faster than centred transitionFD, {fdf / jab:5.1f}x than "
                f"forward, {jab / pin_j:4.2f}x Pinocchio's time; f {f / mjf:4.2f}x mj_forward's time"
            )


if __name__ == "__main__":
    main()
