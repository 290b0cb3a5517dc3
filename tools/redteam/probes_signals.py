"""Signals: SIGINT (Ctrl-C of the whole process group, as a terminal sends it) and SIGTERM at several moments of
a run, sweep, design, trade-off, plan (IPOPT) and NMPC cold start, in real subprocesses."""

from __future__ import annotations

import signal
import tomllib
from pathlib import Path

from fixtures import dump_toml, write_text
from harness import Probe

CAT = "signals"


def _consistent_out(folder: str, names: tuple[str, ...]):
    """An --out folder is all or nothing: absent, or holding every file of the set."""

    def check(wd: Path) -> str | None:
        d = wd / folder
        if not d.exists():
            return None
        have = {p.name for p in d.iterdir()}
        missing = [n for n in names if n not in have]
        if missing and have:
            return f"partial {folder}/ left behind: has {sorted(have)[:5]}, missing {missing}"
        return None

    return check


def probes(configs: Path) -> list[Probe]:
    out: list[Probe] = []
    swingup = tomllib.loads((configs / "cartpole_swingup_mujoco.toml").read_text())
    swingup["plan"]["knots"] = 400  # a long IPOPT solve
    slow_plan = dump_toml(swingup)
    nmpc = tomllib.loads((configs / "pendulum_nmpc_mujoco.toml").read_text())
    nmpc["controller"].update({"horizon": 400, "cold_start": "ipopt", "init_iterations": 3000})
    slow_nmpc = dump_toml(nmpc)
    run_set = ("metrics.json", "result.npz", "scenario.toml", "run.png")
    cases: list[tuple[str, list[str], str | None, object, object]] = [
        # (name, argv, marker that starts the clock, setup, check)
        ("run_long", ["run", "cartpole_lqr_mujoco", "--duration", "120"], "running", None, None),
        (
            "run_long_out",
            ["run", "cartpole_lqr", "--duration", "300", "--out", "o"],
            "running",
            None,
            _consistent_out("o", run_set),
        ),
        ("run_nmpc", ["run", "pendulum_nmpc_mujoco", "--duration", "60"], "running", None, None),
        (
            "sweep_pool",
            [
                "sweep",
                "cartpole_lqr",
                "--param",
                "plant.pole_mass=0.05:0.5",
                "--samples",
                "400",
                "--workers",
                "2",
                "--out",
                "sw",
            ],
            None,
            None,
            _consistent_out("sw", ("sweep.csv", "sweep.json", "sweep.png")),
        ),
        (
            "sweep_serial",
            [
                "sweep",
                "cartpole_lqr",
                "--param",
                "plant.pole_mass=0.05:0.5",
                "--samples",
                "400",
                "--method",
                "serial",
                "--out",
                "sw",
            ],
            None,
            None,
            _consistent_out("sw", ("sweep.csv", "sweep.json", "sweep.png")),
        ),
        ("design_report", ["design", "lqr", "quadrotor_lqr", "--report", "r.html"], None, None, None),
        (
            "tradeoff",
            [
                "design",
                "lqr",
                "cartpole_lqr",
                "--tradeoff",
                "R=1e-3:1e2",
                "--points",
                "200",
                "--workers",
                "2",
                "--out",
                "t",
            ],
            None,
            None,
            _consistent_out("t", ("tradeoff.csv", "tradeoff.json", "tradeoff.png")),
        ),
        ("plan_ipopt", ["plan", "slow.toml", "--out", "o"], None, write_text("slow.toml", slow_plan), None),
        (
            "nmpc_ipopt_cold_start",
            ["run", "nmpc.toml", "--duration", "5"],
            None,
            write_text("nmpc.toml", slow_nmpc),
            None,
        ),
        ("regress", ["regress"], None, None, None),
    ]
    for name, argv, marker, setup, check in cases:
        moments: list[tuple[str, float, str | None]] = [("startup_0.3s", 0.3, None), ("startup_1.2s", 1.2, None)]
        if marker:
            moments += [("mid_0.5s", 0.5, marker), ("mid_2s", 2.0, marker)]
        else:
            moments += [("t_4s", 4.0, None), ("t_7s", 7.0, None)]
        if name in ("run_long", "tradeoff", "sweep_pool", "plan_ipopt"):
            moments += [("t_5.5s", 5.5, None)]
        for mname, at, mk in moments:
            out.append(
                Probe(
                    f"{CAT}/{name}/sigint_{mname}",
                    CAT,
                    kind="proc",
                    argv=argv,
                    expect="interrupt",
                    signal_at=at,
                    signal_marker=mk,
                    setup=setup,
                    check=check,
                    timeout=60,
                )
            )
        out.append(
            Probe(
                f"{CAT}/{name}/sigterm_t_4s",
                CAT,
                kind="proc",
                argv=argv,
                expect="interrupt",
                signal_at=4.0,
                signum=signal.SIGTERM,
                setup=setup,
                check=check,
                timeout=60,
            )
        )
    return out
