"""The compiled constrained linearization (issue 26 item 5) and the completion's messages.

:meth:`ConstrainedDynamics.jacobians` differentiates the KKT residual with the accelerations and forces held
(implicit function theorem), compiles that one function and chains it in NumPy. References, both independent of
that path: the ``cs.jacobian`` of the Schur-complement solution evaluated by CasADi's virtual machine
(:attr:`ConstrainedDynamics.jacobian_function`: another expression, differentiated through the solve), and
central differences of :meth:`ConstrainedDynamics.xdot` (Newton completion on the manifold, then the KKT system).
States off the equilibrium, with velocities, so that the Coriolis and ``J̇v`` terms and the velocity map
``∂v_D/∂q_I`` count. The humanoid (25 DOF, two welded soles) is left to ``benchmarks/contacts.py``: its build
and first compile alone exceed this file's time budget.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest

from shinro_ctrl.codegen import CompilerUnavailable
from shinro_ctrl.errors import InvalidArgument
from shinro_ctrl.multibody.constraints import ConstrainedDynamics
from shinro_ctrl.plants.mjcf import MjcfPlant
from shinro_ctrl.resources import asset_path

ROOT = Path(__file__).resolve().parent.parent
QUADRUPED = ROOT / "assets" / "quadruped.xml"
FEET = ["FL_foot", "FR_foot", "RL_foot", "RR_foot"]
MODELS = {
    "four_bar": (asset_path("gallery/four_bar.xml"), None),
    "gripper": (asset_path("gallery/gripper_equality.xml"), None),
    "biped": (ROOT / "tests" / "data" / "planar_biped_contacts.xml", ["lfoot", "rfoot"]),
    "quadruped": (QUADRUPED, FEET),
}


@pytest.fixture(scope="module", params=list(MODELS))
def model(request: pytest.FixtureRequest) -> MjcfPlant:
    path, contacts = MODELS[request.param]
    return MjcfPlant(path, contacts=contacts) if contacts else MjcfPlant(path)


def _states(plant: MjcfPlant) -> list[tuple[np.ndarray, np.ndarray]]:
    """The operating point and a seeded state near it with velocities and other inputs."""
    rng = np.random.default_rng(7)
    x0, u0 = plant.equilibrium()
    ni = plant.constraints.ni
    x1 = x0 + np.concatenate([0.05 * rng.standard_normal(ni), 0.5 * rng.standard_normal(ni)])
    return [(x0, u0), (x1, u0 + 0.3 * rng.standard_normal(u0.size))]


def test_compiled_jacobians_equal_the_schur_reference_and_central_differences(model: MjcfPlant) -> None:
    cd = model.constraints
    reference = cd.jacobian_function
    h = 1e-6
    for x, u in _states(model):
        A, B = model.linearize(x, u)
        full = cd.complete(x)
        A_ref, B_ref = (m.full() for m in reference(full[: cd.nq], x[cd.ni :], u))
        scale_A, scale_B = max(1.0, np.abs(A_ref).max()), max(1.0, np.abs(B_ref).max())
        assert np.abs(A - A_ref).max() <= 1e-10 * scale_A
        assert np.abs(B - B_ref).max() <= 1e-10 * scale_B
        A_fd = np.column_stack([(cd.xdot(x + h * e, u) - cd.xdot(x - h * e, u)) / (2 * h) for e in np.eye(x.size)])
        B_fd = np.column_stack([(cd.xdot(x, u + h * e) - cd.xdot(x, u - h * e)) / (2 * h) for e in np.eye(u.size)])
        assert np.abs(A - A_fd).max() <= 1e-6 * scale_A
        assert np.abs(B - B_fd).max() <= 1e-6 * scale_B
        assert np.abs(A[cd.ni :, :]).max() > 0.0  # not a vacuous comparison


def test_without_a_compiler_the_virtual_machine_gives_the_same_jacobians(monkeypatch, tmp_path) -> None:
    plant = MjcfPlant(asset_path("gallery/four_bar.xml"))
    (x, u), (x1, u1) = _states(plant)
    compiled = [plant.linearize(x, u), plant.linearize(x1, u1)]
    cd = plant.constraints
    monkeypatch.setenv("CC", "no-such-compiler-cspeed2")
    monkeypatch.setenv("SHINRO_CTRL_CACHE", str(tmp_path))
    vm = ConstrainedDynamics(cd.rb, cd.constraints, active=(0,), q_ref=cd.q_ref)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", CompilerUnavailable)
        for (A, B), (xx, uu) in zip(compiled, [(x, u), (x1, u1)], strict=True):
            A_vm, B_vm = vm.jacobians(xx, uu)
            np.testing.assert_allclose(A_vm, A, rtol=0, atol=1e-12 * max(1.0, np.abs(A).max()))
            np.testing.assert_allclose(B_vm, B, rtol=0, atol=1e-12 * max(1.0, np.abs(B).max()))
    assert not list(tmp_path.iterdir())  # nothing was compiled


def _one_line(exc: pytest.ExceptionInfo[InvalidArgument]) -> str:
    text = str(exc.value)
    assert "\n" not in text
    return text


def test_failed_completion_on_a_floating_base_names_the_joints() -> None:
    plant = MjcfPlant(QUADRUPED, contacts=FEET)  # the module fixture's model (built once per process)
    cd = plant.constraints
    names = cd.independent_names()
    assert names == list(plant.state_names[: cd.ni])  # tangent dofs 8.. map to their joints, not joints[8]
    x = np.concatenate([np.full(cd.ni, 3.0), np.zeros(cd.ni)])  # the feet cannot reach their points
    with pytest.raises(InvalidArgument, match="Newton failed") as exc:
        cd.complete(x)
    text = _one_line(exc)
    assert ", ".join(f"{n} = 3" for n in names) in text
    assert "violates contact" in text


def test_completion_refuses_non_finite_and_far_states_on_the_four_bar() -> None:
    cd = MjcfPlant(asset_path("gallery/four_bar.xml")).constraints
    with pytest.raises(InvalidArgument, match=r"NaN or inf: crank = nan, crank_dot = 0") as exc:
        cd.complete(np.array([np.nan, 0.0]))
    _one_line(exc)
    with pytest.raises(InvalidArgument, match=r"crank_dot = inf"):
        cd.complete(np.array([0.1, np.inf]))
    with pytest.raises(InvalidArgument, match=r"\(crank = 1e\+09\) is 1e\+09 .* from the reference") as exc:
        cd.complete(np.array([1e9, 0.0]))  # would take 4e9 continuation stages: refused, not a hang
    _one_line(exc)
    with pytest.raises(InvalidArgument, match=r"shape \(2,\), got \(3,\)"):
        cd.complete(np.zeros(3))
    # a crank far round (the linkage is a Grashof crank-rocker: every angle closes) still completes
    full = cd.complete(np.array([40.0, 0.0]))
    assert np.abs(cd.residuals(full[: cd.nq])).max() <= 1e-9
