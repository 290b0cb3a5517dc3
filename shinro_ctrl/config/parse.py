"""Loading and parsing a scenario document, table by table (the ``[sim]`` family is in :mod:`.sim_table`)."""

from __future__ import annotations

import copy
import tomllib
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from shinro_ctrl.config.context import _Ctx, whole_steps
from shinro_ctrl.config.schema import (
    ENGINE_KEYS,
    TABLES,
    ControllerConfig,
    EngineConfig,
    PlantConfig,
    Scenario,
)
from shinro_ctrl.config.sim_table import _parse_estimator, _parse_sim
from shinro_ctrl.config.strict import signature_annotations, table_annotations
from shinro_ctrl.errors import ConfigError
from shinro_ctrl.validation import did_you_mean

__all__ = ["load_scenario", "parse_scenario"]


def load_scenario(path: str | Path) -> Scenario:
    """Read and parse a scenario file.

    Args:
        path: A path, or a shipped scenario name (``"cartpole_lqr"``).

    Raises:
        FileNotFoundError: no such file (listing the shipped scenarios).
        ConfigError: an empty name, a file that is not UTF-8 (a byte-order mark is named), malformed
            TOML or an invalid scenario.
    """
    from shinro_ctrl.resources import config_path

    if isinstance(path, str) and not path.strip():
        raise ConfigError(
            "the scenario name is empty (an unset shell variable?): give a scenario file or a shipped name"
        )
    p = config_path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except UnicodeDecodeError as exc:
        raw = p.read_bytes()
        if raw.startswith((b"\xff\xfe", b"\xfe\xff")):
            raise ConfigError(
                f"{p}: saved as UTF-16 (it starts with a UTF-16 byte-order mark); save it as UTF-8"
            ) from None
        raise ConfigError(f"{p}: not a UTF-8 text file ({exc.reason})") from None
    if text.startswith("\ufeff"):
        raise ConfigError(
            f"{p}: starts with a UTF-8 byte-order mark (BOM), which TOML does not allow; "
            "save the file as UTF-8 without BOM"
        )
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{p}: malformed TOML: {exc}") from None
    except RecursionError:
        raise ConfigError(f"{p}: malformed TOML: arrays or tables nested too deeply") from None
    return parse_scenario(doc, source=str(p), path=p)


def parse_scenario(doc: Mapping[str, Any], *, source: str = "<dict>", path: Path | None = None) -> Scenario:
    """Parse a scenario document (the dict a TOML file loads to).

    Raises:
        ConfigError: naming ``source``, the table and the key.
    """
    ctx = _Ctx(source)
    _check_tables(ctx, doc)
    plant_cfg, probe = _parse_plant(ctx, doc, path)
    engine_cfg = _parse_engine(ctx, doc, plant_cfg, probe)
    controller_cfg = _parse_controller(ctx, doc, probe, path)
    plan_cfg = _parse_plan(ctx, doc, controller_cfg, probe)
    sim = _parse_sim(ctx, doc, probe)
    estimator_cfg = _parse_estimator(ctx, doc, sim, probe)
    regression = _parse_regression(ctx, doc)

    name = path.stem if path is not None else "<dict>"
    if sim.initial_state is None and plan_cfg is not None and "start" in plan_cfg:
        sim.initial_state = list(plan_cfg["start"])  # a planned run starts where its plan starts
    scenario = Scenario(
        name, path, plant_cfg, engine_cfg, controller_cfg, sim, regression, copy.deepcopy(dict(doc)), plan_cfg
    )
    scenario.estimator = estimator_cfg
    return scenario


def _check_tables(ctx: _Ctx, doc: Any) -> None:
    """The document is a non-empty mapping of known tables."""
    if not isinstance(doc, Mapping) or not doc:
        raise ctx.error("", "empty scenario: it needs at least a [plant] and a [controller] table")
    for name, table in doc.items():
        if name not in TABLES:
            raise ctx.error("", f"unknown table '{name}'{did_you_mean(name, TABLES)}")
        if not isinstance(table, Mapping):
            raise ctx.error("", f"'{name}' must be a table ([{name}]), got {type(table).__name__}")


