"""Identification data: one experiment's sampled inputs and measured outputs, loaded and checked.

An :class:`Experiment` holds uniformly sampled times ``t (N,)``, the inputs ``u (N - 1, m)`` held over
each sample interval (``u[k]`` acts from ``t[k]`` to ``t[k + 1]``, as a zero-order hold and as the
closed loops record them) and the measured outputs ``y (N, p)``, each column a state of the plant named
in ``outputs``. :func:`load_data` reads

* a ``run --out`` result (``result.npz``): ``t``, ``u`` and either ``y`` (the measured states, named by
  ``[sim] measured`` of the ``scenario.toml`` beside it, with their sensor noise) or, without ``y``,
  the full state ``x``;
* a CSV file with a header of named columns: ``t`` (or ``time``), one column per plant input, and any
  of the plant's states as outputs (the other columns are reported as unknown). The last row's inputs
  may be empty (they act after the last sample).

Checks at the boundary (:class:`~shinro_ctrl.errors.InvalidArgument`, one line): NaN or infinite values
name their rows (CSV: the file's line numbers; npz: the sample indices), gaps in the time column name
the rows where the step changes, and experiments sampled at different rates name both rates.
"""

from __future__ import annotations

import csv
import tomllib
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from shinro_ctrl.errors import InvalidArgument, UnknownName
from shinro_ctrl.validation import close_match_hint

__all__ = ["Experiment", "check_sampling", "experiment", "load_data"]

#: Relative tolerance on the sample interval: a step that differs by more is a gap (or a jitter) in the data.
SAMPLING_RTOL = 1e-6


@dataclass(frozen=True)
class Experiment:
    """One experiment: uniformly sampled inputs and measured outputs.

    Attributes:
        t: Sample times ``(N,)`` [s], uniformly spaced.
        u: Inputs ``(N - 1, m)``; ``u[k]`` is held from ``t[k]`` to ``t[k + 1]``.
        y: Measured outputs ``(N, p)``, column ``j`` the plant state ``outputs[j]``.
        outputs: The measured states' names (a subset of the plant's ``state_names``).
        inputs: The input names (the plant's ``input_names``).
        source: Where the data came from (a file name) for messages.
        row_label: How messages name a row: ``"line"`` (CSV, 1-based file lines) or ``"sample"`` (0-based).
        row_offset: Added to a 0-based sample index to give the row label's number.
    """

    t: np.ndarray
    u: np.ndarray
    y: np.ndarray
    outputs: tuple[str, ...]
    inputs: tuple[str, ...]
    source: str = "<arrays>"
    row_label: str = "sample"
    row_offset: int = 0

    @property
    def dt(self) -> float:
        """The sample interval [s]."""
        return float(self.t[1] - self.t[0])

    @property
    def samples(self) -> int:
        """Number of samples ``N``."""
        return len(self.t)

    def split(self, fraction: float) -> tuple[Experiment, Experiment]:
        """``(first, rest)``: the first ``fraction`` of the samples and the rest (sharing the cut sample).

        For a fit on held-out data: identify on one part, :func:`~shinro_ctrl.identification.compare`
        on the other.
        """
        if not 0.0 < fraction < 1.0:
            raise InvalidArgument(f"split fraction must be in (0, 1), got {fraction!r}")
        k = round(fraction * (self.samples - 1))
        if k < 2 or self.samples - k < 3:
            raise InvalidArgument(f"{self.source}: {self.samples} samples are too few to split at {fraction:g}")
        first = Experiment(
            self.t[: k + 1], self.u[:k], self.y[: k + 1], self.outputs, self.inputs, self.source + " (first part)"
        )
        rest = Experiment(
            self.t[k:],
            self.u[k:],
            self.y[k:],
            self.outputs,
            self.inputs,
            self.source + " (held out)",
            self.row_label,
            self.row_offset + k,
        )
        return first, rest

    def describe_rows(self, index: np.ndarray) -> str:
        """``"lines 12-15, 30"``: the (0-based) sample indices as the source names its rows."""
        return _ranges(self.row_label, [int(i) + self.row_offset for i in index])


