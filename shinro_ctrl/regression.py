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

from shinro_ctrl.errors import ConfigError, InvalidArgument, ShinroError
from shinro_ctrl.sim.metrics import RESPONSE_METRICS

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
        ConfigError: the file is not a baseline (corrupt, another ``format``, a metric that is not a number).
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
    out = {}
    for k, v in data["metrics"].items():
        if isinstance(v, bool) or not (isinstance(v, int | float) or v in ("inf", "-inf") or v is None):
            raise ConfigError(f"{p}: metric '{k}' must be a number, found {v!r}; {hint}")
        out[k] = _to_float(v)
    return out


def baseline_text(result: Any) -> str:
    """The baseline file's JSON text for ``result`` (a :class:`~shinro_ctrl.sim.SimResult`)."""
    from shinro_ctrl import __version__
    from shinro_ctrl.files import _json_safe

    data = {
        "format": BASELINE_FORMAT,
        "scenario": result.scenario,
        "loop": result.loop,
        "shinro_ctrl": __version__,
        "metrics": result.metrics,
    }
    return json.dumps(_json_safe(data), indent=2, sort_keys=True) + "\n"


def write_baseline(path: str | Path, result: Any) -> Path:
    """Store ``result.metrics`` (a :class:`~shinro_ctrl.sim.SimResult`) atomically (a symlink is written through)."""
    from shinro_ctrl.files import atomic_write

    text = baseline_text(result)
    return atomic_write(path, lambda f: f.write(text))


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
        if base is None and metric in RESPONSE_METRICS:
            continue  # step-response metrics newer than the baseline: `regress --update` stores them
        value = float(value)
        if base is None or math.isnan(base):
            ok = False
        elif math.isinf(base) or math.isinf(value):
            ok = base == value
        else:
            ok = abs(value - base) <= ab + rel * abs(base)
        checks.append(MetricCheck(scenario, metric, base, value, rel, ab, ok))
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
