"""``atris soak``: a one-minute run of the four-unit simulated fleet meets the targets
(RSS growth <= 5 MB, no thread left behind, deadline misses <= 0.1 %, no E2E error).

The soak runs in this process through the CLI module, so the JSON it prints is what is
checked and the conftest fixtures catch any thread or bus the fleet leaves behind. The
deadline target assumes the CPU is there: on a machine whose one-minute load average is
above its core count (a shared test host), the miss fraction is held to 2 % and a warning
names the load (docs/reliability.md).
"""

from __future__ import annotations

import argparse
import json
import os
import warnings

import pytest

from atris_node.cli import soak as soak_cli
from atris_node.errors import ConfigError

FIELDS = {"minutes", "units", "rss_start_mb", "rss_end_mb", "rss_growth_mb", "threads_start",
          "threads_end", "cycles", "deadline_misses", "deadline_miss_fraction", "e2e_errors",
          "measurements"}


def overloaded() -> tuple[bool, float]:
    load = os.getloadavg()[0]
    return load > (os.cpu_count() or 1), load


def run_cli(*argv: str) -> None:
    parser = argparse.ArgumentParser()
    soak_cli.add_arguments(parser)
    assert soak_cli.run(parser.parse_args(list(argv))) == 0


def test_one_minute_soak_meets_the_targets(capsys: pytest.CaptureFixture[str]) -> None:
    run_cli("--minutes", "1", "--json")
    report = json.loads(capsys.readouterr().out)
    assert set(report) >= FIELDS
    assert report["units"] == 4 and report["minutes"] == 1.0
    assert 0.0 < report["rss_start_mb"] < 4000.0
    assert report["rss_growth_mb"] <= 5.0
    assert report["threads_start"] >= 1 + 4  # the main thread and one loop per unit
    assert report["threads_end"] == report["threads_start"]
    assert report["e2e_errors"] == 0
    # four units at 20 Hz over the 48 s after the warm-up
    assert 0.8 * 4 * 20 * 48 <= report["cycles"] <= 1.1 * 4 * 20 * 48
    assert report["measurements"] >= 4 * 5
    fraction = report["deadline_miss_fraction"]
    assert fraction == pytest.approx(report["deadline_misses"] / report["cycles"])
    busy, load = overloaded()
    if busy:
        warnings.warn(f"load average {load:.1f} on {os.cpu_count()} cores: deadline misses "
                      f"{fraction:.2%} held to 2 % instead of 0.1 %", stacklevel=1)
    assert fraction <= (0.02 if busy else 0.001), f"deadline misses {fraction:.3%}"


def test_minutes_out_of_range_is_a_clear_error() -> None:
    with pytest.raises(ConfigError, match="--minutes"):
        run_cli("--minutes", "0")
