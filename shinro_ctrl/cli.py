"""The ``shinro-ctrl`` command.

Each subcommand is a function ``cmd_<name>(args) -> int`` registered in
:func:`build_parser`. User errors (our :class:`ShinroError` family, a missing
file, a bad value) print one line on stderr and exit with status 2; anything
else is a bug and shows its traceback. ``--debug`` shows tracebacks always.
"""

from __future__ import annotations

import argparse
import math
import re
import sys
from collections.abc import Sequence
from typing import Any

import numpy as np

from shinro_ctrl.errors import InvalidArgument, ShinroError

__all__ = ["main"]

EXIT_USER_ERROR = 2
_USER_ERRORS = (ShinroError, OSError)  # anything else is a bug and keeps its traceback


class _Parser(argparse.ArgumentParser):
    """argparse with one-line usage errors and our exit status."""

    def error(self, message: str) -> None:  # type: ignore[override]
        raise _UsageError(f"{self.prog}: {message}")


class _UsageError(Exception):
    pass


_PI_TERM = re.compile(r"^([+-]?)(\d*\.?\d*)\*?pi(?:/(\d+\.?\d*))?$")


def parse_number(text: str) -> float:
    """A float, also accepting ``pi``, ``-pi``, ``2pi``, ``pi/2``, ``0.5*pi``."""
    text = text.strip().lower()
    try:
        return float(text)
    except ValueError:
        pass
    m = _PI_TERM.match(text)
    if not m:
        raise InvalidArgument(f"not a number: '{text}'")
    sign = -1.0 if m.group(1) == "-" else 1.0
    factor = float(m.group(2)) if m.group(2) not in ("", ".") else 1.0
    div = float(m.group(3)) if m.group(3) else 1.0
    if div == 0.0:
        raise InvalidArgument(f"not a number: '{text}' (division by zero)")
    return sign * factor * math.pi / div


def parse_vector(text: str) -> np.ndarray:
    """A comma- or space-separated list of numbers (see :func:`parse_number`)."""
    parts = [p for p in re.split(r"[,\s]+", text.strip().strip("[]")) if p]
    if not parts:
        raise InvalidArgument("empty vector")
    return np.array([parse_number(p) for p in parts])


def _matrix_lines(M: np.ndarray, width: int = 11) -> list[str]:
    return [" ".join(f"{v + 0.0:{width}.5g}" for v in row) for row in np.atleast_2d(M)]


def side_by_side(blocks: Sequence[tuple[str, np.ndarray]], gap: str = "   ") -> str:
    """Render matrices next to each other under their titles."""
    cols = []
    for title, M in blocks:
        lines = _matrix_lines(M)
        w = max([len(title), *(len(s) for s in lines)])
        cols.append([title.ljust(w)] + [s.ljust(w) for s in lines])
    height = max(len(c) for c in cols)
    for c in cols:
        c.extend([" " * len(c[0])] * (height - len(c)))
    return "\n".join(gap.join(c[i] for c in cols).rstrip() for i in range(height))


# ------------------------------------------------------------ argument checks
RUN_FILES = ("result.npz", "metrics.json", "scenario.toml", "run.png")
RUN_FILES_BOTH = ("standalone", "mujoco", "run.png")
SWEEP_FILES = ("sweep.csv", "sweep.json", "sweep.png")
CROSSCHECK_PLANTS = ("pendulum", "cartpole", "double_pendulum", "quadrotor")  # plants with a MuJoCo state map
MAX_SAMPLES = 1_000_000
MAX_WORKERS = 256


def _check_step(option: str, value: float) -> None:
    if not (math.isfinite(value) and 0 < value <= 1.0):
        raise InvalidArgument(f"{option} must be a finite step in (0, 1], got {value:g}")


def _check_count(option: str, value: int, limit: int) -> None:
    if not 1 <= value <= limit:
        raise InvalidArgument(f"{option} must be an integer in [1, {limit:,}], got {value}")


