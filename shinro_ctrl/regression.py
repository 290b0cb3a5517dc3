"""Controller regression tests: scenario metrics compared with stored baselines.

Each scenario ``NAME.toml`` in a regression folder has its baseline
``NAME.baseline.json`` beside it. A metric passes when

    |now − baseline| ≤ abs + rel · |baseline|

with ``rel``/``abs`` from the scenario's ``[regression]`` table, or the
defaults in :data:`DEFAULT_TOLERANCES` (tight: the runs are deterministic).
Wall-clock metrics (``solve_time_median_s``) are compared only when the
scenario gives a tolerance for them.

An undefined metric (a settling or rise time that never happened, a metric
of an empty run) is None in the run and ``null`` in the baseline: None
against None passes, None against a number fails with a line saying which
side is undefined. Baselines hold no NaN or infinity.
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from shinro_ctrl.errors import ConfigError, InvalidArgument, ShinroError
from shinro_ctrl.sim.metrics import (
    FLAG_METRICS,
    NEVER_METRICS,
    WALL_CLOCK_METRICS,
    format_metric,
    is_newer_metric,
)

__all__ = [
    "DEFAULT_TOLERANCES",
    "MetricCheck",
    "RegressionReport",
    "baseline_path",
    "baseline_text",
    "compare_metrics",
    "format_report",
    "read_baseline",
    "regression_paths",
    "run_regression",
    "write_baseline",
]

DEFAULT_TOLERANCES: dict[str, dict[str, float]] = {
    "rms_error": {"rel": 1e-3, "abs": 1e-9},
    "max_error": {"rel": 1e-3, "abs": 1e-9},
    "final_error": {"rel": 1e-2, "abs": 1e-6},
    "settling_time": {"rel": 0.0, "abs": 0.05},
    "max_abs_input": {"rel": 1e-3, "abs": 1e-9},
    "constraint_violations": {"rel": 0.0, "abs": 0.0},
    "max_violation": {"rel": 1e-2, "abs": 1e-6},
}
BASELINE_FORMAT = 1


@dataclass(frozen=True)
class MetricCheck:
    """One metric of one scenario against its baseline."""

    scenario: str
    metric: str
    baseline: float | None
    now: float | None
    rel: float
    abs: float
    passed: bool
    note: str = ""

    @property
    def tolerance(self) -> str:
        """The tolerance as text (``abs + rel·|baseline|``)."""
        parts = []
        if self.abs:
            parts.append(f"{self.abs:g}")
        if self.rel:
            parts.append(f"{self.rel:g}·|b|")
        return " + ".join(parts) or "exact"

    def describe(self) -> str:
        """One line: the metric, both values, the tolerance and, for a failure, why."""
        why = f" ({self.note})" if self.note else ""
        return (
            f"{self.scenario}: {self.metric}: baseline {_fmt(self.baseline, self.metric)}, "
            f"now {_fmt(self.now, self.metric)}, tolerance {self.tolerance}{why}"
        )


@dataclass
class RegressionReport:
    """All checks of a regression run."""

    checks: list[MetricCheck] = field(default_factory=list)
    missing: list[str] = field(default_factory=list)
    errors: dict[str, str] = field(default_factory=dict)
    updated: list[str] = field(default_factory=list)
    scenarios: list[str] = field(default_factory=list)
    wall_time_s: float = 0.0
    folder: Path | None = None
    update: bool = False

    @property
    def failures(self) -> list[MetricCheck]:
        return [c for c in self.checks if not c.passed]

    @property
    def passed(self) -> bool:
        return not self.failures and not self.missing and not self.errors


def baseline_path(scenario_path: str | Path) -> Path:
    """``NAME.baseline.json`` beside ``NAME.toml``."""
    p = Path(scenario_path)
    return p.with_name(p.stem + ".baseline.json")


def read_baseline(path: str | Path) -> dict[str, float | bool | None]:
    """The metrics stored in a baseline file (``null``: undefined, None).

    A baseline written before undefined metrics were ``null`` may hold
    ``"inf"`` for a settling or rise time that never happened: it is read as None.

    Raises:
        FileNotFoundError: no baseline.
        ConfigError: the file is not a baseline (corrupt, another ``format``, a metric that is not a number,
            true/false or null, a NaN or an infinity).
    """
    p = Path(path)
    hint = f"rewrite it with 'shinro-ctrl regress {p.parent} --update'"
    try:
        data = json.loads(p.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise
    except (ValueError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{p}: not a valid baseline file ({exc}); {hint}") from None
    except RecursionError:
        raise ConfigError(f"{p}: not a valid baseline file (nested too deeply); {hint}") from None
    if not isinstance(data, dict) or not isinstance(data.get("metrics"), dict):
        raise ConfigError(f"{p}: not a valid baseline file (no 'metrics' table); {hint}")
    fmt = data.get("format")
    if isinstance(fmt, bool) or fmt != BASELINE_FORMAT:
        raise ConfigError(f"{p}: baseline 'format' must be {BASELINE_FORMAT}, found {fmt!r}; {hint}")
    out: dict[str, float | bool | None] = {}
    for k, v in data["metrics"].items():
        if v == "inf" and k in NEVER_METRICS:  # the older spelling of "never"
            v = None
        if isinstance(v, bool) or v is None:
            if isinstance(v, bool) and k not in FLAG_METRICS:
                raise ConfigError(f"{p}: metric '{k}' must be a number or null, found {v!r}; {hint}")
            out[k] = v
            continue
        if not isinstance(v, int | float) or not math.isfinite(v):
            raise ConfigError(f"{p}: metric '{k}' must be a finite number or null, found {v!r}; {hint}")
        out[k] = v if isinstance(v, int) else float(v)
    return out


def baseline_text(result: Any) -> str:
    """The baseline file's JSON text for ``result`` (a :class:`~shinro_ctrl.sim.SimResult`)."""
    from shinro_ctrl import __version__
    from shinro_ctrl._text_formats import json_safe

    data = {
        "format": BASELINE_FORMAT,
        "scenario": result.scenario,
        "loop": result.loop,
        "shinro_ctrl": __version__,
        "metrics": result.metrics,
    }
    return json.dumps(json_safe(data), indent=2, sort_keys=True) + "\n"


