"""Linear-quadratic regulator on a linearized plant, and the Riccati solve it shares with the MPC."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
import scipy.linalg

from shinro_ctrl.controllers.base import Controller
from shinro_ctrl.controllers.lqi import integral_action
from shinro_ctrl.errors import InvalidArgument, NotStabilizable
from shinro_ctrl.validation import as_vector, bound_pair, state_space, weight_matrix

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


def check_stabilizable(A: np.ndarray, B: np.ndarray, *, discrete: bool, names: Any = None) -> None:
    """Raise :class:`NotStabilizable` if an unstable mode of ``A`` is unreachable from ``B``.

    PBH test: ``(A, B)`` is stabilizable iff ``rank [A − λI, B] = n`` for every
    eigenvalue ``λ`` with ``|λ| ≥ 1`` (discrete) or ``Re λ ≥ 0`` (continuous).
    The rank is judged by the smallest singular value relative to ``‖[A, B]‖``.

    Args:
        A: ``(n, n)``.
        B: ``(n, m)``.
        discrete: Stability region of the unit circle (True) or left half-plane.
        names: Optional state names, used to describe the offending mode.
    """
    n = A.shape[0]
    scale = max(1.0, float(np.linalg.norm(np.hstack([A, B]), 2)))
    eigvals, eigvecs = np.linalg.eig(A)
    for k, lam in enumerate(eigvals):
        unstable = abs(lam) >= 1.0 - 1e-12 if discrete else lam.real >= -1e-12
        if not unstable:
            continue
        pbh = np.hstack([A - lam * np.eye(n), B.astype(complex)])
        smin = np.linalg.svd(pbh, compute_uv=False)[-1]
        if smin <= 1e-9 * scale:
            v = eigvecs[:, k]
            i = int(np.argmax(np.abs(v)))
            where = f" (mostly state '{names[i]}')" if names is not None else f" (mostly state {i})"
            region = "|λ| ≥ 1" if discrete else "Re λ ≥ 0"
            raise NotStabilizable(
                f"(A, B) is not stabilizable: the mode λ = {lam:.6g}{where} has {region} "
                f"and the input cannot reach it (PBH rank test, σ_min = {smin:.2e})"
            )


def check_detectable(A: np.ndarray, Q: np.ndarray, *, discrete: bool, names: Any = None) -> None:
    """Raise :class:`NotStabilizable` if an unstable or marginal mode of ``A`` is invisible to ``Q``.

    PBH test on ``(A, Q^½)``: detectable iff ``rank [A − λI; Q^½] = n`` for
    every eigenvalue with ``|λ| ≥ 1`` (discrete) or ``Re λ ≥ 0`` (continuous).
    A mode ``Q`` does not weight costs nothing, so the Riccati solution leaves
    it where it is (on the unit circle for an integrator): the loop would
    never settle.

    Args:
        A: ``(n, n)``.
        Q: Symmetric PSD ``(n, n)``.
        discrete: Stability region of the unit circle (True) or left half-plane.
        names: Optional state names, used to describe the offending mode.
    """
    n = A.shape[0]
    w, V = np.linalg.eigh(0.5 * (Q + Q.T))
    C = (V * np.sqrt(np.clip(w, 0.0, None))) @ V.T  # Q^½
    scale = max(1.0, float(np.linalg.norm(np.vstack([A, C]), 2)))
    eigvals, eigvecs = np.linalg.eig(A)
    for k, lam in enumerate(eigvals):
        unstable = abs(lam) >= 1.0 - 1e-12 if discrete else lam.real >= -1e-12
        if not unstable:
            continue
        smin = np.linalg.svd(np.vstack([A - lam * np.eye(n), C.astype(complex)]), compute_uv=False)[-1]
        if smin <= 1e-9 * scale:
            raise NotStabilizable(
                f"(A, Q^½) is not detectable: the mode λ = {lam:.6g}{_mode_where(eigvecs[:, k], names)} has "
                f"{'|λ| ≥ 1' if discrete else 'Re λ ≥ 0'} and Q does not weight it, so the design would leave it "
                f"unstable or on the stability boundary (PBH rank test, σ_min = {smin:.2e}); weight that state in Q"
            )


def check_closed_loop(poles: np.ndarray, A_cl: np.ndarray, *, discrete: bool, names: Any = None) -> None:
    """Raise :class:`NotStabilizable` unless every closed-loop pole is strictly stable (margin 1e-9)."""
    eigvals, eigvecs = np.linalg.eig(A_cl)
    for k, lam in enumerate(eigvals):
        bad = abs(lam) >= 1.0 - 1e-9 if discrete else lam.real >= -1e-9
        if bad:
            size = f"|p| = {abs(lam):.9g}" if discrete else f"Re p = {lam.real:.3g}"
            raise NotStabilizable(
                f"the closed loop is not strictly stable: pole p = {lam:.6g} ({size})"
                f"{_mode_where(eigvecs[:, k], names)}; increase the weights of Q on that mode"
            )


def _mode_where(v: np.ndarray, names: Any) -> str:
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
    """

    stateful = False  # a pure state feedback

    def __init__(
        self,
        A: Any,
        B: Any,
        Q: Any,
        R: Any,
        *,
        discrete: bool = True,
        x0: Any = None,
        u0: Any = None,
        u_min: Any = None,
        u_max: Any = None,
        feedforward: bool = False,
        state_names: Any = None,
        integral: Any = None,
        integral_dt: float = 1.0,
    ):
        A, B = state_space(A, B)
        n, m = B.shape
        self.A, self.B = A, B
        # LQI (controllers/lqi.py): the design runs on the model augmented with the error integrators.
        self._lqi, design_names = integral_action(A, B, integral, integral_dt, state_names, discrete=bool(discrete))
        A_d, B_d = (A, B) if self._lqi is None else (self._lqi.A_aug, self._lqi.B_aug)
        self.Q = weight_matrix("Q", Q, A_d.shape[0])
        self.R = weight_matrix("R", R, m, definite=True)
        self.discrete = bool(discrete)
        self.x0 = np.zeros(n) if x0 is None else as_vector("x0", x0, n)
        self.u0 = np.zeros(m) if u0 is None else as_vector("u0", u0, m)
        self.u_min, self.u_max = bound_pair("u_min", "u_max", u_min, u_max, m)
        self._saturate = bool(np.any(np.isfinite(self.u_min)) or np.any(np.isfinite(self.u_max)))
        check_stabilizable(A_d, B_d, discrete=self.discrete, names=design_names)
        check_detectable(A_d, self.Q, discrete=self.discrete, names=design_names)
        K, S = riccati(A_d, B_d, self.Q, self.R, discrete=self.discrete)
        self.poles = np.linalg.eigvals(A_d - B_d @ K)
        check_closed_loop(self.poles, A_d - B_d @ K, discrete=self.discrete, names=design_names)
        if self._lqi is not None:
            self.K_i = K[:, n:]  # integrator gain (m, q)
            self._lqi.set_gain(self.K_i)
            self.stateful = True
            K = K[:, :n]
        self.K = K
        self.S = S
        self.state_dim, self.input_dim = n, m
        self._x0_u = self.u0 + self.K @ self.x0  # u = (u0 + K x0) - K x
        self.feedforward = bool(feedforward)
        self.preview = 1 if self.feedforward else 0  # future reference samples the controller wants
        self._B_pinv = np.linalg.pinv(B) if self.feedforward else None

    @classmethod
    def from_plant(
        cls,
        plant: Any,
        Q: Any,
        R: Any,
        *,
        x0: Any = None,
        u0: Any = None,
        discrete: bool = True,
        discretization: str = "step",
        method: str = "exact",
        u_min: Any = None,
        u_max: Any = None,
        feedforward: bool = False,
        integral: Sequence[str] | None = None,
    ) -> LQR:
        """Design on ``plant`` linearized at ``(x0, u0)`` (default its equilibrium).

        Args:
            plant: Any plant.
            Q, R: Weights (full matrices or diagonals).
            x0, u0: Operating point; defaults to ``plant.equilibrium()``.
            discrete: Use the discrete model at ``plant.dt`` (default) or the
                continuous Jacobians.
            discretization: ``step`` (default: the exact linearization of the
                plant's own discrete step), ``euler``, ``zoh`` or ``rk4``.
            method: Linearization method, ``exact`` or ``fd``.
            u_min, u_max: Optional saturation bounds.
            feedforward: Use reference feed-forward (see the class docstring).
            integral: State names whose tracking error is integrated (LQI;
                ``Q`` then has ``n + q`` entries; see ``controllers/lqi.py``).
        """
        lm = plant.linear_model(x0, u0, method=method, discretization=discretization)
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
            state_names=plant.state_names,
            integral=integral,
            integral_dt=plant.dt,
        )
        ctrl.model = lm
        return ctrl

    def __call__(self, x: Any, ref: Any = None) -> np.ndarray:
        """``u = u0 − K (x − x_ref)``, saturated to ``[u_min, u_max]``.

        Args:
            x: State ``(n,)``.
            ref: Optional reference: a state ``(n,)``, or samples ``(k, n)``
                starting at the current time (row 0 is used; with
                ``feedforward`` row 1 gives the feed-forward input).
                Default: the operating point.
        """
        x = as_vector("x", x, self.state_dim)  # fast path for a finite (n,) array
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
        if self._lqi is not None:  # LQI: − K_i z, saturation, clamped integration
            return self._lqi.finish(u, x, r, self.u_min if self._saturate else None, self.u_max)
        if self._saturate:
            np.clip(u, self.u_min, self.u_max, out=u)
        return u

    def cost_to_go(self, x: Any) -> float:
        """Predicted optimal cost ``½ (x − x0)ᵀ S (x − x0)`` from state ``x (n,)``."""
        d = as_vector("x", x, self.state_dim) - self.x0
        if self._lqi is not None:  # the augmented state [x̃; z]
            d = np.concatenate([d, self._lqi.z])
        return 0.5 * float(d @ self.S @ d)

    def reset(self) -> None:
        """Empty the integrators (LQI); a plain LQR has no memory."""
        if self._lqi is not None:
            self._lqi.reset()
