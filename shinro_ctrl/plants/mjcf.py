r"""Bring your own robot: any fixed-base MJCF/URDF tree of hinge and slide joints as a plant.

:class:`MjcfPlant` reads the model file once (MuJoCo compiles it; the
reader ``shinro_ctrl.engine.model_tree`` is the one module of the engine
package a plant may import) and builds the exact equations of motion from
the kinematic tree with :class:`~shinro_ctrl.multibody.RigidBodyTree`:

.. math::

    \dot x = \begin{bmatrix} \dot q \\
        (M(q) + \operatorname{diag}(a))^{-1}\,(\tau_{act}(q, \dot q, u) - b \odot \dot q
        - k \odot (q - q_s) - c(q, \dot q)) \end{bmatrix},
    \qquad x = [q; \dot q].

The expression is a CasADi ``SX`` graph, so ``symbolic()``, exact
``linearize()``, ``get_model()`` and everything downstream work unchanged;
numeric ``dynamics()`` evaluates the compiled function. The MuJoCo engine
loads the same file (:meth:`MjcfPlant.mjcf_patch` edits nothing but the
timestep), so the state map is the identity.

What the symbolic model leaves out, because it is not smooth dynamics:
contacts, joint-limit constraint forces, and MuJoCo's ``ctrlrange`` /
``forcerange`` clamps. Keep trajectories inside the joint ranges and the
inputs inside their ranges (the controller's bounds), or compare with care.
"""

from __future__ import annotations

import functools
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import casadi as cs
import numpy as np

from shinro_ctrl.backend import CasadiBackend
from shinro_ctrl.errors import InvalidArgument, UnknownName
from shinro_ctrl.multibody import ModelTree, RigidBodyTree
from shinro_ctrl.plants.base import MjcfPatch, Plant
from shinro_ctrl.validation import as_vector, check_positive, closest

__all__ = ["MODEL_SUFFIXES", "MjcfPlant", "is_model_file"]

MODEL_SUFFIXES = (".xml", ".mjcf", ".urdf")


def is_model_file(name: Any) -> bool:
    """Whether ``name`` names a model file (MJCF/URDF suffix) rather than a plant class."""
    return isinstance(name, str | os.PathLike) and Path(os.fspath(name)).suffix.lower() in MODEL_SUFFIXES


@functools.lru_cache(maxsize=16)
def _read(path: str, mtime_ns: int) -> tuple[ModelTree, RigidBodyTree, np.ndarray | None]:
    """Read one model file version once: its tree, dynamics builder and first keyframe ``[qpos; qvel]``."""
    # the agreed exception to the layering: the model reader lives in the engine package
    from shinro_ctrl.engine.model_tree import load_model, read_model_tree

    mj, _ = load_model(path)
    tree = read_model_tree(mj, path=path)
    key = np.concatenate([mj.key_qpos[0], mj.key_qvel[0]]).astype(float) if mj.nkey else None
    return tree, RigidBodyTree(tree), key


@functools.lru_cache(maxsize=16)
def _function(path: str, mtime_ns: int, active: tuple[int, ...]) -> cs.Function:
    """The compiled ``f(x, u) -> xdot`` of one model file version and actuator selection."""
    tree, rb, _ = _read(path, mtime_ns)
    x = cs.SX.sym("x", 2 * tree.nq)
    u = cs.SX.sym("u", len(active))
    return cs.Function("f", [x, u], [rb.xdot_sx(x, u, active)], ["x", "u"], ["xdot"])


