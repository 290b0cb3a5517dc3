"""The ``identify`` command: a scenario's plant parameters estimated from logged data, written back as a scenario.

``shinro-ctrl identify CONFIG --data FILE [FILE ...] --params NAME,NAME,... [--out DIR] [--plot FILE.png]``
loads the scenario's plant (its parameters are the priors), reads each data file as one experiment
(``run --out`` results or CSV files with named columns, :mod:`shinro_ctrl.identification.data`),
identifies the parameters (:func:`shinro_ctrl.identification.identify`) and prints the table: estimate,
prior, standard error, 95 % interval, the correlations, the combinations the data cannot determine, and
the fit. ``--out DIR`` writes, as one set, ``<scenario>_identified.toml`` (the scenario with the
estimates in ``[plant]``: ``design`` and ``run`` take it directly) and ``identification.json``.
Parameters named ``body:NAME`` or ``joint:NAME.damping|armature|frictionloss`` identify a model file's
inertials instead (:mod:`shinro_ctrl.cli.identify_model`).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import TYPE_CHECKING, Any

from shinro_ctrl.cli.common import _check_output, path_arg
from shinro_ctrl.errors import InvalidArgument

if TYPE_CHECKING:
    from shinro_ctrl.identification import IdentificationResult

__all__ = ["cmd_identify", "identified_scenario", "register"]

OUTPUT_JSON = "identification.json"


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``identify`` to the ``shinro-ctrl`` parser (``sub``: its subparsers)."""
    p = sub.add_parser("identify", help="estimate a scenario's plant parameters from logged data (grey-box)")
    p.add_argument("config", metavar="CONFIG", help="scenario whose [plant] holds the priors")
    p.add_argument(
        "--data", nargs="+", required=True, type=path_arg, metavar="FILE", help="result.npz (run --out) or CSV files"
    )
    p.add_argument("--params", required=True, metavar="NAME,NAME,...", help="the [plant] parameters to estimate")
    p.add_argument(
        "--out", type=path_arg, metavar="DIR", help="write <scenario>_identified.toml and identification.json"
    )
    p.add_argument("--plot", type=path_arg, metavar="FILE.png", help="measured against model outputs")
    p.add_argument("--mode", choices=("simulation", "prediction"), default="simulation", help="error minimized")
    p.add_argument("--outputs", metavar="NAME,...", help="use only these measured states")
    p.add_argument("--segment", type=float, metavar="SECONDS", help="shooting segment length (default: automatic)")
    p.add_argument(
        "--cutoff",
        type=float,
        metavar="HZ",
        help="model-file parameters (body:/joint:): the zero-phase low-pass cutoff of the derivatives",
    )
    p.add_argument(
        "--holdout",
        type=float,
        default=0.0,
        metavar="FRACTION",
        help="hold out the last FRACTION of each experiment and report the fit on it (default 0: none)",
    )
    p.set_defaults(func=cmd_identify)


