"""The ``[plan]`` table of a scenario: validation and the plan it describes.

Keys (all optional except ``start`` and ``goal`` when no ``file`` is given)::

    [plan]
    start = [0, 0, 3.14159, 0]        # x_start (n,)
    goal = [0, 0, 0, 0]               # x_goal (n,); nan = free component
    knots = 61                        # N
    method = "hermite_simpson"        # | "trapezoid" | "multiple_shooting"
    duration = [0.5, 5.0]             # fixed T, or [T_min, T_max]; absent: free in [0.1, 10] s
    cost = { time = 1, effort = 10 }  # or "effort" | "time"
    bounds = { u_min = [-5], u_max = [5], x_min = [-1, -inf, -inf, -inf], x_max = [1, inf, inf, inf] }
    substeps = 1                      # RK4 steps per interval (multiple_shooting)
    file = "plan.npz"                 # load a saved Trajectory instead of solving

Solved plans are kept in a small cache keyed by the plant's class, parameters,
``dt`` and the table, so a sweep that rebuilds the controller on the same
nominal plant for every sample plans once.

The last knot's input is pinned to the equilibrium input at the goal when the
goal is an equilibrium (so the regulator that takes over starts from rest).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from shinro_ctrl.errors import InvalidArgument, PlanningFailed
from shinro_ctrl.planning.trajectory import METHODS, Trajectory, check_transcription_size
from shinro_ctrl.validation import did_you_mean

__all__ = [
    "BOUND_KEYS",
    "PLAN_KEYS",
    "check_origin",
    "check_plan",
    "equilibrium_input",
    "make_plan",
    "plan_origin",
    "with_plan_file",
]

_CACHE: dict[str, Trajectory] = {}
_CACHE_SIZE = 8

PLAN_KEYS = ("start", "goal", "knots", "method", "duration", "cost", "bounds", "substeps", "file")
BOUND_KEYS = ("u_min", "u_max", "x_min", "x_max")


def _vector(key: str, value: Any, size: int, *, allow_nan: bool = False, allow_inf: bool = False) -> list[float]:
    if not isinstance(value, list | tuple | np.ndarray) or len(value) != size:
        raise InvalidArgument(f"'{key}' must be a list of {size} numbers, got {value!r}")
    out = []
    for v in value:
        if isinstance(v, bool) or not isinstance(v, int | float | np.floating | np.integer):
            raise InvalidArgument(f"'{key}' must hold numbers only, got {v!r}")
        v = float(v)
        if (math.isnan(v) and not allow_nan) or (math.isinf(v) and not allow_inf):
            raise InvalidArgument(f"'{key}' must be finite{' or nan (free)' if allow_nan else ''}, got {value!r}")
        out.append(v)
    return out


def check_plan(spec: Any, n: int, m: int) -> dict[str, Any]:
    """Validate a plan table for a plant with ``n`` states and ``m`` inputs; return it normalized.

    Raises:
        InvalidArgument: an unknown key (with the closest valid one), a wrong
            type, size or value, naming the key.
    """
    if not isinstance(spec, Mapping):
        raise InvalidArgument(f"the plan must be a table, got {spec!r}")
    for key in spec:
        if key not in PLAN_KEYS:
            raise InvalidArgument(f"unknown key '{key}'{did_you_mean(str(key), PLAN_KEYS)}")
    out: dict[str, Any] = {}
    if "file" in spec:
        if not isinstance(spec["file"], str | Path) or not str(spec["file"]):
            raise InvalidArgument(f"'file' must be a path to a saved plan (.npz), got {spec['file']!r}")
        out["file"] = str(spec["file"])
    elif "start" not in spec or "goal" not in spec:
        missing = "start" if "start" not in spec else "goal"
        raise InvalidArgument(f"missing key '{missing}' (a state of {n} values), or give 'file'")
    if "start" in spec:
        out["start"] = _vector("start", spec["start"], n)
    if "goal" in spec:
        out["goal"] = _vector("goal", spec["goal"], n, allow_nan=True)
    if "method" in spec:
        meth = spec["method"]
        if meth not in METHODS:
            raise InvalidArgument(f"'method': unknown transcription {meth!r}{did_you_mean(str(meth), METHODS)}")
    knots, substeps = check_transcription_size(
        spec.get("knots", 61), spec.get("substeps", 1), spec.get("method", "hermite_simpson")
    )
    if "knots" in spec:
        out["knots"] = knots
    if "substeps" in spec:
        out["substeps"] = substeps
    if "method" in spec:
        meth = spec["method"]
        if meth not in METHODS:
            raise InvalidArgument(f"'method': unknown transcription {meth!r}{did_you_mean(str(meth), METHODS)}")
        out["method"] = meth
    if "duration" in spec:
        out["duration"] = _duration(spec["duration"])
    if "cost" in spec:
        out["cost"] = _cost(spec["cost"], m)
    if "bounds" in spec:
        out["bounds"] = _bounds(spec["bounds"], n, m)
    return out


def _duration(d: Any) -> float | list[float]:
    """The plan's ``duration``: a time or a ``[T_min, T_max]`` pair with ``0 < T_min <= T_max``."""
    if isinstance(d, int | float) and not isinstance(d, bool):
        lo = hi = float(d)
        out = float(d)
    elif isinstance(d, list | tuple) and len(d) == 2:
        lo, hi = _vector("duration", d, 2)
        out = [lo, hi]
    else:
        raise InvalidArgument(f"'duration' must be a time [s] or a [T_min, T_max] pair, got {d!r}")
    if not (math.isfinite(lo) and math.isfinite(hi) and 0 < lo <= hi):
        raise InvalidArgument(f"'duration' must satisfy 0 < T_min <= T_max, got {d!r}")
    return out


