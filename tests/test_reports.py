"""Linearization reports: the FD step sweep and the crosscheck plot."""

from __future__ import annotations

import numpy as np
import pytest

from shinro_ctrl.crosscheck import crosscheck
from shinro_ctrl.linearization import complex_step_jacobians
from shinro_ctrl.plants import PLANTS, CartPole
from shinro_ctrl.plots.linearization import eps_sweep, plot_crosscheck, plot_eps_sweep


@pytest.mark.parametrize("name", list(PLANTS))
def test_exact_jacobian_equals_complex_step_reference(name, rng):
    plant = PLANTS[name]()
    x0, u0 = plant.equilibrium()
    x0 = x0 + 0.3 * rng.standard_normal(x0.shape)
    u0 = u0 + 0.3 * rng.standard_normal(u0.shape)
    A, B = plant.linearize(x0, u0)
    Ac, Bc = complex_step_jacobians(plant, x0, u0)
    scale = max(1.0, np.abs(A).max())
    np.testing.assert_allclose(A, Ac, atol=1e-12 * scale)
    np.testing.assert_allclose(B, Bc, atol=1e-12 * scale)


def test_eps_sweep_is_v_shaped_and_exact_is_at_rounding_level(tmp_path):
    sweep = eps_sweep(CartPole(), [0.1, 0.2, 0.3, 0.4], [1.0])
    best = sweep.fd_error.min()
    assert sweep.fd_error[0] > 100 * best and sweep.fd_error[-1] > 100 * best  # both arms of the V
    assert 1e-8 < sweep.best_eps < 1e-3
    assert sweep.exact_error < 1e-12 < best
    png = plot_eps_sweep(sweep, tmp_path / "eps.png")
    assert png.read_bytes()[:4] == b"\x89PNG"


def test_crosscheck_plot(tmp_path):
    png = plot_crosscheck(crosscheck(CartPole()), tmp_path / "cc.png")
    assert png.read_bytes()[:4] == b"\x89PNG" and png.stat().st_size > 20_000
