"""Find the shipped scenario files and MJCF assets.

``configs/`` and ``assets/`` live at the repository root and are copied into
the wheel as ``shinro_ctrl/configs`` and ``shinro_ctrl/assets``. Lookup tries
the installed location first, then the repository root (editable install).
"""

from __future__ import annotations

from pathlib import Path

__all__ = [
    "asset_path",
    "config_path",
    "list_assets",
    "list_configs",
    "regression_dir",
    "shipped_asset",
    "shipped_config",
]

_PKG = Path(__file__).resolve().parent


def _root(kind: str) -> Path:
    for candidate in (_PKG / kind, _PKG.parent / kind):
        if candidate.is_dir():
            return candidate
    raise FileNotFoundError(f"shinro_ctrl data folder '{kind}' is missing from the installation")


def _find(kind: str, name: str | Path, suffix: str) -> Path:
    p = Path(name)
    if p.is_file():
        return p.resolve()
    return _find_shipped(kind, name, suffix)


def _find_shipped(kind: str, name: str | Path, suffix: str) -> Path:
    p = Path(name)
    root = _root(kind)
    candidates = [root / p] if p.suffix else [root / p, root / p.with_suffix(suffix)]
    for candidate in candidates:
        if candidate.is_file():
            return candidate
    shipped = ", ".join(_list(kind, suffix)) or "none"
    raise FileNotFoundError(f"no {kind[:-1]} named '{name}'; shipped {kind}: {shipped}")


def _list(kind: str, suffix: str) -> list[str]:
    root = _root(kind)
    return sorted(str(p.relative_to(root)) for p in root.rglob(f"*{suffix}"))


def config_path(name: str | Path) -> Path:
    """Path of a scenario: an existing path, or a shipped name such as
    ``"cartpole_lqr"``, ``"cartpole_lqr.toml"`` or ``"regression/cartpole_lqr.toml"``.

    Raises:
        FileNotFoundError: listing the shipped scenarios.
    """
    return _find("configs", name, ".toml")


def asset_path(name: str | Path) -> Path:
    """Path of an MJCF model: an existing path or a shipped name such as ``"cartpole.xml"``.

    Raises:
        FileNotFoundError: listing the shipped assets.
    """
    return _find("assets", name, ".xml")


def shipped_config(name: str | Path) -> Path:
    """A scenario shipped with the package, never a same-named file in the current directory.

    Raises:
        FileNotFoundError: listing the shipped scenarios.
    """
    return _find_shipped("configs", name, ".toml")


def shipped_asset(name: str | Path) -> Path:
    """An MJCF model shipped with the package (a plant's own asset), never a file in the current directory.

    Raises:
        FileNotFoundError: listing the shipped assets.
    """
    return _find_shipped("assets", name, ".xml")


def regression_dir() -> Path:
    """The folder of shipped regression scenarios and their baselines."""
    return _root("configs") / "regression"


def list_configs() -> list[str]:
    """Shipped scenario files, relative to the configs folder (``regression/…`` included)."""
    return _list("configs", ".toml")


def list_assets() -> list[str]:
    """Shipped MJCF assets."""
    return _list("assets", ".xml")
