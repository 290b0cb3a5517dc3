"""What the thread-policy tests share (issue 23.3): threads started together, and a call held in progress."""

from __future__ import annotations

import threading
from collections.abc import Callable, Iterable
from typing import Any

import numpy as np


def in_threads(work: Callable[[Any], Any], args: Iterable[Any]) -> list[Any]:
    """``work(arg)`` in one thread per ``arg``, released together by a barrier; the results in ``args`` order.

    The first exception a thread raised is re-raised here, after every thread has ended.
    """
    args = list(args)
    barrier = threading.Barrier(len(args))
    out: list[Any] = [None] * len(args)
    errors: list[BaseException] = []

    def run(i: int) -> None:
        barrier.wait()
        try:
            out[i] = work(args[i])
        except BaseException as exc:  # re-raised in the calling thread below
            errors.append(exc)

    threads = [threading.Thread(target=run, args=(i,)) for i in range(len(args))]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    if errors:
        raise errors[0]
    return out


class BlockingArray:
    """An array-like whose conversion (``np.asarray``) waits until released: a call provably in progress.

    ``entered`` is set when the call starts converting it; the call goes on once ``release`` is set.
    """

    def __init__(self, value: Any):
        self.value = np.asarray(value, dtype=float)
        self.entered = threading.Event()
        self.release = threading.Event()

    def __array__(self, dtype: Any = None, copy: Any = None) -> np.ndarray:
        self.entered.set()
        assert self.release.wait(60)
        return self.value if dtype is None else self.value.astype(dtype)
