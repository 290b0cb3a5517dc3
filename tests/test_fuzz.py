"""Property-based fuzzing of the public boundary: random input only ever yields a result or one of our errors."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from shinro_ctrl.config import load_scenario, parse_scenario
from shinro_ctrl.controllers import LQR, LinearMPC
from shinro_ctrl.errors import ConfigError, ShinroError
from shinro_ctrl.plants import PLANTS, CartPole
from shinro_ctrl.sim import RobotSim

FUZZ = settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])

# ------------------------------------------------------------- random scenarios
scalars = st.one_of(
    st.integers(-5, 5),
    st.floats(allow_nan=True, allow_infinity=True, width=64),
    st.booleans(),
    st.text(max_size=6),
)
values = st.recursive(
    scalars,
    lambda inner: st.one_of(st.lists(inner, max_size=5), st.dictionaries(st.text(max_size=6), inner, max_size=3)),
    max_leaves=8,
)
KNOWN_TABLES = ["plant", "engine", "controller", "sim", "regression"]
KNOWN_KEYS = [
    "type", "dt", "pole_length", "cart_mass", "mass", "Q", "R", "x0", "u0", "horizon", "u_min", "u_max",
    "duration", "initial_state", "reference", "track", "seed", "model", "substeps", "rms_error",
]  # fmt: skip
keys = st.one_of(st.sampled_from(KNOWN_KEYS), st.text(max_size=8))
tables = st.dictionaries(keys, values, max_size=5)
documents = st.dictionaries(st.one_of(st.sampled_from(KNOWN_TABLES), st.text(max_size=8)), tables, max_size=5)

BASES = ["cartpole_lqr", "pendulum_lqr", "cartpole_mpc", "double_pendulum_lqr"]


@st.composite
def mutated_scenarios(draw):
    """A shipped scenario with a few keys replaced, removed or added: deeper than pure noise."""
    doc = {k: dict(v) for k, v in load_scenario(draw(st.sampled_from(BASES))).raw.items()}
    for _ in range(draw(st.integers(1, 3))):
        table = draw(st.sampled_from(sorted(doc)))
        action = draw(st.sampled_from(["replace", "remove", "add"]))
        if action == "replace" and doc[table]:
            doc[table][draw(st.sampled_from(sorted(doc[table])))] = draw(values)
        elif action == "remove" and doc[table]:
            doc[table].pop(draw(st.sampled_from(sorted(doc[table]))))
        else:
            doc[table][draw(keys)] = draw(values)
    return doc


def build_and_run(doc):
    """Parse, build and run briefly; return the result, or raise."""
    scenario = parse_scenario(doc)
    return RobotSim(scenario).run(duration=0.1, progress=False)


@FUZZ
@given(documents)
def test_random_documents_give_a_result_or_a_config_error(doc):
    try:
        build_and_run(doc)
    except ConfigError:
        pass


@FUZZ
@given(mutated_scenarios())
def test_mutated_scenarios_give_a_result_or_our_error(doc):
    # Parsing rejects with ConfigError; a valid-but-hostile scenario (say, an unstable design) may still
    # fail while running, but only ever with one of our errors.
    try:
        parse_scenario(doc)
    except ConfigError:
        return
    try:
        build_and_run(doc)
    except ShinroError:
        pass


# -------------------------------------------------------- arrays at the boundary
def arrays(max_len: int = 6):
    """Arrays of random shape (0-2 dims), sometimes holding NaN or inf, and a few non-array oddities."""
    floats = st.floats(allow_nan=True, allow_infinity=True, width=64)
    shapes = st.lists(st.integers(0, max_len), min_size=0, max_size=2).map(tuple)
    return st.one_of(
        shapes.flatmap(lambda s: st.lists(floats, min_size=int(np.prod(s)), max_size=int(np.prod(s))).map(
            lambda v, s=s: np.array(v, dtype=float).reshape(s)
        )),
        st.sampled_from([None, "abc", [1, "x"], [[1.0], [2.0, 3.0]]]),
    )  # fmt: skip


@FUZZ
@given(st.sampled_from(sorted(PLANTS)), arrays())
def test_step_with_random_input_raises_only_our_errors(name, u):
    plant = PLANTS[name]()
    try:
        plant.step(u)
    except ShinroError:
        pass


@FUZZ
@given(st.sampled_from(sorted(PLANTS)), arrays(), arrays())
def test_linearize_with_random_operating_points_raises_only_our_errors(name, x0, u0):
    plant = PLANTS[name]()
    try:
        A, B = plant.linearize(x0, u0)
    except ShinroError:
        return
    # accepted operating points are finite and give finite Jacobians of the documented shapes
    assert A.shape == (plant.state_dim, plant.state_dim) and B.shape == (plant.state_dim, plant.input_dim)


@FUZZ
@given(arrays(), arrays(), arrays(), arrays())
def test_lqr_with_random_matrices_raises_only_our_errors(A, B, Q, R):
    try:
        LQR(A, B, Q, R)
    except ShinroError:
        pass


@pytest.fixture(scope="module")
def cartpole_model():
    return CartPole(dt=0.02).get_model()


@FUZZ
@given(arrays(), arrays(), st.integers(-2, 6), arrays(), arrays())
def test_linear_mpc_with_random_arguments_raises_only_our_errors(cartpole_model, Q, R, horizon, u_max, x):
    A, B = cartpole_model
    try:
        mpc = LinearMPC(A, B, Q, R, horizon, u_max=u_max)
    except ShinroError:
        return
    try:
        u = mpc(x)
    except ShinroError:
        return
    assert u.shape == (1,) and np.all(np.isfinite(u)) and np.all(u <= mpc.u_max)


# ------------------------------------------------------------ IK at the limits
@pytest.fixture(scope="module")
def arm_and_ik():
    from shinro_ctrl.controllers import IKQP
    from shinro_ctrl.plants import ArmRobot

    arm = ArmRobot()
    return arm, IKQP(arm)


@FUZZ
@given(
    st.lists(st.floats(-5.0, 5.0), min_size=3, max_size=3),
    st.lists(st.floats(-np.pi, np.pi), min_size=3, max_size=3),
    st.integers(0, 2**31 - 1),
)
def test_random_ik_targets_never_violate_joint_limits(arm_and_ik, position, rpy, seed):
    from shinro_ctrl.kinematics import euler_zyx_to_matrix

    arm, ik = arm_and_ik
    T = np.eye(4)
    T[:3, :3] = euler_zyx_to_matrix(np.array(rpy))
    T[:3, 3] = position  # mostly far outside the ~0.9 m reach
    q0 = np.random.default_rng(seed).uniform(arm.joint_limits[:, 0], arm.joint_limits[:, 1])
    result = ik.solve(T, q0, max_iters=30, restarts=1, seed=seed)
    lo, hi = arm.joint_limits[:, 0], arm.joint_limits[:, 1]
    assert np.all(result.q >= lo) and np.all(result.q <= hi)
    assert np.all(np.isfinite(result.q))
    if np.linalg.norm(position) > 2.0:
        assert not result.converged
