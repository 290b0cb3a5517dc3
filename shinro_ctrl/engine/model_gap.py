r"""The model-gap report: what a smooth design model leaves out of a model file, and how large it is.

A plant built from a model file (:class:`~shinro_ctrl.plants.mjcf.MjcfPlant`)
designs on the smooth dynamics ``ẋ = f(x, u)``. The MuJoCo loop runs the file
as it is, with effects that are not smooth and that the design never sees.
:func:`model_gap` measures them at one operating point ``(x0, u0)`` with
MuJoCo itself (``mj_forward`` at ``x0``) and says which are not small:

* **friction loss** per degree of freedom: the Coulomb friction bound
  ``f_loss`` (``frictionloss``) against the *load* the joint carries at
  ``x0``,

  .. math::

      \tau_{load} = c(q, \dot q) - \tau_{passive}(q, \dot q)

  (MuJoCo's ``qfrc_bias`` — gravity, Coriolis and centrifugal forces — minus
  ``qfrc_passive`` — springs, dampers, gravity compensation), and against the
  actuator torque ``τ_act`` that ``u0`` produces in the smooth model. When
  ``|τ_load| ≤ f_loss`` friction alone holds the joint: a static dead band of
  ``±f_loss`` that the design ignores.
* **clamps** per actuator: where ``u0`` lies in ``ctrlrange`` and where the
  actuator force of the smooth model at ``u0`` (``gain·u0 + bias``, MuJoCo's
  ``actuator_force`` with clamping switched off) lies in ``forcerange``; per
  joint, where the total actuator torque lies in ``actuatorfrcrange``; per
  actuator with activation dynamics, where its activation lies in
  ``actrange`` (MuJoCo clamps it; the smooth model does not). A
  margin is the distance to the nearer end as a fraction of the range's width,

  .. math::

      \mathrm{margin} = \frac{\min(v - lo,\; hi - v)}{hi - lo},

  so 0.5 is the middle, 0 the edge and a negative margin lies outside, where
  MuJoCo clamps (an error-level warning: the loop cannot apply ``u0``), except
  within a rounding error of the edge (``−1e-8 ≤ margin < 0``, e.g. an
  equilibrium input computed 1e-10 past it): on the edge, a warning.
* **tendons** with friction loss or a range (:class:`TendonGap`): the friction
  loss against the tendon's load force, the length's margin in the range.
* **contacts** active at ``x0`` (MuJoCo's ``d.contact`` rows that become
  constraints: count, geom pairs, distance; a negative distance is a
  penetration): the smooth model has no contacts.
* **joint-limit margins** at ``x0`` for limited hinge and slide joints, with
  the same margin fraction; MuJoCo's limit constraint is active already when
  the distance to the limit is below the joint's ``margin`` attribute.
* **soft equality constraints**: MuJoCo's equality is soft (``solref``,
  ``solimp``); per active equality, ``x0``'s violation of it and the static
  sag it settles at under the load it carries at ``(x0, u0)``
  (:class:`EqualityGap`); the design model's constraint is exact.

Thresholds (:class:`GapThresholds`, defaults below): a warning when friction
loss exceeds :data:`FRICTION_WARN` (10 %) of the load torque, when a margin to
a clamp is below :data:`CLAMP_WARN` (10 %) of the range, for any contact,
when a joint-limit margin is below :data:`LIMIT_WARN` (5 %) of the range or
inside the joint's MuJoCo ``margin``, and when an equality sags (or ``x0``
violates it) by more than :data:`EQUALITY_WARN` (1e-3 m or rad). Effects
switched off by the model's own ``<flag>`` (``frictionloss``, ``limit``,
``contact``, ``clampctrl``, ``equality``) are not reported: the MuJoCo loop
does not have them either.

This is the MuJoCo side of the report (only the engine package imports
``mujoco``); :meth:`MjcfPlant.model_gap <shinro_ctrl.plants.mjcf.MjcfPlant.model_gap>`
calls :func:`plant_model_gap` for its own file, state layout and inputs; the
``design`` command calls :func:`engine_model_gap` on the scenario's MuJoCo loop.
"""

from __future__ import annotations

import copy
import functools
import math
import os
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Literal

import mujoco
import numpy as np
from numpy.typing import ArrayLike

if TYPE_CHECKING:
    from shinro_ctrl.engine.core import MujocoEngine
    from shinro_ctrl.plants.base import Plant

from shinro_ctrl.engine.model_tree import ModelWarning, load_model
from shinro_ctrl.errors import InvalidArgument
from shinro_ctrl.validation import as_vector

__all__ = [
    "CLAMP_WARN",
    "EQUALITY_WARN",
    "FRICTION_WARN",
    "LIMIT_WARN",
    "ActuatorGap",
    "ContactGap",
    "DofGap",
    "EqualityGap",
    "GapThresholds",
    "GapWarning",
    "ModelGap",
    "TendonGap",
    "engine_model_gap",
    "model_gap",
    "model_gap_of_file",
    "plant_model_gap",
]

#: Warn when a joint's friction loss exceeds this fraction of its load torque ``|τ_load|``.
FRICTION_WARN = 0.10
#: Warn when ``u0`` (or the actuator force it produces) is closer than this fraction of the range to a clamp.
CLAMP_WARN = 0.10
#: Warn when ``x0`` is closer than this fraction of a joint's range to a joint limit.
LIMIT_WARN = 0.05
#: Warn when a soft equality sags (or ``x0`` violates it) by more than this [m or rad].
EQUALITY_WARN = 1e-3