def _check_output(path: str, inputs: Sequence[str | None] = ()) -> None:
    from shinro_ctrl.files import check_output_file

    check_output_file(path, inputs=[i for i in inputs if i], what="--plot", kind=".png")


def _check_scheduler(address: str, timeout: float = 5.0) -> None:
    """Fail fast (one line, a few seconds) when a Dask scheduler address cannot be reached."""
    import socket
    from urllib.parse import urlparse

    url = urlparse(address if "://" in address else f"tcp://{address}")
    try:
        host, port = url.hostname, url.port
    except ValueError:
        host, port = None, None
    if not host or not port:
        raise InvalidArgument(f"--scheduler must look like tcp://HOST:PORT, got '{address}'")
    try:
        socket.create_connection((host, port), timeout=timeout).close()
    except OSError as exc:
        raise InvalidArgument(f"cannot reach the Dask scheduler at '{address}': {exc.strerror or exc}") from None


def _crosscheck_plant(name: str, plant_class):
    """A plant from a short name or class name, or the plant (with its parameters) of a scenario file."""
    from pathlib import Path

    from shinro_ctrl.plants import PLANT_ALIASES, MjcfPlant, is_model_file

    if is_model_file(name):  # an MJCF/URDF model file: the plant is the file, the state map the identity
        return MjcfPlant(name)
    if name.endswith(".toml") or Path(name).is_file():
        from shinro_ctrl.config import load_scenario

        scenario = load_scenario(name)
        plant = plant_class(scenario.plant.type).from_config(scenario.plant.params)
    else:
        plant = plant_class(name)()
    supported = {PLANT_ALIASES.get(a, a) for a in CROSSCHECK_PLANTS} | {"MjcfPlant"}
    if type(plant).__name__ not in supported:
        raise InvalidArgument(
            f"crosscheck supports {', '.join(CROSSCHECK_PLANTS)} (plants whose MuJoCo model maps onto their state); "
            f"got {type(plant).__name__}"
        )
    return plant


# ------------------------------------------------------------------ linearize
def cmd_linearize(args: argparse.Namespace) -> int:
    from shinro_ctrl.linearization import compare
    from shinro_ctrl.plants import plant_from_name

    if args.plot and not args.eps_sweep:
        raise InvalidArgument("--plot goes with --eps-sweep")
    _check_step("--eps", args.eps)
    if args.plot:
        _check_output(args.plot)
    plant = plant_from_name(args.plant)  # a plant name or an MJCF/URDF model file
    x0 = None if args.x0 is None else parse_vector(args.x0)
    u0 = None if args.u0 is None else parse_vector(args.u0)
    cmp = compare(plant, x0, u0, eps=args.eps)
    xe, ue = plant._operating_point(x0, u0)
    print(f"{type(plant).__name__}: continuous-time Jacobians at")
    print(f"  x0 = {dict(zip(plant.state_names, [round(float(v), 6) for v in xe], strict=True))}")
    print(f"  u0 = {dict(zip(plant.input_names, [round(float(v), 6) for v in ue], strict=True))}")
    print()
    print(side_by_side([("A exact (CasADi)", cmp.A_exact), (f"A finite diff (eps={args.eps:g})", cmp.A_fd)]))
    print()
    print(side_by_side([("B exact (CasADi)", cmp.B_exact), ("B finite diff", cmp.B_fd)]))
    print()
    print(f"max |exact - fd| = {cmp.max_abs_error:.3e}   max relative = {cmp.max_rel_error:.3e}")
    if args.eps_sweep:
        from shinro_ctrl.reports import eps_sweep, plot_eps_sweep

        xs, us = xe, ue
        if args.x0 is None and args.u0 is None:
            # At an equilibrium f(x0) = 0 and FD has no rounding error to show: sweep beside it instead.
            xs = xe + 0.1 * np.arange(1, plant.state_dim + 1) / plant.state_dim
            us = ue + 0.1
            print(f"\n(no --x0 given: the sweep uses x0 = {np.round(xs, 4).tolist()}, u0 = {np.round(us, 4).tolist()},")
            print(" off the equilibrium, where f(x0) = 0 would hide FD's rounding error)")
        sweep = eps_sweep(plant, xs, us)
        print()
        print("FD error against a complex-step reference, by step size:")
        for e, err in zip(sweep.eps[::4], sweep.fd_error[::4], strict=True):
            print(f"  eps = {e:8.1e}   max error = {err:8.2e}")
        print(f"  best eps = {sweep.best_eps:.1e}; exact (CasADi) error = {sweep.exact_error:.2e}")
        if args.plot:
            print(f"plot: {plot_eps_sweep(sweep, args.plot, title=f'{type(plant).__name__}: FD step sweep')}")
    elif args.plot:
        raise InvalidArgument("--plot goes with --eps-sweep")
    return 0


