"""A planned trajectory: knots, the interpolants its transcription implies, and solve statistics.

The interpolants are those the transcription promises (so that a controller
tracking ``x_at(t)`` under ``u_at(t)`` follows what the optimizer verified):

* ``hermite_simpson``: inputs linear between knots (first-order hold, the
  midpoint input is the average); states the cubic Hermite polynomial through
  ``(x_k, f_k)`` and ``(x_{k+1}, f_{k+1})`` with ``f_k = f(x_k, u_k)``.
* ``trapezoid``: inputs linear; states the quadratic
  ``x(t_k + τ) = x_k + τ f_k + τ² (f_{k+1} − f_k) / (2 h)``, which meets
  ``x_{k+1}`` exactly when the trapezoidal defect is zero.
* ``multiple_shooting``: inputs held (zero-order hold); states the cubic
  Hermite polynomial through ``(x_k, f(x_k, u_k))`` and
  ``(x_{k+1}, f(x_{k+1}, u_k))``.

Outside ``[t_0, t_N]`` both interpolants hold their end values.
"""

from __future__ import annotations

import json
import zipfile
import zlib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from shinro_ctrl.errors import InvalidArgument

__all__ = ["MAX_KNOTS", "MAX_SHOOTING_STEPS", "MAX_SUBSTEPS", "METHODS", "Trajectory", "check_transcription_size"]

METHODS = ("hermite_simpson", "trapezoid", "multiple_shooting")
MAX_KNOTS = 1_000  # knots of a transcription (20,000 hung building the NLP; 1,000 builds in ~15 s)
MAX_SUBSTEPS = 100  # RK4 steps per interval (multiple_shooting)
MAX_SHOOTING_STEPS = 1_000  # knots x substeps of a multiple-shooting NLP (5,000 take ~100 s to build)


def _count(key: str, value: Any, low: int, high: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int | np.integer) or not low <= value <= high:
        raise InvalidArgument(f"'{key}' must be an integer in [{low}, {high:,}] (the limit), got {value!r}")
    return int(value)


def check_transcription_size(knots: Any, substeps: Any = 1, method: str = "hermite_simpson") -> tuple[int, int]:
    """``(knots, substeps)`` checked against the limits that keep a plan's NLP buildable in seconds.

    Raises:
        InvalidArgument: a count that is not an integer, below its minimum or above its limit (named).
    """
    k = _count("knots", knots, 3, MAX_KNOTS)
    s = _count("substeps", substeps, 1, MAX_SUBSTEPS)
    if method == "multiple_shooting" and k * s > MAX_SHOOTING_STEPS:
        raise InvalidArgument(
            f"'knots' x 'substeps' = {k * s:,} exceeds the limit of {MAX_SHOOTING_STEPS:,} RK4 steps of a "
            "multiple-shooting plan (it would take minutes to build); use fewer knots or substeps"
        )
    return k, s


_REQUIRED = ("t", "x", "u", "xdot", "method", "stats", "status", "state_names", "input_names")


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip()
    return text.splitlines()[0] if text else type(exc).__name__


def _float_array(z: Any, key: str, ndim: int) -> np.ndarray:
    """Array ``key`` of the archive as floats with ``ndim`` dimensions."""
    a = np.asarray(z[key])
    if a.ndim != ndim or a.dtype.kind not in "fiub":
        raise ValueError(f"'{key}' must be a {ndim}-D numeric array, found shape {a.shape} of {a.dtype}")
    return a.astype(float)


