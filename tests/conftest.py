"""Shared fixtures: plant factories and a seeded random generator; one compiled-code cache per test session.

BLAS runs on one thread in the test process and everything it starts (set before NumPy is imported, so the
xdist workers and the CLI subprocesses inherit it). With ``pytest -n auto`` every core already runs a worker;
OpenBLAS's own threads on top of that oversubscribe the cores and spin while they wait for each other: a
condensed-MPC check took 14 s instead of 2.5 s on two busy cores. The matrices here are small, so one thread
is also the faster choice serially. An explicit setting in the environment wins. NumPy is already loaded when
this file runs (the ``shinro_ctrl.testing`` pytest plugin imports it), so this process's OpenBLAS is also told
directly (:func:`_one_blas_thread`).
"""

from __future__ import annotations

import os
import shutil
import signal
import tempfile

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import ctypes  # noqa: E402

import numpy as np  # noqa: E402  (after the thread settings above)
import pytest  # noqa: E402

from shinro_ctrl.plants import CartPole, DoublePendulum, InvertedPendulum  # noqa: E402


def _one_blas_thread() -> None:
    """Set the OpenBLAS libraries already loaded in this process to one thread (Linux; elsewhere nothing)."""
    if os.environ.get("OPENBLAS_NUM_THREADS") != "1":
        return
    try:
        with open("/proc/self/maps") as maps:
            libs = {line.split()[-1] for line in maps if "openblas" in line.lower() and ".so" in line}
    except OSError:
        return
    for path in libs:
        try:
            lib = ctypes.CDLL(path)
        except OSError:
            continue
        for name in ("openblas_set_num_threads", "scipy_openblas_set_num_threads64_", "openblas_set_num_threads64_"):
            setter = getattr(lib, name, None)
            if setter is not None:
                setter(1)
                break


_one_blas_thread()


def _sigint_reaches_commands() -> None:
    """Undo an inherited "ignore SIGINT" (a suite started in the background: ``make test &``).

    A shell without job control starts background commands with SIGINT ignored, an ignored signal stays ignored
    across ``exec``, and Python then installs no KeyboardInterrupt handler: every command the Ctrl-C tests start
    would run to the end and exit 0. A handler set here is reset to the default at ``exec``, so the xdist
    workers and the commands they start get Python's usual Ctrl-C handling. (The CLI itself keeps an ignored
    SIGINT ignored: a user who runs it under ``nohup`` or in the background means it.)
    """
    if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
        signal.signal(signal.SIGINT, signal.default_int_handler)


_sigint_reaches_commands()

PENDULUM_FAMILY = [InvertedPendulum, CartPole, DoublePendulum]

_OWN_CACHE = "_SHINRO_CTRL_TEST_CACHE_OWNER"


def pytest_configure(config: pytest.Config) -> None:
    """Compiled dynamics (shinro_ctrl.codegen) go to a fresh folder shared by the session's xdist workers.

    Set in the controlling process before the workers start, so they inherit it and each library is compiled once
    per session (the others wait on its lock); a SHINRO_CTRL_CACHE (or SHINRO_CTRL_CFLAGS) the caller set is kept.
    """
    if "SHINRO_CTRL_CACHE" not in os.environ:
        os.environ["SHINRO_CTRL_CACHE"] = tempfile.mkdtemp(prefix="shinro-ctrl-test-cache-")
        os.environ[_OWN_CACHE] = str(os.getpid())
    # the suite compiles every model it loads once and calls each a few times: -O0 compiles in a quarter of -O1's
    # time with the same arithmetic (shinro_ctrl.codegen.default_flags); benchmarks measure the shipped -O1
    os.environ.setdefault("SHINRO_CTRL_CFLAGS", "-O0")


def pytest_unconfigure(config: pytest.Config) -> None:
    if os.environ.get(_OWN_CACHE) == str(os.getpid()):
        shutil.rmtree(os.environ.pop("SHINRO_CTRL_CACHE"), ignore_errors=True)
        del os.environ[_OWN_CACHE]


@pytest.fixture
def rng() -> np.random.Generator:
    """A fresh generator with a fixed seed for every test."""
    return np.random.default_rng(12345)


def random_params(cls, rng: np.random.Generator) -> dict:
    """Random but physical constructor arguments for a pendulum-family plant."""
    if cls is InvertedPendulum:
        return {"mass": rng.uniform(0.05, 2), "length": rng.uniform(0.2, 1.5), "damping": rng.uniform(0, 0.1)}
    if cls is CartPole:
        return {
            "cart_mass": rng.uniform(0.2, 3),
            "pole_mass": rng.uniform(0.05, 1),
            "pole_length": rng.uniform(0.2, 1.5),
            "damping": rng.uniform(0, 0.1),
        }
    return {
        "mass_top": rng.uniform(0.05, 1),
        "mass_bottom": rng.uniform(0.05, 1),
        "length_top": rng.uniform(0.2, 1),
        "length_bottom": rng.uniform(0.2, 1),
    }
