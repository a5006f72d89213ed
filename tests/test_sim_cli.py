"""``atris sim`` and ``atris bench sim`` through the real command entry point."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from atris_node.cli import main


def test_feature_sim_json_has_measured_and_true_sectors(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    import cv2

    assert main(["sim", "indoor_lab", "--frames", "1", "--json", "--out", str(tmp_path)]) == 0
    records = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    assert len(records) == 1
    record = records[0]
    assert (record["first_sequence"], record["last_sequence"]) == (0, 15)
    assert len(record["sectors"]) == 8
    keys = {"state", "distance_m", "sigma_m", "confidence", "truth_m"}
    assert all(keys <= set(s) for s in record["sectors"])
    for s in record["sectors"]:
        assert s["state"] in ("VALID", "NO_RETURN", "INVALID")
        assert (s["distance_m"] is None) == (s["state"] != "VALID")  # null unless VALID
        assert (s["sigma_m"] is None) == (s["state"] != "VALID")
    assert {"nearest_m", "closing_speed_mps", "ttc_s", "interference", "ambiguous_samples",
            "too_faint_samples", "near_stripes", "pipeline_ms"} <= set(record)
    assert record["too_faint_samples"] == 0  # a lit wall and ground: nothing too faint
    assert record["near_stripes"] == 0  # nothing nearer than the range
    assert record["interference"] is False and record["pipeline_ms"] > 0
    assert record["sectors"][3]["truth_m"] == pytest.approx(3.0, abs=0.01)
    assert record["truth_line_samples"] > 1000 and record["line_samples"] > 0
    plain = cv2.imread(str(tmp_path / "0000_plain.png"), cv2.IMREAD_UNCHANGED)
    demod = cv2.imread(str(tmp_path / "0000_demod.png"), cv2.IMREAD_UNCHANGED)
    assert plain.shape == demod.shape == (400, 640)
    assert demod.max() == 255 and plain.max() < 255


def test_feature_sim_text_output_and_scene_path(capsys: pytest.CaptureFixture[str]) -> None:
    scene = Path(__file__).resolve().parent.parent / "launch" / "scenes" / "jammer_line.toml"
    assert main(["sim", str(scene), "--frames", "1", "--sectors", "4"]) == 0
    out = capsys.readouterr().out
    assert out.startswith("frame 0:") and out.count("/") >= 4


def test_feature_sim_text_tells_free_from_unknown() -> None:
    """NO_RETURN prints "free", INVALID "?", never a number or a dash for either."""
    from atris_node.cli.sim import _text

    sectors = [{"state": "NO_RETURN", "distance_m": None, "truth_m": None},
               {"state": "INVALID", "distance_m": None, "truth_m": 2.0},
               {"state": "VALID", "distance_m": 1.5, "truth_m": 1.5}]
    line = _text({"frame": 0, "line_samples": 1, "line_row_error_px": 0.0,
                  "sectors": sectors})
    assert " free/  -  " in line and "  ?  / 2.00" in line and " 1.50/ 1.50" in line


def test_exception_sim_bad_arguments(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["sim", "indoor_lab", "--frames", "0"]) == 1
    assert "--frames must be >= 1" in capsys.readouterr().err
    assert main(["sim", "no_such_scene"]) == 1
    assert "no scene named 'no_such_scene'" in capsys.readouterr().err


def test_smoke_bench_sim_json_rows(capsys: pytest.CaptureFixture[str]) -> None:
    argv = ["bench", "sim", "--json", "--frames", "4", "--small", "--scenes", "indoor_lab"]
    assert main(argv) == 0
    rows = json.loads(capsys.readouterr().out)
    assert [(r["width"], r["height"], r["noise"]) for r in rows] == [
        (640, 400, True), (640, 400, False)]
    assert all(r["scene"] == "indoor_lab" and r["frames_per_s"] > 0 for r in rows)