def write_baseline(path: str | Path, result: Any) -> Path:
    """Store ``result.metrics`` (a :class:`~shinro_ctrl.sim.SimResult`) atomically (a symlink is written through)."""
    from shinro_ctrl.files import atomic_write

    text = baseline_text(result)
    return atomic_write(path, lambda f: f.write(text))


def _undefined(v: Any) -> bool:
    return v is None or (isinstance(v, float) and not math.isfinite(v))


def _check(metric: str, value: Any, base: Any, rel: float, ab: float) -> tuple[bool, str]:
    """``(passed, why it failed)`` of one metric against its baseline value."""
    if metric in FLAG_METRICS or isinstance(value, bool) or isinstance(base, bool):
        if bool(value) == bool(base) and not _undefined(value) and not _undefined(base):
            return True, ""
        if metric == "stable" and base and not value:
            return False, "the baseline run was stable, this run is not (it diverged or never settled)"
        return False, f"{metric} changed from {base!r} to {value!r}"
    if _undefined(value) and _undefined(base):
        return True, ""
    if _undefined(value):
        what = "never happens" if metric in NEVER_METRICS else "is undefined"
        return False, f"{metric} {what} in this run but is {_fmt(base, metric)} in the baseline"
    if _undefined(base):
        what = "never happened" if metric in NEVER_METRICS else "was undefined"
        return False, f"{metric} {what} in the baseline but is {_fmt(value, metric)} in this run"
    if abs(float(value) - float(base)) <= ab + rel * abs(float(base)):
        return True, ""
    return False, ""


def compare_metrics(
    scenario: str,
    now: Mapping[str, float | bool | None],
    baseline: Mapping[str, float | bool | None],
    tolerances: Mapping[str, Mapping[str, float]] | None = None,
) -> list[MetricCheck]:
    """Check every metric of ``now`` against ``baseline``.

    An undefined value (None) matches only an undefined one; ``stable``
    must be equal (a baseline with ``stable = true`` fails a run that is not,
    with one line). A metric the baseline does not hold fails, except those
    older baselines predate (:data:`~shinro_ctrl.sim.metrics.NEWER_METRICS`: the step-response
    metrics, ``stable``, ``saturation_fraction`` and the per-input times at a bound).

    Args:
        scenario: Name used in the checks.
        now: Current metrics.
        baseline: Stored metrics.
        tolerances: Per-metric ``{"rel": r, "abs": a}`` overriding the defaults.
    """
    tolerances = dict(tolerances or {})
    checks = []
    for metric, value in now.items():
        if metric in WALL_CLOCK_METRICS and metric not in tolerances:
            continue
        tol = {**DEFAULT_TOLERANCES.get(metric, {"rel": 1e-3, "abs": 1e-9}), **tolerances.get(metric, {})}
        rel, ab = float(tol.get("rel", 0.0)), float(tol.get("abs", 0.0))
        if metric not in baseline:
            if is_newer_metric(metric):
                continue  # metrics newer than the baseline: `regress --update` stores them
            why = "not in the baseline: record it with --update"
            checks.append(MetricCheck(scenario, metric, None, value, rel, ab, False, why))
            continue
        base = baseline[metric]
        ok, why = _check(metric, value, base, rel, ab)
        checks.append(MetricCheck(scenario, metric, base, value, rel, ab, ok, why))
    return checks


