"""Shared fixtures: plant factories and a seeded random generator.

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

PENDULUM_FAMILY = [InvertedPendulum, CartPole, DoublePendulum]


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
