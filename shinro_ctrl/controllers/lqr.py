"""Linear-quadratic regulator on a linearized plant, and the Riccati solve it shares with the MPC."""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING

import numpy as np
import scipy.linalg

from shinro_ctrl.analysis.structure import check_detectable, check_stabilizable
from shinro_ctrl.controllers.base import CallGuard, Controller, check_operating_point, default_input_bounds
from shinro_ctrl.controllers.lqi import integral_action
from shinro_ctrl.errors import InvalidArgument, NonFiniteError, NotStabilizable
from shinro_ctrl.types import Bound, Matrix, Vector, Weight
from shinro_ctrl.validation import as_vector, bound_pair, state_space, weight_matrix

if TYPE_CHECKING:
    from shinro_ctrl.controllers.lqi import IntegralAction
    from shinro_ctrl.plants.base import Plant

__all__ = ["LQR", "check_closed_loop", "check_detectable", "check_stabilizable", "riccati", "riccati_solution"]


def riccati_solution(
    A: np.ndarray, B: np.ndarray, Q: np.ndarray, R: np.ndarray, *, discrete: bool = True, what: str = "the LQR design"
) -> np.ndarray:
    """The stabilizing Riccati solution ``S`` alone (see :func:`riccati`; a terminal cost needs no gain).

    Args:
        A, B, Q, R, discrete, what: As for :func:`riccati`.

    Returns:
        ``S`` ``(n, n)``, symmetrized.

    Raises:
        NotStabilizable: no finite stabilizing solution.
    """
    name = "DARE" if discrete else "CARE"
    try:
        if discrete:
            S = scipy.linalg.solve_discrete_are(A, B, Q, R)
        else:
            S = scipy.linalg.solve_continuous_are(A, B, Q, R)
    except (np.linalg.LinAlgError, ValueError) as exc:
        raise NotStabilizable(
            f"no stabilizing {name} solution for {what} ({exc}); (A, B) must be stabilizable and (A, Q) "
            "detectable: check that every unstable mode is observable through Q"
        ) from exc
    if not np.all(np.isfinite(S)):
        raise NotStabilizable(f"the {name} solution for {what} is not finite")
    return 0.5 * (S + S.T)


def riccati(
    A: np.ndarray, B: np.ndarray, Q: np.ndarray, R: np.ndarray, *, discrete: bool = True, what: str = "the LQR design"
) -> tuple[np.ndarray, np.ndarray]:
    r"""The stabilizing Riccati solution and its gain: the one Riccati path (LQR and the MPC terminal cost).

    Discrete: ``S = Aᵀ S A − Aᵀ S B (R + Bᵀ S B)⁻¹ Bᵀ S A + Q`` and
    ``K = (R + Bᵀ S B)⁻¹ Bᵀ S A``. Continuous: ``Aᵀ S + S A − S B R⁻¹ Bᵀ S + Q = 0``
    and ``K = R⁻¹ Bᵀ S``. Solved by SciPy's Schur method (what python-control's
    ``dlqr``/``lqr`` call without slycot).

    Args:
        A: ``(n, n)``.
        B: ``(n, m)``.
        Q: Symmetric PSD ``(n, n)``.
        R: Symmetric PD ``(m, m)``.
        discrete: DARE (True) or CARE.
        what: What the solution is for, in the error message.

    Returns:
        ``(K (m, n), S (n, n))`` with ``S`` symmetrized.

    Raises:
        NotStabilizable: no finite stabilizing solution.
    """
    S = riccati_solution(A, B, Q, R, discrete=discrete, what=what)
    if discrete:
        BtS = B.T @ S
        K = np.linalg.solve(R + BtS @ B, BtS @ A)
    else:
        K = np.linalg.solve(R, B.T @ S)
    return K, S


