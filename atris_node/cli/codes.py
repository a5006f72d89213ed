"""``atris codes --length N [--mode async|sync] [--json]``: cyclic orthogonal Walsh code sets.

JSON fields (relied on by other tools): ``length``, ``mode``, ``max_codes``, ``codes`` (one
maximal set, lowest rows first, each a string of '0'/'1' chips) and, for async,
``set_count`` and ``sets`` (every maximal set as 1-based rows; left out for N >= 128).
``rows`` gives the 1-based rows of ``codes``.
"""

from __future__ import annotations

import argparse
import json
from typing import Any

from atris_node import codes

#: from this length on the async sets are too many to list (2^21 at N = 128)
SETS_LISTED_BELOW = 128


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--length", "-n", type=int, required=True,
                        help="code length N, a power of two >= 4")
    parser.add_argument("--mode", choices=("async", "sync"), default="async",
                        help="async: orthogonal at any shift; sync: aligned chips only")
    parser.add_argument("--json", action="store_true", help="print as JSON")


def describe(length: int, mode: codes.Mode) -> dict[str, Any]:
    """The JSON document of ``atris codes`` for one length and mode."""
    rows = codes.code_set(length, mode)
    doc: dict[str, Any] = {
        "length": length,
        "mode": mode,
        "max_codes": len(rows),
        "rows": list(rows),
        "codes": [codes.chips_string(codes.walsh_chips(length, r)) for r in rows],
    }
    if mode == "async":
        doc["set_count"] = codes.async_set_count(length)
        if length < SETS_LISTED_BELOW:
            doc["sets"] = [list(s) for s in codes.iter_async_sets(length)]
    return doc


def _rule_text(length: int) -> str:
    ranges = [f"{2**j + 1}..{2 ** (j + 1)}" for j in range(1, codes.max_async_codes(length))]
    return "row 2, then one row from each of: " + ", ".join(ranges)


def print_table(doc: dict[str, Any]) -> None:
    """Readable form of :func:`describe`'s document."""
    print(f"length {doc['length']}, mode {doc['mode']}: {doc['max_codes']} codes")
    print(f"{'row':>5}  chips (1 = projector on)")
    for row, chips in zip(doc["rows"], doc["codes"], strict=True):
        print(f"{row:>5}  {chips}")
    if doc["mode"] != "async":
        return
    print(f"\n{doc['set_count']} maximal sets: {_rule_text(doc['length'])}")
    for rows in doc.get("sets", [])[:64]:
        print("  " + ", ".join(str(r) for r in rows))
    if len(doc.get("sets", [])) > 64:
        print(f"  ... ({doc['set_count'] - 64} more; --json lists all)")


def run(args: argparse.Namespace) -> int:
    doc = describe(codes.check_length(args.length), args.mode)
    if args.json:
        print(json.dumps(doc))
    else:
        print_table(doc)
    return 0
