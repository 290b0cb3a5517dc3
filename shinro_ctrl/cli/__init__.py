"""The ``shinro-ctrl`` command.

Each subcommand is a function ``cmd_<name>(args) -> int`` registered in
:func:`build_parser`. User errors (our :class:`ShinroError` family, a missing
file, a bad value) print one line on stderr and exit with status 2; anything
else is a bug and shows its traceback. ``--debug`` shows tracebacks always.

The commands live by group in :mod:`~shinro_ctrl.cli.models` (``linearize``,
``crosscheck``, ``list``), :mod:`~shinro_ctrl.cli.run` (``run``, ``plan``),
:mod:`~shinro_ctrl.cli.design` and :mod:`~shinro_ctrl.cli.sets` (``regress``,
``sweep``); :mod:`~shinro_ctrl.cli.common` holds the parser class, number
parsing, argument and output checks and the one-line error report. This
module wires them: the parser and :func:`main`.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from shinro_ctrl.cli.common import (
    _NUMERIC_ERRORS,
    _USER_ERRORS,
    CROSSCHECK_PLANTS,
    EXIT_USER_ERROR,
    _caused_by_interrupt,
    _join_negative_values,
    _one_line,
    _Parser,
    _silence_stdout,
    _UsageError,
)

# re-exported (``X as X``): the public names of the former single module
from shinro_ctrl.cli.common import parse_number as parse_number
from shinro_ctrl.cli.common import parse_vector as parse_vector
from shinro_ctrl.cli.common import side_by_side as side_by_side
from shinro_ctrl.cli.design import cmd_design
from shinro_ctrl.cli.models import cmd_crosscheck, cmd_linearize, cmd_list
from shinro_ctrl.cli.run import DEFAULT_SCENARIO as DEFAULT_SCENARIO
from shinro_ctrl.cli.run import cmd_plan, cmd_run
from shinro_ctrl.cli.run import format_metric_comparison as format_metric_comparison
from shinro_ctrl.cli.sets import cmd_regress, cmd_sweep

__all__ = ["main"]


# --------------------------------------------------------------------- parser
def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="shinro-ctrl", description="Model-based control design workbench.")
    parser.add_argument("--debug", action="store_true", help="show tracebacks for every error")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    _add_model_commands(sub)
    _add_run_commands(sub)
    _add_design_command(sub)
    _add_batch_commands(sub)
    p = sub.add_parser("list", help="plants, controllers and shipped scenarios")
    p.set_defaults(func=cmd_list)
    return parser


def _add_model_commands(sub: argparse._SubParsersAction) -> None:
    """``linearize`` and ``crosscheck``."""
    from shinro_ctrl.plants import PLANT_ALIASES

    p = sub.add_parser("linearize", help="exact (CasADi) and finite-difference Jacobians side by side")
    p.add_argument(
        "plant",
        metavar="PLANT",
        help=f"one of: {', '.join(PLANT_ALIASES)}; an MJCF/URDF file; or a scenario file or name (its plant)",
    )
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
        help=f"one of: {', '.join(CROSSCHECK_PLANTS)}; an MJCF/URDF file; or a scenario file or name (its plant)",
    )
    p.add_argument("--x0", help="operating state (pi allowed)")
    p.add_argument("--u0", help="operating input")
    p.add_argument("--eps", type=float, default=1e-6, help="finite-difference step (default 1e-6)")
    p.add_argument("--plot", metavar="PNG", help="draw the exact / FD / MuJoCo comparison")
    p.set_defaults(func=cmd_crosscheck)


def _add_run_commands(sub: argparse._SubParsersAction) -> None:
    """``run`` and ``plan``."""
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


def _add_design_command(sub: argparse._SubParsersAction) -> None:
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


def _add_batch_commands(sub: argparse._SubParsersAction) -> None:
    """``regress`` and ``sweep``."""
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


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
