"""The ``atris`` command: a thin shell over library functions.

Each subcommand lives in its own module with ``add_arguments(parser)`` and
``run(args) -> int`` and is imported only when it is used, so one broken or
slow-to-import subcommand never breaks the others (as in cantools).
Errors print ``error: ...`` and exit 1, usage errors (:class:`UsageError`) exit 2 as
argparse's do; ``--debug`` shows the traceback.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import os
import sys
from collections.abc import Sequence
from types import ModuleType

from atris_node import __version__
from atris_node.errors import AtrisError, UsageError

#: subcommand -> (module, one-line help)
COMMANDS: dict[str, tuple[str, str]] = {
    "run": ("atris_node.cli.run", "run one unit"),
    "launch": ("atris_node.cli.launch", "run the units of a launch file"),
    "sim": ("atris_node.cli.sim", "render a scene, demodulate it and compare with the truth"),
    "codes": ("atris_node.cli.codes", "list cyclic orthogonal Walsh code sets"),
    "monitor": ("atris_node.cli.monitor", "decoded view of every unit on a bus or in a log"),
    "record": ("atris_node.cli.record", "record sub-frames from a camera backend"),
    "replay": ("atris_node.cli.replay", "run the pipeline on recorded sub-frames"),
    "calib": ("atris_node.cli.calib", "calibration: intrinsics, laser planes, verification"),
    "bench": ("atris_node.cli.bench",
              "benchmarks (demod, sim, accuracy, latency, realtime, profile, ...)"),
    "dbc": ("atris_node.cli.dbc", "print the CAN database (DBC), or regenerate the shipped one"),
    "eds": ("atris_node.cli.eds", "print the shipped CANopen EDS"),
    "config": ("atris_node.cli.config", "show the effective configuration"),
    "soak": ("atris_node.cli.soak", "run the simulated fleet and report resource use"),
    "watchdog": ("atris_node.cli.watchdog",
                 "keep the laser enable line set only while a node's lease runs"),
}


def load_command(name: str, table: dict[str, tuple[str, str]]) -> ModuleType:
    """Import the module of subcommand ``name`` from ``table``."""
    module_name, _ = table[name]
    return importlib.import_module(module_name)


def dispatch(prog: str, table: dict[str, tuple[str, str]], argv: Sequence[str]) -> int:
    """Parse ``argv`` for one of the subcommands in ``table`` and run it."""
    width = max(len(n) for n in table)
    listing = "\n".join(f"  {n.ljust(width)}  {h}" for n, (_, h) in table.items())
    if not argv or argv[0] in ("-h", "--help"):
        print(f"usage: {prog} COMMAND [options]\n\ncommands:\n{listing}")
        return 0
    name = argv[0]
    if name not in table:
        raise AtrisError(f"unknown command {name!r}; accepted: {', '.join(table)}")
    module = load_command(name, table)
    parser = argparse.ArgumentParser(prog=f"{prog} {name}", description=table[name][1])
    module.add_arguments(parser)
    args = parser.parse_args(list(argv[1:]))
    return int(module.run(args) or 0)


def _split_global(argv: list[str]) -> tuple[argparse.Namespace, list[str]]:
    parser = argparse.ArgumentParser(prog="atris", add_help=False)
    parser.add_argument("--debug", action="store_true", help="show tracebacks")
    parser.add_argument("-v", "--verbose", action="count", default=0)
    parser.add_argument("--version", action="version", version=f"atris {__version__}")
    return parser.parse_known_args(argv)


#: thread-pool sizes of the BLAS libraries numpy may use
BLAS_THREADS = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")


def one_blas_thread() -> None:
    """One BLAS thread unless the environment says otherwise; called before a
    subcommand imports numpy. An OpenBLAS pool's threads spin for a while after each
    call: the demodulator's gain measure (a dot product over the strip sample of every
    sliding map) kept one spinning on the second core, 20 to 35 % of it, beside the map
    thread or the map process (docs/benchmarks.md, issue 20)."""
    for key in BLAS_THREADS:
        os.environ.setdefault(key, "1")


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``atris`` console script."""
    options, rest = _split_global(list(sys.argv[1:] if argv is None else argv))
    level = logging.DEBUG if options.verbose > 1 else (
        logging.INFO if options.verbose else logging.WARNING)
    logging.basicConfig(level=level, format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    one_blas_thread()
    try:
        return dispatch("atris", COMMANDS, rest)
    except KeyboardInterrupt:
        return 130
    except BrokenPipeError:
        return 0
    except UsageError as exc:
        if options.debug:
            raise
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except (AtrisError, OSError) as exc:
        if options.debug:
            raise
        print(f"error: {exc}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
