"""``atris bench NAME``: benchmarks; each writes rows to stdout (``--json`` for a list)."""

from __future__ import annotations

import argparse

from atris_node.cli import dispatch

#: benchmark -> (module, one-line help); each module has add_arguments and run.
BENCHES: dict[str, tuple[str, str]] = {
    "demod": ("atris_node.bench.demod", "demodulation ms per sub-frame against a plain copy"),
    "sim": ("atris_node.bench.sim", "simulator sub-frames per second"),
    "accuracy": ("atris_node.bench.accuracy", "range error against run time per configuration"),
    "latency": ("atris_node.bench.latency", "data age from sub-frame to frame on the bus"),
    "adaptive": ("atris_node.bench.adaptive", "adaptive N against fixed N = 32"),
    "safety": ("atris_node.bench.safety", "sector verdicts scored against the truth per scene"),
    "bus": ("atris_node.bench.bus", "publish cycle cost and publisher period on a virtual bus"),
    "profile": ("atris_node.bench.profile",
                "pipeline stages and demodulation per map; --sweep: cost growth"),
    "interference": ("atris_node.bench.interference",
                     "foreign-light metric against its limit, both ways, per situation"),
    "realtime": ("atris_node.bench.realtime",
                 "the node chain fed at a camera's native rate: drops, output, age, CPU"),
}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("name", choices=sorted(BENCHES), help="benchmark to run")
    parser.add_argument("rest", nargs=argparse.REMAINDER, help="options of the benchmark")


def run(args: argparse.Namespace) -> int:
    return dispatch("atris bench", BENCHES, [args.name, *args.rest])
