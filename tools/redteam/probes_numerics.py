"""Numerics through the Python API: extreme and non-finite states and inputs, gimbal lock, tiny and huge dt,
operating points that are not equilibria, short horizons, bad weights."""

from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from api import get, judge
from harness import Outcome, Probe

CAT = "numerics"
PLANTS = (
    "CartPole",
    "InvertedPendulum",
    "DoublePendulum",
    "Quadrotor",
    "HolonomicMobileRobot",
    "ArmRobot",
    "MjcfPlant",
)


def _plant(name: str, **kw: Any) -> Any:
    return get("shinro_ctrl.plants", name)(**kw)


def _state_variants(n: int) -> dict[str, tuple[Any, str]]:
    """name -> (state, expectation)."""
    z = np.zeros(n)
    return {
        "nan": (np.r_[math.nan, z[1:]], "refuse"),
        "inf": (np.r_[math.inf, z[1:]], "refuse"),
        "neg_inf": (np.r_[z[:-1], -math.inf], "refuse"),
        "1e308": (np.full(n, 1e308), "either"),
        "1e154": (np.full(n, 1e154), "either"),
        "-1e200": (np.full(n, -1e200), "either"),
        "len_plus1": (np.zeros(n + 1), "refuse"),
        "len_minus1": (np.zeros(max(n - 1, 0)), "refuse"),
        "2d": (np.zeros((n, 2)), "refuse"),
        "strings": (["a"] * n, "refuse"),
        "none": (None, "either"),
    }


def _input_variants(m: int) -> dict[str, tuple[Any, str]]:
    z = np.zeros(m)
    return {
        "nan": (np.r_[math.nan, z[1:]], "refuse"),
        "inf": (np.r_[math.inf, z[1:]], "refuse"),
        "1e308": (np.full(m, 1e308), "either"),
        "len_plus1": (np.zeros(m + 1), "refuse"),
        "empty": (np.zeros(0), "refuse"),
    }


_DIMS = {
    "CartPole": (4, 1),
    "InvertedPendulum": (2, 1),
    "DoublePendulum": (4, 2),
    "Quadrotor": (12, 4),
    "HolonomicMobileRobot": (3, 3),
    "ArmRobot": (6, 6),
    "MjcfPlant": (4, 1),
}


def _op(name: str) -> tuple[np.ndarray, np.ndarray]:
    p = _plant(name)
    x, u = p.equilibrium()
    return np.asarray(x, float), np.asarray(u, float)


