"""Strict scenario parsing: every key checked, every error naming file, table and key."""

from __future__ import annotations

import re

import pytest

from shinro_ctrl.config import load_scenario, parse_scenario
from shinro_ctrl.errors import ConfigError
from shinro_ctrl.resources import config_path, list_configs

BASE = {
    "plant": {"type": "CartPole", "pole_length": 0.5},
    "controller": {"type": "LQR", "Q": [10, 1, 100, 1], "R": [0.1]},
    "sim": {"duration": 1.0, "initial_state": [0, 0, 0.1, 0]},
}


def with_(table: str, **changes):
    doc = {k: dict(v) for k, v in BASE.items()}
    doc.setdefault(table, {}).update(changes)
    return doc


def test_valid_scenario_parses():
    s = parse_scenario(BASE)
    assert s.plant.type == "CartPole" and s.plant.params == {"pole_length": 0.5}
    assert s.controller.type == "LQR" and s.engine is None
    assert s.sim.duration == 1.0 and s.sim.reference == {"kind": "constant"}


@pytest.mark.parametrize(
    "doc,needle",
    [
        ({}, "empty scenario"),
        ({**BASE, "contoller": {}}, "unknown table 'contoller'; did you mean 'controller'"),
        (with_("plant", pole_lenght=0.5), "[plant] unknown key 'pole_lenght'; did you mean 'pole_length'"),
        (with_("plant", type="CartPol"), "did you mean 'CartPole'"),
        (with_("plant", cart_mass=-1.0), "cart_mass"),
        (with_("plant", cart_mass="heavy"), "cart_mass"),
        (with_("controller", type="PID"), "unknown controller type 'PID'"),
        (with_("controller", Qq=[1]), "did you mean 'Q'"),
        (with_("controller", x0=[0, 0]), "'x0' must have 4 values"),
        (with_("sim", duration=-1), "'duration' must be positive"),
        (with_("sim", duration="long"), "'duration' must be a number"),
        (with_("sim", initial_state=[0, 0, float("nan"), 0]), "'initial_state' must be finite"),
        (with_("sim", initial_state=[0, 0]), "'initial_state' must have 4 values"),
        (with_("sim", reference={"kind": "spiral"}), "unknown kind 'spiral'"),
        (with_("sim", reference={"kind": "circle", "radius": 1.0}), "needs 'frequency'"),
        (with_("sim", track=["theta", "phi"]), "unknown state 'phi'"),
        (with_("sim", durration=1.0), "did you mean 'duration'"),
        (with_("engine", type="bullet"), "'type' must be 'mujoco' or 'standalone'"),
        (with_("regression", rms_eror={"rel": 0.1}), "did you mean 'rms_error'"),
        ({"controller": BASE["controller"]}, "missing required table [plant]"),
        ({"plant": BASE["plant"]}, "missing required table [controller]"),
    ],
)
def test_bad_documents_raise_config_error(doc, needle):
    with pytest.raises(ConfigError) as info:
        parse_scenario(doc)
    assert needle in str(info.value)


def test_typo_in_plant_is_reported_before_missing_controller():
    with pytest.raises(ConfigError, match="did you mean 'pole_length'"):
        parse_scenario({"plant": {"type": "CartPole", "pole_lenght": 1.0}})


def test_file_errors_name_the_file(tmp_path):
    bad = tmp_path / "broken.toml"
    bad.write_text("[plant\ntype = 'CartPole'\n")
    with pytest.raises(ConfigError, match=r"broken\.toml: malformed TOML"):
        load_scenario(bad)
    typo = tmp_path / "typo.toml"
    typo.write_text('[plant]\ntype = "CartPole"\npole_lenght = 1.0\n[controller]\ntype = "LQR"\nQ=[1,1,1,1]\nR=[1]\n')
    with pytest.raises(ConfigError, match=r"typo\.toml: \[plant\] unknown key 'pole_lenght'"):
        load_scenario(typo)
    with pytest.raises(FileNotFoundError, match=r"cartpole_lqr\.toml"):
        load_scenario(tmp_path / "missing.toml")


