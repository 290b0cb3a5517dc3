"""Ctrl-C (SIGINT) handling shared by the IPOPT solves and the process pools.

Three places lose or mangle a Ctrl-C unless told otherwise:

- **CasADi's nlpsol** polls Python's signal handlers during an IPOPT solve: the handler's ``KeyboardInterrupt``
  stops IPOPT, but CasADi swallows it and returns the status ``NonIpopt_Exception_Thrown`` (the status of any
  other exception in a callback), which a caller would report as a failed solve. :func:`solve_interruptibly`
  (built on :func:`interrupts`) re-raises the ``KeyboardInterrupt``.
- **Pool workers** are in the terminal's process group, so a Ctrl-C reaches them too: the forkserver printed a
  ``KeyboardInterrupt`` traceback when it came while the server preloaded its modules (SciPy...), or died of it
  while Python started (the parent's next submit then failed with ``EOFError``), and a worker can be hit while
  it imports what its initializer needs, before that initializer runs. :func:`forkserver_context` starts the
  forkserver with SIGINT ignored: an ignored signal stays ignored across ``exec`` and Python then leaves it
  alone, the server keeps it for the workers it forks, so no worker ever sees a Ctrl-C. The parent alone
  handles it: it stops the workers (:func:`stop_pool`) and exits 130. (Blocking SIGINT instead is not
  inherited: the spawn resets the mask.)
- The **parent** must not lose a Ctrl-C that arrives while it starts those processes: :func:`deferred_interrupts`
  holds it and raises it when the block ends, once every started worker is registered and can be stopped.

This module imports nothing but the standard library (the console entry point uses it before the heavy imports).
"""

from __future__ import annotations

import contextlib
import signal
import threading
from collections.abc import Callable, Iterator, Sequence
from types import FrameType
from typing import TYPE_CHECKING, TypeVar

if TYPE_CHECKING:  # the console entry point imports this module first: the standard library's light part only
    from concurrent.futures import ProcessPoolExecutor
    from multiprocessing.context import BaseContext

__all__ = [
    "caused_by_interrupt",
    "deferred_interrupts",
    "forkserver_context",
    "ignore_sigint",
    "interrupts",
    "solve_interruptibly",
    "stop_pool",
]

T = TypeVar("T")


def caused_by_interrupt(exc: BaseException | None) -> bool:
    """True for a ``KeyboardInterrupt``, or an error raised because of one (inside an import or a C extension)."""
    seen: set[int] = set()
    while exc is not None and id(exc) not in seen:
        if isinstance(exc, KeyboardInterrupt):
            return True
        seen.add(id(exc))
        exc = exc.__cause__ or exc.__context__
    return False


@contextlib.contextmanager
def interrupts() -> Iterator[list[bool]]:
    """Record a Ctrl-C (SIGINT) that arrives inside the block; the list yielded becomes ``[True]``.

    The current SIGINT handler is wrapped: it still runs (normally raising ``KeyboardInterrupt``), and the
    interrupt is recorded even when C code in the block catches that exception. Only the main thread receives
    signals in Python; elsewhere (or when SIGINT is not handled by a Python callable: ignored, default) nothing
    is changed and nothing is recorded.
    """
    hit: list[bool] = []
    if threading.current_thread() is not threading.main_thread():
        yield hit
        return
    previous = signal.getsignal(signal.SIGINT)
    if not callable(previous):  # SIG_IGN, SIG_DFL or None: no Python handler runs
        yield hit
        return

    def record(signum: int, frame: FrameType | None) -> None:
        hit.append(True)
        previous(signum, frame)

    signal.signal(signal.SIGINT, record)
    try:
        yield hit
    finally:
        signal.signal(signal.SIGINT, previous)


def solve_interruptibly(solver: Callable[..., T], **kwargs: object) -> T:
    """Call ``solver(**kwargs)`` (a CasADi ``nlpsol`` Function) so that a Ctrl-C inside it raises ``KeyboardInterrupt``.

    Raises:
        KeyboardInterrupt: SIGINT arrived during the call (CasADi had turned it into the IPOPT status
            ``NonIpopt_Exception_Thrown``, or into a ``RuntimeError``).
    """
    with interrupts() as hit:
        try:
            out = solver(**kwargs)
        except Exception:
            if hit:
                raise KeyboardInterrupt from None
            raise
    if hit:
        raise KeyboardInterrupt
    return out


@contextlib.contextmanager
def deferred_interrupts() -> Iterator[None]:
    """A Ctrl-C that arrives inside the block is held and raised as ``KeyboardInterrupt`` when the block ends.

    In the main thread the Python handler is replaced by one that only records the signal, and SIGINT is blocked
    in the calling thread (so the kernel keeps it pending rather than hand it to this thread while the handler
    is briefly ``SIG_IGN``, see :func:`forkserver_context`). When the block ends the mask and handler are
    restored (a pending SIGINT is delivered then, and recorded) and a recorded Ctrl-C is raised, unless SIGINT
    was ignored before the block.
    """
    held: list[int] = []
    main = threading.current_thread() is threading.main_thread() and signal.getsignal(signal.SIGINT) is not None
    previous = signal.signal(signal.SIGINT, lambda signum, frame: held.append(signum)) if main else None
    mask = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT}) if hasattr(signal, "pthread_sigmask") else None
    try:
        yield
    finally:
        if mask is not None:
            signal.pthread_sigmask(signal.SIG_SETMASK, mask)  # a pending SIGINT is delivered here: recorded
        if main:
            signal.signal(signal.SIGINT, previous)
    if held and previous != signal.SIG_IGN:
        raise KeyboardInterrupt


def forkserver_context(preload: Sequence[str]) -> BaseContext:
    """The ``forkserver`` multiprocessing context, its server started with SIGINT ignored (see the module docstring).

    Workers fork from a clean server process (safe when this process runs threads, e.g. a Dask client), and the
    preloaded imports are paid once, not once per worker. A server already running is kept (in the CLI the first
    pool starts it here; a server another caller started earlier may not ignore SIGINT, hence the workers'
    :func:`ignore_sigint` initializer too).
    """
    import multiprocessing
    from multiprocessing import forkserver, resource_tracker

    ctx = multiprocessing.get_context("forkserver")
    ctx.set_forkserver_preload(list(preload))
    # The forkserver starts the resource tracker first, and spawning it ends with an unconditional
    # pthread_sigmask(SIG_UNBLOCK, {SIGINT, SIGTERM}): inside the block below that would unblock SIGINT while it
    # is ignored, and a Ctrl-C then would be lost (the command ran to the end, exit 0). Start it before.
    resource_tracker.ensure_running()
    with deferred_interrupts():
        ignoring = threading.current_thread() is threading.main_thread()
        handler = signal.signal(signal.SIGINT, signal.SIG_IGN) if ignoring else None
        try:  # fork + exec of the server: milliseconds
            forkserver.ensure_running()
        finally:
            if ignoring:
                signal.signal(signal.SIGINT, handler)
    return ctx


def ignore_sigint() -> None:
    """Pool initializer: a worker ignores Ctrl-C (it reaches the whole process group; the parent stops us)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def stop_pool(pool: ProcessPoolExecutor) -> None:
    """Cancel the queued tasks and terminate the workers (promptly, without their tracebacks)."""
    processes = list((getattr(pool, "_processes", None) or {}).values())  # no public terminate before 3.14
    pool.shutdown(wait=False, cancel_futures=True)
    for proc in processes:
        if proc.is_alive():
            proc.terminate()
    for proc in processes:
        proc.join(timeout=5)
