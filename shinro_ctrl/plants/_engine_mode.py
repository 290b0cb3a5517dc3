"""Engine mode of a :class:`~shinro_ctrl.plants.base.Plant`: attaching a physics engine and the engine hooks.

A plant never imports the engine: it is duck-typed. The hooks here
(:meth:`EngineModeMixin.mjcf_patch`, :meth:`EngineModeMixin.engine_read`,
:meth:`EngineModeMixin.engine_write`, :meth:`EngineModeMixin.engine_apply`,
:meth:`EngineModeMixin.engine_state_map`) are listed with every other plant hook
in the :class:`~shinro_ctrl.plants.base.Plant` docstring; this mixin only keeps
them out of ``base.py``.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from shinro_ctrl.errors import InvalidArgument

if TYPE_CHECKING:
    from shinro_ctrl.plants.base import MjcfPatch

__all__ = ["EngineModeMixin"]


class EngineModeMixin:
    """Engine-mode part of :class:`~shinro_ctrl.plants.base.Plant` (attach, check, read/write/apply hooks)."""

    @property
    def engine(self) -> Any:
        """The attached physics engine, or None (standalone)."""
        return self._engine

    def physics_engine(self, engine: Any) -> None:
        """Attach a physics engine (or detach with None).

        On attach the plant's state is read from the engine; on detach the
        plant keeps the last state it had.
        """
        if engine is not None and self.asset is None:
            raise InvalidArgument(f"{type(self).__name__} has no MuJoCo model to attach an engine to")
        self._check_engine(engine)
        self._engine = engine
        if engine is not None:
            self.state = self.engine_read(engine)

    def _check_engine(self, engine: Any) -> None:
        """Raise InvalidArgument unless ``engine`` is None or behaves like a MujocoEngine."""
        needed = ("step", "forward", "get_joint_qpos", "get_joint_vel", "set_joint_ctrl")
        if engine is not None and not all(callable(getattr(engine, a, None)) for a in needed):
            raise InvalidArgument(
                f"{type(self).__name__}.physics_engine expects a MujocoEngine (or None), got {type(engine).__name__}"
            )
        if engine is not None and getattr(engine, "model", None) is not None:
            self._check_engine_matches(engine)

    def _check_engine_matches(self, engine: Any) -> None:
        """Raise InvalidArgument when ``engine`` was built for another plant (type, ``dt`` or a parameter).

        The engine's compiled model is compared with what :meth:`mjcf_patch` would
        write into it (see ``MujocoEngine.for_plant``): step, gravity, body masses
        and positions, joint damping; a body or joint the patch names but the
        model lacks means another plant type. The first mismatch is named.
        """
        try:
            patch = self.mjcf_patch()
        except NotImplementedError:
            return
        m, name = engine.model, type(self).__name__
        rel = 1e-6
        built_for = getattr(engine, "plant_type", None)
        if isinstance(built_for, str) and built_for != name:
            raise InvalidArgument(
                f"{name}.physics_engine: the engine was built for another plant type: {built_for}, not {name}; "
                "build it with MujocoEngine.for_plant(plant)"
            )

        def differs(a: Any, b: Any) -> bool:
            a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
            return a.shape != b.shape or bool(np.any(np.abs(a - b) > rel * np.maximum(1.0, np.abs(b))))

        def mismatch(what: str, engine_value: Any, plant_value: Any) -> InvalidArgument:
            return InvalidArgument(
                f"{name}.physics_engine: the engine was built for another plant: {what} is {engine_value} in the "
                f"engine but {plant_value} in the plant; build it with MujocoEngine.for_plant(plant)"
            )

        engine_dt = float(getattr(engine, "dt", m.opt.timestep))
        if differs(engine_dt, self.dt):
            raise mismatch("dt", f"{engine_dt:g} s", f"{self.dt:g} s")
        if differs(m.opt.gravity, patch.gravity):
            raise mismatch("gravity", list(np.round(m.opt.gravity, 6)), list(patch.gravity))
        for kind, names in (
            ("body", [*patch.inertials, *patch.body_pos, *patch.body_inertia]),
            ("joint", list(patch.joint_damping)),
        ):
            for item in names:
                try:
                    getattr(m, kind)(item)
                except KeyError:
                    raise InvalidArgument(
                        f"{name}.physics_engine: the engine was built for another plant type: its model "
                        f"({engine.source}) has no {kind} '{item}', which {name} needs"
                    ) from None
        for body, (mass, ipos) in patch.inertials.items():
            if differs(m.body(body).mass[0], mass):
                raise mismatch(f"the mass of body '{body}'", f"{m.body(body).mass[0]:g} kg", f"{mass:g} kg")
            if differs(m.body(body).ipos, ipos):
                raise mismatch(f"the centre of mass of body '{body}'", list(m.body(body).ipos), list(ipos))
        for body, pos in patch.body_pos.items():
            if differs(m.body(body).pos, pos):
                raise mismatch(f"the position of body '{body}'", list(m.body(body).pos), list(pos))
        for joint, damping in patch.joint_damping.items():
            dof = int(m.joint(joint).dofadr[0])
            if differs(m.dof_damping[dof], damping):
                raise mismatch(f"the damping of joint '{joint}'", f"{m.dof_damping[dof]:g}", f"{damping:g}")

    def mjcf_patch(self) -> MjcfPatch:
        """How the plant's MJCF asset must be edited to match its parameters."""
        raise NotImplementedError(f"{type(self).__name__} has no matched MuJoCo model")

    def engine_state_map(self, x0: Any = None) -> tuple[np.ndarray, np.ndarray]:
        """How the plant's state relates to MuJoCo's ``z = [qpos..., qvel...]``.

        Returns:
            ``(T (n, n), perm (n,))`` with ``x_plant = T @ z`` (``z`` in the
            order of ``mjd_transitionFD``); ``perm[i]`` is the index in ``z``
            of the coordinate state ``i`` is built on (same joint, same
            derivative order), so ``T == eye(n)[perm]`` unless the plant uses
            other coordinates. Inputs map 1:1 onto actuators (``ctrl = u``).
        """
        raise NotImplementedError(f"{type(self).__name__} has no MuJoCo state map")

    def engine_read(self, engine: Any) -> np.ndarray:
        """Hook: the plant state ``x (n,)`` read from the engine's joints (engine mode)."""
        raise NotImplementedError(f"{type(self).__name__} has no engine mode")

    def engine_write(self, engine: Any, x: np.ndarray) -> None:
        """Hook: write the plant state ``x (n,)`` into the engine's joints (engine mode)."""
        raise NotImplementedError(f"{type(self).__name__} has no engine mode")

    def engine_apply(self, engine: Any, u: np.ndarray) -> None:
        """Hook: apply the input ``u (m,)`` to the engine's actuators (engine mode)."""
        raise NotImplementedError(f"{type(self).__name__} has no engine mode")

    _engine_read = engine_read
    _engine_write = engine_write
    _engine_apply = engine_apply
