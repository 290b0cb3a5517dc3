"""The ``run`` and ``plan`` commands: one scenario's closed loop (one loop or both), and its trajectory plan."""

from __future__ import annotations

import argparse
import math
import os
from pathlib import Path
from typing import Any

from shinro_ctrl.cli.common import PLOT_HELP, RUN_FILES, RUN_FILES_BOTH, path_arg
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
    p.add_argument("--plot", type=path_arg, metavar="FILE", help=f"where to write the plot ({PLOT_HELP})")
    p.add_argument(
        "--out", type=path_arg, metavar="DIR", help="save result.npz, metrics.json, scenario.toml and run.png"
    )
    p.add_argument(
        "--video", type=path_arg, metavar="PATH", help="render the run offscreen with MuJoCo: .gif, or .mp4 with ffmpeg"
    )
    p.add_argument(
        "--plan", type=path_arg, metavar="FILE", help="track this saved plan (.npz from 'plan') instead of planning"
    )
    p.set_defaults(func=cmd_run)

    p = sub.add_parser("plan", help="solve a scenario's [plan] (trajectory optimization) and save it")
    p.add_argument("config", metavar="CONFIG", help="scenario file or shipped name")
    p.add_argument("--plot", type=path_arg, metavar="FILE", help=f"plot the planned states and inputs ({PLOT_HELP})")
    p.add_argument("--out", type=path_arg, metavar="DIR", help="where to write <scenario>_plan.npz (default out/)")
    p.set_defaults(func=cmd_plan)


# ------------------------------------------------------------------------ run
def cmd_run(args: argparse.Namespace) -> int:
    _check_run_args(args)
    from shinro_ctrl.resources import shipped_config
    from shinro_ctrl.sim import format_metrics

    # The embedded default is the shipped file, never a same-named one in the current directory.
    config = shipped_config(DEFAULT_SCENARIO) if args.config is None else args.config
    if args.engine == "both":
        return _run_both(args, config)
    sim = _build_sim(config, args.plan, args.engine)
    _check_duration(args.duration, sim.plant.dt)
    _print_plan(sim.controller)
    label = f"{sim.scenario.name} ({sim.loop})"
    print(f"running {label}: {type(sim.plant).__name__} + {type(sim.controller).__name__}, ", end="")
    print(f"{args.duration if args.duration is not None else sim.scenario.sim.duration:g} s at dt = {sim.plant.dt:g} s")
    result = sim.run(args.duration)
    print(format_metrics(result.metrics))
    plot, video = _save_run(args, sim, result)
    print(f"plot: {plot}")
    if args.video:
        if video is None:
            video = _render(sim, result, args.video)
        print(
            f"video: {args.video} ({video.frames} frames at {video.fps:.3g} frames/s, "
            f"{video.frames / video.fps:.2f} s of playback; rendered in {video.seconds:.2f} s)"
        )
    return 0


def _check_duration(duration: float | None, dt: float) -> None:
    """``--duration``: a whole number of the plant's steps, at least one (never rounded silently), and at most
    the run's limit :data:`~shinro_ctrl.sim.MAX_STEPS` (checked before anything is printed)."""
    if duration is not None:
        from shinro_ctrl.config import whole_steps
        from shinro_ctrl.sim import MAX_STEPS

        steps = whole_steps(duration, dt, "--duration")
        if steps > MAX_STEPS:
            raise InvalidArgument(
                f"--duration = {duration:g} s at dt = {dt:g} s is {steps:.3g} steps; a run keeps every step in "
                f"memory and is limited to {MAX_STEPS:,} steps ({MAX_STEPS * dt:g} s at this dt)"
            )


def _check_config_argument(config: str | None, *, demo: bool = True) -> None:
    """An empty CONFIG (``run ""``, an unset shell variable) is refused, never taken for the demo."""
    if config is not None and not config.strip():
        raise InvalidArgument(
            "the scenario argument CONFIG is empty (an unset shell variable?): give a scenario file or a shipped "
            "name" + (", or leave it out for the demo" if demo else "")
        )


def _check_run_args(args: argparse.Namespace) -> None:
    """Every argument and output path of ``run``, checked before any work (an output never overwrites an input).

    A ``--plot`` or ``--video`` directly inside ``--out`` joins the folder's set (``args.plot_in_out`` /
    ``args.video_in_out`` = its name); one deeper inside, or named like one of the run's own files, is refused
    (the folder is replaced as a whole); ``--plot`` and ``--video`` must be two files.
    """
    from shinro_ctrl.cli.common import _check_output, _inside, _same_path
    from shinro_ctrl.files import check_output_file, check_output_folder
    from shinro_ctrl.plots._figure import plot_format
    from shinro_ctrl.resources import config_path

    _check_config_argument(args.config)
    if args.duration is not None and not (math.isfinite(args.duration) and args.duration > 0):
        raise InvalidArgument(f"--duration must be a positive finite number of seconds, got {args.duration:g}")
    inputs = [config_path(args.config) if args.config else None, getattr(args, "plan", None)]
    both = args.engine == "both"
    if both and args.video:
        raise InvalidArgument("--video renders one loop: give --engine standalone or --engine mujoco")
    if args.plot and args.video and _same_path(args.plot, args.video):
        raise InvalidArgument(f"--plot and --video name the same file '{args.plot}': give each its own name")
    args.plot_in_out = args.video_in_out = None
    if args.out:
        names = RUN_FILES_BOTH if both else RUN_FILES
        for option, value in (("--plot", args.plot), ("--video", args.video)):
            if not value or not _inside(value, args.out):
                continue
            rel = Path(os.path.realpath(value)).relative_to(os.path.realpath(args.out))
            if len(rel.parts) != 1 or rel.name in names[:-1]:
                raise InvalidArgument(
                    f"{option} '{value}' is inside --out '{args.out}', which is replaced as a whole: name a file "
                    f"directly in it (not one of {', '.join(names[:-1])}), or put it elsewhere"
                )
            if option == "--plot":
                plot_format(value, what="--plot")  # as _check_output checks a plot outside the folder
                args.plot_in_out = rel.name  # the plot joins the folder's set under this name
                names = (*names[:-1], rel.name)
            else:
                args.video_in_out = rel.name  # so does the video
                names = (*names, rel.name)
        try:
            check_output_folder(args.out, names, inputs=inputs, what="--out folder")
        except InvalidArgument as exc:
            inside = [
                f"{o} '{v}'" for o, v in (("--plot", args.plot), ("--video", args.video)) if v and _inside(v, args.out)
            ]
            if inside:
                raise InvalidArgument(f"{exc} ({' and '.join(inside)} is inside it)") from None
            raise
    if args.plot and args.plot_in_out is None:
        _check_output(args.plot, inputs)
    if args.video and args.video_in_out is None:
        check_output_file(args.video, inputs=inputs, what="--video")
    if args.video:  # before mujoco is imported: it reads MUJOCO_GL once
        from shinro_ctrl.video import prepare_video

        prepare_video(args.video)


