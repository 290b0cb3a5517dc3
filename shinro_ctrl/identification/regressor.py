r"""The linear-in-parameters inverse-dynamics regressor of a model file: ``τ = Y(q, q̇, q̈) π + τ₀``.

The recursive Newton–Euler algorithm of :class:`~shinro_ctrl.multibody.RigidBodyTree` is linear in every
body's ten inertial parameters, here in the body's own frame about its origin,

    π_b = [m, h_x, h_y, h_z, I_xx, I_yy, I_zz, I_xy, I_xz, I_yz],   h = m c,   I = I_c + m (cᵀc 1 − c cᵀ),

(``c`` the centre of mass, ``I_c`` the rotational inertia about it), and in each joint's armature ``a``,
viscous damping ``b`` and Coulomb friction loss ``f``. The regressor is built from the very same RNEA: the
chosen bodies' parameters enter the RNEA nodes as CasADi symbols — a body whose frame sits at ``(R, p)`` in
the frame of the node that carries it adds

    m,   m p + R h,   R I Rᵀ + m (pᵀp 1 − p pᵀ) + 2 (pᵀ R h) 1 − p (R h)ᵀ − (R h) pᵀ

to the node's mass, first moment and inertia about the node origin — and ``Y = ∂τ/∂π`` is the exact Jacobian
(the RNEA is linear in π, so ``τ = Y π + τ₀`` holds to round-off, with ``τ₀`` the part of the known bodies).
The equation of motion ``(M + diag a) q̈ + c = τ_act + τ_passive + τ_gc`` then reads

    Y(q, q̇, q̈) π = τ_act(q, q̇, u) + τ_passive,known(q, q̇) + τ_gc(q) − τ₀(q, q̇, q̈) − a_known ⊙ q̈,

where the identified joints' damping ``b q̇`` and friction loss ``f sign(q̇)`` are columns of ``Y``.

Physical consistency of a body is the positive definiteness of its pseudo-inertia

    J(π) = [[½ tr(I) 1 − I, h], [hᵀ, m]] ≻ 0

(a positive mass, a positive-definite ``I_c`` and the triangle inequalities of its principal moments;
Wensing, Kim & Slotine 2017), enforced by the log-Cholesky parametrization ``J = U Uᵀ`` with

    U = e^α [[e^{d₁}, s₁₂, s₁₃, t₁], [0, e^{d₂}, s₂₃, t₂], [0, 0, e^{d₃}, t₃], [0, 0, 0, 1]]

(Rucker & Wensing 2022): every real ``θ = (α, d, s, t)`` gives a consistent body and every consistent body
has one ``θ`` (:func:`theta_from_pi`, :func:`pi_from_theta`).
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import casadi as cs
import numpy as np

from shinro_ctrl._scalar_algebra import quat_to_mat
from shinro_ctrl.multibody.rigid_body import CASADI_OPS

if TYPE_CHECKING:
    from shinro_ctrl.multibody.tree import BodyInfo
    from shinro_ctrl.plants.mjcf import MjcfPlant

__all__ = [
    "BODY_PARAMS",
    "JOINT_PARAMS",
    "InertialRegressor",
    "ParamSpec",
    "parse_param_names",
    "pi_from_theta",
    "pseudo_inertia",
    "theta_from_pi",
]

#: Names of a body's ten linear parameters (inertia about the body origin, body frame).
PI_NAMES = ("m", "hx", "hy", "hz", "Ixx", "Iyy", "Izz", "Ixy", "Ixz", "Iyz")
#: The physical parameters reported per body: mass, centre of mass (body frame), inertia about the COM.
BODY_PARAMS = ("mass", "com_x", "com_y", "com_z", "Ixx", "Iyy", "Izz", "Ixy", "Ixz", "Iyz")
#: The joint parameters that can be identified.
JOINT_PARAMS = ("damping", "armature", "frictionloss")


class ParamError(ValueError):
    """A parameter name that does not name a body or joint parameter of the model (one line)."""


@dataclass(frozen=True)
class ParamSpec:
    """What to identify: whole bodies (by index) and joint parameters ``(joint index, "damping"|...)``."""

    bodies: tuple[int, ...]
    joints: tuple[tuple[int, str], ...]

    def pi_names(self, body_names: Sequence[str], joint_names: Sequence[str]) -> list[str]:
        """Names of the entries of π: ``BODY.m``, ``BODY.hx``, …, then ``JOINT.damping``, …"""
        out = [f"{body_names[b]}.{n}" for b in self.bodies for n in PI_NAMES]
        return out + [f"{joint_names[j]}.{k}" for j, k in self.joints]

    def physical_names(self, body_names: Sequence[str], joint_names: Sequence[str]) -> list[str]:
        """Names of the reported parameters: ``BODY.mass``, ``BODY.com_x``, …, ``JOINT.damping``, …"""
        out = [f"{body_names[b]}.{n}" for b in self.bodies for n in BODY_PARAMS]
        return out + [f"{joint_names[j]}.{k}" for j, k in self.joints]


def parse_param_names(names: Sequence[str], body_names: Sequence[str], joint_names: Sequence[str]) -> ParamSpec:
    """``body:NAME`` (its ten inertial parameters) and ``joint:NAME.damping|armature|frictionloss``.

    ``joint:NAME`` alone means its damping. The prefixes may be left out when the name is unambiguous.

    Raises:
        ParamError: an unknown body, joint or parameter, or a single inertial parameter of a body (they are
            identified together), listing the valid names.
    """
    bodies: list[int] = []
    joints: list[tuple[int, str]] = []
    valid_b = [b for b in body_names[1:] if b]
    for raw in names:
        name = raw.strip()
        m = re.fullmatch(r"(?:(body|joint):)?([^.:]+)(?:\.(\w+))?", name)
        if not m:
            raise ParamError(f"parameter '{raw}': expected body:NAME or joint:NAME.damping|armature|frictionloss")
        kind, obj, attr = m.group(1), m.group(2), m.group(3)
        if kind is None:
            kind = "body" if obj in valid_b and attr is None else "joint" if obj in joint_names else "body"
        if kind == "body":
            if obj not in valid_b:
                raise ParamError(f"parameter '{raw}': unknown body '{obj}' (bodies: {', '.join(valid_b)})")
            if attr is not None:
                raise ParamError(
                    f"parameter '{raw}': a body's inertial parameters are identified together; "
                    f"give body:{obj} (mass, com_x..com_z, Ixx..Iyz)"
                )
            b = list(body_names).index(obj)
            if b not in bodies:
                bodies.append(b)
        else:
            if obj not in joint_names:
                raise ParamError(f"parameter '{raw}': unknown joint '{obj}' (joints: {', '.join(joint_names)})")
            attr = attr or "damping"
            if attr not in JOINT_PARAMS:
                raise ParamError(f"parameter '{raw}': unknown joint parameter '{attr}' ({', '.join(JOINT_PARAMS)})")
            key = (list(joint_names).index(obj), attr)
            if key not in joints:
                joints.append(key)
    if not bodies and not joints:
        raise ParamError("no parameters given: name bodies (body:NAME) or joint parameters (joint:NAME.damping)")
    return ParamSpec(tuple(bodies), tuple(joints))


def _body_pi(body: BodyInfo) -> np.ndarray:
    """The model's π_b ``(10,)`` of a body."""
    m = float(body.mass)
    c = np.asarray(body.ipos, dtype=float)
    Ri = quat_to_mat(body.iquat)
    Ic = Ri @ np.diag(np.asarray(body.inertia, dtype=float)) @ Ri.T
    I = Ic + m * (float(c @ c) * np.eye(3) - np.outer(c, c))
    return np.array([m, *(m * c), I[0, 0], I[1, 1], I[2, 2], I[0, 1], I[0, 2], I[1, 2]])


