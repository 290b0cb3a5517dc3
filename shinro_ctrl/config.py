"""Scenario files: strict TOML parsing into dataclasses.

A scenario has the tables ``[plant]`` (required), ``[engine]`` (optional;
absent means standalone), ``[controller]`` (required), ``[plan]`` (only with
a controller that tracks a plan, TVLQR), ``[sim]`` (optional), ``[estimator]``
(optional; output feedback) and ``[regression]`` (only for regression
scenarios). The docs page docs/scenarios.md lists every key.

Parsing is strict and runs table by table in that order: an unknown table or
key raises :class:`~shinro_ctrl.errors.ConfigError` naming the file, the
table and the key, with the closest valid key ("did you mean …?"); a wrong
type or an out-of-range value names the key. Shapes (initial state, weights,
bounds) are checked against the plant, whose class is resolved here, so a
scenario that loads is one that can be built.
"""

from __future__ import annotations

import copy
import math
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from shinro_ctrl.errors import ConfigError
from shinro_ctrl.validation import did_you_mean, unknown_keys

__all__ = [
    "REFERENCE_KINDS",
    "ControllerConfig",
    "EngineConfig",
    "PlantConfig",
    "Scenario",
    "SimConfig",
    "load_scenario",
    "parse_scenario",
]

TABLES = ("plant", "engine", "controller", "plan", "sim", "estimator", "regression")
ENGINE_KEYS = ("type", "model", "substeps")
SIM_KEYS = (
    "duration",
    "initial_state",
    "reference",
    "track",
    "settle_tol",
    "measurement_noise",
    "seed",
    "measured",
    "sensor_noise",
    "process_noise",
    "disturbance",
)
REFERENCE_KINDS: dict[str, tuple[tuple[str, ...], tuple[str, ...]]] = {
    # kind: (required keys, optional keys)
    "constant": ((), ("value",)),
    "step": (("time",), ("initial", "final")),
    "circle": (("radius", "frequency"), ("center", "axes", "phase")),
    "square": (("side", "speed"), ("center", "axes")),
    "waypoints": (("points", "times"), ("interpolation",)),
}
METRICS = (
    "rms_error",
    "max_error",
    "final_error",
    "settling_time",
    "max_abs_input",
    "constraint_violations",
    "max_violation",
    "solve_time_median_s",
)
#: Metrics only output-feedback runs report (``estimation_rms`` and ``estimation_rms_<state>``); a
#: ``[regression]`` table may hold tolerances for them, sweep tables do not list them.
OUTPUT_FEEDBACK_METRICS = ("estimation_rms",)


#: ``[sim] disturbance``: a table or a list of tables (parsed into DisturbanceSpec; checked structurally here).
DisturbanceTables = list


@dataclass
class PlantConfig:
    """``[plant]``: the class name and its constructor arguments."""

    type: str
    params: dict[str, Any] = field(default_factory=dict)


@dataclass
class EngineConfig:
    """``[engine]``: MuJoCo with an optional model (path or asset name) and substeps."""

    type: str = "mujoco"
    model: str | None = None
    substeps: int = 1


@dataclass
class ControllerConfig:
    """``[controller]``: the class name and the keyword arguments of its ``from_plant``."""

    type: str
    options: dict[str, Any] = field(default_factory=dict)


@dataclass
class SimConfig:
    """``[sim]``: run length, initial state, reference and metric settings.

    Attributes:
        duration: Simulated time [s].
        initial_state: ``(n,)``, default the controller's operating point.
        reference: A reference table (``kind`` plus its keys), default constant.
        track: Names of the states the error metrics use (default: the plant's
            ``tracked_states``).
        settle_tol: Absolute band on the tracking-error norm for ``settling_time``.
        measurement_noise: Standard deviations ``(n,)`` of Gaussian noise added
            to the state the controller sees (seeded by ``seed``).
        seed: Seed of every random draw of the run.
        measured: Names of the measured states, in the order of ``y`` (default all).
        sensor_noise: Standard deviations ``(p,)`` of the Gaussian noise on ``y``.
        process_noise: Standard deviations ``(m,)`` of the Gaussian noise added
            to the applied input (the controller does not see it).
        disturbance: Parsed ``disturbance`` entries
            (:class:`~shinro_ctrl.disturbances.DisturbanceSpec`); see
            :mod:`shinro_ctrl.disturbances`.
    """

    duration: float = 5.0
    initial_state: list[float] | None = None
    reference: dict[str, Any] = field(default_factory=lambda: {"kind": "constant"})
    track: list[str] | None = None
    settle_tol: float = 0.01
    measurement_noise: list[float] | None = None
    seed: int = 0
    measured: list[str] | None = None
    sensor_noise: list[float] | None = None
    process_noise: list[float] | None = None
    disturbance: DisturbanceTables | None = None


