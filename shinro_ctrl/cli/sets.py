"""Commands that run sets of scenarios: ``regress`` and ``sweep``."""

from __future__ import annotations

import argparse
import math
import sys

from shinro_ctrl.cli.common import (
    MAX_SAMPLES,
    MAX_WORKERS,
    SWEEP_FILES,
    _check_count,
    _check_scheduler,
    _check_scheduler_address,
    path_arg,
)
from shinro_ctrl.errors import InvalidArgument

__all__ = ["cmd_regress", "cmd_sweep", "register"]


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``regress`` and ``sweep`` to the ``shinro-ctrl`` parser (``sub``: its subparsers)."""
    p = sub.add_parser("regress", help="run regression scenarios and compare with their baselines")
    p.add_argument(
        "dir",
        nargs="?",
        type=path_arg,
        metavar="DIR",
        help="folder of scenarios or one scenario file (default: the shipped set)",
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
    p.add_argument(
        "--out", required=True, type=path_arg, metavar="DIR", help="write sweep.csv, sweep.json and sweep.png here"
    )
    p.add_argument("--scheduler", metavar="ADDRESS", help="run on a Dask cluster (dask.distributed scheduler address)")
    p.add_argument("--engine", choices=("standalone", "mujoco"), help="override the scenario's loop")
    p.add_argument("--method", choices=("auto", "pool", "dask", "batch", "serial"), default="auto")
    p.add_argument("--stable-tol", type=float, metavar="E", help="final-error bound (default 10 x settle_tol)")
    p.add_argument("--metric", default="rms_error", help="metric to plot (default rms_error)")
    p.set_defaults(func=cmd_sweep)


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

    from shinro_ctrl.files import check_output_folder
    from shinro_ctrl.resources import config_path
    from shinro_ctrl.sweep import parse_params, run_sweep

    _check_count("--samples", args.samples, MAX_SAMPLES)
    _check_count("--workers", args.workers, MAX_WORKERS)
    if args.seed < 0:
        raise InvalidArgument(f"--seed must be a non-negative integer, got {args.seed}")
    if args.stable_tol is not None and not (math.isfinite(args.stable_tol) and args.stable_tol > 0):
        raise InvalidArgument(f"--stable-tol must be a positive finite number, got {args.stable_tol:g}")
    if args.scheduler is not None:  # an empty address too (an unset shell variable), never taken for "none"
        _check_scheduler_address(args.scheduler)
    params = parse_params(args.param)
    check_output_folder(args.out, SWEEP_FILES, inputs=[config_path(args.config)], what="--out folder")
    if args.scheduler is not None:
        _check_scheduler(args.scheduler)
    result = run_sweep(  # writes the three files of one sweep as one set (or leaves the previous ones)
        args.config,
        params,
        samples=args.samples,
        grid=args.grid,
        workers=args.workers,
        seed=args.seed,
        out=Path(args.out),
        scheduler=args.scheduler,
        engine=args.engine,
        method=args.method,
        stable_tol=args.stable_tol,
        metric=args.metric,
    )
    print(result.summary())
    if args.workers > 1 and result.workers != args.workers:
        print(
            f"note: --workers {args.workers} asked for, but the '{result.method}' executor ran in one process "
            f"(--method {args.method} picks the vectorized batch path for standalone loops, which is faster than "
            "worker processes); pass --method pool to use worker processes"
        )
    return 0
