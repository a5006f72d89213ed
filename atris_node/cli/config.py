"""``atris config --print``: every effective parameter, its value and where it came from."""

from __future__ import annotations

import argparse
import json

from atris_node.cli.common import add_config_arguments, config_from_args
from atris_node.config import PARAM_BY_KEY


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_config_arguments(parser)
    parser.add_argument("--print", action="store_true", help="print the effective values")
    parser.add_argument("--json", action="store_true", help="print as JSON")


def run(args: argparse.Namespace) -> int:
    cfg = config_from_args(args)
    rows = cfg.describe()
    if args.json:
        print(json.dumps([{"key": k, "value": v, "source": s} for k, v, s in rows], indent=1))
        return 0
    width = max(len(k) for k, _, _ in rows)
    for key, value, source in rows:
        print(f"{key.ljust(width)}  {value!r:<24} {source:<14} # {PARAM_BY_KEY[key].help}")
    return 0