def _cost(c: Any, m: int) -> str | dict[str, Any]:
    """The plan's ``cost``: a preset name or ``{time = w, effort = w or (m,)}``."""
    if isinstance(c, str):
        if c not in ("effort", "time"):
            raise InvalidArgument(f"'cost': unknown preset {c!r}{did_you_mean(c, ('effort', 'time'))}")
        return c
    if isinstance(c, Mapping):
        for key in c:
            if key not in ("time", "effort"):
                raise InvalidArgument(f"'cost': unknown key '{key}'{did_you_mean(str(key), ('time', 'effort'))}")
        cost: dict[str, Any] = {}
        if "time" in c:
            cost["time"] = _vector("cost.time", [c["time"]], 1)[0]
        if "effort" in c:
            e = c["effort"]
            as_list = isinstance(e, list)
            cost["effort"] = _vector("cost.effort", e, m) if as_list else _vector("cost.effort", [e], 1)[0]
        return cost
    raise InvalidArgument(f"'cost' must be 'effort', 'time' or {{ time = w, effort = w }}, got {c!r}")


def _bounds(b: Any, n: int, m: int) -> dict[str, list[float]]:
    """The plan's ``bounds`` table (``u_min``/``u_max`` of ``m``, ``x_min``/``x_max`` of ``n`` values)."""
    if not isinstance(b, Mapping):
        raise InvalidArgument(f"'bounds' must be a table {{ u_min = [...], ... }}, got {b!r}")
    for key in b:
        if key not in BOUND_KEYS:
            raise InvalidArgument(f"'bounds': unknown key '{key}'{did_you_mean(str(key), BOUND_KEYS)}")
    return {
        key: _vector(f"bounds.{key}", b[key], m if key.startswith("u") else n, allow_inf=True)
        for key in BOUND_KEYS
        if key in b
    }