_D = mujoco.mjtDisableBit
#: Names of a free or ball joint's degrees of freedom (MuJoCo's ``qvel`` order: linear, then angular).
_DOF_SUFFIXES = {"free": ("x", "y", "z", "wx", "wy", "wz"), "ball": ("wx", "wy", "wz")}
_KINDS = {
    int(mujoco.mjtJoint.mjJNT_HINGE): "hinge",
    int(mujoco.mjtJoint.mjJNT_SLIDE): "slide",
    int(mujoco.mjtJoint.mjJNT_BALL): "ball",
    int(mujoco.mjtJoint.mjJNT_FREE): "free",
}


@dataclass(frozen=True)
class GapThresholds:
    """When an effect is "not small" (see the module docstring).

    Attributes:
        friction: Friction loss above this fraction of ``|τ_load|`` warns.
        clamp: A margin to ``ctrlrange``/``forcerange``/``actuatorfrcrange`` below this fraction warns.
        limit: A joint-limit margin below this fraction warns.
        equality: A soft equality's sag, or ``x0``'s violation of it, above this [m or rad] warns.
    """

    friction: float = FRICTION_WARN
    clamp: float = CLAMP_WARN
    limit: float = LIMIT_WARN
    equality: float = EQUALITY_WARN

    def __post_init__(self) -> None:
        for name in ("friction", "clamp", "limit", "equality"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v) or v < 0:
                raise InvalidArgument(f"GapThresholds.{name} must be a finite number >= 0, got {v!r}")


@dataclass(frozen=True)
class DofGap:
    """One degree of freedom at ``x0``: its joint limit, load, actuator torque and friction loss.

    Attributes:
        name: The joint's name; for a free joint ``<joint>.x``, ``.y``, ``.z`` (translation), ``.wx``, ``.wy``,
            ``.wz`` (rotation), for a ball joint ``.wx``, ``.wy``, ``.wz``.
        kind: ``"hinge"``, ``"slide"``, ``"ball"`` or ``"free"``.
        q: Position at ``x0`` (None for ball and free joints) [rad or m].
        range: ``(lo, hi)`` of a limited hinge/slide joint, else None.
        limit_margin: ``min(q − lo, hi − q) / (hi − lo)`` (negative outside), None without a limit.
        limit_distance: ``min(q − lo, hi − q)`` [rad or m], None without a limit.
        mujoco_margin: The joint's MuJoCo ``margin`` (its limit constraint is active below it).
        load: ``τ_load = qfrc_bias − qfrc_passive`` [N m or N].
        actuator: ``τ_act``, the generalized force of the actuators at ``u0`` in the smooth model.
        frictionloss: ``f_loss`` [N m or N] (0 without friction loss or with it disabled).
        friction_ratio: ``f_loss / |τ_load|`` (inf for a zero load), None without friction loss.
        friction_holds: ``|τ_load| ≤ f_loss``: friction alone holds the joint (a static dead band).
        friction_to_actuator: ``f_loss / |τ_act|`` (inf for a zero torque), None without friction loss.
        actfrc_range: ``actuatorfrcrange`` of the joint when limited, else None.
        actfrc_margin: Margin of ``τ_act`` in ``actfrc_range``, else None.
    """

    name: str
    kind: str
    q: float | None
    range: tuple[float, float] | None
    limit_margin: float | None
    limit_distance: float | None
    mujoco_margin: float
    load: float
    actuator: float
    frictionloss: float
    friction_ratio: float | None
    friction_holds: bool
    actfrc_range: tuple[float, float] | None = None
    actfrc_margin: float | None = None
    friction_to_actuator: float | None = None


@dataclass(frozen=True)
class ActuatorGap:
    """One actuator at ``u0``: its distance to the control and force clamps.

    Attributes:
        name: The actuator's name.
        ctrl: Its control at ``u0`` (0 for an actuator that is not an input).
        ctrlrange: ``(lo, hi)`` when MuJoCo clamps the control, else None.
        ctrl_margin: Margin of ``ctrl`` in ``ctrlrange`` (negative outside), else None.
        force: Actuator force of the smooth model at ``u0`` (unclamped) [N or N m].
        forcerange: ``(lo, hi)`` when MuJoCo clamps the force, else None.
        force_margin: Margin of ``force`` in ``forcerange``, else None.
        applied_force: The force MuJoCo applies at ``u0`` (after both clamps).
        act: The activation at ``x0`` of an actuator with activation dynamics, else None.
        actrange: ``(lo, hi)`` when MuJoCo clamps the activation (``actlimited``), else None.
        act_margin: Margin of ``act`` in ``actrange``, else None.
    """

    name: str
    ctrl: float
    ctrlrange: tuple[float, float] | None
    ctrl_margin: float | None
    force: float
    forcerange: tuple[float, float] | None
    force_margin: float | None
    applied_force: float
    act: float | None = None
    actrange: tuple[float, float] | None = None
    act_margin: float | None = None


