"""The ``design`` command: a controller's gain or problem, its linear analysis, report and weight trade-off."""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import numpy as np

    from shinro_ctrl.engine.model_gap import ModelGap

import argparse
from typing import Any

from shinro_ctrl.cli.common import path_arg
from shinro_ctrl.errors import InvalidArgument

__all__ = ["cmd_design", "register"]


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``design`` to the ``shinro-ctrl`` parser (``sub``: its subparsers)."""
    p = sub.add_parser("design", help="design a controller from a scenario and print it")
    p.add_argument("kind", choices=("lqr", "mpc"))
    p.add_argument("config", metavar="CONFIG")
    p.add_argument(
        "--report",
        type=path_arg,
        metavar="FILE.html",
        help="write a self-contained HTML design report (plots embedded)",
    )
    p.add_argument("--tradeoff", metavar="KEY=LO:HI", help="LQR weight trade-off, e.g. R=1e-3:1e2 or Q[2]=1:1000")
    p.add_argument("--points", type=int, default=20, metavar="N", help="trade-off points, log-spaced (default 20)")
    p.add_argument("--engine", choices=("standalone", "mujoco"), help="trade-off: loop of the nonlinear runs")
    p.add_argument(
        "--out", type=path_arg, metavar="DIR", help="trade-off: write tradeoff.csv, tradeoff.json, tradeoff.png here"
    )
    p.add_argument("--workers", type=int, default=2, metavar="W", help="trade-off: worker processes (default 2)")
    p.set_defaults(func=cmd_design)


def cmd_design(args: argparse.Namespace) -> int:
    import numpy as np

    from shinro_ctrl.sim import RobotSim

    sim = RobotSim.from_config(args.config)  # the scenario's own loop: a bad [engine] table is reported too
    ctrl = sim.controller
    kind = {"lqr": "LQR", "mpc": "LinearMPC"}[args.kind]
    if type(ctrl).__name__ != kind:
        raise InvalidArgument(f"{args.config} configures a {type(ctrl).__name__} controller, not {kind}")
    _check_design_options(args)  # before anything is printed
    np.set_printoptions(precision=5, suppress=True, linewidth=120)
    if args.kind == "lqr":
        _print_lqr(ctrl, sim.initial_state)
    else:
        _print_mpc(sim)
    return _design_analysis(args, sim)


def _check_design_options(args: argparse.Namespace) -> None:
    """``--tradeoff`` and its options, and ``--report``: checked (output paths too) before any work."""
    if args.tradeoff is not None:
        from shinro_ctrl.analysis.tradeoff import parse_tradeoff

        if args.kind != "lqr":
            raise InvalidArgument("--tradeoff sweeps LQR weights: use 'design lqr'")
        if not args.out:
            raise InvalidArgument("--tradeoff needs --out DIR for tradeoff.csv, tradeoff.json and tradeoff.png")
        from shinro_ctrl.analysis.tradeoff import MAX_POINTS, MAX_WORKERS
        from shinro_ctrl.cli.common import _check_count

        _check_count("--points", args.points, MAX_POINTS, low=2)
        _check_count("--workers", args.workers, MAX_WORKERS)
        parse_tradeoff(args.tradeoff)
        from shinro_ctrl.analysis.tradeoff import OUTPUT_FILES
        from shinro_ctrl.files import check_output_folder

        check_output_folder(args.out, OUTPUT_FILES, inputs=[args.config], what="--out folder")
    elif args.out or args.engine or args.points != 20 or args.workers != 2:
        raise InvalidArgument("--out, --engine, --points and --workers go with --tradeoff KEY=LO:HI")
    if args.report:
        from pathlib import Path

        from shinro_ctrl.files import check_output_file

        report = Path(args.report)
        if report.suffix.lower() not in (".html", ".htm"):
            raise InvalidArgument(f"--report: expected a FILE.html, got '{report}'")
        if args.out:
            from shinro_ctrl.cli.common import _inside

            if _inside(report, args.out):
                raise InvalidArgument(
                    f"--report '{report}' is inside --out '{args.out}', which is replaced as a whole: "
                    "put the report elsewhere"
                )
        # only over a report of ours (its generator meta tag), never through a link
        check_output_file(report, inputs=[args.config], what="--report", kind="HTML report")


def _print_lqr(ctrl: Any, x_init: np.ndarray) -> None:
    """The LQR's model, gain, closed-loop poles and predicted cost from ``x_init``."""
    import numpy as np

    model = ctrl.model  # the Controller contract: the LinearModel designed on, or None
    if not ctrl.discrete:
        method = model.method if model is not None else "exact"
        print(f"model: continuous-time {method} linearization (continuous design: K and the poles are continuous)")
    elif model is not None:
        print(f"model: {model.describe()}")
    print("K =")
    print(ctrl.K)
    print("closed-loop poles:")
    for p in ctrl.poles:
        size = f"|p| = {abs(p):.6f}" if getattr(ctrl, "discrete", True) else f"Re p = {p.real:+.6f}"
        print(f"  {p.real:+.6f} {p.imag:+.6f}j   {size}")
    print(f"predicted cost ½ x0ᵀ S x0 from {np.round(x_init, 6).tolist()}: {ctrl.cost_to_go(x_init):.6g}")


