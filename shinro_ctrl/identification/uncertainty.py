r"""Parameter uncertainty from the Fisher information, and the combinations the data cannot determine.

Near the least-squares estimate the residuals are linear in the unknowns ``w = (θ, s)`` (the physical
parameters ``θ`` and the nuisance initial states ``s`` of the shooting segments):
``e(w) ≈ e(ŵ) + ∂e/∂w (w - ŵ)``. With independent Gaussian sensor noise of variance ``σ_j²`` on
output ``j``, the Fisher information is

.. math::

    \mathcal I = \sum_k \frac{1}{\sigma_{j(k)}^2} \frac{\partial e_k}{\partial w}^{\!\top}
    \frac{\partial e_k}{\partial w},

and its inverse is the Cramér–Rao bound on the covariance of any unbiased estimate. The noise
variances are estimated from the residuals of each output (``σ̂_j² = Σ e_k² / (N_j - dof_j)``, the
degrees of freedom shared out in proportion to the rows). When the fit weighted the outputs with other
variances than the ones found, the sandwich ``A⁻¹ B A⁻¹`` (``A = JᵀWJ``, ``B = JᵀWΣWJ``) is the honest
covariance; it equals ``𝓘⁻¹`` when the weights were right.

The nuisance states are eliminated by the Schur complement of their block, so the parameter
covariance accounts for not knowing them. The identifiability report is the eigen-decomposition of
the parameters' information in *relative* units (each parameter divided by its scale, its prior's
magnitude): an eigenvector ``v`` with ``1/√λ`` above ``max_rel_std`` is a combination of parameters the
data determines to no better than that fraction; :func:`describe_direction` names it.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

__all__ = ["Uncertainty", "describe_direction", "parameter_uncertainty", "weak_directions"]

#: 95 % two-sided quantile of the standard normal distribution.
Z95 = 1.959963984540054


@dataclass(frozen=True)
class Uncertainty:
    """Covariance of the parameter estimates and what it implies.

    Attributes:
        cov: Covariance ``(k, k)`` of the parameters, physical units.
        std: Standard errors ``(k,)``.
        correlation: Correlation matrix ``(k, k)`` (1 on the diagonal; 0 beside a held parameter).
        noise_std: Estimated noise standard deviation per output ``(p,)``.
        info_rel: The parameters' information ``(k, k)`` in relative units (nuisance eliminated).
    """

    cov: np.ndarray
    std: np.ndarray
    correlation: np.ndarray
    noise_std: np.ndarray
    info_rel: np.ndarray

    def interval(self, estimate: np.ndarray) -> np.ndarray:
        """95 % intervals ``(k, 2)``: ``estimate ± 1.96 std``."""
        return np.column_stack([estimate - Z95 * self.std, estimate + Z95 * self.std])


def noise_variances(e: np.ndarray, channel: np.ndarray, channels: int, dof: int) -> np.ndarray:
    """Per-output noise variance ``σ̂_j² = Σ_j e² / (N_j − dof N_j / N)`` from the residuals ``e (R,)``."""
    total = len(e)
    var = np.zeros(channels)
    for j in range(channels):
        ej = e[channel == j]
        n_j = len(ej)
        eff = n_j - dof * n_j / total
        var[j] = float(ej @ ej) / max(eff, 1.0)
    return var


def parameter_uncertainty(
    J: np.ndarray,
    e: np.ndarray,
    weight: np.ndarray,
    channel: np.ndarray,
    channels: int,
    k: int,
    scale: np.ndarray,
    basis: np.ndarray | None = None,
) -> Uncertainty:
    """Covariance of ``k`` parameters from the residual Jacobian at the estimate.

    Args:
        J: Jacobian ``(R, k + s)`` of the raw residuals ``e = y − ŷ`` with respect to the ``k`` physical
            parameters (first columns, physical units) and ``s`` nuisance unknowns.
        e: Raw residuals ``(R,)``.
        weight: Row weights ``(R,)`` the fit used (its cost was ``½ Σ (weight e)²``).
        channel: Output index of each row ``(R,)``; channels: number of outputs.
        k: Number of physical parameters.
        scale: Parameter scales ``(k,)`` (relative units for the identifiability report).
        basis: ``(k, r)`` orthonormal basis, in relative units, of the parameter directions left free
            (the others held at their prior); default all.

    Returns:
        The :class:`Uncertainty`; a held direction has zero variance.
    """
    basis = np.eye(k) if basis is None else basis
    D = np.diag(scale)
    T = D @ basis  # parameters = prior + T a
    Jr = np.hstack([J[:, :k] @ T, J[:, k:]])  # the free unknowns (a, s)
    dof = Jr.shape[1]
    var = noise_variances(e, channel, channels, dof)
    sig2 = var[channel]
    # column equilibration keeps the solves well conditioned (segment states and parameters differ in size)
    cn = np.linalg.norm(Jr, axis=0)
    cn[cn == 0] = 1.0
    Js = Jr / cn
    A = Js.T @ (Js * (weight**2)[:, None])
    B = Js.T @ (Js * (weight**4 * sig2)[:, None])
    Ainv = np.linalg.pinv(A, rcond=1e-13, hermitian=True)
    cov_s = (Ainv @ B @ Ainv) / np.outer(cn, cn)
    r = basis.shape[1]
    cov = T @ cov_s[:r, :r] @ T.T
    cov = 0.5 * (cov + cov.T)
    std = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = cov / np.outer(std, std)
    corr[~np.isfinite(corr)] = 0.0
    np.fill_diagonal(corr, 1.0)
    info_rel = relative_information(J, sig2, k, scale)
    return Uncertainty(cov, std, np.clip(corr, -1.0, 1.0), np.sqrt(var), info_rel)


def relative_information(J: np.ndarray, sig2: np.ndarray, k: int, scale: np.ndarray) -> np.ndarray:
    """The parameters' Fisher information ``(k, k)`` in relative units, the nuisance block eliminated (Schur).

    ``𝓘_pp − 𝓘_pn 𝓘_nn⁺ 𝓘_np`` of the information ``JᵀΣ⁻¹J`` with the parameter columns times their scales
    (the columns equilibrated before the pseudo-inverse).
    """
    Jw = J / np.sqrt(sig2)[:, None]
    Jw[:, :k] *= scale
    cn = np.linalg.norm(Jw, axis=0)
    cn[cn == 0] = 1.0
    info = (Jw.T @ Jw) / np.outer(cn, cn)
    S = info[:k, :k]
    if info.shape[0] > k:
        S = S - info[:k, k:] @ np.linalg.pinv(info[k:, k:], rcond=1e-12, hermitian=True) @ info[k:, :k]
    return S * np.outer(cn[:k], cn[:k])


def weak_directions(info_rel: np.ndarray, max_rel_std: float) -> tuple[np.ndarray, np.ndarray]:
    """``(directions (k, q), rel_std (q,))``: eigenvectors whose relative standard error exceeds ``max_rel_std``.

    An eigenvalue ``λ`` of the relative information means the combination ``vᵀ(θ/scale)`` is determined to
    ``1/√λ`` (a fraction of the parameters' scales).
    """
    lam, V = np.linalg.eigh(0.5 * (info_rel + info_rel.T))
    lam_max = max(float(lam[-1]), 0.0)
    floor = max(lam_max * 1e-12, 1e-300)
    rel_std = 1.0 / np.sqrt(np.maximum(lam, floor))
    weak = rel_std > max_rel_std
    return V[:, weak], rel_std[weak]


def describe_direction(v: np.ndarray, names: Sequence[str], prior: np.ndarray, scale: np.ndarray) -> str:
    """One sentence naming what a direction ``v`` (relative units) the data cannot determine means.

    One dominant parameter: "the data does not see X". Two: the combination kept is read off the
    direction in physical units ``d = scale·v`` — ``d_a ≈ −d_b``: "enter only as their sum";
    ``d_a/a ≈ −d_b/b`` (relative): "only as their product"; ``d_a ≈ d_b``: "only as their difference";
    otherwise the linear combination orthogonal to ``d``. More: the parameters involved are listed.
    """
    w = v / np.max(np.abs(v))
    big = [i for i in np.argsort(-np.abs(w)) if abs(w[i]) > 0.25]
    if len(big) == 1:
        return f"the data does not see {names[big[0]]} in this experiment"
    if len(big) == 2:
        a, b = big
        d = scale * v
        na, nb = names[a], names[b]
        if abs(d[a] + d[b]) < 0.15 * max(abs(d[a]), abs(d[b])):
            return f"{na} and {nb} enter only as their sum in this experiment"
        if abs(d[a] - d[b]) < 0.15 * max(abs(d[a]), abs(d[b])):
            return f"{na} and {nb} enter only as their difference in this experiment"
        if prior[a] != 0 and prior[b] != 0 and d[a] != 0 and d[b] != 0:
            # a·b^q is constant along d  <=>  d_a/a + q d_b/b = 0
            q = -(d[a] / prior[a]) / (d[b] / prior[b])
            if abs(q) < 1:
                na, nb, q = nb, na, 1.0 / q
            for power, sup in ((1, ""), (2, "²"), (3, "³")):
                if abs(abs(q) - power) < 0.15 * power:
                    op, what = ("·", "product") if q > 0 else ("/", "ratio")
                    return f"{na} and {nb} enter only as their {what} {na}{op}{nb}{sup} in this experiment"
        ca, cb = d[b], -d[a]
        return f"{na} and {nb} enter only as the combination {ca:.3g}·{na} {cb:+.3g}·{nb} in this experiment"
    shown = ", ".join(names[i] for i in big[:-1]) + f" and {names[big[-1]]}"
    return f"the data cannot separate {shown}: one combination of them is undetermined in this experiment"