def equilibrium_input(plant: Any, x: np.ndarray, u_guess: np.ndarray, *, tol: float = 1e-8) -> np.ndarray | None:
    """The input that holds ``plant`` at rest in state ``x``, or None if there is none.

    Gauss-Newton on ``min_u |f(x, u)|²`` from ``u_guess`` (a few exact
    Jacobian steps; exact in one step for input-affine dynamics).

    Args:
        plant: Any plant.
        x: State ``(n,)``.
        u_guess: Starting input ``(m,)``.
        tol: Largest ``|f(x, u)|`` accepted as "at rest".
    """
    u = np.asarray(u_guess, dtype=float).copy()
    for _ in range(5):
        r = plant.dynamics(x, u)
        if np.max(np.abs(r)) <= tol:
            return u
        _, B = plant.linearize(x, u)
        du = np.linalg.lstsq(B, -r, rcond=None)[0]
        u = u + du
    return u if np.max(np.abs(plant.dynamics(x, u))) <= tol else None


def make_plan(plant: Any, spec: Mapping[str, Any]) -> Trajectory:
    """Solve (or load) the plan a validated ``[plan]`` table describes.

    Args:
        plant: The plant the plan is for (the nominal model).
        spec: The table (see the module doc); validated with :func:`check_plan`.

    Raises:
        InvalidArgument: invalid table, or a loaded plan of the wrong size.
        PlanningFailed: IPOPT did not converge.
        FileNotFoundError: ``file`` does not exist.
    """
    from shinro_ctrl.planning.collocation import TrajectoryOptimizer

    n, m = plant.state_dim, plant.input_dim
    spec = check_plan(spec, n, m)
    if "file" in spec:
        traj = Trajectory.load(spec["file"])
        if traj.state_dim != n or traj.input_dim != m:
            raise InvalidArgument(
                f"plan file {spec['file']}: expected a plan with {n} states and {m} inputs but found "
                f"{traj.state_dim} and {traj.input_dim}"
            )
        check_origin(traj, plan_origin(plant, spec), spec["file"])
        return traj
    key = repr((type(plant).__name__, sorted(plant.params().items()), plant.dt, sorted(spec.items())))
    if key in _CACHE:
        return _CACHE[key]
    bounds = spec.get("bounds", {})
    opt = TrajectoryOptimizer(
        plant,
        knots=spec.get("knots", 61),
        method=spec.get("method", "hermite_simpson"),
        substeps=spec.get("substeps", 1),
        **{k: bounds.get(k) for k in BOUND_KEYS},
    )
    goal = np.asarray(spec["goal"], dtype=float)
    u_goal = None
    if not np.any(np.isnan(goal)):
        u_goal = equilibrium_input(plant, goal, plant.equilibrium()[1])
        if u_goal is not None and (np.any(u_goal < opt.u_min) or np.any(u_goal > opt.u_max)):
            raise PlanningFailed(
                f"infeasible plan: the input that holds the goal, {np.array2string(u_goal, precision=4)}, "
                "is outside u_min/u_max"
            )
    traj = opt.solve(spec["start"], goal, duration=spec.get("duration"), cost=spec.get("cost", "effort"), u_goal=u_goal)
    traj.origin = plan_origin(plant, spec)
    if len(_CACHE) >= _CACHE_SIZE:
        _CACHE.pop(next(iter(_CACHE)))
    _CACHE[key] = traj
    return traj


# ------------------------------------------------------------ plan origin
def plan_origin(plant: Any, spec: Mapping[str, Any]) -> dict[str, Any]:
    """What a plan is solved for: the plant's class, parameters and ``dt``, and the plan's ``bounds`` table."""
    return {
        "plant": type(plant).__name__,
        "params": _plain(plant.params()),
        "dt": float(plant.dt),
        "bounds": _plain(dict(spec.get("bounds", {}))),
    }


def _plain(value: Any) -> Any:
    """JSON-ready: arrays as lists, numpy scalars as Python numbers, ±inf as strings (as saved)."""
    import json

    from shinro_ctrl._text_formats import json_safe

    def conv(v: Any) -> Any:
        if isinstance(v, np.ndarray):
            return conv(v.tolist())
        if isinstance(v, np.generic):
            return v.item()
        if isinstance(v, Mapping):
            return {str(k): conv(x) for k, x in v.items()}
        if isinstance(v, list | tuple):
            return [conv(x) for x in v]
        if isinstance(v, Path):
            return str(v)
        return v

    return json.loads(json.dumps(json_safe(conv(value)), sort_keys=True))


