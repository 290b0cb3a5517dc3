r"""Disturbances and sensor/process noise of a scenario: what the plant feels and the controller does not know.

A ``[sim] disturbance`` entry is a table (or a list of tables)::

    disturbance = { kind = "step", input = "force", time = 1.0, value = 0.5 }
    disturbance = { kind = "step", body = "quadrotor", time = 0.5, value = [0.3, 0, 0] }

Each acts on exactly one target:

* ``input = <name or index>``: added to that input channel after the
  controller (the applied input is ``u + d``), in both loops, before
  ``plant.step``; in MuJoCo this is the same actuator signal. ``value`` is
  a number in the input's unit.
* ``body = "<MJCF body name>"``: a world-frame force ``value = [Fx, Fy, Fz]``
  [N] at the body's centre of mass. MuJoCo applies it through
  ``xfrc_applied`` (the engine's :meth:`set_body_force`); the standalone
  loop adds its effect ``dt · G F`` to the state after each step, where
  ``G = plant.body_force_map(body)`` is the change of ``ẋ`` per newton
  (for the quadrotor, ``1/m`` on the world velocity). Plants without such
  a map reject body forces, except a model-file plant (``MjcfPlant``),
  which takes them on any body of its file in the MuJoCo loop.

Kinds (``time`` is the start [s], default 0; ``duration`` limits ``step``,
``sine`` and ``noise`` to ``[time, time + duration)``, default forever):

* ``step``: ``d = value``.
* ``impulse``: an impulse ``value`` [unit · s] delivered within the one step
  that contains ``time``, i.e. ``d = value / dt`` there.
* ``sine``: ``d = value · sin(2π frequency (t − time) + phase)``.
* ``noise``: white Gaussian, standard deviation ``value`` per step, from
  its own seeded stream.
* ``push``: a shove on a body, ``d = value`` over ``[time, time + duration)``
  (a ``step`` whose ``time`` and ``duration`` are required and whose target
  must be a ``body``)::

      [[sim.disturbance]]
      kind = "push"
      body = "trunk"
      value = [0, 30, 0]   # 30 N sideways (world y)
      time = 1.0
      duration = 0.1

  In MuJoCo it is ``xfrc_applied[body, :3] = value`` during those steps (the
  controller sees nothing of it but its effect on the state).

Every random draw (disturbance noise, sensor noise, process noise) comes
from its own stream derived from ``[sim] seed``, so adding one kind of
noise does not change the others, nor the legacy ``measurement_noise``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from shinro_ctrl.errors import ConfigError
from shinro_ctrl.validation import did_you_mean

__all__ = [
    "DISTURBANCE_KINDS",
    "DisturbanceProfile",
    "DisturbanceSpec",
    "disturbance_profile",
    "noise_stream",
    "parse_disturbances",
]

#: kind -> (required keys, optional keys) besides ``kind`` and the target (``input`` or ``body``).
DISTURBANCE_KINDS: dict[str, tuple[tuple[str, ...], tuple[str, ...]]] = {
    "step": (("value",), ("time", "duration")),
    "impulse": (("value", "time"), ()),
    "sine": (("value", "frequency"), ("time", "duration", "phase")),
    "noise": (("value",), ("time", "duration")),
    "push": (("value", "time", "duration"), ()),
}
_STREAMS = {"sensor": 1, "process": 2, "disturbance": 3}


def noise_stream(seed: int, what: str) -> np.random.Generator:
    """The seeded generator of one kind of noise (``"sensor"``, ``"process"``, ``"disturbance"``)."""
    return np.random.default_rng([int(seed), _STREAMS[what]])


@dataclass(frozen=True)
class DisturbanceSpec:
    """One parsed disturbance.

    Attributes:
        kind: ``step``, ``impulse``, ``sine``, ``noise`` or ``push``.
        input: Input index, or None for a body force.
        body: Body name, or None for an input disturbance.
        value: ``(1,)`` for an input, ``(3,)`` world force [N] for a body.
        time: Start [s].
        duration: Active length [s] (``inf``: to the end).
        frequency: Sine frequency [Hz].
        phase: Sine phase [rad].
        label: Name used in plots and results.
    """

    kind: str
    input: int | None
    body: str | None
    value: tuple[float, ...]
    time: float = 0.0
    duration: float = math.inf
    frequency: float = 0.0
    phase: float = 0.0
    label: str = ""

    def as_table(self) -> dict[str, Any]:
        """The TOML table this spec round-trips to."""
        out: dict[str, Any] = {"kind": self.kind}
        out["input" if self.input is not None else "body"] = self.input if self.input is not None else self.body
        out["value"] = self.value[0] if self.input is not None else list(self.value)
        out["time"] = self.time
        if math.isfinite(self.duration) and self.kind != "impulse":
            out["duration"] = self.duration
        if self.kind == "sine":
            out["frequency"], out["phase"] = self.frequency, self.phase
        return out


def _number(where: str, key: str, v: Any, *, minimum: float | None = None, positive: bool = False) -> float:
    if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
        raise ConfigError(f"{where}: '{key}' must be a finite number, got {v!r}")
    if positive and v <= 0:
        raise ConfigError(f"{where}: '{key}' must be positive, got {v!r}")
    if minimum is not None and v < minimum:
        raise ConfigError(f"{where}: '{key}' must be >= {minimum:g}, got {v!r}")
    return float(v)


def _one(table: Any, plant: Any, where: str, body_ok: Any) -> DisturbanceSpec:
    if not isinstance(table, Mapping):
        example = '{ kind = "step", input = 0, value = 1.0 }'
        raise ConfigError(f"{where}: expected a table such as {example}, got {table!r}")
    t = dict(table)
    kind = t.get("kind")
    if not isinstance(kind, str) or kind not in DISTURBANCE_KINDS:
        raise ConfigError(f"{where}: unknown kind {kind!r}{did_you_mean(str(kind), DISTURBANCE_KINDS)}")
    required, optional = DISTURBANCE_KINDS[kind]
    allowed = ("kind", "input", "body", *required, *optional)
    for k in t:
        if k not in allowed:
            raise ConfigError(f"{where}: unknown key '{k}' for kind '{kind}'{did_you_mean(k, allowed)}")
    for k in required:
        if k not in t:
            raise ConfigError(f"{where}: kind '{kind}' needs '{k}'")
    if ("input" in t) == ("body" in t):
        raise ConfigError(f"{where}: give exactly one target, 'input' (name or index) or 'body' (a body force)")
    names = tuple(plant.input_names)
    if kind == "push" and "input" in t:
        raise ConfigError(f"{where}: a 'push' is a force on a body: give 'body' (a body name), not 'input'")
    if "input" in t:
        i = t["input"]
        if isinstance(i, str):
            if i not in names:
                raise ConfigError(f"{where}: unknown input '{i}'{did_you_mean(i, names)} (valid: {', '.join(names)})")
            index = names.index(i)
        elif isinstance(i, int) and not isinstance(i, bool) and 0 <= i < len(names):
            index = i
        else:
            raise ConfigError(f"{where}: 'input' must be an input name ({', '.join(names)}) or index, got {i!r}")
        value: tuple[float, ...] = (_number(where, "value", t["value"]),)
        body, label = None, f"d_{names[index]}"
    else:
        body = t["body"]
        if not isinstance(body, str):
            raise ConfigError(f"{where}: 'body' must be a body name, got {body!r}")
        body_ok(body)  # raises ConfigError when the plant cannot take a force on it
        v = t["value"]
        if not isinstance(v, list) or len(v) != 3:
            raise ConfigError(f"{where}: a body force 'value' must be [Fx, Fy, Fz] in newtons, got {v!r}")
        value = tuple(_number(where, "value", x) for x in v)
        index, label = None, f"F_{body}"
    if kind == "noise" and any(x < 0 for x in value):
        raise ConfigError(f"{where}: a noise 'value' is a standard deviation and must be >= 0, got {t['value']!r}")
    return DisturbanceSpec(
        kind=kind,
        input=index,
        body=body,
        value=value,
        time=_number(where, "time", t.get("time", 0.0), minimum=0.0),
        duration=_number(where, "duration", t["duration"], positive=True) if "duration" in t else math.inf,
        frequency=_number(where, "frequency", t["frequency"], positive=True) if "frequency" in t else 0.0,
        phase=_number(where, "phase", t["phase"]) if "phase" in t else 0.0,
        label=label,
    )


def parse_disturbances(value: Any, plant: Any, where: str = "[sim] disturbance") -> list[DisturbanceSpec]:
    """Parse ``[sim] disturbance``: a table or a list of tables (see the module docstring).

    Args:
        value: The TOML value.
        plant: The plant (its input names; its ``body_force_map`` for body forces).
        where: Prefix of error messages.

    Raises:
        ConfigError: unknown kind, key, input or body; a missing key; bad values.
    """
    items = value if isinstance(value, list) else [value]
    if not items:
        raise ConfigError(f"{where}: an empty list; give a table or leave the key out")

    def body_ok(body: str) -> None:
        try:
            plant.body_force_map(body)
        except (ValueError, KeyError, NotImplementedError) as exc:
            # a model-file plant: any body of its file takes a force in MuJoCo (the standalone loop asks the
            # plant for its body_force_map when the run starts)
            tree = getattr(plant, "tree", None)
            names = [b.name for b in getattr(tree, "bodies", ()) if b.name]
            if body in names:
                return
            listed = f" (bodies of the model: {', '.join(names)})" if names else ""
            raise ConfigError(f"{where}: {exc}{listed}") from None

    out = []
    for k, item in enumerate(items):
        out.append(_one(item, plant, where if len(items) == 1 else f"{where}[{k}]", body_ok))
    return out


@dataclass
class DisturbanceProfile:
    """Every disturbance sampled on the run's time grid (built once, before the loop).

    Attributes:
        values: ``(T, k)`` one column per input disturbance, three per body force.
        labels: ``(k,)`` column names (``d_force``, ``F_quadrotor_x``, ...).
        inputs: ``(T, m)`` the sum added to the applied input.
        forces: ``[(body, (T, 3))]`` world forces per body.
    """

    values: np.ndarray
    labels: list[str]
    inputs: np.ndarray
    forces: list[tuple[str, np.ndarray]]

    @property
    def active(self) -> bool:
        """Whether any disturbance is present."""
        return bool(self.labels)


def disturbance_profile(
    specs: list[DisturbanceSpec], t: np.ndarray, dt: float, m: int, seed: int
) -> DisturbanceProfile:
    """Sample ``specs`` at the step times ``t (T,)`` (the value held over ``[t_k, t_k + dt)``)."""
    T = t.shape[0]
    rng = noise_stream(seed, "disturbance")
    cols, labels = [], []
    inputs = np.zeros((T, m))
    forces: dict[str, np.ndarray] = {}
    for s in specs:
        width = len(s.value)
        start = s.time
        on = (t >= start - 1e-12 * max(1.0, start)) & (t < start + s.duration - 1e-12)
        amp = np.asarray(s.value)
        if s.kind in ("step", "push"):
            sig = on[:, None] * amp[None, :]
        elif s.kind == "impulse":
            k = int(np.searchsorted(t, start + 1e-12 * max(1.0, start), side="right")) - 1
            sig = np.zeros((T, width))
            if 0 <= k < T:
                sig[k] = amp / dt
        elif s.kind == "sine":
            sig = on[:, None] * amp[None, :] * np.sin(2 * math.pi * s.frequency * (t - start) + s.phase)[:, None]
        else:  # noise
            sig = on[:, None] * amp[None, :] * rng.standard_normal((T, width))
        if s.input is not None:
            inputs[:, s.input] += sig[:, 0]
            labels.append(s.label)
        else:
            forces[s.body] = forces.get(s.body, np.zeros((T, 3))) + sig
            labels.extend(f"{s.label}_{a}" for a in "xyz")
        cols.append(sig)
    values = np.hstack(cols) if cols else np.zeros((T, 0))
    return DisturbanceProfile(values, labels, inputs, list(forces.items()))