def _ranges(label: str, rows: Sequence[int], limit: int = 6) -> str:
    """``"rows 3-5, 9"`` with at most ``limit`` ranges (then ``", … (K rows)"``)."""
    runs: list[list[int]] = []
    for r in rows:
        if runs and r == runs[-1][1] + 1:
            runs[-1][1] = r
        else:
            runs.append([r, r])
    parts = [f"{a}" if a == b else f"{a}-{b}" for a, b in runs[:limit]]
    more = f", … ({len(rows)} {label}s in all)" if len(runs) > limit else ""
    return f"{label}{'s' if len(rows) > 1 else ''} {', '.join(parts)}{more}"


def experiment(
    t: Sequence[float] | np.ndarray,
    u: Sequence[Sequence[float]] | np.ndarray,
    y: Sequence[Sequence[float]] | np.ndarray,
    outputs: Sequence[str],
    inputs: Sequence[str],
    *,
    source: str = "<arrays>",
    row_label: str = "sample",
    row_offset: int = 0,
) -> Experiment:
    """An :class:`Experiment` from arrays, checked: shapes, finite values (rows named), uniform sampling.

    Args:
        t: Times ``(N,)`` [s], N >= 3, increasing with a constant step.
        u: Inputs ``(N - 1, m)`` (or ``(N, m)``: the last row, acting after the last sample, is dropped).
        y: Outputs ``(N, p)``.
        outputs: Names of ``y``'s columns; inputs: names of ``u``'s columns.
        source: Name used in messages.
    """
    t = np.asarray(t, dtype=float).reshape(-1)
    u = np.asarray(u, dtype=float)
    y = np.asarray(y, dtype=float)
    u = u.reshape(-1, 1) if u.ndim == 1 else u
    y = y.reshape(-1, 1) if y.ndim == 1 else y
    n = len(t)
    if n < 3:
        raise InvalidArgument(f"{source}: {n} samples; identification needs at least 3")
    if u.shape[0] == n:
        u = u[:-1]
    if u.shape != (n - 1, len(inputs)):
        raise InvalidArgument(f"{source}: inputs have shape {u.shape}, expected ({n - 1}, {len(inputs)}) for {n} times")
    if y.shape != (n, len(outputs)):
        raise InvalidArgument(f"{source}: outputs have shape {y.shape}, expected ({n}, {len(outputs)})")
    exp = Experiment(t, u, y, tuple(outputs), tuple(inputs), source, row_label, row_offset)
    _check_finite(exp)
    _check_uniform(exp)
    return exp


def _check_finite(exp: Experiment) -> None:
    """NaN or infinite values: name the rows and the columns."""
    bad_t = ~np.isfinite(exp.t)
    bad_u = ~np.isfinite(exp.u)
    bad_y = ~np.isfinite(exp.y)
    rows = np.flatnonzero(bad_t | np.r_[bad_u.any(axis=1), False] | bad_y.any(axis=1))
    if rows.size:
        cols = [c for c, bad in zip(("t",), (bad_t.any(),), strict=True) if bad]
        cols += [c for j, c in enumerate(exp.inputs) if bad_u[:, j].any()]
        cols += [c for j, c in enumerate(exp.outputs) if bad_y[:, j].any()]
        kind = "NaN" if np.isnan(np.r_[exp.t, exp.u.ravel(), exp.y.ravel()]).any() else "infinite"
        raise InvalidArgument(
            f"{exp.source}: {kind} values in {exp.describe_rows(rows)} (columns {', '.join(cols)}); "
            "remove or fill those rows, or split the data into experiments at them"
        )