def _build_sim(config: Any, plan_file: str | None, engine: str | None) -> Any:
    """The scenario's :class:`~shinro_ctrl.sim.RobotSim` in loop ``engine``, tracking ``plan_file`` if given."""
    from shinro_ctrl.sim import RobotSim

    if plan_file:
        from shinro_ctrl.config import load_scenario
        from shinro_ctrl.planning import with_plan_file

        return RobotSim(with_plan_file(load_scenario(config), plan_file), engine=engine)
    return RobotSim.from_config(config, engine=engine)


def _print_plan(controller: Any) -> None:
    """One line on the plan a plan-tracking controller (TVLQR) follows."""
    traj = getattr(controller, "trajectory", None)
    if traj is not None:
        print(
            f"plan: {traj.method}, T = {traj.duration:.4g} s, solve {traj.solve_time:.3g} s, "
            f"{traj.iterations} iterations, objective {traj.objective:.6g}, max defect {traj.max_defect:.2e}"
        )


def _render(sim: Any, result: Any, path: str | Path) -> Any:
    from shinro_ctrl.video import render_rollout

    return render_rollout(sim, result, path)


def _save_run(args: argparse.Namespace, sim: Any, result: Any) -> tuple[Path, Any]:
    """``--out``: the run's files as one set (the plot, and the video, too when they are named inside it).

    Returns:
        ``(the plot's path, the rendered video or None when it is rendered afterwards)``.
    """
    if not args.out:
        return result.plot(args.plot or Path("out") / f"{sim.scenario.name}_{sim.loop}.png"), None
    from shinro_ctrl.files import atomic_folder

    out = Path(args.out)
    in_set = args.plot_in_out or (None if args.plot else RUN_FILES[-1])
    names = (*RUN_FILES[:-1], *([in_set] if in_set else []), *([args.video_in_out] if args.video_in_out else []))
    video = None
    with atomic_folder(out, names) as staging:  # one complete run or the previous one, even if killed
        result.save(staging)
        if in_set:
            result.plot(staging / in_set)
        if args.video_in_out:
            video = _render(sim, result, staging / args.video_in_out)
    plot = out / in_set if in_set else result.plot(args.plot)
    print(f"saved result.npz, metrics.json, scenario.toml to {out}")
    return plot, video


def _run_both(args: argparse.Namespace, config: Any) -> int:
    """``run --engine both``: the standalone and the MuJoCo loop of one scenario, compared and overlaid."""
    a, b = (_build_sim(config, args.plan, loop) for loop in ("standalone", "mujoco"))
    _check_duration(args.duration, a.plant.dt)
    duration = args.duration if args.duration is not None else a.scenario.sim.duration
    what = f"{type(a.plant).__name__} + {type(a.controller).__name__}"
    print(f"running {a.scenario.name} in both loops: {what}, {duration:g} s at dt = {a.plant.dt:g} s")
    ra, rb = a.run(args.duration), b.run(args.duration)
    print(format_metric_comparison(ra.metrics, rb.metrics, ("standalone", "mujoco")))
    if args.out:
        from shinro_ctrl.files import atomic_folder

        out = Path(args.out)
        in_set = args.plot_in_out or (None if args.plot else RUN_FILES_BOTH[-1])
        with atomic_folder(out, (*RUN_FILES_BOTH[:-1], *([in_set] if in_set else []))) as staging:
            ra.save(staging / "standalone")
            rb.save(staging / "mujoco")
            if in_set:
                ra.plot(staging / in_set, compare=rb)
        plot = out / in_set if in_set else ra.plot(args.plot, compare=rb)
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


# ----------------------------------------------------------------------- plan
def cmd_plan(args: argparse.Namespace) -> int:
    from shinro_ctrl.config import load_scenario

    _check_config_argument(args.config, demo=False)
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
    target = check_output_file(out / f"{scenario.name}_plan.npz", inputs=inputs, what="--out")
    if args.plot:
        from shinro_ctrl.cli.common import _check_output, _same_path

        if _same_path(args.plot, target):
            raise InvalidArgument(f"--plot '{args.plot}' is the plan file written to --out; choose another name")
        _check_output(args.plot, [*inputs, str(target)])
    return target
