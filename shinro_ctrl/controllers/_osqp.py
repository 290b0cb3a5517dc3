"""OSQP set-up with the C library's printed errors turned into our exception.

OSQP validates its data and settings in C and, on failure, prints the reason
(``ERROR in validate_settings: eps_abs must be nonnegative``) to standard
output before the Python wrapper raises a bare ``OSQPException(2)``.
:func:`setup_solver` runs ``solver.setup(...)`` with file descriptor 1
redirected into a temporary file and ``sys.stdout`` replaced by a buffer (the
osqp wheels print through Python's ``sys.stdout``; a C build may ``printf``
to fd 1) and, when the set-up fails, raises
:class:`~shinro_ctrl.errors.InvalidArgument` quoting the first line OSQP
printed; nothing reaches the terminal. Whatever else was written meanwhile
(OSQP's banner with ``verbose=True``, another thread's output) is written back
afterwards, so only OSQP's ``ERROR in ...`` lines are withheld.
"""

from __future__ import annotations

import ctypes
import io
import os
import sys
import tempfile
import threading
from typing import Any

import osqp

from shinro_ctrl.errors import InvalidArgument

__all__ = ["setup_solver"]

_LOCK = threading.Lock()  # fd 1 is process-wide: one redirected set-up at a time


def _c_fflush() -> Any:
    try:
        fflush = ctypes.CDLL(None).fflush
    except (OSError, AttributeError, TypeError):  # pragma: no cover - no C runtime by that name (Windows)
        return lambda: None
    fflush.argtypes = [ctypes.c_void_p]
    return lambda: fflush(None)


_fflush = _c_fflush()


def _flush_python_stdout() -> None:
    stream = sys.stdout
    if stream is not None:
        try:
            stream.flush()
        except (OSError, ValueError):  # closed or broken stream: nothing to keep in order
            pass


def _split(text: str) -> tuple[list[str], str]:
    """OSQP's ``ERROR in ...`` lines, and the rest of ``text`` unchanged."""
    lines = text.splitlines(keepends=True)
    errors = [ln.strip() for ln in lines if ln.lstrip().startswith("ERROR in")]
    return errors, "".join(ln for ln in lines if not ln.lstrip().startswith("ERROR in"))


def setup_solver(solver: Any, what: str, /, *args: Any, **kwargs: Any) -> None:
    """``solver.setup(*args, **kwargs)`` with OSQP's prints captured.

    Both routes OSQP may print by are captured: file descriptor 1 (C
    ``printf``) and Python's ``sys.stdout`` (the wrapper's ``PySys_WriteStdout``,
    which the current osqp wheels use).

    Args:
        solver: An ``osqp.OSQP`` object.
        what: What is being set up, for the message (e.g. ``"MPC problem"``).
        args, kwargs: Passed to ``solver.setup`` (data and settings).

    Raises:
        InvalidArgument: OSQP rejected the data or a setting; the message holds
            OSQP's own first line (e.g. ``eps_abs must be nonnegative``).
    """
    failure: BaseException | None = None
    with _LOCK:
        _flush_python_stdout()
        _fflush()
        try:
            saved = os.dup(1)
        except OSError:  # no fd 1 (a detached process): nothing can be printed there anyway
            saved = None
        py_stdout = sys.stdout
        py_buffer = io.StringIO()
        with tempfile.TemporaryFile() as tmp:
            if saved is not None:
                os.dup2(tmp.fileno(), 1)
            sys.stdout = py_buffer
            try:
                solver.setup(*args, **kwargs)
            except (ValueError, TypeError, osqp.OSQPException) as exc:
                failure = exc
            finally:
                sys.stdout = py_stdout
                if saved is not None:
                    _fflush()
                    os.dup2(saved, 1)
                    os.close(saved)
            tmp.seek(0)
            c_text = tmp.read().decode(errors="replace")
    c_errors, c_rest = _split(c_text)
    py_errors, py_rest = _split(py_buffer.getvalue())
    if c_rest:
        _flush_python_stdout()
        try:
            os.write(1, c_rest.encode())
        except OSError:  # pragma: no cover - fd 1 closed meanwhile
            pass
    if py_rest and py_stdout is not None:
        py_stdout.write(py_rest)
    if failure is None:
        return
    errors = py_errors + c_errors
    if errors:
        head, _, reason = errors[0].partition(": ")
        detail = f"{reason} ({head})" if reason else head
    else:
        detail = str(failure) or repr(failure)
    raise InvalidArgument(f"OSQP rejected the {what}: {detail}") from failure
