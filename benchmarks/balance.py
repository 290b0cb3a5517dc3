"""Push recovery of our legged robots in MuJoCo: the largest sideways push each balance controller recovers from.

For each robot (``assets/quadruped.xml``, ``assets/humanoid.xml``) and each controller, the largest constant
world-frame force along +y on the trunk (the quadruped's ``trunk``, the humanoid's ``torso``) for 0.1 s from
which the robot recovers (back within 5 cm and 0.15 rad of its initial trunk pose and at rest 2 s after the
push), found by bisection to 1 N (:func:`shinro_ctrl.engine.tutorial_lqr.push_recovery`), and the design time
(wall clock of the controller's factory: its standing point, linearization and Riccati solution; for ours also
the plant's build).

Controllers:

* ``transitionFD recipe``: MuJoCo's LQR tutorial (:mod:`shinro_ctrl.engine.tutorial_lqr`): standing point by
  ``mj_inverse`` at the keyframe, ``mjd_transitionFD`` of the full contact model, DARE with a balance cost.
* ``contact-constrained LQR``: ours, exactly as the shipped scenarios design it
  (``configs/quadruped_stand_lqr_mujoco.toml``, ``configs/humanoid_balance_lqr_mujoco.toml``: their
  ``[plant] contacts`` and ``[controller] Q, R``): ``MjcfPlant(..., contacts=...)`` (the exact constrained
  dynamics), its standing equilibrium, the exact linearization of its step and the DARE; in MuJoCo
  ``u = u₀ − K (x_I − x_I0)`` with ``x_I`` the independent joints and their rates read from ``qpos, qvel``, started
  at the design's standing configuration. Its design time is the first design in the process (the in-process
  caches cold; the compiled functions' disk cache as it is: warm after a first run).

Other controllers plug in through :data:`CONTROLLERS`: a name and a factory ``factory(engine, robot) ->
(policy, (qpos0, qvel0))`` where ``policy(qpos, qvel) -> ctrl`` acts in MuJoCo's coordinates (see
:func:`add_controller`). The design time is one sample on a shared 2-core machine: noisy, compare orders of
magnitude.

Run: ``python benchmarks/balance.py`` (``make bench`` runs all benchmarks).
"""

from __future__ import annotations

import tomllib
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from shinro_ctrl.controllers.lqr import LQR
from shinro_ctrl.engine import MujocoEngine
from shinro_ctrl.engine.tutorial_lqr import Policy, push_recovery, simulate_push, transition_fd_lqr
from shinro_ctrl.sim.metrics import balance_metrics

ASSETS = Path(__file__).resolve().parent.parent / "assets"
CONFIGS = Path(__file__).resolve().parent.parent / "configs"


@dataclass(frozen=True)
class Robot:
    """One robot of the table: its model file, feet (support centre), pushed body and balance scenario."""

    name: str
    path: Path
    feet: tuple[str, ...]
    trunk: str
    scenario: Path


ROBOTS = (
    Robot(
        "quadruped",
        ASSETS / "quadruped.xml",
        ("FL_foot", "FR_foot", "RL_foot", "RR_foot"),
        "trunk",
        CONFIGS / "quadruped_stand_lqr_mujoco.toml",
    ),
    Robot(
        "humanoid",
        ASSETS / "humanoid.xml",
        ("left_foot", "right_foot"),
        "torso",
        CONFIGS / "humanoid_balance_lqr_mujoco.toml",
    ),
)

Factory = Callable[[MujocoEngine, Robot], tuple[Policy, tuple[np.ndarray, np.ndarray]]]


def recipe_factory(engine: MujocoEngine, robot: Robot) -> tuple[Policy, tuple[np.ndarray, np.ndarray]]:
    """The MuJoCo-tutorial LQR, started at its own standing point."""
    ctrl = transition_fd_lqr(engine, robot.feet)
    return ctrl, (ctrl.point.qpos.copy(), np.zeros(engine.model.nv))


def constrained_lqr_factory(engine: MujocoEngine, robot: Robot) -> tuple[Policy, tuple[np.ndarray, np.ndarray]]:
    """The LQR designed on the contact-constrained plant, with the robot's scenario's contacts and weights."""
    from shinro_ctrl.plants.mjcf import MjcfPlant

    doc = tomllib.loads(robot.scenario.read_text())
    plant = MjcfPlant(str(robot.path), contacts=doc["plant"]["contacts"])  # its u0: the standing equilibrium
    lqr = LQR.from_plant(plant, doc["controller"]["Q"], doc["controller"]["R"])
    cd = plant.constraints
    x0, u0, K = lqr.x0, lqr.u0, lqr.K
    lo, hi = plant.input_bounds()

    def policy(qpos: np.ndarray, qvel: np.ndarray) -> np.ndarray:
        return np.clip(u0 - K @ (cd.reduce(np.r_[qpos, qvel]) - x0), lo, hi)

    full = cd.complete(x0)
    nq = engine.model.nq
    return policy, (full[:nq].copy(), full[nq:].copy())


#: ``[(name, factory)]`` of the controllers in the table.
CONTROLLERS: list[tuple[str, Factory]] = [
    ("transitionFD recipe", recipe_factory),
    ("contact-constrained LQR", constrained_lqr_factory),
]


def add_controller(name: str, factory: Factory) -> None:
    """Add a controller to the table (e.g. the LQR designed on the contact-constrained plant)."""
    CONTROLLERS.append((name, factory))


#: The push each robot must survive (issue 26): the balance metrics are reported under it.
REQUIRED_PUSH = {"quadruped": 30.0, "humanoid": 15.0}


def measure(robot: Robot, factory: Factory) -> tuple[float, float, float, dict]:
    """``(largest push recovered [N], smallest push tried that was not [N], design time [s], balance metrics
    under the required push)`` for one robot. The design time is the first design in the process (one sample:
    a repeated design would find the plant's in-process caches warm)."""
    engine = MujocoEngine(str(robot.path))
    res = push_recovery(engine, lambda e: factory(e, robot), body=robot.trunk, direction=(0, 1, 0), duration=0.1)
    policy, start = factory(engine, robot)
    monitor = engine.balance_monitor()
    simulate_push(engine, policy, start, body=robot.trunk, force=(0.0, REQUIRED_PUSH[robot.name], 0.0), monitor=monitor)
    return res.largest_force, res.first_failure, res.design_time, balance_metrics(monitor.record())


def main() -> None:
    print("largest sideways push (0.1 s on the trunk, +y) recovered from in MuJoCo, bisection to 1 N;")
    print("design time: the first design in the process (one sample); balance metrics of a run with the required")
    print("push (30 N / 15 N at t = 0.2 s)")
    head = f"{'robot':10s} {'controller':24s} {'push N':>7s} {'fails N':>8s} {'design s':>9s}"
    print(f"{head} {'height m':>9s} {'tilt rad':>9s} {'slip m':>8s} {'in cone':>8s}")
    for robot in ROBOTS:
        for name, factory in CONTROLLERS:
            ok, fail, design, bm = measure(robot, factory)
            print(
                f"{robot.name:10s} {name:24s} {ok:7.1f} {fail:8.1f} {design:9.3f} {bm['trunk_height_error']:9.4f} "
                f"{bm['trunk_orientation_error']:9.4f} {bm['foot_slip']:8.5f} {bm['friction_cone_fraction']:8.3f}"
            )


if __name__ == "__main__":
    main()