def test_shipped_configs_are_found_by_name_and_all_parse():
    assert config_path("cartpole_lqr") == config_path("cartpole_lqr.toml")
    names = list_configs()
    assert "cartpole_lqr.toml" in names
    for name in names:
        load_scenario(name)


def test_initial_state_must_respect_track_limits():
    doc = with_("plant", track_limits=[-1.0, 1.0])
    doc["sim"]["initial_state"] = [2.0, 0.0, 0.0, 0.0]
    with pytest.raises(ConfigError, match=r"x = 2 is outside the plant's limits \[-1, 1\]"):
        parse_scenario(doc)


def test_set_state_outside_declared_limits_is_refused():
    from shinro_ctrl.errors import InvalidArgument
    from shinro_ctrl.plants import CartPole, InvertedPendulum

    with pytest.raises(InvalidArgument, match="outside the plant's limits"):
        CartPole(track_limits=(-1, 1)).set_state([5.0, 0, 0, 0])
    with pytest.raises(InvalidArgument, match="theta_dot"):
        InvertedPendulum(state_bounds=([-1, -1], [1, 1])).set_state([0.0, 3.0])


# ----------------------------------------------------------- strict value types (issue 14, items 7 and 13)
@pytest.mark.parametrize(
    "annotation,value,ok",
    [
        ("bool", True, True),
        ("bool", "false", False),
        ("bool", 0, False),
        ("float", 1, True),
        ("float", True, False),
        ("float", "1.0", False),
        ("int", 3, True),
        ("int", 3.0, False),
        ("str", "euler", True),
        ("str", 1, False),
        ("float | None", 0.5, True),
        ("Any", [[1, 0], [0, 1]], True),
        ("Any", [[1, 0], [0]], False),
        ("Any", ["10"], False),
        ("Any", {"min": [-1, -2], "max": [1, 2]}, True),
        ("Sequence[str] | None", ["a", "b"], True),
        ("Sequence[str] | None", ["a", 1], False),
        ("list[float] | None", [1, 2.5], True),
        ("list[float] | None", [1, "2"], False),
        ("str | Any", "dare", True),
        ("str | Any", [[1.0]], True),
        ("Mapping[str, Any] | None", {"eps_abs": 1e-4}, True),
        ("Mapping[str, Any] | None", 3, False),
    ],
)
def test_check_value_is_strict(annotation, value, ok):
    from shinro_ctrl.config import check_value

    problem = check_value(value, annotation, "k")
    assert (problem is None) == ok, problem
    if not ok:
        assert "'k'" in problem


def test_a_new_table_gets_strict_types_from_its_dataclass():
    # how the [plan] / [estimator] tables (and any later one) are checked: their dataclass's annotations
    from dataclasses import dataclass

    from shinro_ctrl.config import ConfigContext, table_annotations

    @dataclass
    class NewTable:
        enabled: bool = True
        horizon: int = 10
        weights: list[float] | None = None

    ctx = ConfigContext("<test>")
    ctx.check_types("new", {"enabled": False, "horizon": 3, "weights": [1, 2]}, table_annotations(NewTable))
    for bad, needle in (({"enabled": "no"}, "'enabled' must be a boolean"), ({"horizon": 2.5}, "'horizon'")):
        with pytest.raises(ConfigError, match=needle):
            ctx.check_types("new", bad, table_annotations(NewTable))


@pytest.mark.parametrize("key,value", [("substeps", 1001), ("substeps", 10**8)])
def test_sizes_are_bounded_and_the_limit_is_named(key, value):
    doc = {**BASE, "engine": {"type": "mujoco", key: value}}
    with pytest.raises(ConfigError, match="limit of 1,000"):
        parse_scenario(doc)


