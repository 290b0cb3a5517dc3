"""Boundary checks shared by plants, controllers and the config layer.

Each check raises one of our errors with a message that names the argument
and says what was expected and what was found. They run at construction and
at public entry points, never inside hot loops.
"""

from __future__ import annotations

import difflib
import math
from collections.abc import Iterable, Mapping
from typing import Any

import numpy as np

from shinro_ctrl.errors import InvalidArgument, NonFiniteError, ShinroError

__all__ = [
    "MAX_MODEL_ENTRY",
    "MAX_WEIGHT_ENTRY",
    "all_finite",
    "as_matrix",
    "as_vector",
    "bound_pair",
    "bound_vector",
    "check_finite",
    "check_nonnegative",
    "check_positive",
    "close_match_hint",
    "closest",
    "did_you_mean",
    "measurement_matrix",
    "state_space",
    "unknown_keys",
    "weight_matrix",
    "whole_step_count",
]


def closest(word: str, choices: Iterable[str]) -> str | None:
    """The closest of ``choices`` to ``word`` (difflib ratio >= 0.6), or None."""
    found = difflib.get_close_matches(word, list(choices), n=1, cutoff=0.6)
    return found[0] if found else None


def did_you_mean(word: str, choices: Iterable[str]) -> str:
    """A ``"; did you mean 'x'?"`` suffix, or the list of valid choices."""
    choices = sorted(choices)
    near = closest(word, choices)
    if near is not None:
        return f"; did you mean '{near}'?"
    return f"; valid: {', '.join(choices)}" if choices else ""


def close_match_hint(word: str, choices: Iterable[str]) -> str:
    """``"; did you mean 'x'?"`` when one of ``choices`` is close to ``word``, else ``""`` (for a message that lists
    the valid choices itself; :func:`did_you_mean` lists them when none is close)."""
    near = closest(word, choices)
    return f"; did you mean '{near}'?" if near is not None else ""


def unknown_keys(mapping: Mapping[str, Any], allowed: Iterable[str]) -> list[str]:
    """Keys of ``mapping`` not in ``allowed``, in their original order."""
    allowed = set(allowed)
    return [k for k in mapping if k not in allowed]


def _number(name: str, value: Any, what: str) -> Any:
    """Refuse text, booleans and complex numbers where a real number is meant (``float("0.1")`` would accept)."""
    if isinstance(value, str | bytes | bool | complex | np.bool_) or np.iscomplexobj(value):
        raise InvalidArgument(f"{name} must be {what}, got {type(value).__name__} {value!r}")
    return value


def real_array(name: str, value: Any) -> np.ndarray:
    """``value`` as a float array; complex values and text are errors.

    ``np.asarray(value, dtype=float)`` would drop an imaginary part with only a
    warning and parse strings such as ``"10"``; a weight or state given that
    way is a mistake, so it is refused naming ``name``.

    Raises:
        InvalidArgument: complex, text or otherwise non-numeric values.
    """
    arr = np.asarray(value)
    if np.iscomplexobj(arr):
        raise InvalidArgument(f"{name} must be real, got complex values {arr.ravel()[:6].tolist()}")
    if arr.dtype.kind in "USO":
        if arr.dtype.kind in "US" or any(
            isinstance(v, str | bytes | complex) or np.iscomplexobj(v) for v in arr.ravel().tolist()
        ):
            raise InvalidArgument(f"{name} must hold real numbers, got {value!r}")
    return arr.astype(float, copy=False)


def check_positive(name: str, value: Any) -> float:
    """Return ``value`` as a float; raise ``ValueError`` naming it unless finite and > 0."""
    _number(name, value, "a positive number")
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise InvalidArgument(f"{name} must be a positive number, got {value!r}") from None
    if not math.isfinite(v) or v <= 0.0:
        raise InvalidArgument(f"{name} must be positive and finite, got {v!r}")
    return v


