"""``NMPCOptions.riccati`` (issue 27): the RTI's Riccati step forced on a small cart-pole reproduces the condensed QP.

The reference is the other path of the same controller: the condensed QP solved by DAQP (``riccati = False``), a
different algorithm (dense Hessian, Cholesky, active set). Closed-loop calls from the same states must give the same
inputs while the bounds stay inactive (the Riccati step is the QP's solution) and while the force bound is active
(the Riccati step misses a bound and the controller falls back to the condensed QP).
"""

from __future__ import annotations

import numpy as np
import pytest

from shinro_ctrl.controllers.nmpc import NonlinearMPC
from shinro_ctrl.errors import InvalidArgument
from shinro_ctrl.plants import CartPole

Q_CP = [1e3, 1e-2, 1e3, 1e-2]
R_CP = [1e-2]


def _pair(u_max: float) -> tuple[NonlinearMPC, NonlinearMPC]:
    plant = CartPole()
    kw = dict(horizon=12, u_min=-u_max, u_max=u_max, x_min=[-2.0, -np.inf, -np.inf, -np.inf], soft=True)
    kw["x_max"] = [2.0, np.inf, np.inf, np.inf]
    kw.update(cold_start="sqp", init_iterations=10)
    return (
        NonlinearMPC.from_plant(plant, Q_CP, R_CP, riccati=True, **kw),
        NonlinearMPC.from_plant(plant, Q_CP, R_CP, riccati=False, **kw),
    )


@pytest.mark.parametrize("u_max", [40.0, 1.5])
def test_forced_riccati_step_equals_condensed_qp(u_max):
    ric, cond = _pair(u_max)
    assert ric.strategy.riccati and not cond.strategy.riccati
    rng = np.random.default_rng(7)
    x = np.array([0.1, 0.0, 0.25, 0.0])
    clamped = 0
    for _ in range(8):
        u1, u2 = np.asarray(ric(x)), np.asarray(cond(x))
        np.testing.assert_allclose(u1, u2, rtol=1e-7, atol=1e-8)
        clamped += int(abs(u2[0]) >= u_max - 1e-9)
        x = x + np.array([0.02, 0.1, -0.03, 0.2]) * rng.standard_normal(4)  # a new measurement each call
    if u_max < 40.0:
        assert clamped > 0  # the fallback to the condensed QP was exercised


@pytest.mark.parametrize("kw", [{"riccati": "yes"}, {"riccati": True, "solver": "osqp"}])
def test_riccati_option_is_validated_in_one_line(kw):
    with pytest.raises(InvalidArgument, match="riccati") as err:
        NonlinearMPC.from_plant(CartPole(), Q_CP, R_CP, horizon=4, **kw)
    assert "\n" not in str(err.value)
