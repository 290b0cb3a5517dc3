"""All the linear analyses of one designed controller in one object.

:func:`analyze_controller` takes an LQR or a LinearMPC (anything with the
model it was designed on) and returns the pole table, the structure report,
the loop margins and the step metrics of the *linear* closed loop. For a
LinearMPC the feedback analysed is its unconstrained first move, which is
linear: ``δu_0 = −K_N δx`` with ``K_N`` from the backward Riccati recursion
over the horizon ``N`` from the terminal cost ``P_f``,

    P_N = P_f,   P_k = Q + Aᵀ P_{k+1} A − Aᵀ P_{k+1} B (R + Bᵀ P_{k+1} B)⁻¹ Bᵀ P_{k+1} A,
    K_N = (R + Bᵀ P_1 B)⁻¹ Bᵀ P_1 A

(valid while no constraint is active; equal to the LQR gain with the default
``terminal_cost = "lqr"``).
"""

from __future__ import annotations

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
    A: np.ndarray, B: np.ndarray, Q: np.ndarray, R: np.ndarray, P_f: np.ndarray, N: int
) -> np.ndarray:
    """First-move gain ``K_N (m, n)`` of the unconstrained finite-horizon problem (see the module docstring)."""
    P = np.asarray(P_f, dtype=float)
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
    unconstrained first-move gain :func:`finite_horizon_gain`.

    Raises:
        InvalidArgument: a controller without a linear model and gain (e.g. IKQP).
    """
    A = getattr(controller, "A", None)
    B = getattr(controller, "B", None)
    if A is None or B is None:
        raise InvalidArgument(f"{type(controller).__name__} has no linear model (A, B) to analyse")
    model = getattr(controller, "model", None)
    if hasattr(controller, "P_f") and hasattr(controller, "horizon"):
        K = finite_horizon_gain(
            controller.A, controller.B, controller.Q, controller.R, controller.P_f, controller.horizon
        )
        dt = getattr(controller, "dt", None) or (model.dt if model is not None else None)
        if dt is None:
            raise InvalidArgument("LinearMPC without dt: build it with from_plant or pass dt=")
        return np.asarray(A), np.asarray(B), K, float(dt)
    K = getattr(controller, "K", None)
    if K is None:
        raise InvalidArgument(f"{type(controller).__name__} has no feedback gain K to analyse")
    lqi = getattr(controller, "_lqi", None)  # LQI: the loop includes the error integrators
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
        out.append(f"  {'response':24s} {'rise [s]':>9s} {'overshoot':>10s} {'settle 2%':>10s} {'ss error':>10s}")
        for label, s in self.responses.items():
            out.append(
                f"  {label[:24]:24s} {_g(s.rise_time):>9s} {s.overshoot:9.2f}% {_g(s.settling_time):>10s} "
                f"{s.steady_state_error:10.3g}"
            )
        return "\n".join(out)


def _g(v: float) -> str:
    return "inf" if math.isinf(v) else f"{v:.4g}"


def _horizon(poles: PoleTable, dt: float, cap: int = 20000) -> int:
    taus = [r.tau for r in poles.rows if math.isfinite(r.tau)]
    T = 8.0 * max(taus, default=1.0)
    return int(min(cap, max(50, math.ceil(T / dt))))


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
        state_names, input_names: Labels (default the controller's model's plant names, else ``x[i]``/``u[i]``).
        duration: Length of the linear responses [s] (default 8 × the slowest time constant).

    Returns:
        A :class:`DesignAnalysis`. A continuous LQR is analysed on its
        continuous model (margins at ``s = jω``, responses by ``c2d`` at 1 ms).
    """
    A, B, K, dt = feedback_gain(controller)
    n, m = B.shape
    x0 = np.asarray(getattr(controller, "x0", np.zeros(n)), dtype=float)
    n_p = x0.shape[0]  # plant states; n > n_p when the loop carries integrators (LQI)
    snames = tuple(state_names or getattr(controller, "state_names", None) or (f"x[{i}]" for i in range(n_p)))
    # a reference step δr (n_p,) enters the loop as E δr: u = −K_x (x − r) − K_i z, z⁺ = z + dt (x − r)[idx]
    E = B @ K[:, :n_p]
    lqi = getattr(controller, "_lqi", None)
    if n > n_p and lqi is not None:
        snames = (*snames[:n_p], *(f"∫{snames[i]}" for i in lqi.indices))
        E = np.vstack([B[:n_p] @ K[:, :n_p], -lqi.dt * np.eye(n_p)[lqi.indices]])
        x0 = np.concatenate([x0, np.zeros(n - n_p)])
        if x_init is not None:
            x_init = np.concatenate([np.asarray(x_init, dtype=float), np.zeros(n - n_p)])
    inames = tuple(input_names or getattr(controller, "input_names", None) or (f"u[{i}]" for i in range(m)))
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
    steps = _horizon(ptab, step_dt) if duration is None else max(2, round(duration / step_dt))
    t = np.arange(steps + 1) * step_dt
    responses: dict[str, StepMetrics] = {}
    x_lin = np.zeros((steps + 1, n))
    if x_init is not None:
        d0 = np.asarray(x_init, dtype=float) - x0
        X = closed_loop_response(Ad, Bd, Kd, d0, steps)
        x_lin = X + x0
        scale = max(np.abs(d0).max(), 1e-300)
        for i in np.flatnonzero(np.abs(d0) > 1e-9 * scale):
            responses[f"initial: {snames[i]}"] = step_metrics(t, X[:, i], initial=d0[i], final=0.0, target=0.0)
    Acl = Ad - Bd @ Kd
    for name in tracked or ():
        if name not in snames[:n_p]:
            raise InvalidArgument(f"tracked: unknown state '{name}'; states: {', '.join(snames)}")
        j = snames.index(name)
        X = np.zeros((steps + 1, n))
        for k in range(steps):
            X[k + 1] = Acl @ X[k] + Bc_step[:, j]
        try:
            x_ss = np.linalg.solve(np.eye(n) - Acl, Bc_step[:, j])  # exact steady state of the unit step
            if abs(x_ss[j]) < 1e-6:  # the loop does not hold this state off its equilibrium: no step response
                continue
            responses[f"step: {name}"] = step_metrics(t, X[:, j], initial=0.0, final=float(x_ss[j]), target=1.0)
        except InvalidArgument:  # the state does not move at all: nothing to measure
            continue
    return t, x_lin, responses