# ----------------------------------------------------------------- crosscheck
def cmd_crosscheck(args: argparse.Namespace) -> int:
    from shinro_ctrl.crosscheck import crosscheck, format_crosscheck
    from shinro_ctrl.plants import plant_class

    _check_step("--eps", args.eps)
    if args.plot:
        _check_output(args.plot, inputs=[args.plant])
    plant = _crosscheck_plant(args.plant, plant_class)
    x0 = None if args.x0 is None else parse_vector(args.x0)
    u0 = None if args.u0 is None else parse_vector(args.u0)
    result = crosscheck(plant, x0, u0, eps=args.eps)
    print(format_crosscheck(result))
    if args.plot:
        from shinro_ctrl.reports import plot_crosscheck

        print(f"plot: {plot_crosscheck(result, args.plot)}")
    return 0


# ------------------------------------------------------------------------ run
DEFAULT_SCENARIO = "cartpole_lqr.toml"


def cmd_run(args: argparse.Namespace) -> int:
    from pathlib import Path

    from shinro_ctrl.files import check_output_file, check_output_folder
    from shinro_ctrl.resources import config_path

    # every argument and output path is checked before any work (an output never overwrites an input)
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
    from shinro_ctrl.resources import shipped_config
    from shinro_ctrl.sim import RobotSim, format_metrics

    # The embedded default is the shipped file, never a same-named one in the current directory.
    config = args.config or shipped_config(DEFAULT_SCENARIO)
    if both:
        return _run_both(args, config)
    if args.plan:
        sim = RobotSim(_scenario_with_plan_file(config, args.plan), engine=args.engine)
    else:
        sim = RobotSim.from_config(config, engine=args.engine)
    traj = getattr(sim.controller, "trajectory", None)
    if traj is not None:
        print(
            f"plan: {traj.method}, T = {traj.duration:.4g} s, solve {traj.solve_time:.3g} s, "
            f"{traj.iterations} iterations, objective {traj.objective:.6g}, max defect {traj.max_defect:.2e}"
        )
    label = f"{sim.scenario.name} ({sim.loop})"
    print(f"running {label}: {type(sim.plant).__name__} + {type(sim.controller).__name__}, ", end="")
    print(f"{args.duration if args.duration is not None else sim.scenario.sim.duration:g} s at dt = {sim.plant.dt:g} s")
    result = sim.run(args.duration)
    print(format_metrics(result.metrics))
    if args.out:
        from shinro_ctrl.files import atomic_folder

        out = Path(args.out)
        written = RUN_FILES if not args.plot else RUN_FILES[:-1]  # with --plot the plot goes there instead
        with atomic_folder(out, written) as staging:  # one complete run or the previous one, even if killed
            result.save(staging)
            if not args.plot:
                result.plot(staging / "run.png")
        plot = result.plot(args.plot) if args.plot else out / "run.png"
        print(f"saved result.npz, metrics.json, scenario.toml to {out}")
    else:
        plot = result.plot(args.plot or Path("out") / f"{sim.scenario.name}_{sim.loop}.png")
    print(f"plot: {plot}")
    if args.video:
        from shinro_ctrl.video import render_rollout

        video = render_rollout(sim, result, args.video)
        print(
            f"video: {video.path} ({video.frames} frames at {video.fps:.3g} frames/s, "
            f"{video.frames / video.fps:.2f} s of playback; rendered in {video.seconds:.2f} s)"
        )
    return 0


