"""Shared fixtures: plant factories and a seeded random generator; one compiled-code cache per test session."""

from __future__ import annotations

import os
import shutil
import tempfile

import numpy as np
import pytest

from shinro_ctrl.plants import CartPole, DoublePendulum, InvertedPendulum

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
