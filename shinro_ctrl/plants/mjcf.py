r"""Bring your own robot: any MJCF/URDF tree of hinge, slide, ball and free joints as a plant.

:class:`MjcfPlant` reads the model file once (MuJoCo compiles it; the
reader ``shinro_ctrl.engine.model_tree`` is the one module of the engine
package a plant may import) and builds the exact equations of motion from
the kinematic tree with :class:`~shinro_ctrl.multibody.RigidBodyTree`:

.. math::

    \dot x = \begin{bmatrix} \dot q \\
        (M(q) + \operatorname{diag}(a))^{-1}\,(\tau(q, \dot q, u, a_{act}) - c(q, \dot q)) \\
        \dot a_{act}(u, a_{act}) \end{bmatrix},
    \qquad x = [q; \dot q; a_{act}],

with ``τ`` every applied generalized force (actuators through their
transmissions, joint and tendon springs and dampers, gravity compensation;
``RigidBodyTree.generalized_forces``) and ``a_act`` the actuator activations
(none for actuators without activation dynamics).

The expression is a CasADi ``SX`` graph, so ``symbolic()``, ``get_model()``
and everything downstream work unchanged. Numeric ``dynamics()`` and exact
``linearize()`` evaluate machine code: ``f`` and its exact Jacobians (by
differentiating the inverse dynamics, see
:meth:`~shinro_ctrl.multibody.RigidBodyTree.xdot_jacobians_sx`) generated to
C and compiled once by :func:`shinro_ctrl.codegen.compiled_by_key` (``f`` at
construction, the Jacobians at the first ``linearize``), cached on disk under
a key of the model's numbers and the code that builds them, so another
process loading the same model loads the libraries in milliseconds; CasADi's
virtual machine, with a one-line ``CompilerUnavailable`` warning, when no C
compiler can build them. One library serves every actuator selection. The MuJoCo engine
loads the same file (:meth:`MjcfPlant.mjcf_patch` edits nothing but the
timestep), so the state map is the identity.

With equality constraints the state is the independent coordinates and the
dynamics the exact KKT system (:mod:`shinro_ctrl.multibody.constraints`; see the class).

What the symbolic model leaves out, because it is not smooth dynamics:
contacts, joint-limit constraint forces, joint and tendon friction loss,
and MuJoCo's ``ctrlrange`` / ``forcerange`` / ``actrange`` clamps. Keep
trajectories inside the joint ranges and the inputs inside their ranges
(the controller's bounds), or compare with care.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import json
import math
import os
import threading
import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Protocol

import casadi as cs
import numpy as np

from shinro_ctrl.backend import ArrayBackend, CasadiBackend
from shinro_ctrl.codegen import compiled_by_key
from shinro_ctrl.errors import InvalidArgument, NonFiniteError, UnknownName
from shinro_ctrl.linearization import LinearModel, discretize
from shinro_ctrl.multibody import RigidBodyTree, configuration
from shinro_ctrl.multibody.constraints import ConstrainedDynamics
from shinro_ctrl.multibody.contacts import (
    MIN_NORMAL_SHARE,
    TANGENTIAL_WEIGHT,
    ContactFrame,
    StandingEquilibrium,
    check_conditioning,
    contact_constraints,
    standing_equilibrium,
)
from shinro_ctrl.plants.base import MjcfPatch, Plant
from shinro_ctrl.validation import as_vector, check_positive, closest

if TYPE_CHECKING:
    from numpy.typing import ArrayLike

    from shinro_ctrl.engine.model_gap import GapThresholds, ModelGap
    from shinro_ctrl.engine.model_tree import RobotModel
    from shinro_ctrl.multibody import ModelTree

__all__ = ["MODEL_SUFFIXES", "MjcfPlant", "is_model_file"]

MODEL_SUFFIXES = (".xml", ".mjcf", ".urdf")

#: How far a user's quaternion's norm may be from 1 to be normalized (with a note) rather than refused.
QUATERNION_TOLERANCE = 1e-6

#: How far inside a joint's range (as a fraction of its width) the default operating point moves a ``qpos0``
#: that lies outside the range, or on its edge.
RANGE_MARGIN = 0.01


def is_model_file(name: object) -> bool:
    """Whether ``name`` names a model file rather than a plant class.

    True for an MJCF/URDF suffix in any case (``.xml``, ``.mjcf``, ``.urdf``,
    ``.XML`` ...), and for an existing file of another name whose content is
    MJCF or URDF (``shinro_ctrl.engine.model_tree.model_kind``).
    """
    if not isinstance(name, str | os.PathLike) or isinstance(name, bytes):
        return False
    p = Path(os.fspath(name))
    if p.suffix.lower() in MODEL_SUFFIXES:
        return True
    if p.suffix.lower() == ".toml" or not p.is_file():
        return False
    from shinro_ctrl.engine.model_tree import model_kind

    try:
        model_kind(p)
    except (InvalidArgument, OSError):
        return False
    return True


def _floating_names(tree: ModelTree, joint_names: Sequence[str]) -> tuple[list[str], list[str], list[str]]:
    """``(qpos names, qvel names, tangent position names)`` of a tree with ball or free joints.

    A free joint ``root``: ``root_x, root_y, root_z, root_qw, root_qx, root_qy, root_qz``; velocities
    ``root_vx, root_vy, root_vz`` (world) and ``root_wx, root_wy, root_wz`` (body); the tangent
    positions ``root_x, root_y, root_z, root_rx, root_ry, root_rz`` (a rotation vector in the body
    frame). A ball ``b``: ``b_qw .. b_qz``, ``b_wx .. b_wz``, ``b_rx .. b_rz``.
    """
    qn: list[str] = []
    vn: list[str] = []
    tn: list[str] = []
    for j, name in zip(tree.joints, joint_names, strict=True):
        if j.type == "free":
            lin = [f"{name}_{c}" for c in "xyz"]
            qn += [*lin, *(f"{name}_q{c}" for c in "wxyz")]
            vn += [*(f"{name}_v{c}" for c in "xyz"), *(f"{name}_w{c}" for c in "xyz")]
            tn += [*lin, *(f"{name}_r{c}" for c in "xyz")]
        elif j.type == "ball":
            qn += [f"{name}_q{c}" for c in "wxyz"]
            vn += [f"{name}_w{c}" for c in "xyz"]
            tn += [f"{name}_r{c}" for c in "xyz"]
        else:
            qn.append(name)
            vn.append(f"{name}_dot")
            tn.append(name)
    return qn, vn, tn


def _qpos0(tree: ModelTree) -> np.ndarray:
    """MuJoCo's ``qpos0``: each hinge's and slide's reference, a free body's model pose, a ball's identity."""
    out: list[float] = []
    for j in tree.joints:
        if j.type == "free":
            b = tree.bodies[j.body]
            quat = np.asarray(b.quat, dtype=float)
            out += [*np.asarray(b.pos, dtype=float).tolist(), *(quat / np.linalg.norm(quat)).tolist()]
        elif j.type == "ball":
            out += [1.0, 0.0, 0.0, 0.0]
        else:
            out.append(float(j.qpos0))
    return np.array(out)


@functools.lru_cache(maxsize=16)
def _read(source: str, mtime_ns: int) -> tuple[RobotModel, RigidBodyTree]:
    """Read one model file version once: the checked model and its dynamics builder."""
    # the agreed exception to the layering: the model reader lives in the engine package
    from shinro_ctrl.engine.model_tree import read_robot

    robot = read_robot(source)
    return robot, RigidBodyTree(robot.tree)


@functools.lru_cache(maxsize=16)
def _symbolic(source: str, mtime_ns: int, active: tuple[int, ...]) -> cs.Function:
    """The CasADi ``SX`` function ``f(x, u) -> xdot`` of one model file version and actuator selection."""
    robot, rb = _read(source, mtime_ns)
    x = cs.SX.sym("x", robot.tree.nq + robot.tree.nv + robot.tree.na)
    u = cs.SX.sym("u", len(active))
    return cs.Function("f", [x, u], [rb.xdot_sx(x, u, active)], ["x", "u"], ["xdot"])