@dataclass
class Trajectory:
    """A trajectory ``x(t), u(t)`` on ``N`` knots.

    Attributes:
        t: Knot times ``(N,)`` [s], starting at 0.
        x: Knot states ``(N, n)``.
        u: Knot inputs ``(N, m)`` (for ``multiple_shooting`` the last row
            repeats the one before: inputs are held over each interval).
        xdot: State derivatives at the knots ``(N, n)`` as the interpolant
            uses them (``f(x_k, u_k)``; for ``multiple_shooting`` the right
            end of interval ``k`` uses ``u_k``, stored in ``xdot_right``).
        method: Transcription, one of :data:`METHODS`.
        solve_time: Wall-clock time of the NLP solve [s].
        iterations: IPOPT iterations.
        objective: Optimal objective value.
        max_defect: Largest absolute dynamics defect of the transcription.
        status: IPOPT's return status.
        state_names, input_names: Labels.
        xdot_right: ``(N - 1, n)`` right-end derivatives for ``multiple_shooting``
            (None otherwise).
        origin: What the plan was solved for: ``{"plant": class name, "params": {...},
            "dt": step [s], "bounds": the plan's bounds table}`` (None for a hand-made
            trajectory). Saved with the plan; a loaded plan is refused on another plant.
    """

    t: np.ndarray
    x: np.ndarray
    u: np.ndarray
    xdot: np.ndarray
    method: str = "hermite_simpson"
    solve_time: float = 0.0
    iterations: int = 0
    objective: float = float("nan")
    max_defect: float = float("nan")
    status: str = ""
    state_names: tuple[str, ...] = ()
    input_names: tuple[str, ...] = ()
    xdot_right: np.ndarray | None = None
    origin: dict[str, Any] | None = None

    def __post_init__(self) -> None:
        self.t = np.asarray(self.t, dtype=float)
        self.x = np.asarray(self.x, dtype=float)
        self.u = np.asarray(self.u, dtype=float)
        self.xdot = np.asarray(self.xdot, dtype=float)
        if self.method not in METHODS:
            raise InvalidArgument(f"Trajectory: unknown method {self.method!r}; valid: {', '.join(METHODS)}")
        N = self.t.shape[0]
        if N < 2 or self.x.shape[0] != N or self.u.shape[0] != N or self.xdot.shape != self.x.shape:
            raise InvalidArgument(
                f"Trajectory: expected t (N,), x (N, n), u (N, m), xdot (N, n) with N >= 2 but found "
                f"{self.t.shape}, {self.x.shape}, {self.u.shape}, {self.xdot.shape}"
            )
        if not np.all(np.isfinite(self.t)) or np.any(np.diff(self.t) <= 0):
            raise InvalidArgument("Trajectory: knot times t must be finite and strictly increasing")
        sizes = (("state", self.state_names, self.x.shape[1]), ("input", self.input_names, self.u.shape[1]))
        for what, names, size in sizes:
            if names and len(names) != size:
                raise InvalidArgument(f"Trajectory: {len(names)} {what} names for {size} {what}s")
        if self.method == "multiple_shooting":
            if self.xdot_right is None or np.shape(self.xdot_right) != (N - 1, self.x.shape[1]):
                raise InvalidArgument(f"Trajectory: multiple_shooting needs xdot_right of shape ({N - 1}, n)")
            self.xdot_right = np.asarray(self.xdot_right, dtype=float)
        if not (np.all(np.isfinite(self.x)) and np.all(np.isfinite(self.u))):
            raise InvalidArgument("Trajectory: x and u must be finite")

    # ------------------------------------------------------------ properties
    @property
    def duration(self) -> float:
        """``t_N − t_0`` [s]."""
        return float(self.t[-1] - self.t[0])

    @property
    def knots(self) -> int:
        """Number of knots ``N``."""
        return int(self.t.shape[0])

    @property
    def state_dim(self) -> int:
        return int(self.x.shape[1])

    @property
    def input_dim(self) -> int:
        return int(self.u.shape[1])

    # ----------------------------------------------------------- interpolants
    def _locate(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Interval index ``k``, local time ``τ`` and step ``h`` for times ``t`` (clamped to the knots)."""
        tc = np.clip(t, self.t[0], self.t[-1])
        k = np.clip(np.searchsorted(self.t, tc, side="right") - 1, 0, self.knots - 2)
        h = self.t[k + 1] - self.t[k]
        return k, tc - self.t[k], h

    def u_at(self, t: Any) -> np.ndarray:
        """Input at time(s) ``t``: scalar → ``(m,)``, ``(T,)`` → ``(T, m)``.

        Linear between knots (``hermite_simpson``, ``trapezoid``) or held
        (``multiple_shooting``); held at the end values outside the knots.
        """
        ts = np.asarray(t, dtype=float)
        scalar = ts.ndim == 0
        ts = np.atleast_1d(ts)
        k, tau, h = self._locate(ts)
        if self.method == "multiple_shooting":
            out = self.u[k]
            out = np.where((ts >= self.t[-1])[:, None], self.u[-1], out)
        else:
            s = (tau / h)[:, None]
            out = (1.0 - s) * self.u[k] + s * self.u[k + 1]
        return out[0] if scalar else out

    def x_at(self, t: Any) -> np.ndarray:
        """State at time(s) ``t``: scalar → ``(n,)``, ``(T,)`` → ``(T, n)`` (see the module doc)."""
        ts = np.asarray(t, dtype=float)
        scalar = ts.ndim == 0
        ts = np.atleast_1d(ts)
        k, tau, h = self._locate(ts)
        x0, x1 = self.x[k], self.x[k + 1]
        f0 = self.xdot[k]
        f1 = self.xdot_right[k] if self.method == "multiple_shooting" else self.xdot[k + 1]
        tau_, h_ = tau[:, None], h[:, None]
        if self.method == "trapezoid":
            out = x0 + tau_ * f0 + tau_**2 * (f1 - f0) / (2.0 * h_)
        else:
            s = tau_ / h_
            s2, s3 = s * s, s * s * s
            out = (
                (2 * s3 - 3 * s2 + 1) * x0 + (s3 - 2 * s2 + s) * h_ * f0 + (-2 * s3 + 3 * s2) * x1 + (s3 - s2) * h_ * f1
            )
        return out[0] if scalar else out

    def sample(self, dt: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(t (K,), x (K, n), u (K, m))`` at a fixed step ``dt`` from 0 to the last knot (inclusive).

        Args:
            dt: Sampling step [s], > 0.
        """
        if not dt > 0:
            raise InvalidArgument(f"dt must be positive, got {dt!r}")
        K = int(np.floor(self.duration / dt + 1e-9)) + 1
        ts = self.t[0] + dt * np.arange(K)
        return ts, self.x_at(ts), self.u_at(ts)

    # ------------------------------------------------------------------ files
    def save(self, path: str | Path) -> Path:
        """Write the trajectory (and :attr:`origin`) to an ``.npz`` file atomically and return its path.

        The file carries our marker, so a later save may replace it; an existing file that
        shinro-ctrl did not write, or a symbolic link, is refused.

        Raises:
            InvalidArgument: ``path`` is a file shinro-ctrl did not write, a link or a folder.
        """
        from shinro_ctrl._text_formats import json_safe
        from shinro_ctrl.files import GENERATOR, NPZ_MARKER, write_output

        path = Path(path)
        arrays: dict[str, Any] = {
            "t": self.t,
            "x": self.x,
            "u": self.u,
            "xdot": self.xdot,
            "method": np.array(self.method),
            "stats": np.array([self.solve_time, self.iterations, self.objective, self.max_defect]),
            "status": np.array(self.status),
            "state_names": np.array(self.state_names, dtype=str),
            "input_names": np.array(self.input_names, dtype=str),
            NPZ_MARKER: np.array(GENERATOR),
        }
        if self.xdot_right is not None:
            arrays["xdot_right"] = self.xdot_right
        if self.origin is not None:
            arrays["origin"] = np.array(json.dumps(json_safe(self.origin), sort_keys=True))
        path.parent.mkdir(parents=True, exist_ok=True)
        write_output(path, lambda f: np.savez(f, **arrays), binary=True, what="plan file", kind="NPZ")
        return path

    @classmethod
    def load(cls, path: str | Path) -> Trajectory:
        """Read a trajectory written by :meth:`save`.

        Raises:
            FileNotFoundError: no such file.
            InvalidArgument: the file is not a saved trajectory (not an ``.npz``, truncated,
                missing arrays, wrong shapes or types), one line naming the file.
        """
        path = Path(path)
        if not path.is_file():
            where = " (it is a directory)" if path.is_dir() else ""
            raise FileNotFoundError(f"plan file not found: '{path}'{where}")

        def bad(why: str) -> InvalidArgument:
            return InvalidArgument(f"plan file '{path}' is not a saved plan ({why}); write one with 'shinro-ctrl plan'")

        with open(path, "rb") as f:
            head = f.read(6)
        if head.startswith(b"\x93NUMPY"):
            raise bad("a single .npy array, not an .npz archive")
        if not head.startswith((b"PK\x03\x04", b"PK\x05\x06")):
            raise bad("not an .npz archive" if head else "an empty file")
        try:
            z = np.load(path, allow_pickle=False)
        except (ValueError, OSError, EOFError, zipfile.BadZipFile) as exc:
            raise bad(f"cannot be read as .npz: {_first_line(exc)}") from None
        if not isinstance(z, np.lib.npyio.NpzFile):
            raise bad("a single .npy array, not an .npz archive")
        with z:
            missing = [k for k in _REQUIRED if k not in z.files]
            if missing:
                raise bad(f"missing {', '.join(missing)}")
            try:
                stats = np.asarray(z["stats"], dtype=float).ravel()
                if stats.shape != (4,):
                    raise ValueError(f"stats has {stats.size} entries, expected 4")
                origin = json.loads(str(z["origin"])) if "origin" in z.files else None
                if origin is not None and not isinstance(origin, dict):
                    raise ValueError("origin is not a table")
                return cls(
                    t=_float_array(z, "t", 1),
                    x=_float_array(z, "x", 2),
                    u=_float_array(z, "u", 2),
                    xdot=_float_array(z, "xdot", 2),
                    method=str(z["method"]),
                    solve_time=float(stats[0]),
                    iterations=int(stats[1]) if np.isfinite(stats[1]) else 0,
                    objective=float(stats[2]),
                    max_defect=float(stats[3]),
                    status=str(z["status"]),
                    state_names=tuple(str(s) for s in np.atleast_1d(z["state_names"])),
                    input_names=tuple(str(s) for s in np.atleast_1d(z["input_names"])),
                    xdot_right=_float_array(z, "xdot_right", 2) if "xdot_right" in z.files else None,
                    origin=origin,
                )
            except InvalidArgument as exc:
                raise bad(str(exc).removeprefix("Trajectory: ")) from None
            except (KeyError, ValueError, TypeError, IndexError, OSError, EOFError, zipfile.BadZipFile) as exc:
                raise bad(_first_line(exc)) from None
            except zlib.error as exc:
                raise bad(f"corrupt data: {_first_line(exc)}") from None

    # ------------------------------------------------------------------- plot
    def plot(self, path: str | Path, *, samples: int = 400) -> Path:
        """Plot the states and inputs (interpolants as lines, knots as dots) to a PNG or PDF (by the suffix)."""
        import matplotlib.pyplot as plt

        from shinro_ctrl.plots import axis_label
        from shinro_ctrl.plots._figure import save_figure

        n, m = self.state_dim, self.input_dim
        ts = np.linspace(self.t[0], self.t[-1], samples)
        xs, us = self.x_at(ts), self.u_at(ts)
        fig, axes = plt.subplots(n + m, 1, figsize=(8, 1.5 * (n + m) + 0.8), sharex=True, squeeze=False)
        for i in range(n):
            ax = axes[i, 0]
            ax.plot(ts, xs[:, i], color="C0", lw=1.3)
            ax.plot(self.t, self.x[:, i], ".", color="C0", ms=3)
            ax.set_ylabel(axis_label(self.state_names[i]) if self.state_names else f"x{i}", fontsize=9)
            ax.grid(alpha=0.3)
        for j in range(m):
            ax = axes[n + j, 0]
            ax.plot(ts, us[:, j], color="C2", lw=1.3)
            ax.plot(self.t, self.u[:, j], ".", color="C2", ms=3)
            ax.set_ylabel(axis_label(self.input_names[j], is_input=True) if self.input_names else f"u{j}", fontsize=9)
            ax.grid(alpha=0.3)
        axes[-1, 0].set_xlabel("time [s]")
        fig.suptitle(
            f"{self.method}: {self.knots} knots, T = {self.duration:.3g} s, objective {self.objective:.4g}, "
            f"max defect {self.max_defect:.1e}",
            x=0.02,
            ha="left",
            fontsize=10,
        )
        fig.tight_layout(rect=(0, 0, 1, 0.97))
        try:
            return save_figure(fig, path, dpi=110)
        finally:
            plt.close(fig)

    def summary(self) -> str:
        """Solve statistics on a few lines."""
        return (
            f"  method      {self.method} ({self.knots} knots)\n"
            f"  status      {self.status}\n"
            f"  duration    {self.duration:.6g} s\n"
            f"  solve time  {self.solve_time:.4g} s\n"
            f"  iterations  {self.iterations}\n"
            f"  objective   {self.objective:.8g}\n"
            f"  max defect  {self.max_defect:.3e}"
        )