@dataclass(frozen=True)
class TendonGap:
    r"""A tendon with friction loss or a range (MuJoCo-loop only) at ``x0``.

    The tendon's load is the tendon force that keeps its length still under the load torque
    (no actuation): with ``J`` the tendon's Jacobian and ``Λ = (J M⁻¹ Jᵀ)⁻¹``,

    .. math::

        f_{load} = \Lambda\, J M^{-1} 	au_{load},

    so its friction loss holds the tendon by itself when ``|f_load| ≤ f_loss``.

    Attributes:
        name: The tendon's name (``tendon <i>`` for an unnamed one).
        length: Its length at ``x0`` [m or rad].
        range: ``(lo, hi)`` when limited, else None.
        limit_margin: ``min(L − lo, hi − L) / (hi − lo)``, None without a range.
        limit_distance: ``min(L − lo, hi − L)``, None without a range.
        mujoco_margin: The tendon's MuJoCo ``margin``.
        load: ``f_load`` above [N].
        frictionloss: ``f_loss`` (0 without or disabled).
        friction_ratio: ``f_loss / |f_load|`` (inf for a zero load), None without friction loss.
        friction_holds: ``|f_load| ≤ f_loss``.
    """

    name: str
    length: float
    range: tuple[float, float] | None
    limit_margin: float | None
    limit_distance: float | None
    mujoco_margin: float
    load: float
    frictionloss: float
    friction_ratio: float | None
    friction_holds: bool


@dataclass(frozen=True)
class EqualityGap:
    r"""One active equality constraint at ``x0``: how far ``x0`` is from it, and how far MuJoCo's soft
    version of it sags under the load it carries there.

    MuJoCo's equality is soft: its constraint force is ``f = −(A + R)⁻¹ (J a₀ − a_ref)`` with
    ``A = J M⁻¹ Jᵀ``, the regularizer ``R`` and ``a_ref = −b v − k·d·r`` (``solref``/``solimp``). Held
    still (``v = 0``, constraint acceleration 0) under the unconstrained smooth acceleration ``a₀`` at
    ``(x0, u0)``, the violation it settles at is

    .. math::

        r = (k\,d)^{-1}\, R\, A^{-1} J a_0,

    exact for a constant impedance ``d`` (``solimp`` with equal ``dmin``, ``dmax``), the first-order
    estimate at ``x0``'s impedance otherwise. The design model's constraint is exact (``r = 0``).

    Attributes:
        name: The equality's name (``equality <i> (<type>)`` for an unnamed one).
        kind: ``"connect"``, ``"weld"``, ``"joint"``, ``"tendon"`` ...
        violation: ``max |r|`` of its rows at ``x0`` (MuJoCo's ``efc_pos``) [m or rad].
        sag: ``max |r|`` of its rows at the soft steady state above [m or rad].
    """

    name: str
    kind: str
    violation: float
    sag: float


@dataclass(frozen=True)
class ContactGap:
    """One contact MuJoCo finds at ``x0``.

    Attributes:
        geom1, geom2: The two geoms (names, or ``geom <i> of body '<body>'`` for unnamed ones).
        dist: Signed distance [m]; negative is a penetration.
    """

    geom1: str
    geom2: str
    dist: float


@dataclass(frozen=True)
class GapWarning:
    """An effect of the model-gap report that is not small.

    Attributes:
        level: ``"warning"``, or ``"error"`` where the MuJoCo loop cannot do what the design assumes
            (``u0`` or ``x0`` outside a range MuJoCo clamps or limits).
        effect: ``"friction"``, ``"clamp"``, ``"contact"``, ``"limit"`` or ``"equality"``.
        message: One line for the user.
    """

    level: Literal["warning", "error"]
    effect: str
    message: str

    def __str__(self) -> str:
        return f"{'ERROR' if self.level == 'error' else 'warning'}: {self.message}"


