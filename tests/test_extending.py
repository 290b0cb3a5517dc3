"""docs/extending.md done from outside the package: a plant, a controller, an estimator and a CLI command
defined here, registered by their definition (or ``add_command``), used by a scenario dict and the command line
through the public API only, and checked against closed forms and a loop written out by hand."""

from __future__ import annotations

import argparse

import numpy as np
import pytest

import shinro_ctrl.cli as cli
from shinro_ctrl.cli import add_command, main
from shinro_ctrl.controllers import Controller, controller_class
from shinro_ctrl.errors import ConfigError, InvalidArgument
from shinro_ctrl.estimators import Estimator, estimator_class
from shinro_ctrl.plants import Plant, plant_class
from shinro_ctrl.sim import RobotSim
from shinro_ctrl.validation import as_vector, check_positive


# ----------------------------------------------------------- "Add a plant"
class ExtendingCart(Plant):
    """A cart of mass ``m`` with viscous friction ``c`` pushed by ``F``: ``p̈ = (F − c ṗ) / m``."""

    state_names = ("p", "v")
    input_names = ("F",)
    param_names = ("mass", "friction")
    position_indices = (0,)
    velocity_indices = (1,)
    aliases = ("extending_cart",)

    def __init__(self, mass: float = 2.0, friction: float = 0.5, dt: float = 0.01):
        params = {"mass": check_positive("mass", mass), "friction": check_positive("friction", friction)}
        self._init(dt=dt, params=params)

    def equations(self, bk, x, u, p):
        _, v = bk.unpack(x, 2)
        (force,) = bk.unpack(u, 1)
        return bk.stack([v, (force - p["friction"] * v) / p["mass"]])


# ----------------------------------------------------------- "Add a controller"
class ExtendingPD(Controller):
    """``F = clip(−kp (p − r) − kd v, ±f_max)`` on the estimate it is fed."""

    def __init__(self, kp: float, kd: float, f_max: float):
        self.kp, self.kd = kp, kd
        self.u_min, self.u_max = np.array([-f_max]), np.array([f_max])

    @classmethod
    def from_plant(cls, plant, *, kp: float = 4.0, kd: float = 3.0, f_max: float = 5.0) -> ExtendingPD:
        return cls(kp, kd, f_max)

    def __call__(self, x, ref=None):
        x = as_vector("x", x, 2)
        r = 0.0 if ref is None else float(np.asarray(ref)[0])
        return np.clip([-self.kp * (x[0] - r) - self.kd * x[1]], self.u_min, self.u_max)


# ----------------------------------------------------------- "Add an estimator"
class ExtendingDifferencer(Estimator):
    """Measures the position only; the velocity is the difference of two positions over ``dt``.

    Exact for the semi-implicit Euler step (``p[k] = p[k-1] + dt v[k]``), so the loop equals full-state
    feedback; ``offset`` is added to the position estimate (a key of the ``[estimator]`` table).
    """

    def __init__(self, dt: float, position: int, offset: float):
        self.n, self.measured, self.dt, self.offset = 2, (position,), dt, offset

    @classmethod
    def from_plant(cls, plant, *, measured=None, offset: float = 0.0) -> ExtendingDifferencer:
        names = list(measured or plant.state_names)
        if names != ["p"]:
            raise InvalidArgument(f"ExtendingDifferencer measures the position 'p' only, got {names}")
        return cls(plant.dt, plant.state_names.index("p"), offset)

    def reset(self, x0_hat, P0=None) -> None:
        self.x_hat = np.array(x0_hat, dtype=float)
        self.last = None

    def update(self, y, u):
        p = float(np.asarray(y)[0])
        v = self.x_hat[1] if self.last is None else (p - self.last) / self.dt
        self.last = p
        self.x_hat = np.array([p + self.offset, v])
        return self.x_hat


SCENARIO = {
    "plant": {"type": "extending_cart", "mass": 2.0, "friction": 0.5, "dt": 0.01},
    "controller": {"type": "ExtendingPD", "kp": 4.0, "kd": 3.0, "f_max": 5.0},
    "sim": {
        "duration": 6.0,
        "initial_state": [1.0, 0.0],
        "reference": {"kind": "constant", "value": [0.0, 0.0]},
        "measured": ["p"],
    },
    "estimator": {"type": "ExtendingDifferencer", "offset": 0.02},
}