def check_closed_loop(
    poles: np.ndarray, A_cl: np.ndarray, *, discrete: bool, names: Sequence[str] | None = None
) -> None:
    """Raise :class:`NotStabilizable` unless every closed-loop pole is strictly stable beyond rounding.

    The margin is relative, ``10³ eps max(1, ‖A_cl‖)``: a mode the design leaves on the stability
    boundary (an unweighted integrator stays at ``z = 1`` to rounding) is refused, while a fast
    sampled loop whose poles sit at ``1 − dt·σ`` (``dt = 1e-9``) is not.
    """
    eigvals, eigvecs = np.linalg.eig(A_cl)
    margin = 1e3 * float(np.finfo(float).eps) * max(1.0, float(np.linalg.norm(A_cl, 2)))
    for k, lam in enumerate(eigvals):
        bad = abs(lam) >= 1.0 - margin if discrete else lam.real >= -margin
        if bad:
            size = f"|p| = {abs(lam):.9g}" if discrete else f"Re p = {lam.real:.3g}"
            raise NotStabilizable(
                f"the closed loop is not strictly stable: pole p = {lam:.6g} ({size})"
                f"{_mode_where(eigvecs[:, k], names)}; increase the weights of Q on that mode"
            )


def _design(
    A: np.ndarray, B: np.ndarray, Q: np.ndarray, R: np.ndarray, *, discrete: bool, names: Sequence[str] | None
) -> tuple[np.ndarray, np.ndarray]:
    """``(K, S)`` of a design whose closed loop is strictly stable, judged by the Riccati solution itself.

    When the Riccati solve fails or leaves a pole on or outside the stability boundary, the PBH tests
    (:func:`~shinro_ctrl.analysis.structure.check_stabilizable` and ``check_detectable`` on
    ``(A, Q^½)``) name the mode at fault; a rank test never refuses a design that the Riccati solution
    stabilizes.
    """
    try:
        K, S = riccati(A, B, Q, R, discrete=discrete)
        check_closed_loop(np.linalg.eigvals(A - B @ K), A - B @ K, discrete=discrete, names=names)
    except NotStabilizable:
        check_stabilizable(A, B, discrete=discrete, names=names)
        check_detectable(
            A,
            _sqrt_psd(Q),
            discrete=discrete,
            names=names,
            seen_by="the weights Q",
            pair="(A, Q^½)",
            fix="Q does not weight it, so the design would leave it unstable or on the stability boundary; "
            "weight that state in Q",
        )
        raise
    return K, S


def _design_weight(Q: Weight, size: int, lqi: IntegralAction | None, names: Sequence[str] | None) -> np.ndarray:
    """``Q`` on the design state; with integral action its shape error says the integral states are appended."""
    try:
        return weight_matrix("Q", Q, size)
    except InvalidArgument as exc:
        if lqi is None:
            given = np.shape(Q)
            if len(given) >= 1 and given[0] > size:  # more weights than states: integral weights without integral
                raise InvalidArgument(
                    f"{exc}; Q weights the {size} states only: weights for integral states need 'integral' "
                    "(the states whose error is integrated)"
                ) from None
            raise
        q = len(lqi.indices)
        n = size - q
        listed = f": {', '.join(names)}" if names is not None else ""
        raise InvalidArgument(
            f"{exc}; with integral action Q weights the {n} states and then the {q} integral state"
            f"{'s' if q != 1 else ''} appended after them ({size} entries{listed})"
        ) from None


def _sqrt_psd(Q: np.ndarray) -> np.ndarray:
    """``Q^½`` of a symmetric PSD matrix."""
    w, V = np.linalg.eigh(0.5 * (Q + Q.T))
    return (V * np.sqrt(np.clip(w, 0.0, None))) @ V.T


def _mode_where(v: np.ndarray, names: Sequence[str] | None) -> str:
    i = int(np.argmax(np.abs(v)))
    return f" (mostly state '{names[i]}')" if names is not None and i < len(names) else f" (mostly state {i})"


