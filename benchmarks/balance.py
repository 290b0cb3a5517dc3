"""Push recovery of our legged robots in MuJoCo: the largest sideways push each balance controller recovers from.

For each robot (``assets/quadruped.xml``, ``assets/humanoid.xml``) and each controller, the largest constant
world-frame force along +y on the trunk (the quadruped's ``trunk``, the humanoid's ``torso``) for 0.1 s from
which the robot recovers (back within 5 cm and 0.15 rad of its initial trunk pose and at rest 2 s after the
push), found by bisection to 1 N (:func:`shinro_ctrl.engine.tutorial_lqr.push_recovery`), and the design time
(wall clock of the controller's factory: its standing point, linearization and Riccati solution).

Controllers:

* ``transitionFD recipe``: MuJoCo's LQR tutorial (:mod:`shinro_ctrl.engine.tutorial_lqr`): standing point by
  ``mj_inverse`` at the keyframe, ``mjd_transitionFD`` of the full contact model, DARE with a balance cost.

Other controllers plug in through :data:`CONTROLLERS`: a name and a factory ``factory(engine, robot) ->
(policy, (qpos0, qvel0))`` where ``policy(qpos, qvel) -> ctrl`` acts in MuJoCo's coordinates (see
:func:`add_controller`). The design time is one sample on a shared 2-core machine: noisy, compare orders of
magnitude.

Run: ``python benchmarks/balance.py`` (``make bench`` runs all benchmarks).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from shinro_ctrl.engine import MujocoEngine
from shinro_ctrl.engine.tutorial_lqr import Policy, push_recovery, simulate_push, transition_fd_lqr
from shinro_ctrl.sim.metrics import balance_metrics

ASSETS = Path(__file__).resolve().parent.parent / "assets"


@dataclass(frozen=True)
class Robot:
    """One robot of the table: its model file, feet (support centre) and pushed body."""

    name: str
    path: Path
    feet: tuple[str, ...]
    trunk: str


ROBOTS = (
    Robot("quadruped", ASSETS / "quadruped.xml", ("FL_foot", "FR_foot", "RL_foot", "RR_foot"), "trunk"),
    Robot("humanoid", ASSETS / "humanoid.xml", ("left_foot", "right_foot"), "torso"),
)

Factory = Callable[[MujocoEngine, Robot], tuple[Policy, tuple[np.ndarray, np.ndarray]]]


def recipe_factory(engine: MujocoEngine, robot: Robot) -> tuple[Policy, tuple[np.ndarray, np.ndarray]]:
    """The MuJoCo-tutorial LQR, started at its own standing point."""
    ctrl = transition_fd_lqr(engine, robot.feet)
    return ctrl, (ctrl.point.qpos.copy(), np.zeros(engine.model.nv))


#: ``[(name, factory)]`` of the controllers in the table.
CONTROLLERS: list[tuple[str, Factory]] = [("transitionFD recipe", recipe_factory)]


def add_controller(name: str, factory: Factory) -> None:
    """Add a controller to the table (e.g. the LQR designed on the contact-constrained plant)."""
    CONTROLLERS.append((name, factory))


#: The push each robot must survive (issue 26): the balance metrics are reported under it.
REQUIRED_PUSH = {"quadruped": 30.0, "humanoid": 15.0}


def measure(robot: Robot, factory: Factory, repeats: int = 3) -> tuple[float, float, float, dict]:
    """``(largest push recovered [N], smallest push tried that was not [N], median design time [s], balance
    metrics under the required push)`` for one robot."""
    engine = MujocoEngine(str(robot.path))
    res = push_recovery(engine, lambda e: factory(e, robot), body=robot.trunk, direction=(0, 1, 0), duration=0.1)
    designs = [res.design_time]
    for _ in range(repeats - 1):
        t0 = time.perf_counter()
        policy, start = factory(engine, robot)
        designs.append(time.perf_counter() - t0)
    monitor = engine.balance_monitor()
    simulate_push(engine, policy, start, body=robot.trunk, force=(0.0, REQUIRED_PUSH[robot.name], 0.0), monitor=monitor)
    return res.largest_force, res.first_failure, float(np.median(designs)), balance_metrics(monitor.record())


def main() -> None:
    print("largest sideways push (0.1 s on the trunk, +y) recovered from in MuJoCo, bisection to 1 N;")
    print("design time: median of 3; balance metrics of a run with the required push (30 N / 15 N at t = 0.2 s)")
    head = f"{'robot':10s} {'controller':22s} {'push N':>7s} {'fails N':>8s} {'design s':>9s}"
    print(f"{head} {'height m':>9s} {'tilt rad':>9s} {'slip m':>8s} {'in cone':>8s}")
    for robot in ROBOTS:
        for name, factory in CONTROLLERS:
            ok, fail, design, bm = measure(robot, factory)
            print(
                f"{robot.name:10s} {name:22s} {ok:7.1f} {fail:8.1f} {design:9.3f} {bm['trunk_height_error']:9.4f} "
                f"{bm['trunk_orientation_error']:9.4f} {bm['foot_slip']:8.5f} {bm['friction_cone_fraction']:8.3f}"
            )


if __name__ == "__main__":
    main()
