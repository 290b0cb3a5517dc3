r"""Offset-free linear MPC with a constant input-disturbance model.

With ``LinearMPC(..., disturbance_model="input")`` the plant is modelled as
``x̃_{k+1} = A x̃_k + B (ũ_k + d) + c`` with an unknown constant ``d (m,)``.
An estimator augmented with ``d`` (``KalmanFilter(...,
disturbance_model="input")``; the scenario layer builds it) hands the
controller ``[x̂; d̂]``. The MPC then optimizes the *effective* input
``v = u + d̂``: its prediction model, cost and horizon are unchanged in ``v``,
so the target input shifts from ``u_ref`` to ``u_ref − d̂`` (the steady state
holds ``x = r`` with ``u = u_ref − d̂``), and the applied input is
``u = v − d̂``. At a steady state of the loop the estimator's innovation is
zero, so when the number of measured outputs equals ``m`` (and the augmented
model is detectable) the measured outputs reach their set-points despite
the disturbance (Pannocchia and Rawlings' offset-free condition).

Input bounds: the QP keeps its bounds on ``v`` (the bounds of ``u`` shifted
by ``d̂`` would change the QP at every call); the returned ``u = v − d̂`` is
clipped to ``[u_min, u_max]``, so the hard bounds always hold and the plan is
exact whenever the bounds on ``u`` are not active.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike

from shinro_ctrl.types import Vector
from shinro_ctrl.validation import as_vector

if TYPE_CHECKING:
    from shinro_ctrl.controllers.mpc import LinearMPC

__all__ = ["offset_free_call"]


def offset_free_call(
    mpc: LinearMPC, z: Vector, ref: ArrayLike | None = None, u_ref: ArrayLike | None = None
) -> np.ndarray:
    """The input ``u (m,)`` of an offset-free ``LinearMPC`` from the augmented estimate ``z = [x̂; d̂]`` ``(n + m,)``."""
    n, m = mpc.n, mpc.m
    z = as_vector("x", z, n + m)
    d = z[n:]
    v = type(mpc).__call__(mpc, z[:n].copy(), ref, u_ref=u_ref)
    u = v - d
    np.clip(u, mpc.u_min, mpc.u_max, out=u)
    return u
