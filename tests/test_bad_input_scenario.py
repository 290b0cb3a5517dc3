"""Scenario tables: strict TOML types in every key of every table (named by key), and files a scenario names."""

from __future__ import annotations

import re
from datetime import date, datetime

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from shinro_ctrl.config import parse_scenario
from shinro_ctrl.errors import ConfigError, ShinroError

from .bad_input_helpers import _doc, check_one_line_exit_2

# ------------------------------------------------------------------------------------------- TYPES
TYPE_CASES = {
    # item 7: a string or boolean where a boolean or number is meant, named by key
    "discrete_string": ({"controller": {"discrete": "false"}}, "'discrete' must be a boolean"),
    "feedforward_string": ({"controller": {"feedforward": "false"}}, "'feedforward' must be a boolean"),
    "dt_boolean": ({"plant": {"dt": True}}, "'dt' must be a number"),
    "mass_boolean": ({"plant": {"pole_mass": False}}, "'pole_mass' must be a number"),
    "Q_strings": ({"controller": {"Q": ["10", "1", "100", "1"]}}, "'Q' must be a number or an array of numbers"),
    "R_boolean": ({"controller": {"R": [True]}}, "'R'"),
    "Q_ragged": ({"controller": {"Q": [[1, 0], [0, 1, 2], [0], [1]]}}, "'Q' is ragged"),
    "Q_table": ({"controller": {"Q": {"a": "b"}}}, "'Q.a' must be a number"),
    "x0_string": ({"controller": {"x0": "0,0,0,0"}}, "'x0'"),
    "duration_bool": ({"sim": {"duration": True}}, "'duration' must be a number"),
    "duration_date": ({"sim": {"duration": date(2020, 1, 1)}}, "'duration' must be a number, got date-time"),
    "seed_float": ({"sim": {"seed": 1.5}}, "'seed' must be an integer"),
    "track_numbers": ({"sim": {"track": [1, 2]}}, "'track'"),
    "substeps_float": ({"engine": {"type": "mujoco", "substeps": 2.0}}, "'substeps' must be an integer"),
    "model_number": ({"engine": {"type": "mujoco", "model": 3}}, "'model' must be a string"),
    "reference_kind_number": ({"sim": {"reference": {"kind": 1}}}, "'kind' must be a string"),
    "reference_kind_array": ({"sim": {"reference": {"kind": ["step"]}}}, "'kind' must be a string"),
    "plant_type_number": ({"plant": {"type": 5}}, "'type' must be a string"),
    "regression_tol_string": ({"regression": {"rms_error": {"rel": "0.1"}}}, "rms_error.rel"),
    "method_boolean": ({"controller": {"method": True}}, "'method' must be a string"),
    # options a controller forwards (**options, e.g. LinearMPC's MPCOptions) are typed too
    "mpc_u_min_boolean": (
        {"controller": {"type": "LinearMPC", "horizon": 5, "u_min": [True], "u_max": [1]}},
        "'u_min' must be a number or an array of numbers",
    ),
    "mpc_soft_string": (
        {"controller": {"type": "LinearMPC", "horizon": 5, "u_min": [-1], "u_max": [1], "soft": "yes"}},
        "'soft' must be a boolean",
    ),
    "mpc_solver_number": (
        {"controller": {"type": "LinearMPC", "horizon": 5, "u_min": [-1], "u_max": [1], "solver": 1}},
        "'solver' must be a string",
    ),
}
OSQP_TYPE_CASES = {
    "eps_abs_string": ({"eps_abs": "x"}, "'eps_abs' must be a number"),
    "max_iter_list": ({"max_iter": [1]}, "'max_iter' must be an integer"),
    "max_iter_float": ({"max_iter": 10.5}, "'max_iter' must be an integer"),
    "polishing_string": ({"polishing": "yes"}, "'polishing' must be a boolean"),
}


@pytest.mark.parametrize("case", sorted(OSQP_TYPE_CASES))
def test_osqp_settings_types_name_the_setting(case):
    from shinro_ctrl.sim import RobotSim

    settings, needle = OSQP_TYPE_CASES[case]
    doc = _doc(
        {"controller": {"type": "LinearMPC", "horizon": 5, "u_min": [-1], "u_max": [1], "osqp_settings": settings}}
    )
    with pytest.raises(ShinroError, match=needle):
        RobotSim(parse_scenario(doc))


@pytest.mark.parametrize("case", sorted(TYPE_CASES))
def test_types_strict_in_every_table(case):
    changes, needle = TYPE_CASES[case]
    with pytest.raises(ConfigError) as info:
        parse_scenario(_doc(changes))
    assert needle in str(info.value), str(info.value)


@pytest.mark.parametrize("case", ["discrete_string", "dt_boolean", "Q_strings", "Q_ragged"])
def test_types_through_the_cli(case, tmp_path, capsys):
    from shinro_ctrl.files import dump_toml

    changes, needle = TYPE_CASES[case]
    path = tmp_path / f"{case}.toml"
    path.write_text(dump_toml(_doc(changes)))
    check_one_line_exit_2(["design", "lqr", str(path)], needle, capsys)