def _run_both(args: argparse.Namespace, config: Any) -> int:
    """``run --engine both``: the standalone and the MuJoCo loop of one scenario, compared and overlaid."""
    from pathlib import Path

    from shinro_ctrl.sim import RobotSim

    sims = []
    for loop in ("standalone", "mujoco"):
        scenario = _scenario_with_plan_file(config, args.plan) if args.plan else config
        sims.append(RobotSim(scenario, engine=loop) if args.plan else RobotSim.from_config(scenario, engine=loop))
    a, b = sims
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
    rows = [f"  {'metric':22s} {names[0]:>14s} {names[1]:>14s} {'difference':>12s}"]
    for key in a:
        va, vb = a[key], b.get(key, math.nan)

        def show(v: float) -> str:
            return "never" if isinstance(v, float) and math.isinf(v) else f"{v:.6g}"

        diff = vb - va if math.isfinite(va) and math.isfinite(vb) else math.nan
        rows.append(f"  {key:22s} {show(va):>14s} {show(vb):>14s} {'—' if math.isnan(diff) else f'{diff:+.3g}':>12s}")
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
    from pathlib import Path

    from shinro_ctrl.config import load_scenario
    from shinro_ctrl.planning.spec import make_plan
    from shinro_ctrl.plants import plant_class

    scenario = load_scenario(args.config)
    if scenario.plan is None:
        raise InvalidArgument(f"{scenario.name}: no [plan] table to solve")
    plant = plant_class(scenario.plant.type).from_config(scenario.plant.params)
    traj = make_plan(plant, scenario.plan)
    print(f"plan {scenario.name}: {type(plant).__name__}")
    print(traj.summary())
    out = Path(args.out) if args.out else Path("out")
    path = traj.save(out / f"{scenario.name}_plan.npz")
    print(f"saved {path}")
    if args.plot:
        print(f"plot: {traj.plot(args.plot)}")
    return 0


