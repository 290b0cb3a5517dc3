"""The shared array aliases (shinro_ctrl.types): the scenario checker reads them as numbers or arrays of numbers.

A ``from_plant`` annotated ``Q: Weight`` or ``x0: Vector | None`` must check a TOML value as strictly as the
``Any`` it replaced: a string, a boolean or a ragged array is refused by key, a number, an array or a table of
numbers (Bryson weights) passes.
"""

from __future__ import annotations

import inspect

import pytest

from shinro_ctrl.config import parse_scenario
from shinro_ctrl.config.strict import check_value
from shinro_ctrl.controllers import LQR, TVLQR, LinearMPC, NonlinearMPC
from shinro_ctrl.errors import ConfigError
from shinro_ctrl.estimators import ExtendedKalmanFilter, KalmanFilter, Luenberger
from shinro_ctrl.types import NUMERIC_ALIASES

BAD = {
    "string": ("fast", "must be a number or an array of numbers, got string"),
    "boolean": (True, "must be a number or an array of numbers, got boolean"),
    "strings": (["1", "2"], "must be a number or an array of numbers"),
    "ragged": ([[1.0, 2.0], [3.0]], "is ragged"),
    "table_of_strings": ({"bryson": ["a"]}, "must be a number or an array of numbers"),
}
GOOD = [0.5, 3, [1.0, 2.0], [[1.0, 0.0], [0.0, 1.0]], {"bryson": [1.0, 2.0]}]


@pytest.mark.parametrize("alias", sorted(NUMERIC_ALIASES))
@pytest.mark.parametrize("case", sorted(BAD))
def test_an_alias_refuses_what_is_not_numbers(alias, case):
    value, needle = BAD[case]
    for annotation in (alias, f"{alias} | None", f"shinro_ctrl.types.{alias}"):
        problem = check_value(value, annotation, "k")
        assert problem is not None and needle in problem, (annotation, problem)


@pytest.mark.parametrize("alias", sorted(NUMERIC_ALIASES))
def test_an_alias_accepts_numbers_arrays_and_tables_of_numbers(alias):
    for value in GOOD:
        assert check_value(value, alias, "k") is None, value


def test_an_unknown_annotation_still_checks_only_structure():
    """The aliases are recognised by name: another name keeps the checker's structural-only rule."""
    assert check_value("fast", "SomethingElse", "k") is None


@pytest.mark.parametrize(
    ("cls", "keys"),
    [
        (LQR, ("Q", "R", "x0", "u0", "u_min", "u_max")),
        (LinearMPC, ("Q", "R", "x0", "u0")),
        (KalmanFilter, ("Qn", "Rn", "x0", "u0", "Qd")),
        (ExtendedKalmanFilter, ("Qn", "Rn")),
        (Luenberger, ("poles", "x0", "u0")),
        (NonlinearMPC, ("Q", "R")),
        (TVLQR, ("Q", "R")),
    ],
)
def test_scenario_keys_are_annotated_with_an_alias(cls, keys):
    """The keys a scenario table fills name an alias (no ``Any``), so the checker above applies to them."""
    params = inspect.signature(cls.from_plant).parameters
    for key in keys:
        atoms = {a.strip().rsplit(".", 1)[-1] for a in str(params[key].annotation).split("|")} - {"None"}
        assert atoms and atoms <= NUMERIC_ALIASES, (cls.__name__, key, params[key].annotation)


@pytest.mark.parametrize(
    ("estimator", "key", "value"),
    [
        ({"type": "Luenberger", "poles": [0.5, 0.5, 0.6, 0.6]}, "poles", "fast"),
        ({"type": "KalmanFilter"}, "Qn", ["a"]),
        ({"type": "KalmanFilter"}, "x0", [True, 0, 0, 0]),
        ({"type": "ExtendedKalmanFilter"}, "Rn", [[1.0], [2.0, 3.0]]),
    ],
)
def test_estimator_keys_typed_with_aliases_are_refused_by_key(estimator, key, value):
    doc = {
        "plant": {"type": "CartPole"},
        "controller": {"type": "LQR", "Q": [10, 1, 100, 1], "R": [0.1]},
        "sim": {"measured": ["x", "theta"]},
        "estimator": {**estimator, key: value},
    }
    with pytest.raises(ConfigError, match=f"\\[estimator\\] '{key}'"):
        parse_scenario(doc)


@pytest.mark.parametrize(
    "scenario", ["cartpole_lqr", "cartpole_mpc", "cartpole_nmpc_swingup_mujoco", "regression/cartpole_tvlqr_swingup"]
)
@pytest.mark.parametrize("key", ["Q", "R"])
def test_a_string_weight_is_refused_by_the_scenario_checker_for_every_controller(scenario, key):
    import tomllib

    from shinro_ctrl.errors import ConfigError
    from shinro_ctrl.resources import config_path
    from shinro_ctrl.sim import RobotSim

    doc = tomllib.loads(config_path(scenario).read_text())
    doc["controller"][key] = "abc"
    with pytest.raises(ConfigError, match=rf"\[controller\] '{key}' must be a number or an array of numbers"):
        RobotSim.from_config(doc)