def _check_uniform(exp: Experiment) -> None:
    """A constant sample interval: a gap or jitter names the rows where the step differs."""
    steps = np.diff(exp.t)
    dt = float(np.median(steps))
    if not dt > 0:
        raise InvalidArgument(f"{exp.source}: times must increase (median step {dt:g} s)")
    bad = np.flatnonzero(np.abs(steps - dt) > SAMPLING_RTOL * dt + 1e-12)
    if bad.size:
        k = int(bad[0])
        where = exp.describe_rows(np.array([k]))
        raise InvalidArgument(
            f"{exp.source}: gap in the time column: the step is {steps[k]:.6g} s after {where} "
            f"instead of the sampling step {dt:.6g} s ({exp.describe_rows(bad)} differ); split the data at the gaps "
            "into experiments"
        )


def check_sampling(experiments: Sequence[Experiment], dt: float | None = None, *, what: str = "the plant") -> float:
    """The common sample interval of ``experiments``; mismatched sampling names both rates.

    Args:
        experiments: One or more experiments.
        dt: The step they must share (the plant's), or None to take the first's.
        what: What ``dt`` belongs to, for the message.
    """
    if not experiments:
        raise InvalidArgument("no identification data: give at least one experiment")
    ref = experiments[0].dt if dt is None else float(dt)
    ref_name = experiments[0].source if dt is None else what
    for e in experiments:
        if abs(e.dt - ref) > SAMPLING_RTOL * ref + 1e-12:
            raise InvalidArgument(
                f"mismatched sampling: {e.source} is sampled every {e.dt:.6g} s, {ref_name} every {ref:.6g} s "
                f"({1 / e.dt:.6g} Hz vs {1 / ref:.6g} Hz)"
            )
    return ref


def load_data(
    path: str | Path,
    state_names: Sequence[str],
    input_names: Sequence[str],
    *,
    outputs: Sequence[str] | None = None,
) -> Experiment:
    """Read one experiment from a ``run --out`` ``result.npz`` (or its folder) or a CSV file with named columns.

    Args:
        path: ``result.npz``, a folder holding one, or a ``.csv`` file.
        state_names: The plant's state names (the possible outputs).
        input_names: The plant's input names (the required input columns).
        outputs: Keep only these measured states (default: every state the file measures).

    Raises:
        FileNotFoundError: no such file.
        InvalidArgument: unreadable file, missing or unknown columns (the valid names are listed),
            NaN or infinite values (rows named), gaps in time.
    """
    p = Path(path)
    if p.is_dir():
        p = p / "result.npz"
    if not p.exists():
        raise FileNotFoundError(f"identification data {str(path)!r}: no such file")
    if p.suffix.lower() == ".npz":
        exp = _load_npz(p, tuple(state_names), tuple(input_names))
    elif p.suffix.lower() in (".csv", ".txt"):
        exp = _load_csv(p, tuple(state_names), tuple(input_names))
    else:
        raise InvalidArgument(f"{p}: identification data must be a result.npz (run --out) or a .csv file")
    if outputs is not None:
        exp = select_outputs(exp, outputs)
    return exp


def select_outputs(exp: Experiment, outputs: Sequence[str]) -> Experiment:
    """``exp`` with only the named outputs; a name it does not measure lists the ones it does."""
    idx = []
    for name in outputs:
        if name not in exp.outputs:
            raise UnknownName(
                f"{exp.source} does not measure {name!r}{close_match_hint(name, exp.outputs)}; "
                f"it measures: {', '.join(exp.outputs)}"
            )
        idx.append(exp.outputs.index(name))
    return Experiment(
        exp.t, exp.u, exp.y[:, idx], tuple(outputs), exp.inputs, exp.source, exp.row_label, exp.row_offset
    )