@dataclass(frozen=True)
class ModelGap:
    """What the smooth design model leaves out at one operating point (see the module docstring).

    Attributes:
        model: The model file (or ``"<MjModel>"``).
        x0: The state ``(nq + nv [+ na],)``.
        u0: The controls of every actuator ``(nu,)``.
        dofs: One :class:`DofGap` per degree of freedom, in MuJoCo's dof order.
        actuators: One :class:`ActuatorGap` per actuator.
        contacts: One :class:`ContactGap` per active contact.
        equalities: One :class:`EqualityGap` per active equality constraint.
        tendons: One :class:`TendonGap` per tendon with friction loss or a range.
        warnings: Every effect above its threshold, errors first.
        thresholds: The thresholds used.
        disabled: Effects the model's own flags switch off (``"contact"``, ``"frictionloss"`` ...).
    """

    model: str
    x0: np.ndarray
    u0: np.ndarray
    dofs: tuple[DofGap, ...]
    actuators: tuple[ActuatorGap, ...]
    contacts: tuple[ContactGap, ...]
    warnings: tuple[GapWarning, ...]
    thresholds: GapThresholds = field(default_factory=GapThresholds)
    disabled: tuple[str, ...] = ()
    equalities: tuple[EqualityGap, ...] = ()
    tendons: tuple[TendonGap, ...] = ()

    @property
    def n_contacts(self) -> int:
        """The number of active contacts at ``x0``."""
        return len(self.contacts)

    @property
    def max_penetration(self) -> float:
        """The deepest penetration at ``x0`` [m] (0 without contacts or penetration)."""
        return max(0.0, *(-c.dist for c in self.contacts))  # contacts within a geom margin have dist > 0

    @property
    def errors(self) -> tuple[GapWarning, ...]:
        """The error-level warnings."""
        return tuple(w for w in self.warnings if w.level == "error")

    def format(self) -> str:
        """The report as a compact text table (what ``crosscheck`` and ``design`` print)."""
        out = ["model gap at the operating point (what the smooth design model leaves out; MuJoCo has it):"]
        out += _dof_table(self.dofs)
        out += _actuator_table(self.actuators)
        if self.contacts:
            pairs = ", ".join(f"{c.geom1} – {c.geom2} ({_f(c.dist)} m)" for c in self.contacts[:6])
            more = f", … {len(self.contacts) - 6} more" if len(self.contacts) > 6 else ""
            out.append(
                f"  contacts at x0: {len(self.contacts)}, max penetration {_f(self.max_penetration)} m: {pairs}{more}"
            )
        else:
            out.append("  contacts at x0: none" + (" (disabled in the model)" if "contact" in self.disabled else ""))
        if self.tendons:
            out.append(
                "  tendons (friction loss and range: MuJoCo only): "
                + ", ".join(
                    f"{g.name} length {_f(g.length)} range {_rng(g.range)} margin {_pct(g.limit_margin)} "
                    f"load {_f(g.load)} frictionloss {_f(g.frictionloss)}"
                    for g in self.tendons
                )
            )
        if self.equalities:
            out.append(
                "  equalities (violation at x0; static sag of MuJoCo's soft constraint under the load): "
                + ", ".join(f"{q.name} {_f(q.violation, '.3g')} / {_f(q.sag, '.3g')}" for q in self.equalities)
            )
        if self.disabled:
            out.append(f"  disabled by the model's flags: {', '.join(self.disabled)}")
        t = self.thresholds
        if self.warnings:
            out += [f"  {w}" for w in self.warnings]
        else:
            out.append(
                f"  no effect above its threshold (friction > {t.friction:.0%} of the load, a clamp within "
                f"{t.clamp:.0%}, any contact, a limit within {t.limit:.0%}, an equality's sag > {t.equality:g})"
            )
        return "\n".join(line.rstrip() for line in out)


# ------------------------------------------------------------------ compute
def _margin(v: float, lo: float, hi: float) -> float:
    """``min(v − lo, hi − v) / (hi − lo)`` (see the module docstring); 0 for an empty range at ``v``."""
    width = hi - lo
    d = min(v - lo, hi - v)
    if width <= 0.0:
        return 0.0 if d >= 0.0 else -math.inf
    return d / width


def _label(m: mujoco.MjModel, kind: str, i: int) -> str:
    name = m.joint(i).name if kind == "joint" else m.actuator(i).name
    return name or f"{kind} {i}"


def _geom_label(m: mujoco.MjModel, g: int) -> str:
    name = m.geom(g).name
    if name:
        return name
    b = int(m.geom_bodyid[g])
    return f"geom {g} of body '{m.body(b).name or ('world' if b == 0 else b)}'"


def _free_model(m: mujoco.MjModel) -> mujoco.MjModel:
    """A copy of ``m`` with every clamp switched off: its ``actuator_force`` is the smooth model's."""
    free = copy.copy(m)
    free.opt.disableflags |= int(_D.mjDSBL_CLAMPCTRL)
    free.actuator_forcelimited[:] = 0
    free.jnt_actfrclimited[:] = 0
    free.opt.jacobian = int(mujoco.mjtJacobian.mjJAC_DENSE)  # efc_J dense for the equality rows
    return free


def model_gap(
    model: mujoco.MjModel,
    x0: ArrayLike,
    u0: ArrayLike,
    *,
    thresholds: GapThresholds | None = None,
    source: str = "<MjModel>",
) -> ModelGap:
    """The model-gap report of an ``MjModel`` at ``(x0, u0)`` (see the module docstring).

    Args:
        model: The compiled model (not modified).
        x0: State ``[qpos (nq); qvel (nv)]``, optionally followed by the activations ``act (na)``;
            without them, a filter actuator's activation is its control (its steady state) and an
            integrator's is 0.
        u0: Controls of all ``nu`` actuators.
        thresholds: When an effect warns; default :class:`GapThresholds()`.
        source: The model's file, for the report.

    Returns:
        A :class:`ModelGap`.

    Raises:
        InvalidArgument: wrong lengths.
        NonFiniteError: NaN or inf in ``x0`` or ``u0``.
    """
    m = model
    t = thresholds or GapThresholds()
    nq, nv, na, nu = m.nq, m.nv, m.na, m.nu
    sizes = (nq + nv, nq + nv + na) if na else (nq + nv,)
    try:
        size = int(np.size(x0))
    except (TypeError, ValueError):  # ragged: as_vector says what it expected
        size = -1
    x = as_vector("x0", x0, size if size in sizes else sizes[0]).copy()
    u = as_vector("u0", u0, nu).copy()
    flags = int(m.opt.disableflags)
    off = {
        "contact": bool(flags & int(_D.mjDSBL_CONTACT) or flags & int(_D.mjDSBL_CONSTRAINT)),
        "frictionloss": bool(flags & int(_D.mjDSBL_FRICTIONLOSS) or flags & int(_D.mjDSBL_CONSTRAINT)),
        "limit": bool(flags & int(_D.mjDSBL_LIMIT) or flags & int(_D.mjDSBL_CONSTRAINT)),
        "clampctrl": bool(flags & int(_D.mjDSBL_CLAMPCTRL)),
        "equality": bool(flags & int(_D.mjDSBL_EQUALITY) or flags & int(_D.mjDSBL_CONSTRAINT)),
    }
    free = _free_model(m)
    d = _forward(free, x, u)  # the smooth model's forces: no clamps
    applied = _forward(m, x, u).actuator_force  # what MuJoCo applies: clamped as the model says
    load = d.qfrc_bias - d.qfrc_passive
    tau_act = d.qfrc_actuator.copy()
    routed = np.asarray(m.jnt_actgravcomp, dtype=bool)[m.dof_jntid] if nv else np.zeros(0, dtype=bool)
    if routed.any():  # gravity compensation routed through the actuators is part of qfrc_actuator, not u0's
        tau_act[routed] -= d.qfrc_gravcomp[routed]
        load[routed] -= d.qfrc_gravcomp[routed]
    warns: list[GapWarning] = []
    dofs = _dofs(m, x, load, tau_act, off, t, warns)
    force = np.asarray(d.actuator_force, dtype=float)
    actuators = _actuators(m, u, force, np.asarray(applied), np.array(d.act), off, t, warns)
    contacts = _contacts(m, d, off, warns)
    equalities = _equalities(free, d, t, warns)
    tendons = _tendons(free, d, load, off, t, warns)
    warns.sort(key=lambda w: w.level != "error")
    return ModelGap(
        model=source,
        x0=x,
        u0=u,
        dofs=tuple(dofs),
        actuators=tuple(actuators),
        contacts=tuple(contacts),
        warnings=tuple(warns),
        thresholds=t,
        disabled=tuple(k for k, v in off.items() if v),
        equalities=tuple(equalities),
        tendons=tuple(tendons),
    )


