"""The options of a linear MPC, written once and validated once.

:class:`MPCOptions` holds everything about a linear MPC besides the model
``(A, B)``, the weights ``(Q, R)`` and the horizon. Users pass the options as
keyword arguments (``LinearMPC(A, B, Q, R, N, u_max=3)``); the controller
builds one :class:`MPCOptions` from them and calls :meth:`MPCOptions.resolve`
once the sizes are known, which returns a validated copy (arrays of the right
shape, merged OSQP settings). The sparse QP builder and the controller read
the resolved copy; nothing validates an option twice.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from shinro_ctrl.errors import InvalidArgument
from shinro_ctrl.validation import as_vector, bound_pair, bound_vector, check_positive, weight_matrix

__all__ = ["DEFAULT_OSQP_SETTINGS", "PLANT_GIVEN", "MPCOptions", "MPCProblem"]

#: Defaults tuned for closed-loop control of the cart-pole benchmark (see
#: benchmarks/mpc.py and docs/mpc.md). eps <= 1e-4 keeps the first move within
#: ~1 % of the exact optimum; check_termination 5 avoids paying for 25
#: iterations when 5-10 suffice warm; under-relaxation alpha = 1.3 (OSQP's
#: default 1.6) halved the warm-started iteration count (median 20 -> 10 at
#: N = 50); the duality-gap test (check_dualgap) made active-bound solves
#: crawl into the iteration limit; max_iter 10000 leaves room for cold solves
#: with active soft bounds (up to ~3000 iterations measured). Every key can be
#: overridden with ``osqp_settings``.
DEFAULT_OSQP_SETTINGS: dict[str, Any] = {
    "eps_abs": 1e-4,
    "eps_rel": 1e-4,
    "warm_starting": True,
    "polishing": True,  # exactness: the polished solution is the QP's optimum (the first move within 1e-7)
    "check_termination": 5,
    "check_dualgap": False,
    "alpha": 1.3,
    "adaptive_rho": True,
    "scaling": 10,
    "max_iter": 10000,
    "verbose": False,
}


#: Options ``from_plant`` fills in from the plant (a scenario cannot set them).
PLANT_GIVEN = ("dt", "offset", "state_names", "input_names")


@dataclass(frozen=True)
class MPCOptions:
    """Options of a linear MPC besides ``(A, B, Q, R, horizon)``.

    Attributes:
        x0: Operating-point state ``(n,)`` [absolute units]; default zeros.
        u0: Operating-point input ``(m,)``; default zeros.
        dt: Sampling time [s] (informational; used by ``describe``).
        u_min: Lower input bounds ``(m,)`` (a scalar broadcasts; -inf = none).
        u_max: Upper input bounds ``(m,)``.
        x_min: Lower state bounds ``(n,)`` on ``x_1 … x_N`` (never on the measured ``x_0``).
        x_max: Upper state bounds ``(n,)``.
        du_max: Input-rate bounds ``(m,)``, ``|u_k − u_{k−1}| <= du_max`` per step.
        soft: Make the state bounds soft with slack variables.
        soft_weight_l1: Linear slack weight ``w_1`` >= 0.
        soft_weight_quad: Quadratic slack weight ``w_2`` > 0.
        terminal_cost: ``"lqr"`` (the DARE's solution, so with no active
            constraint the first move equals the LQR input; ``"dare"``, its
            former name, is read as ``"lqr"``), ``"Q"``, or a matrix ``(n, n)``.
        u_ref: Default input reference ``(m,)`` in absolute units (default ``u0``).
        offset: Affine term ``d`` ``(n,)`` of the model; zero at an equilibrium.
        fallback: None (raise on failure) or ``"shift"``.
        disturbance_model: None, or ``"input"`` for offset-free MPC: the
            controller then takes ``[x̂; d̂]`` ``(n + m,)`` from an estimator
            with a constant input disturbance ``d̂`` (see ``controllers/offset_free.py``).
        solver: QP backend, ``"auto"``, ``"osqp"`` (sparse) or ``"daqp"``
            (condensed, dense active set).
        osqp_settings: Overrides of :data:`DEFAULT_OSQP_SETTINGS` (after
            :meth:`resolve`: the merged settings).
        state_names: Names of the states for messages (default ``x[i]``).
        input_names: Names of the inputs for messages (default ``u[i]``).
    """

    x0: Any = None
    u0: Any = None
    dt: float | None = None
    u_min: Any = None
    u_max: Any = None
    x_min: Any = None
    x_max: Any = None
    du_max: Any = None
    soft: bool = False
    soft_weight_l1: float = 1e2
    soft_weight_quad: float = 1e2
    terminal_cost: str | Any = "lqr"
    u_ref: Any = None
    offset: Any = None
    fallback: str | None = None
    disturbance_model: str | None = None
    solver: str = "auto"
    osqp_settings: Mapping[str, Any] | None = None
    state_names: Any = None
    input_names: Any = None
    _resolved: tuple[int, int] | None = dataclasses.field(default=None, init=False, repr=False, compare=False)

    def resolve(self, n: int, m: int) -> MPCOptions:
        """A validated copy for ``n`` states and ``m`` inputs.

        Vectors become float arrays of their sizes (bounds ±inf where absent),
        names become tuples, a matrix terminal cost a symmetric PSD ``(n, n)``
        array, and ``osqp_settings`` the defaults merged with the overrides.
        A copy resolved for the same sizes is returned as is.

        Raises:
            InvalidArgument: wrong shapes, crossed bounds, ``du_max <= 0``,
                negative or non-finite slack weights, an unknown ``fallback``,
                ``terminal_cost`` or OSQP setting.
            NonFiniteError: NaN or inf where a finite number is needed.
        """
        from shinro_ctrl.controllers._osqp import merge_settings  # OSQP's setting names, on demand

        if self._resolved == (n, m):
            return self
        u_min, u_max = bound_pair("u_min", "u_max", self.u_min, self.u_max, m)
        x_min, x_max = bound_pair("x_min", "x_max", self.x_min, self.x_max, n)
        du_max = None
        if self.du_max is not None:
            du_max = bound_vector("du_max", self.du_max, m, np.inf)
            if np.any(du_max <= 0):
                raise InvalidArgument(f"du_max must be > 0, got {np.array2string(du_max, precision=4)}")
        w1, w2 = float(self.soft_weight_l1), float(self.soft_weight_quad)
        if not math.isfinite(w1) or w1 < 0:
            raise InvalidArgument(f"soft_weight_l1 must be >= 0 and finite, got {self.soft_weight_l1!r}")
        if not math.isfinite(w2) or w2 <= 0:
            raise InvalidArgument(f"soft_weight_quad must be > 0 and finite, got {self.soft_weight_quad!r}")
        if self.fallback not in (None, "shift"):
            raise InvalidArgument(f"fallback must be None or 'shift', got {self.fallback!r}")
        if self.disturbance_model not in (None, "input"):
            raise InvalidArgument(f"disturbance_model must be None or 'input', got {self.disturbance_model!r}")
        from shinro_ctrl.controllers.qp.dispatch import BACKENDS

        valid = ("auto", *BACKENDS)  # a backend added to BACKENDS is a valid solver name
        if self.solver not in valid:
            raise InvalidArgument(f"solver must be one of {', '.join(map(repr, valid))}, got {self.solver!r}")
        tc = self.terminal_cost
        if isinstance(tc, str):
            tc = "lqr" if tc == "dare" else tc
            if tc not in ("lqr", "Q"):
                raise InvalidArgument(f"terminal_cost must be 'lqr', 'Q' or an (n, n) matrix, got {tc!r}")
        else:
            tc = weight_matrix("terminal_cost", tc, n)
        out = dataclasses.replace(
            self,
            x0=np.zeros(n) if self.x0 is None else as_vector("x0", self.x0, n),
            u0=np.zeros(m) if self.u0 is None else as_vector("u0", self.u0, m),
            dt=None if self.dt is None else check_positive("dt", self.dt),
            u_min=u_min,
            u_max=u_max,
            x_min=x_min,
            x_max=x_max,
            du_max=du_max,
            soft=bool(self.soft),
            soft_weight_l1=w1,
            soft_weight_quad=w2,
            terminal_cost=tc,
            u_ref=None if self.u_ref is None else as_vector("u_ref", self.u_ref, m),
            offset=np.zeros(n) if self.offset is None else as_vector("offset", self.offset, n),
            osqp_settings=merge_settings(DEFAULT_OSQP_SETTINGS, self.osqp_settings),
            state_names=_names("state_names", self.state_names, n, "x"),
            input_names=_names("input_names", self.input_names, m, "u"),
        )
        object.__setattr__(out, "_resolved", (n, m))  # replace() of it starts unresolved again
        return out


def _names(arg: str, names: Any, size: int, prefix: str) -> tuple[str, ...]:
    if names is None:
        return tuple(f"{prefix}[{i}]" for i in range(size))
    names = tuple(str(s) for s in names)
    if len(names) != size:
        raise InvalidArgument(f"{arg}: expected {size} names but found {len(names)}")
    return names


@dataclass(frozen=True, eq=False)
class MPCProblem:
    """The validated model, weights and horizon of a linear MPC: what its backends solve, with :class:`MPCOptions`.

    Attributes:
        A: Discrete state matrix ``(n, n)``.
        B: Discrete input matrix ``(n, m)``.
        Q: Stage state weight ``(n, n)``.
        R: Stage input weight ``(m, m)``.
        Qf: Terminal weight ``(n, n)``.
        K: The DARE's LQR gain ``(m, n)`` (None for another terminal cost).
        N: Horizon.
    """

    A: np.ndarray
    B: np.ndarray
    Q: np.ndarray
    R: np.ndarray
    Qf: np.ndarray
    K: np.ndarray | None
    N: int

    @property
    def n(self) -> int:
        """States."""
        return self.B.shape[0]

    @property
    def m(self) -> int:
        """Inputs."""
        return self.B.shape[1]
