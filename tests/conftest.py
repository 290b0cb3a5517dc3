"""Shared fixtures: plant factories and a seeded random generator."""

from __future__ import annotations

import numpy as np
import pytest

from shinro_ctrl.plants import CartPole, DoublePendulum, InvertedPendulum

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