def check_nonnegative(name: str, value: Any) -> float:
    """Return ``value`` as a float; raise ``ValueError`` naming it unless finite and >= 0."""
    _number(name, value, "a non-negative number")
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise InvalidArgument(f"{name} must be a non-negative number, got {value!r}") from None
    if not math.isfinite(v) or v < 0.0:
        raise InvalidArgument(f"{name} must be >= 0 and finite, got {v!r}")
    return v


def check_finite(name: str, value: Any) -> Any:
    """Raise :class:`NonFiniteError` naming ``name`` if ``value`` holds NaN or inf."""
    arr = np.asarray(value, dtype=float)
    if not np.all(np.isfinite(arr)):
        raise NonFiniteError(f"{name} must be finite, got {np.array2string(arr, precision=4)}")
    return value


def as_vector(name: str, value: Any, n: int, *, finite: bool = True) -> np.ndarray:
    """``value`` as a float array of shape ``(n,)``; a scalar is accepted when n == 1.

    Raises:
        ValueError: wrong shape or not numeric (the message names ``name``).
        NonFiniteError: NaN or inf, when ``finite``.
    """
    if type(value) is np.ndarray and value.shape == (n,) and value.dtype == np.float64:
        if math.isfinite(sum(value.tolist())):  # fast path (a finite sum may overflow: slow path decides)
            return value
        arr = value
    else:
        try:
            arr = real_array(name, value)
        except InvalidArgument:
            raise
        except (TypeError, ValueError):
            raise InvalidArgument(f"{name} must be numeric with shape ({n},), got {value!r}") from None
    if arr.ndim == 0 and n == 1:
        arr = arr.reshape(1)
    if arr.shape != (n,):
        raise InvalidArgument(f"{name}: expected shape ({n},) but found {arr.shape}")
    if finite and not np.all(np.isfinite(arr)):
        raise NonFiniteError(f"{name} must be finite, got {np.array2string(arr, precision=4)}")
    return arr


def as_matrix(name: str, value: Any, shape: tuple[int, int], *, finite: bool = True) -> np.ndarray:
    """``value`` as a float array of exactly ``shape``.

    Raises:
        ValueError: wrong shape or not numeric.
        NonFiniteError: NaN or inf, when ``finite``.
    """
    try:
        arr = np.atleast_2d(real_array(name, value))
    except InvalidArgument:
        raise
    except (TypeError, ValueError):
        raise InvalidArgument(f"{name} must be a numeric {shape} matrix, got {value!r}") from None
    if arr.shape != shape:
        raise InvalidArgument(f"{name}: expected shape {shape} but found {arr.shape}")
    if finite and not np.all(np.isfinite(arr)):
        raise NonFiniteError(f"{name} must be finite")
    return arr


