r"""Actuator transmissions, force law and activation dynamics, exactly as MuJoCo defines them.

Every actuator has a *length* ``l(q)``, a *moment arm* ``r(q) (nq,)`` and a
*velocity* ``l̇ = r·q̇``; its scalar force ``F`` acts on the joints as the
generalized force ``r F``. By transmission:

* **joint** ``j`` with gear ``g``: ``l = g q_j``, ``r = g e_j``.
* **tendon** (fixed: ``L = Σ_k c_k q_{j_k}``) with gear ``g``: ``l = g L``,
  ``r = g c`` (constant), so a tendon actuator pushes every joint of the
  tendon in proportion to its coefficient.
* **site** ``s`` (a thruster): a force along ``g[0:3]`` and a torque about
  ``g[3:6]``, both in the site frame ``R_s``, at the site's origin. The
  generalized force is ``J_sᵀ w`` with the world wrench
  ``w = [R_s g[0:3]; R_s g[3:6]]`` and ``J_s = [J_p; J_ω]`` the site's
  point and angular Jacobians: ``r = J_pᵀ R_s g[0:3] + J_ωᵀ R_s g[3:6]``,
  and ``l = 0``.
* **site with a reference site** ``ref``: the directions are in the
  reference frame ``R_ref``, the translational length is
  ``l = (R_refᵀ (p_s − p_ref))·g[0:3]``, and, as MuJoCo computes it,
  ``r = ΔJ_pᵀ R_ref g[0:3] + ΔJ_ωᵀ R_ref g[3:6]`` with ``ΔJ = J_s(p_s) −
  J_ref(p_ref)`` over the joints that move only one of the two sites (the
  joints that move both drop out). MuJoCo's rotational length (an
  axis-angle of the relative rotation) is not smooth at zero: a rotational
  refsite transmission is accepted only when the force does not depend on
  its length.

The force ``F = gain(l, l̇)·a + bias(l, l̇)`` with ``gain = p₀`` (fixed) or
``p₀ + p₁ l + p₂ l̇`` (affine), ``bias = 0`` (none) or ``b₀ + b₁ l + b₂ l̇``
(affine); the input ``a`` is the control ``u`` for an actuator without
dynamics and its activation otherwise. Activation dynamics
(:meth:`Transmissions.activation_rates`):

* ``filter`` and ``filterexact``: ``ȧ = (u − a)/τ`` (``τ = dynprm[0]``).
  MuJoCo integrates ``filterexact`` exactly in its step
  (``a⁺ = a + (u − a)(1 − e^{−h/τ})``) and ``filter`` by Euler; the
  continuous model is the same ODE for both.
* ``integrator``: ``ȧ = u``.

MuJoCo-loop only (not smooth, never in these equations): the ``ctrlrange``,
``forcerange`` and ``actrange`` clamps.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, TypeAlias

import numpy as np

from shinro_ctrl._scalar_algebra import _add, _const, _dot, _matTvec, _matvec, _mul, _sub

if TYPE_CHECKING:
    from shinro_ctrl.multibody.rigid_body import Scalar
    from shinro_ctrl.multibody.tree import ActuatorInfo, ModelTree, TendonInfo

__all__ = ["SiteFrame", "Transmissions", "tendon_length", "tendon_velocity"]

#: A site's world frame and Jacobians: ``(p (3,), R (3, 3), Jp, Jw)`` with ``Jp``/``Jw`` the columns
#: ``(nq,)`` of the point and angular Jacobians, each a 3-list or None (a structural zero).
SiteFrame: TypeAlias = "tuple[list[Scalar], list[list[Scalar]], list[list[Scalar] | None], list[list[Scalar] | None]]"
#: ``site(s, at=None) -> SiteFrame`` (see :meth:`Transmissions.length_and_moment`).
SiteLookup: TypeAlias = "Callable[..., SiteFrame]"


def tendon_length(tendon: TendonInfo, q: Sequence[Scalar], adr: Sequence[int] | None = None) -> Scalar:
    """``L = Σ_k c_k q_{j_k}`` of a fixed tendon; ``adr``: each joint's index in ``q`` (default the joint index)."""
    return _add(*(_mul(c, q[j if adr is None else adr[j]]) for j, c in zip(tendon.joints, tendon.coefs, strict=True)))


def tendon_velocity(tendon: TendonInfo, qd: Sequence[Scalar], adr: Sequence[int] | None = None) -> Scalar:
    """``L̇ = Σ_k c_k q̇_{j_k}`` of a fixed tendon; ``adr``: each joint's index in ``q̇`` (default the joint index)."""
    return tendon_length(tendon, qd, adr)