def _parse_plant(ctx: _Ctx, doc: Mapping[str, Any], path: Path | None) -> tuple[PlantConfig, Any]:
    """``[plant]``: the class, its keys and types; returns the config and a plant built from it.

    The plant (the probe) is what the later tables are checked against (shapes, limits, names).
    """
    from shinro_ctrl.plants import plant_class

    if "plant" not in doc:
        raise ctx.error("", "missing required table [plant]")
    pt = dict(doc["plant"])
    if "type" not in pt:
        raise ctx.error("plant", "missing key 'type' (a plant class name such as 'CartPole')")
    ctx.check_types("plant", {"type": pt["type"]}, {})
    try:
        cls = plant_class(str(pt["type"]))
    except ConfigError as exc:
        raise ctx.error("plant", str(exc)) from None
    ctx.check_keys("plant", pt, ("type", *cls.config_keys()))
    ctx.check_types("plant", pt, signature_annotations(cls.__init__, 1))
    params = {k: v for k, v in pt.items() if k != "type"}
    if cls.__name__ == "MjcfPlant" and str(pt["type"]) != "MjcfPlant":  # type = "robot.xml": the model file
        if "model" in params:
            raise ctx.error("plant", f"'type' is the model file {pt['type']!r}: remove 'model' (or type = MjcfPlant)")
        params["model"] = str(pt["type"])
    if cls.__name__ == "MjcfPlant" and path is not None and isinstance(params.get("model"), str):
        beside = path.parent / params["model"]  # a model path relative to the scenario file
        if not Path(params["model"]).is_absolute() and beside.is_file():
            params["model"] = str(beside.resolve())
    try:
        probe = cls.from_config(params)
    except ConfigError as exc:
        raise ctx.error("plant", str(exc).removeprefix("[plant] ")) from None
    return PlantConfig(cls.__name__, params), probe


def _parse_engine(ctx: _Ctx, doc: Mapping[str, Any], plant: PlantConfig, probe: Any) -> EngineConfig | None:
    """``[engine]`` (optional; absent or ``type = "standalone"``: None)."""
    engine_cfg = None
    if "engine" in doc:
        et = dict(doc["engine"])
        ctx.check_keys("engine", et, ENGINE_KEYS)
        ctx.check_types("engine", et, table_annotations(EngineConfig))
        etype = et.get("type", "mujoco")
        if etype not in ("mujoco", "standalone"):
            raise ctx.error("engine", f"'type' must be 'mujoco' or 'standalone', got {etype!r}")
        substeps = et.get("substeps", 1)
        if isinstance(substeps, bool) or not isinstance(substeps, int) or substeps < 1:
            raise ctx.error("engine", f"'substeps' must be a positive integer, got {substeps!r}")
        model = et.get("model")
        if model is not None and not isinstance(model, str):
            raise ctx.error("engine", f"'model' must be a path or an asset name, got {model!r}")
        if etype == "mujoco":
            if probe.asset is None and model is None:
                raise ctx.error("engine", f"{plant.type} has no MuJoCo model; remove [engine] or give 'model'")
            engine_cfg = EngineConfig("mujoco", model, substeps)
    return engine_cfg


def _parse_controller(ctx: _Ctx, doc: Mapping[str, Any], probe: Any, path: Path | None = None) -> ControllerConfig:
    """``[controller]``: the class, its keys (``from_plant``'s keywords) and types, Bryson weights, ``x0``/``u0``;
    an ``Exported`` controller's relative ``path`` is found beside the scenario file first."""
    n = probe.state_dim
    if "controller" not in doc:
        raise ctx.error("", "missing required table [controller]")
    ct = dict(doc["controller"])
    from shinro_ctrl.controllers import CONTROLLER_REGISTRY, controller_keys

    if "type" not in ct:
        raise ctx.error("controller", f"missing key 'type' (one of {', '.join(CONTROLLER_REGISTRY.names())})")
    ctx.check_types("controller", {"type": ct["type"]}, {})
    try:
        ccls = CONTROLLER_REGISTRY.lookup(str(ct["type"]))
    except ConfigError as exc:
        raise ctx.error("controller", str(exc)) from None
    ctx.check_keys("controller", ct, ("type", *controller_keys(ccls)))
    annotations = getattr(ccls, "option_annotations", None)  # a controller forwarding **options names their types
    ctx.check_types("controller", ct, annotations() if annotations else signature_annotations(ccls.from_plant, 1))
    _bryson_weights(ctx, ct, n, probe.input_dim)
    for key in ("x0", "u0"):
        if key in ct:
            ctx.vector("controller", key, ct[key], n if key == "x0" else probe.input_dim)
    if ccls.__name__ == "Exported" and path is not None and isinstance(ct.get("path"), str):
        beside = path.parent / ct["path"]  # an exported folder relative to the scenario file
        if not Path(ct["path"]).is_absolute() and beside.is_dir():
            ct["path"] = str(beside.resolve())
    return ControllerConfig(ccls.__name__, {k: v for k, v in ct.items() if k != "type"})


