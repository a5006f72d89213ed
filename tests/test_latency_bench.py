"""``atris bench latency``: the row's fields, and ages that are consistent (no timing target
is asserted here; the figures are in docs/benchmarks.md)."""

from __future__ import annotations

import math

from atris_node.bench.latency import measure


def test_row_has_send_and_receive_ages_and_the_send_comes_first() -> None:
    row = measure("indoor_lab", seconds=1.5, code_length=8)
    assert {"scene", "width", "height", "samples", "p50_ms", "p99_ms", "max_ms",
            "receive_p50_ms", "receive_p99_ms", "last_frame_p50_ms", "last_frame_p99_ms",
            "pipeline_p50_ms"} <= set(row)
    assert (row["width"], row["height"]) == (640, 400)
    assert row["samples"] > 0
    ages = [row[k] for k in ("p50_ms", "p99_ms", "max_ms", "receive_p50_ms",
                             "receive_p99_ms", "last_frame_p50_ms", "last_frame_p99_ms",
                             "pipeline_p50_ms")]
    assert all(math.isfinite(a) and a > 0 for a in ages)
    assert row["p50_ms"] <= row["receive_p50_ms"] and row["p99_ms"] <= row["receive_p99_ms"]
    assert row["pipeline_p50_ms"] < row["p50_ms"] <= row["p99_ms"] <= row["max_ms"]
    assert row["p50_ms"] < row["last_frame_p50_ms"]  # the sector frames follow the quality