def cmd_identify(args: argparse.Namespace) -> int:
    from shinro_ctrl.config import load_scenario
    from shinro_ctrl.identification import compare, identify, load_data, plot_fit
    from shinro_ctrl.plants import plant_class

    if not 0.0 <= args.holdout < 1.0:
        raise InvalidArgument(f"--holdout must be in [0, 1), got {args.holdout:g}")
    scenario = load_scenario(args.config)
    names = [p.strip() for p in args.params.split(",") if p.strip()]
    if any(n.startswith(("body:", "joint:")) for n in names):  # a model file's inertials and joints
        from shinro_ctrl.cli.identify_model import cmd_identify_model_file

        return cmd_identify_model_file(args, scenario, names)
    outputs = [o.strip() for o in args.outputs.split(",") if o.strip()] if args.outputs else None
    inputs = [args.config, *args.data]
    if args.out:
        from shinro_ctrl.files import check_output_folder

        check_output_folder(args.out, _out_names(scenario.name), inputs=inputs, what="--out folder")
    if args.plot:
        _check_output(args.plot, inputs)
    plant = plant_class(scenario.plant.type).from_config(scenario.plant.params)
    exps = [load_data(f, plant.state_names, plant.input_names, outputs=outputs) for f in args.data]
    held_out = []
    if args.holdout > 0:
        parts = [e.split(1.0 - args.holdout) for e in exps]
        exps, held_out = [a for a, _ in parts], [b for _, b in parts]
    result = identify(plant, exps, names, mode=args.mode, segment=args.segment)
    print(f"{scenario.name}: {plant.__class__.__name__} identified from {len(exps)} experiment(s)")
    print(result.summary())
    reports = [compare(plant, result, e) for e in held_out]
    for r in reports:
        print(r.line())
    if args.plot:
        from shinro_ctrl.identification.fit import FitReport

        shown = reports or [
            FitReport(e.t, e.y, yh, e.outputs, result.fit_percent, result.nrmse, e.source, result.segment)
            for e, yh in zip(exps, _estimation_outputs(plant, result, exps), strict=True)
        ]
        print(f"saved {plot_fit(shown, args.plot, title=f'{scenario.name}: measured vs identified model')}")
    if args.out:
        _write_out(args.out, scenario, result, reports)
    return 0


def _out_names(name: str) -> tuple[str, str]:
    return (f"{name}_identified.toml", OUTPUT_JSON)


def _estimation_outputs(plant: Any, result: IdentificationResult, exps: list) -> list:
    from shinro_ctrl.identification.estimate import simulate_segments

    return [simulate_segments(plant, result, e) for e in exps]


def identified_scenario(scenario: Any, result: IdentificationResult) -> dict[str, Any]:
    """The scenario document with the estimates in ``[plant]`` (relative model paths made absolute)."""
    doc = {table: dict(body) if isinstance(body, dict) else body for table, body in scenario.raw.items()}
    doc["plant"] = {**doc["plant"], **{k: float(v) for k, v in result.estimate.items()}}
    base = scenario.path.parent if scenario.path is not None else Path.cwd()
    for table in ("plant", "engine"):
        model = doc.get(table, {}).get("model") if isinstance(doc.get(table), dict) else None
        if isinstance(model, str) and not Path(model).is_absolute() and (base / model).exists():
            doc[table]["model"] = str((base / model).resolve())
    return doc


def _write_out(out: str, scenario: Any, result: IdentificationResult, reports: list) -> None:
    from shinro_ctrl._text_formats import dump_toml
    from shinro_ctrl.files import atomic_folder

    toml_name, json_name = _out_names(scenario.name)
    header = (
        f"# {scenario.name} with [plant] {', '.join(result.params)} identified by shinro-ctrl identify\n"
        + "".join(
            f"# {p} = {result.estimate[p]:.6g} (prior {result.prior[p]:.6g}, 95 % interval "
            f"[{result.interval[p][0]:.6g}, {result.interval[p][1]:.6g}])\n"
            for p in result.params
        )
    )
    report = {
        "scenario": scenario.name,
        "plant": result.plant_type,
        "params": list(result.params),
        "estimate": result.estimate,
        "prior": result.prior,
        "std_error": result.std_error,
        "interval95": {k: list(v) for k, v in result.interval.items()},
        "correlation": result.correlation.tolist(),
        "unidentifiable": result.unidentifiable,
        "held_at_prior": list(result.held),
        "warnings": result.warnings,
        "noise_std": result.noise_std,
        "fit_percent": result.fit_percent,
        "fit_percent_held_out": [r.fit_percent for r in reports],
        "mode": result.mode,
        "segment_samples": result.segment,
    }
    with atomic_folder(out, _out_names(scenario.name)) as staging:
        (staging / toml_name).write_text(header + dump_toml(identified_scenario(scenario, result)), encoding="utf-8")
        (staging / json_name).write_text(json.dumps(report, indent=2) + "\n", encoding="utf-8")
    print(f"saved {toml_name} and {json_name} to {out}")
