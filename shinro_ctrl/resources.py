"""Find the shipped scenario files and MJCF assets.

``configs/`` and ``assets/`` live at the repository root and are copied into
the wheel as ``shinro_ctrl/configs`` and ``shinro_ctrl/assets``. Lookup tries
the installed location first, then the repository root (editable install).
This module imports nothing else from the package, so the engine (asset paths)
and the scenario layer share it.
"""

from __future__ import annotations

from pathlib import Path

__all__ = [
    "asset_path",
    "config_path",
    "data_root",
    "find_data",
    "find_shipped",
    "list_assets",
    "list_configs",
    "list_data",
    "regression_dir",
    "shipped_asset",
    "shipped_config",
]


_PKG = Path(__file__).resolve().parent


def data_root(kind: str) -> Path:
    """The folder of ``kind`` (``"assets"`` or ``"configs"``).

    Raises:
        FileNotFoundError: the folder is missing from the installation.
    """
    for candidate in (_PKG / kind, _PKG.parent / kind):
        if candidate.is_dir():
            return candidate
    raise FileNotFoundError(f"shinro_ctrl data folder '{kind}' is missing from the installation")


#: What one file of each data folder is, for messages.
_FILE_KIND = {"configs": "scenario", "assets": "model"}


def _file_kind(kind: str) -> str:
    return _FILE_KIND.get(kind, kind.rstrip("s"))


def _check_name(kind: str, name: str | Path) -> Path:
    """``name`` as a path that can name a file: not empty, not a folder.

    Raises:
        FileNotFoundError: an empty name (an unset shell variable?).
        IsADirectoryError: ``name`` is a folder (``'.'``, ``'configs/'``), here or in the ``kind`` folder.
    """
    if not str(name).strip():
        raise FileNotFoundError(f"the {_file_kind(kind)} name is empty (an unset shell variable?): give a file or name")
    p = Path(name)
    if p.is_dir() or not p.name or p.name in (".", ".."):
        raise IsADirectoryError(f"'{name}' is a folder, not a {_file_kind(kind)} file")
    return p


def find_data(kind: str, name: str | Path, suffix: str) -> Path:
    """An existing file path as given, else the shipped file of that name (see :func:`find_shipped`).

    Raises:
        FileNotFoundError: no such file (or an empty name), listing the shipped ones.
        IsADirectoryError: ``name`` is a folder, not a file.
    """
    p = _check_name(kind, name)
    if p.is_file():
        return p.resolve()
    return find_shipped(kind, name, suffix)


def find_shipped(kind: str, name: str | Path, suffix: str) -> Path:
    """The shipped file ``name`` (``suffix`` optional) in the ``kind`` folder only.

    Raises:
        FileNotFoundError: no such file (or an empty name), listing the shipped ones.
        IsADirectoryError: ``name`` is a folder (also a folder of the shipped ones, ``regression/``).
    """
    p = _check_name(kind, name)
    root = data_root(kind)
    candidates = [root / p] if p.suffix else [root / p, root / p.with_suffix(suffix)]
    for candidate in candidates:
        if candidate.is_file():
            return candidate
    if (root / p).is_dir() and not p.is_absolute():
        raise IsADirectoryError(f"'{name}' is a folder of shipped {kind}, not a {_file_kind(kind)} file")
    shipped = ", ".join(list_data(kind, suffix)) or "none"
    raise FileNotFoundError(f"no {kind[:-1]} named '{name}'; shipped {kind}: {shipped}")


def list_data(kind: str, suffix: str) -> list[str]:
    """The shipped files of ``kind`` ending in ``suffix``, relative to the folder, sorted."""
    root = data_root(kind)
    return sorted(str(p.relative_to(root)) for p in root.rglob(f"*{suffix}"))


def asset_path(name: str | Path) -> Path:
    """Path of an MJCF asset: an existing path, or a shipped name such as ``"cartpole.xml"``.

    Raises:
        FileNotFoundError: listing the shipped assets.
    """
    return find_data("assets", name, ".xml")


def shipped_asset(name: str | Path) -> Path:
    """Path of a shipped MJCF asset, looked up in the package's assets folder only.

    A same-named file in the current directory never shadows it.

    Raises:
        FileNotFoundError: listing the shipped assets.
    """
    return find_shipped("assets", name, ".xml")


def list_assets() -> list[str]:
    """Names of the shipped MJCF assets."""
    return list_data("assets", ".xml")


def config_path(name: str | Path) -> Path:
    """Path of a scenario: an existing path, or a shipped name such as
    ``"cartpole_lqr"``, ``"cartpole_lqr.toml"`` or ``"regression/cartpole_lqr.toml"``.

    Raises:
        FileNotFoundError: listing the shipped scenarios.
    """
    return find_data("configs", name, ".toml")


def shipped_config(name: str | Path) -> Path:
    """A scenario shipped with the package, never a same-named file in the current directory.

    Raises:
        FileNotFoundError: listing the shipped scenarios.
    """
    return find_shipped("configs", name, ".toml")


def regression_dir() -> Path:
    """The folder of shipped regression scenarios and their baselines."""
    return data_root("configs") / "regression"


def list_configs() -> list[str]:
    """Shipped scenario files, relative to the configs folder (``regression/…`` included)."""
    return list_data("configs", ".toml")
