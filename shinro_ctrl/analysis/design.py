"""All the linear analyses of one designed controller in one object.

:func:`analyze_controller` takes an LQR or a LinearMPC (anything with the
model it was designed on) and returns the pole table, the structure report,
the loop margins and the step metrics of the *linear* closed loop. For a
LinearMPC the feedback analysed is its unconstrained first move, which is
linear: ``δu_0 = −K_N δx`` with ``K_N`` from the backward Riccati recursion
over the horizon ``N`` from the terminal cost ``Qf``,

    P_N = Q_f,   P_k = Q + Aᵀ P_{k+1} A − Aᵀ P_{k+1} B (R + Bᵀ P_{k+1} B)⁻¹ Bᵀ P_{k+1} A,
    K_N = (R + Bᵀ P_1 B)⁻¹ Bᵀ P_1 A

(valid while no constraint is active; equal to the LQR gain with the default
``terminal_cost = "lqr"``).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from shinro_ctrl.analysis.margins import LoopMargins, loop_margins
from shinro_ctrl.analysis.poles import PoleTable, pole_table
from shinro_ctrl.analysis.response import StepMetrics, closed_loop_response, step_metrics
from shinro_ctrl.analysis.structure import StructureReport, structure_report
from shinro_ctrl.errors import InvalidArgument

__all__ = ["DesignAnalysis", "analyze_controller", "feedback_gain", "finite_horizon_gain"]


def finite_horizon_gain(
    A: np.ndarray, B: np.ndarray, Q: np.ndarray, R: np.ndarray, Qf: np.ndarray, N: int
) -> np.ndarray:
    """First-move gain ``K_N (m, n)`` of the unconstrained finite-horizon problem (see the module docstring)."""
    P = np.asarray(Qf, dtype=float)
    K = np.zeros((B.shape[1], A.shape[0]))
    for _ in range(int(N)):
        BtP = B.T @ P
        K = np.linalg.solve(R + BtP @ B, BtP @ A)
        P = Q + A.T @ P @ A - (A.T @ P @ B) @ K
        P = 0.5 * (P + P.T)
    return K


def feedback_gain(controller: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray, float | None]:
    """``(A, B, K, dt)`` of the linear state feedback a controller applies near its operating point.

    LQR: its ``K`` on its own ``(A, B)`` (continuous when designed with
    ``discrete=False``, then ``dt`` is None); with integral action (LQI) the
    model augmented with the integrators and ``[K, K_i]``. LinearMPC: the
    unconstrained first-move gain ``K_mpc`` (:func:`finite_horizon_gain`).

    Raises:
        InvalidArgument: a controller without a linear model and gain (e.g. IKQP).
    """
    A = getattr(controller, "A", None)
    B = getattr(controller, "B", None)
    if A is None or B is None:
        raise InvalidArgument(f"{type(controller).__name__} has no linear model (A, B) to analyse")
    model = getattr(controller, "model", None)
    K_mpc = getattr(controller, "K_mpc", None)  # LinearMPC: its unconstrained first-move gain
    if K_mpc is not None:
        K = np.asarray(K_mpc)
        dt = getattr(controller, "dt", None) or (model.dt if model is not None else None)
        if dt is None:
            raise InvalidArgument("LinearMPC without dt: build it with from_plant or pass dt=")
        return np.asarray(A), np.asarray(B), K, float(dt)
    K = getattr(controller, "K", None)
    if K is None:
        raise InvalidArgument(f"{type(controller).__name__} has no feedback gain K to analyse")
    lqi = getattr(controller, "integral_action", None)  # LQI: the loop includes the error integrators
    if lqi is not None:
        A, B, K = lqi.A_aug, lqi.B_aug, np.hstack([K, lqi.K_i])
    if getattr(controller, "discrete", True):
        dt = model.dt if model is not None else getattr(controller, "dt", None)
        if dt is None:
            raise InvalidArgument("a discrete LQR built from matrices has no dt; use LQR.from_plant")
        return np.asarray(A), np.asarray(B), np.asarray(K), float(dt)
    return np.asarray(A), np.asarray(B), np.asarray(K), None


@dataclass
class DesignAnalysis:
    """Everything :func:`analyze_controller` computes.

    Attributes:
        A, B, K: The analysed loop ``(n, n)``, ``(n, m)``, ``(m, n)``.
        dt: Sampling time [s] (None: continuous).
        state_names, input_names: Labels.
        poles: :class:`PoleTable` of ``A − B K``.
        structure: :class:`StructureReport` of ``(A, B, C)``.
        margins: :class:`LoopMargins`.
        t: Times ``(T + 1,)`` of the linear initial-condition response [s].
        x_lin: Linear closed-loop states ``(T + 1, n)`` in absolute units from ``x_init``.
        responses: Label → :class:`StepMetrics` (``"initial: theta"``, ``"step: x"``, …).
        measured: States used as outputs for the observability test.
        x0, u0: Operating point ``(n,)``, ``(m,)``.
    """

    A: np.ndarray
    B: np.ndarray
    K: np.ndarray
    dt: float | None
    state_names: tuple[str, ...]
    input_names: tuple[str, ...]
    poles: PoleTable
    structure: StructureReport
    margins: LoopMargins
    t: np.ndarray
    x_lin: np.ndarray
    responses: dict[str, StepMetrics] = field(default_factory=dict)
    measured: tuple[str, ...] = ()
    x0: np.ndarray | None = None
    u0: np.ndarray | None = None

    @property
    def zeta_min(self) -> float:
        return self.poles.zeta_min

    def format(self) -> str:
        """Text of all tables (what ``shinro-ctrl design`` prints)."""
        out = [
            "closed-loop pole table (continuous equivalents s = ln(z)/dt):" if self.dt else "closed-loop pole table:",
            self.poles.format(),
        ]
        obs = f" (observability from the measured states {', '.join(self.measured)})" if self.measured else ""
        out += [f"structure{obs}:", self.structure.format()]
        out += ["loop margins (loop broken at the plant input):", self.margins.format()]
        out.append("linear closed-loop response metrics:")
        w = max([24, *(len(label) for label in self.responses)])
        out.append(f"  {'response':{w}s} {'rise [s]':>9s} {'overshoot':>10s} {'settle 2%':>10s} {'ss error':>10s}")
        for label, s in self.responses.items():
            out.append(
                f"  {label:{w}s} {_g(s.rise_time):>9s} {s.overshoot:9.2f}% {_g(s.settling_time):>10s} "
                f"{_g(s.steady_state_error, '.3g'):>10s}"
            )
        return "\n".join(out)


def _g(v: float | None, fmt: str = ".4g") -> str:
    return "n/a" if v is None or not math.isfinite(v) else format(v, fmt)


#: Longest linear response [steps of dt] :func:`analyze_controller` extends to while a response has not settled.
MAX_RESPONSE_STEPS = 10_000_000


def _horizon(poles: PoleTable, dt: float, cap: int = 20000) -> int:
    taus = [r.tau for r in poles.rows if math.isfinite(r.tau)]
    T = 8.0 * max(taus, default=1.0)
    return int(min(cap, max(50, math.ceil(T / dt))))


def _holdable(A: np.ndarray, B: np.ndarray, j: int, n_p: int, discrete: bool) -> bool:
    """True when a unit step in state ``j`` (the other references at the operating point) is an equilibrium.

    The reference ``δx = e_j`` can be held iff some ``δu`` solves ``(A − I) e_j + B δu = 0``
    (discrete) or ``A e_j + B δu = 0`` (continuous) on the plant's own states. An
    underactuated plant cannot hold most states at an offset (a pendulum tilted at rest):
    its steady-state error for that step is then not applicable.
    """
    Ap, Bp = A[:n_p, :n_p], B[:n_p]
    col = Ap[:, j] - (1.0 if discrete else 0.0) * np.eye(n_p)[:, j]
    size = float(np.linalg.norm(col))
    if size == 0.0:
        return True
    du = np.linalg.lstsq(Bp, -col, rcond=None)[0]
    return bool(np.linalg.norm(col + Bp @ du) <= 1e-8 * (size + float(np.linalg.norm(Bp)) * float(np.linalg.norm(du))))


def analyze_controller(
    controller: Any,
    *,
    x_init: Any = None,
    measured: Any = None,
    tracked: Any = None,
    state_names: Any = None,
    input_names: Any = None,
    duration: float | None = None,
) -> DesignAnalysis:
    """Poles, structure, margins and linear response metrics of a designed controller.

    Args:
        controller: An LQR or LinearMPC (see :func:`feedback_gain`).
        x_init: Initial state ``(n,)`` (absolute) of the initial-condition
            response; default none (only reference steps).
        measured: Names of measured states for the observability test (default: skip it).
        tracked: Names of states whose unit reference step is analysed (default none).
        state_names, input_names: Labels (default the controller's, else its model's: the plant's names; else
            ``x[i]``/``u[i]``).
        duration: Least length of the linear responses [s] (e.g. the scenario's duration). Default and
            at least: 8 × the slowest time constant; extended (doubling, up to
            :data:`MAX_RESPONSE_STEPS`) until every response settles.

    Returns:
        A :class:`DesignAnalysis`. A continuous LQR is analysed on its
        continuous model (margins at ``s = jω``, responses by ``c2d`` at 1 ms).
        A reference step in a state the plant cannot hold at an offset (no
        input makes it an equilibrium) has ``steady_state_error`` None
        (printed ``n/a``).
    """
    A, B, K, dt = feedback_gain(controller)
    n, m = B.shape
    x0 = np.asarray(getattr(controller, "x0", np.zeros(n)), dtype=float)
    n_p = x0.shape[0]  # plant states; n > n_p when the loop carries integrators (LQI)
    model = getattr(controller, "model", None)  # the plant's names travel with the model it was designed on
    snames = tuple(
        state_names
        or getattr(controller, "state_names", None)
        or getattr(model, "state_names", None)
        or (f"x[{i}]" for i in range(n_p))
    )
    # a reference step δr (n_p,) enters the loop as E δr: u = −K_x (x − r) − K_i z, z⁺ = z + dt (x − r)[idx]
    E = B @ K[:, :n_p]
    lqi = getattr(controller, "integral_action", None)
    if n > n_p and lqi is not None:
        snames = (*snames[:n_p], *(f"∫{snames[i]}" for i in lqi.indices))
        E = np.vstack([B[:n_p] @ K[:, :n_p], -lqi.dt * np.eye(n_p)[lqi.indices]])
        x0 = np.concatenate([x0, np.zeros(n - n_p)])
        if x_init is not None:
            x_init = np.concatenate([np.asarray(x_init, dtype=float), np.zeros(n - n_p)])
    inames = tuple(
        input_names
        or getattr(controller, "input_names", None)
        or getattr(model, "input_names", None)
        or (f"u[{i}]" for i in range(m))
    )
    lam = np.linalg.eigvals(A - B @ K)
    poles = pole_table(lam, dt)
    C = None
    meas = tuple(measured or ())
    if meas:
        bad = [s for s in meas if s not in snames]
        if bad:
            raise InvalidArgument(f"measured: unknown state '{bad[0]}'; states: {', '.join(snames)}")
        meas = (*meas, *snames[n_p:])  # integrator states are the controller's own: always known
        C = np.eye(n)[[snames.index(s) for s in meas]]
    structure = structure_report(A, B, C, discrete=dt is not None, state_names=snames)
    margins = loop_margins((A, B), K, dt=dt, input_names=inames)
    t, x_lin, responses = _linear_responses(A, B, K, dt, E, poles, duration, x_init, x0, snames, n_p, tracked)
    u0 = np.asarray(getattr(controller, "u0", np.zeros(m)), dtype=float)
    return DesignAnalysis(A, B, K, dt, snames, inames, poles, structure, margins, t, x_lin, responses, meas, x0, u0)


def _linear_responses(
    A: np.ndarray,
    B: np.ndarray,
    K: np.ndarray,
    dt: float | None,
    E: np.ndarray,
    poles: PoleTable,
    duration: float | None,
    x_init: Any,
    x0: np.ndarray,
    snames: tuple[str, ...],
    n_p: int,
    tracked: Any,
) -> tuple[np.ndarray, np.ndarray, dict[str, StepMetrics]]:
    """The initial-condition and unit-step responses of :func:`analyze_controller`: ``(t, x_lin, responses)``.

    Computed on a discrete model (a continuous loop is sampled at 1 ms); ``E (n, n_p)`` maps a
    reference step onto the closed loop.
    """
    n, m = B.shape
    if dt is None:
        import scipy.linalg

        h = 1e-3
        Acl_d = scipy.linalg.expm((A - B @ K) * h)
        step_dt, Ad, Bd, Kd = h, Acl_d, np.zeros((n, m)), np.zeros((m, n))
        Bc_step = np.linalg.solve(A - B @ K, (Acl_d - np.eye(n)) @ E)  # ZOH of E δr
    else:
        step_dt, Ad, Bd, Kd = dt, A, B, K
        Bc_step = E
    ptab = poles if dt is not None else pole_table(np.linalg.eigvals(Ad - Bd @ Kd), step_dt)
    steps = _horizon(ptab, step_dt)
    if duration is not None:
        steps = max(steps, round(duration / step_dt))
    steps = min(steps, MAX_RESPONSE_STEPS)
    t = np.arange(steps + 1) * step_dt
    Acl = Ad - Bd @ Kd
    x_lin = np.zeros((steps + 1, n))
    starts: dict[str, tuple[np.ndarray, int, float, float]] = {}  # label -> (start, index, final, target)
    if x_init is not None:
        d0 = np.asarray(x_init, dtype=float) - x0
        x_lin = closed_loop_response(Ad, Bd, Kd, d0, steps) + x0
        scale = max(np.abs(d0).max(), 1e-300)
        for i in np.flatnonzero(np.abs(d0) > 1e-9 * scale):
            starts[f"initial: {snames[i]}"] = (d0, int(i), 0.0, 0.0)
    steps_of: dict[str, int] = {}
    for name in tracked or ():
        if name not in snames[:n_p]:
            raise InvalidArgument(f"tracked: unknown state '{name}'; states: {', '.join(snames)}")
        j = snames.index(name)
        try:
            x_ss = np.linalg.solve(np.eye(n) - Acl, Bc_step[:, j])  # exact steady state of the unit step
        except np.linalg.LinAlgError:
            continue
        if abs(x_ss[j]) < 1e-6:  # the loop does not hold this state off its equilibrium: no step response
            continue
        starts[f"step: {name}"] = (-x_ss, j, float(x_ss[j]), 1.0)  # the step: x − x_ss from −x_ss to 0
        steps_of[f"step: {name}"] = j
    responses: dict[str, StepMetrics] = {}
    for label, (start, i, final, target) in starts.items():
        metrics = _settled_response(Acl, start, i, final, target, steps, step_dt)
        if metrics is None:
            continue  # the state does not move at all: nothing to measure
        if label in steps_of and not _holdable(A, B, i, n_p, dt is not None):
            metrics = dataclasses.replace(metrics, steady_state_error=None)  # cannot be held at an offset
        responses[label] = metrics
    return t, x_lin, responses


def _settled_response(
    Acl: np.ndarray, start: np.ndarray, i: int, final: float, target: float, steps: int, dt: float
) -> StepMetrics | None:
    """The metrics of state ``i`` of ``δx_{k+1} = Acl δx_k`` from ``start``, shifted so it ends at ``final``.

    A step response ``x_{k+1} = Acl x_k + b`` from 0 is ``x_ss + δx`` with ``δx`` from ``−x_ss``.
    Sampled every ``stride`` steps (``Acl^stride``), the stride doubling, ``steps`` samples each
    time, until the response settles or spans :data:`MAX_RESPONSE_STEPS`.
    """
    stride, P = 1, Acl
    while True:
        X = closed_loop_response(P, np.zeros((Acl.shape[0], 1)), np.zeros((1, Acl.shape[0])), start, steps)
        t = np.arange(steps + 1) * dt * stride
        try:
            m = step_metrics(t, X[:, i] + final, initial=float(start[i]) + final, final=final, target=target)
        except InvalidArgument:
            return None
        if m.settling_time is not None or 2 * stride * steps > MAX_RESPONSE_STEPS:
            return m
        stride, P = 2 * stride, P @ P