def _dofs(
    m: mujoco.MjModel,
    x: np.ndarray,
    load: np.ndarray,
    tau_act: np.ndarray,
    off: dict[str, bool],
    t: GapThresholds,
    warns: list[GapWarning],
) -> list[DofGap]:
    rows = []
    for j in range(m.njnt):
        kind = _KINDS[int(m.jnt_type[j])]
        name = _label(m, "joint", j)
        ndof = {"free": 6, "ball": 3}.get(kind, 1)
        scalar = ndof == 1
        q = float(x[int(m.jnt_qposadr[j])]) if scalar else None
        rng = lim_margin = lim_dist = None
        mj_margin = float(m.jnt_margin[j])
        if scalar and m.jnt_limited[j] and not off["limit"]:
            lo, hi = (float(v) for v in m.jnt_range[j])
            rng = (lo, hi)
            lim_margin, lim_dist = _margin(q, lo, hi), min(q - lo, hi - q)
            _limit_warning(warns, f"joint '{name}'", q, rng, lim_dist, lim_margin, mj_margin, t)
        afr = afm = None
        if scalar and m.jnt_actfrclimited[j]:
            lo, hi = (float(v) for v in m.jnt_actfrcrange[j])
            afr = (lo, hi)
            dof = int(m.jnt_dofadr[j])
            afm = _margin(float(tau_act[dof]), lo, hi)
            _clamp_warning(
                warns, afm, t, f"joint '{name}': actuator torque {tau_act[dof]:.4g}", "actuatorfrcrange", afr
            )
        for k in range(ndof):
            dof = int(m.jnt_dofadr[j]) + k
            fl = 0.0 if off["frictionloss"] else float(m.dof_frictionloss[dof])
            ld = float(load[dof])
            ratio = None if fl == 0.0 else (fl / abs(ld) if ld != 0.0 else math.inf)
            ta = float(tau_act[dof])
            to_act = None if fl == 0.0 else (fl / abs(ta) if ta != 0.0 else math.inf)
            holds = fl > 0.0 and abs(ld) <= fl
            label = name if scalar else f"{name}.{_DOF_SUFFIXES[kind][k]}"
            if ratio is not None and ratio > t.friction:
                _friction_warning(warns, f"joint '{label}'", "load torque", fl, ld, ratio, holds, t)
            rows.append(
                DofGap(
                    name=label,
                    kind=kind,
                    q=q,
                    range=rng,
                    limit_margin=lim_margin,
                    limit_distance=lim_dist,
                    mujoco_margin=mj_margin,
                    load=ld,
                    actuator=float(tau_act[dof]),
                    frictionloss=fl,
                    friction_ratio=ratio,
                    friction_holds=holds,
                    actfrc_range=afr if k == 0 else None,
                    actfrc_margin=afm if k == 0 else None,
                    friction_to_actuator=to_act,
                )
            )
    return rows


#: A value past a range's end by at most this fraction of its width is on the edge (rounding), not outside it.
_ROUNDING = 1e-8


def _clamp_warning(
    warns: list[GapWarning], margin: float, t: GapThresholds, what: str, rng_name: str, rng: tuple[float, float]
) -> None:
    where = f"{what} against {rng_name} [{rng[0]:.4g}, {rng[1]:.4g}]"
    if -_ROUNDING <= margin < 0:  # e.g. an equilibrium input 1.5e-10 past a gripper's [-0.08, 0] (Piper's file)
        warns.append(
            GapWarning(
                "warning", "clamp", f"{where} is on its edge (past it by {-margin:.1e} of the range, a rounding error)"
            )
        )
    elif margin < 0:
        warns.append(GapWarning("error", "clamp", f"{where} is outside the range: MuJoCo clamps it"))
    elif margin < t.clamp:
        warns.append(
            GapWarning("warning", "clamp", f"{where} is {margin:.1%} of the range from a clamp (< {t.clamp:.0%})")
        )


