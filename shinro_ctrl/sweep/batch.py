"""Vectorized closed-loop rollout of many plant instances under one LQR.

A robustness sweep runs the same controller on thousands of perturbed plants.
For a standalone loop with a linear state feedback, every instance can advance
together: the plant's one dynamics definition (:meth:`Plant.dynamics`) is
evaluated once per step on the whole batch ``X (N, n)``, ``U (N, m)`` with
per-instance parameters ``{name: (N,)}``, and the step is the same
semi-implicit Euler as :meth:`Plant.integrate` (velocities first, then the
positions with the new velocities, then the plant's own :meth:`Plant.clip_state`).
The metrics of :func:`shinro_ctrl.sim.compute_metrics` are accumulated per
instance while stepping, so memory stays ``O(N)`` whatever the duration.

Results agree with the per-instance :class:`~shinro_ctrl.sim.RobotSim` loop
to floating-point tolerance (different summation orders and vectorized
``sin``/``cos`` change the last bits); a closed loop that diverges amplifies
those bits, so compare diverging instances by verdict, not by value.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from shinro_ctrl.errors import InvalidArgument
from shinro_ctrl.plants import Plant
from shinro_ctrl.sim.metrics import StreamingMetrics, bound_excess
from shinro_ctrl.validation import as_vector, real_array

__all__ = ["BatchRollout", "batch_clip", "batch_unsupported_reason", "lqr_batch_rollout"]

ClipFn = Callable[[np.ndarray], np.ndarray]


def batch_clip(plant: Plant) -> ClipFn:
    """The batch form ``X (N, n) -> X`` of the plant's clipping: its own :meth:`Plant.clip_state`.

    The hook's contract is that it accepts a batch as well as one state, so the
    rollout clips exactly as the per-instance step does.
    """
    return plant.clip_state


def batch_unsupported_reason(plant: Plant, controller: Any) -> str | None:
    """Why ``plant`` + ``controller`` cannot use :func:`lqr_batch_rollout` (None if they can).

    Requirements: an :class:`~shinro_ctrl.controllers.LQR` (a linear law with
    ``K``, ``u0``), a standalone plant that integrates with the base
    semi-implicit Euler (position/velocity index pairs, no ``integrate``
    override), no state limits (stops),
    and constructor parameters that are exactly the dynamics' ``param_names``
    (so per-instance parameters can be handed to ``dynamics``).
    """
    from shinro_ctrl.controllers import LQR

    name = type(plant).__name__
    if not isinstance(controller, LQR):
        return f"the controller is {type(controller).__name__}, not LQR"
    if controller.stateful:
        return "the LQR integrates tracking errors (LQI): its law is not u = u0 - K x"
    if plant.engine is not None:
        return "the loop runs in MuJoCo"
    if type(plant).integrate is not Plant.integrate or not plant.position_indices:
        return f"{name} does not integrate with the base semi-implicit Euler"
    if np.isfinite(np.concatenate(plant.state_limits())).any():
        return f"{name} has state limits (stops) whose contacts the batch rollout does not count"
    if set(plant.params()) != set(plant.param_names):
        return (
            f"{name}'s constructor arguments ({', '.join(plant.params())}) do not map onto its dynamics "
            f"parameters ({', '.join(plant.param_names)})"
        )
    return None


@dataclass
class BatchRollout:
    """Per-instance outcome of :func:`lqr_batch_rollout`.

    Attributes:
        metrics: Metric name → ``(N,)`` array, as :func:`~shinro_ctrl.sim.compute_metrics`
            defines them (NaN for diverged instances). ``solve_time_median_s``
            is the median over steps of the batch controller call divided by
            ``N`` (amortized per instance).
        diverged_step: ``(N,)`` int: the step ``k`` whose update made the
            state non-finite (the loop time is ``t[k]``), or -1.
        t: Times ``(steps + 1,)`` [s].
        finite: ``(N,)`` bool: every state of the instance stayed finite.
        elapsed_s: Wall time of the rollout [s].
    """

    metrics: dict[str, np.ndarray]
    diverged_step: np.ndarray
    t: np.ndarray
    finite: np.ndarray
    elapsed_s: float


def lqr_batch_rollout(
    plant: Plant,
    controller: Any,
    *,
    params: Mapping[str, np.ndarray],
    x0: np.ndarray,
    ref: np.ndarray,
    steps: int,
    tracked: list[int],
    settle_tol: float = 0.01,
    progress: Callable[[int, int], None] | None = None,
) -> BatchRollout:
    """Roll out ``N`` plant instances under the LQR ``u = u0 − K (x − r)`` for ``steps`` steps.

    Each step: ``U = clip(u0 − (X − r) Kᵀ, u_min, u_max)``, ``Ẋ =
    plant.dynamics(X, U, params=params)`` (one numpy evaluation for the whole
    batch), then ``v ← v + dt v̇`` and ``q ← q + dt v`` for every
    (position, velocity) index pair, then the plant's clipping. An instance
    whose state becomes non-finite is marked diverged at that step and frozen
    (its row is reset to ``r``), so it never poisons the others.

    Args:
        plant: The nominal plant (its ``dt``, indices, clipping and the
            parameters not in ``params``); see :func:`batch_unsupported_reason`.
        controller: An LQR (``K (m, n)``, ``u0 (m,)``, ``u_min``, ``u_max``).
        params: Dynamics parameter name → ``(N,)`` values.
        x0: Initial state ``(n,)`` shared by all instances, or ``(N, n)``.
        ref: Constant reference state ``(n,)``.
        steps: Number of steps of ``plant.dt``.
        tracked: State indices of the tracking error.
        settle_tol: Error band of ``settling_time``.
        progress: Optional ``callback(done_steps, steps)``.

    Returns:
        A :class:`BatchRollout`.

    Raises:
        ValueError: the plant/controller pair is not supported, or shapes disagree.
    """
    reason = batch_unsupported_reason(plant, controller)
    if reason is not None:
        raise InvalidArgument(f"batch rollout not supported: {reason}")
    clip = batch_clip(plant)
    n, m, dt = plant.state_dim, plant.input_dim, plant.dt
    N, P, X, r = _batch_inputs(n, params, x0, ref)
    K, u0, u_min, u_max, saturate, x_min, x_max = _law(controller, n, m)
    x_bounds = x_min is not None or x_max is not None
    qi = np.asarray(plant.position_indices, dtype=int)
    vi = np.asarray(plant.velocity_indices, dtype=int)

    t = np.arange(steps + 1) * dt
    alive = np.ones(N, dtype=bool)
    died = np.full(N, -1, dtype=int)
    acc = StreamingMetrics(N, tracked, r, settle_tol, *((u_min, u_max) if saturate else (None, None)))
    x_excess = np.zeros(N)  # bound excess of the current state (index k); none at k = 0
    call_times = np.empty(steps)
    clock = time.perf_counter
    start = clock()
    every = max(1, steps // 100)

    with np.errstate(all="ignore"):
        acc.track(X, 0)
        for k in range(steps):
            c0 = clock()
            U = u0 - (X - r) @ K.T
            if saturate:
                np.clip(U, u_min, u_max, out=U)
            call_times[k] = clock() - c0
            # compute_metrics' violation at index k: input k and state k (for k >= 1).
            acc.inputs(U, np.maximum(bound_excess(U, u_min, u_max), x_excess) if saturate else x_excess)

            Xd = plant.dynamics(X, U, params=P)
            X[:, vi] += dt * Xd[:, vi]
            X[:, qi] += dt * X[:, vi]
            X = clip(X)

            bad = alive & ~np.isfinite(X).all(axis=1)
            if bad.any():
                died[bad] = k
                alive &= ~bad
                X[bad] = r
            if x_bounds:
                x_excess = bound_excess(X, x_min, x_max)
            acc.track(X, k + 1)
            if progress is not None and (k % every == 0 or k == steps - 1):
                progress(k + 1, steps)
        acc.violation(x_excess)  # index T: the final state only
    elapsed = clock() - start
    metrics = acc.finish(t, call_times, alive)
    return BatchRollout(metrics=metrics, diverged_step=died, t=t, finite=alive, elapsed_s=elapsed)


def _batch_inputs(
    n: int, params: Mapping[str, np.ndarray], x0: np.ndarray, ref: np.ndarray
) -> tuple[int, dict[str, np.ndarray], np.ndarray, np.ndarray]:
    """Validated ``(N, params, X (N, n) a fresh copy of x0, ref (n,))`` of :func:`lqr_batch_rollout`."""
    sizes = {np.shape(v) for v in params.values()}
    if len(sizes) != 1 or len(next(iter(sizes))) != 1:
        raise InvalidArgument(f"params must all be (N,) arrays of one length, got shapes {sorted(sizes)}")
    N = next(iter(sizes))[0]
    P = {k: real_array(f"params[{k!r}]", v) for k, v in params.items()}
    x0_ = real_array("x0", x0)
    if x0_.shape not in ((n,), (N, n)):
        raise InvalidArgument(f"x0: expected shape ({n},) or ({N}, {n}) for {N} instances but found {x0_.shape}")
    X = np.array(np.broadcast_to(x0_, (N, n)))
    r = as_vector("ref", ref, n)
    return N, P, X, r


def _law(controller: Any, n: int, m: int) -> tuple:
    """``(K, u0, u_min, u_max, saturate, x_min, x_max)`` of the LQR, the state bounds None unless ``(n,)``."""
    K = np.asarray(controller.K, dtype=float).reshape(m, n)
    u0 = np.asarray(controller.u0, dtype=float).reshape(m)
    u_min = np.asarray(controller.u_min, dtype=float)
    u_max = np.asarray(controller.u_max, dtype=float)
    saturate = bool(np.isfinite(u_min).any() or np.isfinite(u_max).any())
    x_min, x_max = controller.x_min, controller.x_max
    if x_min is not None and np.shape(x_min) != (n,):
        x_min = None
    if x_max is not None and np.shape(x_max) != (n,):
        x_max = None
    return K, u0, u_min, u_max, saturate, x_min, x_max