@functools.lru_cache(maxsize=16)
def _constrained(
    source: str,
    mtime_ns: int,
    active: tuple[int, ...],
    q_ref: tuple[float, ...],
    what: str,
    contacts: tuple[str, ...] = (),
) -> ConstrainedDynamics:
    """The constrained dynamics of one model file version, actuator selection, reference and contacts (built once).

    The contacts' constraints (:func:`~shinro_ctrl.multibody.contacts.contact_constraints`) follow the model's
    equalities and hold each contact where it is at ``q_ref`` (first projected onto the equalities).
    """
    from shinro_ctrl.engine.model_tree import read_contact_frames

    robot, rb = _read(source, mtime_ns)
    frames = read_contact_frames(robot.path) if contacts else {}
    q = np.array(q_ref)
    equalities = list(robot.tree.equalities)
    if contacts and equalities:
        q = ConstrainedDynamics(rb, equalities, active=active, q_ref=q, what=what).q_ref
    constraints = equalities + contact_constraints(rb, [frames[c] for c in contacts], q)
    # compiled at the first linearize, keyed by the model's numbers and code (+ the constraints, rows, coordinates)
    key = _model_key(robot.tree, "constrained")
    return ConstrainedDynamics(rb, constraints, active=active, q_ref=q, what=what, compile_key=key)


@functools.lru_cache(maxsize=1)
def _code_fingerprint() -> str:
    """A hash of the source of every module that shapes the compiled expressions (part of their cache key)."""
    pkg = Path(__file__).resolve().parent.parent
    files = [pkg / "_scalar_algebra.py", Path(__file__).resolve(), *sorted((pkg / "multibody").glob("*.py"))]
    return hashlib.sha256(b"".join(f.read_bytes() for f in files)).hexdigest()


def _model_key(tree: ModelTree, what: str) -> str:
    """What a compiled function of ``tree`` depends on: its numbers (not its name or path) and the code."""
    desc = dataclasses.asdict(tree)
    desc.pop("path", None)
    desc.pop("name", None)
    text = json.dumps(desc, sort_keys=True, default=lambda o: o.tolist() if hasattr(o, "tolist") else repr(o))
    return f"{what}|{_code_fingerprint()}|{text}"


@functools.lru_cache(maxsize=16)
def _function(source: str, mtime_ns: int) -> cs.Function:
    """The compiled ``f(x, u_all) -> (xdot, s)`` of one model file version, ``u_all`` every actuator's control.

    One library serves every actuator selection (the plant scatters its
    inputs into ``u_all``, zeros elsewhere). ``s`` is the sum of every entry
    of ``x``, ``u_all`` and ``xdot``, computed in C: finite unless one of them
    is NaN or inf (or the sum overflows), the fast path's finiteness check.
    See :mod:`shinro_ctrl.codegen`; the CasADi virtual machine when no
    compiler can build it.
    """
    robot, rb = _read(source, mtime_ns)
    every = tuple(range(robot.tree.nu))

    def build() -> cs.Function:
        x = cs.SX.sym("x", robot.tree.nq + robot.tree.nv + robot.tree.na)
        u = cs.SX.sym("u", robot.tree.nu)
        xdot = rb.xdot_sx(x, u, every)
        total = cs.sum1(x) + cs.sum1(u) + cs.sum1(xdot)
        return cs.Function("mjcf_f", [x, u], [xdot, total], ["x", "u"], ["xdot", "sum"])

    return compiled_by_key("mjcf_f", _model_key(robot.tree, "f"), build)


@functools.lru_cache(maxsize=16)
def _jacobian_function(source: str, mtime_ns: int) -> cs.Function:
    """The compiled exact Jacobians ``(x, u_all) -> (Aᵀ, B_allᵀ, s)``.

    Transposed, so that their column-major nonzeros are ``A``'s and
    ``B_all``'s row-major entries; ``s`` is the sum of all their entries and
    of ``x`` and ``u_all``, computed in C: finite unless one is NaN or inf (or
    the sum overflows), the cheap finiteness check of :meth:`MjcfPlant.linearize`.
    """
    robot, rb = _read(source, mtime_ns)
    every = tuple(range(robot.tree.nu))

    def build() -> cs.Function:
        x = cs.SX.sym("x", robot.tree.nq + robot.tree.nv + robot.tree.na)
        u = cs.SX.sym("u", robot.tree.nu)
        A, B = rb.xdot_jacobians_sx(x, u, every)
        total = cs.sum1(cs.sum2(A)) + cs.sum1(cs.sum2(B)) + cs.sum1(x) + cs.sum1(u)
        return cs.Function("mjcf_jac", [x, u], [A.T, B.T, total], ["x", "u"], ["A_T", "B_T", "sum"])

    return compiled_by_key("mjcf_jac", _model_key(robot.tree, "jac"), build)