def _differences(saved: Any, now: Any, where: str) -> list[str]:
    """``key: saved → now`` for every leaf that differs (floats to a relative 1e-9)."""
    if isinstance(saved, dict) and isinstance(now, dict):
        out = []
        for k in sorted(set(saved) | set(now)):
            key = f"{where}.{k}" if where else k
            if k not in saved or k not in now:
                out.append(f"{key} = {saved.get(k, '(none)')} in the plan, {now.get(k, '(none)')} in the scenario")
            else:
                out.extend(_differences(saved[k], now[k], key))
        return out
    if isinstance(saved, list) and isinstance(now, list) and len(saved) == len(now):
        if all(not _differences(a, b, where) for a, b in zip(saved, now, strict=True)):
            return []
        return [f"{where} = {saved} in the plan, {now} in the scenario"]
    numbers = (int, float)
    if isinstance(saved, numbers) and isinstance(now, numbers) and not isinstance(saved, bool):
        if math.isclose(float(saved), float(now), rel_tol=1e-9, abs_tol=1e-12):
            return []
    elif saved == now:
        return []
    return [f"{where} = {saved} in the plan, {now} in the scenario"]


def check_origin(traj: Trajectory, origin: Mapping[str, Any], source: str | Path = "plan") -> None:
    """Refuse a loaded plan solved for another plant, parameters, ``dt`` or bounds than ``origin``.

    Raises:
        InvalidArgument: naming the first mismatches (plan value, scenario value), or a plan
            without its origin (written before plans recorded it).
    """
    if traj.origin is None:
        raise InvalidArgument(
            f"plan file {source} does not record the plant, parameters, dt and bounds it was solved for "
            "(written by an older version): solve it again with 'shinro-ctrl plan CONFIG'"
        )
    saved = _plain(traj.origin)
    now = _plain(dict(origin))
    if saved.get("plant") != now.get("plant"):
        raise InvalidArgument(
            f"plan file {source} was solved for a {saved.get('plant')}, the scenario's plant is a {now.get('plant')}"
        )
    keys = ("params", "dt", "bounds")
    diffs = _differences({k: saved.get(k) for k in keys}, {k: now.get(k) for k in keys}, "")
    if diffs:
        more = f" (and {len(diffs) - 2} more)" if len(diffs) > 2 else ""
        raise InvalidArgument(
            f"plan file {source} was solved for another {now['plant']}: {'; '.join(diffs[:2])}{more}; "
            "solve the plan for this scenario with 'shinro-ctrl plan CONFIG'"
        )


def with_plan_file(scenario: Any, plan_file: str | Path) -> Any:
    """The scenario with its ``[plan]`` replaced by a saved plan (what ``run --plan FILE`` runs).

    The plan's ``start`` and ``bounds`` (the controller's saturation) are kept; the plan file
    is checked against the scenario's plant, parameters, ``dt`` and bounds when the
    controller is built (:func:`check_origin`).

    Args:
        scenario: A :class:`~shinro_ctrl.config.Scenario` whose controller tracks a plan.
        plan_file: A ``.npz`` written by ``shinro-ctrl plan`` (:meth:`Trajectory.save`).

    Returns:
        The same scenario object, changed in place.

    Raises:
        InvalidArgument: the scenario has no ``[plan]`` table.
    """
    if scenario.plan is None:
        raise InvalidArgument(f"--plan: {scenario.name} has no [plan] table (its controller tracks no plan)")
    spec = {k: v for k, v in scenario.plan.items() if k in ("start", "bounds")}  # bounds: the saturation
    spec["file"] = str(plan_file)
    scenario.plan = scenario.controller.options["plan"] = spec
    return scenario