# every TOML value type (string, integer, float, boolean, date-time, array, table) in every key of every table
TOML_VALUES = st.recursive(
    st.one_of(
        st.text(max_size=8),
        st.integers(min_value=-(2**63), max_value=2**63 - 1),
        st.floats(allow_nan=True, allow_infinity=True),
        st.booleans(),
        st.dates(),
        st.datetimes(min_value=datetime(1900, 1, 1)),
    ),
    lambda children: st.lists(children, max_size=5) | st.dictionaries(st.text(max_size=5), children, max_size=3),
    max_leaves=12,
)
TABLE_KEYS = {
    "plant": ["cart_mass", "pole_mass", "pole_length", "damping", "gravity", "dt", "track_limits", "type"],
    "controller": ["Q", "R", "x0", "u0", "discrete", "discretization", "method", "u_min", "u_max", "feedforward"],
    "engine": ["type", "model", "substeps"],
    "sim": ["duration", "initial_state", "reference", "track", "settle_tol", "measurement_noise", "seed"],
    "sim.reference": ["kind", "value", "time", "initial", "final", "radius", "frequency", "axes", "points"],
    "regression": ["rms_error", "settling_time"],
}
MPC_KEYS = ["horizon", "x_min", "x_max", "du_max", "soft", "soft_weight_l1", "terminal_cost", "osqp_settings"]


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    table=st.sampled_from(sorted(TABLE_KEYS)),
    data=st.data(),
    value=TOML_VALUES,
)
def test_property_any_toml_value_anywhere_is_accepted_or_a_config_error(table, data, value):
    """Whatever value of whatever TOML type lands in whatever key: a scenario, or a ShinroError naming the key."""
    from shinro_ctrl.sim import RobotSim

    key = data.draw(st.sampled_from(TABLE_KEYS[table]))
    doc = _doc({})
    if table == "sim.reference":
        doc["sim"] = {"reference": {"kind": "step", "time": 0.5, key: value}}
    elif table == "engine":
        doc["engine"] = {"type": "mujoco", key: value}
    else:
        doc.setdefault(table, {})[key] = value
    try:
        scenario = parse_scenario(doc)
    except ConfigError as exc:
        assert "Traceback" not in str(exc) and str(exc).strip()
        return
    try:  # a scenario that parses is one that builds, or fails with the project's error
        RobotSim(scenario)
    except ShinroError:
        pass


ESTIMATOR_KEYS = ["type", "Qn", "Rn", "Qn_on", "steady_state", "discretization", "initial_estimate", "P0"]
PLAN_KEYS = ["start", "goal", "knots", "method", "duration", "cost", "bounds", "substeps", "file"]


@settings(max_examples=100, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(key=st.sampled_from(ESTIMATOR_KEYS), value=TOML_VALUES)
def test_property_estimator_table_of_any_type(key, value):
    from shinro_ctrl.sim import RobotSim

    doc = _doc({"sim": {"measured": ["x", "theta"]}})
    doc["estimator"] = {"type": "KalmanFilter", key: value}
    try:
        RobotSim(parse_scenario(doc))
    except ShinroError:
        pass


@settings(max_examples=100, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(key=st.sampled_from(PLAN_KEYS), value=TOML_VALUES)
def test_property_plan_table_of_any_type(key, value):
    # parsed only: a plan that parses is solved by trajectory optimization, too slow for a property test
    doc = _doc({"controller": {"type": "TVLQR", "Q": [10, 1, 100, 1], "R": [0.1]}})
    doc["plan"] = {"start": [0, 0, 0.2, 0], "goal": [0, 0, 0, 0], key: value}
    try:
        parse_scenario(doc)
    except ConfigError:
        pass


@settings(max_examples=100, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(key=st.sampled_from(MPC_KEYS), value=TOML_VALUES)
def test_property_mpc_options_of_any_type(key, value):
    from shinro_ctrl.sim import RobotSim

    doc = _doc({"controller": {"type": "LinearMPC", "horizon": 5, "u_min": [-10], "u_max": [10], key: value}})
    try:
        RobotSim(parse_scenario(doc))
    except ShinroError:
        pass


@pytest.mark.parametrize(
    "changes,where",
    [
        ({"engine": {"type": "mujoco", "model": "0"}}, "[engine] model"),
        ({"engine": {"type": "mujoco", "model": "no_such_dir/robot.xml"}}, "[engine] model"),
        ({"plant": {"type": "MjcfPlant", "model": "no_such_robot.xml"}}, "[plant] MjcfPlant"),
        ({"plant": {"type": "no_such_robot.urdf"}}, "[plant] MjcfPlant"),
        (
            {
                "controller": {"type": "TVLQR", "Q": [1, 1, 1, 1], "R": [1]},
                "plan": {"file": "no_such_plan.npz"},
            },
            "plan file not found",
        ),
        (
            {"controller": {"type": "TVLQR", "Q": [1, 1, 1, 1], "R": [1]}, "plan": {"file": "."}},
            "is a directory",
        ),
    ],
    ids=["engine_model", "engine_model_dir", "plant_model", "plant_model_shorthand", "plan_file", "plan_dir"],
)
def test_a_missing_file_a_scenario_names_is_a_config_error_naming_the_key(changes, where, tmp_path, monkeypatch):
    """Through the Python API too (not only the CLI, which treats OSError as a user error): the project's error."""
    from shinro_ctrl.sim import RobotSim

    monkeypatch.chdir(tmp_path)
    doc = {**_doc({}), **changes}
    with pytest.raises(ConfigError, match=re.escape(where)):
        RobotSim.from_config(doc)