def regression_paths(target: str | Path | None) -> tuple[Path, list[Path]]:
    """The folder and the scenario files a regression run covers.

    Args:
        target: A folder of ``*.toml`` scenarios, a single scenario file, or
            None for the shipped set.

    Raises:
        FileNotFoundError: no such folder or file, or a folder without scenarios.
    """
    from shinro_ctrl.resources import regression_dir

    path = regression_dir() if target is None else Path(target)
    if path.is_file():
        if path.suffix != ".toml":
            raise FileNotFoundError(f"'{path}' is not a regression scenario (*.toml) or a folder of them")
        return path.parent, [path]
    if not path.is_dir():
        raise FileNotFoundError(f"no regression folder or scenario file '{path}'")
    paths = sorted(p for p in path.glob("*.toml") if p.is_file())
    if not paths:
        raise FileNotFoundError(f"no regression scenarios (*.toml) in '{path}'")
    return path, paths


def run_regression(
    directory: str | Path | None = None, *, update: bool = False, progress: bool | None = None
) -> RegressionReport:
    """Run every scenario in ``directory`` (default: the shipped ``configs/regression``).

    Every scenario (and, when comparing, every baseline) is parsed and
    validated before anything runs; with ``update`` the baselines are written
    only after every scenario ran, as one set (:func:`~shinro_ctrl.files.atomic_write_set`:
    all new or all old even if killed), and not at all if a run failed.

    Args:
        directory: Folder of regression scenarios, or one scenario file.
        update: Rewrite the baselines instead of comparing. The shipped
            baselines inside the installed package are rewritten only when
            their folder is named explicitly.
        progress: Passed to :meth:`RobotSim.run`.

    Raises:
        FileNotFoundError: the folder does not exist or holds no scenario.
        ConfigError: a scenario or baseline is invalid (nothing was run or written).
        InvalidArgument: ``update`` without a folder.
    """
    from shinro_ctrl.files import atomic_write_set, recover_journals, remove_stale_temps
    from shinro_ctrl.resources import regression_dir
    from shinro_ctrl.sim import RobotSim

    if update and directory is None:
        raise InvalidArgument(
            f"refusing to rewrite the shipped baselines in '{regression_dir()}' without their folder named; "
            "update your own folder with 'shinro-ctrl regress DIR --update'"
        )
    folder, paths = regression_paths(directory)
    report = RegressionReport(folder=folder, update=update)
    recover_journals(folder)  # an update killed after its commit point completes first
    if update:  # temporaries orphaned by a killed earlier update (a live concurrent writer's are locked)
        remove_stale_temps(folder, ".*.baseline.json.*.tmp")
    # 1. parse and validate everything
    sims = []
    for path in paths:
        sim = RobotSim.from_config(path)
        if not update and baseline_path(path).exists():
            read_baseline(baseline_path(path))
        sims.append((path, sim))
    # 2. run
    t0 = time.perf_counter()
    results = {}
    for path, sim in sims:
        label = f"{path.stem} ({sim.loop})"
        report.scenarios.append(label)
        try:
            result = sim.run(progress=progress)
        except ShinroError as exc:  # a run that diverges or turns infeasible is a regression, not an abort
            report.errors[label] = f"{type(exc).__name__}: {str(exc).splitlines()[0]}"
            continue
        if update:
            results[label] = (baseline_path(path), result)
            continue
        try:
            baseline = read_baseline(baseline_path(path))
        except FileNotFoundError:
            report.missing.append(label)
            continue
        report.checks.extend(compare_metrics(label, result.metrics, baseline, sim.scenario.regression))
    report.wall_time_s = time.perf_counter() - t0
    # 3. write, all or nothing
    if update and not report.errors:
        atomic_write_set({base: baseline_text(result) for base, result in results.values()}, folder)
        report.updated.extend(results)
    return report


def _fmt(v: float | bool | None, metric: str = "") -> str:
    return format_metric(metric, v)


def format_report(report: RegressionReport) -> str:
    """The table (scenario, metric, baseline, now, tolerance, verdict) and a summary line."""
    rows = [("scenario", "metric", "baseline", "now", "tolerance", "verdict")]
    for c in report.checks:
        verdict = "ok" if c.passed else "FAIL"
        rows.append((c.scenario, c.metric, _fmt(c.baseline, c.metric), _fmt(c.now, c.metric), c.tolerance, verdict))
    widths = [max(len(r[i]) for r in rows) for i in range(6)]
    lines = ["  ".join(cell.ljust(w) for cell, w in zip(r, widths, strict=True)).rstrip() for r in rows]
    lines.insert(1, "  ".join("-" * w for w in widths))
    if not report.checks:
        lines = []
    lines.extend(f"FAIL {c.describe()}" for c in report.failures if c.note)
    where = f" {report.folder}" if report.folder is not None else " DIR"
    for label in report.missing:
        lines.append(f"{label}: no baseline (record one with 'shinro-ctrl regress{where} --update')")
    for label, message in report.errors.items():
        lines.append(f"{label}: FAILED to run: {message}")
    for label in report.updated:
        lines.append(f"{label}: baseline written")
    if report.update and report.errors:
        lines.append("no baseline written: every scenario must run before the set is updated")
    n = len(report.scenarios)
    verdict = "FAILED" if report.errors else "updated" if report.updated else ("passed" if report.passed else "FAILED")
    lines.append(f"{n} scenario runs in {report.wall_time_s:.1f} s: {verdict}")
    return "\n".join(lines)
