"""One registry convention for plants, controllers and estimators.

Each base class owns one :class:`Registry` and registers its subclasses where
they are defined (``__init_subclass__`` calls :meth:`Registry.register`), so a
class defined anywhere, in the package or in a user's module, is found by its
name the moment its ``class`` statement has run:

* :data:`shinro_ctrl.plants.base.PLANT_REGISTRY` (a plant's ``aliases`` too),
* :data:`shinro_ctrl.controllers.base.CONTROLLER_REGISTRY`,
* :data:`shinro_ctrl.estimators.base.ESTIMATOR_REGISTRY`.

A scenario's ``type = "Name"`` is looked up with :meth:`Registry.lookup`
(an unknown name is a :class:`~shinro_ctrl.errors.ConfigError` with the
closest known name); :meth:`Registry.names` lists them (the CLI's ``list``);
:meth:`Registry.shipped` keeps the classes the package itself defines. Each
package ``__init__`` imports its modules eagerly, so ``import
shinro_ctrl.controllers`` has registered every shipped controller and static
tools see every name.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from types import MappingProxyType
from typing import Generic, TypeVar

from shinro_ctrl.errors import ConfigError, InvalidArgument
from shinro_ctrl.validation import did_you_mean

__all__ = ["Registry", "is_abstract"]

T = TypeVar("T")


def is_abstract(cls: type) -> bool:
    """True while ``cls`` still has an abstract method.

    Works inside ``__init_subclass__``, before ``ABCMeta`` has set ``__abstractmethods__``.
    """
    return any(getattr(getattr(cls, name, None), "__isabstractmethod__", False) for name in dir(cls))


class Registry(Generic[T]):
    """Classes of one kind by name (and alias): register at definition, look up with "did you mean", list.

    Args:
        kind: What the classes are, for messages (``"plant"``, ``"controller"``, ``"estimator"``).
        package: The package whose classes are "shipped" (``"shinro_ctrl.plants"``).
    """

    def __init__(self, kind: str, package: str) -> None:
        self.kind = kind
        self.package = package
        self._classes: dict[str, type[T]] = {}
        self._aliases: dict[str, str] = {}

    def register(self, cls: type[T], *, aliases: Iterable[str] = ()) -> type[T]:
        """Register ``cls`` under its class name and ``aliases``; returns ``cls`` (usable as a decorator).

        Abstract classes (an abstract method left) and private ones (name starting with ``_``) are not
        registered: neither can be a scenario's type. A class redefined in the same module (a reload, a
        notebook cell run twice) replaces the earlier one.

        Raises:
            InvalidArgument: the name or an alias is taken by a class of another module.
        """
        name = cls.__name__
        if name.startswith("_") or is_abstract(cls):
            return cls
        aliases = tuple(aliases)
        for key in (name, *aliases):
            owner = self._classes.get(self._aliases.get(key, key))
            if owner is not None and owner.__module__ != cls.__module__:
                raise InvalidArgument(
                    f"{self.kind} name '{key}' of {cls.__module__}.{cls.__qualname__} is taken by "
                    f"{owner.__module__}.{owner.__qualname__}; name the class differently"
                )
        self._classes[name] = cls
        for alias in aliases:
            self._aliases[alias] = name
        return cls

    def lookup(self, name: str) -> type[T]:
        """The class registered as ``name`` (a class name or an alias).

        Raises:
            ConfigError: unknown name, with the closest known one (or the list of known names).
        """
        cls = self._classes.get(self._aliases.get(name, name))
        if cls is None:
            raise ConfigError(
                f"unknown {self.kind} type '{name}'{did_you_mean(name, [*self._classes, *self._aliases])}"
            )
        return cls

    def names(self, *, shipped: bool = False) -> list[str]:
        """The registered class names in order of definition (``shipped=True``: only the package's own)."""
        return list(self.shipped() if shipped else self._classes)

    def shipped(self) -> dict[str, type[T]]:
        """Class name -> class, for the classes defined in :attr:`package`."""
        prefix = self.package + "."
        return {name: cls for name, cls in self._classes.items() if cls.__module__.startswith(prefix)}

    @property
    def aliases(self) -> MappingProxyType[str, str]:
        """Alias -> class name (read-only, live)."""
        return MappingProxyType(self._aliases)

    def __contains__(self, name: object) -> bool:
        return name in self._classes or name in self._aliases

    def __iter__(self) -> Iterator[str]:
        return iter(list(self._classes))

    def __len__(self) -> int:
        return len(self._classes)

    def items(self) -> list[tuple[str, type[T]]]:
        """``(class name, class)`` pairs in order of definition."""
        return list(self._classes.items())

    def __repr__(self) -> str:
        return f"Registry({self.kind!r}: {', '.join(self._classes)})"