def _actuators(
    m: mujoco.MjModel,
    u: np.ndarray,
    force: np.ndarray,
    applied: np.ndarray,
    acts: np.ndarray,
    off: dict[str, bool],
    t: GapThresholds,
    warns: list[GapWarning],
) -> list[ActuatorGap]:
    rows = []
    for a in range(m.nu):
        name = _label(m, "actuator", a)
        c = float(u[a])
        cr = cm = fr = fm = None
        if m.actuator_ctrllimited[a] and not off["clampctrl"]:
            lo, hi = (float(v) for v in m.actuator_ctrlrange[a])
            cr, cm = (lo, hi), _margin(c, lo, hi)
            _clamp_warning(warns, cm, t, f"actuator '{name}': u0 = {c:.4g}", "ctrlrange", cr)
        if m.actuator_forcelimited[a]:
            lo, hi = (float(v) for v in m.actuator_forcerange[a])
            fr, fm = (lo, hi), _margin(float(force[a]), lo, hi)
            _clamp_warning(warns, fm, t, f"actuator '{name}': force {force[a]:.4g} at u0", "forcerange", fr)
        act = ar = am = None
        adr = int(m.actuator_actadr[a])
        if adr >= 0:  # the activation's last element drives the force (MuJoCo's convention)
            act = float(acts[adr + int(m.actuator_actnum[a]) - 1])
            if m.actuator_actlimited[a]:
                lo, hi = (float(v) for v in m.actuator_actrange[a])
                ar, am = (lo, hi), _margin(act, lo, hi)
                _clamp_warning(warns, am, t, f"actuator '{name}': activation {act:.4g} at x0", "actrange", ar)
        rows.append(ActuatorGap(name, c, cr, cm, float(force[a]), fr, fm, float(applied[a]), act, ar, am))
    return rows


def _forward(m: mujoco.MjModel, x: np.ndarray, u: np.ndarray) -> mujoco.MjData:
    """``mj_forward`` of ``m`` at the state ``x`` and controls ``u`` (see :func:`model_gap` for the activations)."""
    nq, nv, na = m.nq, m.nv, m.na
    d = mujoco.MjData(m)
    d.qpos[:] = x[:nq]
    d.qvel[:] = x[nq : nq + nv]
    if na and x.size == nq + nv + na:
        d.act[:] = x[nq + nv :]
    elif na:
        for a in range(m.nu):
            adr = int(m.actuator_actadr[a])
            if adr >= 0 and int(m.actuator_dyntype[a]) != int(mujoco.mjtDyn.mjDYN_INTEGRATOR):
                d.act[adr : adr + int(m.actuator_actnum[a])] = u[a]
    d.ctrl[:] = u
    mujoco.mj_forward(m, d)
    return d


def _limit_warning(
    warns: list[GapWarning],
    what: str,
    v: float,
    rng: tuple[float, float],
    dist: float,
    frac: float,
    mj: float,
    t: GapThresholds,
) -> None:
    """The joint- or tendon-limit warning of ``what`` at ``v`` (see the module docstring)."""
    where = f"{what} at {v:.4g} (range [{rng[0]:.4g}, {rng[1]:.4g}])"
    if dist < 0:
        warns.append(GapWarning("error", "limit", f"{where} is outside its range: MuJoCo's limit pushes back"))
    elif frac < t.limit or dist < mj:
        active = " (MuJoCo's limit constraint is active)" if dist < mj else ""
        warns.append(
            GapWarning(
                "warning",
                "limit",
                f"{where} is {frac:.1%} of its range from a limit (< {t.limit:.0%}){active}: the design model has "
                "no limits",
            )
        )


def _friction_warning(
    warns: list[GapWarning], what: str, load: str, fl: float, ld: float, ratio: float, holds: bool, t: GapThresholds
) -> None:
    """The friction-loss warning of ``what`` (a joint or tendon) against its ``load`` ``ld``."""
    if holds:
        msg = (
            f"{what}: friction loss {fl:.4g} ≥ its {load} |{ld:.4g}|: friction alone holds it, a static dead band "
            f"of ±{fl:.4g} the design ignores"
        )
    else:
        msg = (
            f"{what}: friction loss {fl:.4g} is {ratio:.0%} of its {load} {ld:.4g} (> {t.friction:.0%}): the design "
            "model has no friction loss"
        )
    warns.append(GapWarning("warning", "friction", msg))