def probes() -> list[Probe]:
    out: list[Probe] = []

    def add(name: str, func: Callable[[Path], Outcome], timeout: float = 30.0) -> None:
        out.append(Probe(f"{CAT}/{name}", CAT, kind="py", func=func, timeout=timeout))

    for pname in PLANTS:
        n, m = _DIMS[pname]
        for vname, (x, exp) in _state_variants(n).items():
            if vname in ("none", "strings"):
                continue

            def dyn(wd: Path, pname=pname, x=x, exp=exp) -> Outcome:
                p = _plant(pname)
                _, u0 = _op(pname)
                return judge(lambda: p.dynamics(x, u0), exp, ("x", "state", "finite", "nan", "inf", "shape", "length"))

            def lin(wd: Path, pname=pname, x=x, exp=exp) -> Outcome:
                p = _plant(pname)
                _, u0 = _op(pname)
                return judge(
                    lambda: p.linearize(x, u0), exp, ("x0", "x", "state", "finite", "nan", "inf", "shape", "length")
                )

            def setstep(wd: Path, pname=pname, x=x, exp=exp) -> Outcome:
                p = _plant(pname)
                _, u0 = _op(pname)

                def call() -> Any:
                    p.set_state(x)
                    return p.step(u0)

                return judge(call, exp, ("x", "state", "finite", "nan", "inf", "shape", "length", "diverged"))

            add(f"{pname}/dynamics/x_{vname}", dyn)
            add(f"{pname}/linearize/x_{vname}", lin)
            add(f"{pname}/set_state_step/x_{vname}", setstep)
        for vname, (u, exp) in _input_variants(m).items():

            def dyn_u(wd: Path, pname=pname, u=u, exp=exp) -> Outcome:
                p = _plant(pname)
                x0, _ = _op(pname)
                return judge(lambda: p.dynamics(x0, u), exp, ("u", "input", "finite", "nan", "inf", "shape", "length"))

            def step_u(wd: Path, pname=pname, u=u, exp=exp) -> Outcome:
                p = _plant(pname)
                return judge(
                    lambda: p.step(u), exp, ("u", "input", "finite", "nan", "inf", "shape", "length", "diverged")
                )

            def lin_u(wd: Path, pname=pname, u=u, exp=exp) -> Outcome:
                p = _plant(pname)
                x0, _ = _op(pname)
                return judge(
                    lambda: p.linearize(x0, u), exp, ("u0", "u", "input", "finite", "nan", "inf", "shape", "length")
                )

            add(f"{pname}/dynamics/u_{vname}", dyn_u)
            add(f"{pname}/step/u_{vname}", step_u)
            add(f"{pname}/linearize/u_{vname}", lin_u)
        for dt, exp in ((1e-12, "either"), (1e3, "either"), (0.0, "refuse"), (-0.01, "refuse"), (math.nan, "refuse")):
            if pname == "MjcfPlant" and dt == 1e3:
                continue

            def make(wd: Path, pname=pname, dt=dt, exp=exp) -> Outcome:
                def call() -> Any:
                    p = _plant(pname, dt=dt)
                    _x0, u0 = _op(pname)
                    return [p.step(u0), p.linearize()[0]]

                return judge(call, exp, ("dt",))

            add(f"{pname}/dt_{dt:g}", make)

    # gimbal lock of the quadrotor's ZYX Euler angles
    for pitch in (math.pi / 2, -math.pi / 2, math.pi / 2 - 1e-9, math.pi / 2 + 1e-12):
        x = np.zeros(12)
        x[4] = pitch
        for what in ("linearize", "dynamics", "lqr"):

            def gimbal(wd: Path, x=x, what=what) -> Outcome:
                q = _plant("Quadrotor")
                _, u0 = q.equilibrium()
                if what == "linearize":
                    return judge(
                        lambda: q.linearize(x, u0), "either", ("pitch", "gimbal", "singular", "euler"), limit=1e8
                    )
                if what == "dynamics":
                    xr = x.copy()
                    xr[9:12] = 0.3  # body rates: the Euler-rate map divides by cos(pitch)
                    return judge(
                        lambda: q.dynamics(xr, u0), "either", ("pitch", "gimbal", "singular", "euler"), limit=1e8
                    )
                LQR = get("shinro_ctrl.controllers", "LQR")
                return judge(
                    lambda: LQR.from_plant(q, np.ones(12), np.ones(4), x0=x, u0=u0).K,
                    "either",
                    ("pitch", "gimbal", "singular", "euler", "equilibrium", "x0"),
                    limit=1e8,
                )

            add(f"Quadrotor/gimbal_{what}_pitch_{pitch:.12g}", gimbal)

    # ---- LQR
    Q4, R1 = np.array([10.0, 1, 100, 1]), np.array([0.1])

    def lqr(**kw: Any) -> Any:
        return get("shinro_ctrl.controllers", "LQR").from_plant(
            _plant("CartPole", **kw.pop("plant", {})), kw.pop("Q", Q4), kw.pop("R", R1), **kw
        )

    lqr_cases: dict[str, tuple[Callable[[], Any], str, tuple[str, ...]]] = {
        "x0_not_equilibrium": (lambda: lqr(x0=[0.0, 1.0, 0.0, 0.0]).K, "refuse", ("x0", "equilibrium")),
        "u0_not_equilibrium": (lambda: lqr(u0=[1.0]).K, "refuse", ("u0", "equilibrium")),
        "x0_tilted": (lambda: lqr(x0=[0.0, 0.0, 0.5, 0.0]).K, "refuse", ("x0", "equilibrium")),
        "Q_nan": (lambda: lqr(Q=[math.nan, 1, 1, 1]).K, "refuse", ("Q",)),
        "Q_negative": (lambda: lqr(Q=[-1.0, 1, 1, 1]).K, "refuse", ("Q",)),
        "Q_wrong_len": (lambda: lqr(Q=[1.0, 1, 1]).K, "refuse", ("Q",)),
        "Q_inf": (lambda: lqr(Q=[math.inf, 1, 1, 1]).K, "refuse", ("Q",)),
        "R_zero": (lambda: lqr(R=[0.0]).K, "refuse", ("R",)),
        "R_negative": (lambda: lqr(R=[-1.0]).K, "refuse", ("R",)),
        "R_nan": (lambda: lqr(R=[math.nan]).K, "refuse", ("R",)),
        "R_huge": (lambda: lqr(R=[1e300]).K, "either", ("R",)),
        "Q_tiny": (lambda: lqr(Q=[1e-300] * 4).K, "either", ("Q",)),
        "dt_1e-9": (lambda: lqr(plant={"dt": 1e-9}).K, "ok", ()),
        "dt_1e-6": (lambda: lqr(plant={"dt": 1e-6}).K, "ok", ()),
        "dt_10": (lambda: lqr(plant={"dt": 10.0}).K, "either", ("dt",)),
        "plant_none": (lambda: get("shinro_ctrl.controllers", "LQR").from_plant(None, Q4, R1), "refuse", ("plant",)),
        "plant_class": (
            lambda: get("shinro_ctrl.controllers", "LQR").from_plant(get("shinro_ctrl.plants", "CartPole"), Q4, R1),
            "refuse",
            ("plant", "class", "instance"),
        ),
        "call_x_1e308": (lambda: lqr()(np.full(4, 1e308)), "refuse", ("x", "state", "finite", "overflow")),
        "call_x_nan": (lambda: lqr()(np.array([math.nan, 0, 0, 0])), "refuse", ("x", "state", "finite", "nan")),
        "call_x_wrong_len": (lambda: lqr()(np.zeros(3)), "refuse", ("x", "state", "shape", "length")),
        "call_ref_nan": (lambda: lqr()(np.zeros(4), np.array([math.nan, 0, 0, 0])), "refuse", ("ref", "finite", "nan")),
        "u_min_gt_u_max": (lambda: lqr(u_min=[1.0], u_max=[-1.0]).K, "refuse", ("u_min", "u_max")),
        "integral_unknown": (lambda: lqr(integral=["bogus"]).K, "refuse", ("bogus",)),
        "integral_wrong_Q": (lambda: lqr(integral=["x"]).K, "refuse", ("Q", "integral")),
    }
    for name, (call, exp, needles) in lqr_cases.items():
        add(f"LQR/{name}", lambda wd, call=call, exp=exp, needles=needles: judge(call, exp, needles))

    def stiff_joint(wd: Path) -> Outcome:
        LQR = get("shinro_ctrl.controllers", "LQR")
        A = np.array([[1.0, 0.01], [-1e6 * 0.01, 1.0]])  # a joint of stiffness 1e6 stepped at dt 0.01
        B = np.array([[0.0], [0.01]])

        def call() -> Any:
            return LQR(A, B, np.eye(2), np.eye(1)).K

        def stabilizes(K: Any) -> str | None:
            rho = max(abs(np.linalg.eigvals(A - B @ np.asarray(K))))
            return None if rho < 1 else f"closed loop not stable (spectral radius {rho:.3g})"

        return judge(call, "ok", (), check=stabilizes)

    add("LQR/stiff_joint_1e6", stiff_joint)

    def k_mutable(wd: Path) -> Outcome:
        c = lqr()
        u_before = np.asarray(c(np.array([0.0, 0, 0.1, 0]))).copy()
        try:
            c.K[0, 0] = 1e6
        except (ValueError, TypeError, AttributeError) as exc:
            return Outcome("ok", f"K is read-only ({type(exc).__name__})")
        u_after = np.asarray(c(np.array([0.0, 0, 0.1, 0])))
        if not np.allclose(u_before, u_after):
            return Outcome("wrong_answer_exit0", "a caller mutating lqr.K changed the controller's output")
        return Outcome("ok", "K is a copy")

    add("LQR/K_mutable", k_mutable)

    # ---- Linear MPC
    def mpc(solver: str = "osqp", **kw: Any) -> Any:
        LinearMPC = get("shinro_ctrl.controllers", "LinearMPC")
        opts: dict[str, Any] = {"horizon": 20, "u_min": [-3.0], "u_max": [3.0], "solver": solver}
        opts.update(kw)
        return LinearMPC.from_plant(_plant("CartPole", dt=0.02), kw.pop("Q", Q4), R1, **opts)

    def unstable_closed_loop(wd: Path) -> Outcome:
        return judge(lambda: mpc(horizon=1, terminal_cost="Q"), "refuse", ("horizon", "terminal", "stable"))

    add("LinearMPC/horizon1_terminal_Q", unstable_closed_loop)
    mpc_cases: dict[str, tuple[Callable[[], Any], str, tuple[str, ...]]] = {}
    for solver in ("osqp", "daqp"):
        mpc_cases.update(
            {
                f"{solver}/horizon_0": (lambda s=solver: mpc(s, horizon=0), "refuse", ("horizon",)),
                f"{solver}/horizon_neg": (lambda s=solver: mpc(s, horizon=-3), "refuse", ("horizon",)),
                f"{solver}/horizon_float": (lambda s=solver: mpc(s, horizon=2.5), "refuse", ("horizon",)),
                f"{solver}/horizon_huge": (lambda s=solver: mpc(s, horizon=10**7), "refuse", ("horizon",)),
                f"{solver}/u_min_gt_u_max": (
                    lambda s=solver: mpc(s, u_min=[1.0], u_max=[-1.0]),
                    "refuse",
                    ("u_min", "u_max"),
                ),
                f"{solver}/call_x_nan": (
                    lambda s=solver: mpc(s)(np.array([math.nan, 0, 0, 0])),
                    "refuse",
                    ("x", "state", "finite", "nan"),
                ),
                f"{solver}/call_x_1e308": (
                    lambda s=solver: mpc(s)(np.full(4, 1e308)),
                    "refuse",
                    ("x", "state", "finite", "infeasible"),
                ),
                f"{solver}/call_infeasible_state": (
                    lambda s=solver: mpc(s, x_min=[-0.1, -1e9, -1e9, -1e9], x_max=[0.1, 1e9, 1e9, 1e9])(
                        np.array([5.0, 0, 0, 0])
                    ),
                    "refuse",
                    ("infeasible", "x_max", "bound"),
                ),
                f"{solver}/call_ok": (lambda s=solver: mpc(s)(np.array([0.0, 0, 0.1, 0])), "ok", ()),
            }
        )
    mpc_cases["osqp/settings_nan"] = (
        lambda: mpc("osqp", osqp_settings={"eps_abs": math.nan}),
        "refuse",
        ("eps_abs", "osqp_settings"),
    )
    mpc_cases["osqp/settings_unknown"] = (lambda: mpc("osqp", osqp_settings={"bogus": 1}), "refuse", ("bogus",))
    mpc_cases["solver_bogus"] = (lambda: mpc("bogus"), "refuse", ("solver", "bogus"))
    for name, (call, exp, needles) in mpc_cases.items():
        add(f"LinearMPC/{name}", lambda wd, call=call, exp=exp, needles=needles: judge(call, exp, needles))

    # ---- Nonlinear MPC
    def nmpc(**kw: Any) -> Any:
        NMPC = get("shinro_ctrl.controllers", "NonlinearMPC")
        opts: dict[str, Any] = {"horizon": 20, "u_min": [-1.0], "u_max": [1.0]}
        opts.update(kw)
        return NMPC.from_plant(_plant("InvertedPendulum", dt=0.05), np.array([10.0, 0.1]), np.array([1.0]), **opts)

    nmpc_cases: dict[str, tuple[Callable[[], Any], str, tuple[str, ...]]] = {
        "soft_tight_bounds": (
            lambda: nmpc(soft=True, x_min=[-0.01, -0.01], x_max=[0.01, 0.01])(np.array([0.5, 0.0])),
            "ok",
            (),
        ),
        "soft_tight_bounds_ipopt": (
            lambda: nmpc(soft=True, x_min=[-0.01, -0.01], x_max=[0.01, 0.01], cold_start="ipopt", iterations=3)(
                np.array([0.5, 0.0])
            ),
            "ok",
            (),
        ),
        "horizon_0": (lambda: nmpc(horizon=0), "refuse", ("horizon",)),
        "horizon_1": (lambda: nmpc(horizon=1)(np.array([0.1, 0.0])), "either", ("horizon",)),
        "call_x_nan": (lambda: nmpc()(np.array([math.nan, 0.0])), "refuse", ("x", "state", "finite", "nan")),
        "call_x_1e308": (lambda: nmpc()(np.array([1e308, 0.0])), "refuse", ("x", "state", "finite")),
        "Qf_wrong_shape": (lambda: nmpc(Qf=np.eye(3)), "refuse", ("Qf",)),
        "osqp_settings_nan": (
            lambda: nmpc(solver="osqp", osqp_settings={"eps_abs": math.nan}),
            "refuse",
            ("eps_abs", "osqp_settings"),
        ),
        "tol_negative": (lambda: nmpc(tol=-1.0), "refuse", ("tol",)),
        "iterations_0": (lambda: nmpc(iterations=0), "refuse", ("iterations",)),
        "dt_mismatch": (lambda: nmpc(dt=0.0), "refuse", ("dt",)),
        "integrator_bogus": (lambda: nmpc(integrator="bogus"), "refuse", ("integrator", "bogus")),
    }
    for name, (call, exp, needles) in nmpc_cases.items():
        add(
            f"NonlinearMPC/{name}",
            lambda wd, call=call, exp=exp, needles=needles: judge(call, exp, needles),
            timeout=60,
        )

    # ---- Kalman filter
    def kf(**kw: Any) -> Any:
        KF = get("shinro_ctrl.estimators.kalman", "KalmanFilter")
        opts: dict[str, Any] = {"Qn": [1e-3], "Rn": [1e-4, 1e-4], "measured": ["x", "theta"]}
        opts.update(kw)
        return KF.from_plant(_plant("CartPole"), **opts)

    kf_cases: dict[str, tuple[Callable[[], Any], str, tuple[str, ...]]] = {
        "Rn_zero": (lambda: kf(Rn=[0.0, 0.0]), "refuse", ("Rn",)),
        "Rn_negative": (lambda: kf(Rn=[-1.0, 1.0]), "refuse", ("Rn",)),
        "Qn_nan": (lambda: kf(Qn=[math.nan]), "refuse", ("Qn",)),
        "Rn_wrong_len": (lambda: kf(Rn=[1e-4]), "refuse", ("Rn",)),
        "measured_unknown": (lambda: kf(measured=["bogus"]), "refuse", ("bogus",)),
        "update_y_nan": (
            lambda: kf().update(np.array([math.nan, 0.0]), np.zeros(1)),
            "refuse",
            ("y", "finite", "nan", "measurement"),
        ),
        "update_y_wrong_len": (
            lambda: kf().update(np.zeros(3), np.zeros(1)),
            "refuse",
            ("y", "shape", "length", "measurement"),
        ),
        "update_u_inf": (
            lambda: kf().update(np.zeros(2), np.array([math.inf])),
            "refuse",
            ("u", "finite", "inf", "input"),
        ),
        "update_y_1e308": (
            lambda: kf().update(np.full(2, 1e308), np.zeros(1)),
            "either",
            ("y", "finite", "measurement"),
        ),
        "update_ok": (lambda: kf().update(np.array([0.01, 0.02]), np.zeros(1)), "ok", ()),
    }
    for name, (call, exp, needles) in kf_cases.items():
        add(f"KalmanFilter/{name}", lambda wd, call=call, exp=exp, needles=needles: judge(call, exp, needles))
    return out