class Transmissions:
    """The actuators of a :class:`ModelTree`: moment arms, forces and activation dynamics.

    Args:
        tree: The model description (actuators, tendons, sites).

    Attributes:
        nq: Number of joint velocities (degrees of freedom, ``nv``): moment arms and forces have this length.
        nu: Number of actuators.
        na: Number of activation states.
    """

    def __init__(self, tree: ModelTree):
        self.tree = tree
        self.nq = tree.nv
        self._qadr, self._dadr = tree.qposadr, tree.dofadr
        self.nu = tree.nu
        self.na = tree.na

    # ------------------------------------------------------------ inputs
    def actuator_inputs(self, u: Sequence[Scalar], act: Sequence[Scalar], active: Sequence[int]) -> list[Scalar]:
        """What multiplies each actuator's gain ``(nu,)``: its control (0 when not in ``active``) or activation."""
        ctrl = self.controls(u, active)
        return [act[a.act] if a.act >= 0 else ctrl[k] for k, a in enumerate(self.tree.actuators)]

    def controls(self, u: Sequence[Scalar], active: Sequence[int]) -> list[Scalar]:
        """Every actuator's control ``(nu,)``: ``u`` for the ``active`` ones, 0 for the others."""
        ctrl: list[Scalar] = [0.0] * self.nu
        for k, a in zip(active, u, strict=True):
            ctrl[k] = a
        return ctrl

    def activation_rates(self, u: Sequence[Scalar], act: Sequence[Scalar], active: Sequence[int]) -> list[Scalar]:
        """``ȧ (na,)``: ``(u − a)/τ`` for filter and filterexact, ``u`` for integrator."""
        ctrl = self.controls(u, active)
        rate: list[Scalar] = [0.0] * self.na
        for k, a in enumerate(self.tree.actuators):
            if a.act < 0:
                continue
            if a.dyntype == "integrator":
                rate[a.act] = ctrl[k]
            else:  # filter, filterexact
                rate[a.act] = _mul(1.0 / a.dynprm[0], _sub(ctrl[k], act[a.act]))
        return rate

    # ------------------------------------------------------- transmission
    def length_and_moment(self, a: ActuatorInfo, q: Sequence[Scalar], site: SiteLookup) -> tuple[Scalar, list[Scalar]]:
        """Actuator length ``l`` and moment arm ``r (nq,)`` (see the module docstring).

        ``site(s, at=None)`` gives site ``s``'s :data:`SiteFrame`, with the point Jacobian at the
        world point ``at`` (moving with the site's body) when given.
        """
        n = self.nq
        r: list[Scalar] = [0.0] * n
        g = a.gear6
        if a.transmission == "joint":
            r[self._dadr[a.target]] = g[0]
            return _mul(g[0], q[self._qadr[a.target]]), r
        if a.transmission == "tendon":
            t = self.tree.tendons[a.target]
            for j, c in zip(t.joints, t.coefs, strict=True):
                r[self._dadr[j]] = _add(r[self._dadr[j]], g[0] * c)
            return _mul(g[0], tendon_length(t, q, self._qadr)), r
        # site
        p, R, Jp, Jw = site(a.target)
        length: Scalar = 0.0
        gf, gt = _const(np.asarray(g[:3])), _const(np.asarray(g[3:6]))
        if a.refsite >= 0:
            pr, Rr, Jpr, Jwr = site(a.refsite)
            # as MuJoCo: the difference over the joints that move only one of the two sites
            common = [c1 is not None and c2 is not None for c1, c2 in zip(Jp, Jpr, strict=True)]
            Jp = [None if c else _diff(c1, c2) for c, c1, c2 in zip(common, Jp, Jpr, strict=True)]
            Jw = [None if c else _diff(c1, c2) for c, c1, c2 in zip(common, Jw, Jwr, strict=True)]
            if any(gf):
                rel = _matTvec(Rr, [_sub(p[i], pr[i]) for i in range(3)])
                length = _dot(rel, gf)
            R = Rr
        wf = _matvec(R, gf) if any(gf) else None
        wt = _matvec(R, gt) if any(gt) else None
        for k in range(n):
            terms = []
            if wf is not None and Jp[k] is not None:
                terms.append(_dot(Jp[k], wf))
            if wt is not None and Jw[k] is not None:
                terms.append(_dot(Jw[k], wt))
            r[k] = _add(*terms)
        return length, r

    def generalized_forces(
        self,
        q: Sequence[Scalar],
        qd: Sequence[Scalar],
        inputs: Sequence[Scalar],
        site: SiteLookup,
    ) -> list[Scalar]:
        """``τ_act = Σ_a r_a F_a (nq,)`` for the actuator inputs ``(nu,)`` (:meth:`actuator_inputs`).

        Args:
            q: Joint coordinates ``(nq,)``.
            qd: Joint velocities ``(nq,)``.
            inputs: Each actuator's control or activation ``(nu,)``.
            site: The world frame and Jacobians of a site by index (evaluated only for site
                transmissions; see :meth:`length_and_moment`).
        """
        tau: list[Scalar] = [0.0] * self.nq
        if not self.tree.actuation_enabled:
            return tau
        for a, x in zip(self.tree.actuators, inputs, strict=True):
            length, r = self.length_and_moment(a, q, site)
            vel = _dot(r, qd)
            p0, p1, p2 = (float(c) for c in a.gainprm)
            gain: Scalar = p0 if a.gaintype == "fixed" else _add(p0, _mul(p1, length), _mul(p2, vel))
            b0, b1, b2 = (float(c) for c in a.biasprm)
            bias: Scalar = 0.0 if a.biastype == "none" else _add(b0, _mul(b1, length), _mul(b2, vel))
            force = _add(_mul(gain, x), bias)
            for k in range(self.nq):
                tau[k] = _add(tau[k], _mul(r[k], force))
        return tau


def _diff(a: list[Scalar] | None, b: list[Scalar] | None) -> list[Scalar] | None:
    if b is None:
        return a
    if a is None:
        return [_sub(0.0, c) for c in b]
    return [_sub(x, y) for x, y in zip(a, b, strict=True)]