class LQR(Controller):
    r"""Infinite-horizon LQR ``u = u0 − K (x − x_ref)``.

    Discrete (default): minimizes ``½ Σ_k x̃_kᵀ Q x̃_k + ũ_kᵀ R ũ_k`` subject to
    ``x̃_{k+1} = A x̃_k + B ũ_k``, with ``S`` the DARE solution; the optimal
    cost from ``x̃`` is ``½ x̃ᵀ S x̃``. Continuous (``discrete=False``): the
    same with an integral and the CARE. ``x̃ = x − x_ref`` (``x_ref = x0``
    unless a reference is passed), ``ũ = u − u0``.

    Args:
        A: ``(n, n)`` state matrix.
        B: ``(n, m)`` input matrix.
        Q: ``(n, n)`` symmetric PSD weight, or its diagonal ``(n,)``.
        R: ``(m, m)`` symmetric PD weight, or its diagonal ``(m,)``.
        discrete: Treat ``(A, B)`` as discrete (True) or continuous.
        x0: Operating-point state ``(n,)`` (default zeros).
        u0: Operating-point input ``(m,)`` (default zeros).
        u_min, u_max: Optional saturation bounds ``(m,)`` (±inf allowed).
        feedforward: Track a moving reference with the input that makes the
            design model follow it: given ``ref = [r_k, r_{k+1}]`` ``(2, n)``,
            ``ũ_ff = B⁺ (r̃_{k+1} − A r̃_k)`` and ``u = u0 + ũ_ff − K (x − r_k)``
            (exact when ``B`` has full row rank, e.g. kinematic plants).
        state_names: Optional names used in error messages.
        integral: States (names, or indices) whose tracking error
            ``x[i] − r[i]`` is integrated (LQI, discrete only): ``Q`` then
            weights ``[x̃; z]`` with ``n + q`` entries; the integrators are
            clamped while the input saturates (see ``controllers/lqi.py``).
        integral_dt: Integration step [s] (``from_plant`` passes ``plant.dt``).

    Attributes:
        K: Gain ``(m, n)``.
        K_i: Integrator gain ``(m, q)`` (LQI only).
        S: Riccati solution ``(n, n)``.
        poles: Closed-loop eigenvalues of ``A − B K`` ``(n,)``.

    Raises:
        ValueError: wrong shapes, asymmetric or indefinite weights.
        NotStabilizable: an unstable mode the input cannot reach (PBH test).

    Threads: a plain LQR is a pure state feedback (no buffer is shared between calls): one object
    may be called from any number of threads at once. With integral action (LQI) it keeps the
    integrators between calls: a call that enters while another thread is inside raises
    :class:`~shinro_ctrl.errors.ConcurrentUse` (use one controller per thread).
    """

    stateful = False  # a pure state feedback

    def __init__(
        self,
        A: Matrix,
        B: Matrix,
        Q: Weight,
        R: Weight,
        *,
        discrete: bool = True,
        x0: Vector | None = None,
        u0: Vector | None = None,
        u_min: Bound = None,
        u_max: Bound = None,
        feedforward: bool = False,
        state_names: Sequence[str] | None = None,
        integral: str | int | Sequence[str | int] | None = None,
        integral_dt: float = 1.0,
        difference: Callable[[np.ndarray, np.ndarray], np.ndarray] | None = None,
    ):
        A, B = state_space(A, B)
        n, m = B.shape
        self.A, self.B = A, B
        # LQI (controllers/lqi.py): the design runs on the model augmented with the error integrators.
        self._lqi, design_names = integral_action(A, B, integral, integral_dt, state_names, discrete=bool(discrete))
        A_d, B_d = (A, B) if self._lqi is None else (self._lqi.A_aug, self._lqi.B_aug)
        self.Q = _design_weight(Q, A_d.shape[0], self._lqi, design_names)
        self.R = weight_matrix("R", R, m, definite=True)
        self.discrete = bool(discrete)
        # a floating base: the model acts on the deviation difference(x, x0) (n,), the state x0 is longer
        self._difference = difference
        if difference is not None and x0 is None:
            raise InvalidArgument("LQR: a difference map needs the operating state x0")
        self.x0 = np.zeros(n) if x0 is None else as_vector("x0", x0, n if difference is None else np.size(x0))
        self.u0 = np.zeros(m) if u0 is None else as_vector("u0", u0, m)
        self.u_min, self.u_max = bound_pair("u_min", "u_max", u_min, u_max, m)
        self._saturate = bool(np.any(np.isfinite(self.u_min)) or np.any(np.isfinite(self.u_max)))
        K, S = _design(A_d, B_d, self.Q, self.R, discrete=self.discrete, names=design_names)
        self.poles = np.linalg.eigvals(A_d - B_d @ K)
        if self._lqi is not None:
            self.K_i = K[:, n:]  # integrator gain (m, q)
            self._lqi.set_gain(self.K_i)
            self.stateful = True
            K = K[:, :n]
        self.K = K
        self.S = S
        self.state_dim, self.input_dim = len(self.x0), m
        self._x0_u = self.u0 + self.K @ self.x0 if difference is None else None  # u = (u0 + K x0) - K x
        self._guard = CallGuard("LQR with integral action")
        self.feedforward = bool(feedforward)
        self.preview = 1 if self.feedforward else 0  # future reference samples the controller wants
        self._B_pinv = np.linalg.pinv(B) if self.feedforward else None

    @property
    def integral_action(self) -> IntegralAction | None:
        """The LQI integrators (augmented model, ``K_i``, integrator state), or None for a plain LQR."""
        return self._lqi

    @classmethod
    def from_plant(
        cls,
        plant: Plant,
        Q: Weight,
        R: Weight,
        *,
        x0: Vector | None = None,
        u0: Vector | None = None,
        discrete: bool = True,
        discretization: str = "step",
        method: str = "exact",
        u_min: Bound = None,
        u_max: Bound = None,
        feedforward: bool = False,
        integral: Sequence[str] | None = None,
    ) -> LQR:
        """Design on ``plant`` linearized at ``(x0, u0)`` (default its equilibrium).

        The operating point must be an equilibrium, ``f(x0, u0) = 0`` (the LQR
        does not carry the affine term; see
        :func:`~shinro_ctrl.controllers.base.check_operating_point`).

        Args:
            plant: Any plant.
            Q, R: Weights (full matrices or diagonals).
            x0, u0: Operating point; defaults to ``plant.equilibrium()``.
            discrete: Use the discrete model at ``plant.dt`` (default) or the
                continuous Jacobians.
            discretization: ``step`` (default: the exact linearization of the
                plant's own discrete step), ``euler``, ``zoh`` or ``rk4``.
            method: Linearization method, ``exact`` or ``fd``.
            u_min, u_max: Optional saturation bounds; a side left None takes the plant's
                physical range (``plant.input_bounds()``, e.g. a model file's ``ctrlrange``).
            feedforward: Use reference feed-forward (see the class docstring).
            integral: State names whose tracking error is integrated (LQI;
                ``Q`` then has ``n + q`` entries; see ``controllers/lqi.py``).

        Raises:
            TypeError: ``plant`` is not a plant instance (None, a class).
            InvalidArgument: ``(x0, u0)`` is not an equilibrium (naming the residual and the nearest
                equilibrium input when there is one).
        """
        lm = plant.linear_model(x0, u0, method=method, discretization=discretization)
        check_operating_point(plant, lm.x0, lm.u0, cls.__name__)
        u_min, u_max = default_input_bounds(plant, u_min, u_max)
        A, B = (lm.A, lm.B) if discrete else (lm.A_c, lm.B_c)
        ctrl = cls(
            A,
            B,
            Q,
            R,
            discrete=discrete,
            x0=lm.x0,
            u0=lm.u0,
            u_min=u_min,
            u_max=u_max,
            feedforward=feedforward,
            state_names=plant.tangent_names,
            integral=integral,
            integral_dt=plant.dt,
            difference=plant.difference if plant.tangent_dim != plant.state_dim else None,
        )
        ctrl.model = lm
        return ctrl

    def __call__(self, x: Vector, ref: Vector | Matrix | None = None) -> np.ndarray:
        """``u = u0 − K (x − x_ref)``, saturated to ``[u_min, u_max]``.

        Args:
            x: State ``(n,)``.
            ref: Optional reference: a state ``(n,)``, or samples ``(k, n)``
                starting at the current time (row 0 is used; with
                ``feedforward`` row 1 gives the feed-forward input).
                Default: the operating point.
        """
        if self._lqi is None:
            return self._law(x, ref)
        guard = self._guard  # the integrators: one thread at a time
        if not guard.acquire(False):
            raise guard.refused()
        try:
            return self._law(x, ref)
        finally:
            guard.release()

    def _law(self, x: Vector, ref: Vector | Matrix | None) -> np.ndarray:
        x = as_vector("x", x, self.state_dim)  # fast path for a finite (n,) array
        if self._difference is not None:  # a floating base: the deviations in the tangent space
            return self._law_tangent(x, ref)
        if ref is None:
            u = self._x0_u - self.K @ x
            r = self.x0
        else:
            ref = np.asarray(ref, dtype=float)
            if ref.ndim == 2:
                if ref.shape[1] != self.state_dim or ref.shape[0] < 1:
                    raise InvalidArgument(f"ref: expected (k, {self.state_dim}) but found {ref.shape}")
                r = as_vector("ref", ref[0], self.state_dim)
                u = self.u0 - self.K @ (x - r)
                if self.feedforward and ref.shape[0] > 1:
                    r_next = as_vector("ref", ref[1], self.state_dim)
                    u = u + self._B_pinv @ ((r_next - self.x0) - self.A @ (r - self.x0))
            else:
                r = as_vector("ref", ref, self.state_dim)
                u = self.u0 - self.K @ (x - r)
        # the state (or the reference) is finite but K x may overflow float64: a finite sum (0.2 µs) proves every
        # entry finite; otherwise the entries are checked (a finite sum of huge entries can overflow)
        if not math.isfinite(sum(u.tolist())) and not np.isfinite(u).all():
            raise NonFiniteError(
                f"LQR: the input for the state {np.array2string(x, precision=3)} overflows float64 "
                f"(u = {np.array2string(u, precision=3)}): the state is far outside the linear model's range"
            )
        if self._lqi is not None:  # LQI: − K_i z, saturation, clamped integration
            return self._lqi.finish(u, x, r, self.u_min if self._saturate else None, self.u_max)
        if self._saturate:
            np.clip(u, self.u_min, self.u_max, out=u)
        return u

    def _law_tangent(self, x: np.ndarray, ref: Vector | Matrix | None) -> np.ndarray:
        """:meth:`_law` with every deviation ``x ⊖ r`` from the plant's ``difference`` (a floating base)."""
        dif = self._difference
        r = self.x0 if ref is None else np.asarray(ref, dtype=float)
        rows = r if r.ndim == 2 else r[None, :]
        if rows.shape[1] != self.state_dim or rows.shape[0] < 1:
            raise InvalidArgument(f"ref: expected ({self.state_dim},) or (k, {self.state_dim}) but found {r.shape}")
        r0 = as_vector("ref", rows[0], self.state_dim)
        u = self.u0 - self.K @ dif(x, r0)
        if self.feedforward and rows.shape[0] > 1:
            r1 = as_vector("ref", rows[1], self.state_dim)
            u = u + self._B_pinv @ (dif(r1, self.x0) - self.A @ dif(r0, self.x0))
        if not np.isfinite(u).all():
            raise NonFiniteError(f"LQR: the input for the state {np.array2string(x, precision=3)} overflows float64")
        if self._lqi is not None:
            raise InvalidArgument("LQR: integral action on a floating base is not supported yet")
        if self._saturate:
            np.clip(u, self.u_min, self.u_max, out=u)
        return u

    def cost_to_go(self, x: Vector) -> float:
        """Predicted optimal cost ``½ (x ⊖ x0)ᵀ S (x ⊖ x0)`` from state ``x (n,)``."""
        x = as_vector("x", x, self.state_dim)
        d = x - self.x0 if self._difference is None else self._difference(x, self.x0)
        if self._lqi is not None:  # the augmented state [x̃; z]
            d = np.concatenate([d, self._lqi.z])
        return 0.5 * float(d @ self.S @ d)

    def reset(self) -> None:
        """Empty the integrators (LQI); a plain LQR has no memory."""
        if self._lqi is not None:
            with self._guard:
                self._lqi.reset()