@dataclass
class EstimatorConfig:
    """``[estimator]``: the estimator class name and the keyword arguments of its ``from_plant``.

    ``measured`` comes from ``[sim] measured``; ``Qn`` and ``Rn``, when the
    table leaves them out, from ``[sim] process_noise`` and ``sensor_noise``
    (variances: the standard deviations squared).
    """

    type: str
    options: dict[str, Any] = field(default_factory=dict)


@dataclass
class Scenario:
    """A parsed scenario.

    Attributes:
        name: File stem (or ``"<dict>"``).
        path: Source file, or None for a dict.
        plant, engine, controller, sim: The parsed tables (``engine`` None when standalone).
        regression: Metric → ``{"rel": r, "abs": a}`` tolerances.
        raw: The document as loaded (for saving the resolved config).
        plan: The validated ``[plan]`` table (also passed to the controller as its
            ``plan`` option), or None.
    """

    name: str
    path: Path | None
    plant: PlantConfig
    engine: EngineConfig | None
    controller: ControllerConfig
    sim: SimConfig
    regression: dict[str, dict[str, float]]
    raw: dict[str, Any]
    plan: dict[str, Any] | None = None
    estimator: EstimatorConfig | None = None


class _Ctx:
    """Formats errors with the file and table they come from."""

    def __init__(self, source: str):
        self.source = source

    def error(self, table: str, message: str) -> ConfigError:
        where = f"[{table}] " if table else ""
        return ConfigError(f"{self.source}: {where}{message}")

    def check_keys(self, table: str, mapping: Mapping[str, Any], allowed: tuple[str, ...]) -> None:
        bad = unknown_keys(mapping, allowed)
        if bad:
            raise self.error(table, f"unknown key '{bad[0]}'{did_you_mean(bad[0], allowed)}")

    def number(self, table: str, key: str, value: Any, *, positive: bool = False, minimum: float | None = None):
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise self.error(table, f"'{key}' must be a number, got {type(value).__name__} {value!r}")
        v = float(value)
        if not math.isfinite(v):
            raise self.error(table, f"'{key}' must be finite, got {value!r}")
        if positive and v <= 0:
            raise self.error(table, f"'{key}' must be positive, got {value!r}")
        if minimum is not None and v < minimum:
            raise self.error(table, f"'{key}' must be >= {minimum:g}, got {value!r}")
        return v

    def vector(self, table: str, key: str, value: Any, n: int | None = None, *, finite: bool = True) -> list[float]:
        if not isinstance(value, list) or not value:
            raise self.error(table, f"'{key}' must be a non-empty list of numbers, got {value!r}")
        out = []
        for v in value:
            if isinstance(v, bool) or not isinstance(v, int | float):
                raise self.error(table, f"'{key}' must hold numbers only, got {v!r}")
            if finite and not math.isfinite(v):
                raise self.error(table, f"'{key}' must be finite, got {value!r}")
            out.append(float(v))
        if n is not None and len(out) != n:
            raise self.error(table, f"'{key}' must have {n} values, got {len(out)}")
        return out

    def check_types(self, table: str, mapping: Mapping[str, Any], annotations: Mapping[str, Any]) -> None:
        """Check every value of ``mapping`` strictly against its key's type annotation (see :func:`check_value`)."""
        for key, value in mapping.items():
            if key == "type" and table in ("plant", "controller", "estimator"):
                annotation: Any = "str"
            else:
                annotation = annotations.get(key, "")
            problem = check_value(value, annotation, key)
            if problem:
                raise self.error(table, problem)


