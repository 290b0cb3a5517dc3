"""The QP backends of ``LinearMPC`` by name, and which one ``solver="auto"`` uses.

Every backend is a class with the same interface (the qpsolvers pattern: one
file per backend, one signature, this dispatch table): built from an
:class:`~.options.MPCProblem` and resolved :class:`~.options.MPCOptions`, it
owns its buffers and solver object and offers ``solve(x, ref, u_ref, u_prev)
-> MPCSolution``, ``reset()``, ``describe()`` and ``settled``. ``"auto"`` picks
DAQP on the condensed QP while it is small, else OSQP on the sparse QP.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Protocol

import numpy as np

from shinro_ctrl.controllers.qp.backend_daqp import DaqpBackend
from shinro_ctrl.controllers.qp.backend_osqp import OsqpBackend
from shinro_ctrl.controllers.qp.condensed import MAX_DENSE_SIZE, condensed_size
from shinro_ctrl.controllers.qp.options import MPCOptions, MPCProblem
from shinro_ctrl.controllers.qp.solution import MPCSolution

__all__ = ["AUTO_DAQP_MAX_VARIABLES", "BACKENDS", "MPCBackend", "choose_solver", "dense_size"]


class MPCBackend(Protocol):
    """What ``LinearMPC`` needs of a QP backend."""

    name: str
    settled: bool

    def solve(
        self, x: np.ndarray, ref: np.ndarray | None, u_ref: np.ndarray | None, u_prev: np.ndarray | None
    ) -> MPCSolution:
        """One MPC step from the measured state ``x`` (checked references, previous input)."""
        ...

    def reset(self) -> None:
        """Forget warm starts (the next solve repeats a fresh controller's)."""
        ...

    def describe(self) -> str:
        """Sizes and settings of the QP and the solver."""
        ...


#: The backends by name (``LinearMPC(solver=...)``): each a class built as ``cls(problem, options)``
#: that satisfies :class:`MPCBackend`. An entry added here is a valid ``solver`` name (see
#: ``docs/extending.md``, "Add a solver backend").
BACKENDS: dict[str, Callable[[MPCProblem, MPCOptions], MPCBackend]] = {"osqp": OsqpBackend, "daqp": DaqpBackend}

#: ``solver="auto"`` uses DAQP while the condensed QP has at most this many
#: variables ``N·m`` plus slacks (and fits :data:`~shinro_ctrl.controllers.qp.condensed.MAX_DENSE_SIZE`).
#: Measured with ``benchmarks/mpc.py --crossover`` (median call, warm closed
#: loop, both backends exact): see :func:`choose_solver`.
AUTO_DAQP_MAX_VARIABLES = 250


def choose_solver(n: int, m: int, N: int, opts: MPCOptions) -> str:
    """The backend ``solver="auto"`` picks for a resolved :class:`MPCOptions`.

    A warm DAQP call on the condensed QP costs about ``O(nz·(nz + rows))``
    (``nz = N·m`` inputs plus one slack per soft-bounded state and stage) and
    its build ``O(N³)``; an OSQP call on the sparse QP ``O(N (n + m)²)`` per
    ADMM iteration plus the polish. Measured (``benchmarks/mpc.py
    --crossover``, median call, warm closed loop, both exact): DAQP is 2-5x
    faster up to ``nz`` ≈ 200 (cart-pole ``N = 200``: 0.24 vs 0.53 ms;
    quadrotor with soft bounds ``N = 30``, ``nz = 180``: 0.11 vs 0.28 ms),
    level with OSQP near ``nz`` = 400 on the cart-pole and already 1.6x slower
    at ``nz = 360`` on the soft-bounded quadrotor (``N = 60``). Rule:
    ``"daqp"`` when ``nz <= AUTO_DAQP_MAX_VARIABLES`` (250) and the dense
    matrices fit :data:`~shinro_ctrl.controllers.qp.condensed.MAX_DENSE_SIZE`, else ``"osqp"``.

    Args:
        n: States.
        m: Inputs.
        N: Horizon.
        opts: The resolved options (bounds decide slacks and dense rows).
    """
    if opts.solver != "auto":
        return opts.solver
    soft_rows = int(np.count_nonzero(np.isfinite(opts.x_min) | np.isfinite(opts.x_max))) if opts.soft else 0
    nz = N * (m + soft_rows)
    return "daqp" if nz <= AUTO_DAQP_MAX_VARIABLES and dense_size(n, m, N, opts) <= MAX_DENSE_SIZE else "osqp"


def dense_size(n: int, m: int, N: int, opts: MPCOptions) -> int:
    """Entries of the condensed QP's dense matrices for these sizes and bounds (see ``condensed_size``)."""
    bounded = np.isfinite
    return condensed_size(
        n,
        m,
        N,
        u_rows=int(np.count_nonzero(bounded(opts.u_min) | bounded(opts.u_max))),
        rate_rows=0 if opts.du_max is None else int(np.count_nonzero(bounded(opts.du_max))),
        x_rows=int(np.count_nonzero(bounded(opts.x_min) | bounded(opts.x_max))),
        soft=bool(opts.soft),
    )
