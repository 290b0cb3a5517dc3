"""Contact-constrained linearization against MuJoCo's ``mjd_transitionFD``: the planar biped and the quadruped.

Two models, each held on its feet by point contacts, at its standing equilibrium (:meth:`MjcfPlant.equilibrium`):

* ``tests/data/planar_biped_contacts.xml`` with ``contacts=["lfoot", "rfoot"]`` (7 DOF: slide x, slide z, base
  pitch and two 2-joint legs; two point feet);
* ``assets/quadruped.xml`` with ``contacts=["FL_foot", "FR_foot", "RL_foot", "RR_foot"]`` (18 DOF: a free-joint
  trunk and 12 actuated joints; four sphere feet): the free base is dependent, the design state is the six
  independent leg joints and their rates.

``ours`` is the whole :meth:`MjcfPlant.linearize` call at ``(x0, u0)``: input checks, the Newton completion of
the dependent coordinates (compiled), the compiled derivatives of the KKT residual and their chaining in NumPy
(the implicit function theorem: :meth:`ConstrainedDynamics.jacobians`). ``mjd_transitionFD`` (centred and
forward) differentiates MuJoCo's full step with its soft contacts, on the same file at the same full state
``[qpos; qvel]``, ctrl ``u0``. Each figure is the median of 2,000 individually timed calls, the minimum over 3
repeats (``benchmarks/_timing.py``, as ``benchmarks/compiled_dynamics.py``), with the mean of all calls in
brackets: the 2-core machine is shared, and the mean carries the preemptions the median leaves out.

``compile`` is the first linearize in a fresh cache folder (C generation and the compiler, default flags
``-O1``); ``cached load`` the first linearize of a new process when the libraries are already on disk (a
subprocess of this script). Both include the Newton completion's library.

Run: ``python benchmarks/contacts.py`` (``--first MODEL`` is the subprocess's mode).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import mujoco
import numpy as np
from _timing import per_call_us  # benchmarks/_timing.py (the script's folder is on sys.path)

from shinro_ctrl.plants.mjcf import MjcfPlant

ROOT = Path(__file__).resolve().parent.parent
MODELS = {
    "planar biped, 2 point feet": (ROOT / "tests" / "data" / "planar_biped_contacts.xml", ["lfoot", "rfoot"]),
    "quadruped, 4 point feet": (ROOT / "assets" / "quadruped.xml", ["FL_foot", "FR_foot", "RL_foot", "RR_foot"]),
}


def _first(name: str) -> dict[str, float]:
    """Plant build, equilibrium and first linearize of one model in this process (wall seconds)."""
    path, contacts = MODELS[name]
    t = time.perf_counter()
    plant = MjcfPlant(path, contacts=contacts)
    build = time.perf_counter() - t
    x0, u0 = plant.equilibrium()
    t = time.perf_counter()
    plant.linearize(x0, u0)
    return {"build": build, "first": time.perf_counter() - t}


def _row(name: str) -> list[str]:
    path, contacts = MODELS[name]
    first = _first(name)  # a fresh cache folder: compiles
    cached = json.loads(
        subprocess.run(
            [sys.executable, __file__, "--first", name], capture_output=True, text=True, check=True
        ).stdout.splitlines()[-1]
    )
    plant = MjcfPlant(path, contacts=contacts)
    x0, u0 = plant.equilibrium()
    ours = per_call_us(lambda: plant.linearize(x0, u0))

    m = mujoco.MjModel.from_xml_path(str(path))
    d = mujoco.MjData(m)
    full = plant.constraints.complete(x0)
    d.qpos[:], d.qvel[:] = full[: m.nq], full[m.nq :]
    d.ctrl[:] = 0.0
    d.ctrl[list(plant.active_actuators)] = u0
    mujoco.mj_forward(m, d)
    nx = 2 * m.nv + m.na
    Ad, Bd = np.zeros((nx, nx)), np.zeros((nx, m.nu))
    centred = per_call_us(lambda: mujoco.mjd_transitionFD(m, d, 1e-6, True, Ad, Bd, None, None))
    forward = per_call_us(lambda: mujoco.mjd_transitionFD(m, d, 1e-6, False, Ad, Bd, None, None))
    print(
        f"{name}: nq {m.nq}, nv {m.nv}, design state {plant.state_dim}, full state {nx}, MuJoCo contacts "
        f"at the state {d.ncon}; plant build {first['build']:.2f} s, compile (first linearize, cold cache) "
        f"{first['first']:.2f} s, cached load (new process: build {cached['build']:.2f} s, first linearize "
        f"{cached['first'] * 1e3:.1f} ms)"
    )
    return [
        f"| {name} | {ours[0]:.1f} ({ours[1]:.1f}) | {centred[0]:.1f} ({centred[1]:.1f}) | "
        f"{forward[0]:.1f} ({forward[1]:.1f}) | {centred[0] / ours[0]:.1f}x / {forward[0] / ours[0]:.1f}x |"
    ]


def main() -> None:
    rows = []
    with tempfile.TemporaryDirectory(prefix="shinro-ctrl-bench-") as cache:
        os.environ["SHINRO_CTRL_CACHE"] = cache  # cold: the first linearize compiles; the subprocess inherits it
        for name in MODELS:
            rows += _row(name)
    print()
    print(
        "| model | MjcfPlant.linearize [us] median (mean) | transitionFD centred [us] | transitionFD forward [us] "
        "| speed-up centred / forward |"
    )
    print("| --- | --- | --- | --- | --- |")
    for row in rows:
        print(row)


if __name__ == "__main__":
    if len(sys.argv) == 3 and sys.argv[1] == "--first":
        print(json.dumps(_first(sys.argv[2])))
    else:
        main()
