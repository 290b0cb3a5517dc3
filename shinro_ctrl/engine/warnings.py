"""MuJoCo's warnings: the process-wide handler that records their text, and the warning tables.

MuJoCo prints its warnings (``WARNING: XML contains a 'NaN'``, ...) on the
terminal unless a handler takes them. The handler installed here keeps their
text per thread instead; the engine turns the ones of a step into errors, and
the model loader (:func:`collect_messages`) reports the ones of a model file
as a :class:`ModelWarning`, which the CLI prints as ``warning: ...`` after a
successful command (never as stray lines of MuJoCo's own).
"""

from __future__ import annotations

import threading
from collections.abc import Iterator
from contextlib import contextmanager

import mujoco

__all__ = ["ModelWarning", "collect_messages", "install_warning_handler", "take_warning_messages"]


class ModelWarning(UserWarning):
    """A model file loads, but something about it deserves a word (MuJoCo's own warnings, a welded base)."""


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


@contextmanager
def collect_messages() -> Iterator[list[str]]:
    """Collect MuJoCo's warnings of the ``with`` block in this thread (none reach the terminal).

    Installs the handler if needed. Messages recorded before the block stay
    for the next :func:`take_warning_messages`; the block's own go into the
    yielded list only.

    Yields:
        The list the block's messages are appended to when it ends.
    """
    with _WARNING_LOCK:
        if not _HANDLER["installed"]:
            mujoco.set_mju_user_warning(_record_warning)
            _HANDLER["installed"] = True
    before = take_warning_messages()
    out: list[str] = []
    try:
        yield out
    finally:
        out.extend(take_warning_messages())
        if before:
            _RECENT.messages = before
