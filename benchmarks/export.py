"""C step time of exported controllers beside the Python step, measured by each folder's own test program.

For each scenario: ``export_scenario`` records the Python loop (both loops), writes the folder, builds it
with ``-O2`` and runs its test program, which checks C against Python on every recorded step and then
times the step (median over repeated passes of the recording: wall time per step). The Python figure is
the median of the estimator update plus the controller call replaying the same recording.

Goals (issue 27): LQR step <= 0.2 µs; EKF step on the quadrotor <= 2 µs.

Run: ``python benchmarks/export.py [--repeats R]`` (the machine is shared: take the median of repeats).
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
from pathlib import Path

from shinro_ctrl.export.pipeline import export_scenario
from shinro_ctrl.resources import config_path

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


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=3, help="exports per scenario (median of their timings)")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
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
        print(f"{'scenario':28s} {'steps':>6s} {'max rel err':>11s} {'C step':>10s} {'Python step':>12s} {'goal':>8s}")
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


if __name__ == "__main__":
    main()
