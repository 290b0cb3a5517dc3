"""Capturing what IPOPT (C code) prints on file descriptors 1 and 2 during a solve."""

from __future__ import annotations

import ctypes
import os
import sys
import tempfile
import threading
from typing import Any


def _c_fflush() -> Any:
    try:
        fflush = ctypes.CDLL(None).fflush
    except (OSError, AttributeError, TypeError):  # pragma: no cover - no C runtime by that name
        return lambda: None
    fflush.argtypes = [ctypes.c_void_p]
    return lambda: fflush(None)


_fflush = _c_fflush()
_LOCK = threading.Lock()  # fds 1 and 2 are process-wide: one captured solve at a time


class _captured:
    """Capture what C code prints on file descriptors 1 and 2 during a block (when ``active``)."""

    def __init__(self, active: bool):
        self.active = active
        self._text = ""

    def __enter__(self) -> _captured:
        if not self.active:
            return self
        _LOCK.acquire()
        for stream in (sys.stdout, sys.stderr):  # keep Python's buffered text in order
            try:
                if stream is not None:
                    stream.flush()
            except (OSError, ValueError):
                pass
        self._saved = []
        try:
            self._tmp = tempfile.TemporaryFile(mode="w+b")
            for fd in (1, 2):
                self._saved.append((fd, os.dup(fd)))
                os.dup2(self._tmp.fileno(), fd)
        except OSError:  # no usable descriptors (embedded interpreters): do not capture
            self._restore()
            self.active = False
            _LOCK.release()
        return self

    def _restore(self) -> None:
        _fflush()
        for fd, saved in self._saved:
            os.dup2(saved, fd)
            os.close(saved)
        self._saved = []

    def __exit__(self, *exc: Any) -> None:
        if not self.active:
            return
        try:
            self._restore()
            self._tmp.seek(0)
            self._text = self._tmp.read().decode("utf-8", "replace")
            self._tmp.close()
        finally:
            _LOCK.release()

    def text(self) -> str:
        return self._text
