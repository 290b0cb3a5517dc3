"""Contact-constrained linearization against MuJoCo's ``mjd_transitionFD``, on the planar biped.

``MjcfPlant(tests/data/planar_biped_contacts.xml, contacts=["lfoot", "rfoot"])`` (7 DOF: a slide x, slide z,
pitch base and two 2-joint legs; two point feet): the exact contact-constrained Jacobians
(:meth:`MjcfPlant.linearize`: Newton completion of the dependent joints, then the implicit-function-theorem
Jacobians evaluated by CasADi's virtual machine, not compiled) against ``mjd_transitionFD`` (centred, full
contact model) on the same file at the same state, in one run. Medians of 5 repeats of 200 calls each, on a
shared 2-core machine (noisy).

Not yet here (issue 26 items 4 and 5 on the legged robots): contacts on a free-joint base are refused by
``MjcfPlant`` for now, so the 18-DOF quadruped's figures and the push-recovery comparison with
``benchmarks/balance.py``'s transitionFD recipe are left for when they are supported.

Run: ``python benchmarks/contacts.py``.
"""

from __future__ import annotations

import statistics
import time
from pathlib import Path

import mujoco
import numpy as np

from shinro_ctrl.plants.mjcf import MjcfPlant

BIPED = Path(__file__).resolve().parent.parent / "tests" / "data" / "planar_biped_contacts.xml"


def _median_us(fn, calls: int = 200, repeats: int = 5) -> float:
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        for _ in range(calls):
            fn()
        times.append((time.perf_counter() - t) / calls * 1e6)
    return statistics.median(times)


def main() -> None:
    t = time.perf_counter()
    plant = MjcfPlant(BIPED, contacts=["lfoot", "rfoot"])
    build = time.perf_counter() - t
    x0, u0 = plant.equilibrium()
    t = time.perf_counter()
    plant.linearize(x0, u0)
    first = time.perf_counter() - t
    ours = _median_us(lambda: plant.linearize(x0, u0))

    m = mujoco.MjModel.from_xml_path(str(BIPED))
    d = mujoco.MjData(m)
    full = plant.constraints.complete(x0)
    d.qpos[:], d.qvel[:], d.ctrl[:] = full[: m.nq], full[m.nq :], u0
    mujoco.mj_forward(m, d)
    nx = 2 * m.nv + m.na
    Ad, Bd = np.zeros((nx, nx)), np.zeros((nx, m.nu))

    def fd() -> None:
        mujoco.mjd_transitionFD(m, d, 1e-6, True, Ad, Bd, None, None)

    theirs = _median_us(fd)
    print(f"planar biped, 2 point contacts: design state {plant.state_dim}, full state {nx}")
    print(f"plant build (symbolic KKT, equilibrium QP): {build:.2f} s; first linearize {first * 1e3:.1f} ms")
    print("| method | time per linearization [us] |")
    print("| --- | --- |")
    print(f"| contact-constrained exact (MjcfPlant.linearize) | {ours:.1f} |")
    print(f"| mjd_transitionFD (centred, full contact model) | {theirs:.1f} |")
    print(f"ratio transitionFD / ours: {theirs / ours:.2f}")


if __name__ == "__main__":
    main()
