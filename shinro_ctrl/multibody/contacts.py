r"""Contacts held as holonomic constraints, and the standing equilibrium under them.

A contact names a geom, site or body of the model that stays where it is at the
reference configuration (the first keyframe, else ``qpos0``):

* **point contact**: a sphere geom or a sphere site. Its *centre* is held to its
  reference position in the world (a ``connect`` to the world: three rows), so the
  contact point (the sphere's lowest point, straight below the centre on a level floor)
  stays put as long as the foot does not roll; the foot may turn about the centre
  freely. The force is the world-frame force on the centre ``λ = (f_x, f_y, f_z)``.
* **flat contact**: any other geom (a box sole, a capsule, a mesh), any other site, or
  a body. Its frame is welded to its reference pose in the world (a ``weld``: three
  position and three orientation rows). The force is the world-frame wrench ``λ =
  (f_x, f_y, f_z, ½-vee torque rows)`` on the frame's origin.

The dynamics are then exactly :class:`~shinro_ctrl.multibody.constraints.ConstrainedDynamics`
with these constraints beside the model's own equalities: the KKT system with the contact
Jacobians, in the coordinates the contacts leave free. Redundant rows (two points on one sole,
a point beside a weld, a planar model's out-of-plane rows) are normal: the dynamics keep an
independent subset; :meth:`ConstrainedDynamics.constraint_forces` reports the minimum-norm
split over all rows.

**Friction.** Each contact's coefficient ``μ`` is MuJoCo's: the larger of the contact's own
sliding friction (a body or site: the largest of its body's colliding geoms) and the floor's
(the largest of the world body's geoms); MuJoCo takes the maximum of the two geoms'
coefficients by default. The floor normal is the world ``+z``.

**Standing equilibrium** (:func:`standing_equilibrium`). At a configuration ``q`` on the
contacts and ``q̇ = 0``, the static balance is linear in the inputs ``u`` and the forces ``λ``
(all rows, redundant ones included):

.. math::

    τ_0(q) + B_u(q)\,u − g(q) + J(q)^\top λ = 0,

with ``τ = τ_0 + B_u u`` the applied generalized forces (actuators, springs, gravity
compensation) and ``g`` the gravity forces. It is solved as the convex QP

.. math::

    \min_{u, λ}\ \|u\|^2 + w_t \|f_t\|^2 + ε\|λ\|^2 \quad\text{s.t. the balance, }
    u_{\min} ≤ u ≤ u_{\max},\ |f_x|, |f_y| ≤ \tfrac{μ}{\sqrt 2} f_z,\
    f_{z,i} ≥ \frac{α}{N_b} \sum_{j \in b} f_{z,j},

the inner linearized pyramid (inside the exact cone ``‖f_{xy}‖ ≤ μ f_z``, so its answers are
in the exact cone).

**Tangential forces** (``w_t`` = ``tangential_weight``, default :data:`TANGENTIAL_WEIGHT`). With
several contacts the statics leave internal forces free (two feet squeezing or splaying, heel and toe
of one sole pulling apart), and the least-torque split uses them: our humanoid's legs splayed with
24 N at each heel and squeezed each sole fore and aft with 47 N, the quadruped's with 5-10 N. A
friction contact holds a sustained tangential load only by creeping (MuJoCo's soft friction needs a
steady slip velocity for a steady force; a rubber sole creeps too), and the design model holds the
feet still, so the feet slid apart (2 cm in 10 s) and the pelvis turned (0.13 rad). Weighting
``‖f_t‖²`` [1/m², beside N² m² of torque] makes the equilibrium lean on friction only as much as the
torques need: the humanoid's tangential forces fall to 0.2 N (the hip roll torques rise from 0.05 to
23 N m, near the 20 N m of MuJoCo's own ``mj_inverse`` at rest), the quadruped's to 0.01 N.

**Several contact points on one foot** (the last constraint, ``α`` = ``min_share``, default
:data:`MIN_NORMAL_SHARE`). A flat sole modelled by its corner points (``N_b`` contacts on one body
``b``) leaves the split of the foot's load between its corners to the optimizer: statics fix only
the foot's total force and moment, and the least-torque split is degenerate. Left alone it may load
one edge only (our humanoid: the inner sole corners at 0.18 kN, the outer ones at 0 N): the centre of
pressure then sits on the sole's edge, where a real (or MuJoCo's soft) contact rolls about the edge
that the design model holds fixed. So every contact carries at least ``α`` of the even share of its
foot's load, which keeps each foot's centre of pressure inside its support polygon with a margin (a
rectangle of corners: within ``1 − α`` of the half-length from its centre along each axis). It is
linear in ``λ`` and homogeneous, so it scales with the load. A body with one contact (a point foot)
is unaffected (``f_z ≥ 0`` only): the quadruped's equilibrium does not change. The torque rows of a
*flat* (welded) contact are free: its centre of pressure is not checked against an outline (a site or
body has none); model a sole by its corner points to get the constraint.

**Choosing the contacts.** Hold a foot where the robot's joints can hold it. Two flat soles welded to
the floor (or each by its four corners) on legs *without an ankle roll joint* (our humanoid, like
the H1) over-constrain the frontal plane: the contact Jacobian is then nearly rank-deficient (the
humanoid's 12th singular value is 1e-4 beside 0.05 for the 11th). The design locks a motion (both
knees bending with the pelvis pitching) that only 0.1 mm of foot deformation per radian resists; MuJoCo's
soft contacts allow it, the LQR does not see it, and it grows at 3.3/s: the robot fell after 3-4 s
for every weighting tried. Hold such a sole at two points on its centre line instead (sphere sites
at the heel and the toe, ``<side>_heel`` and ``<side>_toe`` in ``assets/humanoid.xml``): the foot
may roll about that line in the design, its centre of pressure lies on it (half the sole's width from
either edge), the Jacobian's rank is clean (10, next singular value 0.13) and the LQR stands the
robot for as long as it runs. Redundant rows are harmless; near-redundant ones are not:
:func:`check_conditioning` (called by ``MjcfPlant`` with contacts) warns with
:class:`NearlyRedundantContacts` when the smallest singular value of the rows the dynamics keep is
below :data:`NEAR_REDUNDANT` of the largest.

When the QP is infeasible, linear feasibility problems name the constraint that fails: the balance
alone (``posture``: the actuators and contacts cannot hold ``q`` at all), with the friction cones
and ``f_z ≥ 0`` (``friction``), with the actuator ranges (``torque``), with the minimum share
(``support``: a foot's centre of pressure would be too near its edge).
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence
from dataclasses import dataclass

import casadi as cs
import numpy as np

from shinro_ctrl._interrupts import solve_interruptibly
from shinro_ctrl.errors import InvalidArgument
from shinro_ctrl.multibody.constraints import ConstrainedDynamics, Constraint
from shinro_ctrl.multibody.rigid_body import NUMPY_OPS, RigidBodyTree

__all__ = [
    "EQUILIBRIUM_FAILURES",
    "MIN_NORMAL_SHARE",
    "NEAR_REDUNDANT",
    "TANGENTIAL_WEIGHT",
    "ContactFrame",
    "EquilibriumNotFound",
    "NearlyRedundantContacts",
    "StandingEquilibrium",
    "check_conditioning",
    "contact_constraints",
    "standing_equilibrium",
]

#: The constraint an impossible standing equilibrium names first.
EQUILIBRIUM_FAILURES = ("posture", "friction", "torque", "support")
#: Default ``min_share``: each contact's normal force is at least this fraction of the even share of its foot's load.
MIN_NORMAL_SHARE = 0.5
#: Weight of ``‖λ‖²`` beside ``‖u‖²`` in the equilibrium QP (makes the forces unique).
FORCE_WEIGHT = 1e-6
#: Default ``tangential_weight``: weight of the contacts' tangential forces ``‖f_t‖²`` [1/m²] beside ``‖u‖²``.
TANGENTIAL_WEIGHT = 100.0
#: Kept constraint rows whose smallest singular value is below this fraction of the largest are nearly redundant.
NEAR_REDUNDANT = 1e-3
#: Residual of the static balance [N or N m] accepted as zero.
BALANCE_TOL = 1e-7


@dataclass(frozen=True)
class ContactFrame:
    """Where a named contact sits on the robot.

    Attributes:
        name: The geom's, site's or body's name.
        element: ``"geom"``, ``"site"`` or ``"body"``.
        body: Index of the body it is fixed on (MuJoCo's order; 0 is the world).
        pos: Origin in the body frame ``(3,)`` [m] (a sphere's centre).
        quat: Orientation in the body frame ``(w, x, y, z)``.
        point: True for a point contact (a sphere), False for a flat (welded) one.
        friction: Sliding friction coefficient ``μ`` of the contact with the floor.
    """

    name: str
    element: str
    body: int
    pos: np.ndarray
    quat: np.ndarray
    point: bool
    friction: float

    @property
    def rows(self) -> int:
        """Rows of its constraint: 3 (point) or 6 (flat)."""
        return 3 if self.point else 6

    def describe(self) -> str:
        """How messages name it, e.g. ``"contact 'FL_foot' (point, geom)"``."""
        return f"contact '{self.name}' ({'point' if self.point else 'flat'}, {self.element})"


def contact_constraints(rb: RigidBodyTree, frames: Sequence[ContactFrame], q: np.ndarray) -> list[Constraint]:
    """The constraints that hold each contact frame at its world pose at ``q (nq,)``.

    A point contact is a ``connect`` of its centre to the world, a flat one a ``weld`` of its frame.

    Raises:
        InvalidArgument: a contact fixed to the world body (it cannot move, so it holds nothing).
    """
    out = []
    for f in frames:
        if f.body == 0:
            raise InvalidArgument(
                f"{f.describe()} is fixed to the world body: it cannot move, so it holds nothing (name a geom, "
                "site or body of the robot)"
            )
        R, p = rb.frame_pose(list(q), f.body, f.pos, f.quat, NUMPY_OPS)
        p = np.array([float(v) for v in p])
        if f.point:
            out.append(Constraint("connect", label=f.describe(), body1=f.body, pos1=f.pos, body2=0, pos2=p))
        else:
            from scipy.spatial.transform import Rotation  # here: the weld case only (an import of ~50 ms)

            xyzw = Rotation.from_matrix(np.array([[float(v) for v in r] for r in R])).as_quat()
            quat2 = np.r_[xyzw[3], xyzw[:3]]
            out.append(
                Constraint(
                    "weld", label=f.describe(), body1=f.body, pos1=f.pos, quat1=f.quat, body2=0, pos2=p, quat2=quat2
                )
            )
    return out


class NearlyRedundantContacts(UserWarning):
    """Contacts that hold a motion only by a nearly redundant row (module docstring, "Choosing the contacts")."""


def check_conditioning(
    cd: ConstrainedDynamics, frames: Sequence[ContactFrame], q: np.ndarray, *, what: str = "the contacts"
) -> float:
    """``σ_r / σ_1`` of the constraint Jacobian at ``q (nq,)``, ``r`` the rows the dynamics keep; warns below
    :data:`NEAR_REDUNDANT`.

    A small ratio means a row the dynamics count as independent barely constrains anything: the design locks a
    motion that the real (soft) contacts resist only by a tiny deformation (our humanoid's eight sole corners:
    1.7e-5), so a controller designed on it does not see that motion.

    Warns:
        NearlyRedundantContacts: naming the contacts and the ratio.
    """
    _, J = cd.constraint_jacobian(q)
    s = np.linalg.svd(J, compute_uv=False)
    kept = len(cd.rows)
    ratio = float(s[kept - 1] / s[0]) if kept and s[0] > 0 else 1.0
    if ratio < NEAR_REDUNDANT:
        names = ", ".join(f.name for f in frames)
        warnings.warn(
            NearlyRedundantContacts(
                f"{what} ({names}) are nearly redundant: the smallest of the {kept} constraint directions the "
                f"dynamics keep is {ratio:.2g} of the largest, so the design locks a motion the contacts barely "
                "resist (a controller will not see it); hold fewer points, e.g. a sole without an ankle roll joint "
                "at its heel and toe"
            ),
            stacklevel=3,
        )
    return ratio


class EquilibriumNotFound(InvalidArgument):
    """No standing equilibrium: :attr:`failure` is ``"posture"``, ``"friction"`` or ``"torque"``."""

    def __init__(self, message: str, failure: str):
        super().__init__(message)
        self.failure = failure


@dataclass(frozen=True)
class StandingEquilibrium:
    """A standing equilibrium (see the module docstring).

    Attributes:
        q: Configuration ``(nq,)`` on the contacts (every joint, dependent ones included).
        u: Inputs ``(m,)`` that hold it, inside the actuator ranges.
        forces: Per contact (by name) its force ``(3,)`` or wrench ``(6,)`` in the world frame.
        friction_margin: Per contact ``μ f_z − ‖f_{xy}‖`` [N] (≥ 0: inside the exact cone).
        residual: Largest static-balance residual ``|τ₀ + B_u u − g + Jᵀλ|`` [N or N m].
    """

    q: np.ndarray
    u: np.ndarray
    forces: dict[str, np.ndarray]
    friction_margin: dict[str, float]
    residual: float


def _static_terms(rb: RigidBodyTree, q: np.ndarray, active: Sequence[int]) -> tuple[np.ndarray, np.ndarray]:
    """``(b, B_u)`` with ``τ_0 − g = b`` and ``τ = τ_0 + B_u u`` at ``q``, ``v = 0`` (affine in ``u``).

    Generalized forces over the ``nv`` tangent directions (a free base's six included: ``B_u`` is zero there).
    """
    n, m = rb.nv, len(active)
    ql, zero = list(q), [0.0] * n

    def tau(u: np.ndarray) -> np.ndarray:
        return np.array([float(v) for v in rb.generalized_forces(ql, zero, list(u), active, (), NUMPY_OPS)])

    t0 = tau(np.zeros(m))
    Bu = np.column_stack([tau(e) - t0 for e in np.eye(m)]) if m else np.zeros((n, 0))
    g = np.array([float(v) for v in rb.bias(ql, zero, NUMPY_OPS)])
    return t0 - g, Bu


def standing_equilibrium(
    cd: ConstrainedDynamics,
    frames: Sequence[ContactFrame],
    q: np.ndarray,
    active: Sequence[int],
    u_bounds: tuple[np.ndarray, np.ndarray],
    *,
    min_share: float = MIN_NORMAL_SHARE,
    tangential_weight: float = TANGENTIAL_WEIGHT,
    what: str = "the standing equilibrium",
) -> StandingEquilibrium:
    """The inputs and contact forces that hold ``q`` still (module docstring: the QP and its diagnosis).

    Args:
        cd: The constrained dynamics whose last constraints are the contacts ``frames`` (in order).
        frames: The contacts.
        q: Configuration ``(nq,)`` on the constraints.
        active: The actuators that are the inputs.
        u_bounds: ``(u_min, u_max)`` (±inf where unbounded).
        min_share: ``α`` in ``[0, 1]``: every contact's normal force is at least ``α`` times the even share
            ``Σ_{j on b} f_z,j / N_b`` of the load on its body ``b`` (its foot: the ``N_b`` contacts on that
            body; module docstring); 0: only ``f_z ≥ 0``. Vacuous for a body's only contact.
        tangential_weight: ``w_t ≥ 0``, weight of the tangential forces ``‖f_t‖²`` in the objective (module
            docstring); 0: only the least-norm tie-break.
        what: How messages name the problem.

    Raises:
        EquilibriumNotFound: no equilibrium (one line naming the failing constraint).
    """
    import scipy.optimize  # here, not at module import: every plant imports this module, few need the LP

    if not (isinstance(min_share, int | float) and 0.0 <= min_share <= 1.0):
        raise InvalidArgument(f"min_share must be a number in [0, 1] (a fraction of the even share), got {min_share!r}")
    if not (isinstance(tangential_weight, int | float) and 0.0 <= tangential_weight < np.inf):
        raise InvalidArgument(f"tangential_weight must be a finite number ≥ 0, got {tangential_weight!r}")
    rb = cd.rb
    m = len(active)
    b, Bu = _static_terms(rb, q, active)
    _, J = cd.constraint_jacobian(q)  # all rows, the contacts' last
    R = J.shape[0]
    crow = R - sum(f.rows for f in frames)
    A = np.hstack([Bu, J.T])  # A [u; λ] = −b
    nz = m + R
    # inequality rows G z ≤ 0 (friction pyramid) and bounds
    G = []
    r = crow
    for f in frames:
        mu = f.friction / np.sqrt(2.0)
        for k in (0, 1):
            for s in (1.0, -1.0):
                row = np.zeros(nz)
                row[m + r + k], row[m + r + 2] = s, -mu
                G.append(row)
        r += f.rows
    zrows = [m + crow + sum(f.rows for f in frames[:i]) + 2 for i in range(len(frames))]

    def support(share: float) -> np.ndarray:
        """Rows ``−f_z,i + (share / N_b) Σ_{j on b} f_z,j ≤ 0``: each contact carries ``share`` of the even split
        of its body's (foot's) load over the ``N_b`` contacts on that body (vacuous for a body's only contact)."""
        rows = np.zeros((len(frames), nz))
        for i, (f, zi) in enumerate(zip(frames, zrows, strict=True)):
            group = [zj for g, zj in zip(frames, zrows, strict=True) if g.body == f.body]
            rows[i, group] = share / len(group)
            rows[i, zi] -= 1.0
        return rows

    pyramid = np.array(G).reshape(-1, nz)
    G = np.vstack([pyramid, support(0.0)])  # the pyramid, and f_z ≥ 0
    lo, hi = np.r_[u_bounds[0], np.full(R, -np.inf)], np.r_[u_bounds[1], np.full(R, np.inf)]
    free = [(None, None)] * nz
    boxed = [
        (None if not np.isfinite(a) else a, None if not np.isfinite(c) else c) for a, c in zip(lo, hi, strict=True)
    ]

    def feasible(ineq: bool, bounds: list[tuple[float | None, float | None]]) -> bool:
        res = scipy.optimize.linprog(
            np.zeros(nz),
            A_ub=G if ineq and len(G) else None,
            b_ub=np.zeros(len(G)) if ineq and len(G) else None,
            A_eq=A,
            b_eq=-b,
            bounds=bounds,
            method="highs",
        )
        return res.status == 0

    if not feasible(False, free):
        resid = b - A @ np.linalg.lstsq(A, b, rcond=None)[0]
        raise EquilibriumNotFound(
            f"{what} does not exist: posture: the actuators and contacts cannot hold this configuration still "
            f"(unbalanced generalized force {np.abs(resid).max():.3g} N or N m; move the base over the contacts "
            "or add a contact)",
            "posture",
        )
    if not feasible(True, free):
        mus = ", ".join(f"{f.name} μ={f.friction:g}" for f in frames)
        raise EquilibriumNotFound(
            f"{what} does not exist: friction: no contact forces inside the friction cones ({mus}; the inner "
            "pyramid) hold this configuration (widen the stance, raise the friction, or change the posture)",
            "friction",
        )
    if not feasible(True, boxed):
        raise EquilibriumNotFound(
            f"{what} does not exist: torque: holding this configuration with contact forces inside the friction "
            "cones needs torques outside the actuator ranges (ctrlrange; lower the load or change the posture)",
            "torque",
        )
    if min_share > 0.0:
        G = np.vstack([G, support(float(min_share))])  # f_z ≥ 0 kept: at min_share = 1 a lone contact's row is 0 ≤ 0
        bodies = [f.body for f in frames]
        feet = "; ".join(
            ", ".join(f.name for f in frames if f.body == b) for b in dict.fromkeys(bodies) if bodies.count(b) > 1
        )
        if not feasible(True, boxed):
            raise EquilibriumNotFound(
                f"{what} does not exist: support: no contact forces inside the friction cones and torques inside "
                f"the actuator ranges give every contact at least {min_share:g} of the even share of its foot's "
                f"load ({feet}: a foot's centre of pressure would sit too near its edge; move the centre of mass "
                "over the feet, or lower min_share)",
                "support",
            )
    # the QP: min ‖u‖² + ε‖λ‖² (convex; IPOPT)
    weights = np.r_[np.ones(m), np.full(R, FORCE_WEIGHT)]
    r = m + crow
    for f in frames:  # the tangential rows f_x, f_y of each contact
        weights[r : r + 2] = tangential_weight
        r += f.rows
    H = np.diag(weights)
    Aall = np.vstack([A, G]) if len(G) else A
    lba = np.r_[-b, np.full(len(G), -np.inf)]
    uba = np.r_[-b, np.zeros(len(G))]
    zs = cs.MX.sym("z", nz)
    nlp = {"x": zs, "f": 0.5 * cs.dot(zs, cs.mtimes(cs.DM(H), zs)), "g": cs.mtimes(cs.DM(Aall), zs)}
    opts = {"ipopt": {"print_level": 0, "sb": "yes", "tol": 1e-12, "max_iter": 200}, "print_time": False}
    solver = cs.nlpsol("standing", "ipopt", nlp, opts)
    lbx = np.where(np.isfinite(lo), lo, -np.inf)
    ubx = np.where(np.isfinite(hi), hi, np.inf)
    sol = solve_interruptibly(solver, x0=np.zeros(nz), lbg=lba, ubg=uba, lbx=lbx, ubx=ubx)
    z = np.asarray(sol["x"]).ravel()
    residual = float(np.abs(A @ z + b).max())
    if not solver.stats().get("success", False) or residual > BALANCE_TOL * max(1.0, np.abs(b).max()):
        res = scipy.optimize.linprog(  # the feasible point the LP found (never expected: the QP is convex)
            np.zeros(nz),
            A_ub=G if len(G) else None,
            b_ub=np.zeros(len(G)) if len(G) else None,
            A_eq=A,
            b_eq=-b,
            bounds=boxed,
            method="highs",
        )
        z = res.x
        residual = float(np.abs(A @ z + b).max())
    u, lam = z[:m], z[m:]
    forces, margin = {}, {}
    r = crow
    for f in frames:
        w = lam[r : r + f.rows].copy()
        forces[f.name] = w
        margin[f.name] = float(f.friction * w[2] - np.hypot(w[0], w[1]))
        r += f.rows
    return StandingEquilibrium(
        q=np.array(q, dtype=float), u=u, forces=forces, friction_margin=margin, residual=residual
    )