def cart_by_hand(x0, steps: int, dt=0.01, mass=2.0, friction=0.5, offset=0.0) -> np.ndarray:
    """The same closed loop written out: PD on (p + offset, v), semi-implicit Euler."""
    p, v = x0
    out = [(p, v)]
    for _ in range(steps):
        force = min(max(-4.0 * (p + offset) - 3.0 * v, -5.0), 5.0)
        v = v + dt * (force - friction * v) / mass
        p = p + dt * v
        out.append((p, v))
    return np.array(out)


def test_the_three_classes_register_by_being_defined():
    assert plant_class("extending_cart") is ExtendingCart is plant_class("ExtendingCart")
    assert controller_class("ExtendingPD") is ExtendingPD
    assert estimator_class("ExtendingDifferencer") is ExtendingDifferencer
    with pytest.raises(ConfigError, match="did you mean 'extending_cart'"):
        plant_class("extending_crt")


def test_the_new_plant_linearizes_to_its_closed_form():
    A, B = ExtendingCart(mass=2.0, friction=0.5).linearize([0.3, -1.0], [2.0])
    np.testing.assert_allclose(A, [[0.0, 1.0], [0.0, -0.25]], rtol=0, atol=1e-14)
    np.testing.assert_allclose(B, [[0.0], [0.5]], rtol=0, atol=1e-14)


def test_a_scenario_dict_runs_the_new_plant_controller_and_estimator():
    result = RobotSim.from_config(SCENARIO).run()
    np.testing.assert_allclose(result.x, cart_by_hand([1.0, 0.0], 600, offset=0.02), rtol=0, atol=1e-9)
    assert result.metrics["max_abs_input"] <= 5.0  # the loop read the bounds through the contract
    full_state = RobotSim.from_config(
        {k: v for k, v in SCENARIO.items() if k != "estimator"}
        | {"sim": {"duration": 6.0, "initial_state": [1.0, 0.0]}}
    )
    np.testing.assert_allclose(full_state.run().x, cart_by_hand([1.0, 0.0], 600), rtol=0, atol=1e-9)


def test_the_scenario_layer_checks_the_new_classes_keys():
    bad = {**SCENARIO, "controller": {**SCENARIO["controller"], "k_p": 1.0}}
    with pytest.raises(ConfigError, match=r"\[controller\] unknown key 'k_p'"):
        RobotSim.from_config(bad)
    bad = {**SCENARIO, "plant": {**SCENARIO["plant"], "mas": 1.0}}
    with pytest.raises(ConfigError, match="did you mean 'mass'"):
        RobotSim.from_config(bad)


# ----------------------------------------------------------- "Add a CLI command"
def cmd_describe_plant(args: argparse.Namespace) -> int:
    plant = plant_class(args.plant)()  # an unknown name is our ConfigError: one line, exit 2
    print(f"{type(plant).__name__}: states {', '.join(plant.state_names)}; inputs {', '.join(plant.input_names)}")
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("describe-plant", help="a plant's state and input names")
    p.add_argument("plant", metavar="PLANT")
    p.set_defaults(func=cmd_describe_plant)


def test_a_cli_command_added_from_outside(monkeypatch, capsys):
    monkeypatch.setattr(cli, "COMMANDS", list(cli.COMMANDS))  # the addition ends with this test
    add_command(register)
    add_command(register)  # once only
    assert cli.COMMANDS.count(register) == 1
    assert main(["describe-plant", "extending_cart"]) == 0
    assert capsys.readouterr().out == "ExtendingCart: states p, v; inputs F\n"
    assert main(["describe-plant", "extending_crt"]) == 2
    err = capsys.readouterr().err
    assert err == "error: unknown plant type 'extending_crt'; did you mean 'extending_cart'?\n", err
    assert "describe-plant" in cli.build_parser().format_help()