def _parse_regression(ctx: _Ctx, doc: Mapping[str, Any]) -> dict[str, dict[str, float]]:
    """``[regression]``: metric → ``{"rel": r, "abs": a}`` tolerances."""
    from shinro_ctrl.sim.metrics import METRICS, OUTPUT_FEEDBACK_METRICS

    regression: dict[str, dict[str, float]] = {}
    for metric, tol in dict(doc.get("regression", {})).items():
        if metric not in METRICS and not metric.startswith(OUTPUT_FEEDBACK_METRICS):
            raise ctx.error("regression", f"unknown metric '{metric}'{did_you_mean(metric, METRICS)}")
        if not isinstance(tol, Mapping):
            raise ctx.error("regression", f"'{metric}' must be a table such as {{ rel = 0.05 }}, got {tol!r}")
        ctx.check_keys(f"regression.{metric}", tol, ("rel", "abs"))
        regression[metric] = {k: ctx.number("regression", f"{metric}.{k}", v, minimum=0.0) for k, v in tol.items()}
    return regression


def _parse_plan(ctx: _Ctx, doc: Mapping[str, Any], controller: ControllerConfig, probe: Any) -> dict[str, Any] | None:
    """``[plan]`` (or ``plan`` inside ``[controller]``): validated, and handed to the controller as ``plan``."""
    from shinro_ctrl.controllers import CONTROLLER_REGISTRY, controller_keys
    from shinro_ctrl.errors import InvalidArgument
    from shinro_ctrl.planning.spec import check_plan

    takes_plan = "plan" in controller_keys(CONTROLLER_REGISTRY.lookup(controller.type))
    table = "plan" if "plan" in doc else "controller"
    if "plan" in doc and "plan" in controller.options:
        raise ctx.error("controller", "'plan' is given twice: keep the [plan] table and remove 'plan' here")
    spec = doc.get("plan", controller.options.get("plan"))
    if spec is None:
        if takes_plan:
            raise ctx.error("", f"missing table [plan]: a {controller.type} controller tracks a planned trajectory")
        return None
    if not takes_plan:
        raise ctx.error("plan", f"a {controller.type} controller takes no plan; remove [plan] or use TVLQR")
    try:
        plan = check_plan(spec, probe.state_dim, probe.input_dim)
    except InvalidArgument as exc:
        raise ctx.error(table, str(exc)) from None
    if isinstance(plan.get("duration"), float):  # a fixed horizon is tracked step by step: whole steps of dt
        try:
            whole_steps(plan["duration"], probe.dt, "'duration'")
        except ConfigError as exc:
            raise ctx.error(table, str(exc)) from None
    if "start" in plan:
        lo, hi = probe.state_limits()
        for i, v in enumerate(plan["start"]):
            if not lo[i] <= v <= hi[i]:
                raise ctx.error(
                    table,
                    f"'start' {probe.state_names[i]} = {v:g} is outside the plant's limits [{lo[i]:g}, {hi[i]:g}]",
                )
    controller.options["plan"] = plan
    return plan


def _bryson_weights(ctx: _Ctx, ct: dict[str, Any], n: int, m: int) -> None:
    """``Q = { bryson = [x_max...] }`` / ``R = { bryson = [u_max...] }`` become diagonals ``1/x_max²`` in place."""
    from shinro_ctrl.analysis.weights import bryson_diagonal
    from shinro_ctrl.errors import InvalidArgument

    for key, size in (("Q", n), ("R", m)):
        value = ct.get(key)
        if not isinstance(value, Mapping):
            continue
        if set(value) != {"bryson"}:
            raise ctx.error("controller", f"'{key}' as a table takes only 'bryson' (largest deviations), got {value!r}")
        limits = ctx.vector("controller", f"{key}.bryson", value["bryson"], size, finite=False)
        try:
            ct[key] = bryson_diagonal(f"{key}.bryson", limits, allow_inf=key == "Q").tolist()
        except InvalidArgument as exc:
            raise ctx.error("controller", str(exc)) from None
