"""Units and panels: the SI unit of a state, input or swept parameter from its name, and the grouping of signals
into at most :data:`MAX_ROWS` panels."""

from __future__ import annotations

import re
from collections.abc import Sequence

__all__ = ["MAX_ROWS", "axis_label", "param_unit", "signal_groups", "unit_of"]

MAX_ROWS = 6

_ANGLE = re.compile(r"^(theta|phi|psi|alpha|beta|q|roll|pitch|yaw|angle|arm|pendulum|hinge|joint)(_?\d+)?$")
_RATE = re.compile(
    r"^((theta|phi|psi|alpha|beta|q|angle|arm|pendulum|hinge|joint)(_?\d+)?_dot|omega(_?\d+)?|[pqr]|\w+_rate)$"
)
_POSITION = re.compile(r"^(x|y|z|pos_?\w*|position\w*)(_?\d+)?$")
_VELOCITY = re.compile(r"^(x_dot|y_dot|z_dot|v[xyz]?|vel\w*|velocity\w*|\w+_velocity)(_?\d+)?$")
_FORCE = re.compile(r"^(f|force|thrust|f_?\w+)(_?\d+)?$", re.IGNORECASE)
_TORQUE = re.compile(r"^(tau|torque|moment|motor|m)(_?\w+)?$", re.IGNORECASE)
_KIND_TITLES = {"m": "position", "rad": "angle", "m/s": "velocity", "rad/s": "angular rate"}


def unit_of(name: str, *, is_input: bool = False) -> str:
    """The SI unit of a state or input from its name (``''`` when the name does not say).

    ``x, y, z`` → m; ``x_dot, vx`` → m/s; ``theta, roll, q1`` → rad;
    ``theta_dot, omega, p, q, r, *_rate`` → rad/s; inputs ``force, thrust`` → N,
    ``tau*, torque, motor`` → N m.
    """
    n = name.strip().lower()
    if is_input:
        if _FORCE.match(n):
            return "N"
        if _TORQUE.match(n):
            return "N m"
    if _VELOCITY.match(n):
        return "m/s"
    if _RATE.match(n):
        return "rad/s"
    if _ANGLE.match(n):
        return "rad"
    if _POSITION.match(n):
        return "m"
    return ""


def _units(names: Sequence[str], declared: Sequence[str] | None, *, is_input: bool) -> list[str]:
    if declared is not None and len(declared) == len(names):
        return [str(u) for u in declared]
    return [unit_of(s, is_input=is_input) for s in names]


def _label(name: str, unit: str) -> str:
    return f"{name} [{unit}]" if unit else name


def signal_groups(
    state_names: Sequence[str],
    input_names: Sequence[str],
    *,
    state_units: Sequence[str] | None = None,
    input_units: Sequence[str] | None = None,
    extra_rows: int = 0,
    max_rows: int = MAX_ROWS,
) -> list[tuple[str, str, list[tuple[str, int]]]]:
    """The panels of a run plot: ``[(title, unit, [("x" | "u", index), ...]), ...]``.

    One panel per signal when they fit in ``max_rows``; otherwise states of one
    unit share a panel (the quadrotor: position, attitude, velocity, angular
    rate), and inputs of one unit share one (thrust [N], torques [N m]).
    """
    su = _units(state_names, state_units, is_input=False)
    iu = _units(input_names, input_units, is_input=True)
    if len(state_names) + len(input_names) + extra_rows <= max_rows:
        panels = [(_label(s, su[i]), su[i], [("x", i)]) for i, s in enumerate(state_names)]
        panels += [(_label(s, iu[j]), iu[j], [("u", j)]) for j, s in enumerate(input_names)]
        return panels
    panels: list[tuple[str, str, list[tuple[str, int]]]] = []
    for kind, names, units in (("x", state_names, su), ("u", input_names, iu)):
        order: dict[str, list[tuple[str, int]]] = {}
        for i, _ in enumerate(names):
            order.setdefault(units[i], []).append((kind, i))
        for unit, members in order.items():
            if len(members) == 1:
                title = names[members[0][1]]
            elif kind == "x":
                title = _KIND_TITLES.get(unit, "states")
                if unit == "rad" and any(names[i] in ("roll", "pitch", "yaw") for _, i in members):
                    title = "attitude"
            else:
                title = "inputs"
            panels.append((f"{title} [{unit}]" if unit else title, unit, members))
    return panels


def axis_label(name: str, unit: str | None = None, *, is_input: bool = False) -> str:
    """``"name [unit]"``, the label every plot axis gets (``unit`` default :func:`unit_of` ``name``; no brackets
    when the unit is unknown)."""
    return _label(name, unit_of(name, is_input=is_input) if unit is None else unit)


_PARAM_UNITS = (
    (re.compile(r"(^|_)(mass|m[0-9]?)(_|$)"), "kg"),
    (re.compile(r"(length|radius|arm_length|offset|l[0-9]?$)"), "m"),
    (re.compile(r"(^|_)(gravity|g)$"), "m/s²"),
    (re.compile(r"(^|_)dt$"), "s"),
    (re.compile(r"(inertia|^i[xyz]{2}$)"), "kg m²"),
    (re.compile(r"yaw_moment_coefficient"), "m"),
)


def param_unit(key: str) -> str:
    """The unit of a swept key such as ``plant.pole_mass`` (``''`` when its name does not say)."""
    name = key.rsplit(".", 1)[-1].lower()
    for pattern, unit in _PARAM_UNITS:
        if pattern.search(name):
            return unit
    return ""


def _param_label(key: str) -> str:
    unit = param_unit(key)
    return f"{key} [{unit}]" if unit else key
