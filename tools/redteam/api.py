"""Python-API helpers for the ``py`` probes: look an API up (absent -> n/a), call it, judge what came back."""

from __future__ import annotations

import importlib
from collections.abc import Callable
from typing import Any

import numpy as np
from harness import NotApplicable, Outcome


def get(module: str, attr: str | None = None) -> Any:
    """``module.attr`` of the target tree, or :class:`NotApplicable` when that tree has no such API."""
    try:
        mod = importlib.import_module(module)
    except ImportError as exc:
        raise NotApplicable(f"no module {module}") from exc
    if attr is None:
        return mod
    try:
        return getattr(mod, attr)
    except AttributeError as exc:
        raise NotApplicable(f"no {module}.{attr}") from exc


def clean_error(exc: BaseException) -> bool:
    """A refusal a user can act on: our error classes, or a plain TypeError/ValueError with a message."""
    errors = get("shinro_ctrl.errors")
    if isinstance(exc, errors.ShinroError):
        return bool(str(exc).strip())
    return type(exc) in (TypeError, ValueError) and bool(str(exc).strip())


def finite_problem(value: Any, limit: float = float("inf")) -> str | None:
    """Why a returned value is not a sane number array (non-finite or absurdly large), or None."""
    if isinstance(value, tuple | list):
        for v in value:
            why = finite_problem(v, limit)
            if why:
                return why
        return None
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        return None
    if not np.all(np.isfinite(arr)):
        return "returned a non-finite value"
    if arr.size and float(np.max(np.abs(arr))) > limit:
        return f"returned entries of magnitude {float(np.max(np.abs(arr))):.3g}"
    return None


def judge(
    call: Callable[[], Any],
    expect: str,
    needles: tuple[str, ...] = (),
    limit: float = float("inf"),
    check: Callable[[Any], str | None] | None = None,
) -> Outcome:
    """Call ``call`` and classify: ``expect`` is ``refuse``, ``ok`` or ``either``.

    A clean refusal (see :func:`clean_error`) is ok unless ``expect == 'ok'``; an unexpected exception type is a
    traceback; a non-finite or absurd result, or an accepted input that should have been refused, is a wrong answer.
    """
    try:
        value = call()
    except NotApplicable:
        raise
    except Exception as exc:
        msg = f"{type(exc).__name__}: {str(exc).strip().splitlines()[0][:200] if str(exc).strip() else ''}"
        if not clean_error(exc):
            return Outcome("traceback", f"uncaught {msg}")
        if expect == "ok":
            return Outcome("misleading_message", f"valid input refused: {msg}")
        low = str(exc).lower()
        if needles and not any(n.lower() in low for n in needles):
            return Outcome("misleading_message", f"does not name {'/'.join(needles)}: {msg}")
        return Outcome("ok", msg)
    why = finite_problem(value, limit)
    if why:
        return Outcome("wrong_answer_exit0", why)
    if check is not None:
        why = check(value)
        if why:
            return Outcome("wrong_answer_exit0", why)
    if expect == "refuse":
        return Outcome("wrong_answer_exit0", f"accepted, expected a refusal naming {'/'.join(needles) or 'the input'}")
    return Outcome("ok", "finite result")