def _inertia_matrix(pi: Sequence) -> list[list]:
    return [[pi[4], pi[7], pi[8]], [pi[7], pi[5], pi[9]], [pi[8], pi[9], pi[6]]]


def _to_node(pi: Sequence, R: np.ndarray, p: np.ndarray) -> tuple:
    """A body's (m, h, I) in its node frame about the node origin (module docstring), on any scalars."""
    m = pi[0]
    hb = [pi[1], pi[2], pi[3]]
    Ib = _inertia_matrix(pi)
    Rh = [sum(R[r, k] * hb[k] for k in range(3)) for r in range(3)]
    h = [m * p[r] + Rh[r] for r in range(3)]
    RI = [[sum(R[r, k] * Ib[k][c] for k in range(3)) for c in range(3)] for r in range(3)]
    RIRt = [[sum(RI[r][k] * R[c, k] for k in range(3)) for c in range(3)] for r in range(3)]
    pp = float(p @ p)
    pRh = sum(p[k] * Rh[k] for k in range(3))
    I = [
        [
            RIRt[r][c]
            + m * ((pp if r == c else 0.0) - p[r] * p[c])
            + (2 * pRh if r == c else 0.0)
            - p[r] * Rh[c]
            - Rh[r] * p[c]
            for c in range(3)
        ]
        for r in range(3)
    ]
    return m, h, I


