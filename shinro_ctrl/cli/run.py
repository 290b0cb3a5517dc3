"""The ``run`` and ``plan`` commands: one scenario's closed loop (one loop or both), and its trajectory plan."""

from __future__ import annotations

import argparse
import math
import os
from pathlib import Path
from typing import Any

from shinro_ctrl.cli.common import RUN_FILES, RUN_FILES_BOTH
from shinro_ctrl.errors import InvalidArgument

__all__ = ["DEFAULT_SCENARIO", "cmd_plan", "cmd_run", "format_metric_comparison", "register"]

DEFAULT_SCENARIO = "cartpole_lqr.toml"


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``run`` and ``plan`` to the ``shinro-ctrl`` parser (``sub``: its subparsers)."""
    p = sub.add_parser("run", help="run a scenario (default: the embedded cart-pole LQR demo)")
    p.add_argument("config", nargs="?", metavar="CONFIG", help="scenario file or shipped name")
    p.add_argument(
        "--engine",
        choices=("standalone", "mujoco", "both"),
        help="override the scenario's loop; 'both' runs the two loops and overlays them with their differences",
    )
    p.add_argument("--duration", type=float, metavar="S", help="simulated seconds (default: the scenario's)")
    p.add_argument("--plot", metavar="PNG", help="where to write the plot")
    p.add_argument("--out", metavar="DIR", help="save result.npz, metrics.json, scenario.toml and run.png")
    p.add_argument("--video", metavar="PATH", help="render the run offscreen with MuJoCo: .gif, or .mp4 with ffmpeg")
    p.add_argument("--plan", metavar="FILE", help="track this saved plan (.npz from 'plan') instead of planning")
    p.set_defaults(func=cmd_run)

    p = sub.add_parser("plan", help="solve a scenario's [plan] (trajectory optimization) and save it")
    p.add_argument("config", metavar="CONFIG", help="scenario file or shipped name")
    p.add_argument("--plot", metavar="PNG", help="plot the planned states and inputs")
    p.add_argument("--out", metavar="DIR", help="where to write <scenario>_plan.npz (default out/)")
    p.set_defaults(func=cmd_plan)


# ------------------------------------------------------------------------ run
def cmd_run(args: argparse.Namespace) -> int:
    _check_run_args(args)
    from shinro_ctrl.resources import shipped_config
    from shinro_ctrl.sim import format_metrics

    # The embedded default is the shipped file, never a same-named one in the current directory.
    config = args.config or shipped_config(DEFAULT_SCENARIO)
    if args.engine == "both":
        return _run_both(args, config)
    sim = _build_sim(config, args.plan, args.engine)
    _print_plan(sim.controller)
    label = f"{sim.scenario.name} ({sim.loop})"
    print(f"running {label}: {type(sim.plant).__name__} + {type(sim.controller).__name__}, ", end="")
    print(f"{args.duration if args.duration is not None else sim.scenario.sim.duration:g} s at dt = {sim.plant.dt:g} s")
    result = sim.run(args.duration)
    print(format_metrics(result.metrics))
    print(f"plot: {_save_run(args, sim, result)}")
    if args.video:
        from shinro_ctrl.video import render_rollout

        video = render_rollout(sim, result, args.video)
        print(
            f"video: {video.path} ({video.frames} frames at {video.fps:.3g} frames/s, "
            f"{video.frames / video.fps:.2f} s of playback; rendered in {video.seconds:.2f} s)"
        )
    return 0


def _check_run_args(args: argparse.Namespace) -> None:
    """Every argument and output path of ``run``, checked before any work (an output never overwrites an input)."""
    from shinro_ctrl.files import check_output_file, check_output_folder
    from shinro_ctrl.resources import config_path

    if args.duration is not None and not (math.isfinite(args.duration) and args.duration > 0):
        raise InvalidArgument(f"--duration must be a positive finite number of seconds, got {args.duration:g}")
    inputs = [config_path(args.config) if args.config else None, getattr(args, "plan", None)]
    both = args.engine == "both"
    if both and args.video:
        raise InvalidArgument("--video renders one loop: give --engine standalone or --engine mujoco")
    if args.out:
        check_output_folder(args.out, RUN_FILES_BOTH if both else RUN_FILES, inputs=inputs)
    if args.plot:
        check_output_file(args.plot, inputs=inputs, what="--plot", kind=".png")  # a PNG whatever its name
    if args.video:
        check_output_file(args.video, inputs=inputs, what="--video")
    if args.video:  # before mujoco is imported: it reads MUJOCO_GL once
        from shinro_ctrl.video import prepare_video

        prepare_video(args.video)


def _build_sim(config: Any, plan_file: str | None, engine: str | None) -> Any:
    """The scenario's :class:`~shinro_ctrl.sim.RobotSim` in loop ``engine``, tracking ``plan_file`` if given."""
    from shinro_ctrl.sim import RobotSim

    if plan_file:
        return RobotSim(_scenario_with_plan_file(config, plan_file), engine=engine)
    return RobotSim.from_config(config, engine=engine)


def _print_plan(controller: Any) -> None:
    """One line on the plan a plan-tracking controller (TVLQR) follows."""
    traj = getattr(controller, "trajectory", None)
    if traj is not None:
        print(
            f"plan: {traj.method}, T = {traj.duration:.4g} s, solve {traj.solve_time:.3g} s, "
            f"{traj.iterations} iterations, objective {traj.objective:.6g}, max defect {traj.max_defect:.2e}"
        )


