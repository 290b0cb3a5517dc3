"""Strict value types: a TOML value must match the type annotation of the argument or field it fills.

One checker for every table (:func:`check_value`): ``"bool"``, ``"int"``, ``"float"``, ``"str"``,
``"list[float]"``, ``"Sequence[str]"``, ``"Mapping[...]"``, ``"Any"`` and the array aliases of
:mod:`shinro_ctrl.types` (``"Vector"``, ``"Weight"`` …) (numbers or arrays/tables of numbers) and
unions with ``"|"``. A new table parsed through ``_Ctx.check_types`` with its dataclass's
:func:`table_annotations` gets strict types for free.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from shinro_ctrl.types import NUMERIC_ALIASES

__all__ = [
    "MAX_ELEMENTS",
    "MAX_NESTING",
    "SIZE_LIMITS",
    "check_value",
    "signature_annotations",
    "table_annotations",
    "toml_type",
]

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
    if base == "Any" or base in NUMERIC_ALIASES:  # Vector, Weight, ... (shinro_ctrl.types): numbers or arrays
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
