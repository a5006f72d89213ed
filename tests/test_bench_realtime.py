"""`atris bench realtime`: camera formats, the row's fields and the drop rule.

Behaviour only: the machine is shared, so no figure here is compared with a time budget.
"""

from __future__ import annotations

import itertools
import json
import math
import time
from collections.abc import Callable
from dataclasses import replace
from typing import Any

import numpy as np
import pytest

from atris_node.bench import realtime
from atris_node.bench.pacing import PacedCamera, PacedProjector, Prerendered
from atris_node.bench.realtime import Options, parse_camera
from atris_node.cli import main
from atris_node.errors import UsageError

SMALL = "320x200@120"


def _finite(value: Any) -> bool:
    """True when every number in ``value`` (nested dicts and lists) is finite."""
    if isinstance(value, dict):
        return all(_finite(v) for v in value.values())
    if isinstance(value, list):
        return all(_finite(v) for v in value)
    return not isinstance(value, float) or math.isfinite(value)


def test_named_and_spelled_out_cameras() -> None:
    assert parse_camera("oak") == realtime.CameraSpec("oak", 1280, 800, 8, 120.0)
    assert parse_camera("paper") == realtime.CameraSpec("paper", 2048, 1088, 10, 600.0)
    spec = parse_camera("640x400@120")
    assert (spec.width, spec.height, spec.bits, spec.rate_hz) == (640, 400, 8, 120.0)
    spec = parse_camera("2048x1088x10@600")
    assert (spec.width, spec.height, spec.bits, spec.rate_hz) == (2048, 1088, 10, 600.0)


@pytest.mark.parametrize("text", ["", "oak-d", "640x400", "640x400@", "640x@120",
                                  "640x400x7@120", "640x400@0", "640x400@20000",
                                  "16x16@120", "640x400x10@1e3"])
def test_exception_bad_camera_is_refused(text: str) -> None:
    with pytest.raises(UsageError, match="accepted: oak, paper or WxH"):
        parse_camera(text)


def test_exception_bad_camera_exits_2_and_says_what_is_accepted(
        capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["bench", "realtime", "--camera", "1280x800@fast"]) == 2
    err = capsys.readouterr().err
    assert "1280x800@fast" in err and "accepted: oak, paper or WxH[xBITS]@RATE" in err


@pytest.mark.parametrize("option", [["--code-length", "12"], ["--seconds", "0"],
                                    ["--queue", "0"], ["--mode", "both"]])
def test_exception_bad_options_exit_2(option: list[str],
                                      capsys: pytest.CaptureFixture[str]) -> None:
    try:
        code = main(["bench", "realtime", "--camera", SMALL, *option])
    except SystemExit as exc:  # argparse's own usage errors
        code = int(exc.code or 0)
    assert code == 2
    assert "error" in capsys.readouterr().err


def test_smoke_short_run_reports_every_field() -> None:
    row = realtime.measure(Options(parse_camera(SMALL), mode="sliding", seconds=1.5,
                                   warmup_s=1.0, code_length=8))
    assert set(row) >= {"camera", "mode", "sub_frames", "measurements", "output_hz",
                        "expected_output_hz", "age_ms", "stages", "threads",
                        "process_cpu_pct", "peak_rss_mb", "prerendered_mb",
                        "sensor_late_max_ms"}
    json.dumps(row, allow_nan=False)  # one JSON object, no NaN or inf
    assert _finite(row)
    subs = row["sub_frames"]
    assert subs["offered"] == 180
    assert subs["gaps"] >= 0
    assert subs["offered"] == subs["consumed"] + subs["dropped"] + subs["pending"]
    assert row["measurements"] > 0 and row["output_hz"] > 0
    assert row["expected_output_hz"] == 120.0
    age = row["age_ms"]
    assert age["samples"] > 0 and 0 < age["p50"] <= age["p99"] <= age["max"]
    assert set(row["stages"]) == {"demod", "pipeline", "publish"}
    # the stage timers count calls inside the counted time span, the camera counts
    # sub-frames by sequence: at either end up to a queue of frames may be read outside it
    calls = row["stages"]["demod"]["calls"]
    assert abs(calls - subs["consumed"]) <= 2 * row["queue_depth"] or subs["dropped"] > 0
    assert row["stages"]["pipeline"]["calls"] > 0
    assert any(t["thread"].startswith("atris-unit") for t in row["threads"])
    assert row["peak_rss_mb"] > row["prerendered_mb"] > 0


STALLED = Options(parse_camera("320x200@240"), mode="sliding", seconds=1.0, warmup_s=0.5,
                  code_length=4, queue_depth=2, stall_ms=40.0)


