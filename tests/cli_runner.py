"""The ``shinro-ctrl`` command run in the test process: what a subprocess shows, without a fresh interpreter.

A ``python -m shinro_ctrl.cli`` subprocess spends about a second importing NumPy, CasADi, MuJoCo and Matplotlib
before the command starts; most CLI tests check what a command prints, writes and returns, which
:func:`shinro_ctrl.cli.main` does the same in process. :func:`cli` runs it there and returns the same
``CompletedProcess`` a subprocess gives (status, stdout, stderr; an unexpected exception becomes its traceback
on stderr and status 1, as the interpreter would report it). Tests of the process itself (signals, the entry
point, broken pipes, killed workers, a child's environment) keep a real subprocess.
"""

from __future__ import annotations

import contextlib
import io
import os
import subprocess
import sys
import traceback
from pathlib import Path

from shinro_ctrl.cli import main

__all__ = ["cli"]


def cli(*args: str, cwd: str | Path | None = None) -> subprocess.CompletedProcess:
    """Run ``shinro-ctrl ARGS`` in this process (in ``cwd`` when given); its status, stdout and stderr."""
    out, err = io.StringIO(), io.StringIO()
    here = os.getcwd()
    try:
        if cwd is not None:
            os.chdir(cwd)
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            try:
                status = main(list(args))
            except SystemExit as exc:  # argparse's --help and usage errors
                code = exc.code
                status = code if isinstance(code, int) else (0 if code is None else 1)
                if code is not None and not isinstance(code, int):
                    print(code, file=sys.stderr)
            except Exception:  # a bug: the interpreter would print the traceback and exit 1
                traceback.print_exc(file=sys.stderr)
                status = 1
    finally:
        os.chdir(here)
    return subprocess.CompletedProcess(["shinro-ctrl", *args], status, out.getvalue(), err.getvalue())
