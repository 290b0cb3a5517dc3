"""The one OSQP adapter: set-up with captured C errors, settings validation, compiled fast path.

:class:`OsqpQP` holds one set-up problem and routes updates and solves through
OSQP's compiled solver object when available (public API otherwise);
:func:`merge_settings` checks user settings by name. This module is the only
one that touches OSQP's private ``_solver``.

Set-up errors:

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
import math
import os
import sys
import tempfile
import threading
from collections.abc import Mapping
from typing import Any

import numpy as np
import osqp
import scipy.sparse as sp

from shinro_ctrl.concurrency import CallGuard
from shinro_ctrl.errors import ConcurrentUse, InvalidArgument
from shinro_ctrl.validation import closest, unknown_keys

__all__ = ["OsqpQP", "merge_settings", "setup_solver", "valid_settings"]

_LOCK = threading.Lock()  # fd 1 is process-wide: one redirected set-up at a time
_OSQP_SIGINT = int(osqp.SolverStatus.OSQP_SIGINT)  # OSQP's own Ctrl-C handler stopped the solve


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


def setup_solver(solver: osqp.OSQP, what: str, /, *args: Any, **kwargs: Any) -> None:
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


def valid_settings() -> tuple[str, ...]:
    """The setting names ``OSQP.setup`` accepts (``solver_type``/``cg_preconditioner`` for the two aliases)."""
    ext = osqp.OSQP().ext
    names = {k for k in ext.OSQPSettings.__dict__ if not k.startswith("_")}
    names -= {"linsys_solver", "cg_precond"}  # set through the two aliases below
    return tuple(sorted(names | {"solver_type", "cg_preconditioner"}))


def merge_settings(
    defaults: Mapping[str, Any], overrides: Mapping[str, Any] | None, name: str = "osqp_settings"
) -> dict[str, Any]:
    """``defaults`` updated with ``overrides`` after checking every override's name.

    Args:
        defaults: The caller's default settings.
        overrides: The user's settings (None: none).
        name: The argument name for messages.

    Raises:
        InvalidArgument: an unknown setting, naming the closest valid one and listing all.
    """
    settings = dict(defaults)
    if overrides:
        valid = valid_settings()
        bad = unknown_keys(overrides, valid)
        if bad:
            close = closest(bad[0], valid)
            near = f" (did you mean '{close}'?)" if close else ""
            raise InvalidArgument(f"{name}: unknown OSQP setting '{bad[0]}'{near}; valid settings: {', '.join(valid)}")
        for key, value in overrides.items():
            _check_setting_type(name, key, value)
        settings.update(overrides)
    return settings


_FLAGS = {"verbose", "warm_starting", "polishing", "rho_is_vec", "scaled_termination", "check_dualgap", "adaptive_rho"}


def _check_setting_type(name: str, key: str, value: Any) -> None:
    """The setting's value has the type of OSQP's own default (named in the message, before OSQP sees it)."""
    default = getattr(osqp.OSQP().ext.OSQPSettings(), key, None)
    if key in ("solver_type", "cg_preconditioner") or default is None:
        return
    is_bool = isinstance(value, bool)
    if isinstance(default, float):
        ok, want = isinstance(value, int | float) and not is_bool, "a number"
    elif isinstance(default, int) and key in _FLAGS:
        ok, want = isinstance(value, int), "a boolean or an integer"
    elif isinstance(default, int):
        ok, want = isinstance(value, int) and not is_bool, "an integer"
    else:
        ok, want = isinstance(value, int | str) and not is_bool, "an integer or a name"
    if not ok:
        raise InvalidArgument(f"{name}: '{key}' must be {want}, got {type(value).__name__} {value!r}")
    if isinstance(default, float) and not math.isfinite(value):  # OSQP would take NaN and compare nothing with it
        raise InvalidArgument(f"{name}: '{key}' must be a finite number, got {value!r}")


class OsqpQP:
    """One OSQP problem set up once and updated in place: the project's only OSQP adapter.

    ``min ½ zᵀ P z + qᵀ z  s.t.  l ≤ A z ≤ u`` with a fixed sparsity pattern.
    Updates and solves go through OSQP's compiled solver object when the
    wrapper exposes it (``OSQP._solver``: about 25-40 µs less per call than
    ``OSQP.update``/``OSQP.solve``, which clamp arguments and pack a result
    namespace); otherwise through the public API. The compiled path neither
    clamps infinite bounds nor checks lengths: callers pass bounds within
    ±1e30 in arrays of the set-up lengths.

    Args:
        what: What is being set up, for error messages.
        P: Upper-triangular cost Hessian, CSC ``(n, n)``.
        q: Linear cost ``(n,)``.
        A: Constraint matrix, CSC ``(m, n)``.
        l: Lower bounds ``(m,)``.
        u: Upper bounds ``(m,)``.
        settings: OSQP settings (already merged with the caller's defaults).
        fast: Use the compiled path when available (False forces the public API).

    Attributes:
        solver: The public ``osqp.OSQP`` object.
        fast: Whether calls go through the compiled solver.

    Threads: one object serves one thread at a time. A method entered while
    another thread is inside one, or a ``solve`` from a thread other than
    the one that made the latest write (``update``, ``warm_start``,
    ``update_rho``), raises
    :class:`~shinro_ctrl.errors.ConcurrentUse` instead of letting OSQP's C
    workspace be written by two threads (which crashed the process). An
    owner that serializes its calls (``LinearMPC`` holds a lock around its
    whole step, ``IKQP`` around its kernel) never sees it; a thread that
    takes over an idle object starts with a write.
    """

    _NEEDED = ("update_data_vec", "update_data_mat", "warm_start", "update_rho", "solve", "info", "solution")

    def __init__(
        self,
        what: str,
        P: sp.csc_matrix,
        q: np.ndarray,
        A: sp.csc_matrix,
        l: np.ndarray,
        u: np.ndarray,
        settings: Mapping[str, Any],
        *,
        fast: bool = True,
    ):
        self.what = what
        self.settings = dict(settings)
        self._data = (P, q, A, l, u)
        self.prefer_fast = bool(fast)
        self._guard = CallGuard(f"this OSQP problem ({what})")  # held while a method runs
        self._writer: int | None = None  # the thread of the latest update (a solve from another is concurrent use)
        self.setup()

    def _enter(self, method: str, *, writes: bool = False) -> None:
        """Claim the object for one method call (take its guard), or raise :class:`ConcurrentUse`."""
        if not self._guard.acquire(False):
            raise self._guard.refused()
        me = threading.get_ident()
        if writes:
            self._writer = me
        elif self._writer is not None and self._writer != me:
            self._guard.release()
            raise ConcurrentUse(
                f"OsqpQP.{method} called from another thread than the latest update of this OSQP problem "
                f"({self.what}): its data may be the other thread's"
            )

    def setup(self) -> None:
        """(Re)create and set up the OSQP object from the set-up data (a clean solver state)."""
        self._enter("setup", writes=True)
        try:
            self.solver = osqp.OSQP()
            setup_solver(self.solver, self.what, *self._data, **self.settings)
            raw = getattr(self.solver, "_solver", None) if self.prefer_fast else None
            self._raw = raw if raw is not None and all(hasattr(raw, a) for a in self._NEEDED) else None
        finally:
            self._guard.release()

    @property
    def fast(self) -> bool:
        """True when calls go through OSQP's compiled solver object."""
        return self._raw is not None

    @fast.setter
    def fast(self, value: bool) -> None:
        self.prefer_fast = bool(value)
        if not value:
            self._raw = None
        elif self._raw is None:
            raw = getattr(self.solver, "_solver", None)
            self._raw = raw if raw is not None and all(hasattr(raw, a) for a in self._NEEDED) else None

    def update(
        self,
        q: np.ndarray | None,
        l: np.ndarray,
        u: np.ndarray,
        Px: np.ndarray | None = None,
        Ax: np.ndarray | None = None,
    ) -> None:
        """New ``q`` (None keeps it), ``l``, ``u``; optionally new values ``Px`` / ``Ax`` of P's / A's pattern."""
        self._enter("update", writes=True)
        try:
            raw = self._raw
            if raw is not None:
                if raw.update_data_vec(q, l, u) != 0:  # pragma: no cover - sizes are fixed
                    raise RuntimeError("OSQP rejected the vector update")
                if Px is not None or Ax is not None:
                    raw.update_data_mat(Px, None, Ax, None)
                return
            kwargs = {"l": l, "u": u}
            if q is not None:
                kwargs["q"] = q
            if Px is not None:
                kwargs["Px"] = Px
            if Ax is not None:
                kwargs["Ax"] = Ax
            self.solver.update(**kwargs)
        finally:
            self._guard.release()

    def warm_start(self, x: np.ndarray, y: np.ndarray) -> None:
        """Primal ``x (n,)`` and dual ``y (m,)`` starting iterates for the next solve."""
        self._enter("warm_start", writes=True)
        try:
            if self._raw is not None:
                self._raw.warm_start(x, y)
            else:
                self.solver.warm_start(x=x, y=y)
        finally:
            self._guard.release()

    def update_settings(self, **settings: Any) -> None:
        """Change settings between solves (e.g. tighter ``eps_abs``/``eps_rel`` for one re-solve).

        Only the settings OSQP allows to change after set-up (tolerances,
        ``max_iter``, ``polishing``, ``time_limit``, …); kept in :attr:`settings`.
        """
        self._enter("update_settings")
        try:
            self.solver.update_settings(**settings)
            self.settings.update(settings)
        finally:
            self._guard.release()

    def update_rho(self, rho: float) -> None:
        """Set the ADMM step ``rho`` (OSQP adapts it between solves when ``adaptive_rho``)."""
        self._enter("update_rho", writes=True)
        try:
            if self._raw is not None:
                self._raw.update_rho(rho)
            else:
                self.solver.update_settings(rho=rho)
        finally:
            self._guard.release()

    def solve(self) -> tuple[Any, Any]:
        """Solve; returns ``(solution, info)`` (``.x``, ``.y``, ``.prim_inf_cert``; ``.status``, ``.iter``, …).

        Raises:
            KeyboardInterrupt: OSQP caught Ctrl-C (status ``interrupted``): the interruption ends the
                command, it is never reported as an infeasible or failed solve.
            ConcurrentUse: another thread is inside this object, or made the latest update.
        """
        self._enter("solve")
        try:
            raw = self._raw
            if raw is not None:
                raw.solve()
                info = raw.info
            else:
                sol = self.solver.solve(raise_error=False)
                info = sol.info
        finally:
            self._guard.release()
        if info.status_val == _OSQP_SIGINT:
            raise KeyboardInterrupt("OSQP solve interrupted")
        return (raw.solution if raw is not None else sol), info
