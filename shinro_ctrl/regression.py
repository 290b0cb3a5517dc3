"""Controller regression tests: scenario metrics compared with stored baselines.

Each scenario ``NAME.toml`` in a regression folder has its baseline
``NAME.baseline.json`` beside it. A metric passes when

    |now − baseline| ≤ abs + rel · |baseline|

with ``rel``/``abs`` from the scenario's ``[regression]`` table, or the
defaults in :data:`DEFAULT_TOLERANCES` (tight: the runs are deterministic).
Wall-clock metrics (``solve_time_median_s``) are compared only when the
scenario gives a tolerance for them.
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from shinro_ctrl.errors import ConfigError, ShinroError

__all__ = [
    "DEFAULT_TOLERANCES",
    "MetricCheck",
    "RegressionReport",
    "baseline_path",
    "compare_metrics",
    "format_report",
    "read_baseline",
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
TIMING_METRICS = ("solve_time_median_s",)
BASELINE_FORMAT = 1


@dataclass(frozen=True)
class MetricCheck:
    """One metric of one scenario against its baseline."""

    scenario: str
    metric: str
    baseline: float | None
    now: float
    rel: float
    abs: float
    passed: bool

    @property
    def tolerance(self) -> str:
        """The tolerance as text (``abs + rel·|baseline|``)."""
        parts = []
        if self.abs:
            parts.append(f"{self.abs:g}")
        if self.rel:
            parts.append(f"{self.rel:g}·|b|")
        return " + ".join(parts) or "exact"


@dataclass
class RegressionReport:
    """All checks of a regression run."""

    checks: list[MetricCheck] = field(default_factory=list)
    missing: list[str] = field(default_factory=list)
    errors: dict[str, str] = field(default_factory=dict)
    updated: list[str] = field(default_factory=list)
    scenarios: list[str] = field(default_factory=list)
    wall_time_s: float = 0.0

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


def _to_float(v: Any) -> float:
    if v == "inf":
        return math.inf
    if v == "-inf":
        return -math.inf
    return math.nan if v is None else float(v)


def read_baseline(path: str | Path) -> dict[str, float]:
    """The metrics stored in a baseline file.

    Raises:
        FileNotFoundError: no baseline.
        ConfigError: the file is not a baseline (corrupt or another format).
    """
    p = Path(path)
    try:
        data = json.loads(p.read_text(encoding="utf-8"))
        return {k: _to_float(v) for k, v in data["metrics"].items()}
    except FileNotFoundError:
        raise
    except (ValueError, KeyError, TypeError, AttributeError) as exc:
        raise ConfigError(f"{p}: not a valid baseline file ({exc}); rewrite it with 'regress --update'") from None


def write_baseline(path: str | Path, result: Any) -> Path:
    """Store ``result.metrics`` (a :class:`~shinro_ctrl.sim.SimResult`) atomically."""
    from shinro_ctrl import __version__
    from shinro_ctrl.files import dump_json

    return dump_json(
        path,
        {
            "format": BASELINE_FORMAT,
            "scenario": result.scenario,
            "loop": result.loop,
            "shinro_ctrl": __version__,
            "metrics": result.metrics,
        },
    )


def compare_metrics(
    scenario: str,
    now: Mapping[str, float],
    baseline: Mapping[str, float],
    tolerances: Mapping[str, Mapping[str, float]] | None = None,
) -> list[MetricCheck]:
    """Check every metric of ``now`` against ``baseline``.

    Args:
        scenario: Name used in the checks.
        now: Current metrics.
        baseline: Stored metrics.
        tolerances: Per-metric ``{"rel": r, "abs": a}`` overriding the defaults.
    """
    tolerances = dict(tolerances or {})
    checks = []
    for metric, value in now.items():
        if metric in TIMING_METRICS and metric not in tolerances:
            continue
        tol = {**DEFAULT_TOLERANCES.get(metric, {"rel": 1e-3, "abs": 1e-9}), **tolerances.get(metric, {})}
        rel, ab = float(tol.get("rel", 0.0)), float(tol.get("abs", 0.0))
        base = baseline.get(metric)
        value = float(value)
        if base is None or math.isnan(base):
            ok = False
        elif math.isinf(base) or math.isinf(value):
            ok = base == value
        else:
            ok = abs(value - base) <= ab + rel * abs(base)
        checks.append(MetricCheck(scenario, metric, base, value, rel, ab, ok))
    return checks


def run_regression(
    directory: str | Path | None = None, *, update: bool = False, progress: bool | None = None
) -> RegressionReport:
    """Run every scenario in ``directory`` (default: the shipped ``configs/regression``).

    Args:
        directory: Folder of regression scenarios.
        update: Rewrite every baseline (atomically) instead of comparing.
        progress: Passed to :meth:`RobotSim.run`.

    Raises:
        FileNotFoundError: the folder does not exist or holds no scenario.
        ConfigError: a scenario or baseline is invalid.
    """
    from shinro_ctrl.resources import regression_dir
    from shinro_ctrl.sim import RobotSim

    folder = regression_dir() if directory is None else Path(directory)
    if not folder.is_dir():
        raise FileNotFoundError(f"no regression folder '{folder}'")
    paths = sorted(folder.glob("*.toml"))
    if not paths:
        raise FileNotFoundError(f"no regression scenarios (*.toml) in '{folder}'")
    report = RegressionReport()
    if update:  # temporary files orphaned by an interrupted earlier update (see files.atomic_write)
        for orphan in folder.glob(".*.baseline.json.*.tmp"):
            orphan.unlink(missing_ok=True)
    t0 = time.perf_counter()
    for path in paths:
        sim = RobotSim.from_config(path)
        label = f"{path.stem} ({sim.loop})"
        report.scenarios.append(label)
        try:
            result = sim.run(progress=progress)
        except ShinroError as exc:  # a run that diverges or turns infeasible is a regression, not an abort
            report.errors[label] = f"{type(exc).__name__}: {str(exc).splitlines()[0]}"
            continue
        base = baseline_path(path)
        if update:
            write_baseline(base, result)
            report.updated.append(label)
            continue
        try:
            baseline = read_baseline(base)
        except FileNotFoundError:
            report.missing.append(label)
            continue
        report.checks.extend(compare_metrics(label, result.metrics, baseline, sim.scenario.regression))
    report.wall_time_s = time.perf_counter() - t0
    return report


def _fmt(v: float | None) -> str:
    if v is None:
        return "—"
    if math.isinf(v):
        return "inf" if v > 0 else "-inf"
    return f"{v:.6g}"


def format_report(report: RegressionReport) -> str:
    """The table (scenario, metric, baseline, now, tolerance, verdict) and a summary line."""
    rows = [("scenario", "metric", "baseline", "now", "tolerance", "verdict")]
    for c in report.checks:
        rows.append((c.scenario, c.metric, _fmt(c.baseline), _fmt(c.now), c.tolerance, "ok" if c.passed else "FAIL"))
    widths = [max(len(r[i]) for r in rows) for i in range(6)]
    lines = ["  ".join(cell.ljust(w) for cell, w in zip(r, widths, strict=True)).rstrip() for r in rows]
    lines.insert(1, "  ".join("-" * w for w in widths))
    if not report.checks:
        lines = []
    for label in report.missing:
        lines.append(f"{label}: no baseline (run 'shinro-ctrl regress --update' to record one)")
    for label, message in report.errors.items():
        lines.append(f"{label}: FAILED to run: {message}")
    for label in report.updated:
        lines.append(f"{label}: baseline written")
    n = len(report.scenarios)
    verdict = "FAILED" if report.errors else "updated" if report.updated else ("passed" if report.passed else "FAILED")
    lines.append(f"{n} scenario runs in {report.wall_time_s:.1f} s: {verdict}")
    return "\n".join(lines)