def _save_run(args: argparse.Namespace, sim: Any, result: Any) -> Path:
    """``--out``: the run's files as one set (the plot too, unless ``--plot`` puts it elsewhere); returns the plot."""
    if not args.out:
        return result.plot(args.plot or Path("out") / f"{sim.scenario.name}_{sim.loop}.png")
    from shinro_ctrl.files import atomic_folder

    out = Path(args.out)
    written = RUN_FILES if not args.plot else RUN_FILES[:-1]  # with --plot the plot goes there instead
    with atomic_folder(out, written) as staging:  # one complete run or the previous one, even if killed
        result.save(staging)
        if not args.plot:
            result.plot(staging / "run.png")
    plot = result.plot(args.plot) if args.plot else out / "run.png"
    print(f"saved result.npz, metrics.json, scenario.toml to {out}")
    return plot


def _run_both(args: argparse.Namespace, config: Any) -> int:
    """``run --engine both``: the standalone and the MuJoCo loop of one scenario, compared and overlaid."""
    a, b = (_build_sim(config, args.plan, loop) for loop in ("standalone", "mujoco"))
    duration = args.duration if args.duration is not None else a.scenario.sim.duration
    what = f"{type(a.plant).__name__} + {type(a.controller).__name__}"
    print(f"running {a.scenario.name} in both loops: {what}, {duration:g} s at dt = {a.plant.dt:g} s")
    ra, rb = a.run(args.duration), b.run(args.duration)
    print(format_metric_comparison(ra.metrics, rb.metrics, ("standalone", "mujoco")))
    if args.out:
        from shinro_ctrl.files import atomic_folder

        out = Path(args.out)
        with atomic_folder(out, RUN_FILES_BOTH if not args.plot else RUN_FILES_BOTH[:-1]) as staging:
            ra.save(staging / "standalone")
            rb.save(staging / "mujoco")
            if not args.plot:
                ra.plot(staging / "run.png", compare=rb)
        plot = ra.plot(args.plot, compare=rb) if args.plot else out / "run.png"
        print(f"saved standalone/ and mujoco/ (result.npz, metrics.json, scenario.toml each) to {out}")
    else:
        plot = ra.plot(args.plot or Path("out") / f"{a.scenario.name}_both.png", compare=rb)
    print(f"plot: {plot}")
    return 0


def format_metric_comparison(a: dict[str, float], b: dict[str, float], names: tuple[str, str]) -> str:
    """Two runs' metrics side by side with their difference ``b − a``."""
    from shinro_ctrl.sim.metrics import format_metric

    rows = [f"  {'metric':22s} {names[0]:>14s} {names[1]:>14s} {'difference':>12s}"]
    for key in a:
        va, vb = a[key], b.get(key)
        numbers = all(isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v) for v in (va, vb))
        diff = f"{vb - va:+.3g}" if numbers else "—"
        rows.append(f"  {key:22s} {format_metric(key, va):>14s} {format_metric(key, vb):>14s} {diff:>12s}")
    return "\n".join(rows)


def _scenario_with_plan_file(config: str, plan_file: str):
    """The scenario with its plan replaced by a saved one (``run --plan FILE``)."""
    from shinro_ctrl.config import load_scenario

    scenario = load_scenario(config)
    if scenario.plan is None:
        raise InvalidArgument(f"--plan: {scenario.name} has no [plan] table (its controller tracks no plan)")
    spec = {k: v for k, v in scenario.plan.items() if k in ("start", "bounds")}  # bounds: the saturation
    spec["file"] = str(plan_file)
    scenario.plan = scenario.controller.options["plan"] = spec
    return scenario


# ----------------------------------------------------------------------- plan
def cmd_plan(args: argparse.Namespace) -> int:
    from shinro_ctrl.config import load_scenario
    from shinro_ctrl.planning.spec import make_plan
    from shinro_ctrl.plants import plant_class

    scenario = load_scenario(args.config)
    if scenario.plan is None:
        raise InvalidArgument(f"{scenario.name}: no [plan] table to solve")
    target = _check_plan_outputs(args, scenario)  # before the plan is solved
    plant = plant_class(scenario.plant.type).from_config(scenario.plant.params)
    traj = make_plan(plant, scenario.plan)
    print(f"plan {scenario.name}: {type(plant).__name__}")
    print(traj.summary())
    path = traj.save(target)
    print(f"saved {path}")
    if args.plot:
        print(f"plot: {traj.plot(args.plot)}")
    return 0


def _check_plan_outputs(args: argparse.Namespace, scenario: Any) -> Path:
    """The plan file ``DIR/NAME_plan.npz`` (``--out DIR``, default ``out/`` as for ``run``'s plot) and ``--plot``.

    Checked before any work, as ``run`` checks its outputs: neither is one of the inputs (the scenario, a
    plan file it loads), an existing file that is not an earlier output of the same kind, or the other one.
    Each file is written atomically.
    """
    from shinro_ctrl.files import check_output_file

    out = Path(args.out) if args.out else Path("out")
    if out.exists() and not out.is_dir():
        raise InvalidArgument(f"--out '{out}' exists and is not a folder")
    inputs = [scenario.path, scenario.plan.get("file")]
    target = check_output_file(out / f"{scenario.name}_plan.npz", inputs=inputs, what="--out", kind=".npz")
    if args.plot:
        if os.path.abspath(args.plot) == os.path.abspath(target):
            raise InvalidArgument(f"--plot '{args.plot}' is the plan file written to --out; choose another name")
        check_output_file(args.plot, inputs=[*inputs, target], what="--plot", kind=".png")
    return target
