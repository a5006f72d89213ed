"""Write parsed TOML documents back to text, for tests that fuzz the file loaders.

Accepts what ``tomllib`` gives (tables, arrays of tables, strings, ints, floats including
nan and inf, bools, lists) and nothing else; the inverse of ``tomllib.loads`` up to
formatting. Mutated documents (a value of the wrong type, a deleted or unknown key) are
written as they are: judging them is the loader's job.

Example:
    >>> import tomllib
    >>> doc = {"a": 1, "t": {"x": [1.5, float("inf")]}, "u": [{"k": "v"}]}
    >>> tomllib.loads(dumps(doc)) == doc
    True
"""

from __future__ import annotations

import json
import math
import re
from collections.abc import Mapping
from typing import Any

from atris_node.errors import ConfigError

_BARE_KEY = re.compile(r"^[A-Za-z0-9_-]+$")


def key(name: str) -> str:
    """A TOML key: bare when it can be, else a quoted string."""
    return name if _BARE_KEY.match(name) else json.dumps(name)


def value(item: Any) -> str:
    """One inline TOML value."""
    if isinstance(item, bool):
        return "true" if item else "false"
    if isinstance(item, int):
        return str(item)
    if isinstance(item, float):
        return _float(item)
    if isinstance(item, str):
        return json.dumps(item)
    if isinstance(item, list | tuple):
        return "[" + ", ".join(value(v) for v in item) + "]"
    if isinstance(item, Mapping):
        return "{" + ", ".join(f"{key(k)} = {value(v)}" for k, v in item.items()) + "}"
    raise ConfigError(f"cannot write a {type(item).__name__} as TOML; accepted: bool, int, "
                      "float, str, list, table")


def _float(item: float) -> str:
    if math.isnan(item):
        return "nan"
    if math.isinf(item):
        return "inf" if item > 0 else "-inf"
    return repr(item)


def _is_table_array(item: Any) -> bool:
    return isinstance(item, list) and bool(item) and all(isinstance(v, Mapping) for v in item)


def dumps(doc: Mapping[str, Any], prefix: str = "") -> str:
    """The TOML text of ``doc`` (nested tables become ``[a.b]`` headers)."""
    lines = [f"{key(k)} = {value(v)}" for k, v in doc.items()
             if not isinstance(v, Mapping) and not _is_table_array(v)]
    out = "\n".join(lines) + ("\n" if lines else "")
    for k, v in doc.items():
        name = f"{prefix}{key(k)}"
        if isinstance(v, Mapping):
            out += f"\n[{name}]\n" + dumps(v, f"{name}.")
        elif _is_table_array(v):
            for table in v:
                out += f"\n[[{name}]]\n" + dumps(table, f"{name}.")
    return out