def _tendons(
    m: mujoco.MjModel,
    d: mujoco.MjData,
    load: np.ndarray,
    off: dict[str, bool],
    t: GapThresholds,
    warns: list[GapWarning],
) -> list[TendonGap]:
    """Tendons with friction loss or a range (:class:`TendonGap`); ``d`` of the model ``m``."""
    out = []
    for i in range(m.ntendon):
        fl = 0.0 if off["frictionloss"] else float(m.tendon_frictionloss[i])
        limited = bool(m.tendon_limited[i]) and not off["limit"]
        if fl == 0.0 and not limited:
            continue
        name = m.tendon(i).name or f"tendon {i}"
        J = np.zeros((1, m.nv))
        adr, nnz = int(m.ten_J_rowadr[i]), int(m.ten_J_rownnz[i])
        J[0, m.ten_J_colind[adr : adr + nnz]] = d.ten_J[adr : adr + nnz]
        MinvJt = np.zeros((1, m.nv))
        mujoco.mj_solveM(m, d, MinvJt, J)
        a = float(J[0] @ MinvJt[0])
        f_load = float(MinvJt[0] @ load) / a if a > 0.0 else 0.0
        L = float(d.ten_length[i])
        rng = margin = dist = None
        if limited:
            lo, hi = (float(v) for v in m.tendon_range[i])
            rng, margin, dist = (lo, hi), _margin(L, lo, hi), min(L - lo, hi - L)
            _limit_warning(warns, f"tendon '{name}'", L, rng, dist, margin, float(m.tendon_margin[i]), t)
        ratio = None if fl == 0.0 else (fl / abs(f_load) if f_load != 0.0 else math.inf)
        holds = fl > 0.0 and abs(f_load) <= fl
        if ratio is not None and ratio > t.friction:
            _friction_warning(warns, f"tendon '{name}'", "load force", fl, f_load, ratio, holds, t)
        out.append(TendonGap(name, L, rng, margin, dist, float(m.tendon_margin[i]), f_load, fl, ratio, holds))
    return out


def _equalities(m: mujoco.MjModel, d: mujoco.MjData, t: GapThresholds, warns: list[GapWarning]) -> list[EqualityGap]:
    """The active equality rows of ``d`` (dense ``efc_J``): violation at ``x0``, soft sag (:class:`EqualityGap`)."""
    rows = np.flatnonzero(d.efc_type[: d.nefc] == int(mujoco.mjtConstraint.mjCNSTR_EQUALITY))
    if not rows.size:
        return []
    J = np.asarray(d.efc_J[: d.nefc * m.nv]).reshape(d.nefc, m.nv)[rows]
    MinvJt = np.zeros((rows.size, m.nv))
    mujoco.mj_solveM(m, d, MinvJt, J)  # rows of (M⁻¹ Jᵀ)ᵀ
    A = J @ MinvJt.T
    kd = d.efc_KBIP[rows, 0] * d.efc_KBIP[rows, 2]
    sag = d.efc_R[rows] * np.linalg.lstsq(A, J @ d.qacc_smooth, rcond=None)[0] / kd
    pos = np.asarray(d.efc_pos)[rows]
    ids = np.asarray(d.efc_id)[rows]
    out = []
    for e in dict.fromkeys(ids.tolist()):
        mine = ids == e
        kind = mujoco.mjtEq(int(m.eq_type[e])).name.removeprefix("mjEQ_").lower()
        name = m.equality(e).name or f"equality {e} ({kind})"
        gap = EqualityGap(name, kind, float(np.abs(pos[mine]).max()), float(np.abs(sag[mine]).max()))
        out.append(gap)
        if gap.violation > t.equality:
            warns.append(
                GapWarning(
                    "warning",
                    "equality",
                    f"x0 violates equality '{name}' by {gap.violation:.3g}: MuJoCo's constraint pulls it back",
                )
            )
        if gap.sag > t.equality:
            warns.append(
                GapWarning(
                    "warning",
                    "equality",
                    f"MuJoCo's soft equality '{name}' sags by about {gap.sag:.3g} under the load at x0 (its solref/"
                    "solimp): the design model's constraint is exact",
                )
            )
    return out


def _contacts(m: mujoco.MjModel, d: mujoco.MjData, off: dict[str, bool], warns: list[GapWarning]) -> list[ContactGap]:
    if off["contact"]:
        return []
    rows = []
    for i in range(d.ncon):
        c = d.contact[i]
        if int(c.exclude) != 0:  # in the margin's gap: not a constraint
            continue
        g1, g2 = (int(g) for g in c.geom)
        rows.append(ContactGap(_geom_label(m, g1), _geom_label(m, g2), float(c.dist)))
    if rows:
        depth = max(0.0, -min(r.dist for r in rows))
        pairs = sorted({f"{r.geom1} – {r.geom2}" for r in rows})
        shown = ", ".join(pairs[:4]) + (f", … {len(pairs) - 4} more" if len(pairs) > 4 else "")
        warns.append(
            GapWarning(
                "warning",
                "contact",
                f"{len(rows)} contact{'s' if len(rows) > 1 else ''} at x0 ({shown}; max penetration {depth:.3g} m): "
                "the design model has no contacts",
            )
        )
    return rows


@functools.lru_cache(maxsize=8)
def _load(path: str, mtime_ns: int) -> mujoco.MjModel:
    with warnings.catch_warnings():  # the plant reading this file has reported MuJoCo's warnings about it once
        warnings.simplefilter("ignore", ModelWarning)
        return load_model(path)[0]


def model_gap_of_file(
    path: str | os.PathLike[str],
    x0: ArrayLike,
    u0: ArrayLike,
    *,
    thresholds: GapThresholds | None = None,
    source: str | None = None,
) -> ModelGap:
    """:func:`model_gap` of a model file as MuJoCo loads it (compiled once per file version; MuJoCo's own
    warnings while loading are not repeated: the plant that read the file reported them).

    ``source`` names the file in the report (default ``path``; e.g. the user's URDF when ``path`` is its
    MJCF translation).

    Raises:
        FileNotFoundError: no such file.
        InvalidArgument: MuJoCo cannot load it; wrong lengths (see :func:`model_gap`).
    """
    p = Path(path).resolve()
    model = _load(str(p), p.stat().st_mtime_ns)
    return model_gap(model, x0, u0, thresholds=thresholds, source=source or str(p))


