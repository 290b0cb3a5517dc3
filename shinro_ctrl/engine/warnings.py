"""MuJoCo's warnings: the process-wide handler that records their text, and the warning tables."""

from __future__ import annotations

import threading

import mujoco

__all__ = ["install_warning_handler", "take_warning_messages"]

_WARNINGS = {
    int(w): (w.name, text)
    for w, text in (
        (mujoco.mjtWarning.mjWARN_INERTIA, "invalid body inertia"),
        (mujoco.mjtWarning.mjWARN_CONTACTFULL, "contact buffer full"),
        (mujoco.mjtWarning.mjWARN_CNSTRFULL, "constraint buffer full"),
        (mujoco.mjtWarning.mjWARN_BADQPOS, "NaN, inf or |value| > 1e10 in qpos"),
        (mujoco.mjtWarning.mjWARN_BADQVEL, "NaN, inf or |value| > 1e10 in qvel"),
        (mujoco.mjtWarning.mjWARN_BADQACC, "NaN, inf or |value| > 1e10 in qacc"),
        (mujoco.mjtWarning.mjWARN_BADCTRL, "NaN, inf or |value| > 1e10 in ctrl"),
    )
}
_DOF_WARNINGS = {
    int(mujoco.mjtWarning.mjWARN_BADQPOS),
    int(mujoco.mjtWarning.mjWARN_BADQVEL),
    int(mujoco.mjtWarning.mjWARN_BADQACC),
}
_RESET_WARNINGS = _DOF_WARNINGS

# ------------------------------------------------------ MuJoCo's warning text
_WARNING_LOCK = threading.Lock()
_HANDLER = {"installed": False}
_RECENT = threading.local()
_KEEP_MESSAGES = 8


def _record_warning(message: str) -> None:
    """MuJoCo user-warning handler: keep the text (per thread) instead of printing and logging it."""
    msgs = getattr(_RECENT, "messages", None)
    if msgs is None:
        msgs = _RECENT.messages = []
    msgs.append(" ".join(str(message).split()))
    del msgs[:-_KEEP_MESSAGES]


def install_warning_handler() -> None:
    """Route MuJoCo's warnings to the engine (no print to stdout, no ``MUJOCO_LOG.TXT``).

    Called by the first :class:`MujocoEngine`; calling it again re-installs
    the handler (for example after other code replaced it). Process-wide.
    """
    with _WARNING_LOCK:
        mujoco.set_mju_user_warning(_record_warning)
        _HANDLER["installed"] = True


def take_warning_messages() -> list[str]:
    """MuJoCo warning messages recorded in this thread since the last call (oldest first), then forget them."""
    msgs = getattr(_RECENT, "messages", None)
    if not msgs:
        return []
    out = list(msgs)
    msgs.clear()
    return out