# --------------------------------------------------------------------- design
def cmd_design(args: argparse.Namespace) -> int:
    from shinro_ctrl.sim import RobotSim

    sim = RobotSim.from_config(args.config)  # the scenario's own loop: a bad [engine] table is reported too
    ctrl = sim.controller
    kind = {"lqr": "LQR", "mpc": "LinearMPC"}[args.kind]
    if type(ctrl).__name__ != kind:
        raise InvalidArgument(f"{args.config} configures a {type(ctrl).__name__} controller, not {kind}")
    if args.tradeoff is not None:  # checked before anything is printed
        from shinro_ctrl.tradeoff import parse_tradeoff

        if args.kind != "lqr":
            raise InvalidArgument("--tradeoff sweeps LQR weights: use 'design lqr'")
        if not args.out:
            raise InvalidArgument("--tradeoff needs --out DIR for tradeoff.csv, tradeoff.json and tradeoff.png")
        if args.points < 2 or args.workers < 1:
            raise InvalidArgument(f"--points must be >= 2 and --workers >= 1, got {args.points} and {args.workers}")
        parse_tradeoff(args.tradeoff)
        from shinro_ctrl.files import check_output_folder
        from shinro_ctrl.tradeoff import OUTPUT_FILES

        check_output_folder(args.out, OUTPUT_FILES, inputs=[args.config])
    elif args.out or args.engine or args.points != 20 or args.workers != 2:
        raise InvalidArgument("--out, --engine, --points and --workers go with --tradeoff KEY=LO:HI")
    if args.report:
        from pathlib import Path

        from shinro_ctrl.files import check_output_file

        report = Path(args.report)
        if report.suffix.lower() not in (".html", ".htm"):
            raise InvalidArgument(f"--report: expected a FILE.html, got '{report}'")
        check_output_file(report, inputs=[args.config], what="--report")
        if report.is_file() and report.stat().st_size and not report.read_bytes()[:15].lower() == b"<!doctype html>":
            raise InvalidArgument(f"--report '{report}' exists and is not an HTML report; refusing to overwrite it")
    np.set_printoptions(precision=5, suppress=True, linewidth=120)
    if args.kind == "lqr":
        model = ctrl.model  # the Controller contract: the LinearModel designed on, or None
        if not ctrl.discrete:
            method = model.method if model is not None else "exact"
            print(f"model: continuous-time {method} linearization (continuous design: K and the poles are continuous)")
        elif model is not None:
            print(
                f"model: {model.discretization} discretization of the {model.method} linearization, dt = {model.dt:g} s"
            )
        print("K =")
        print(ctrl.K)
        print("closed-loop poles:")
        for p in ctrl.poles:
            size = f"|p| = {abs(p):.6f}" if getattr(ctrl, "discrete", True) else f"Re p = {p.real:+.6f}"
            print(f"  {p.real:+.6f} {p.imag:+.6f}j   {size}")
        x_init = sim.initial_state
        print(f"predicted cost ½ x0ᵀ S x0 from {np.round(x_init, 6).tolist()}: {ctrl.cost_to_go(x_init):.6g}")
        return _design_analysis(args, sim)
    print(ctrl.describe())
    result = sim.run(min(sim.scenario.sim.duration, 2.0))
    solve = result.solve_times
    print(
        f"closed loop ({len(solve)} steps, {sim.loop}): median call {1e3 * np.median(solve):.3f} ms, "
        f"p95 {1e3 * np.percentile(solve, 95):.3f} ms, max {1e3 * solve.max():.3f} ms"
    )
    print(f"constraint violations: {result.metrics['constraint_violations']}")
    return _design_analysis(args, sim)


def _design_analysis(args: argparse.Namespace, sim) -> int:
    """``design``: poles, structure, margins, linear step metrics; ``--report`` and ``--tradeoff``."""
    from shinro_ctrl.analysis import analyze_controller

    plant = sim.plant
    tracked = [plant.state_names[i] for i in sim.tracked]
    analysis = analyze_controller(
        sim.controller,
        x_init=sim.initial_state,
        measured=tracked,
        tracked=tracked,
        state_names=plant.state_names,
        input_names=plant.input_names,
    )
    if args.kind == "mpc":
        print("linear analysis of the unconstrained first move (finite-horizon Riccati gain):")
    print(analysis.format())
    if args.report:
        from shinro_ctrl.analysis.report import write_report
        from shinro_ctrl.sim import RobotSim

        run = RobotSim(sim.scenario, engine="standalone").run()
        path = write_report(
            args.report,
            analysis,
            title=f"{sim.scenario.name}: {type(plant).__name__} + {type(sim.controller).__name__}",
            nonlinear=(run.t, run.x, run.u),
            x_ref=run.ref,
            u_min=run.u_min,
            u_max=run.u_max,
            description=repr(plant),
        )
        print(f"report: {path}")
    if args.tradeoff:
        from shinro_ctrl.tradeoff import parse_tradeoff, run_tradeoff

        key, lo, hi = parse_tradeoff(args.tradeoff)
        result = run_tradeoff(
            args.config, key, lo, hi, points=args.points, engine=args.engine, out=args.out, workers=args.workers
        )
        print(result.summary())
    return 0


