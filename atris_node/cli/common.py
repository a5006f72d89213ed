"""Options shared by the subcommands that build a unit configuration."""

from __future__ import annotations

import argparse
import os
import sys

from atris_node import config


def add_config_arguments(parser: argparse.ArgumentParser) -> None:
    """``--config FILE`` (default $ATRIS_CONFIG) and repeated ``--set key=value``."""
    parser.add_argument("--config", default=os.environ.get("ATRIS_CONFIG"),
                        help="TOML parameter file (default: $ATRIS_CONFIG)")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                        help="override one parameter (repeatable)")


def config_from_args(args: argparse.Namespace) -> config.Config:
    """The effective configuration: defaults < file < ATRIS_* environment < --set."""
    return config.load(file=args.config, overrides=args.set)


def add_output_argument(parser: argparse.ArgumentParser) -> None:
    """``--output/-o FILE`` for commands that print a shipped file."""
    parser.add_argument("--output", "-o", help="write to this file instead of stdout")


def write_text(text: str, output: str | None) -> int:
    """Write ``text`` to ``output`` (a path) or to stdout; exit status 0."""
    if output:
        with open(output, "w", encoding="utf-8") as out:
            out.write(text)
    else:
        sys.stdout.write(text)
    return 0
