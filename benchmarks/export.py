"""C step time of exported controllers beside the Python step, measured by each folder's own test program.

For each scenario: ``export_scenario`` records the Python loop (both loops), writes the folder, builds it
with ``-O2`` and runs its test program, which checks C against Python on every recorded step and then
times the step (median over repeated passes of the recording: wall time per step). The Python figure is
the median of the estimator update plus the controller call replaying the same recording.

Goals (issue 27): LQR step <= 0.2 µs; EKF step on the quadrotor <= 2 µs; LinearMPC cart-pole N = 50 with
bounds <= 10 µs (:func:`mpc_rows`); NonlinearMPC RTI cart-pole swing-up N = 40 <= 40 µs (:func:`nmpc_rows`).
The quadrotor EKF row's C step is the EKF update and the LQR together (the goal is the EKF's; the LQR adds
about 0.01 µs).

Run: ``python benchmarks/export.py [--repeats R] [--only mpc|nmpc|cond]`` (the machine is shared: take the median
of repeats).
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
from pathlib import Path

import numpy as np

from shinro_ctrl.controllers._nmpc_ocp import riccati_functions
from shinro_ctrl.controllers.qp.ltv import CondensedLTV
from shinro_ctrl.controllers.qp.prestabilized import PrestabilizedLTV
from shinro_ctrl.export.pipeline import export_scenario
from shinro_ctrl.resources import config_path
from shinro_ctrl.sim import RobotSim

QUAD_EKF = """[plant]
type = "Quadrotor"

[engine]
type = "mujoco"

[controller]
type = "LQR"
Q = [10, 10, 10, 1, 1, 1, 1, 1, 1, 1, 1, 1]
R = [1, 1, 1, 1]

[estimator]
type = "ExtendedKalmanFilter"

[sim]
duration = 1.0
initial_state = [0.2, -0.1, 0.1, 0.05, 0, 0, 0, 0, 0, 0, 0, 0]
measured = ["x", "y", "z", "roll", "pitch", "yaw"]
sensor_noise = [0.001, 0.001, 0.001, 0.001, 0.001, 0.001]
process_noise = [0.01, 0.001, 0.001, 0.001]
seed = 3
"""


QUAD_MPC = """[plant]
type = "Quadrotor"
mass = 0.5
inertia = [3.0e-3, 3.0e-3, 5.0e-3]
dt = 0.01

[engine]
type = "mujoco"

[controller]
type = "LinearMPC"
horizon = 30
Q = [10, 10, 10, 2, 2, 2, 1, 1, 1, 0.1, 0.1, 0.1]
R = [0.1, 200, 200, 200]
u_min = [0.0, -0.05, -0.05, -0.05]
u_max = [9.81, 0.05, 0.05, 0.05]
x_min = [-inf, -inf, -inf, -0.5, -0.5, -inf, -inf, -inf, -inf, -inf, -inf, -inf]
x_max = [inf, inf, inf, 0.5, 0.5, inf, inf, inf, inf, inf, inf, inf]
soft = true