# -------------------------------------------------------------------- regress
def cmd_regress(args: argparse.Namespace) -> int:
    from shinro_ctrl.regression import format_report, run_regression

    report = run_regression(args.dir, update=args.update)
    print(format_report(report))
    where = report.folder if report.folder is not None else "DIR"
    if report.passed or (args.update and not report.errors):
        return 0
    for c in report.failures:
        print(f"regression: {c.scenario}: {c.metric} = {c.now:.6g}, baseline {c.baseline}", file=sys.stderr)
    for label in report.missing:
        print(f"regression: {label}: no baseline (shinro-ctrl regress {where} --update)", file=sys.stderr)
    for label, message in report.errors.items():
        print(f"regression: {label}: {message}", file=sys.stderr)
    return 1


# ---------------------------------------------------------------------- sweep
def cmd_sweep(args: argparse.Namespace) -> int:
    from pathlib import Path

    from shinro_ctrl.files import atomic_folder, check_output_folder
    from shinro_ctrl.resources import config_path
    from shinro_ctrl.sweep import parse_params, run_sweep

    _check_count("--samples", args.samples, MAX_SAMPLES)
    _check_count("--workers", args.workers, MAX_WORKERS)
    if args.seed < 0:
        raise InvalidArgument(f"--seed must be a non-negative integer, got {args.seed}")
    if args.stable_tol is not None and not (math.isfinite(args.stable_tol) and args.stable_tol > 0):
        raise InvalidArgument(f"--stable-tol must be a positive finite number, got {args.stable_tol:g}")
    params = parse_params(args.param)
    check_output_folder(args.out, SWEEP_FILES, inputs=[config_path(args.config)])
    if args.scheduler:
        _check_scheduler(args.scheduler)
    out = Path(args.out)
    with atomic_folder(out, SWEEP_FILES) as staging:  # the three files of one sweep, or the previous ones
        result = run_sweep(
            args.config,
            params,
            samples=args.samples,
            grid=args.grid,
            workers=args.workers,
            seed=args.seed,
            out=staging,
            scheduler=args.scheduler,
            engine=args.engine,
            method=args.method,
            stable_tol=args.stable_tol,
            metric=args.metric,
        )
    result.files = {k: out / Path(v).name for k, v in result.files.items()}
    print(result.summary())
    if args.workers > 1 and result.workers != args.workers:
        print(
            f"note: --workers {args.workers} asked for, but the '{result.method}' executor ran in one process "
            f"(--method {args.method} picks the vectorized batch path for standalone loops, which is faster than "
            "worker processes); pass --method pool to use worker processes"
        )
    return 0


# ----------------------------------------------------------------------- list
def cmd_list(args: argparse.Namespace) -> int:
    from shinro_ctrl.controllers import CONTROLLERS
    from shinro_ctrl.plants import PLANT_ALIASES, PLANTS
    from shinro_ctrl.resources import list_configs

    alias = {v: k for k, v in PLANT_ALIASES.items()}
    print("plants:")
    for name, cls in PLANTS.items():
        doc = (cls.__doc__ or "").strip().splitlines()[0]
        print(f"  {name:22s} {alias.get(name, ''):16s} {doc}")
    print("controllers:")
    for name in CONTROLLERS:
        print(f"  {name}")
    print("scenarios:")
    for name in list_configs():
        print(f"  {name}")
    return 0


