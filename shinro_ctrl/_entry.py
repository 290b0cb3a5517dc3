"""The ``shinro-ctrl`` console script (and ``python -m shinro_ctrl.cli``): Ctrl-C handling first, then the CLI.

Every Ctrl-C ends the command with the status 130 and the one line ``interrupted``, never a traceback and never
death by the signal:

- while the command line imports NumPy, CasADi or MuJoCo (a second or two at start-up) — this module imports
  nothing but the standard library until the handler is in place;
- after the command, while Python shuts down: CPython restores SIGINT's default action during finalization (a
  Ctrl-C then killed the process by SIGINT, status −2, nothing printed). SIGINT is ignored from the moment the
  command's status is known; the command has finished by then and its status stands;
- after an interrupt inside an extension module's import (MuJoCo's runs Python code through ``PyRun_String``):
  CPython then keeps its "unhandled KeyboardInterrupt" flag set although the exception was handled, and
  ``python -m`` re-killed the process by SIGINT after its clean exit 130. Running any code through
  ``PyRun_SimpleString`` resets that flag (CPython resets it before every such evaluation), so an interrupted
  command does that before it exits, with Python's normal shutdown (pool semaphores released, files flushed).
"""

from __future__ import annotations

import sys
from collections.abc import Sequence
from typing import NoReturn

from shinro_ctrl._interrupts import caused_by_interrupt

__all__ = ["main"]

EXIT_INTERRUPTED = 130


def main(argv: Sequence[str] | None = None) -> NoReturn:
    """Run ``shinro-ctrl`` (see :func:`shinro_ctrl.cli.main`); exits with its status."""
    try:
        try:
            from shinro_ctrl.cli import main as cli_main
        except BaseException as exc:
            if not caused_by_interrupt(exc):
                raise
            raise KeyboardInterrupt from None
        status = cli_main(argv)  # prints "interrupted" and returns 130 for an interrupt inside the command
    except KeyboardInterrupt:  # during the imports, or between them and the command's own handling
        print("interrupted", file=sys.stderr)
        status = EXIT_INTERRUPTED
    _exit(status)


def _exit(status: int) -> NoReturn:
    """Leave with ``status``, Ctrl-C ignored from now on (see the module docstring)."""
    import signal
    import threading

    if threading.current_thread() is threading.main_thread():
        try:
            signal.signal(signal.SIGINT, signal.SIG_IGN)
        except KeyboardInterrupt:  # arrived just before: the command has ended all the same
            signal.signal(signal.SIGINT, signal.SIG_IGN)
    if status == EXIT_INTERRUPTED:
        _reset_unhandled_interrupt_flag()
    sys.exit(status)


def _reset_unhandled_interrupt_flag() -> None:
    """Clear CPython's stale "unhandled KeyboardInterrupt" flag (see the module docstring); a no-op elsewhere."""
    try:
        import ctypes

        ctypes.pythonapi.PyRun_SimpleString(b"")
    except (ImportError, AttributeError, OSError):  # not CPython, or no ctypes
        pass


if __name__ == "__main__":  # pragma: no cover
    main()