def _load_npz(p: Path, states: tuple[str, ...], inputs: tuple[str, ...]) -> Experiment:
    try:
        with np.load(p, allow_pickle=False) as z:
            arrays = {k: np.asarray(z[k]) for k in z.files}
    except (OSError, ValueError) as exc:
        raise InvalidArgument(f"{p}: not a readable .npz file ({exc})") from None
    missing = [k for k in ("t", "u") if k not in arrays] + ([] if "x" in arrays or "y" in arrays else ["x or y"])
    if missing:
        raise InvalidArgument(f"{p}: missing arrays {', '.join(missing)} (a run --out result.npz has t, u, x, y)")
    if "y" in arrays:
        measured = _measured_names(p, states, arrays["y"].shape[1] if arrays["y"].ndim == 2 else 1)
        y = arrays["y"]
    else:
        measured, y = states, arrays["x"]
    return experiment(arrays["t"], arrays["u"], y, measured, inputs, source=str(p))


def _measured_names(p: Path, states: tuple[str, ...], columns: int) -> tuple[str, ...]:
    """The names of ``y``'s columns: ``[sim] measured`` of the ``scenario.toml`` beside the result (default all)."""
    scenario = p.with_name("scenario.toml")
    names: Sequence[str] | None = None
    if scenario.exists():
        try:
            doc = tomllib.loads(scenario.read_text(encoding="utf-8"))
        except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
            raise InvalidArgument(f"{scenario}: cannot read the measured states' names ({exc})") from None
        names = doc.get("sim", {}).get("measured")
    if names is None:
        if columns != len(states):
            raise InvalidArgument(
                f"{p}: y has {columns} columns but no scenario.toml beside it names them ([sim] measured)"
            )
        names = states
    names = tuple(str(n) for n in names)
    if len(names) != columns:
        raise InvalidArgument(f"{p}: y has {columns} columns but [sim] measured names {len(names)}")
    return names


def _load_csv(p: Path, states: tuple[str, ...], inputs: tuple[str, ...]) -> Experiment:
    try:
        with p.open(newline="", encoding="utf-8") as f:
            rows = list(csv.reader(f))
    except (OSError, UnicodeDecodeError) as exc:
        raise InvalidArgument(f"{p}: cannot read ({exc})") from None
    while rows and not any(c.strip() for c in rows[-1]):
        rows.pop()  # trailing blank lines; a blank line inside is a row of missing values (named as such)
    if len(rows) < 2:
        raise InvalidArgument(f"{p}: needs a header of column names and at least one data row")
    header = [h.strip() for h in rows[0]]
    time_cols = [h for h in header if h in ("t", "time")]
    if not time_cols:
        raise InvalidArgument(f"{p}: no time column: name one 't' or 'time' (columns: {', '.join(header)})")
    known = {time_cols[0], *states, *inputs}
    unknown = [h for h in header if h not in known]
    if unknown:
        raise UnknownName(
            f"{p}: unknown column {unknown[0]!r}{close_match_hint(unknown[0], sorted(known))}; "
            f"valid: {time_cols[0]}, inputs {', '.join(inputs)}, states {', '.join(states)}"
        )
    missing = [i for i in inputs if i not in header]
    if missing:
        raise InvalidArgument(
            f"{p}: missing input column(s) {', '.join(missing)} (the plant's inputs: {', '.join(inputs)})"
        )
    outputs = tuple(s for s in states if s in header)
    if not outputs:
        raise InvalidArgument(f"{p}: no measured state: name at least one column after a state ({', '.join(states)})")
    values = np.full((len(rows) - 1, len(header)), np.nan)
    for i, row in enumerate(rows[1:]):
        for j, cell in enumerate(row[: len(header)]):
            cell = cell.strip()
            if cell:
                try:
                    values[i, j] = float(cell)
                except ValueError:
                    raise InvalidArgument(
                        f"{p}: line {i + 2}, column {header[j]!r}: {cell!r} is not a number"
                    ) from None
    col = {h: j for j, h in enumerate(header)}
    t = values[:, col[time_cols[0]]]
    u = values[:-1, [col[i] for i in inputs]]
    y = values[:, [col[s] for s in outputs]]
    return experiment(t, u, y, outputs, inputs, source=str(p), row_label="line", row_offset=2)