def pseudo_inertia(pi: Sequence[float]) -> np.ndarray:
    """``J(π) = [[½ tr(I) 1 − I, h], [hᵀ, m]]`` ``(4, 4)``: positive definite iff the body is consistent."""
    pi = np.asarray(pi, dtype=float)
    I = np.array(_inertia_matrix(pi), dtype=float)
    J = np.zeros((4, 4))
    J[:3, :3] = 0.5 * np.trace(I) * np.eye(3) - I
    J[:3, 3] = J[3, :3] = pi[1:4]
    J[3, 3] = pi[0]
    return J


def pi_from_theta(theta: np.ndarray | cs.SX | cs.MX) -> np.ndarray | cs.SX | cs.MX:
    """π ``(10,)`` of the log-Cholesky coordinates θ = (α, d₁, d₂, d₃, s₁₂, s₂₃, s₁₃, t₁, t₂, t₃)."""
    a, d1, d2, d3, s12, s23, s13, t1, t2, t3 = (theta[i] for i in range(10))
    ea = cs.exp(a) if isinstance(theta, cs.SX | cs.MX) else np.exp(a)
    ex = cs.exp if isinstance(theta, cs.SX | cs.MX) else np.exp
    U = [[ex(d1), s12, s13, t1], [0, ex(d2), s23, t2], [0, 0, ex(d3), t3], [0, 0, 0, 1]]
    J = [[sum(U[r][k] * U[c][k] for k in range(4)) for c in range(4)] for r in range(4)]
    e2 = ea * ea
    S = [[J[r][c] * e2 for c in range(3)] for r in range(3)]
    tr = S[0][0] + S[1][1] + S[2][2]
    vals = [
        J[3][3] * e2,
        J[0][3] * e2,
        J[1][3] * e2,
        J[2][3] * e2,
        tr - S[0][0],
        tr - S[1][1],
        tr - S[2][2],
        -S[0][1],
        -S[0][2],
        -S[1][2],
    ]
    return cs.vertcat(*vals) if isinstance(theta, cs.SX | cs.MX) else np.array(vals, dtype=float)


def theta_from_pi(pi: Sequence[float]) -> np.ndarray:
    """The log-Cholesky θ ``(10,)`` of a consistent π (``J(π) ≻ 0``).

    Raises:
        np.linalg.LinAlgError: π is not consistent (``J`` is not positive definite).
    """
    J = pseudo_inertia(pi)
    P = np.eye(4)[::-1]
    L = np.linalg.cholesky(P @ J @ P)  # P J P = L Lᵀ  →  J = U Uᵀ with U = P L P upper triangular
    U = P @ L @ P
    a = np.log(U[3, 3])
    U = U / U[3, 3]
    return np.array(
        [a, np.log(U[0, 0]), np.log(U[1, 1]), np.log(U[2, 2]), U[0, 1], U[1, 2], U[0, 2], U[0, 3], U[1, 3], U[2, 3]]
    )


def physical_from_pi(pi: np.ndarray) -> np.ndarray:
    """``(mass, com (3,), I_c (xx, yy, zz, xy, xz, yz))`` ``(10,)`` of a body's π (mass > 0)."""
    m = float(pi[0])
    c = np.asarray(pi[1:4], dtype=float) / m
    I = np.array(_inertia_matrix(pi), dtype=float) - m * (float(c @ c) * np.eye(3) - np.outer(c, c))
    return np.array([m, *c, I[0, 0], I[1, 1], I[2, 2], I[0, 1], I[0, 2], I[1, 2]])


