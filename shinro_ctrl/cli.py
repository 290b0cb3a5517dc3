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


# ------------------------------------------------------------------ linearize
def cmd_linearize(args: argparse.Namespace) -> int:
    from shinro_ctrl.linearization import compare
    from shinro_ctrl.plants import plant_class

    plant = plant_class(args.plant)()
    x0 = None if args.x0 is None else parse_vector(args.x0)
    u0 = None if args.u0 is None else parse_vector(args.u0)
    cmp = compare(plant, x0, u0, eps=args.eps)
    xe, ue = plant._operating_point(x0, u0)
    print(f"{type(plant).__name__}: continuous-time Jacobians at")
    print(f"  x0 = {dict(zip(plant.state_names, np.round(xe, 6).tolist(), strict=True))}")
    print(f"  u0 = {dict(zip(plant.input_names, np.round(ue, 6).tolist(), strict=True))}")
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

    plant = plant_class(args.plant)()
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

    if args.video:  # before mujoco is imported: it reads MUJOCO_GL once
        from shinro_ctrl.video import prepare_video

        prepare_video(args.video)
    from shinro_ctrl.resources import shipped_config
    from shinro_ctrl.sim import RobotSim, format_metrics

    # The embedded default is the shipped file, never a same-named one in the current directory.
    sim = RobotSim.from_config(args.config or shipped_config(DEFAULT_SCENARIO), engine=args.engine)
    label = f"{sim.scenario.name} ({sim.loop})"
    print(f"running {label}: {type(sim.plant).__name__} + {type(sim.controller).__name__}, ", end="")
    print(f"{args.duration if args.duration is not None else sim.scenario.sim.duration:g} s at dt = {sim.plant.dt:g} s")
    result = sim.run(args.duration)
    print(format_metrics(result.metrics))
    if args.out:
        out = result.save(args.out)
        plot = result.plot(args.plot or out / "run.png")
        print(f"saved result.npz, metrics.json, scenario.toml to {out}")
    else:
        plot = result.plot(args.plot or Path("out") / f"{sim.scenario.name}_{sim.loop}.png")
    print(f"plot: {plot}")
    if args.video:
        from shinro_ctrl.video import render_rollout

        video = render_rollout(sim, result, args.video)
        print(f"video: {video.path} ({video.frames} frames, {video.ms_per_frame:.0f} ms/frame)")
    return 0


# --------------------------------------------------------------------- design
def cmd_design(args: argparse.Namespace) -> int:
    from shinro_ctrl.sim import RobotSim

    sim = RobotSim.from_config(args.config)  # the scenario's own loop: a bad [engine] table is reported too
    ctrl = sim.controller
    kind = {"lqr": "LQR", "mpc": "LinearMPC"}[args.kind]
    if type(ctrl).__name__ != kind:
        raise InvalidArgument(f"{args.config} configures a {type(ctrl).__name__} controller, not {kind}")
    np.set_printoptions(precision=5, suppress=True, linewidth=120)
    if args.kind == "lqr":
        model = getattr(ctrl, "model", None)
        if model is not None:
            print(
                f"model: {model.discretization} discretization of the {model.method} linearization, dt = {model.dt:g} s"
            )
        print("K =")
        print(ctrl.K)
        print("closed-loop poles:")
        for p in ctrl.poles:
            print(f"  {p.real:+.6f} {p.imag:+.6f}j   |p| = {abs(p):.6f}")
        x_init = sim.initial_state
        print(f"predicted cost ½ x0ᵀ S x0 from {np.round(x_init, 6).tolist()}: {ctrl.cost_to_go(x_init):.6g}")
        return 0
    print(ctrl.describe())
    result = sim.run(min(sim.scenario.sim.duration, 2.0))
    solve = result.solve_times
    print(
        f"closed loop ({len(solve)} steps, {sim.loop}): median call {1e3 * np.median(solve):.3f} ms, "
        f"p95 {1e3 * np.percentile(solve, 95):.3f} ms, max {1e3 * solve.max():.3f} ms"
    )
    print(f"constraint violations: {result.metrics['constraint_violations']}")
    return 0