# ------------------------------------------------------------ strict value types
# One checker for every table: a key's TOML value must match the type annotation of the Python argument or
# dataclass field it fills ("bool", "int", "float", "str", "list[float]", "Sequence[str]", "Mapping[...]",
# "Any" = numbers or arrays/tables of numbers, unions with "|"). A new table parsed through
# ``_Ctx.check_types`` with its dataclass's ``table_annotations`` gets strict types for free.
MAX_NESTING = 4  # arrays of arrays deeper than this are never a scenario value
MAX_ELEMENTS = 100_000  # numbers in one array value
SIZE_LIMITS: dict[str, int] = {
    # integer keys that size work or memory, with their limit (the error says it)
    "substeps": 1_000,
    "num_dof": 64,
    "num_wheels": 64,
    "control_iters": 1_000,
    "horizon": 10_000,
}
_TOML_TYPE = {bool: "boolean", int: "integer", float: "float", str: "string", list: "array", dict: "table"}


def toml_type(value: Any) -> str:
    """The TOML name of a loaded value's type (``string``, ``boolean``, ``array``, ``date-time`` …)."""
    for t, name in _TOML_TYPE.items():
        if type(value) is t:
            return name
    if isinstance(value, Mapping):
        return "table"
    return "date-time" if type(value).__module__ == "datetime" else type(value).__name__


def _is_number(v: Any) -> bool:
    return isinstance(v, int | float) and not isinstance(v, bool)