class InertialRegressor:
    """``Y(q, q̇, q̈)`` and the right-hand side ``y(q, q̇, q̈, u)`` of a model file's plant (module docstring).

    Args:
        plant: An :class:`~shinro_ctrl.plants.MjcfPlant` (its tree, rigid-body tree and active actuators).
        spec: The parameters (:func:`parse_param_names`).

    Attributes:
        function: CasADi ``(q, qd, qdd, u) -> (Y (nq, k), y (nq,))``, SX, one sample.
        pi_prior: The model's π ``(k,)``.
        pi_names: Names of π's entries.
    """

    def __init__(self, plant: MjcfPlant, spec: ParamSpec):
        tree, rb = plant.tree, plant.rigid_body_tree
        nq = tree.nq
        if tree.na:
            raise ParamError("models with actuator activation states are not supported by the regressor")
        self.spec = spec
        body_names = [b.name for b in tree.bodies]
        joint_names = [j.name for j in tree.joints]
        self.pi_names = spec.pi_names(body_names, joint_names)
        self.body_names, self.joint_names = body_names, joint_names
        q, qd, qdd = cs.SX.sym("q", nq), cs.SX.sym("qd", nq), cs.SX.sym("qdd", nq)
        u = cs.SX.sym("u", len(plant.active_actuators))
        k = 10 * len(spec.bodies) + len(spec.joints)
        pi = cs.SX.sym("pi", k)
        nodes = [(m, list(h), [list(r) for r in I]) for m, h, I in rb.node_inertials()]
        prior = []
        for n, b in enumerate(spec.bodies):
            body = tree.bodies[b]
            if body.gravcomp:
                raise ParamError(f"body '{body.name}' has gravcomp: its mass also enters the applied forces")
            node, R, p = rb.body_placement(b)
            R, p = np.asarray(R, dtype=float), np.asarray(p, dtype=float)
            if node < 0:
                raise ParamError(f"body '{body.name}' is welded to the world: its inertia never acts")
            pb = _body_pi(body)
            prior.append(pb)
            m0, h0, I0 = _to_node(pb, R, p)
            ms, hs, Is = _to_node([pi[10 * n + i] for i in range(10)], R, p)
            M, H, II = nodes[node]
            nodes[node] = (
                M - m0 + ms,
                [H[r] - h0[r] + hs[r] for r in range(3)],
                [[II[r][c] - I0[r][c] + Is[r][c] for c in range(3)] for r in range(3)],
            )
        rnea = rb.inverse_dynamics(
            list(cs.vertsplit(q)),
            list(cs.vertsplit(qd)),
            list(cs.vertsplit(qdd)),
            CASADI_OPS,
            inertials=nodes,
            armature=False,
        )
        lhs = [cs.SX(v) if isinstance(v, float | int) else v for v in rnea]
        rhs = rb.generalized_forces(
            list(cs.vertsplit(q)), list(cs.vertsplit(qd)), list(cs.vertsplit(u)), plant.active_actuators, (), CASADI_OPS
        )
        rhs = [cs.SX(v) if isinstance(v, float | int) else v for v in rhs]
        armature_known = {i: j.armature for i, j in enumerate(tree.joints)}
        off = 10 * len(spec.bodies)
        for n, (j, attr) in enumerate(spec.joints):
            jt = tree.joints[j]
            if attr == "damping":
                lhs[j] = lhs[j] + pi[off + n] * qd[j]
                if tree.damping_enabled:
                    rhs[j] = rhs[j] + jt.damping * qd[j]  # the model's damping is in τ_passive: undo it
                prior.append(np.array([jt.damping]))
            elif attr == "armature":
                lhs[j] = lhs[j] + pi[off + n] * qdd[j]
                armature_known.pop(j, None)
                prior.append(np.array([jt.armature]))
            else:
                lhs[j] = lhs[j] + pi[off + n] * cs.sign(qd[j])
                prior.append(np.array([jt.frictionloss]))
        for j, a in armature_known.items():
            if a:
                rhs[j] = rhs[j] - a * qdd[j]
        lhs_v, rhs_v = cs.vertcat(*lhs), cs.vertcat(*rhs)
        Y = cs.jacobian(lhs_v, pi)
        tau0 = cs.substitute(lhs_v, pi, cs.DM.zeros(k))
        self.function = cs.Function(
            "regressor", [q, qd, qdd, u], [Y, rhs_v - tau0], ["q", "qd", "qdd", "u"], ["Y", "y"]
        )
        self.pi_prior = np.concatenate(prior) if prior else np.zeros(0)
        self.nq, self.k = nq, k
        self.nb = len(spec.bodies)