# ------------------------------------------------------ "Add a solver backend"
class BoxLsqBackend:
    """A LinearMPC backend written outside the package: the condensed input-only QP with input bounds,
    ``min ½ Uᵀ H U + fᵀ U, lo ≤ U ≤ hi``, solved as the bounded least squares ``min ½ ‖Lᵀ U + L⁻¹ f‖²``
    (``H = L Lᵀ``) by scipy's ``lsq_linear``. No state or rate bounds (refused)."""

    name = "box_lsq"

    def __init__(self, problem, options):
        import scipy.linalg

        from tests.test_mpc import condensed

        if np.isfinite(options.x_min).any() or np.isfinite(options.x_max).any() or options.du_max is not None:
            raise InvalidArgument("box_lsq takes input bounds only")
        self.problem, self.options, self.settled = problem, options, True
        p = problem
        self._condensed = lambda x: condensed(p.A, p.B, p.Q, p.R, p.Qf, p.N, x)
        H, _ = self._condensed(np.zeros(p.A.shape[0]))
        self._L = scipy.linalg.cholesky(H, lower=True)
        m = p.B.shape[1]
        self._lo = np.tile(options.u_min - options.u0, p.N)
        self._hi = np.tile(options.u_max - options.u0, p.N)
        self._m = m

    def solve(self, x, ref, u_ref, u_prev):
        import scipy.linalg
        from scipy.optimize import lsq_linear

        from shinro_ctrl.controllers.mpc import MPCSolution

        p, o = self.problem, self.options
        e0 = x - o.x0
        H, f = self._condensed(e0)
        b = -scipy.linalg.solve_triangular(self._L, f, lower=True)
        res = lsq_linear(self._L.T, b, bounds=(self._lo, self._hi), method="bvls", tol=1e-14, max_iter=1000)
        U = res.x.reshape(p.N, self._m)
        X = [e0]
        for k in range(p.N):
            X.append(p.A @ X[-1] + p.B @ U[k])
        return MPCSolution(
            status="solved",
            iterations=int(res.nit),
            solve_time_s=0.0,
            objective=float(0.5 * res.x @ H @ res.x + f @ res.x),
            states=np.array(X) + o.x0,
            inputs=U + o.u0,
            u=np.clip(U[0] + o.u0, o.u_min, o.u_max),
            backend=self.name,
        )

    def reset(self):
        pass

    def describe(self):
        return f"box_lsq: {self.problem.N * self._m} inputs, scipy lsq_linear (BVLS)"


def test_a_solver_backend_added_from_outside_runs_linear_mpc(monkeypatch):
    """Registered in BACKENDS, its name is a valid ``solver``; its first moves equal DAQP's exact ones."""
    from shinro_ctrl.controllers import LinearMPC
    from shinro_ctrl.controllers.qp import dispatch
    from shinro_ctrl.plants import CartPole

    with pytest.raises(InvalidArgument, match="solver must be one of 'auto', 'osqp', 'daqp', got 'box_lsq'"):
        LinearMPC.from_plant(CartPole(), [10, 1, 100, 1], [0.1], horizon=20, solver="box_lsq")
    monkeypatch.setitem(dispatch.BACKENDS, "box_lsq", BoxLsqBackend)
    kw = dict(horizon=20, u_min=-3.0, u_max=3.0)
    ours = LinearMPC.from_plant(CartPole(), [10, 1, 100, 1], [0.1], solver="box_lsq", **kw)
    exact = LinearMPC.from_plant(CartPole(), [10, 1, 100, 1], [0.1], solver="daqp", **kw)
    assert isinstance(ours.backend, BoxLsqBackend) and "box_lsq: 20 inputs" in ours.describe()
    plant = CartPole()
    plant.set_state([0.0, 0.0, 0.25, 0.0])
    saturated = 0
    for _ in range(100):
        x = plant.get_state()
        u = ours(x)
        np.testing.assert_allclose(u, exact(x), atol=1e-7)
        saturated += abs(u[0]) >= 3.0 - 1e-9
        plant.step(u)
    assert saturated > 0 and abs(plant.get_state()[2]) < 0.05  # the bounds were active; the pole is caught