[sim]
duration = 6.0
initial_state = [0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0]
reference = { kind = "constant", value = [1.0, -0.5, 1.5, 0, 0, 0, 0, 0, 0, 0, 0, 0] }
track = ["x", "y", "z"]
"""


def _row(label: str, cfg: Path, goal: float | None, tmp: Path, repeats: int) -> None:
    c_ns, py_s = [], []
    rep = None
    for r in range(repeats):
        rep = export_scenario(cfg, tmp / f"out{r}", cflags="-O2")
        assert rep.build is not None and rep.build.ok, rep.build.summary() if rep.build else "not built"
        c_ns.append(rep.build.c_step_ns)
        py_s.append(rep.python_step_s)
    assert rep is not None and rep.build is not None
    c = statistics.median(c_ns) / 1e3
    py = statistics.median(py_s) * 1e6
    g = f"<= {goal:g} µs" if goal else ""
    print(f"{label:28s} {rep.build.steps:6d} {rep.build.max_rel_err:11.2e} {c:8.3f} µs {py:9.2f} µs {g:>8s}")


def mpc_rows(tmp: Path, repeats: int) -> None:
    """The MPC exports: cart-pole LinearMPC N = 50 with input and cart bounds (configs/cartpole_mpc_mujoco.toml),
    the quadrotor MPC of configs/quadrotor_mpc_mujoco.toml (soft tilt bounds) toward a constant set-point (the
    exported step takes a set-point, not a previewed trajectory).

    The C figure is the test program's: wall time per step over a pass of the recording (bound-active steps,
    which take more active-set iterations, included), median of passes; the Python figure the median step of
    the controller on its DAQP backend.
    """
    quad = tmp / "quadrotor_mpc_setpoint.toml"
    quad.write_text(QUAD_MPC)
    for label, cfg, goal in (
        ("cart-pole LinearMPC N=50", config_path("cartpole_mpc_mujoco.toml"), 10.0),
        ("quadrotor LinearMPC N=30", quad, None),
    ):
        _row(label, cfg, goal, tmp / label.replace(" ", "_"), repeats)


#: Published RTI timings of acados/ACADO for comparable problems (the reference to beat), with their source.
ACADOS_REFERENCE = (
    "reference: ACADO's generated RTI solvers 'formulate and solve practically relevant problems in only a few "
    "tens of microseconds', guiding example the full swing-up of an inverted pendulum (Quirynen, Vukov, Zanon, "
    "Diehl, Optim. Control Appl. Meth. 36:685-704, 2015, doi:10.1002/oca.2152); acados (Verschueren et al., "
    "Math. Prog. Comp., 2022, doi:10.1007/s12532-021-00208-8) benchmarks its RTI against ACADO on a chain of "
    "masses and a pendulum on a cart"
)


def nmpc_rows(tmp: Path, repeats: int) -> None:
    """NonlinearMPC RTI: the cart-pole swing-up of configs/cartpole_nmpc_swingup_mujoco.toml (N = 40, soft cart
    bounds, |F| <= 40 N, ``riccati = true``), exported ``repeats`` times as ``shinro-ctrl export`` does (1,000 recorded
    steps from both loops, verified, ``-O2``).

    Both sides take the Riccati step and, where it breaks a bound, solve the QP in the policy's prestabilized
    variables (condition number ~10; the condensed Hessian's is 1e8-1e9): printed beside the C and Python step are
    the agreement (max relative error, steps above the 1e-9 tolerance; the export fails on any) and acados'
    published figures.
    """
    cfg = config_path("cartpole_nmpc_swingup_mujoco.toml")
    c_ns, py_s = [], []
    rep = None
    for r in range(repeats):
        rep = export_scenario(cfg, tmp / f"nmpc{r}", cflags="-O2")
        assert rep.build is not None and rep.build.ok and not rep.build.heap, rep.build.summary() if rep.build else ""
        c_ns.append(rep.build.c_step_ns)
        py_s.append(rep.python_step_s)
    assert rep is not None and rep.build is not None
    c = statistics.median(c_ns) / 1e3
    py = statistics.median(py_s) * 1e6
    label = "cart-pole NMPC RTI N=40"
    print(f"{label:28s} {rep.build.steps:6d} {rep.build.max_rel_err:11.2e} {c:8.3f} µs {py:9.2f} µs {'<= 40 µs':>8s}")
    print(
        f"  steps above the 1e-9 tolerance: {rep.build.disagreements} of {rep.build.steps}; C step of each export: "
        + ", ".join(f"{v / 1e3:.1f} µs" for v in c_ns)
    )
    print(f"  {ACADOS_REFERENCE}")


def conditioning_rows() -> None:
    """Conditioning of the swing-up's bound-active QPs (standalone, 8 s): the condensed Hessian ``H`` against the
    prestabilized one ``blockdiag(R_e,k)`` (input parts; the slacks' block is ``w2 I`` in both), and the dual Hessian
    ``A_W H_v^-1 A_W^T`` of the prestabilized QP's final working set (slack bounds included).

    After each call the controller is prepared for the next (shifted, linearized): its linearization point and stage
    matrices are read then, and on the calls where the Riccati step breaks a bound both QPs are rebuilt from them
    (CondensedLTV's condensing; the Riccati functions and PrestabilizedLTV).
    """
    sim = RobotSim.from_config(config_path("cartpole_nmpc_swingup_mujoco.toml"), engine="standalone")
    res = sim.run(8.0, progress=False)
    ctrl = sim.controller
    rti, ocp = ctrl.strategy, ctrl.ocp
    o = ocp.options
    n, m, N = ocp.n, ocp.m, ocp.N
    back, fwd = riccati_functions(n, m, N, codegen=False)
    Wt = np.swapaxes(ocp.W, 1, 2).reshape(N * n, n).T
    ctrl.reset()
    rows = []
    saved = None
    for k in range(res.x.shape[0] - 1):
        x, ref = res.x[k], res.ref[k]
        ctrl(x, ref)
        if saved is not None and ctrl.last.qp_iterations > 0:  # this call's QP was the saved point's
            X, U, G = saved
            e, du = (X[1:] - ref).ravel(), (U - ocp.u0).ravel()
            cond = CondensedLTV(G, ocp.W, ocp.R, o.u_min, o.u_max, o.x_min, o.x_max, soft=o.soft)
            cond.build(e, du)
            Gt = G.reshape(N * n, -1).T
            KK, Re = back(Gt, Wt, ocp.R.T, e, du)
            KK = np.array(KK).T.reshape(N, n + 1, m)
            Re = np.array(Re).T.reshape(N, m, m)
            dU, dX, _, _ = (np.array(v).T for v in fwd(Gt, KK.reshape(-1, m).T, Wt, ocp.R.T, e, du, x - X[0]))
            pqp = PrestabilizedLTV(G, o.u_min, o.u_max, o.x_min, o.x_max, soft=o.soft)
            ok, status, _ = pqp.solve(np.swapaxes(KK[:, :n, :], 1, 2), Re, dU, dX, U, X[1:])
            assert ok, status
            act = np.flatnonzero(pqp.lam)
            Aall = np.vstack([np.eye(pqp.nvar), pqp.A])[act]
            dual = Aall @ np.linalg.solve(pqp.H, Aall.T)
            nu = N * m  # the input parts (the slacks' block is w2 I in both)
            rows.append((np.linalg.cond(cond.H[:nu, :nu]), np.linalg.cond(pqp.H[:nu, :nu]), np.linalg.cond(dual)))
        saved = (rti.X.copy(), rti.U.copy(), np.concatenate([rti.A, rti.B, rti.D[:, :, None]], axis=2))
    c = np.array(rows)
    print(f"conditioning over the {len(rows)} bound-active QPs of the standalone swing-up (min - max):")
    print(f"  condensed Hessian H (inputs)     {c[:, 0].min():9.2e} - {c[:, 0].max():9.2e}")
    print(f"  prestabilized blockdiag(R_e,k)   {c[:, 1].min():9.2e} - {c[:, 1].max():9.2e}")
    print(f"  working set's dual Hessian       {c[:, 2].min():9.2e} - {c[:, 2].max():9.2e}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=3, help="exports per scenario (median of their timings)")
    ap.add_argument("--only", choices=("all", "mpc", "nmpc", "cond"), default="all", help="rows to run (default: all)")
    args = ap.parse_args()
    if args.only == "cond":
        conditioning_rows()
        return
    with tempfile.TemporaryDirectory() as tmp:
        print(f"{'scenario':28s} {'steps':>6s} {'max rel err':>11s} {'C step':>10s} {'Python step':>12s} {'goal':>8s}")
        if args.only == "mpc":
            mpc_rows(Path(tmp), args.repeats)
            return
        if args.only == "nmpc":
            nmpc_rows(Path(tmp), args.repeats)
            return
        quad = Path(tmp) / "quadrotor_ekf_lqr.toml"
        quad.write_text(QUAD_EKF)
        cases = [
            ("cart-pole LQR", config_path("cartpole_lqr.toml"), 0.2),
            ("cart-pole LQI (saturated)", config_path("cartpole_lqi_disturbance_mujoco.toml"), None),
            ("cart-pole LQG (Kalman)", config_path("cartpole_lqg.toml"), None),
            ("pendulum EKF + LQR", config_path("pendulum_ekf_mujoco.toml"), None),
            ("quadrotor EKF + LQR", quad, 2.0),
            ("cart-pole TVLQR swing-up", config_path("cartpole_swingup_mujoco.toml"), None),
        ]
        for label, cfg, goal in cases:
            c_ns, py_s = [], []
            rep = None
            for r in range(args.repeats):
                rep = export_scenario(cfg, Path(tmp) / f"out{r}", cflags="-O2")
                assert rep.build is not None and rep.build.ok, rep.build.summary() if rep.build else "not built"
                c_ns.append(rep.build.c_step_ns)
                py_s.append(rep.python_step_s)
            c = statistics.median(c_ns) / 1e3
            py = statistics.median(py_s) * 1e6
            g = f"<= {goal:g} µs" if goal else ""
            print(f"{label:28s} {rep.build.steps:6d} {rep.build.max_rel_err:11.2e} {c:8.3f} µs {py:9.2f} µs {g:>8s}")
        mpc_rows(Path(tmp), args.repeats)
        nmpc_rows(Path(tmp), args.repeats)
        conditioning_rows()


if __name__ == "__main__":
    main()