class _CompiledJacobian:
    """``(A, B)`` at ``(x, u)`` from the compiled Jacobian function, compiled on the first call.

    Stands where :class:`~shinro_ctrl.linearization.ExactJacobian` stands for
    other plants (``Plant.linearize`` calls it). Threads: each thread
    evaluates in its own buffer; the first build is behind a lock.
    """

    def __init__(self, source: str, mtime_ns: int, nx: int, nu: int, active: tuple[int, ...]):
        self._key = (source, mtime_ns)
        self._nx, self._nu, self._active = nx, nu, active
        self._fun: cs.Function | None = None
        self._lock = threading.Lock()
        self._local = threading.local()

    def set_params(self, p: np.ndarray) -> None:
        """``MjcfPlant`` has no parameters: nothing to bind."""

    def _buffers(self) -> _Buffers:
        try:
            return self._local.buffers
        except AttributeError:
            pass
        if self._fun is None:
            with self._lock:
                if self._fun is None:
                    self._fun = _jacobian_function(*self._key)
        b = self._local.buffers = _Buffers(
            self._fun, self._nu, self._active, ((self._nx, self._nx), (self._nx, self._nu), (1,))
        )
        return b

    def __call__(self, x0: np.ndarray, u0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return self.evaluate(x0, u0)[:2]

    def evaluate(self, x0: np.ndarray, u0: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
        """``(A, B, s)``: fresh Jacobians and the sum of all entries of ``A``, ``B_all``, ``x0`` and ``u_all``."""
        b = self._buffers()
        b.set(x0, u0)
        b.run()
        A, B, s = b.out
        return A.copy(), (B.copy() if b.every else B[:, list(self._active)]), float(s[0])


class MujocoEngine(Protocol):
    """What :class:`MjcfPlant`'s engine hooks use of a ``shinro_ctrl.engine.MujocoEngine`` (duck-typed)."""

    model: object
    data: object

    def get_state_vector(self) -> np.ndarray: ...

    def set_state_vector(self, x: np.ndarray) -> None: ...

    def set_ctrl(self, u: np.ndarray) -> None: ...


class _Buffers:
    """One thread's arrays bound to a compiled function's ``FunctionBuffer`` (inputs ``x``, ``u_all``).

    The plant's inputs ``u`` (the selected actuators) are scattered into
    ``u_all``; the other actuators' controls stay 0.
    """

    __slots__ = ("active", "buf", "every", "out", "run", "u", "x")

    def __init__(self, fun: cs.Function, nu: int, active: tuple[int, ...], shapes: tuple[tuple[int, ...], ...]):
        self.x = np.zeros(fun.size1_in(0))
        self.u = np.zeros(nu)
        self.active = np.array(active, dtype=int)
        self.every = active == tuple(range(nu))
        self.out = tuple(np.zeros(shape) for shape in shapes)
        self.buf, self.run = fun.buffer()
        self.buf.set_arg(0, memoryview(self.x))
        self.buf.set_arg(1, memoryview(self.u))
        for k, a in enumerate(self.out):
            self.buf.set_res(k, memoryview(a.reshape(-1)))

    def set(self, x: np.ndarray, u: np.ndarray) -> None:
        """Copy ``x`` and the selected inputs ``u`` into the bound arrays."""
        self.x[:] = x
        if self.every:
            self.u[:] = u
        else:
            self.u[self.active] = u


class MjcfPlant(Plant):
    """A plant whose dynamics come from an MJCF (or URDF) model file.

    State ``x = [qpos; qvel]`` ``(2 nq,)`` in MuJoCo's joint order, named
    after the joints (``shoulder``, …, ``shoulder_dot``, …), followed by
    the actuator activations ``act`` ``(na,)`` in MuJoCo's order (named
    ``<actuator>_act``) when actuators have activation dynamics; inputs
    ``u`` the selected actuators' controls, named after the actuators. The
    physics are the model's: bodies with full inertia tensors and off-axis
    centres of mass, joint damping, stiffness and armature, fixed tendons
    with their springs and dampers, gravity and gravity compensation
    (``gravcomp``), and actuators with a joint, fixed-tendon or site
    transmission (``motor``, ``position``/``velocity`` servos through their
    gains and biases, ``general`` with fixed/affine gain and bias; filter,
    filterexact and integrator activation dynamics; see
    :mod:`shinro_ctrl.multibody.transmission`).

    Kept out of the smooth model, though MuJoCo applies them in its loop:
    joint and tendon ``frictionloss`` (recorded in ``tree.joints[i].frictionloss``),
    joint and tendon limits, contacts, and the ``ctrlrange``,
    ``forcerange`` and ``actrange`` clamps. :attr:`state_bounds` are the
    joint ranges of the limited joints (±inf elsewhere): the standalone step
    stops there, and controllers that take state bounds get them.

    The file's kind is read from its content (``<mujoco>`` or ``<robot>``),
    whatever its name. Everything in it the plant cannot model (stiffness or
    a joint actuator on a ball or free joint, tendon or inactive equality constraints, spatial tendons that act,
    fluid forces, an unsupported actuator ...) and every invalid number (a
    ``NaN`` gravity, an infinite mass) is refused in one error that lists them
    all by element name, with the reason and the fix where one exists.

    Equality constraints (``<joint>`` couplings and URDF ``<mimic>``,
    ``<connect>``, ``<weld>``) are exact constrained dynamics, held in
    :attr:`constraints` (a :class:`~shinro_ctrl.multibody.constraints.ConstrainedDynamics`,
    None without equalities) and delegated to: the state is then
    ``[q_I; q̇_I]``, the *independent* joints chosen at the reference
    configuration (first keyframe, else ``qpos0``, projected onto the
    constraints), named after them; :meth:`dynamics` completes the dependent
    joints by Newton and solves the KKT system; :meth:`linearize` gives the
    exact Jacobians by the implicit function theorem; :meth:`symbolic`
    unrolls the Newton steps in ``SX``; the engine hooks read the independent
    joints and complete the dependent ones when writing. ``x0`` may then be
    ``[q_I; q̇_I]`` or a full ``[qpos; qvel]`` that satisfies the constraints;
    the keyframe is projected onto them (refused, naming the constraint, when
    it cannot be). ``engine_state_map`` (``crosscheck``) does not apply.

    A URDF file carries no actuators: its inputs are joint torques (forces
    for prismatic joints), one motor per joint named after the joint, in an
    MJCF translation that both the plant and the engine load (see
    ``shinro_ctrl.engine.model_tree.urdf_with_motors``); messages name the
    URDF and its elements, never the translation. MuJoCo welds a URDF's root
    link to the world: when that root carries mass and several moving
    branches (a legged or wheeled robot meant to float), the plant says so
    with a :class:`~shinro_ctrl.engine.warnings.ModelWarning`.

    ``MjcfPlant`` has no float physical parameters: the model file is the
    parameter. ``param_names`` is empty, ``params()`` is ``{}`` and
    ``symbolic(params=True)`` takes an empty ``p``; to change the physics,
    edit the file.

    Threads: :meth:`dynamics`, :meth:`linearize`, :meth:`equilibrium_input`
    and the other model methods may be called from any number of threads at
    once: each thread evaluates the compiled dynamics and the compiled exact
    Jacobians in its own buffers (created on its first call; the first
    compilation is behind a lock). :meth:`step` and the state belong to one thread (see
    :class:`~shinro_ctrl.plants.base.Plant`).

    **Floating bases.** Free and ball joints hold unit quaternions: the
    state is MuJoCo's ``[qpos; qvel; act]`` with ``nq ≠ nv`` (a free joint
    ``root``: ``root_x .. root_z, root_qw .. root_qz``, then the world
    velocity ``root_vx ..`` and the body rates ``root_wx ..``), stepped on
    the manifold. The linear models live in the tangent space of
    :attr:`tangent_dim` ``= 2 nv + na`` coordinates (:meth:`difference`,
    :meth:`retract`, :meth:`tangent_maps`; MuJoCo's ``mj_differentiatePos``
    / ``mj_integratePos`` and ``mjd_transitionFD`` conventions). A user's
    quaternion within :data:`QUATERNION_TOLERANCE` of unit norm is
    normalized with a warning, else refused. With ``contacts`` on a floating
    base (a legged robot standing on its feet) the constrained dynamics live in
    the tangent space and the base's rotations are always dependent, so the
    state is again a flat ``[q_I; v_I]`` of joint coordinates (the trunk's pose
    is completed from the feet) and :attr:`floating` is False; a base that its
    contacts leave free to rotate is refused in one line.

    Args:
        model: MJCF/URDF path, or the name of a shipped asset; default the
            shipped Furuta pendulum ``"furuta_pendulum.xml"`` (so that
            ``MjcfPlant()`` works like every other plant's defaults).
        actuators: Names of the actuators that are the inputs, in this order;
            None: all, in the model's order. Actuators left out get control 0.
        dt: Step [s]; default the model's ``opt.timestep``.
        x0: Operating state ``(2 nq + na,)``; default the model's first
            keyframe (``[key qpos; key qvel; key act]``), else ``[qpos0; 0]``
            with every joint whose ``qpos0`` lies outside its range (or on
            its edge) moved inside it, :data:`RANGE_MARGIN` of the range's
            width from the nearer end, and the activations that hold it
            there when there are any (else 0). Must lie within the joint
            ranges.
        u0: Operating input ``(m,)``; default :meth:`equilibrium_input` at
            ``x0`` when the actuators can hold it there (gravity
            compensation), else zeros.
        backend: The seed's keyword, accepted and not used.

    Raises:
        FileNotFoundError: no such file or shipped asset.
        InvalidArgument: a file that is not MJCF/URDF or that MuJoCo cannot
            load; unsupported features or invalid numbers (all listed at
            once); no actuators, an unknown actuator name; a bad ``dt`` or
            ``u0``; an ``x0`` (or keyframe) outside a joint's range (naming
            the joint) or off the equality constraints (naming the constraint).
    """

    def __init__(
        self,
        model: str | os.PathLike[str] = "furuta_pendulum.xml",
        *,
        actuators: Sequence[str] | None = None,
        dt: float | None = None,
        x0: ArrayLike | None = None,
        u0: ArrayLike | None = None,
        contacts: Sequence[str] | None = None,
        backend: ArrayBackend | None = None,
    ):
        from shinro_ctrl.engine.model_tree import resolve_model_path

        source = resolve_model_path(model)
        mtime = source.stat().st_mtime_ns
        robot, rb = _read(str(source), mtime)
        for note in robot.notes:
            from shinro_ctrl.engine.model_tree import ModelWarning

            warnings.warn(ModelWarning(note), stacklevel=2)
        tree = robot.tree
        names = [a.name for a in tree.actuators]
        if actuators is None:
            active = tuple(range(tree.nu))
        else:
            if isinstance(actuators, str) or not all(isinstance(a, str) for a in actuators) or not actuators:
                raise InvalidArgument(f"actuators must be a non-empty list of actuator names, got {actuators!r}")
            active_list = []
            for a in actuators:
                if a not in names:
                    near = closest(a, names)
                    hint = f" (did you mean '{near}'?)" if near else ""
                    raise UnknownName(f"unknown actuator {a!r}{hint}; actuators in the model: {', '.join(names)}")
                active_list.append(names.index(a))
            if len(set(active_list)) != len(active_list):
                raise InvalidArgument(f"actuators lists a name twice: {list(actuators)!r}")
            active = tuple(active_list)
        self.tree, self.rigid_body_tree = tree, rb
        self.source_path = str(robot.source)  # the user's file (a URDF itself for a URDF)
        self.joint_names = tuple(j.name or f"q{i}" for i, j in enumerate(tree.joints))
        self.constraints: ConstrainedDynamics | None = None
        self.contacts = self._contact_frames(robot.path, contacts)
        if (tree.equalities or self.contacts) and tree.na:
            dyn = ", ".join(f"'{a.name or f'u{k}'}' ({a.dyntype})" for k, a in enumerate(tree.actuators) if a.act >= 0)
            raise InvalidArgument(
                f"{self._label()}: activation dynamics on actuators {dyn} with equality constraints are not "
                'supported yet; give those actuators dyntype="none" or remove the equality constraints'
            )
        if tree.equalities or self.contacts:  # exact constrained dynamics in the independent coordinates
            ref, key = self._default_x0(robot.keyframe), robot.keyframe
            what = f"{self._label()}: " + (f"keyframe '{key[0]}'" if key and key[0] else "the reference (qpos0)")
            self.constraints = _constrained(
                str(source), mtime, active, tuple(ref[: tree.nq]), what, tuple(f.name for f in self.contacts)
            )
        else:
            self._fun = _function(str(source), mtime)  # compiled: u_all, every actuator's control
        self.model_path = str(robot.path)  # the file plant and engine load (a URDF's translation)
        self.asset = self.model_path  # the engine loads the same file
        self.active_actuators = active
        nq = tree.nq
        free = self.constraints.independent if self.constraints else range(nq)
        acts = sorted((a.act, a.name or f"u{k}") for k, a in enumerate(tree.actuators) if a.act >= 0)
        # with constraints the design state [q_I; v_I] is flat even on a floating base (its rotations are dependent)
        self.floating = tree.floating and self.constraints is None
        _, dof_vel, dof_pos = _floating_names(tree, self.joint_names)  # per degree of freedom
        if self.floating:  # quaternions: [qpos; qvel] with nq != nv (see the class docstring)
            qn, vn, tn = _floating_names(tree, self.joint_names)
            self.state_names = (*qn, *vn, *(f"{name}_act" for _, name in acts))
            self._tangent_names = (*tn, *vn, *(f"{name}_act" for _, name in acts))
            # the plain coordinates and their rates (the quaternions are stepped on the manifold)
            qi, vi = configuration.plain_indices(tree)
            self.position_indices = tuple(qi)
            self.velocity_indices = tuple(nq + i for i in vi)
        else:
            self.state_names = (
                *(dof_pos[i] for i in free),
                *(dof_vel[i] for i in free),
                *(f"{name}_act" for _, name in acts),
            )
            self._tangent_names = self.state_names
            nq = len(free)  # the design coordinates
            self.position_indices = tuple(range(nq))
            self.velocity_indices = tuple(range(nq, 2 * nq))
        self.input_names = tuple(names[k] or f"u{k}" for k in active)
        self._local = threading.local()  # per-thread evaluation buffers (see the class docstring)
        self.state_bounds = self._joint_range_bounds()
        self._init(dt=tree.timestep if dt is None else check_positive("dt", dt), params={}, backend=backend)
        self._key = (str(source), mtime, active)
        self._jacobian: _CompiledJacobian | None = None
        if self.constraints is None:  # compiled at the first linearize (a constrained model: see linearize)
            self._jacobian = _CompiledJacobian(str(source), mtime, self.state_dim, tree.nu, active)
            self._exact = self._jacobian  # what Plant.linearize's general path calls
        if self.constraints is not None:
            self._x0 = self._constrained_x0(robot.keyframe, x0)
        elif x0 is None:
            self._x0 = self._default_x0(robot.keyframe)
            held = self._hold_activations(self._x0) if tree.na and robot.keyframe is None else None
            if held is not None:
                self._x0 = held[0]
        else:
            self._x0 = self._user_state(x0, "x0")
            self._check_in_range(self._x0, "x0")
        if self.contacts:  # a warning when a contact row barely constrains anything (contacts.py)
            check_conditioning(
                self.constraints, self.contacts, self.constraints.q_ref, what=f"{self._label()}: contacts"
            )
        if u0 is not None:
            self._u0 = as_vector("u0", u0, self.input_dim).copy()
        elif self.contacts:
            self._u0 = self.standing_equilibrium().u
        else:
            self._u0 = self._default_u0()
        self.state = self._x0.copy()

    # ------------------------------------------------------------ contacts
    def _contact_frames(self, path: Path, contacts: Sequence[str] | None) -> tuple[ContactFrame, ...]:
        """The named contacts, checked (unknown names listed with the valid ones; no repeats)."""
        if contacts is None:
            return ()
        if isinstance(contacts, str) or not all(isinstance(c, str) for c in contacts):
            raise InvalidArgument(
                f"contacts must be a list of geom, site or body names, got {contacts!r} (e.g. ['FL_foot', 'FR_foot'])"
            )
        if len(set(contacts)) != len(contacts):
            raise InvalidArgument(f"contacts lists a name twice: {list(contacts)!r}")
        from shinro_ctrl.engine.model_tree import read_contact_frames

        frames = read_contact_frames(path)
        out = []
        for c in contacts:
            if c not in frames:
                near = closest(c, list(frames))
                hint = f" (did you mean '{near}'?)" if near else ""
                valid = ", ".join(f"{f.name} ({f.element})" for f in frames.values())
                raise UnknownName(
                    f"{self._label()}: unknown contact {c!r}{hint}; the model's geoms, sites and bodies: {valid}"
                )
            out.append(frames[c])
        return tuple(out)

    def _full_state(self, x: ArrayLike | None) -> np.ndarray:
        """The full ``[qpos; qvel]`` of a design state (default the operating state)."""
        x = as_vector("x", self._x0 if x is None else x, self.state_dim)
        return x if self.constraints is None else self.constraints.complete(x, what=f"{self._label()}: x")

    def standing_equilibrium(
        self,
        posture: ArrayLike | None = None,
        *,
        min_share: float = MIN_NORMAL_SHARE,
        tangential_weight: float = TANGENTIAL_WEIGHT,
    ) -> StandingEquilibrium:
        """The inputs and contact forces that hold a posture still, inside the friction cones and actuator ranges.

        See :func:`shinro_ctrl.multibody.contacts.standing_equilibrium` (a QP: least ``‖u‖²``, contact
        forces inside the inner friction pyramid, each contact's normal force at least ``min_share`` of the even
        share of the load, ``u`` inside the ``ctrlrange``).

        Args:
            posture: Design state ``[q_I; q̇_I]`` or a full ``qpos (nq,)`` (projected onto the contacts:
                the nearest configuration that keeps every contact where it is); default the operating state.
            min_share: ``α ∈ [0, 1]``: each contact carries at least ``α Σ_j f_z,j / N_b`` over the ``N_b``
                contacts on its body (keeps the centre of pressure of a foot with several contact points off
                its edge; 0: only ``f_z ≥ 0``; no effect on a body's only contact).
            tangential_weight: Weight of the contacts' tangential forces ``‖f_t‖²`` beside ``‖u‖²`` (a sustained
                tangential force makes a soft contact creep; 0: least torque only).

        Raises:
            InvalidArgument: no contacts; a posture off the contacts that cannot be projected.
            EquilibriumNotFound: none exists; the one-line message names the failing constraint
                (``posture``, ``friction``, ``torque`` or ``support``).
        """
        if not self.contacts:
            raise InvalidArgument(
                f"{self._label()}: standing_equilibrium needs contacts (MjcfPlant(..., contacts=[...]))"
            )
        cd = self.constraints
        if posture is not None and np.size(posture) == self.tree.nq:
            q = cd.project(as_vector("posture", posture, self.tree.nq), what=f"{self._label()}: posture")
        else:
            xi = self._x0 if posture is None else as_vector("posture", posture, self.state_dim)
            q = cd.complete(np.r_[xi[: cd.ni], np.zeros(cd.ni)], what=f"{self._label()}: posture")[: self.tree.nq]
        return standing_equilibrium(
            cd,
            self.contacts,
            q,
            self.active_actuators,
            self.input_bounds(),
            min_share=min_share,
            tangential_weight=tangential_weight,
            what=f"{self._label()}: the standing equilibrium",
        )

    def contact_forces(self, x: ArrayLike | None = None, u: ArrayLike | None = None) -> dict[str, np.ndarray]:
        """Each contact's world-frame force ``(3,)`` (point) or wrench ``(6,)`` (flat) at ``(x, u)``.

        The KKT forces, split over redundant rows by least norm
        (:meth:`ConstrainedDynamics.constraint_forces`); default the operating point.
        """
        if not self.contacts:
            raise InvalidArgument(f"{self._label()}: contact_forces needs contacts (MjcfPlant(..., contacts=[...]))")
        full = self._full_state(x)
        u = as_vector("u", self._u0 if u is None else u, self.input_dim)
        forces = self.constraints.constraint_forces(full, u)[-len(self.contacts) :]
        return {f.name: w for f, w in zip(self.contacts, forces, strict=True)}

    # ------------------------------------------------------------ limits
    def input_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """``(u_min (m,), u_max (m,))``: the ``ctrlrange`` of each selected actuator that clamps its control.

        ±inf for an actuator without one (``ctrllimited`` false, or clamping disabled by
        ``<flag clampctrl="disable"/>``). A ``forcerange`` limits the force, not the control: it is not a
        bound on ``u`` (the MuJoCo loop counts it as saturation where it binds).
        """
        m = self.input_dim
        lo, hi = np.full(m, -np.inf), np.full(m, np.inf)
        for k, a in enumerate(self.active_actuators):
            rng = self.tree.actuators[a].ctrlrange
            if rng is not None:
                lo[k], hi[k] = rng
        return lo, hi

    # ------------------------------------------------------------ operating
    def _default_x0(self, keyframe: tuple[str, np.ndarray] | None) -> np.ndarray:
        """The first keyframe, else ``[qpos0; 0]`` moved inside the joint ranges (see the class docstring)."""
        if keyframe is not None:
            name, x = keyframe
            self._check_in_range(x, f"keyframe '{name}'" if name else "the model's first keyframe")
            return x.copy()
        x = np.r_[_qpos0(self.tree), np.zeros(self.tree.nv + self.tree.na)]
        for i, j in zip(self.tree.qposadr, self.tree.joints, strict=True):
            if j.limited and j.type in ("hinge", "slide"):
                lo, hi = j.range
                margin = RANGE_MARGIN * (hi - lo)
                x[i] = min(max(x[i], lo + margin), hi - margin)
        return x

    def _user_state(self, x: ArrayLike, what: str) -> np.ndarray:
        """A user's full state ``[qpos; qvel; act]``: its length checked (naming ``nq``), its quaternions made unit.

        A quaternion whose norm is within :data:`QUATERNION_TOLERANCE` of 1 is normalized with a
        one-line :class:`~shinro_ctrl.engine.warnings.ModelWarning`-free note (a ``UserWarning``);
        farther from 1 it is refused: a typo, not rounding.
        """
        if self.floating and np.size(x) != self.state_dim:
            t = self.tree
            raise InvalidArgument(
                f"{self._label()}: {what} has {np.size(x)} entries; expected {self.state_dim} = nq {t.nq} (qpos, "
                f"with {len(configuration.quaternion_slices(t))} unit quaternion(s)) + nv {t.nv} (qvel)"
                + (f" + na {t.na} (act)" if t.na else "")
            )
        x = as_vector(what, x, self.state_dim).copy()
        if not self.floating:
            return x
        nq = self.tree.nq
        for a, _ in configuration.quaternion_slices(self.tree):
            q = x[a : a + 4]
            n = float(np.linalg.norm(q))
            names = ", ".join(self.state_names[a : a + 4])
            if abs(n - 1.0) > QUATERNION_TOLERANCE:
                raise InvalidArgument(
                    f"{self._label()}: {what} quaternion ({names}) = {q.tolist()} has norm {n:.6g}, not 1 (within "
                    f"{QUATERNION_TOLERANCE:g}); give a unit quaternion (w, x, y, z)"
                )
            if n != 1.0:
                if abs(n - 1.0) > 1e-12:
                    warnings.warn(
                        f"{self._label()}: {what} quaternion ({names}) normalized (its norm was {n:.12g})", stacklevel=3
                    )
                x[a : a + 4] = q / n
        assert x[:nq].shape == (nq,)
        return x

    def _hold_activations(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
        r"""``(x, u)`` at the positions of ``x`` at rest with activations and inputs that hold it, or None.

        ``q̈`` is affine in the inputs ``u`` and the activations ``a``: ``q̈ = a₀ + B_u u + B_a a``.
        At an equilibrium ``ȧ = 0``: a filter's activation equals its input (``a = u``; 0 for an
        actuator that is not an input), an integrator's input is 0 and its activation is free.
        Solves for the free unknowns in the least-squares sense and accepts an exact solution.
        """
        nq, nv, m = self.tree.nq, self.tree.nv, self.input_dim
        x = x.copy()
        x[nq:] = 0.0
        z = np.zeros(m)
        a0 = self._eval_one(x, z)[nq : nq + nv]
        cols, unknowns = [], []  # each unknown: (input index or -1, activation index or -1)
        input_of = {a: k for k, a in enumerate(self.active_actuators)}
        for a, act in enumerate(self.tree.actuators):
            k = input_of.get(a, -1)
            if act.act < 0 and k < 0:
                continue
            if act.act >= 0 and act.dyntype != "integrator" and k < 0:
                continue  # a filter driven by 0 settles at 0
            xe, ue = x.copy(), z.copy()
            if act.act >= 0:
                xe[nq + nv + act.act] = 1.0
            if k >= 0 and act.dyntype != "integrator":
                ue[k] = 1.0
            cols.append(self._eval_one(xe, ue)[nq : nq + nv] - a0)
            unknowns.append((k if act.dyntype != "integrator" else -1, act.act))
        if not cols:
            return None
        B = np.column_stack(cols)
        if not (np.isfinite(a0).all() and np.isfinite(B).all()):
            return None
        sol, *_ = np.linalg.lstsq(B, -a0, rcond=None)
        if np.abs(a0 + B @ sol).max() > 1e-9 * max(1.0, np.abs(a0).max()):
            return None
        u = np.zeros(m)
        for v, (k, ia) in zip(sol, unknowns, strict=True):
            if k >= 0:
                u[k] = v
            if ia >= 0:
                x[nq + nv + ia] = v
        return x, u

    def state_ranges(self) -> tuple[np.ndarray, np.ndarray]:
        """``(x_min (n,), x_max (n,))``: the ranges of the limited joints on their positions, ±inf elsewhere.

        The controllers that take state bounds (``LinearMPC``, ``NonlinearMPC``) use these by default.
        """
        lo, hi = self._joint_range_bounds()
        return lo, hi

    def _joint_range_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Joint ranges of limited joints for the positions; ±inf elsewhere (velocities, activations).

        With equality constraints, the positions are the independent joints'.
        """
        lo = np.full(self.state_dim, -np.inf)
        hi = np.full(self.state_dim, np.inf)
        if self.floating:
            for i, j in zip(self.tree.qposadr, self.tree.joints, strict=True):
                if j.limited and j.type in ("hinge", "slide"):
                    lo[i], hi[i] = j.range
            return lo, hi
        free = self.constraints.independent if self.constraints else range(self.tree.nq)
        dof_joint = [j for j, jt in enumerate(self.tree.joints) for _ in range({"free": 6, "ball": 3}.get(jt.type, 1))]
        for k, i in enumerate(free):
            joint = self.tree.joints[dof_joint[i]]
            if joint.limited and joint.type in ("hinge", "slide"):
                lo[k], hi[k] = joint.range
        return lo, hi

    def _constrained_x0(self, keyframe: tuple[str, np.ndarray] | None, x0: ArrayLike | None) -> np.ndarray:
        """The design operating state: the keyframe projected onto the constraints, or the user's ``x0``.

        A user's ``x0`` is either the design state ``[q_I; q̇_I]`` (completed) or a full ``[q; q̇]`` (checked).
        """
        cd, nq, nv = self.constraints, self.tree.nq, self.tree.nv
        if x0 is None:
            what = f"keyframe '{keyframe[0]}'" if keyframe and keyframe[0] else "the default operating point"
            full = cd.project_state(self._default_x0(keyframe), f"{self._label()}: {what}")
        elif np.size(x0) == nq + nv and nq + nv != 2 * cd.ni:
            full = cd.check_full(as_vector("x0", x0, nq + nv), f"{self._label()}: x0")
        else:
            full = cd.complete(as_vector("x0", x0, 2 * cd.ni), what=f"{self._label()}: x0")
        self._check_in_range(full, "x0")
        return cd.reduce(full)

    def _check_in_range(self, x: np.ndarray, what: str) -> None:
        """Raise InvalidArgument naming every joint of ``x`` outside its range."""
        outside = [
            f"'{self.joint_names[k]}' = {x[i]:g} (range [{j.range[0]:g}, {j.range[1]:g}])"
            for k, (i, j) in enumerate(zip(self.tree.qposadr, self.tree.joints, strict=True))
            if j.limited and j.type in ("hinge", "slide") and not j.range[0] <= x[i] <= j.range[1]
        ]
        if outside:
            raise InvalidArgument(
                f"{self._label()}: {what} puts {'joints' if len(outside) > 1 else 'a joint'} outside the joint "
                f"range: {', '.join(outside)}; MuJoCo's joint limit would push it back (give an operating "
                "point inside the ranges)"
            )

    def _default_u0(self) -> np.ndarray:
        try:
            return self.equilibrium_input(self._x0)
        except InvalidArgument:
            return np.zeros(self.input_dim)

    def equilibrium(self) -> tuple[np.ndarray, np.ndarray]:
        """The operating point ``(x0 (2nq,), u0 (m,))`` (see the constructor)."""
        return self._x0.copy(), self._u0.copy()

    def equilibrium_input(self, x: ArrayLike, *, tol: float = 1e-9) -> np.ndarray:
        r"""The input that makes the accelerations (and activation rates) vanish at ``x`` (e.g. gravity compensation).

        ``q̈`` (and ``ȧ``) is affine in ``u``: ``[q̈; ȧ] = a₀ + B_q u`` with
        ``a₀`` its value at ``u = 0`` and column ``k`` of ``B_q`` equal to its
        value at ``e_k`` minus ``a₀`` (exact for an affine map, up to
        rounding). Returns the least-squares solution of ``B_q u = −a₀``.
        With activation dynamics the forces come from the activations in
        ``x``: a filter holds when its input equals its activation, an
        integrator when its input is 0.

        Args:
            x: State ``(2nq,)`` (usually with zero velocities).
            tol: Largest acceptable residual ``|q̈|`` relative to ``max(1, |a₀|)``.

        Raises:
            InvalidArgument: the actuators cannot hold ``x`` (an unactuated
                direction with a nonzero acceleration); the message gives the
                residual acceleration.
            NonFiniteError: the accelerations at ``x`` overflow float64.
        """
        x = as_vector("x", x, self.state_dim)
        nq = self.tree.nq if self.constraints is None else len(self.position_indices)
        u0 = np.zeros(self.input_dim)
        a0 = self._eval_one(x, u0)[nq:]  # q̈ and ȧ
        Bq = np.column_stack([self._eval_one(x, e)[nq:] - a0 for e in np.eye(self.input_dim)])
        if not (np.isfinite(a0).all() and np.isfinite(Bq).all()):
            raise NonFiniteError(
                f"{self._label()}: the accelerations at x = {np.array2string(x, precision=4)} overflow float64 "
                "(check the magnitudes of the masses, gains and gears in the model file)"
            )
        u, *_ = np.linalg.lstsq(Bq, -a0, rcond=None)
        res = a0 + Bq @ u
        if np.abs(res).max() > tol * max(1.0, np.abs(a0).max()):
            raise InvalidArgument(
                f"{self._label()}: the actuators cannot hold x = {np.array2string(x, precision=4)}: residual "
                f"acceleration {np.array2string(res, precision=3)} (expected 0)"
            )
        return u

    def model_gap(
        self, x0: ArrayLike | None = None, u0: ArrayLike | None = None, *, thresholds: GapThresholds | None = None
    ) -> ModelGap:
        """What the smooth model leaves out at ``(x0, u0)`` and how large it is, measured by MuJoCo on the file.

        Friction loss per joint against its load torque, the distance of ``u0`` to each ``ctrlrange`` /
        ``forcerange`` clamp, the contacts active at ``x0`` and the joint-limit margins, with a warning
        for each effect above its threshold (see :mod:`shinro_ctrl.engine.model_gap`).

        Args:
            x0: State ``(n,)``; default the operating state.
            u0: Input ``(m,)``; default the operating input. Actuators that are not inputs get 0.
            thresholds: When an effect warns (default :class:`~shinro_ctrl.engine.model_gap.GapThresholds`).

        Raises:
            InvalidArgument: wrong shapes.
            NonFiniteError: NaN or inf in ``x0`` or ``u0``.
        """
        # the model file's reader family (agreed exception to the layering, like engine.model_tree)
        from shinro_ctrl.engine.model_gap import plant_model_gap

        x = as_vector("x0", self._x0 if x0 is None else x0, self.state_dim)
        u = as_vector("u0", self._u0 if u0 is None else u0, self.input_dim)
        return plant_model_gap(self, self.model_path, x, u, thresholds=thresholds, source=self.source_path)

    # -------------------------------------------------------------- dynamics
    def _eval_one(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        """``ẋ (nx,)`` at one ``x``, ``u`` through this thread's buffer (constrained: Newton, then the KKT system)."""
        if self.constraints is not None:
            return self.constraints.xdot(x, u)
        return self._eval_checked(x, u)[0]

    def _eval_checked(self, x: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, float]:
        """``(ẋ, s)`` with ``s`` the sum of ``x``, ``u`` and ``ẋ`` computed in C (see :func:`_function`)."""
        if self.constraints is not None:
            xd = self.constraints.xdot(x, u)
            return xd, float(np.sum(x) + np.sum(u) + np.sum(xd))
        try:
            b = self._local.buffers
        except AttributeError:
            shapes = ((self.state_dim,), (1,))
            b = self._local.buffers = _Buffers(self._fun, self.tree.nu, self.active_actuators, shapes)
        b.set(x, u)
        b.run()
        return b.out[0].copy(), float(b.out[1][0])

    def dynamics(self, state: ArrayLike, control: ArrayLike, params: dict[str, ArrayLike] | None = None) -> np.ndarray:
        """``ẋ = f(x, u)`` (see :meth:`Plant.dynamics`).

        Raises:
            InvalidArgument: wrong shapes.
            NonFiniteError: ``x`` or ``u`` holds NaN or inf, or ``ẋ`` overflows float64.
        """
        if params is None and self._plain(state, control):  # straight into this thread's compiled-function buffer
            self.check_model_domain(state)
            xdot, total = self._eval_checked(state, control)
            if math.isfinite(total):  # no NaN or inf in x, u or ẋ (or an overflow: the general path decides)
                return xdot
        for what, v, names in (("x", state, self.state_names), ("u", control, self.input_names)):
            a = np.asarray(v, dtype=float)
            if not np.isfinite(a).all():
                k = int(np.argwhere(~np.isfinite(a))[0][-1]) if a.ndim else 0
                raise NonFiniteError(
                    f"{self._label()}.dynamics: {what} holds NaN or inf (in {names[min(k, len(names) - 1)]}): "
                    f"{np.array2string(a, precision=4)}"
                )
        return super().dynamics(state, control, params)

    def _plain(self, x: object, u: object) -> bool:
        """One float64 state ``(n,)`` and input ``(m,)``: the compiled fast paths take them as they are."""
        return (
            type(x) is np.ndarray
            and type(u) is np.ndarray
            and x.shape == (self.state_dim,)
            and u.shape == (self.input_dim,)
            and x.dtype == np.float64
            and u.dtype == np.float64
        )

    def linearize(
        self, x0: ArrayLike | None = None, u0: ArrayLike | None = None, *, method: str = "exact", eps: float = 1e-6
    ) -> tuple[np.ndarray, np.ndarray]:
        """Continuous-time Jacobians ``(A_c, B_c)`` at ``(x0, u0)`` (see :meth:`Plant.linearize`).

        ``"exact"`` evaluates the compiled Jacobian function. A fast path for
        one float64 ``x0`` and ``u0``: finiteness is checked on one sum of
        ``x0``, ``u0``, ``A`` and ``B`` computed in C (the general path, with
        every check and message, decides whenever it is not finite). A
        constrained model's exact Jacobians come from the implicit function
        theorem on its KKT system, compiled at the first call
        (:meth:`ConstrainedDynamics.jacobians`).
        """
        if self.floating:  # the tangent space: A_t = D A E, B_t = D B (see tangent_maps)
            x0, u0 = self.operating_point(x0, u0)
            A, B = self._full_linearize(x0, u0, method, eps)
            D, E = self.tangent_maps(x0)
            return D @ A @ E, D @ B
        return self._full_linearize(x0, u0, method, eps)

    def _full_linearize(
        self, x0: ArrayLike | None, u0: ArrayLike | None, method: str, eps: float
    ) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`linearize` in the full state ``[qpos; qvel; act]`` (a floating base's quaternions included)."""
        if self.constraints is not None:
            if method != "exact":
                return super().linearize(x0, u0, method=method, eps=eps)
            x0, u0 = self.operating_point(x0, u0)
            A, B = self.constraints.jacobians(x0, u0)
            if not (math.isfinite(A.sum()) and math.isfinite(B.sum())):  # the message only when it is needed
                where = f"{self._label()}.linearize (exact) at x0 = {x0.tolist()}, u0 = {u0.tolist()}"
                self._check_finite_model(A, B, where)
            return A, B
        if method == "exact" and self._plain(x0, u0):
            self.check_model_domain(x0)
            A, B, total = self._jacobian.evaluate(x0, u0)
            if math.isfinite(total):
                return A, B
        return super().linearize(x0, u0, method=method, eps=eps)

    # ------------------------------------------------------ the tangent space
    @property
    def tangent_dim(self) -> int:
        """``2 nv + na`` (``state_dim`` without ball or free joints): the linear models' state dimension."""
        return len(self._tangent_names)

    @property
    def tangent_names(self) -> tuple[str, ...]:
        """Names of the deviation coordinates: a quaternion's three rotation-vector components ``<joint>_rx`` ..."""
        return self._tangent_names

    def difference(self, x: ArrayLike, x_ref: ArrayLike) -> np.ndarray:
        """``dx = x ⊖ x_ref`` ``(..., 2 nv + na)``: exactly MuJoCo's ``mj_differentiatePos`` on ``qpos`` (``dt = 1``).

        ``dx = [qpos ⊖ qpos_ref; qvel − qvel_ref; act − act_ref]``; on a quaternion (a ball, or a
        free joint's orientation) ``2 log(q_ref⁻¹ ⊗ q)``, the rotation vector in the reference body
        frame taken on the short arc (see :mod:`shinro_ctrl.multibody.configuration`); elsewhere the
        plain difference. The coordinates of ``mjd_transitionFD``'s Jacobians. Without ball or free
        joints ``x − x_ref``.
        """
        if not self.floating:
            return super().difference(x, x_ref)
        X, R = np.broadcast_arrays(np.asarray(x, dtype=float), np.asarray(x_ref, dtype=float))
        nq, t = self.tree.nq, self.tree
        flat_x, flat_r = X.reshape(-1, X.shape[-1]), R.reshape(-1, R.shape[-1])
        out = np.empty((flat_x.shape[0], self.tangent_dim))
        for k in range(flat_x.shape[0]):
            out[k, : t.nv] = configuration.difference(t, flat_x[k, :nq], flat_r[k, :nq])
            out[k, t.nv :] = flat_x[k, nq:] - flat_r[k, nq:]
        return out.reshape(*X.shape[:-1], self.tangent_dim)

    def retract(self, x_ref: ArrayLike, dx: ArrayLike) -> np.ndarray:
        """``x = x_ref ⊕ dx`` ``(..., nq + nv + na)``: MuJoCo's ``mj_integratePos(qpos_ref, dx[:nv], 1)`` on ``qpos``.

        The inverse of :meth:`difference`; a quaternion moves by ``q_ref ⊗ exp(φ/2)``.
        """
        if not self.floating:
            return super().retract(x_ref, dx)
        R, Dx = np.asarray(x_ref, dtype=float), np.asarray(dx, dtype=float)
        lead = np.broadcast_shapes(R.shape[:-1], Dx.shape[:-1])
        R = np.broadcast_to(R, (*lead, R.shape[-1])).reshape(-1, R.shape[-1])
        Dx = np.broadcast_to(Dx, (*lead, Dx.shape[-1])).reshape(-1, Dx.shape[-1])
        nq, t = self.tree.nq, self.tree
        out = np.empty((R.shape[0], self.state_dim))
        for k in range(R.shape[0]):
            out[k, :nq] = configuration.integrate(t, R[k, :nq], Dx[k, : t.nv])
            out[k, nq:] = R[k, nq:] + Dx[k, t.nv :]
        return out.reshape(*lead, self.state_dim)

    def tangent_maps(self, x: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
        r"""``(D (n_t, n), E (n, n_t))`` at ``x``: ``D = ∂ difference(·, x)/∂x``, ``E = ∂ retract(x, ·)/∂dx`` at 0.

        On a quaternion ``E = ½ L(q)[:, 1:]`` and ``D = 2 L(q̄)[1:, :]`` (``L(q) p = q ⊗ p``), identity
        blocks elsewhere; ``D E = I``. The tangent linearization is ``A_t = D A E``, ``B_t = D B``
        (continuous; exact: the rotation-vector rate is ``ω`` to first order, and the extra
        ``−½ [ω₀]×`` of a spinning body comes out of ``D A E``), and the tangent step Jacobian
        ``D(F(x₀, u₀)) (∂F/∂x) E(x₀)``.
        """
        x = as_vector("x", x, self.state_dim)
        if not self.floating:
            n = self.state_dim
            return np.eye(n), np.eye(n)
        t, nq, rest = self.tree, self.tree.nq, self.state_dim - self.tree.nq
        D = np.zeros((self.tangent_dim, self.state_dim))
        E = np.zeros((self.state_dim, self.tangent_dim))
        D[: t.nv, :nq] = configuration.difference_jacobian(t, x[:nq])
        E[:nq, : t.nv] = configuration.tangent_basis(t, x[:nq])
        D[t.nv :, nq:] = np.eye(rest)
        E[nq:, t.nv :] = np.eye(rest)
        return D, E

    def step_jacobians(self, x0: ArrayLike | None = None, u0: ArrayLike | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Exact Jacobians of the standalone step (see :meth:`Plant.step_jacobians`), in the tangent space.

        With ball or free joints: ``A = D(x⁺) (∂F/∂x) E(x₀)``, ``B = D(x⁺) ∂F/∂u``, with ``x⁺ = F(x₀, u₀)``
        (:meth:`tangent_maps`): the coordinates of MuJoCo's ``mjd_transitionFD``.
        """
        A, B = super().step_jacobians(x0, u0)
        if not self.floating:
            return A, B
        x0, u0 = self.operating_point(x0, u0)
        xn = np.asarray(self.symbolic_step()(x0, u0, []), dtype=float).reshape(-1)
        Dn, _ = self.tangent_maps(xn)
        _, E = self.tangent_maps(x0)
        return Dn @ A @ E, Dn @ B

    def discrete_offset(self, model: LinearModel) -> np.ndarray:
        """The affine term of ``model`` (see :meth:`Plant.discrete_offset`), in the tangent space."""
        if not self.floating or model.discretization == "step":
            return super().discrete_offset(model)
        D, _ = self.tangent_maps(model.x0)
        drift = (D @ np.asarray(self.dynamics(model.x0, model.u0), dtype=float)).reshape(-1, 1)
        return discretize(model.A_c, drift, model.dt, model.discretization)[1][:, 0]

    def linear_model(
        self,
        x0: ArrayLike | None = None,
        u0: ArrayLike | None = None,
        *,
        method: str = "exact",
        discretization: str = "euler",
        eps: float = 1e-6,
    ) -> LinearModel:
        """The discrete model (see :meth:`Plant.linear_model`); with ball or free joints in the tangent space.

        ``A``, ``B`` act on ``difference(x, x0)`` (:meth:`difference`); ``x0`` stays the full state.
        """
        if self.floating and discretization == "step" and method != "exact":
            raise InvalidArgument(
                f"{self._label()}: discretization='step' with method={method!r} is not available on a floating "
                "base; use method='exact'"
            )
        lm = super().linear_model(x0, u0, method=method, discretization=discretization, eps=eps)
        if self.floating:
            lm = dataclasses.replace(lm, state_names=self._tangent_names)
        return lm

    def equations(
        self, bk: ArrayBackend, x: np.ndarray | cs.SX, u: np.ndarray | cs.SX, p: dict[str, float]
    ) -> np.ndarray | cs.SX | list[float]:
        """``ẋ``: the model's SX expression for the CasADi backend, the compiled function otherwise."""
        if isinstance(bk, CasadiBackend):
            return self.symbolic()(x, u)
        if np.iscomplexobj(x) or np.iscomplexobj(u):  # complex step: the scalar algorithms on complex numbers
            return self._f_complex(np.asarray(x), np.asarray(u))
        x = np.asarray(x, dtype=float)
        u = np.asarray(u, dtype=float)
        if x.ndim == 1 and u.ndim == 1:
            out = self._eval_one(x, u)
            return out.tolist() if bk.name == "list" else out
        lead = np.broadcast_shapes(x.shape[:-1], u.shape[:-1])
        xb = np.broadcast_to(x, (*lead, x.shape[-1])).reshape(-1, x.shape[-1])
        ub = np.broadcast_to(u, (*lead, u.shape[-1])).reshape(-1, u.shape[-1])
        out = np.empty_like(xb)
        for k in range(xb.shape[0]):
            out[k] = self._eval_one(xb[k], ub[k])
        return out.reshape(*lead, x.shape[-1])

    def _f_complex(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        """``ẋ`` for complex ``x (..., n)``, ``u (..., m)`` by the scalar algorithms (complex-step reference)."""
        lead = np.broadcast_shapes(x.shape[:-1], u.shape[:-1])
        xb = np.broadcast_to(x, (*lead, x.shape[-1])).reshape(-1, x.shape[-1])
        ub = np.broadcast_to(u, (*lead, u.shape[-1])).reshape(-1, u.shape[-1])
        rb, active = self.rigid_body_tree, self.active_actuators
        if self.constraints is not None:
            raise InvalidArgument(
                f"{self._label()}: no complex-step evaluation of a constrained model (use method='fd')"
            )
        out = np.array([rb.xdot_numpy(xb[k], ub[k], active) for k in range(xb.shape[0])], dtype=complex)
        return out.reshape(*lead, x.shape[-1])

    def compiled_functions(self) -> tuple[cs.Function, cs.Function]:
        """The compiled functions behind :meth:`dynamics` and :meth:`linearize` (the Jacobians built on first call).

        ``f(x, u_all) -> (ẋ, sum)`` and ``jac(x, u_all) -> (Aᵀ, B_allᵀ,
        sum)``, where ``u_all`` holds every actuator's control in the model's
        order (one library serves every actuator selection), the Jacobians
        come transposed (dense, so their column-major nonzeros are ``A``'s and
        ``B_all``'s row-major entries) and ``sum`` adds up every input and
        output entry (the fast paths' finiteness check). CasADi's
        virtual-machine functions when no compiler could build them. For callers that bind their own
        ``Function.buffer()``; the plant's methods need none of this.
        """
        if self.constraints is not None:
            raise InvalidArgument(
                f"{self._label()}: a constrained model's dynamics are not compiled (they complete the dependent "
                "joints by Newton's method first); use dynamics() and linearize()"
            )
        return self._fun, _jacobian_function(*self._key[:2])

    def symbolic(self, params: bool = False) -> cs.Function:
        """The dynamics as a CasADi ``Function`` ``f(x, u)`` (``params=True``: ``f(x, u, p)`` with an empty ``p``)."""
        if params not in self._symbolic:
            f = self.constraints.symbolic_function() if self.constraints is not None else _symbolic(*self._key)
            if not params:
                self._symbolic[False] = f
            else:
                x = cs.SX.sym("x", self.state_dim)
                u = cs.SX.sym("u", self.input_dim)
                p = cs.SX.sym("p", 0)
                self._symbolic[True] = cs.Function("f", [x, u, p], [f(x, u)], ["x", "u", "p"], ["xdot"])
        return self._symbolic[params]

    def integrate(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        """One step as MuJoCo's Euler: ``q̇⁺ = q̇ + dt q̈``, ``q⁺ = q + dt q̇⁺``, then the joint ranges.

        Activations: ``a⁺ = a + dt ȧ`` (filter, integrator), and the exact
        ``a⁺ = a + (u − a)(1 − e^{−dt/τ})`` for ``filterexact``, as MuJoCo
        steps them (MuJoCo's ``actrange`` clamp is its loop's only). The joint
        ranges act as inelastic stops (:meth:`clip_state`).
        """
        xd = self._eval_one(x, u)
        new = x.copy()
        if self.floating:  # on the manifold: qpos⁺ = qpos ⊕ dt q̇⁺ (a quaternion times exp(dt ω⁺ / 2))
            nq, nv = self.tree.nq, self.tree.nv
            new[nq : nq + nv] += self.dt * xd[nq : nq + nv]
            new[:nq] = configuration.integrate(self.tree, x[:nq], new[nq : nq + nv], self.dt)
            if self.tree.na:
                new[nq + nv :] += self._activation_steps * xd[nq + nv :]
            return self.clip_state(new)
        nq = len(self.position_indices)
        new[nq : 2 * nq] += self.dt * xd[nq : 2 * nq]
        new[:nq] += self.dt * new[nq : 2 * nq]
        if self.tree.na:
            new[2 * nq :] += self._activation_steps * xd[2 * nq :]
        return self.clip_state(new)

    def symbolic_step(self) -> cs.Function:
        """The standalone step :meth:`integrate` (before the stops) as a CasADi ``Function`` ``F(x, u, p)``.

        This is the ``discretization="step"`` model (LinearMPC's default): semi-implicit Euler for
        the joints and MuJoCo's own activation update, exact for ``filterexact`` and Euler for
        ``filter`` and ``integrator``.
        """
        na = self.tree.na
        x = cs.SX.sym("x", self.state_dim)
        u = cs.SX.sym("u", self.input_dim)
        p = cs.SX.sym("p", 0)
        xd = self.symbolic()(x, u)
        if self.floating:
            nq, nv = self.tree.nq, self.tree.nv
            v = x[nq : nq + nv] + self.dt * xd[nq : nq + nv]
            parts = [configuration.integrate_sx(self.tree, x[:nq], v, self.dt), v]
            if na:
                parts.append(x[nq + nv :] + cs.DM(self._activation_steps) * xd[nq + nv :])
            return cs.Function("F", [x, u, p], [cs.vertcat(*parts)], ["x", "u", "p"], ["x_next"])
        nq = len(self.position_indices)
        v = x[nq : 2 * nq] + self.dt * xd[nq : 2 * nq]
        parts = [x[:nq] + self.dt * v, v]
        if na:
            parts.append(x[2 * nq :] + cs.DM(self._activation_steps) * xd[2 * nq :])
        return cs.Function("F", [x, u, p], [cs.vertcat(*parts)], ["x", "u", "p"], ["x_next"])

    @functools.cached_property
    def _activation_steps(self) -> np.ndarray:
        """Per activation, ``h`` with ``a⁺ = a + h ȧ``: ``dt``, or ``τ (1 − e^{−dt/τ})`` for filterexact."""
        h = np.full(self.tree.na, self.dt)
        for a in self.tree.actuators:
            if a.dyntype == "filterexact":
                tau = a.dynprm[0]
                h[a.act] = tau * -np.expm1(-self.dt / tau)
        return h

    # ---------------------------------------------------------------- engine
    def mjcf_patch(self) -> MjcfPatch:
        """The model file itself (absolute path), unedited but for ``timestep = dt``.

        The gravity is the model's own. ``model_file``: the MuJoCo loop keeps the file's own options
        (integrator, contacts, limits, friction loss, clamps); ``model="matched"`` builds the idealized
        copy ``crosscheck`` compares (see ``MujocoEngine.for_plant``).
        """
        g = self.tree.gravity  # the model's own (its disable flag stays in the file)
        return MjcfPatch(
            asset=self.model_path,
            timestep=self.dt,
            gravity=(float(g[0]), float(g[1]), float(g[2])),
            model_file=True,
        )

    def engine_state_map(self, x0: ArrayLike | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Identity: the state is MuJoCo's ``[qpos; qvel; act]`` (see :meth:`Plant.engine_state_map`).

        On a floating base the identity of the tangent space (``2 nv + na``): the linear models are in
        ``mjd_transitionFD``'s own coordinates (``crosscheck`` compares them directly).
        """
        if self.constraints is not None:
            raise NotImplementedError(
                f"{self._label()}: a constrained model's state is its independent coordinates, MuJoCo's dependent "
                "joints follow them nonlinearly (its equality constraints)"
            )
        n = self.tangent_dim
        return np.eye(n), np.arange(n)

    def engine_read(self, engine: MujocoEngine) -> np.ndarray:
        """The state ``[qpos; qvel; act]`` read from the engine (constrained: its independent coordinates)."""
        x = engine.get_state_vector()
        return x if self.constraints is None else self.constraints.reduce(x)

    def engine_write(self, engine: MujocoEngine, x: np.ndarray) -> None:
        """Write ``[qpos; qvel; act]`` into the engine (constrained: the dependent coordinates completed)."""
        engine.set_state_vector(x if self.constraints is None else self.constraints.complete(x))

    def engine_apply(self, engine: MujocoEngine, u: np.ndarray) -> None:
        """Set the selected actuators' controls (the others stay 0)."""
        if len(self.active_actuators) == self.tree.nu and self.active_actuators == tuple(range(self.tree.nu)):
            engine.set_ctrl(u)
            return
        for k, a in enumerate(self.active_actuators):
            engine.data.ctrl[a] = u[k]

    def _check_engine(self, engine: MujocoEngine | None) -> None:
        super()._check_engine(engine)
        if engine is not None:
            m = engine.model
            if m.nq != self.tree.nq or m.nu != self.tree.nu or m.na != self.tree.na:
                raise InvalidArgument(
                    f"{self._label()}: engine model has nq={m.nq}, nu={m.nu}, na={m.na}; expected "
                    f"nq={self.tree.nq}, nu={self.tree.nu}, na={self.tree.na} (the same model file)"
                )
            if len(self.active_actuators) != self.tree.nu:
                engine.data.ctrl[:] = 0.0

    # ---------------------------------------------------------------- config
    def _label(self) -> str:
        return f"MjcfPlant('{Path(self.source_path).name}')"

    def __repr__(self) -> str:
        return f"MjcfPlant('{self.source_path}', dt={self.dt:g})"
