"""Model-file identification: the RNEA regressor against MuJoCo, estimates against a known truth, consistency.

Data come from MuJoCo (RK4) on a copy of tests/data/ident_two_link_arm.xml whose forearm mass, centre of mass
and joint dampings were changed (the estimator only has the file), PRBS torques on both joints and sensor noise
on positions and velocities. On a planar arm the upper arm's mass enters only as mass·COM and the forearm's
mass combines with the upper arm's first moment, so the calibrated test identifies the forearm with the upper arm
known, and a second one frees both bodies to check that the inseparable parameters are named and held.
"""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np
import pytest

from shinro_ctrl.errors import UnknownName
from shinro_ctrl.identification import Experiment
from shinro_ctrl.identification.mjcf import identify_model_file
from shinro_ctrl.identification.regressor import (
    InertialRegressor,
    parse_param_names,
    pi_from_theta,
    pseudo_inertia,
    theta_from_pi,
)
from shinro_ctrl.plants import plant_class
from shinro_ctrl.sim.excitation import prbs_signal

MODEL = Path(__file__).parent / "data" / "ident_two_link_arm.xml"
TRUTH = {
    "forearm.mass": 0.65,
    "forearm.com_x": -0.005,
    "forearm.com_z": -0.14,
    "forearm.Iyy": 0.0055,  # unchanged diaginertia: the COM moved, the inertia about it did not
    "shoulder.damping": 0.12,
    "elbow.damping": 0.03,
}


def _truth_model(upper_mass: float | None = None) -> mujoco.MjModel:
    spec = mujoco.MjSpec.from_file(str(MODEL))
    fa = spec.body("forearm")
    fa.mass, fa.ipos = 0.65, [-0.005, 0.0, -0.14]
    if upper_mass is not None:
        spec.body("upper_arm").mass = upper_mass
    spec.joint("shoulder").damping[0] = 0.12
    spec.joint("elbow").damping[0] = 0.03
    return spec.compile()


def _experiment(model: mujoco.MjModel, plant, seed: int, seconds: float = 2.0) -> Experiment:
    dt = model.opt.timestep
    N = round(seconds / dt)
    u = np.c_[
        prbs_signal(2.0, (0.5, 20.0), dt, N, seed=2 * seed + 1), prbs_signal(1.0, (0.5, 20.0), dt, N, seed=2 * seed + 2)
    ]
    d = mujoco.MjData(model)
    Y = np.empty((N + 1, 4))
    Y[0] = np.r_[d.qpos, d.qvel]
    for k in range(N):
        d.ctrl[:] = u[k]
        mujoco.mj_step(model, d)
        Y[k + 1] = np.r_[d.qpos, d.qvel]
    Y += np.random.default_rng(seed).normal(size=Y.shape) * np.r_[2e-4, 2e-4, 2e-3, 2e-3]
    return Experiment(
        t=np.arange(N + 1) * dt, u=u, y=Y, outputs=tuple(plant.state_names), inputs=tuple(plant.input_names)
    )


@pytest.fixture(scope="module")
def plant():
    return plant_class("MjcfPlant")(model=str(MODEL))


def test_regressor_is_mujocos_inverse_dynamics(plant):
    """Y(q, q̇, q̈) π_model = y(q, q̇, q̈, u) at MuJoCo's q̈ (qacc_smooth) for random states and inputs."""
    names = ([b.name for b in plant.tree.bodies], [j.name for j in plant.tree.joints])
    spec = parse_param_names(["body:upper_arm", "body:forearm", "joint:shoulder", "elbow.armature"], *names)
    reg = InertialRegressor(plant, spec)
    m = mujoco.MjModel.from_xml_path(str(MODEL))
    d = mujoco.MjData(m)
    rng = np.random.default_rng(3)
    for _ in range(4):
        d.qpos[:], d.qvel[:], d.ctrl[:] = rng.uniform(-2, 2, 2), rng.normal(size=2), rng.normal(size=2)
        mujoco.mj_forward(m, d)
        Y, y = reg.function(d.qpos, d.qvel, d.qacc_smooth, d.ctrl)
        np.testing.assert_allclose(np.asarray(Y) @ reg.pi_prior, np.asarray(y).ravel(), atol=1e-12)
    # log-Cholesky round trip, and every θ is a consistent body
    for b in range(2):
        pi = reg.pi_prior[10 * b : 10 * b + 10]
        np.testing.assert_allclose(pi_from_theta(theta_from_pi(pi)), pi, atol=1e-14)
    theta = rng.normal(size=10)
    assert np.linalg.eigvalsh(pseudo_inertia(pi_from_theta(theta))).min() > 0