def _print_mpc(sim: Any) -> None:
    """The MPC problem and the solve statistics of a short closed-loop run (at most 2 s)."""
    import numpy as np

    ctrl = sim.controller
    if getattr(ctrl, "model", None) is not None:
        print(f"model: {ctrl.model.describe()}")
    print(ctrl.describe())
    dt = sim.plant.dt
    result = sim.run(dt * min(round(sim.scenario.sim.duration / dt), max(1, int(2.0 / dt))))  # <= 2 s, whole steps
    solve = result.solve_times
    print(
        f"closed loop ({len(solve)} steps, {sim.loop}): median call {1e3 * np.median(solve):.3f} ms, "
        f"p95 {1e3 * np.percentile(solve, 95):.3f} ms, max {1e3 * solve.max():.3f} ms"
    )
    print(f"constraint violations: {result.metrics['constraint_violations']}")


def _model_gap(sim: Any) -> ModelGap | None:
    """The model-gap report at the controller's operating point: on the scenario's MuJoCo model when its loop
    is MuJoCo (any plant), else on the model file of a plant built from one; None otherwise."""
    from shinro_ctrl.cli.models import model_gap_of

    plant, ctrl = sim.plant, sim.controller
    x0, u0 = ctrl.x0[: plant.state_dim], ctrl.u0
    if sim.engine is None:
        return model_gap_of(plant, x0, u0)
    from shinro_ctrl.engine.model_gap import engine_model_gap

    engine = sim.engine
    z, ctrl_now = engine.get_state_vector(), engine.data.ctrl.copy()
    try:
        plant.engine_write(engine, x0)
        plant.engine_apply(engine, u0)
        return engine_model_gap(engine)
    finally:  # the loop's engine is left as it was
        engine.set_state_vector(z)
        engine.data.ctrl[:] = ctrl_now


def _print_loop_delay(sim, analysis) -> None:
    """The pure delay the scenario's ``[sim] actuator`` / ``sensor`` put in each input's loop, against its margin.

    At input ``i`` the loop carries the actuator's delay ``d_i`` plus the sensor's: exactly when every measured
    state is delayed alike, at most its largest delay otherwise (the bound is printed as such).
    """
    act, sen = sim.actuator, sim.sensor
    if (act is None or not act.delay.any()) and (sen is None or not sen.delay.any()):
        return
    dt = sim.plant.dt
    s_max = float(sen.delay.max()) if sen is not None and sen.delay.size else 0.0
    uniform = sen is None or not sen.delay.size or bool((sen.delay == sen.delay[0]).all())
    print("delay in the loop ([sim] actuator and sensor) against the delay margin:")
    for i, c in enumerate(analysis.margins.channels[: sim.plant.input_dim]):
        d = (float(act.delay[i]) if act is not None else 0.0) + s_max
        verdict = "inside" if d < c.delay_margin else "OUTSIDE: expect the loop to lose stability"
        print(
            f"  {c.name}: {'' if uniform else 'at most '}{d:g} s ({round(d / dt)} steps) of {c.delay_margin:.4g} s "
            f"({verdict}; a lag adds phase the margin does not count)"
        )


def _design_analysis(args: argparse.Namespace, sim) -> int:
    """``design``: poles, structure, margins, linear step metrics; ``--report`` and ``--tradeoff``."""
    from shinro_ctrl.analysis import analyze_controller

    plant = sim.plant
    tracked = [plant.state_names[i] for i in sim.tracked]
    analysis = analyze_controller(
        sim.controller,
        x_init=sim.initial_state,
        measured=tracked,
        tracked=tracked,
        state_names=plant.state_names,
        input_names=plant.input_names,
        duration=sim.scenario.sim.duration,
    )
    if args.kind == "mpc":
        print("linear analysis of the unconstrained first move (finite-horizon Riccati gain):")
    print(analysis.format())
    gap = _model_gap(sim)
    if gap is not None:
        print(gap.format())
    _print_loop_delay(sim, analysis)
    if args.report:
        from shinro_ctrl.analysis.report import write_report
        from shinro_ctrl.sim import RobotSim

        run = RobotSim(sim.scenario, engine="standalone").run()
        path = write_report(
            args.report,
            analysis,
            title=f"{sim.scenario.name}: {type(plant).__name__} + {type(sim.controller).__name__}",
            nonlinear=(run.t, run.x, run.u),
            x_ref=run.ref,
            u_min=run.u_min,
            u_max=run.u_max,
            description=repr(plant),
            model_gap=gap,
        )
        print(f"report: {path}")
    if args.tradeoff:
        from shinro_ctrl.analysis.tradeoff import parse_tradeoff, run_tradeoff

        key, lo, hi = parse_tradeoff(args.tradeoff)
        result = run_tradeoff(
            args.config, key, lo, hi, points=args.points, engine=args.engine, out=args.out, workers=args.workers
        )
        print(result.summary())
    return 0