def weight_matrix(name: str, value: Any, n: int, *, definite: bool = False, rtol: float = 1e-9) -> np.ndarray:
    """A cost weight as a symmetric ``(n, n)`` matrix: the one weight check of LQR and MPC.

    Accepts a full matrix, or a vector of length ``n`` (or a scalar when
    ``n == 1``) meaning the diagonal. With ``s = max |W_ij|`` the matrix must
    be symmetric, ``max |W − Wᵀ| <= rtol · s``, and positive semidefinite,
    ``λ_min(W) >= −rtol · s`` (positive definite, ``λ_min > rtol · s``, when
    ``definite``): LQR and MPC costs are otherwise meaningless. The
    tolerances are relative to the matrix's own scale, so a large weight
    symmetric up to rounding passes and a tiny one is judged as strictly.

    Returns:
        ``½ (W + Wᵀ)`` ``(n, n)``.

    Raises:
        InvalidArgument: wrong shape, asymmetric, or not (semi)definite.
        NonFiniteError: NaN or inf.
    """
    try:
        arr = real_array(name, value)
    except InvalidArgument:
        raise
    except (TypeError, ValueError):
        raise InvalidArgument(f"{name} must be a numeric ({n}, {n}) matrix, got {value!r}") from None
    if arr.ndim <= 1:
        arr = np.diag(as_vector(name, arr, n))
    if arr.shape != (n, n):
        raise InvalidArgument(f"{name}: expected ({n}, {n}) but found {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise NonFiniteError(f"{name} must be finite")
    tiny = np.finfo(float).tiny
    scale = max(float(np.max(np.abs(arr), initial=0.0)), tiny)
    if scale > MAX_WEIGHT_ENTRY:
        raise InvalidArgument(
            f"{name}: entries up to {scale:.3g} are too large for the design's arithmetic (|entry| <= "
            f"{MAX_WEIGHT_ENTRY:.0e}); scale the weights down (only their ratios matter)"
        )
    half = 0.5 * arr  # halves first: arr ± arrᵀ may overflow float64 for entries near its limit
    half_asym = float(np.max(np.abs(half - half.T), initial=0.0))
    if half_asym > 0.5 * rtol * scale:
        asym = f"{2.0 * half_asym:.3g}" if half_asym < 8e307 else f"{half_asym:.3g}·2"
        raise InvalidArgument(f"{name} must be symmetric; max |{name} - {name}ᵀ| = {asym} (scale {scale:.3g})")
    W = half + half.T
    try:
        lam_min = float(np.linalg.eigvalsh(W).min()) if W.size else 0.0
    except np.linalg.LinAlgError:
        raise InvalidArgument(
            f"{name}: its eigenvalues cannot be computed (entries up to {scale:.3g}); scale the weights down"
        ) from None
    if definite and (not W.size or lam_min <= rtol * scale):
        raise InvalidArgument(f"{name} must be positive definite; smallest eigenvalue {lam_min:.3g}")
    if lam_min < -rtol * scale:
        raise InvalidArgument(f"{name} must be positive semidefinite; smallest eigenvalue {lam_min:.3g}")
    return W


#: Largest weight entry a design accepts: a Riccati solution scales with the weights and meets the model's entries.
MAX_WEIGHT_ENTRY = 1e150

#: Largest model-matrix entry a design accepts: products like ``Aᵀ S A`` stay within float64 up to about 1e100.
MAX_MODEL_ENTRY = 1e100


def state_space(A: Any, B: Any) -> tuple[np.ndarray, np.ndarray]:
    """Validate a linear pair: ``A`` square ``(n, n)``, ``B`` ``(n, m)`` (a ``(n,)`` vector means m = 1).

    Returns:
        ``(A, B)`` as float arrays.

    Raises:
        InvalidArgument: not numeric, wrong shapes, or empty.
        NonFiniteError: NaN or inf, or an entry above :data:`MAX_MODEL_ENTRY`.
    """
    try:
        A_ = np.atleast_2d(real_array("A", A))
        B_ = real_array("B", B)
    except InvalidArgument:
        raise
    except (TypeError, ValueError):
        raise InvalidArgument("A and B must be numeric matrices") from None
    if A_.ndim != 2 or A_.shape[0] != A_.shape[1]:
        raise InvalidArgument(f"A: expected a square (n, n) matrix but found {A_.shape}")
    n = A_.shape[0]
    if B_.ndim == 1 and B_.shape == (n,):
        B_ = B_.reshape(n, 1)
    if B_.ndim != 2 or B_.shape[0] != n:
        raise InvalidArgument(f"B: expected ({n}, m) but found {B_.shape}")
    m = B_.shape[1]
    if m == 0 or n == 0:
        raise InvalidArgument(f"A and B must have at least one state and one input, found n={n}, m={m}")
    for name, M in (("A", A_), ("B", B_)):
        if not np.all(np.isfinite(M)):
            raise NonFiniteError(f"{name} must be finite")
        big = np.abs(M)
        if big.max() > MAX_MODEL_ENTRY:
            i, j = np.unravel_index(int(np.argmax(big)), M.shape)
            raise NonFiniteError(
                f"{name}[{i}, {j}] = {M[i, j]:.3g} is too large for a design (|entry| <= {MAX_MODEL_ENTRY:.0e}): "
                "the products of a Riccati or pole-placement step overflow float64; check the model's "
                "parameters and units"
            )
    return A_, B_


def measurement_matrix(C: Any, n: int) -> np.ndarray:
    """A measurement matrix ``C`` ``(p, n)`` of ``y = C x``; a vector ``(n,)`` is one row (``p = 1``).

    Raises:
        InvalidArgument: not ``n`` columns (the check of :func:`as_matrix`, named ``C``).
        NonFiniteError: NaN or inf.
    """
    C = np.atleast_2d(np.asarray(C, dtype=float))
    return as_matrix("C", C, (C.shape[0], n))


def bound_vector(name: str, value: Any, size: int, default: float) -> np.ndarray:
    """A bound vector ``(size,)``: None gives ``default``, a scalar broadcasts; ±inf allowed, NaN not.

    Raises:
        InvalidArgument: not numeric or the wrong shape.
        NonFiniteError: NaN.
    """
    if value is None:
        return np.full(size, default)
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise InvalidArgument(f"{name} must be numeric with shape ({size},), got {value!r}") from None
    if arr.ndim == 0:
        arr = np.full(size, float(arr))
    if arr.shape != (size,):
        raise InvalidArgument(f"{name}: expected ({size},) but found {arr.shape}")
    if np.any(np.isnan(arr)):
        raise NonFiniteError(f"{name} must not contain NaN, got {np.array2string(arr, precision=4)}")
    return arr


def bound_pair(lo_name: str, hi_name: str, lo: Any, hi: Any, size: int) -> tuple[np.ndarray, np.ndarray]:
    """Lower and upper bounds ``(size,)`` (None = unbounded) with ``lo <= hi`` and each finite on its own side.

    Raises:
        InvalidArgument: wrong shape, ``lo > hi``, ``lo = +inf`` or ``hi = -inf`` (naming the index).
        NonFiniteError: NaN.
    """
    lo_arr = bound_vector(lo_name, lo, size, -np.inf)
    hi_arr = bound_vector(hi_name, hi, size, np.inf)
    bad = np.flatnonzero(~(lo_arr <= hi_arr) | (lo_arr == np.inf) | (hi_arr == -np.inf))
    if bad.size:
        i = int(bad[0])
        raise InvalidArgument(
            f"{lo_name} must be <= {hi_name} (and finite on its side); index {i}: {lo_arr[i]} > {hi_arr[i]}"
        )
    return lo_arr, hi_arr


def all_finite(*arrays: np.ndarray) -> bool:
    """True when every entry of every array is finite.

    ``np.isfinite(a).all()`` per array: about 1.5x cheaper than summing the
    entries as Python floats (7 µs for a 7-DOF arm's ``A`` and ``B``), and,
    unlike a numpy sum, it cannot overflow into a warning.
    """
    return all(bool(np.isfinite(a).all()) for a in arrays)


#: Relative tolerance of "a whole number of steps" (``t / dt`` is rarely an exact integer in floats).
STEP_RTOL = 1e-9


def whole_step_count(seconds: float, dt: float, what: str, error: type[ShinroError] = InvalidArgument) -> int:
    """``round(seconds / dt)``, refusing a time between two whole steps (rounding it would move it silently).

    Raises:
        error: ``seconds / dt`` is not within :data:`STEP_RTOL` (relative) of a whole number; the message names
            both values and the two nearest valid times.
    """
    ratio = seconds / dt
    steps = round(ratio)
    if abs(ratio - steps) > STEP_RTOL * max(1.0, ratio):
        lo, hi = math.floor(ratio) * dt, math.ceil(ratio) * dt
        raise error(
            f"{what} = {seconds:g} s is not a whole number of steps of dt = {dt:g} s ({ratio:.6g} steps): "
            f"use {lo:g} s or {hi:g} s"
        )
    return int(steps)