# -------------------------------------------------------------------- regress
def cmd_regress(args: argparse.Namespace) -> int:
    from shinro_ctrl.regression import format_report, run_regression

    report = run_regression(args.dir, update=args.update)
    print(format_report(report))
    if report.passed or (args.update and not report.errors):
        return 0
    for c in report.failures:
        print(f"regression: {c.scenario}: {c.metric} = {c.now:.6g}, baseline {c.baseline}", file=sys.stderr)
    for label in report.missing:
        print(f"regression: {label}: no baseline", file=sys.stderr)
    for label, message in report.errors.items():
        print(f"regression: {label}: {message}", file=sys.stderr)
    return 1


# ---------------------------------------------------------------------- sweep
def cmd_sweep(args: argparse.Namespace) -> int:
    from shinro_ctrl.sweep import parse_params, run_sweep

    result = run_sweep(
        args.config,
        parse_params(args.param),
        samples=args.samples,
        grid=args.grid,
        workers=args.workers,
        seed=args.seed,
        out=args.out,
        scheduler=args.scheduler,
        engine=args.engine,
        method=args.method,
        stable_tol=args.stable_tol,
        metric=args.metric,
    )
    print(result.summary())
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
    p.add_argument("plant", metavar="PLANT", help=f"one of: {', '.join(PLANT_ALIASES)}")
    p.add_argument("--x0", help="operating state, e.g. '0,0,0.1,0' (pi allowed: 'pi,pi,0,0')")
    p.add_argument("--u0", help="operating input, e.g. '0'")
    p.add_argument("--eps", type=float, default=1e-6, help="finite-difference step (default 1e-6)")
    p.add_argument("--eps-sweep", action="store_true", help="FD error against the step size (complex-step reference)")
    p.add_argument("--plot", metavar="PNG", help="with --eps-sweep: plot the V-shaped error curve")
    p.set_defaults(func=cmd_linearize)

    p = sub.add_parser("crosscheck", help="exact vs finite differences vs MuJoCo's mjd_transitionFD")
    p.add_argument("plant", metavar="PLANT", help=f"one of: {', '.join(PLANT_ALIASES)}")
    p.add_argument("--x0", help="operating state (pi allowed)")
    p.add_argument("--u0", help="operating input")
    p.add_argument("--eps", type=float, default=1e-6, help="finite-difference step (default 1e-6)")
    p.add_argument("--plot", metavar="PNG", help="draw the exact / FD / MuJoCo comparison")
    p.set_defaults(func=cmd_crosscheck)

    p = sub.add_parser("run", help="run a scenario (default: the embedded cart-pole LQR demo)")
    p.add_argument("config", nargs="?", metavar="CONFIG", help="scenario file or shipped name")
    p.add_argument("--engine", choices=("standalone", "mujoco"), help="override the scenario's loop")
    p.add_argument("--duration", type=float, metavar="S", help="simulated seconds (default: the scenario's)")
    p.add_argument("--plot", metavar="PNG", help="where to write the plot")
    p.add_argument("--out", metavar="DIR", help="save result.npz, metrics.json, scenario.toml and run.png")
    p.add_argument("--video", metavar="PATH", help="render the run offscreen with MuJoCo: .gif, or .mp4 with ffmpeg")
    p.set_defaults(func=cmd_run)

    p = sub.add_parser("design", help="design a controller from a scenario and print it")
    p.add_argument("kind", choices=("lqr", "mpc"))
    p.add_argument("config", metavar="CONFIG")
    p.set_defaults(func=cmd_design)

    p = sub.add_parser("regress", help="run regression scenarios and compare with their baselines")
    p.add_argument("dir", nargs="?", metavar="DIR", help="folder of scenarios (default: the shipped regression set)")
    p.add_argument("--update", action="store_true", help="rewrite the baselines (atomically)")
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
    debug = "--debug" in argv
    if debug:  # accepted anywhere on the line, before or after the subcommand
        argv = ["--debug", *(a for a in argv if a != "--debug")]
    try:
        parser = build_parser()
        args = parser.parse_args(argv)
        if not getattr(args, "command", None):
            parser.print_help()
            return 0
        return int(args.func(args) or 0)
    except _UsageError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return EXIT_USER_ERROR
    except _USER_ERRORS as exc:
        if debug:
            raise
        msg = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        if isinstance(exc, KeyError) and msg.startswith(("'", '"')):
            msg = msg[1:-1]
        print(f"error: {msg}", file=sys.stderr)
        return EXIT_USER_ERROR
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
