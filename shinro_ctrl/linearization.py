"""Exact and finite-difference linearization, and discretization.

For continuous dynamics ``xdot = f(x, u)`` the linearization at an operating
point ``(x0, u0)`` is

    A_c = ∂f/∂x (x0, u0)    (n, n)
    B_c = ∂f/∂u (x0, u0)    (n, m)

*Exact* Jacobians come from ``casadi.jacobian`` of the plant's symbolic
expression. They are compiled once per plant into a ``casadi.Function`` and
evaluated through its buffer interface, which writes straight into
preallocated numpy arrays (about 0.5 µs, against 50–90 µs for an ordinary
CasADi call). *Finite differences* (central, step ``eps``) of the numeric
dynamics are the independent cross-check.

Discretizations at step ``dt``:

* ``euler``: ``A = I + dt A_c``, ``B = dt B_c``.
* ``zoh``:   ``expm([[A_c, B_c], [0, 0]] dt) = [[A, B], [0, I]]`` (exact for LTI).
* ``rk4``:   one classical RK4 step of the linear system,
  ``A = Σ_{k=0..4} (dt A_c)^k / k!``, ``B = Σ_{k=1..4} dt^k A_c^{k-1} / k! · B_c``.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import casadi as cs
import numpy as np
import scipy.linalg

from shinro_ctrl.errors import InvalidArgument

__all__ = [
    "DISCRETIZATIONS",
    "MODEL_DISCRETIZATIONS",
    "ExactJacobian",
    "LinearModel",
    "LinearizationComparison",
    "compare",
    "complex_step_jacobians",
    "discretize",
    "fd_jacobians",
]

DISCRETIZATIONS = ("euler", "zoh", "rk4")
#: Every discrete model a plant builds: the discretizations of its continuous Jacobians, and ``"step"``,
#: the exact Jacobians of the discrete step its standalone loop takes (``Plant.step_jacobians``).
MODEL_DISCRETIZATIONS = (*DISCRETIZATIONS, "step")


@dataclass(frozen=True)
class LinearModel:
    """A discrete linear model with the context it came from.

    ``x[k+1] - x0 ≈ A (x[k] - x0) + B (u[k] - u0)``.

    Attributes:
        A: State matrix ``(n, n)`` (discrete).
        B: Input matrix ``(n, m)`` (discrete).
        dt: Sampling time [s].
        x0: Operating-point state ``(n,)``.
        u0: Operating-point input ``(m,)``.
        A_c: Continuous state matrix ``(n, n)``.
        B_c: Continuous input matrix ``(n, m)``.
        method: ``"exact"`` or ``"fd"``.
        discretization: ``"euler"``, ``"zoh"``, ``"rk4"`` (of ``A_c, B_c``) or ``"step"`` (the exact
            Jacobians of the plant's standalone step).
        state_names, input_names: The plant's names (None when unknown).
    """

    A: np.ndarray
    B: np.ndarray
    dt: float
    x0: np.ndarray
    u0: np.ndarray
    A_c: np.ndarray
    B_c: np.ndarray
    method: str
    discretization: str
    state_names: tuple[str, ...] | None = None
    input_names: tuple[str, ...] | None = None

    def describe(self) -> str:
        """One line naming the model: which discretization of which linearization, and ``dt``."""
        if self.discretization == "step":
            how = "discretization 'step' (the exact Jacobians of the plant's own standalone step"
            how += ")" if self.method == "exact" else f", by {self.method})"
        else:
            how = f"{self.discretization} discretization of the {self.method} linearization"
        return f"{how}, dt = {self.dt:g} s"

    def to_statespace(
        self,
        *,
        discrete: bool = True,
        C: np.ndarray | None = None,
        state_names: Any = None,
        input_names: Any = None,
        output_names: Any = None,
    ) -> Any:
        """This model as a python-control ``StateSpace`` (deviation variables ``x − x0``, ``u − u0``).

        Args:
            discrete: ``(A, B)`` with ``dt`` (True) or the continuous ``(A_c, B_c)``.
            C: Output matrix ``(p, n)``; default the identity (every state measured).
            state_names: ``(n,)`` names (default the model's, else ``x[i]``); input_names ``(m,)``
                (default the model's, else ``u[i]``); output_names ``(p,)`` (default: the state
                names when ``C`` is the identity, else ``y[i]``).

        Returns:
            ``control.StateSpace`` with ``D = 0`` and the names as its labels.
        """
        import control  # deferred: importing python-control costs about a second

        n, m = self.B.shape
        Cm = np.eye(n) if C is None else np.atleast_2d(np.asarray(C, dtype=float))
        if Cm.ndim != 2 or Cm.shape[1] != n:
            raise InvalidArgument(f"C: expected (p, {n}) but found {Cm.shape}")
        state_names = self.state_names if state_names is None else state_names
        input_names = self.input_names if input_names is None else input_names
        states = [f"x[{i}]" for i in range(n)] if state_names is None else [str(s) for s in state_names]
        inputs = [f"u[{i}]" for i in range(m)] if input_names is None else [str(s) for s in input_names]
        if output_names is None:
            outputs = states if C is None else [f"y[{i}]" for i in range(Cm.shape[0])]
        else:
            outputs = [str(s) for s in output_names]
        for what, names, size in (("state", states, n), ("input", inputs, m), ("output", outputs, Cm.shape[0])):
            if len(names) != size:
                raise InvalidArgument(f"{what}_names: expected {size} names but found {len(names)}")
        A, B, dt = (self.A, self.B, self.dt) if discrete else (self.A_c, self.B_c, 0)
        return control.ss(A, B, Cm, np.zeros((Cm.shape[0], m)), dt, states=states, inputs=inputs, outputs=outputs)


def discretize(A_c: np.ndarray, B_c: np.ndarray, dt: float, method: str = "euler") -> tuple[np.ndarray, np.ndarray]:
    """Discretize ``(A_c, B_c)`` at step ``dt`` with ``euler``, ``zoh`` or ``rk4``.

    Args:
        A_c: Continuous state matrix ``(n, n)``.
        B_c: Continuous input matrix ``(n, m)``.
        dt: Sampling time [s], positive.
        method: One of :data:`DISCRETIZATIONS`.

    Returns:
        ``(A, B)``, discrete matrices of shapes ``(n, n)`` and ``(n, m)``.
    """
    n, m = B_c.shape
    if method == "euler":
        return np.eye(n) + dt * A_c, dt * B_c
    if method == "zoh":
        aug = np.zeros((n + m, n + m))
        aug[:n, :n] = A_c
        aug[:n, n:] = B_c
        E = scipy.linalg.expm(aug * dt)
        return E[:n, :n].copy(), E[:n, n:].copy()
    if method == "rk4":
        A = np.eye(n)
        Bsum = np.zeros((n, n))
        term = np.eye(n)  # (dt A_c)^k / k!
        for k in range(1, 5):
            Bsum += term * (dt / k)  # dt^k A_c^{k-1} / k!
            term = term @ (dt * A_c) / k
            A = A + term
        return A, Bsum @ B_c
    raise InvalidArgument(f"unknown discretization {method!r}; valid: {', '.join(DISCRETIZATIONS)}")


def fd_jacobians(
    f: Callable[[np.ndarray, np.ndarray], np.ndarray], x0: np.ndarray, u0: np.ndarray, eps: float = 1e-6
) -> tuple[np.ndarray, np.ndarray]:
    """Central finite-difference Jacobians of a batch-aware ``f(x, u)``.

    All ``2 (n + m)`` perturbed points are evaluated in one batched call, so
    the cost is one numpy evaluation over ``2 (n + m)`` instances.

    Args:
        f: Dynamics accepting ``x`` of shape ``(N, n)`` and ``u`` of ``(N, m)``.
        x0: State ``(n,)``.
        u0: Input ``(m,)``.
        eps: Perturbation step (absolute).

    Returns:
        ``(A_c, B_c)`` of shapes ``(n, n)`` and ``(n, m)``; error O(eps²) plus
        rounding O(1e-16 / eps).
    """
    n, m = x0.shape[0], u0.shape[0]
    k = n + m
    z0 = np.concatenate([x0, u0])
    Z = np.repeat(z0[None, :], 2 * k, axis=0)
    idx = np.arange(k)
    Z[idx, idx] += eps
    Z[k + idx, idx] -= eps
    F = f(Z[:, :n], Z[:, n:])
    J = ((F[:k] - F[k:]) / (2.0 * eps)).T
    return J[:, :n].copy(), J[:, n:].copy()


def complex_step_jacobians(plant, x0: np.ndarray, u0: np.ndarray, h: float = 1e-30) -> tuple[np.ndarray, np.ndarray]:
    """Jacobians by complex-step differentiation: ``∂f/∂z_i = Im f(z + i h e_i) / h``.

    No subtraction, hence no cancellation: for dynamics built from analytic
    operations (sin, cos, products, quotients) the result is exact to
    rounding for any tiny ``h``. It is an independent reference for the exact
    (CasADi) Jacobians, computed from the plant's numeric dynamics with
    complex arrays through :class:`~shinro_ctrl.backend.NumpyBackend`.

    Args:
        plant: A plant (its ``_f`` evaluated with complex states and inputs).
        x0: State ``(n,)``.
        u0: Input ``(m,)``.
        h: Imaginary step.

    Returns:
        ``(A_c (n, n), B_c (n, m))``.
    """
    from shinro_ctrl.backend import NumpyBackend

    n, m = x0.shape[0], u0.shape[0]
    k = n + m
    Z = np.repeat(np.concatenate([x0, u0]).astype(complex)[None, :], k, axis=0)
    Z[np.arange(k), np.arange(k)] += 1j * h
    F = np.asarray(plant.equations(NumpyBackend(), Z[:, :n], Z[:, n:], plant.dynamics_params()))
    J = (F.imag / h).T
    return J[:, :n].copy(), J[:, n:].copy()


class ExactJacobian:
    """Exact Jacobians of a symbolic ``f(x, u, p)``, compiled once, evaluated fast.

    Args:
        f: ``casadi.Function`` with inputs ``(x, u, p)`` and output ``xdot``.
        p: Parameter values ``(n_p,)`` bound at construction (see :meth:`set_params`).

    Calling the instance with ``(x0, u0)`` returns fresh ``(A_c, B_c)`` arrays.
    The CasADi buffer is bound to arrays this object owns, so the evaluation
    itself allocates nothing. Threads: a lock serializes the buffer's use (its cost,
    about 0.1 µs, is a few percent of the call), so concurrent calls are correct.
    CasADi writes column-major nonzeros; the function returns the *transposed* Jacobians, whose column-major layout is
    the row-major layout of ``A_c`` and ``B_c``, so reading back is a plain copy.
    """

    def __init__(self, f: cs.Function, p: np.ndarray):
        x = cs.SX.sym("x", f.size1_in(0))
        u = cs.SX.sym("u", f.size1_in(1))
        ps = cs.SX.sym("p", f.size1_in(2))
        xdot = f(x, u, ps)
        jac = cs.Function(
            "jac_f",
            [x, u, ps],
            [cs.densify(cs.jacobian(xdot, x)).T, cs.densify(cs.jacobian(xdot, u)).T],
            ["x", "u", "p"],
            ["A_T", "B_T"],
        )
        self.function = jac
        self.n, self.m = x.shape[0], u.shape[0]
        self._x = np.zeros(self.n)
        self._u = np.zeros(self.m)
        self._p = np.zeros(ps.shape[0])
        self._A = np.zeros((self.n, self.n))
        self._B = np.zeros((self.n, self.m))
        self._lock = threading.Lock()
        self._buf, self._eval = jac.buffer()
        self._buf.set_arg(0, memoryview(self._x))
        self._buf.set_arg(1, memoryview(self._u))
        self._buf.set_arg(2, memoryview(self._p))
        self._buf.set_res(0, memoryview(self._A.reshape(-1)))
        self._buf.set_res(1, memoryview(self._B.reshape(-1)))
        self._lock = threading.Lock()
        self.set_params(p)

    def set_params(self, p: np.ndarray) -> None:
        """Bind new parameter values ``(n_p,)``."""
        with self._lock:
            self._p[:] = p

    def __call__(self, x0: np.ndarray, u0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        with self._lock:  # one buffer: concurrent callers take turns (an uncontended lock costs ~0.1 us)
            self._x[:] = x0
            self._u[:] = u0
            self._eval()
            return self._A.copy(), self._B.copy()


@dataclass(frozen=True)
class LinearizationComparison:
    """Exact and finite-difference linearizations side by side.

    Attributes:
        A_exact, B_exact: Exact continuous Jacobians.
        A_fd, B_fd: Central finite-difference Jacobians.
        max_abs_error: ``max |exact − fd|`` over A and B.
        max_rel_error: ``max |exact − fd| / max(1, |exact|)`` over A and B.
    """

    A_exact: np.ndarray
    B_exact: np.ndarray
    A_fd: np.ndarray
    B_fd: np.ndarray
    max_abs_error: float
    max_rel_error: float


def compare(plant, x0=None, u0=None, *, eps: float = 1e-6) -> LinearizationComparison:
    """Linearize ``plant`` exactly and by finite differences and compare.

    Args:
        plant: Any :class:`~shinro_ctrl.plants.base.Plant`.
        x0: Operating-point state ``(n,)``; default the plant's equilibrium.
        u0: Operating-point input ``(m,)``; default the plant's equilibrium input.
        eps: Finite-difference step.
    """
    Ae, Be = plant.linearize(x0, u0, method="exact")
    Af, Bf = plant.linearize(x0, u0, method="fd", eps=eps)
    exact = np.hstack([Ae, Be])
    diff = np.abs(exact - np.hstack([Af, Bf]))
    return LinearizationComparison(
        Ae,
        Be,
        Af,
        Bf,
        float(diff.max(initial=0.0)),
        float((diff / np.maximum(1.0, np.abs(exact))).max(initial=0.0)),
    )