def test_forearm_and_damping_within_their_intervals(plant, tmp_path):
    """True values inside the 95 % intervals, errors a few standard errors at most; undetermined ones held."""
    r = identify_model_file(
        plant, _experiment(_truth_model(), plant, seed=6), ["body:forearm", "joint:shoulder", "joint:elbow"], cutoff=80
    )
    res = r.result
    for name, true in TRUTH.items():
        lo, hi = res.interval[name]
        assert lo <= true <= hi, (name, true, lo, hi)
        assert name not in res.held
        assert 0 < res.std_error[name] < 0.05 * max(abs(true), 0.01), name
        assert res.prior[name] != true or name == "forearm.Iyy"  # the estimator started elsewhere
    assert all(f > 95.0 for f in res.fit_percent.values()), res.fit_percent  # torques explained (97-99 %)
    assert {"forearm.Ixx", "forearm.com_y"} <= set(res.held)
    assert any("forearm.mass·com_y" in s for s in res.unidentifiable)
    assert r.consistent()
    # the identified model file loads and holds the estimates (MuJoCo writes 6 significant digits)
    out = r.write_model(tmp_path / "identified.xml")
    m = mujoco.MjModel.from_xml_path(str(out))
    fa = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "forearm")
    assert m.body_mass[fa] == pytest.approx(res.estimate["forearm.mass"], rel=1e-5)
    np.testing.assert_allclose(
        m.body_ipos[fa][[0, 2]], [res.estimate["forearm.com_x"], res.estimate["forearm.com_z"]], rtol=1e-5
    )
    assert m.dof_damping[0] == pytest.approx(res.estimate["shoulder.damping"], rel=1e-5)


def test_inseparable_parameters_are_named_and_consistency_holds(plant):
    """Both bodies free: the upper arm's mass (only mass·COM acts) and the forearm mass (absorbed by the upper
    arm's first moment) are held and named; the least-squares estimate is not consistent (the held mass makes the
    inertia about the COM indefinite) and the constrained one is."""
    exp = _experiment(_truth_model(upper_mass=1.4), plant, seed=1, seconds=1.0)
    r = identify_model_file(plant, exp, ["body:upper_arm", "body:forearm", "joint:shoulder", "joint:elbow"], cutoff=80)
    res = r.result
    assert "upper_arm.mass" in res.held and "forearm.mass" in res.held
    assert res.estimate["upper_arm.mass"] == pytest.approx(1.2)  # its prior
    assert any("upper_arm.mass and its centre of mass enter only as their product" in s for s in res.unidentifiable)
    assert any("forearm.mass" in s and "upper_arm.mass·com_z" in s for s in res.unidentifiable)
    assert r.constrained
    assert r.consistent()
    for b in range(2):
        assert np.linalg.eigvalsh(pseudo_inertia(r.pi[10 * b : 10 * b + 10])).min() > 0
    assert res.interval["elbow.damping"][0] <= 0.03 <= res.interval["elbow.damping"][1]


@pytest.mark.parametrize(
    ("name", "needle"),
    [
        ("body:nope", "unknown body 'nope' (bodies: upper_arm, forearm)"),
        ("joint:elbow.stiffness", "unknown joint parameter 'stiffness'"),
        ("body:forearm.mass", "identified together; give body:forearm"),
        ("joint:wrist", "unknown joint 'wrist' (joints: shoulder, elbow)"),
    ],
)
def test_bad_parameter_names(plant, name, needle):
    exp = Experiment(
        t=np.arange(3) * 0.002,
        u=np.zeros((2, 2)),
        y=np.zeros((3, 4)),
        outputs=tuple(plant.state_names),
        inputs=tuple(plant.input_names),
    )
    with pytest.raises(UnknownName) as err:
        identify_model_file(plant, exp, [name])
    assert needle in str(err.value) and "\n" not in str(err.value)


def test_cli_identifies_a_model_file_scenario(plant, tmp_path, capsys):
    """``identify`` with body:/joint: names on an MjcfPlant scenario: the table, the model file, the scenario."""
    from shinro_ctrl.cli import main

    exp = _experiment(_truth_model(), plant, seed=6)
    rows = ["t,shoulder,elbow,shoulder_dot,elbow_dot,shoulder_motor,elbow_motor"]
    u = np.vstack([exp.u, np.full((1, 2), np.nan)])
    for t, y, uu in zip(exp.t, exp.y, u, strict=True):
        rows.append(
            ",".join(f"{v:.17g}" for v in (t, *y)) + "," + ",".join("" if np.isnan(v) else f"{v:.17g}" for v in uu)
        )
    csv = tmp_path / "log.csv"
    csv.write_text("\n".join(rows) + "\n")
    cfg = tmp_path / "arm.toml"
    cfg.write_text(f'[plant]\ntype = "MjcfPlant"\nmodel = "{MODEL}"\n\n[controller]\ntype = "LQR"\n')
    out = tmp_path / "out"
    argv = ["identify", str(cfg), "--data", str(csv), "--params", "body:forearm,joint:shoulder,joint:elbow"]
    assert main([*argv, "--cutoff", "80", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "forearm.mass" in text and "saved ident_two_link_arm_identified.xml" in text
    m = mujoco.MjModel.from_xml_path(str(out / "ident_two_link_arm_identified.xml"))
    assert m.body_mass[2] == pytest.approx(0.65, rel=0.01)
    assert str(out / "ident_two_link_arm_identified.xml") in (out / "arm_identified.toml").read_text()
    assert main([*argv, "--plot", str(tmp_path / "fit.png")]) == 2  # options of the grey-box fit only
    assert "--plot: not used with body:/joint: parameters" in capsys.readouterr().err
