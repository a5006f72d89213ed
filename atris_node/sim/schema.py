"""A small declarative checker for scene tables: every key typed, ranged and named in errors.

A table is read with :func:`read_table` against a mapping ``key -> Field``. Unknown keys,
missing required keys, wrong types and out-of-range values raise
:class:`atris_node.errors.ConfigError` whose message names the dotted key, says what is
accepted and what was given, e.g. ``scene camera.exposure_us: must be > 0, got -3``.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

from atris_node.errors import ConfigError

#: marks a field without default
REQUIRED: Any = object()
Check = Callable[[Any], str | None]


def fail(where: str, problem: str, value: Any) -> ConfigError:
    """The ConfigError for ``where`` (dotted key) with ``problem`` and the value given."""
    return ConfigError(f"scene {where}: {problem}, got {value!r}")


def positive(v: float) -> str | None:
    """Accept v > 0."""
    return None if v > 0 else "must be > 0"


def non_negative(v: float) -> str | None:
    """Accept v >= 0."""
    return None if v >= 0 else "must be >= 0"


def within(lo: float, hi: float) -> Check:
    """Accept lo <= v <= hi (numbers) or each element of a list in that range."""
    def check(v: Any) -> str | None:
        values = v if isinstance(v, tuple) else (v,)
        return None if all(lo <= x <= hi for x in values) else f"must be in [{lo}, {hi}]"
    return check


def one_of(*choices: str) -> Check:
    """Accept one of ``choices``."""
    return lambda v: None if v in choices else f"must be one of {', '.join(choices)}"


@dataclass(frozen=True)
class Field:
    """One key of a table: kind is float, int, bool, str, dict, list, 'vec3' or 'floats'."""

    kind: Any
    default: Any = REQUIRED
    check: Check | None = None


def _number(value: Any, where: str, integer: bool) -> float | int:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise fail(where, "must be an integer" if integer else "must be a number", value)
    if integer and not isinstance(value, int):
        raise fail(where, "must be an integer", value)
    if not math.isfinite(value):
        raise fail(where, "must be a finite number", value)
    return int(value) if integer else float(value)


def _floats(value: Any, where: str, length: int | None) -> tuple[float, ...]:
    if not isinstance(value, list) or (length is not None and len(value) != length):
        size = f"{length} numbers" if length else "a list of numbers"
        raise fail(where, f"must be {size}", value)
    return tuple(float(_number(x, f"{where}[{i}]", False)) for i, x in enumerate(value))


def convert(field: Field, value: Any, where: str) -> Any:
    """Convert ``value`` to the field's kind; raise ConfigError naming ``where``."""
    if field.kind is float or field.kind is int:
        typed: Any = _number(value, where, field.kind is int)
    elif field.kind == "vec3":
        typed = _floats(value, where, 3)
    elif field.kind == "floats":
        typed = _floats(value, where, None)
    elif field.kind in (bool, str, dict, list):
        if not isinstance(value, field.kind):
            kind = {dict: "table", list: "list"}.get(field.kind, field.kind.__name__)
            raise fail(where, f"must be a {kind}", value)
        typed = value
    else:  # pragma: no cover - a programming error in a spec
        raise TypeError(f"unknown field kind {field.kind!r}")
    problem = field.check(typed) if field.check else None
    if problem:
        raise fail(where, problem, value)
    return typed


def read_table(table: Any, where: str, spec: Mapping[str, Field]) -> dict[str, Any]:
    """Check ``table`` against ``spec``; return a dict with every key of ``spec`` filled."""
    if not isinstance(table, dict):
        raise fail(where, "must be a table", table)
    unknown = sorted(set(table) - set(spec))
    if unknown:
        raise ConfigError(f"scene {where}.{unknown[0]}: unknown key; accepted: "
                          f"{', '.join(sorted(spec))}")
    out: dict[str, Any] = {}
    for key, field in spec.items():
        if key in table:
            out[key] = convert(field, table[key], f"{where}.{key}")
        elif field.default is REQUIRED:
            raise ConfigError(f"scene {where}.{key}: required key is missing")
        else:
            out[key] = field.default
    return out


def tables(value: Any, where: str) -> list[dict[str, Any]]:
    """An array of tables (``[[name]]``), or one table, as a list of tables."""
    if isinstance(value, dict):
        return [value]
    if not isinstance(value, list) or not all(isinstance(v, dict) for v in value):
        raise fail(where, "must be a table or an array of tables", value)
    return list(value)
