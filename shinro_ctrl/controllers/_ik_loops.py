"""The iteration loops of :class:`~shinro_ctrl.controllers.ik_qp.IKQP`: solve to a tolerance, track for one step.

Free functions over an explicit :class:`~shinro_ctrl.controllers._ik_parts.IKKernel`
(the kinematics, task error and box QP of one arm): :func:`solve_to_tolerance`
repeats the kernel's QP step to convergence with random restarts (inverse
kinematics), :func:`track_step` for the few iterations of one control step
inside the velocity box.
"""

from __future__ import annotations

import math

import numpy as np

from shinro_ctrl.controllers._ik_parts import IKKernel
from shinro_ctrl.kinematics import IKResult

__all__ = ["solve_to_tolerance", "track_step"]


def solve_to_tolerance(
    kernel: IKKernel,
    q0: np.ndarray,
    pt: list[float],
    Rt: np.ndarray,
    s: np.ndarray,
    neg_s: np.ndarray,
    *,
    max_iters: int,
    tol: float,
    restarts: int,
    seed: int | None,
) -> IKResult:
    """IK from ``q0`` (inside the limits) to the target ``(pt, Rt)``, each iteration inside ``|Δq| ≤ s``.

    Attempts after the first start from random joint vectors drawn uniformly
    inside ``[sample_lo, sample_hi]`` (``numpy.random.default_rng(seed)``, seed
    0 for None); the best attempt (converged, else the smallest weighted error)
    is returned. The QP's warm start is reset first, so the result depends only
    on the arguments (see :meth:`IKQP.solve`).
    """
    kernel.qp.reset()  # the same call gives the same answer, whatever was solved before
    best, total = _attempt(kernel, q0, pt, Rt, s, neg_s, max_iters, tol)
    attempts = 1
    rng = None
    while not best[1] and attempts <= restarts:
        rng = rng or np.random.default_rng(0 if seed is None else seed)
        start = rng.uniform(kernel.sample_lo, kernel.sample_hi)
        res, its = _attempt(kernel, start, pt, Rt, s, neg_s, max_iters, tol)
        total += its
        attempts += 1
        if res[1] or res[4] < best[4]:
            best = res
    q, converged, pos_err, ori_err, _ = best
    if q is not kernel.evaluated:  # a restart was run after the best attempt
        kernel.evaluate(q)
    return IKResult(q, converged, total, pos_err, ori_err, kernel.J[: kernel.k].copy(), attempts)


def _attempt(
    kernel: IKKernel,
    q: np.ndarray,
    pt: list[float],
    Rt: np.ndarray,
    s: np.ndarray,
    neg_s: np.ndarray,
    max_iters: int,
    tol: float,
) -> tuple[tuple[np.ndarray, bool, float, float, float], int]:
    """One local solve; returns ``((q, converged, pos_err, ori_err, cost), iterations)``."""
    lo, hi = kernel.lo, kernel.hi
    weights = kernel.weights
    w0, w1, w2 = weights[:3].tolist()
    w3, w4, w5 = weights[3:].tolist() if kernel.k == 6 else (0.0, 0.0, 0.0)
    pose = kernel.k == 6
    evaluate, error, qp_step = kernel.evaluate, kernel.error, kernel.qp_step
    best_cost = math.inf
    stalled = 0
    it = 0
    while True:
        evaluate(q)
        pos_err, ori_err = error(pt, Rt)
        if pos_err < tol and (ori_err < tol or not pose):
            return (q, True, pos_err, ori_err, 0.0), it
        e0, e1, e2, e3, e4, e5 = kernel.et
        cost = w0 * e0 * e0 + w1 * e1 * e1 + w2 * e2 * e2 + w3 * e3 * e3 + w4 * e4 * e4 + w5 * e5 * e5
        if cost < best_cost * (1.0 - 1e-6):
            best_cost, stalled = cost, 0
        else:
            stalled += 1
        if it >= max_iters or stalled >= 10:
            return (q, False, pos_err, ori_err, cost), it
        scale = math.sqrt(e0 * e0 + e1 * e1 + e2 * e2 + (e3 * e3 + e4 * e4 + e5 * e5 if pose else 0.0))
        q, _ = qp_step(q, lo, hi, s, neg_s, scale)
        it += 1


def track_step(
    kernel: IKKernel,
    q0: np.ndarray,
    pt: list[float],
    Rt: np.ndarray,
    vdt: np.ndarray,
    *,
    iters: int,
    tol: float,
) -> tuple[np.ndarray, int, int, float, float]:
    """Up to ``iters`` QP iterations from ``q0`` towards ``(pt, Rt)`` inside ``|q' − q0| ≤ vdt`` and the limits.

    Returns:
        ``(q, iterations, OSQP status of the last QP (-1: none), pos_err, ori_err)``.
    """
    neg_vdt = -vdt
    box_lo = np.maximum(kernel.lo, q0 - vdt)
    box_hi = np.minimum(kernel.hi, q0 + vdt)
    q = q0
    status = -1
    it = 0
    while True:
        kernel.evaluate(q)
        pos_err, ori_err = kernel.error(pt, Rt)
        if it >= iters or kernel.converged(pos_err, ori_err, tol):
            return q, it, status, pos_err, ori_err
        scale = math.hypot(pos_err, ori_err) if kernel.k == 6 else pos_err
        q, status = kernel.qp_step(q, box_lo, box_hi, vdt, neg_vdt, scale)
        it += 1