def engine_model_gap(engine: MujocoEngine, *, thresholds: GapThresholds | None = None) -> ModelGap:
    """:func:`model_gap` of the model an engine simulates, at the state and controls it holds now.

    For any plant with a MuJoCo loop (a built-in plant's MuJoCo twin as much as a model file): write the
    operating point first with ``plant.engine_write(engine, x0)`` and ``plant.engine_apply(engine, u0)``.
    The engine's state is not changed.
    """
    d = engine.data
    x = np.concatenate([d.qpos, d.qvel, d.act])
    return model_gap(engine.model, x, np.array(d.ctrl), thresholds=thresholds, source=engine.source)


def plant_model_gap(
    plant: Plant,
    path: str | os.PathLike[str],
    x0: ArrayLike,
    u0: ArrayLike,
    *,
    thresholds: GapThresholds | None = None,
    source: str | None = None,
) -> ModelGap:
    """:func:`model_gap` of a model file as it is (no patch), at a plant's operating point.

    The state and controls MuJoCo sees are the ones the plant's own engine hooks write
    (``plant.engine_write(engine, x0)``, ``plant.engine_apply(engine, u0)`` on a fresh engine of the
    file), so every state layout a plant has (activations, independent coordinates of a constrained
    model, unselected actuators at 0) maps onto MuJoCo's ``[qpos; qvel; act]`` and ``ctrl`` as in its loop.

    Raises:
        FileNotFoundError: no such file.
        InvalidArgument: MuJoCo cannot load it; a state or input the plant's hooks refuse.
    """
    from shinro_ctrl.engine.core import MujocoEngine

    p = Path(path).resolve()
    engine = MujocoEngine.from_model(_load(str(p), p.stat().st_mtime_ns), source=source or str(p))
    plant.engine_write(engine, np.asarray(x0, dtype=float))
    plant.engine_apply(engine, np.asarray(u0, dtype=float))
    return engine_model_gap(engine, thresholds=thresholds)


# ----------------------------------------------------------------- format
#: Values printed as 0 (rounding residue of a load or torque that vanishes, e.g. about a vertical axis).
_TINY = 1e-12


def _f(v: float | None, fmt: str = ".4g") -> str:
    if v is None:
        return "—"
    if math.isinf(v):
        return "inf" if v > 0 else "-inf"
    return format(0.0 if abs(v) < _TINY else v, fmt)


def _pct(v: float | None) -> str:
    return "—" if v is None else ("-inf" if math.isinf(v) else f"{100 * v:.1f}%")


def _rng(r: tuple[float, float] | None) -> str:
    return "—" if r is None else f"[{r[0]:.4g}, {r[1]:.4g}]"


def _columns(head: list[str], rows: list[list[str]]) -> list[str]:
    widths = [max(len(h), *(len(r[k]) for r in rows)) for k, h in enumerate(head)]

    def line(cells: list[str]) -> str:
        return "    " + "  ".join(
            c.ljust(w) if k == 0 else c.rjust(w) for k, (c, w) in enumerate(zip(cells, widths, strict=True))
        )

    return [line(head), *(line(r) for r in rows)]


def _dof_table(dofs: tuple[DofGap, ...]) -> list[str]:
    if not dofs:
        return []
    rows = []
    for g in dofs:
        fr = "—" if g.friction_ratio is None else (_pct(g.friction_ratio) if math.isfinite(g.friction_ratio) else "inf")
        rows.append(
            [
                g.name,
                _f(g.q),
                _rng(g.range),
                _pct(g.limit_margin),
                _f(g.load),
                _f(g.actuator),
                _f(g.frictionloss) if g.frictionloss else "—",
                fr + (" holds" if g.friction_holds else ""),
            ]
        )
    head = ["joint", "q", "range", "limit margin", "load τ", "actuator τ", "frictionloss", "friction/load"]
    out = ["  joints (load τ = qfrc_bias − qfrc_passive; actuator τ at u0, smooth model):"]
    out += _columns(head, rows)
    limited = [g for g in dofs if g.actfrc_range is not None]
    if limited:
        out.append(
            "    actuatorfrcrange: "
            + ", ".join(f"{g.name} {_rng(g.actfrc_range)} margin {_pct(g.actfrc_margin)}" for g in limited)
        )
    return out


def _actuator_table(actuators: tuple[ActuatorGap, ...]) -> list[str]:
    if not actuators:
        return []
    rows = [
        [
            a.name,
            _f(a.ctrl),
            _rng(a.ctrlrange),
            _pct(a.ctrl_margin),
            _f(a.force),
            _rng(a.forcerange),
            _pct(a.force_margin),
        ]
        for a in actuators
    ]
    head = ["actuator", "u0", "ctrlrange", "margin", "force", "forcerange", "margin"]
    if any(a.act is not None for a in actuators):
        head += ["act", "actrange", "margin"]
        for r, a in zip(rows, actuators, strict=True):
            r += [_f(a.act), _rng(a.actrange), _pct(a.act_margin)]
    return ["  actuators (force at u0, smooth model: MuJoCo clamps to the ranges):", *_columns(head, rows)]
