"""The ``shinro-ctrl`` command.

Each subcommand is a function ``cmd_<name>(args) -> int`` beside the
``register(subparsers)`` that adds its parser, in its command module;
:data:`COMMANDS` lists the modules' ``register`` and :func:`build_parser`
calls each (:func:`add_command` adds another). User errors (our
:class:`ShinroError` family, a missing file, a bad value) print one line on
stderr and exit with status 2; anything else is a bug and shows its traceback. ``--debug`` shows tracebacks always.

The commands live by group in :mod:`~shinro_ctrl.cli.models` (``linearize``,
``crosscheck``, ``list``), :mod:`~shinro_ctrl.cli.run` (``run``, ``plan``),
:mod:`~shinro_ctrl.cli.design` and :mod:`~shinro_ctrl.cli.sets` (``regress``,
``sweep``); :mod:`~shinro_ctrl.cli.common` holds the parser class, number
parsing, argument and output checks and the one-line error report. This
module wires them: the list of commands and :func:`main`.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable, Sequence

from shinro_ctrl.cli import design, identify, models, run, sets
from shinro_ctrl.cli.common import (
    _NUMERIC_ERRORS,
    _USER_ERRORS,
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
from shinro_ctrl.cli.run import DEFAULT_SCENARIO as DEFAULT_SCENARIO
from shinro_ctrl.cli.run import format_metric_comparison as format_metric_comparison

__all__ = ["COMMANDS", "add_command", "build_parser", "main"]


# --------------------------------------------------------------------- parser
#: The ``register(subparsers)`` of each command module, in the order of the help; :func:`add_command` adds one.
COMMANDS: list[Callable[[argparse._SubParsersAction], None]] = [
    models.register,  # linearize, crosscheck, list
    run.register,  # run, plan
    design.register,  # design
    sets.register,  # regress, sweep
    identify.register,  # identify
]


def add_command(register: Callable[[argparse._SubParsersAction], None]) -> None:
    """Add a command: ``register(subparsers)`` adds its parser and ``set_defaults(func=handler)``.

    The handler takes the parsed ``argparse.Namespace`` and returns the exit status; it reports a user
    error by raising one of our errors (:mod:`shinro_ctrl.errors`), which :func:`main` prints as one line
    with exit status 2.
    """
    if register not in COMMANDS:
        COMMANDS.append(register)


def build_parser() -> argparse.ArgumentParser:
    """The ``shinro-ctrl`` parser: each module in :data:`COMMANDS` registers its own commands."""
    parser = _Parser(prog="shinro-ctrl", description="Model-based control design workbench.")
    parser.add_argument("--debug", action="store_true", help="show tracebacks for every error")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    for register in COMMANDS:
        register(sub)
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


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
