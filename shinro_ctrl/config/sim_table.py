"""The ``[sim]`` table (run length, initial state, reference, output feedback) and the ``[estimator]`` table."""

from __future__ import annotations

import inspect
from collections.abc import Mapping
from typing import Any

from shinro_ctrl.config.context import _Ctx, whole_steps
from shinro_ctrl.config.schema import REFERENCE_KINDS, SIM_KEYS, EstimatorConfig, SimConfig
from shinro_ctrl.config.strict import signature_annotations, table_annotations, toml_type
from shinro_ctrl.errors import ConfigError
from shinro_ctrl.validation import close_match_hint, did_you_mean

__all__: list[str] = []


def _parse_sim(ctx: _Ctx, doc: Mapping[str, Any], probe: Any) -> SimConfig:
    """``[sim]`` (optional): every key checked against the plant ``probe``."""
    n = probe.state_dim
    st = dict(doc.get("sim", {}))
    ctx.check_keys("sim", st, SIM_KEYS)
    ctx.check_types("sim", st, table_annotations(SimConfig))
    sim = SimConfig()
    if "duration" in st:
        sim.duration = ctx.number("sim", "duration", st["duration"], positive=True)
    try:  # a duration is run step by step: never rounded silently
        whole_steps(sim.duration, probe.dt, "'duration'" if "duration" in st else "'duration' (the default)")
    except ConfigError as exc:
        raise ctx.error("sim", str(exc)) from None
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
    _parse_nonideal(ctx, st, sim, probe)
    if "excitation" in st:
        from shinro_ctrl.sim.excitation import parse_excitation

        try:
            parse_excitation(st["excitation"], probe.input_names, probe.dt)
        except ConfigError as exc:
            raise ctx.error("sim", str(exc)) from None
        exc_value = st["excitation"]
        sim.excitation = [dict(e) for e in (exc_value if isinstance(exc_value, list) else [exc_value])]
    if "seed" in st:
        if isinstance(st["seed"], bool) or not isinstance(st["seed"], int) or st["seed"] < 0:
            raise ctx.error("sim", f"'seed' must be a non-negative integer, got {st['seed']!r}")
        sim.seed = st["seed"]
    return sim


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
                raise ctx.error(
                    "sim",
                    f"'measured': unknown state '{v}'{close_match_hint(v, names)} (valid: {', '.join(names)})",
                )
        if len(set(measured)) != len(measured):
            raise ctx.error("sim", f"'measured' lists a state twice: {measured!r}")
        sim.measured = list(measured)
    p = len(sim.measured) if sim.measured is not None else probe.state_dim
    for key, size in (("sensor_noise", p), ("process_noise", probe.input_dim)):
        if key in st:  # one standard deviation per measured state / per input
            if key == "sensor_noise" and sim.measured is None and isinstance(st[key], list) and len(st[key]) != size:
                raise ctx.error(
                    "sim",
                    f"'sensor_noise' must have {size} values (one per measured state; without 'measured' all "
                    f"{size} states are measured), got {len(st[key])}",
                )
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


def _parse_nonideal(ctx: _Ctx, st: Mapping[str, Any], sim: SimConfig, probe: Any) -> None:
    """``[sim] actuator`` (one value per input) and ``sensor`` (one per state): see :mod:`.nonideal_table`."""
    from shinro_ctrl.config.nonideal_table import ACTUATOR_KEYS, SENSOR_KEYS, nonideal_channels
    from shinro_ctrl.errors import InvalidArgument

    for key, keys, size, unit in (
        ("actuator", ACTUATOR_KEYS, probe.input_dim, "one per input"),
        ("sensor", SENSOR_KEYS, probe.state_dim, "one per state"),
    ):
        if key in st:
            try:
                nonideal_channels(st[key], keys, size, probe.dt, unit=unit, what=key)
            except InvalidArgument as exc:
                raise ctx.error("sim", str(exc)) from None
            setattr(sim, key, dict(st[key]))


def _parse_estimator(ctx: _Ctx, doc: Mapping[str, Any], sim: SimConfig, probe: Any) -> EstimatorConfig | None:
    """``[estimator]``: the class, its keys (``from_plant``'s keywords but ``measured``) and their types."""
    if "estimator" not in doc:
        if sim.measured is not None and len(sim.measured) < probe.state_dim:
            raise ctx.error(
                "sim",
                f"'measured' = {sim.measured} leaves states unmeasured; add an [estimator] table "
                '(type = "KalmanFilter", "ExtendedKalmanFilter" or "Luenberger")',
            )
        return None
    from shinro_ctrl.estimators import ESTIMATOR_REGISTRY

    et = dict(doc["estimator"])
    if "type" not in et:
        raise ctx.error("estimator", f"missing key 'type' (one of {', '.join(ESTIMATOR_REGISTRY.names())})")
    try:
        ecls = ESTIMATOR_REGISTRY.lookup(str(et["type"]))
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
