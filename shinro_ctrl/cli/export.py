"""The ``export`` command: a scenario's controller and estimator as verified, dependency-free C."""

from __future__ import annotations

import argparse

from shinro_ctrl.cli.common import path_arg

__all__ = ["cmd_export", "register"]


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``export`` to the ``shinro-ctrl`` parser (``sub``: its subparsers)."""
    p = sub.add_parser(
        "export",
        help="export the scenario's controller and estimator as C99 (built and verified against Python)",
    )
    p.add_argument("config", metavar="CONFIG", help="scenario file or shipped name")
    p.add_argument("--out", type=path_arg, metavar="DIR", required=True, help="the folder to write")
    p.add_argument("--name", metavar="NAME", help="C name of the API (default: the scenario's file stem)")
    p.add_argument(
        "--no-verify", action="store_true", help="write the folder without building it and replaying the recording"
    )
    p.set_defaults(func=cmd_export)


def cmd_export(args: argparse.Namespace) -> int:
    """Record, write, build, replay; print the agreement and the C and Python step times."""
    from shinro_ctrl.export.pipeline import export_scenario

    rep = export_scenario(args.config, args.out, name=args.name, verify=not args.no_verify)
    runs = ", ".join(f"{k} {v}" for k, v in rep.steps.items())
    print(f"exported {rep.name} to {rep.out} ({len(rep.files)} files)")
    print(f"recorded {sum(rep.steps.values())} closed-loop steps ({runs}); {rep.clamped_steps} with a bound active")
    if rep.build is None:
        print("not verified (--no-verify): run 'make check' in the folder")
    else:
        b = rep.build
        print(
            f"verified: C equals Python on {b.steps} steps, max relative error {b.max_rel_err:.2e} "
            f"(tolerance 1e-9); controller objects use no heap"
        )
        c = f"{b.c_step_ns / 1e3:.3f} µs" if b.c_step_ns is not None else "not timed"
        print(f"step time (median): C {c}, Python {rep.python_step_s * 1e6:.2f} µs (estimator + controller)")
    return 0
