"""Building a :class:`~shinro_ctrl.plants.base.Plant` from a ``[plant]`` table."""

from __future__ import annotations

import inspect
from dataclasses import asdict, is_dataclass
from typing import TYPE_CHECKING, Any

from shinro_ctrl.errors import ConfigError
from shinro_ctrl.validation import did_you_mean, unknown_keys

if TYPE_CHECKING:
    from shinro_ctrl.plants.base import Plant

__all__ = ["ConfigMixin"]


class ConfigMixin:
    """The scenario-configuration part of :class:`~shinro_ctrl.plants.base.Plant`."""

    @classmethod
    def config_keys(cls) -> tuple[str, ...]:
        """The keys a ``[plant]`` table may hold: the constructor's arguments."""
        sig = inspect.signature(cls.__init__)
        return tuple(k for k in sig.parameters if k not in ("self", "backend"))

    @classmethod
    def from_config(cls, config: Any, *, engine: Any = None) -> Plant:
        """Build the plant from a mapping or dataclass of constructor arguments.

        Args:
            config: Constructor keyword arguments (a ``type`` key is ignored).
            engine: Optional engine to attach.

        Raises:
            ConfigError: an unknown key (with the closest valid one) or an
                invalid value (naming the key).
        """
        if is_dataclass(config) and not isinstance(config, type):
            config = asdict(config)
        kwargs = {k: v for k, v in dict(config).items() if k != "type"}
        allowed = cls.config_keys()
        bad = unknown_keys(kwargs, allowed)
        if bad:
            raise ConfigError(f"[plant] {cls.__name__}: unknown key '{bad[0]}'{did_you_mean(bad[0], allowed)}")
        try:
            plant = cls(**kwargs)
        except (TypeError, ValueError, FileNotFoundError) as exc:  # a missing model file is a bad [plant] value
            raise ConfigError(f"[plant] {cls.__name__}: {exc}") from exc
        if engine is not None:
            plant.physics_engine(engine)
        return plant