# ------------------------------------------------------- duration and dt
@pytest.mark.parametrize(
    "dt, duration, needle",
    [
        (10.0, 0.5, "'duration' = 0.5 s is shorter than one step (dt = 10 s)"),
        (0.01, 0.005, "shorter than one step"),
        (
            0.01,
            1.005,
            "'duration' = 1.005 s is not a whole number of steps of dt = 0.01 s (100.5 steps): use 1 s or 1.01 s",
        ),
        (0.03, 1.0, "not a whole number of steps of dt = 0.03 s"),
        (0.3, 5.0, "'duration' (the default) = 5 s is not a whole number"),
    ],
)
def test_a_duration_that_is_not_whole_steps_is_refused_naming_both(dt, duration, needle):
    doc = with_("plant", dt=dt)
    if needle.startswith("'duration' (the default)"):
        del doc["sim"]["duration"]
    else:
        doc["sim"]["duration"] = duration
    with pytest.raises(ConfigError, match=re.escape(needle)) as info:
        parse_scenario(doc)
    assert "[sim]" in str(info.value) and len(str(info.value).splitlines()) == 1


@pytest.mark.parametrize("dt, duration", [(0.01, 6.0), (0.01, 0.01), (0.002, 3.0), (0.1, 0.3), (1 / 3, 2.0)])
def test_whole_step_durations_pass_despite_rounding(dt, duration):
    from shinro_ctrl.config import whole_steps

    doc = with_("plant", dt=dt)
    doc["sim"]["duration"] = duration
    assert parse_scenario(doc).sim.duration == duration
    assert whole_steps(duration, dt) == round(duration / dt)


def test_a_fixed_plan_horizon_must_be_whole_steps_too():
    doc = {
        "plant": {"type": "CartPole"},
        "controller": {"type": "TVLQR", "Q": [1, 1, 1, 1], "R": [1]},
        "plan": {"start": [0, 0, 3.14, 0], "goal": [0, 0, 0, 0], "duration": 2.005},
    }
    with pytest.raises(ConfigError, match=r"\[plan\] 'duration' = 2.005 s is not a whole number of steps of dt = 0.01"):
        parse_scenario(doc)
    doc["plan"]["duration"] = 2.0
    assert parse_scenario(doc).plan["duration"] == 2.0
    doc["plan"]["duration"] = [0.5, 2.005]  # a free horizon is the optimizer's to pick
    parse_scenario(doc)


@pytest.mark.parametrize(
    "plan, needle",
    [
        ({"knots": 20_000}, "'knots' must be an integer in [3, 1,000] (the limit), got 20000"),
        ({"knots": 2}, "'knots' must be an integer in [3, 1,000]"),
        ({"knots": 61.0}, "'knots' must be an integer"),
        ({"substeps": 10**8}, "'substeps' must be an integer in [1, 100] (the limit), got 100000000"),
        ({"substeps": 0}, "'substeps'"),
        ({"method": "multiple_shooting", "knots": 200, "substeps": 50}, "exceeds the limit of 1,000 RK4 steps"),
    ],
)
def test_plan_sizes_are_bounded_and_the_limit_is_named(plan, needle):
    doc = {
        "plant": {"type": "CartPole"},
        "controller": {"type": "TVLQR", "Q": [1, 1, 1, 1], "R": [1]},
        "plan": {"start": [0, 0, 3.14, 0], "goal": [0, 0, 0, 0], **plan},
    }
    with pytest.raises(ConfigError, match=re.escape(needle)):
        parse_scenario(doc)


# --------------------------------------------------------- file encoding
@pytest.mark.parametrize(
    "prefix, needle",
    [
        (b"\xef\xbb\xbf", "starts with a UTF-8 byte-order mark (BOM)"),
        (b"\xff\xfe", "UTF-16"),
    ],
)
def test_a_byte_order_mark_is_named(prefix, needle, tmp_path):
    path = tmp_path / "bom.toml"
    text = config_path("pendulum_lqr").read_text(encoding="utf-8")
    path.write_bytes(prefix + (text.encode("utf-16-le") if prefix == b"\xff\xfe" else text.encode()))
    with pytest.raises(ConfigError, match=re.escape(needle)):
        load_scenario(path)


@pytest.mark.parametrize("name", ["", "  ", "\t"])
def test_an_empty_scenario_name_is_refused(name):
    with pytest.raises(ConfigError, match="scenario name is empty"):
        load_scenario(name)
