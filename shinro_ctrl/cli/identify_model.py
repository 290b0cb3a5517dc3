"""``shinro-ctrl identify`` on a model-file scenario: bodies' inertials and joint parameters, an updated model file.

``shinro-ctrl identify CONFIG --data FILE ... --params body:forearm,joint:elbow.damping [--cutoff HZ] [--out DIR]``
with an ``MjcfPlant`` scenario runs :func:`shinro_ctrl.identification.mjcf.identify_model_file` (the
inverse-dynamics regressor; every joint position must be in the data) and prints the table. ``--out DIR``
writes, as one set, ``<model>_identified.xml`` (the model file with the estimates), ``<scenario>_identified.toml``
(the scenario with ``[plant] model`` — and ``[engine] model`` when it named the same file — pointing to it) and
``identification.json``.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

from shinro_ctrl.errors import ConfigError, InvalidArgument

__all__ = ["cmd_identify_model_file"]

OUTPUT_JSON = "identification.json"


def _names(scenario: Any, model: Path) -> tuple[str, str, str]:
    return (f"{model.stem}_identified.xml", f"{scenario.name}_identified.toml", OUTPUT_JSON)


def cmd_identify_model_file(args: argparse.Namespace, scenario: Any, names: list[str]) -> int:
    """The model-file branch of ``identify`` (module docstring); returns the exit code."""
    from shinro_ctrl._text_formats import dump_toml
    from shinro_ctrl.files import atomic_folder, check_output_folder
    from shinro_ctrl.identification import load_data
    from shinro_ctrl.identification.mjcf import identify_model_file
    from shinro_ctrl.plants import plant_class

    unused = [
        opt
        for opt, given in (
            ("--plot", args.plot),
            ("--outputs", args.outputs),
            ("--segment", args.segment),
            ("--holdout", args.holdout),
            ("--mode prediction", args.mode != "simulation"),
        )
        if given
    ]
    if unused:
        raise InvalidArgument(
            f"{', '.join(unused)}: not used with body:/joint: parameters (the inverse-dynamics regressor "
            "fits the joint torques; --cutoff sets its filter)"
        )
    plant = plant_class(scenario.plant.type).from_config(scenario.plant.params)
    model = getattr(plant, "model_path", None)
    if type(plant).__name__ != "MjcfPlant" or model is None:
        raise ConfigError(
            f"{scenario.name}: body:/joint: parameters identify a model file's inertials; [plant] is "
            f"{scenario.plant.type}, not a model file (name its [plant] parameters instead)"
        )
    model = Path(model)
    out_names = _names(scenario, model)
    if args.out:
        check_output_folder(args.out, out_names, inputs=[args.config, *args.data], what="--out folder")
    exps = [load_data(f, plant.state_names, plant.input_names) for f in args.data]
    ident = identify_model_file(plant, exps, names, cutoff=getattr(args, "cutoff", None))
    res = ident.result
    print(f"{scenario.name}: {model.name} identified from {len(exps)} experiment(s) (inverse dynamics)")
    print(res.summary())
    if not args.out:
        return 0
    xml_name, toml_name, json_name = out_names
    with atomic_folder(args.out, out_names) as staging:
        written = ident.write_model(staging / xml_name)
        final = (Path(args.out) / xml_name).resolve()
        doc = {table: dict(body) if isinstance(body, dict) else body for table, body in scenario.raw.items()}
        doc["plant"] = {**doc["plant"], "model": str(final)}
        if isinstance(doc.get("engine"), dict) and isinstance(doc["engine"].get("model"), str):
            base = scenario.path.parent if scenario.path is not None else Path.cwd()
            em = Path(doc["engine"]["model"])
            full = em if em.is_absolute() else base / em
            if full.exists() and full.resolve() == model.resolve():
                doc["engine"]["model"] = str(final)
            elif full.exists():  # another file (the real robot's): the identified scenario still finds it
                doc["engine"]["model"] = str(full.resolve())
        header = f"# {scenario.name} with {model.name}'s {', '.join(names)} identified by shinro-ctrl identify\n"
        (staging / toml_name).write_text(header + dump_toml(doc), encoding="utf-8")
        report = {
            "scenario": scenario.name,
            "model": str(model),
            "params": list(res.params),
            "estimate": res.estimate,
            "prior": res.prior,
            "std_error": res.std_error,
            "interval95": {k: list(v) for k, v in res.interval.items()},
            "unidentifiable": res.unidentifiable,
            "held_at_prior": list(res.held),
            "warnings": res.warnings,
            "consistent": ident.consistent(),
        }
        (staging / json_name).write_text(json.dumps(report, indent=2) + "\n", encoding="utf-8")
    print(f"saved {written.name}, {toml_name} and {json_name} to {args.out}")
    return 0