def _shown(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def _numeric_problem(value: Any, key: str, depth: int = 0) -> str | None:
    """None if ``value`` is a number, a rectangular array of numbers or a table of such; else the problem."""
    if _is_number(value):
        return None
    if depth >= MAX_NESTING:
        return f"'{key}' is nested more than {MAX_NESTING} levels deep"
    if isinstance(value, list):
        if len(value) > MAX_ELEMENTS:
            return f"'{key}' has {len(value)} elements; the limit is {MAX_ELEMENTS}"
        for v in value:
            problem = _numeric_problem(v, key, depth + 1)
            if problem:
                return problem
            if isinstance(v, Mapping):
                return f"'{key}' must hold numbers or arrays of numbers, got a table {_shown(v)}"
        kinds = {isinstance(v, list) for v in value}
        if len(kinds) > 1:
            return f"'{key}' mixes numbers and arrays: {_shown(value)}"
        if kinds == {True}:
            lengths = {len(v) for v in value}
            if len(lengths) > 1:
                return f"'{key}' is ragged: its rows have {sorted(lengths)} elements; all rows need the same length"
        return None
    if isinstance(value, Mapping):
        for k, v in value.items():
            problem = _numeric_problem(v, f"{key}.{k}", depth + 1)
            if problem:
                return problem
        return None
    return f"'{key}' must be a number or an array of numbers, got {toml_type(value)} {_shown(value)}"


def _atom_accepts(atom: str, value: Any, key: str) -> str | None:
    """None when ``value`` fits the annotation atom, else the expectation in words (or a precise problem)."""
    base = atom.split("[", 1)[0].strip().rsplit(".", 1)[-1]
    inner = atom[len(atom.split("[", 1)[0]) :].strip("[] ")
    if base == "bool":
        return None if isinstance(value, bool) else "a boolean (true or false, unquoted)"
    if base == "int":
        return None if isinstance(value, int) and not isinstance(value, bool) else "an integer"
    if base == "float":
        return None if _is_number(value) else "a number"
    if base == "str":
        return None if isinstance(value, str) else "a string"
    if base in ("list", "Sequence", "tuple"):
        item = inner.split(",")[0].strip()
        if not isinstance(value, list):
            return f"an array of {'strings' if item == 'str' else 'numbers'}"
        if item == "str":
            return None if all(isinstance(v, str) for v in value) else "an array of strings"
        problem = _numeric_problem(value, key)
        return problem or None
    if base in ("dict", "Mapping"):
        if not isinstance(value, Mapping):
            return "a table such as { key = value }"
        return _structure_problem(value, key)  # the table's own keys are checked by its consumer
    if base == "Any":
        return _numeric_problem(value, key)
    # an annotation this checker does not know: only the structural bounds apply
    if isinstance(value, list | Mapping):
        return _structure_problem(value, key)
    return None


def _structure_problem(value: Any, key: str, depth: int = 0) -> str | None:
    if depth > MAX_NESTING:
        return f"'{key}' is nested more than {MAX_NESTING} levels deep"
    if isinstance(value, list):
        if len(value) > MAX_ELEMENTS:
            return f"'{key}' has {len(value)} elements; the limit is {MAX_ELEMENTS}"
        return next((p for v in value if (p := _structure_problem(v, key, depth + 1))), None)
    if isinstance(value, Mapping):
        return next((p for k, v in value.items() if (p := _structure_problem(v, f"{key}.{k}", depth + 1))), None)
    return None


def check_value(value: Any, annotation: Any, key: str) -> str | None:
    """Check one TOML value strictly against a type annotation.

    Args:
        value: The loaded TOML value.
        annotation: A type annotation, as a string (``"float | None"``) or a type; ``""`` for unknown.
        key: The key, for the message.

    Returns:
        None when the value fits, else the message (naming the key, the expected and the found type).
        A string never passes for a number or a boolean, a boolean never for a number, a float never for
        an integer; arrays must be rectangular and at most :data:`MAX_NESTING` deep; integer sizes listed in
        :data:`SIZE_LIMITS` are bounded.
    """
    text = annotation if isinstance(annotation, str) else getattr(annotation, "__name__", str(annotation))
    text = text.replace("typing.", "").replace("collections.abc.", "")
    atoms = [a.strip() for a in text.split("|") if a.strip() and a.strip() != "None"]
    if not atoms:
        return _structure_problem(value, key)
    expected = []
    for atom in atoms:
        problem = _atom_accepts(atom, value, key)
        if problem is None:
            break
        expected.append(problem)
    else:
        if len(expected) == 1 and expected[0].startswith("'"):
            return expected[0]  # a precise problem (ragged, nested, a string inside an array)
        words = " or ".join(dict.fromkeys(e for e in expected if not e.startswith("'"))) or expected[0]
        if words.startswith("'"):
            return words
        return f"'{key}' must be {words}, got {toml_type(value)} {_shown(value)}"
    limit = SIZE_LIMITS.get(key)
    if limit is not None and _is_number(value) and value > limit:
        return f"'{key}' = {value!r} exceeds the limit of {limit:,}"
    return None


def signature_annotations(func: Any, skip: int = 0) -> dict[str, Any]:
    """Parameter name → annotation of ``func`` (after the first ``skip`` parameters), for :meth:`_Ctx.check_types`."""
    import inspect

    params = list(inspect.signature(func).parameters.values())[skip:]
    return {p.name: p.annotation for p in params if p.annotation is not inspect.Parameter.empty}


def table_annotations(cls: type) -> dict[str, Any]:
    """Field name → annotation of a config dataclass, for :meth:`_Ctx.check_types`."""
    from dataclasses import fields

    return {f.name: f.type for f in fields(cls)}


def load_scenario(path: str | Path) -> Scenario:
    """Read and parse a scenario file.

    Args:
        path: A path, or a shipped scenario name (``"cartpole_lqr"``).

    Raises:
        FileNotFoundError: no such file (listing the shipped scenarios).
        ConfigError: malformed TOML or an invalid scenario.
    """
    from shinro_ctrl.resources import config_path

    p = config_path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except UnicodeDecodeError as exc:
        raise ConfigError(f"{p}: not a UTF-8 text file ({exc.reason})") from None
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
    from shinro_ctrl.plants import plant_class

    ctx = _Ctx(source)
    if not isinstance(doc, Mapping) or not doc:
        raise ctx.error("", "empty scenario: it needs at least a [plant] and a [controller] table")
    for name, table in doc.items():
        if name not in TABLES:
            raise ctx.error("", f"unknown table '{name}'{did_you_mean(name, TABLES)}")
        if not isinstance(table, Mapping):
            raise ctx.error("", f"'{name}' must be a table ([{name}]), got {type(table).__name__}")

    # [plant]
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
    plant_cfg = PlantConfig(cls.__name__, params)
    n = probe.state_dim

    # [engine]
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
                raise ctx.error("engine", f"{cls.__name__} has no MuJoCo model; remove [engine] or give 'model'")
            engine_cfg = EngineConfig("mujoco", model, substeps)

    # [controller]
    if "controller" not in doc:
        raise ctx.error("", "missing required table [controller]")
    ct = dict(doc["controller"])
    if "type" not in ct:
        raise ctx.error("controller", "missing key 'type' (LQR, LinearMPC or IKQP)")
    ctx.check_types("controller", {"type": ct["type"]}, {})
    from shinro_ctrl.controllers import controller_class, controller_keys

    try:
        ccls = controller_class(str(ct["type"]))
    except ConfigError as exc:
        raise ctx.error("controller", str(exc)) from None
    ctx.check_keys("controller", ct, ("type", *controller_keys(ccls)))
    annotations = getattr(ccls, "option_annotations", None)  # a controller forwarding **options names their types
    ctx.check_types("controller", ct, annotations() if annotations else signature_annotations(ccls.from_plant, 1))
    _bryson_weights(ctx, ct, n, probe.input_dim)
    for key in ("x0", "u0"):
        if key in ct:
            ctx.vector("controller", key, ct[key], n if key == "x0" else probe.input_dim)
    controller_cfg = ControllerConfig(ccls.__name__, {k: v for k, v in ct.items() if k != "type"})
    plan_cfg = _parse_plan(ctx, doc, controller_cfg, probe)

    # [sim]
    st = dict(doc.get("sim", {}))
    ctx.check_keys("sim", st, SIM_KEYS)
    ctx.check_types("sim", st, table_annotations(SimConfig))
    sim = SimConfig()
    if "duration" in st:
        sim.duration = ctx.number("sim", "duration", st["duration"], positive=True)
    if "initial_state" in st:
        sim.initial_state = ctx.vector("sim", "initial_state", st["initial_state"], n)
        lo, hi = probe.state_limits()
        for i, v in enumerate(sim.initial_state):
            if not lo[i] <= v <= hi[i]:
                raise ctx.error(
                    "sim",
                    f"'initial_state' {probe.state_names[i]} = {v:g} is outside the plant's limits "
                    f"[{lo[i]:g}, {hi[i]:g}] (state_bounds / track_limits)",
                )
    if "reference" in st:
        sim.reference = _parse_reference(ctx, st["reference"], n)
    if "track" in st:
        track = st["track"]
        if not isinstance(track, list) or not track or not all(isinstance(t, str) for t in track):
            raise ctx.error("sim", f"'track' must be a list of state names, got {track!r}")
        for t in track:
            if t not in probe.state_names:
                raise ctx.error("sim", f"'track': unknown state '{t}'{did_you_mean(t, probe.state_names)}")
        sim.track = list(track)
    if "settle_tol" in st:
        sim.settle_tol = ctx.number("sim", "settle_tol", st["settle_tol"], positive=True)
    if "measurement_noise" in st:
        sim.measurement_noise = ctx.vector("sim", "measurement_noise", st["measurement_noise"], n)
        if any(v < 0 for v in sim.measurement_noise):
            raise ctx.error("sim", "'measurement_noise' standard deviations must be >= 0")
    _parse_output_feedback(ctx, st, sim, probe)
    if "seed" in st:
        if isinstance(st["seed"], bool) or not isinstance(st["seed"], int) or st["seed"] < 0:
            raise ctx.error("sim", f"'seed' must be a non-negative integer, got {st['seed']!r}")
        sim.seed = st["seed"]
    estimator_cfg = _parse_estimator(ctx, doc, sim, probe)

    # [regression]
    regression: dict[str, dict[str, float]] = {}
    for metric, tol in dict(doc.get("regression", {})).items():
        if metric not in METRICS and not metric.startswith(OUTPUT_FEEDBACK_METRICS):
            raise ctx.error("regression", f"unknown metric '{metric}'{did_you_mean(metric, METRICS)}")
        if not isinstance(tol, Mapping):
            raise ctx.error("regression", f"'{metric}' must be a table such as {{ rel = 0.05 }}, got {tol!r}")
        ctx.check_keys(f"regression.{metric}", tol, ("rel", "abs"))
        regression[metric] = {k: ctx.number("regression", f"{metric}.{k}", v, minimum=0.0) for k, v in tol.items()}

    name = path.stem if path is not None else "<dict>"
    if sim.initial_state is None and plan_cfg is not None and "start" in plan_cfg:
        sim.initial_state = list(plan_cfg["start"])  # a planned run starts where its plan starts
    scenario = Scenario(
        name, path, plant_cfg, engine_cfg, controller_cfg, sim, regression, copy.deepcopy(dict(doc)), plan_cfg
    )
    scenario.estimator = estimator_cfg
    return scenario


def _parse_plan(ctx: _Ctx, doc: Mapping[str, Any], controller: ControllerConfig, probe: Any) -> dict[str, Any] | None:
    """``[plan]`` (or ``plan`` inside ``[controller]``): validated, and handed to the controller as ``plan``."""
    from shinro_ctrl.controllers import controller_class, controller_keys
    from shinro_ctrl.errors import InvalidArgument
    from shinro_ctrl.planning.spec import check_plan

    takes_plan = "plan" in controller_keys(controller_class(controller.type))
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


def _parse_reference(ctx: _Ctx, ref: Any, n: int) -> dict[str, Any]:
    if not isinstance(ref, Mapping):
        raise ctx.error("sim", f"'reference' must be a table such as {{ kind = \"constant\" }}, got {ref!r}")
    ref = dict(ref)
    kind = ref.get("kind", "constant")
    if not isinstance(kind, str):
        raise ctx.error("sim.reference", f"'kind' must be a string such as \"step\", got {toml_type(kind)} {kind!r}")
    if kind not in REFERENCE_KINDS:
        raise ctx.error("sim", f"reference: unknown kind '{kind}'{did_you_mean(str(kind), REFERENCE_KINDS)}")
    required, optional = REFERENCE_KINDS[kind]
    ctx.check_keys("sim.reference", ref, ("kind", *required, *optional))
    for key in required:
        if key not in ref:
            raise ctx.error("sim", f"reference kind '{kind}' needs '{key}'")
    out: dict[str, Any] = {"kind": kind}
    for key in ("value", "initial", "final", "center"):
        if key in ref:
            out[key] = ctx.vector("sim.reference", key, ref[key], n)
    for key in ("time", "radius", "side", "speed", "frequency"):
        if key in ref:
            out[key] = ctx.number("sim.reference", key, ref[key], positive=key != "time", minimum=0.0)
    if "phase" in ref:
        out["phase"] = ctx.number("sim.reference", "phase", ref["phase"])
    if "axes" in ref:
        axes = ref["axes"]
        if (
            not isinstance(axes, list)
            or len(axes) != 2
            or not all(isinstance(a, int) and not isinstance(a, bool) and 0 <= a < n for a in axes)
            or axes[0] == axes[1]
        ):
            raise ctx.error("sim.reference", f"'axes' must be two distinct state indices in [0, {n}), got {axes!r}")
        out["axes"] = list(axes)
    if kind == "waypoints":
        pts = ref["points"]
        if not isinstance(pts, list) or not pts:
            raise ctx.error("sim.reference", "'points' must be a non-empty list of states")
        out["points"] = [ctx.vector("sim.reference", "points", p, n) for p in pts]
        out["times"] = ctx.vector("sim.reference", "times", ref["times"], len(pts))
        if any(b <= a for a, b in zip(out["times"], out["times"][1:], strict=False)):
            raise ctx.error("sim.reference", "'times' must be strictly increasing")
        interp = ref.get("interpolation", "linear")
        if interp not in ("linear", "hold"):
            raise ctx.error("sim.reference", f"'interpolation' must be 'linear' or 'hold', got {interp!r}")
        out["interpolation"] = interp
    return out


def _parse_output_feedback(ctx: _Ctx, st: Mapping[str, Any], sim: SimConfig, probe: Any) -> None:
    """``[sim] measured``, ``sensor_noise``, ``process_noise`` and ``disturbance``."""
    names = probe.state_names
    if "measured" in st:
        measured = st["measured"]
        if not isinstance(measured, list) or not measured or not all(isinstance(v, str) for v in measured):
            raise ctx.error("sim", f"'measured' must be a non-empty list of state names, got {measured!r}")
        for v in measured:
            if v not in names:
                hint = did_you_mean(v, names)
                raise ctx.error(
                    "sim",
                    f"'measured': unknown state '{v}'{hint if 'did you mean' in hint else ''} "
                    f"(valid: {', '.join(names)})",
                )
        if len(set(measured)) != len(measured):
            raise ctx.error("sim", f"'measured' lists a state twice: {measured!r}")
        sim.measured = list(measured)
    p = len(sim.measured) if sim.measured is not None else probe.state_dim
    for key, size in (("sensor_noise", p), ("process_noise", probe.input_dim)):
        if key in st:  # one standard deviation per measured state / per input
            values = ctx.vector("sim", key, st[key], size)
            bad = [i for i, v in enumerate(values) if v < 0]
            if bad:
                raise ctx.error("sim", f"'{key}' standard deviations must be >= 0, got {values[bad[0]]:g} at {bad[0]}")
            setattr(sim, key, values)
    if sim.sensor_noise is not None and sim.measurement_noise is not None:
        raise ctx.error("sim", "give 'sensor_noise' (on the measured outputs) or 'measurement_noise', not both")
    if "disturbance" in st:
        from shinro_ctrl.disturbances import parse_disturbances

        try:
            sim.disturbance = parse_disturbances(st["disturbance"], probe, "[sim] disturbance")
        except ConfigError as exc:
            raise ctx.error("", str(exc)) from None


def _parse_estimator(ctx: _Ctx, doc: Mapping[str, Any], sim: SimConfig, probe: Any) -> EstimatorConfig | None:
    """``[estimator]``: the class, its keys (``from_plant``'s keywords but ``measured``) and their types."""
    if "estimator" not in doc:
        if sim.measured is not None and len(sim.measured) < probe.state_dim:
            raise ctx.error(
                "sim",
                f"'measured' = {sim.measured} leaves states unmeasured; add an [estimator] table "
                "(type = \"KalmanFilter\", \"ExtendedKalmanFilter\" or \"Luenberger\")",
            )
        return None
    import inspect

    from shinro_ctrl.estimators import estimator_class

    et = dict(doc["estimator"])
    if "type" not in et:
        raise ctx.error("estimator", "missing key 'type' (KalmanFilter, ExtendedKalmanFilter, Luenberger or FullState)")
    try:
        ecls = estimator_class(str(et["type"]))
    except ConfigError as exc:
        raise ctx.error("estimator", str(exc)) from None
    params = list(inspect.signature(ecls.from_plant).parameters.values())[1:]
    keys = tuple(q.name for q in params if q.kind == q.KEYWORD_ONLY and q.name != "measured")  # measured: [sim]
    loop_keys = {"initial_estimate": "list[float]", "P0": "Any"}  # read by the loop (output_feedback.LOOP_KEYS)
    ctx.check_keys("estimator", et, ("type", *keys, *loop_keys))
    ctx.check_types("estimator", et, {**signature_annotations(ecls.from_plant, 1), **loop_keys})
    if "initial_estimate" in et:
        ctx.vector("estimator", "initial_estimate", et["initial_estimate"], probe.state_dim)
    if ecls.__name__ == "FullState" and sim.measured is not None and len(sim.measured) < probe.state_dim:
        raise ctx.error("estimator", "FullState needs every state measured; remove [sim] measured or pick a filter")
    return EstimatorConfig(ecls.__name__, {k: v for k, v in et.items() if k != "type"})