# --------------------------------------------------------------------- parser
def build_parser() -> argparse.ArgumentParser:
    from shinro_ctrl.plants import PLANT_ALIASES

    parser = _Parser(prog="shinro-ctrl", description="Model-based control design workbench.")
    parser.add_argument("--debug", action="store_true", help="show tracebacks for every error")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)

    p = sub.add_parser("linearize", help="exact (CasADi) and finite-difference Jacobians side by side")
    p.add_argument("plant", metavar="PLANT", help=f"one of: {', '.join(PLANT_ALIASES)}; or an MJCF/URDF model file")
    p.add_argument("--x0", help="operating state, e.g. '0,0,0.1,0' (pi allowed: 'pi,pi,0,0')")
    p.add_argument("--u0", help="operating input, e.g. '0'")
    p.add_argument("--eps", type=float, default=1e-6, help="finite-difference step (default 1e-6)")
    p.add_argument("--eps-sweep", action="store_true", help="FD error against the step size (complex-step reference)")
    p.add_argument("--plot", metavar="PNG", help="with --eps-sweep: plot the V-shaped error curve")
    p.set_defaults(func=cmd_linearize)

    p = sub.add_parser("crosscheck", help="exact vs finite differences vs MuJoCo's mjd_transitionFD")
    p.add_argument(
        "plant",
        metavar="PLANT",
        help=f"one of: {', '.join(CROSSCHECK_PLANTS)}; an MJCF/URDF model file; or a scenario file (its plant)",
    )
    p.add_argument("--x0", help="operating state (pi allowed)")
    p.add_argument("--u0", help="operating input")
    p.add_argument("--eps", type=float, default=1e-6, help="finite-difference step (default 1e-6)")
    p.add_argument("--plot", metavar="PNG", help="draw the exact / FD / MuJoCo comparison")
    p.set_defaults(func=cmd_crosscheck)

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

    p = sub.add_parser("design", help="design a controller from a scenario and print it")
    p.add_argument("kind", choices=("lqr", "mpc"))
    p.add_argument("config", metavar="CONFIG")
    p.add_argument("--report", metavar="FILE.html", help="write a self-contained HTML design report (plots embedded)")
    p.add_argument("--tradeoff", metavar="KEY=LO:HI", help="LQR weight trade-off, e.g. R=1e-3:1e2 or Q[2]=1:1000")
    p.add_argument("--points", type=int, default=20, metavar="N", help="trade-off points, log-spaced (default 20)")
    p.add_argument("--engine", choices=("standalone", "mujoco"), help="trade-off: loop of the nonlinear runs")
    p.add_argument("--out", metavar="DIR", help="trade-off: write tradeoff.csv, tradeoff.json, tradeoff.png here")
    p.add_argument("--workers", type=int, default=2, metavar="W", help="trade-off: worker processes (default 2)")
    p.set_defaults(func=cmd_design)

    p = sub.add_parser("regress", help="run regression scenarios and compare with their baselines")
    p.add_argument(
        "dir", nargs="?", metavar="DIR", help="folder of scenarios or one scenario file (default: the shipped set)"
    )
    p.add_argument(
        "--update", action="store_true", help="rewrite the baselines as one set (the shipped ones only if DIR is named)"
    )
    p.set_defaults(func=cmd_regress)

    p = sub.add_parser("sweep", help="robustness sweep: the nominal controller on perturbed plants")
    p.add_argument("config", metavar="CONFIG", help="scenario file or shipped name")
    p.add_argument("--param", action="append", required=True, metavar="KEY=LO:HI", help="e.g. plant.pole_mass=0.05:0.5")
    p.add_argument("--samples", type=int, default=16, metavar="N", help="Monte-Carlo samples, or points per parameter")
    p.add_argument("--grid", action="store_true", help="full grid of N points per parameter instead of random samples")
    p.add_argument("--workers", type=int, default=1, metavar="W", help="local worker processes (default 1)")
    p.add_argument("--seed", type=int, default=0, metavar="S", help="seed of the parameter draws (default 0)")
    p.add_argument("--out", required=True, metavar="DIR", help="write sweep.csv, sweep.json and sweep.png here")
    p.add_argument("--scheduler", metavar="ADDRESS", help="run on a Dask cluster (dask.distributed scheduler address)")
    p.add_argument("--engine", choices=("standalone", "mujoco"), help="override the scenario's loop")
    p.add_argument("--method", choices=("auto", "pool", "dask", "batch", "serial"), default="auto")
    p.add_argument("--stable-tol", type=float, metavar="E", help="final-error bound (default 10 x settle_tol)")
    p.add_argument("--metric", default="rms_error", help="metric to plot (default rms_error)")
    p.set_defaults(func=cmd_sweep)

    p = sub.add_parser("list", help="plants, controllers and shipped scenarios")
    p.set_defaults(func=cmd_list)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``shinro-ctrl``; returns the exit status."""
    argv = list(sys.argv[1:] if argv is None else argv)
    import os

    os.environ.setdefault("MPLBACKEND", "Agg")  # the CLI writes files only; the library never picks a backend
    debug = "--debug" in argv
    if debug:  # accepted anywhere on the line, before or after the subcommand
        argv = ["--debug", *(a for a in argv if a != "--debug")]
    import warnings

    # Warnings are held back until the command's outcome is known: a failing command prints its one error line
    # alone (a warning about a huge dt before "error: ..." misleads), a successful one prints them at the end.
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("default")
        try:
            parser = build_parser()
            args = parser.parse_args(_join_negative_values(parser, argv))
            if not getattr(args, "command", None):
                parser.print_help()
                return 0
            status = int(args.func(args) or 0)
            sys.stdout.flush()
        except _UsageError as exc:
            print(f"error: {exc}", file=sys.stderr)
            return EXIT_USER_ERROR
        except BrokenPipeError:  # `shinro-ctrl ... | head`: the reader left; exit quietly
            _silence_stdout()
            return 141
        except _USER_ERRORS + _NUMERIC_ERRORS as exc:
            if debug:
                raise
            print(f"error: {_one_line(exc)}", file=sys.stderr)
            return EXIT_USER_ERROR
        except KeyboardInterrupt:
            print("interrupted", file=sys.stderr)
            return 130
        except Exception as exc:
            if _caused_by_interrupt(exc):  # Ctrl-C inside an import or a C extension, re-raised as another error
                print("interrupted", file=sys.stderr)
                return 130
            raise
    for w in caught:
        print(f"warning: {w.message}", file=sys.stderr)
    return status


_NUMERIC_ERRORS = (OverflowError, FloatingPointError, RecursionError, MemoryError)


def _caused_by_interrupt(exc: BaseException) -> bool:
    seen = set()
    while exc is not None and id(exc) not in seen:
        if isinstance(exc, KeyboardInterrupt):
            return True
        seen.add(id(exc))
        exc = exc.__cause__ or exc.__context__
    return False


def _one_line(exc: BaseException) -> str:
    msg = str(exc).strip().splitlines()[0] if str(exc).strip() else ""
    if isinstance(exc, KeyError) and msg.startswith(("'", '"')):
        msg = msg[1:-1]
    if isinstance(exc, _NUMERIC_ERRORS) and not isinstance(exc, ShinroError):  # ours already say what overflowed
        what = {
            RecursionError: "input nested too deeply",
            MemoryError: "out of memory (reduce the problem size)",
        }.get(type(exc), "numeric overflow (a value too large for float64)")
        return f"{what}: {msg}" if msg else what
    return msg or type(exc).__name__


def _silence_stdout() -> None:
    import os

    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
    except (OSError, ValueError):
        pass


def _looks_like_value(token: str) -> bool:
    """A token starting with '-' that is a (vector of) number(s), not an option: '-0.1,0', '-pi,0', '-1e-3'."""
    if not token.startswith("-") or token.startswith("--"):
        return False
    try:
        parse_vector(token)
    except InvalidArgument:
        return False
    return True


def _join_negative_values(parser: argparse.ArgumentParser, argv: list[str]) -> list[str]:
    """``--x0 -0.1,0`` → ``--x0=-0.1,0``: argparse takes a value starting with '-' for an option."""
    takes_value = set()
    subparsers = [parser]
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            subparsers.extend(action.choices.values())
    for p in subparsers:
        for action in p._actions:
            if action.option_strings and action.nargs is None:  # an option that takes one value
                takes_value.update(action.option_strings)
    out: list[str] = []
    i = 0
    while i < len(argv):
        token = argv[i]
        if token in takes_value and i + 1 < len(argv) and _looks_like_value(argv[i + 1]):
            out.append(f"{token}={argv[i + 1]}")
            i += 2
            continue
        out.append(token)
        i += 1
    return out


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
