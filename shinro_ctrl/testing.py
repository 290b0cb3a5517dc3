"""Pytest helpers for controller regression tests in users' own test suites.

Installed as a pytest plugin (entry point ``shinro_ctrl``), so the
:func:`run_scenario` fixture is available in any test once the package is
installed::

    from shinro_ctrl.testing import assert_matches_baseline

    def test_my_gains(run_scenario, tmp_path):
        result = run_scenario("configs/my_cartpole.toml")
        assert_matches_baseline(result, "configs/my_cartpole.baseline.json", {"rms_error": {"rel": 0.01}})

Set ``SHINRO_UPDATE_BASELINES=1`` to (re)write the baselines instead of
comparing, after a deliberate change.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import pytest

from shinro_ctrl.regression import compare_metrics, read_baseline, write_baseline

__all__ = ["assert_matches_baseline", "run_scenario"]


def assert_matches_baseline(
    result: Any,
    path: str | Path,
    tolerances: Mapping[str, Mapping[str, float]] | None = None,
    *,
    update: bool | None = None,
) -> None:
    """Assert that ``result.metrics`` match the baseline file within tolerances.

    Args:
        result: A :class:`~shinro_ctrl.sim.SimResult`.
        path: The baseline JSON file.
        tolerances: Per-metric ``{"rel": r, "abs": a}`` (defaults: the
            regression defaults, tight for deterministic metrics).
        update: Write the baseline instead of comparing (default: the
            ``SHINRO_UPDATE_BASELINES`` environment variable).

    Raises:
        AssertionError: a metric is out of tolerance or the baseline is missing,
            with a table of every failing metric.
    """
    if update is None:
        update = os.environ.get("SHINRO_UPDATE_BASELINES", "") not in ("", "0")
    path = Path(path)
    if update:
        write_baseline(path, result)
        return
    if not path.exists():
        raise AssertionError(f"no baseline at {path}; run with SHINRO_UPDATE_BASELINES=1 to record one")
    checks = compare_metrics(result.scenario, result.metrics, read_baseline(path), tolerances)
    failed = [c for c in checks if not c.passed]
    if failed:
        lines = [f"{len(failed)} metric(s) of {result.scenario} moved away from {path}:"]
        lines += [f"  {c.describe()}" for c in failed]
        raise AssertionError("\n".join(lines))


@pytest.fixture
def run_scenario() -> Callable[..., Any]:
    """A function ``run_scenario(config, *, engine=None, duration=None) -> SimResult``.

    ``config`` is a path, a shipped scenario name or a dict; ``engine``
    overrides the loop (``"standalone"`` or ``"mujoco"``).
    """
    from shinro_ctrl.sim import RobotSim

    def _run(config: Any, *, engine: str | None = None, duration: float | None = None) -> Any:
        return RobotSim.from_config(config, engine=engine).run(duration, progress=False)

    return _run
