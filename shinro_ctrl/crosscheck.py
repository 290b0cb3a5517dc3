"""Three independent linearizations of a plant, side by side.

For a plant with a matched MuJoCo model, :func:`crosscheck` computes the
continuous Jacobians ``A_c = ∂f/∂x``, ``B_c = ∂f/∂u`` at an operating point
three ways:

* **exact**: CasADi's symbolic Jacobian of the plant's dynamics;
* **fd**: central finite differences of the plant's numeric dynamics;
* **mujoco**: MuJoCo's ``mjd_transitionFD`` on the matched MJCF model
  (built by ``MujocoEngine.for_plant(plant, model="matched")``: the plant's exact
  twin; for a user's model file, a copy with Euler, explicit damping and contacts,
  limits, friction loss and clamps off, whatever the MuJoCo loop runs).

MuJoCo differentiates one discrete step. With its Euler integrator
(semi-implicit: ``v⁺ = v + h a(q, v, u)``, ``q⁺ = q + h v⁺``) and explicit
damping (``mjDSBL_EULERDAMP``), the velocity rows of the transition Jacobians
are exactly ``[h ∂a/∂q, I + h ∂a/∂v]`` and ``h ∂a/∂u``, so the continuous
acceleration Jacobians are recovered without discretization error; the
position rows of the continuous model are ``q̇ = v``; actuator activations
(``act⁺ = act + h_a ȧct``) likewise give their rows exactly. The result, in
MuJoCo's order ``z = [qpos, qvel, act]``, is converted to the plant's state with the plant's
``engine_state_map()``: ``x = T z`` gives ``A_x = T A_z T⁻¹``, ``B_x = T B_z``.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from shinro_ctrl.engine import MujocoEngine
from shinro_ctrl.errors import InvalidArgument
from shinro_ctrl.validation import as_vector, check_positive

__all__ = ["CrosscheckResult", "crosscheck", "format_crosscheck", "mujoco_continuous_jacobians"]

_REPEATS = 5


@dataclass(frozen=True)
class CrosscheckResult:
    """Exact, finite-difference and MuJoCo linearizations of one plant.

    All matrices are continuous-time and in the plant's state order.

    Attributes:
        plant: ``repr`` of the plant (class and parameters).
        state_names: Names of the ``n`` states.
        input_names: Names of the ``m`` inputs.
        x0: Operating state ``(n,)``.
        u0: Operating input ``(m,)``.
        A_exact, B_exact: CasADi Jacobians ``(n, n)``, ``(n, m)``.
        A_fd, B_fd: Central finite differences of the plant's dynamics.
        A_mujoco, B_mujoco: From ``mjd_transitionFD`` on the matched model.
        fd_max_abs_error: ``max |fd − exact|`` over A and B.
        fd_max_rel_error: ``max |fd − exact| / max(1, |exact|)`` over A and B.
        mujoco_max_abs_error: ``max |mujoco − exact|`` over A and B.
        mujoco_max_rel_error: ``max |mujoco − exact| / max(1, |exact|)``.
        eps: Finite-difference step used by both fd and MuJoCo.
        mujoco_timestep: MuJoCo's ``opt.timestep`` [s] (the differentiated step).
        model: Path of the MJCF model.
        time_exact_s: One exact evaluation [s] (median, compiled function).
        time_fd_s: One finite-difference linearization [s] (median).
        time_mujoco_s: One ``mjd_transitionFD`` plus conversion [s] (median).
        time_build_s: Loading, patching and compiling the MuJoCo model [s].
    """

    plant: str
    state_names: tuple[str, ...]
    input_names: tuple[str, ...]
    x0: np.ndarray
    u0: np.ndarray
    A_exact: np.ndarray
    B_exact: np.ndarray
    A_fd: np.ndarray
    B_fd: np.ndarray
    A_mujoco: np.ndarray
    B_mujoco: np.ndarray
    fd_max_abs_error: float
    fd_max_rel_error: float
    mujoco_max_abs_error: float
    mujoco_max_rel_error: float
    eps: float
    mujoco_timestep: float
    model: str
    time_exact_s: float
    time_fd_s: float
    time_mujoco_s: float
    time_build_s: float


def mujoco_continuous_jacobians(
    engine: MujocoEngine, z0: Any, u0: Any, *, eps: float = 1e-6
) -> tuple[np.ndarray, np.ndarray]:
    """Continuous Jacobians of a MuJoCo model in its own state order ``z = [qpos, qvel, act]``.

    Sets the engine's state to ``z0`` and control to ``u0`` (they stay set),
    differentiates one Euler step with ``mjd_transitionFD`` and recovers the
    continuous rows (see the module docstring). Activations (``na > 0``) step
    as ``act⁺ = act + h_a ȧct`` with ``h_a = h`` (filter, integrator) or
    ``τ (1 − e^{−h/τ})`` (filterexact: MuJoCo's exact update), so their rows
    are recovered exactly too, away from an ``actrange`` clamp.

    Args:
        engine: An engine using the Euler integrator with explicit damping
            (as ``MujocoEngine.for_plant(plant, model="matched")`` builds), ``nq == nv``.
        z0: State ``(2 nv + na,)``.
        u0: Control ``(nu,)``.
        eps: Finite-difference step.

    Returns:
        ``(A_z (2nv+na, 2nv+na), B_z (2nv+na, nu))``.

    Raises:
        ValueError: the model does not meet the conditions above.
    """
    m = engine.model
    nv, nu, na = m.nv, m.nu, m.na
    if z0 is not None and m.nq != nv:
        raise InvalidArgument(f"crosscheck needs nq == nv when z0 is given; the model has nq={m.nq}, nv={nv}")
    if engine.integrator != "mjINT_EULER" or not engine.explicit_damping:
        raise InvalidArgument(
            "crosscheck needs the Euler integrator with mjDSBL_EULERDAMP "
            '(as MujocoEngine.for_plant(plant, model="matched") sets); '
            f"the model uses {engine.integrator} with explicit damping {engine.explicit_damping}"
        )
    if z0 is not None:
        engine.set_state_vector(z0)
    engine.set_ctrl(u0)
    A_d, B_d = engine.transition_jacobians(eps)
    h = float(m.opt.timestep)
    n = 2 * nv + na
    A = np.zeros((n, n))
    A[:nv, nv : 2 * nv] = np.eye(nv)
    A[nv : 2 * nv] = A_d[nv : 2 * nv] / h
    A[nv : 2 * nv, nv : 2 * nv] -= np.eye(nv) / h
    # a free or ball joint's rotation rows (the tangent space, mjd_transitionFD's coordinates): the rotation
    # vector's rate is ω + ½ δθ × ω, so its row block is −½ [ω]× on the rotation columns (0 at rest)
    for j in range(m.njnt):
        kind = int(m.jnt_type[j])  # mjtJoint: 0 free, 1 ball (only the engine package imports mujoco)
        if kind in (0, 1):
            r = int(m.jnt_dofadr[j]) + (3 if kind == 0 else 0)
            wx, wy, wz = (float(v) for v in engine.data.qvel[r : r + 3])
            A[r : r + 3, r : r + 3] = -0.5 * np.array([[0.0, -wz, wy], [wz, 0.0, -wx], [-wy, wx, 0.0]])
    B = np.zeros((n, nu))
    B[nv : 2 * nv] = B_d[nv : 2 * nv] / h
    if na:
        h_a = _activation_steps(m, h)[:, None]
        A[2 * nv :] = (A_d[2 * nv :] - np.eye(n)[2 * nv :]) / h_a
        B[2 * nv :] = B_d[2 * nv :] / h_a
    return A, B


def _activation_steps(m: Any, h: float) -> np.ndarray:
    """Per activation, ``h_a`` with MuJoCo's Euler ``act⁺ = act + h_a ȧct``."""
    out = np.full(m.na, h)
    filterexact = 3  # mjtDyn.mjDYN_FILTEREXACT (only the engine package imports mujoco)
    for a in range(m.nu):
        if int(m.actuator_dyntype[a]) == filterexact and int(m.actuator_actnum[a]):
            tau = max(float(m.actuator_dynprm[a, 0]), 1e-15)
            out[int(m.actuator_actadr[a])] = tau * -np.expm1(-h / tau)
    return out


def crosscheck(plant: Any, x0: Any = None, u0: Any = None, *, eps: float = 1e-6) -> CrosscheckResult:
    """Compare a plant's exact linearization with finite differences and with MuJoCo.

    Args:
        plant: A plant with a matched MJCF asset and ``engine_state_map()``
            (inverted pendulum, cart-pole, double pendulum).
        x0: Operating state ``(n,)``; default the plant's equilibrium.
        u0: Operating input ``(m,)``; default the plant's equilibrium input.
        eps: Finite-difference step for both the plant and MuJoCo.

    Returns:
        A :class:`CrosscheckResult`; the plant itself is not modified (the
        MuJoCo model is a fresh one, not attached to the plant).

    Raises:
        ValueError: wrong shapes, or a plant without a matched model.
        NonFiniteError: non-finite ``x0`` / ``u0``.
    """
    eps = check_positive("eps", eps)
    xe, ue = plant.equilibrium()
    x0 = as_vector("x0", xe if x0 is None else x0, plant.state_dim).copy()
    u0 = as_vector("u0", ue if u0 is None else u0, plant.input_dim).copy()
    T = _comparable_state_map(plant, x0, u0)

    A_e, B_e = plant.linearize(x0, u0, method="exact")  # first call compiles
    t_exact = _median_time(lambda: plant.linearize(x0, u0, method="exact"))
    A_f, B_f = plant.linearize(x0, u0, method="fd", eps=eps)
    t_fd = _median_time(lambda: plant.linearize(x0, u0, method="fd", eps=eps))

    t0 = time.perf_counter()
    engine = MujocoEngine.for_plant(plant, model="matched")  # the exact twin, never the realistic loop
    t_build = time.perf_counter() - t0
    plant.engine_write(engine, x0)  # the plant's own conversion (quaternions, relative hinges)
    T_inv = np.linalg.inv(T)

    def mujoco_jacobians() -> tuple[np.ndarray, np.ndarray]:
        A_z, B_z = mujoco_continuous_jacobians(engine, None, u0, eps=eps)
        return T @ A_z @ T_inv, T @ B_z

    A_m, B_m = mujoco_jacobians()
    t_mj = _median_time(mujoco_jacobians)

    fd_abs, fd_rel = _errors(A_e, B_e, A_f, B_f)
    mj_abs, mj_rel = _errors(A_e, B_e, A_m, B_m)
    return CrosscheckResult(
        plant=repr(plant),
        state_names=tuple(plant.tangent_names),
        input_names=tuple(plant.input_names),
        x0=x0,
        u0=u0,
        A_exact=A_e,
        B_exact=B_e,
        A_fd=A_f,
        B_fd=B_f,
        A_mujoco=A_m,
        B_mujoco=B_m,
        fd_max_abs_error=fd_abs,
        fd_max_rel_error=fd_rel,
        mujoco_max_abs_error=mj_abs,
        mujoco_max_rel_error=mj_rel,
        eps=eps,
        mujoco_timestep=float(engine.model.opt.timestep),
        model=engine.source,
        time_exact_s=t_exact,
        time_fd_s=t_fd,
        time_mujoco_s=t_mj,
        time_build_s=t_build,
    )


def _comparable_state_map(plant: Any, x0: np.ndarray, u0: np.ndarray) -> np.ndarray:
    """``T (n, n)`` of ``plant.engine_state_map`` at ``x0``, refused where it changes along the motion."""
    try:
        T, _ = plant.engine_state_map(x0)
    except NotImplementedError as exc:
        raise InvalidArgument(f"{type(plant).__name__} has no MuJoCo state map to cross-check against") from exc
    # With a state-dependent coordinate map x = g(z), A_x = T A_z T⁻¹ + (dT/dt) T⁻¹: the comparison is
    # exact only where T does not change along the motion (any equilibrium; zero body rates for a free body).
    T_ahead, _ = plant.engine_state_map(x0 + 1e-6 * plant.dynamics(x0, u0))  # T a microsecond later
    if np.abs(T_ahead - T).max() > 1e-12 * max(1.0, np.abs(T).max()):
        raise InvalidArgument(
            f"{type(plant).__name__}: MuJoCo's coordinates differ from the plant's by a map that changes along the "
            "motion at this point, so the linearizations are not comparable; choose an operating point where it "
            "does not (an equilibrium, or zero angular rates)"
        )
    return T


def _errors(A: np.ndarray, B: np.ndarray, A2: np.ndarray, B2: np.ndarray) -> tuple[float, float]:
    exact = np.hstack([A, B])
    diff = np.abs(np.hstack([A2, B2]) - exact)
    return float(diff.max(initial=0.0)), float((diff / np.maximum(1.0, np.abs(exact))).max(initial=0.0))


def _median_time(fn: Callable[[], Any], repeats: int = _REPEATS) -> float:
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return float(np.median(times))


# ------------------------------------------------------------------ formatting
def _fmt(v: float) -> str:
    return "0" if v == 0.0 else f"{v:.5g}"


def _block(M: np.ndarray, width: int) -> list[str]:
    return [" ".join(f"{_fmt(v):>{width}}" for v in row) for row in M]


def _side_by_side(
    title: str,
    row_names: Sequence[str],
    mats: Sequence[np.ndarray],
    headers: Sequence[str],
    exact: np.ndarray,
) -> list[str]:
    width = max(9, *(len(_fmt(v)) for M in mats for v in M.ravel()))
    blocks = [_block(M, width) for M in mats]
    bw = max(len(blocks[0][0]) if blocks[0] else 0, *(len(h) for h in headers))
    nw = max(len(title), *(len(r) for r in row_names))
    sep = "  │  "
    lines = [f"{title:<{nw}}  " + sep.join(f"{h:^{bw}}" for h in headers)]
    for i, name in enumerate(row_names):
        lines.append(f"{name:<{nw}}  " + sep.join(f"{b[i]:>{bw}}" for b in blocks))
    errs = ["(reference)"] + [f"max |Δ| = {np.abs(M - exact).max(initial=0.0):.2e}" for M in mats[1:]]
    lines.append(f"{'':<{nw}}  " + sep.join(f"{e:^{bw}}" for e in errs))
    return lines


def _vec(v: np.ndarray) -> str:
    return "[" + ", ".join(_fmt(float(c)) for c in v) + "]"


def _duration(s: float) -> str:
    return f"{s * 1e6:.1f} µs" if s < 1e-3 else f"{s * 1e3:.2f} ms"


def format_crosscheck(result: CrosscheckResult) -> str:
    """A readable report: A and B side by side (exact | fd | MuJoCo), errors and timings."""
    r = result
    headers = ("exact (CasADi)", "finite differences", "MuJoCo mjd_transitionFD")
    lines = [
        f"Crosscheck of {r.plant}",
        f"  at x0 = {_vec(r.x0)}, u0 = {_vec(r.u0)}; continuous-time Jacobians in the plant's state order",
        f"  MuJoCo model {r.model} (Euler, h = {r.mujoco_timestep:g} s, explicit damping), eps = {r.eps:g}",
        "",
    ]
    lines.append(f"A = ∂ẋ/∂x, columns: {', '.join(r.state_names)}")
    lines += _side_by_side("A", r.state_names, (r.A_exact, r.A_fd, r.A_mujoco), headers, r.A_exact)
    lines += ["", f"B = ∂ẋ/∂u, columns: {', '.join(r.input_names)}"]
    lines += _side_by_side("B", r.state_names, (r.B_exact, r.B_fd, r.B_mujoco), headers, r.B_exact)
    lines += [
        "",
        f"  {'':<20}{'max |Δ| vs exact':>18}{'max relative':>16}{'time per call':>18}",
        f"  {'exact (CasADi)':<20}{'—':>18}{'—':>16}{_duration(r.time_exact_s):>18}",
        f"  {'finite differences':<20}{r.fd_max_abs_error:>18.2e}{r.fd_max_rel_error:>16.2e}"
        f"{_duration(r.time_fd_s):>18}",
        f"  {'MuJoCo':<20}{r.mujoco_max_abs_error:>18.2e}{r.mujoco_max_rel_error:>16.2e}"
        f"{_duration(r.time_mujoco_s):>18}  (+ {_duration(r.time_build_s)} to build the model)",
    ]
    return "\n".join(line.rstrip() for line in lines)
