"""The Python API of plants, controllers, engine and metrics: no silent wrong answer, the project's error."""

from __future__ import annotations

import pytest

from shinro_ctrl.errors import ShinroError


# ------------------------------------------------------------------ API: no silent wrong answer
def _api_cases():
    import numpy as np

    from shinro_ctrl.controllers import IKQP, LQR, LinearMPC
    from shinro_ctrl.engine import MujocoEngine
    from shinro_ctrl.plants import CartPole, InvertedPendulum
    from shinro_ctrl.sim import RobotSim, compute_metrics
    from shinro_ctrl.sweep.batch import lqr_batch_rollout

    huge = np.array([1e300, 1e300, 1e300, 1e300])
    return {
        # item 8: Q = 0 leaves the cart's integrator on the unit circle
        "lqr_q_zero": (lambda: LQR.from_plant(CartPole(), [0, 0, 0, 0], [1]), "NotStabilizable", "not detectable"),
        "lqr_q_zero_continuous": (
            lambda: LQR.from_plant(CartPole(), [0, 1, 1, 1], [1], discrete=False),
            "NotStabilizable",
            "mostly state 'x'",
        ),
        # item 9: finite or an error saying what overflowed
        "linearize_huge_state": (lambda: CartPole().linearize(huge, [0.0]), "NonFiniteError", "overflows"),
        "linearize_huge_eps": (
            lambda: CartPole().linearize(None, None, method="fd", eps=1e300),
            "NonFiniteError",
            "eps = 1e+300",
        ),
        "fd_eps_below_resolution": (
            lambda: CartPole().linearize([1e12, 0, 0, 0], [0], method="fd"),
            "InvalidArgument",
            "below float64's resolution",
        ),
        "zoh_huge_dt": (lambda: CartPole(dt=1e6).get_model(discretization="zoh"), "NonFiniteError", "dt = 1e+06"),
        "rk4_huge_dt": (lambda: CartPole(dt=1e80).get_model(discretization="rk4"), "NonFiniteError", "rk4"),
        "dynamics_overflow": (
            lambda: CartPole().dynamics([0, 0, 1e308, 1e308], [1e308]),
            "NonFiniteError",
            "overflows float64",
        ),
        "mpc_huge_state": (
            lambda: LinearMPC.from_plant(CartPole(), [1, 1, 1, 1], [1], horizon=10, u_min=[-1], u_max=[1])(
                np.array([0, 0, 1e14, 0])
            ),
            "NonFiniteError",
            "numeric range",
        ),
        # item 10: complex numbers are an error, not truncated with a warning
        "lqr_complex_Q": (
            lambda: LQR.from_plant(CartPole(), np.diag([1 + 1j, 1, 1, 1]), [1]),
            "InvalidArgument",
            "real",
        ),
        "lqr_complex_R": (
            lambda: LQR.from_plant(CartPole(), [1, 1, 1, 1], np.array([[1 + 0j]])),
            "InvalidArgument",
            "real",
        ),
        "complex_x0": (lambda: CartPole().linearize(np.array([0, 0, 1j, 0]), [0]), "InvalidArgument", "real"),
        # item 11: an engine built for another plant is refused, naming the parameter
        "engine_other_dt": (
            lambda: CartPole(dt=0.02).physics_engine(MujocoEngine.for_plant(CartPole(dt=0.01))),
            "InvalidArgument",
            "dt",
        ),
        "engine_other_mass": (
            lambda: CartPole(pole_mass=0.3).physics_engine(MujocoEngine.for_plant(CartPole())),
            "InvalidArgument",
            "mass of body 'pole'",
        ),
        "engine_other_damping": (
            lambda: CartPole(damping=0.5).physics_engine(MujocoEngine.for_plant(CartPole())),
            "InvalidArgument",
            "damping",
        ),
        "engine_other_type": (
            lambda: InvertedPendulum().physics_engine(MujocoEngine.for_plant(CartPole())),
            "InvalidArgument",
            "CartPole, not InvertedPendulum",
        ),
        # item 14: the project's errors, never numpy/AttributeError/TypeError
        "batch_shapes": (
            lambda: CartPole().dynamics(np.zeros((5, 4)), np.zeros((3, 1))),
            "InvalidArgument",
            "batch shapes",
        ),
        "param_string": (lambda: CartPole(pole_mass="0.1"), "InvalidArgument", "pole_mass"),
        "param_bool": (lambda: CartPole(dt=True), "InvalidArgument", "dt"),
        "for_plant_name": (lambda: MujocoEngine.for_plant("cartpole"), "InvalidArgument", "plant instance"),
        "from_config_none": (lambda: RobotSim.from_config(None), "InvalidArgument", "NoneType"),
        "ikqp_non_arm": (lambda: IKQP(CartPole()), "InvalidArgument", "arm plant"),
        "metrics_overflow": (
            lambda: compute_metrics(
                np.arange(3) * 0.1,
                np.array([[1e308], [-1e308], [1e308]]),
                np.zeros((2, 1)),
                np.array([[-1e308], [1e308], [-1e308]]),
                tracked=[0],
            ),
            "NonFiniteError",
            "metrics overflow",
        ),
        "batch_rollout_shapes": (
            lambda: lqr_batch_rollout(
                CartPole(),
                LQR.from_plant(CartPole(), [1, 1, 1, 1], [1]),
                params={"pole_mass": np.full(5, 0.1)},
                x0=np.zeros((3, 4)),
                ref=np.zeros(4),
                steps=3,
                tracked=[0],
            ),
            "InvalidArgument",
            "for 5 instances",
        ),
    }


@pytest.mark.parametrize("case", sorted(_api_cases()))
def test_api_raises_the_projects_error(case):
    import warnings

    fn, kind, needle = _api_cases()[case]
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a warning (ComplexWarning, overflow) is not an answer either
        with pytest.raises(ShinroError) as info:
            fn()
    assert type(info.value).__name__ == kind and needle in str(info.value), (type(info.value), str(info.value))
