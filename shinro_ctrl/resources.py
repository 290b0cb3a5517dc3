"""Find the shipped scenario files and MJCF assets.

``configs/`` and ``assets/`` live at the repository root and are copied into
the wheel as ``shinro_ctrl/configs`` and ``shinro_ctrl/assets``. Lookup tries
the installed location first, then the repository root (editable install).
The folder lookup itself is the core module :mod:`shinro_ctrl.data_paths`
(which the engine uses for assets); this module adds the scenario files.
"""

from __future__ import annotations

from pathlib import Path

from shinro_ctrl.data_paths import asset_path, data_root, find_data, find_shipped, list_assets, list_data, shipped_asset

__all__ = [
    "asset_path",
    "config_path",
    "list_assets",
    "list_configs",
    "regression_dir",
    "shipped_asset",
    "shipped_config",
]


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