class MjcfPlant(Plant):
    """A plant whose dynamics come from an MJCF (or URDF) model file.

    State ``x = [qpos; qvel]`` ``(2 nq,)`` in MuJoCo's joint order, named
    after the joints (``shoulder``, …, ``shoulder_dot``, …); inputs ``u`` the
    selected actuators' controls, named after the actuators. The physics are
    the model's: bodies with full inertia tensors and off-axis centres of
    mass, joint damping, stiffness and armature, gravity, and actuators with
    a joint transmission (``motor``, ``position``/``velocity`` servos through
    their gains and biases, ``general`` with fixed/affine gain and bias; see
    :mod:`shinro_ctrl.multibody`).

    A URDF file carries no actuators: its inputs are joint torques (forces
    for prismatic joints), one motor per joint named after the joint, in an
    MJCF translation that both the plant and the engine load (see
    ``shinro_ctrl.engine.model_tree.urdf_with_motors``).

    ``MjcfPlant`` has no float physical parameters: the model file is the
    parameter. ``param_names`` is empty, ``params()`` is ``{}`` and
    ``symbolic(params=True)`` takes an empty ``p``; to change the physics,
    edit the file.

    Args:
        model: MJCF/URDF path, or the name of a shipped asset; default the
            shipped Furuta pendulum ``"furuta_pendulum.xml"`` (so that
            ``MjcfPlant()`` works like every other plant's defaults).
        actuators: Names of the actuators that are the inputs, in this order;
            None: all, in the model's order. Actuators left out get control 0.
        dt: Step [s]; default the model's ``opt.timestep``.
        x0: Operating state ``(2 nq,)``; default the model's first keyframe,
            else ``[qpos0; 0]``.
        u0: Operating input ``(m,)``; default :meth:`equilibrium_input` at
            ``x0`` when the actuators can hold it there (gravity
            compensation), else zeros.
        backend: Kept for API compatibility (unused).

    Raises:
        FileNotFoundError: no such file or shipped asset.
        InvalidArgument: an unsupported joint or actuator (named), no
            actuators, an unknown actuator name, a bad ``dt``/``x0``/``u0``.
    """

    def __init__(
        self,
        model: str | os.PathLike = "furuta_pendulum.xml",
        *,
        actuators: Sequence[str] | None = None,
        dt: float | None = None,
        x0: Any = None,
        u0: Any = None,
        backend: Any = None,
    ):
        from shinro_ctrl.engine.model_tree import resolve_model_path, urdf_with_motors

        path = resolve_model_path(model)
        if path.suffix.lower() == ".urdf":  # URDF has no actuators: a motor per joint, in a converted MJCF
            path = urdf_with_motors(path)
        mtime = path.stat().st_mtime_ns
        tree, rb, key = _read(str(path), mtime)
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
        self._fun = _function(str(path), mtime, active)
        self.model_path = str(path)
        self.asset = str(path)  # the engine loads the same file
        self.active_actuators = active
        nq = tree.nq
        self.joint_names = tuple(j.name or f"q{i}" for i, j in enumerate(tree.joints))
        self.state_names = (*self.joint_names, *(f"{j}_dot" for j in self.joint_names))
        self.input_names = tuple(names[k] or f"u{k}" for k in active)
        self.position_indices = tuple(range(nq))
        self.velocity_indices = tuple(range(nq, 2 * nq))
        self._init(dt=tree.timestep if dt is None else check_positive("dt", dt), params={}, backend=backend)
        # fast numeric path: one buffer bound to arrays this object owns
        self._xb = np.zeros(2 * nq)
        self._ub = np.zeros(len(active))
        self._yb = np.zeros(2 * nq)
        self._buf, self._eval = self._fun.buffer()
        self._buf.set_arg(0, memoryview(self._xb))
        self._buf.set_arg(1, memoryview(self._ub))
        self._buf.set_res(0, memoryview(self._yb))
        if x0 is None:
            x0 = key if key is not None else np.r_[[j.qpos0 for j in tree.joints], np.zeros(nq)]
        self._x0 = as_vector("x0", x0, 2 * nq).copy()
        self._u0 = as_vector("u0", u0, self.input_dim).copy() if u0 is not None else self._default_u0()
        self.state = self._x0.copy()

    # ------------------------------------------------------------ operating
    def _default_u0(self) -> np.ndarray:
        try:
            return self.equilibrium_input(self._x0)
        except InvalidArgument:
            return np.zeros(self.input_dim)

    def equilibrium(self) -> tuple[np.ndarray, np.ndarray]:
        """The operating point ``(x0 (2nq,), u0 (m,))`` (see the constructor)."""
        return self._x0.copy(), self._u0.copy()

    def equilibrium_input(self, x: Any, *, tol: float = 1e-9) -> np.ndarray:
        r"""The input that makes the accelerations vanish at ``x`` (e.g. gravity compensation).

        ``q̈`` is affine in ``u``: ``q̈ = a₀ + B_q u`` with ``a₀ = q̈(x, 0)``
        and column ``k`` of ``B_q = ∂q̈/∂u`` equal to ``q̈(x, e_k) − a₀``
        (exact for an affine map, up to rounding). Returns the least-squares
        solution of ``B_q u = −a₀``.

        Args:
            x: State ``(2nq,)`` (usually with zero velocities).
            tol: Largest acceptable residual ``|q̈|`` relative to ``max(1, |a₀|)``.

        Raises:
            InvalidArgument: the actuators cannot hold ``x`` (an unactuated
                direction with a nonzero acceleration); the message gives the
                residual acceleration.
        """
        x = as_vector("x", x, self.state_dim)
        nq = self.tree.nq
        u0 = np.zeros(self.input_dim)
        a0 = self._eval_one(x, u0)[nq:]
        Bq = np.column_stack([self._eval_one(x, e)[nq:] - a0 for e in np.eye(self.input_dim)])
        u, *_ = np.linalg.lstsq(Bq, -a0, rcond=None)
        res = a0 + Bq @ u
        if np.abs(res).max() > tol * max(1.0, np.abs(a0).max()):
            raise InvalidArgument(
                f"{self._label()}: the actuators cannot hold x = {np.array2string(x, precision=4)}: residual "
                f"acceleration {np.array2string(res, precision=3)} (expected 0)"
            )
        return u

    def state_limits(self) -> tuple[np.ndarray, np.ndarray]:
        """Joint ranges of limited joints for the positions; ±inf elsewhere."""
        lo = np.full(self.state_dim, -np.inf)
        hi = np.full(self.state_dim, np.inf)
        for i, j in enumerate(self.tree.joints):
            if j.limited:
                lo[i], hi[i] = j.range
        return lo, hi

    # -------------------------------------------------------------- dynamics
    def _eval_one(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        self._xb[:] = x
        self._ub[:] = u
        self._eval()
        return self._yb.copy()

    def equations(self, bk: Any, x: Any, u: Any, p: Any) -> Any:
        """``ẋ``: the model's SX expression for the CasADi backend, the compiled function otherwise."""
        if isinstance(bk, CasadiBackend):
            return self._fun(x, u)
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
        out = np.array([rb.xdot_numpy(xb[k], ub[k], active) for k in range(xb.shape[0])], dtype=complex)
        return out.reshape(*lead, x.shape[-1])

    def symbolic(self, params: bool = False) -> cs.Function:
        """The dynamics as a CasADi ``Function`` ``f(x, u)`` (``params=True``: ``f(x, u, p)`` with an empty ``p``)."""
        if params not in self._symbolic:
            if not params:
                self._symbolic[False] = self._fun
            else:
                x = cs.SX.sym("x", self.state_dim)
                u = cs.SX.sym("u", self.input_dim)
                p = cs.SX.sym("p", 0)
                self._symbolic[True] = cs.Function("f", [x, u, p], [self._fun(x, u)], ["x", "u", "p"], ["xdot"])
        return self._symbolic[params]

    def integrate(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        """One semi-implicit Euler step: ``q̇⁺ = q̇ + dt q̈``, ``q⁺ = q + dt q̇⁺`` (MuJoCo's Euler)."""
        nq = self.tree.nq
        xd = self._eval_one(x, u)
        new = x.copy()
        new[nq:] += self.dt * xd[nq:]
        new[:nq] += self.dt * new[nq:]
        return new

    # ---------------------------------------------------------------- engine
    def mjcf_patch(self) -> MjcfPatch:
        """The model file itself (absolute path), unedited but for ``timestep = dt``.

        The gravity written is the model's own; the engine sets MuJoCo's Euler
        integrator with explicit damping, as for every plant.
        """
        g = self.tree.gravity  # the model's own (its disable flag stays in the file)
        return MjcfPatch(asset=self.model_path, timestep=self.dt, gravity=tuple(float(c) for c in g))

    def engine_state_map(self, x0: Any = None) -> tuple[np.ndarray, np.ndarray]:
        """Identity: the state is MuJoCo's ``[qpos; qvel]`` (see :meth:`Plant.engine_state_map`)."""
        n = self.state_dim
        return np.eye(n), np.arange(n)

    def engine_read(self, engine: Any) -> np.ndarray:
        return engine.get_state_vector()

    def engine_write(self, engine: Any, x: np.ndarray) -> None:
        engine.set_state_vector(x)

    def engine_apply(self, engine: Any, u: np.ndarray) -> None:
        if len(self.active_actuators) == self.tree.nu and self.active_actuators == tuple(range(self.tree.nu)):
            engine.set_ctrl(u)
            return
        for k, a in enumerate(self.active_actuators):
            engine.data.ctrl[a] = u[k]

    def _check_engine(self, engine: Any) -> None:
        super()._check_engine(engine)
        if engine is not None:
            m = engine.model
            if m.nq != self.tree.nq or m.nu != self.tree.nu:
                raise InvalidArgument(
                    f"{self._label()}: engine model has nq={m.nq}, nu={m.nu}; expected nq={self.tree.nq}, "
                    f"nu={self.tree.nu} (the same model file)"
                )
            if len(self.active_actuators) != self.tree.nu:
                engine.data.ctrl[:] = 0.0

    # ---------------------------------------------------------------- config
    def _label(self) -> str:
        return f"MjcfPlant('{Path(self.model_path).name}')"

    def __repr__(self) -> str:
        return f"MjcfPlant('{self.model_path}', dt={self.dt:g})"
