"""Commands that run sets of scenarios: ``regress`` and ``sweep``."""

from __future__ import annotations

import argparse
import math
import sys

from shinro_ctrl.cli.common import MAX_SAMPLES, MAX_WORKERS, SWEEP_FILES, _check_count, _check_scheduler
from shinro_ctrl.errors import InvalidArgument

__all__ = ["cmd_regress", "cmd_sweep"]


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
    params = parse_params(args.param)
    check_output_folder(args.out, SWEEP_FILES, inputs=[config_path(args.config)])
    if args.scheduler:
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