def test_feature_a_stalled_consumer_drops_and_the_counts_add_up() -> None:
    """Every map stalls 40 ms in the camera loop (no map thread) while sub-frames come
    every 4 ms: the camera's queue fills and the sub-frames that find it full are dropped,
    never lost from the count."""
    row = realtime.measure(replace(STALLED, worker="inline"))
    subs = row["sub_frames"]
    assert subs["offered"] == 240
    assert subs["dropped"] > 0
    assert subs["offered"] == subs["consumed"] + subs["dropped"] + subs["pending"]
    assert 0 < subs["gaps"] <= subs["dropped"]
    assert row["output_hz"] < row["expected_output_hz"]
    assert row["maps"]["skipped"] == 0


def test_with_the_map_thread_a_slow_pipeline_skips_maps_instead_of_dropping_sub_frames(
        ) -> None:
    """The same 40 ms stall per map on the map thread: the loop keeps reading, so the
    camera drops (almost) nothing and maps are skipped instead, newest first. Both runs in
    one test, compared with each other (a loaded machine can still drop a few: run at
    nice 10 beside two CPU-bound processes on 2 cores, 76 against 161, so half, not a
    quarter).

    Checked by running the map-thread row with ``worker="inline"`` as well: its drops were
    those of the first row and the comparison failed."""
    threaded = realtime.measure(STALLED)
    serial = realtime.measure(replace(STALLED, worker="inline"))
    subs = threaded["sub_frames"]
    assert subs["offered"] == subs["consumed"] + subs["dropped"] + subs["pending"]
    assert subs["dropped"] * 2 < serial["sub_frames"]["dropped"]
    assert threaded["maps"]["skipped"] > 0
    assert 0 < threaded["output_hz"] < threaded["expected_output_hz"]


def test_cli_prints_one_json_object(capsys: pytest.CaptureFixture[str]) -> None:
    code = main(["bench", "realtime", "--camera", SMALL, "--mode", "block",
                 "--code-length", "4", "--seconds", "0.5", "--warmup", "0.5", "--json"])
    assert code == 0
    row = json.loads(capsys.readouterr().out)
    assert row["mode"] == "block" and row["expected_output_hz"] == 30.0
    assert row["camera"] == {"name": SMALL, "width": 320, "height": 200, "bits": 8,
                             "rate_hz": 120.0}


def _pictures(rate_hz: float) -> Prerendered:
    """Tiny pre-rendered pictures: OFF all 0, ON all 1 (calibration and mounting unused)."""
    off = [np.zeros((4, 8), np.uint8) for _ in range(4)]
    on = [np.ones((4, 8), np.uint8) for _ in range(4)]
    return Prerendered(off, on, rate_hz, 8, 100.0, None, None)  # type: ignore[arg-type]


def _wait_for(condition: Callable[[], bool], timeout_s: float = 5.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not condition() and time.monotonic() < deadline:
        time.sleep(0.005)


def test_feature_a_full_queue_drops_the_arriving_sub_frame() -> None:
    """Nobody reads: the first ``queue_depth`` counted sub-frames stay queued, every later
    one is dropped, and they add up."""
    camera = PacedCamera(_pictures(2000.0), PacedProjector(), queue_depth=3)
    camera.count(0, 20)
    camera.start(lead_s=0.0)
    _wait_for(lambda: camera.counts.offered >= 20)
    pending = camera.stop()
    assert (camera.counts.offered, camera.counts.dropped, pending) == (20, 17, 3)
    assert camera.counts.consumed == 0


def test_feature_the_projector_strobes_its_code_by_sequence_while_lit() -> None:
    projector = PacedProjector()
    camera = PacedCamera(_pictures(500.0), projector, queue_depth=64)
    projector.set_code([1, 0, 1, 0])
    projector.strobe(1, 0)  # lit from now on
    camera.count(0, 8)
    camera.start(lead_s=0.0)
    subs = [camera.read(1.0) for _ in range(8)]
    projector.off()
    camera.close()
    camera.stop()
    assert [s.sequence for s in subs] == list(range(8))
    assert [s.chip for s in subs] == [1, 0, 1, 0, 1, 0, 1, 0]
    assert [int(s.pixels[0, 0]) for s in subs] == [s.chip for s in subs]
    assert all(b.host_time_s - a.host_time_s == pytest.approx(1 / 500.0)
               for a, b in itertools.pairwise(subs))
    assert camera.counts.consumed == 8 and camera.counts.gaps == 0
