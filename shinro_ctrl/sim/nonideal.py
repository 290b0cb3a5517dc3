"""Non-ideal actuators and sensors in the closed loop: delay, first-order lag, quantization, rate limit.

:class:`RobotSim` holds one :class:`ActuatorModel` between the controller and
the plant and one :class:`SensorModel` between the plant and the estimator
when the scenario's ``[sim]`` table names them (``[sim] actuator = { delay,
lag, quantization, rate_limit }``, ``[sim] sensor = { delay, quantization }``),
in both loops (standalone and MuJoCo: the models act on the signals the loop
exchanges with ``plant.step`` once per control step ``dt``, so a MuJoCo loop
with substeps holds the applied input constant over its substeps as it does
without them). Each model is reset at the start of every run, and its step
writes into buffers allocated at construction.

**Actuator.** The controller's command ``c_k`` goes through, per input ``i``
and in this order:

1. delay of ``d_i`` whole steps (a FIFO): ``v_k = c_{k − d_i}``, with
   ``c_j = u₀`` (the operating input) for ``j < 0``;
2. rate limit ``r_i``: ``w_k = w_{k−1} + clip(v_k − w_{k−1}, −r_i dt, r_i dt)``
   (``w_{−1} = u₀``), so ``|Δw|/dt ≤ r_i``;
3. quantization ``q_i``: ``s_k = q_i · round(w_k / q_i)`` (nearest multiple,
   ties to even); the rate limiter keeps its own unquantized ``w``, so a slow
   ramp still advances, and ``|Δs| ≤ r_i dt + q_i``;
4. first-order lag ``τ_i``: ``u̇_a = (s − u_a)/τ`` integrated exactly over the
   step with ``s`` held (zero-order hold): with ``α = e^{−dt/τ}``,

       u_a(t_{k+1}) = s_k + (u_a(t_k) − s_k) α,

   and the plant is given the exact mean of ``u_a`` over the step,

       ū_k = s_k + (u_a(t_k) − s_k) β,   β = (τ/dt)(1 − α),

   the constant input with the same impulse ``∫ u_a dt`` (``u_a(t_0) = u₀``;
   ``τ = 0``: ``ū_k = s_k``).

A stage whose parameter is zero (``rate_limit``: ``inf``) is the identity.
The trajectory the loop records (``SimResult.u``) is the command ``c``; the
controller and the estimator know only the command.

**Sensor.** The measurement ``y_k`` (after the sensor noise of ``[sim]``) is
quantized, ``q_i round(y_i / q_i)``, and delayed by ``d_i`` whole steps; before
``d_i`` readings exist the sensor repeats its first reading. The estimator
(and through it the controller) is given the delayed reading; the recorded
``SimResult.y`` is what it was given.

A delay is given in seconds and must be a whole number of steps of ``dt``
(:func:`~shinro_ctrl.config.nonideal_table.delay_steps` refuses anything else,
naming the two nearest valid delays).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from shinro_ctrl.config.nonideal_table import ACTUATOR_KEYS, SENSOR_KEYS, delay_steps, nonideal_channels
from shinro_ctrl.errors import InvalidArgument
from shinro_ctrl.validation import as_vector, check_positive

__all__ = ["ActuatorModel", "DelayLine", "SensorModel"]


class DelayLine:
    """A FIFO of whole steps per channel: ``out_k[i] = in_{k − d_i}[i]``, allocation-free per step.

    Args:
        steps: Delay per channel ``(p,)`` [steps], non-negative integers.
    """

    def __init__(self, steps: np.ndarray):
        self.steps = np.asarray(steps, dtype=np.intp).copy()
        p = self.steps.shape[0]
        self._len = L = int(self.steps.max(initial=0)) + 1
        self._buf = np.zeros((L, p))
        self._flat = self._buf.reshape(-1)  # a view: np.take reads the ring through it
        self._head = 0
        self.delayed = bool(self.steps.any())
        self._uniform = bool((self.steps == self.steps[0]).all()) if p else True
        # with per-channel delays: the flat indices of the samples to read, for each position of the head
        heads = np.arange(L, dtype=np.intp)[:, None]
        self._table = ((heads - self.steps[None, :]) % L) * p + np.arange(p, dtype=np.intp)[None, :]

    def reset(self, value: np.ndarray) -> None:
        """Fill the line with ``value`` ``(p,)``: the output before any input has travelled through."""
        self._buf[:] = value
        self._head = 0

    def push(self, value: np.ndarray, out: np.ndarray) -> np.ndarray:
        """Write ``value`` ``(p,)`` and read the delayed sample of every channel into ``out`` ``(p,)``."""
        self._head = h = (self._head + 1) % self._len
        self._buf[h] = value
        if not self.delayed:
            np.copyto(out, value)
        elif self._uniform:
            np.copyto(out, self._buf[(h - int(self.steps[0])) % self._len])
        else:
            np.take(self._flat, self._table[h], out=out, mode="clip")  # "raise" would buffer `out`
        return out


def _quantize(v: np.ndarray, q: np.ndarray, mask: np.ndarray | None, tmp: np.ndarray) -> None:
    """``v ← q rint(v / q)`` in place (ties to even) where ``mask`` (q > 0; None: everywhere); ``q`` holds 1 where
    it is 0."""
    np.divide(v, q, out=tmp)
    np.rint(tmp, out=tmp)
    tmp *= q
    if mask is None:
        np.copyto(v, tmp)
    else:
        np.copyto(v, tmp, where=mask)


class ActuatorModel:
    """The input path from the controller's command to the plant (module docstring for the math and order).

    Args:
        input_dim: Inputs ``m``.
        dt: Control step [s].
        delay: Transport delay [s] per input (scalar or ``(m,)``), whole steps of ``dt``.
        lag: Time constant τ [s] of the first-order lag (0: none).
        quantization: Quantization step q (0: none).
        rate_limit: Largest rate |Δu|/dt [unit/s] (inf: none).

    Raises:
        InvalidArgument: a negative, NaN or infinite value (but ``rate_limit = inf``), a non-positive rate
            limit, a wrong length, or a delay that is not a whole number of steps.
    """

    def __init__(
        self,
        input_dim: int,
        dt: float,
        *,
        delay: float | np.ndarray | list[float] = 0.0,
        lag: float | np.ndarray | list[float] = 0.0,
        quantization: float | np.ndarray | list[float] = 0.0,
        rate_limit: float | np.ndarray | list[float] = np.inf,
    ):
        dt = check_positive("dt", dt)
        m = int(input_dim)
        table = {
            "delay": _as_list(delay),
            "lag": _as_list(lag),
            "quantization": _as_list(quantization),
            "rate_limit": _as_list(rate_limit),
        }
        ch = nonideal_channels(table, ACTUATOR_KEYS, m, dt, unit="one per input", what="actuator")
        self.input_dim, self.dt = m, dt
        self.delay, self.lag = ch["delay"], ch["lag"]
        self.quantization, self.rate_limit = ch["quantization"], ch["rate_limit"]
        self.delay_steps = np.array([delay_steps(float(d), dt) for d in self.delay], dtype=np.intp)
        self._line = DelayLine(self.delay_steps)
        self._rated = bool(np.isfinite(self.rate_limit).any())
        self._step_max = self.rate_limit * dt  # inf where unlimited: the clip is then the identity
        self._quantized = bool((self.quantization > 0).any())
        self._qmask = None if (self.quantization > 0).all() else self.quantization > 0
        self._q = np.where(self.quantization > 0, self.quantization, 1.0)
        self._lagged = bool((self.lag > 0).any())
        with np.errstate(divide="ignore", over="ignore", invalid="ignore"):
            x = np.where(self.lag > 0, dt / np.where(self.lag > 0, self.lag, 1.0), np.inf)  # dt/τ; inf: no lag
            self._alpha = np.exp(-x)  # u_a(t_{k+1}) = s + (u_a(t_k) − s) α
            beta = -np.expm1(-x) / x  # (τ/dt)(1 − α), accurate for τ ≫ dt too
        self._beta = np.where(np.isfinite(x), beta, 0.0)  # the step's mean: s + (u_a − s) β
        self._v = np.zeros(m)
        self._w = np.zeros(m)
        self._a = np.zeros(m)
        self._lo = np.zeros(m)
        self._hi = np.zeros(m)
        self._tmp = np.zeros(m)
        self._out = np.zeros(m)

    @classmethod
    def from_table(cls, table: Mapping[str, Any], input_dim: int, dt: float) -> ActuatorModel:
        """From a ``[sim] actuator`` table (every key optional)."""
        ch = nonideal_channels(table, ACTUATOR_KEYS, input_dim, dt, unit="one per input", what="actuator")
        return cls(input_dim, dt, **ch)

    @property
    def ideal(self) -> bool:
        """True when every stage is the identity."""
        return not (self._line.delayed or self._rated or self._quantized or self._lagged)

    def reset(self, u0: Any) -> None:
        """Start a run at rest at the operating input ``u0`` ``(m,)``: FIFO, rate limiter and lag all hold it."""
        u0 = as_vector("u0", u0, self.input_dim)
        self._line.reset(u0)
        self._w[:] = u0
        self._a[:] = u0

    def __call__(self, u: np.ndarray) -> np.ndarray:
        """The input ``(m,)`` the plant receives over this step for the command ``u`` ``(m,)``.

        Returns an internal buffer, overwritten by the next call.
        """
        v = self._line.push(u, self._v)
        if self._rated:
            w = self._w
            np.subtract(w, self._step_max, out=self._lo)
            np.add(w, self._step_max, out=self._hi)
            np.minimum(v, self._hi, out=v)  # w_k = w_{k−1} + clip(v − w_{k−1}, ±r dt)
            np.maximum(v, self._lo, out=v)
            np.copyto(w, v)
        if self._quantized:
            _quantize(v, self._q, self._qmask, self._tmp)
        out = self._out
        if not self._lagged:
            np.copyto(out, v)
            return out
        a, tmp = self._a, self._tmp
        np.subtract(a, v, out=tmp)  # u_a − s
        np.multiply(tmp, self._beta, out=out)
        out += v  # ū = s + (u_a − s) β
        tmp *= self._alpha
        np.add(v, tmp, out=a)  # u_a ← s + (u_a − s) α
        return out


class SensorModel:
    """The measurement path from the plant to the estimator: quantization, then a delay of whole steps.

    Args:
        output_dim: Measured outputs ``p``.
        dt: Control step [s].
        delay: Delay [s] per output (scalar or ``(p,)``), whole steps of ``dt``.
        quantization: Quantization step per output (0: none).

    Attributes:
        states: The state index each output measures when built by :meth:`from_table` (else None).

    Raises:
        InvalidArgument: a negative, NaN or infinite value, a wrong length, or a delay that is not a whole
            number of steps.
    """

    def __init__(
        self,
        output_dim: int,
        dt: float,
        *,
        delay: float | np.ndarray | list[float] = 0.0,
        quantization: float | np.ndarray | list[float] = 0.0,
    ):
        dt = check_positive("dt", dt)
        p = int(output_dim)
        table = {"delay": _as_list(delay), "quantization": _as_list(quantization)}
        ch = nonideal_channels(table, SENSOR_KEYS, p, dt, unit="one per output", what="sensor")
        self.output_dim, self.dt = p, dt
        self.delay, self.quantization = ch["delay"], ch["quantization"]
        self.delay_steps = np.array([delay_steps(float(d), dt) for d in self.delay], dtype=np.intp)
        self._line = DelayLine(self.delay_steps)
        self._quantized = bool((self.quantization > 0).any())
        self._qmask = None if (self.quantization > 0).all() else self.quantization > 0
        self._q = np.where(self.quantization > 0, self.quantization, 1.0)
        self._v = np.zeros(p)
        self._tmp = np.zeros(p)
        self._out = np.zeros(p)
        self._primed = False
        self.states: tuple[int, ...] | None = None  # the state each output measures, when built from_table

    @classmethod
    def from_table(cls, table: Mapping[str, Any], state_dim: int, dt: float, measured: Any = None) -> SensorModel:
        """From a ``[sim] sensor`` table (values per state ``(n,)``), for the outputs at the ``measured`` indices."""
        ch = nonideal_channels(table, SENSOR_KEYS, state_dim, dt, unit="one per state", what="sensor")
        idx = np.arange(state_dim, dtype=np.intp) if measured is None else np.asarray(measured, dtype=np.intp)
        sensor = cls(idx.shape[0], dt, **{k: v[idx] for k, v in ch.items()})
        sensor.states = tuple(int(i) for i in idx)
        return sensor

    def reset(self) -> None:
        """Forget the readings: the next one fills the delay line (the sensor repeats it until it arrives)."""
        self._primed = False

    def __call__(self, y: np.ndarray) -> np.ndarray:
        """The reading ``(p,)`` the estimator is given now, for the measurement ``y`` ``(p,)`` taken now.

        Returns an internal buffer, overwritten by the next call.
        """
        v = self._v
        np.copyto(v, y)
        if self._quantized:
            _quantize(v, self._q, self._qmask, self._tmp)
        if not self._primed:
            self._line.reset(v)
            self._primed = True
        return self._line.push(v, self._out)


def _as_list(value: Any) -> Any:
    """A scalar as is; an array as a list of floats (the table checker takes TOML-like values)."""
    if isinstance(value, np.ndarray):
        return [float(v) for v in value.reshape(-1)] if value.ndim else float(value)
    if isinstance(value, tuple):
        return list(value)
    if value is None:
        raise InvalidArgument("a non-ideal actuator or sensor parameter must be a number or a list, got None")
    return value
