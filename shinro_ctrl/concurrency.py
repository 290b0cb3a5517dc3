"""Detecting concurrent use of a stateful object (the package's thread policy, issue 23.3).

A public object that keeps state or buffers between calls either works
correctly under concurrent calls (a lock around its buffer use) or detects a
second thread and raises :class:`~shinro_ctrl.errors.ConcurrentUse`;
:class:`CallGuard` is the detector every such object holds.
"""

from __future__ import annotations

import threading

from shinro_ctrl.errors import ConcurrentUse

__all__ = ["CallGuard"]


class CallGuard:
    """Detects a call entering a stateful object while another thread is inside it.

    The code that reads and writes the object's state or buffers runs inside
    ``if not guard.acquire(False): raise guard.refused()`` ... ``guard.release()``
    (a non-blocking lock: about 0.1 µs, the bound C methods of a
    :class:`threading.Lock`), or ``with guard:`` where a few tenths of a µs do
    not matter. A second thread is refused with
    :class:`~shinro_ctrl.errors.ConcurrentUse` instead of interleaving. A copy
    or a pickle of the object gets a fresh guard.

    Args:
        what: The object's name, for the message.
    """

    __slots__ = ("acquire", "release", "what")

    def __init__(self, what: str):
        lock = threading.Lock()
        self.acquire, self.release, self.what = lock.acquire, lock.release, what

    def refused(self) -> ConcurrentUse:
        """The error for a call that found the object busy."""
        return ConcurrentUse(
            f"{self.what} was called while another thread is inside it: it keeps state or buffers between "
            "calls, so its calls must come in order from one thread; use one object per thread"
        )

    def __enter__(self) -> None:
        if not self.acquire(False):
            raise self.refused()

    def __exit__(self, *exc: object) -> None:
        self.release()

    def __reduce__(self) -> tuple[type, tuple[str]]:
        return CallGuard, (self.what,)
