"""`atris bench accuracy`: rows, scene scaling, summary and the work-precision plot."""

from __future__ import annotations

import argparse
from pathlib import Path

import pytest

from atris_node.bench import accuracy
from atris_node.sim import load_scene


def test_rows_carry_the_documented_fields() -> None:
    grid = accuracy.Grid(scenes=("indoor_lab",), code_lengths=(4,),
                         resolutions=((640, 400),), demods=("sliding",),
                         methods=("steger",), roi=(True,))
    rows = list(accuracy.scene_rows("indoor_lab", grid))
    assert len(rows) == 1
    for row in rows:
        assert set(row) >= {"config", "scene", "ms_per_frame", "range_rmse_m",
                            "valid_fraction"}
        assert row["config"] == {"peak_method": "steger", "roi_bands": True,
                                 "identity": "aligned", "code_length": 4,
                                 "resolution": "640x400", "demod": "sliding"}
        assert row["ms_per_frame"] > row["demod_ms"] > 0
        assert 0.0 < row["valid_fraction"] <= 1.0
        assert row["range_rmse_m"] is not None and 0.0 < row["range_rmse_m"] < 0.5
        assert row["sectors_valid"] > 0
        assert row["sectors_too_near"] + row["sectors_too_far"] <= row["sectors_valid"]


def test_scaling_keeps_the_optics() -> None:
    scene = load_scene("indoor_lab")
    big = accuracy.scaled(scene, 1280, 800)
    assert big.camera.focal_px == pytest.approx(2 * scene.camera.focal_px)
    assert big.camera.cx_px == pytest.approx(2 * scene.camera.cx_px + 0.5)
    assert big.camera.psf_sigma_px == pytest.approx(2 * scene.camera.psf_sigma_px)


def test_quick_grid_is_small() -> None:
    args = argparse.Namespace(quick=True, scenes=None)
    grid = accuracy.grid_of(args)
    count = (len(grid.scenes) * len(grid.code_lengths) * len(grid.resolutions)
             * len(grid.demods) * len(grid.methods) * len(grid.roi))
    assert count == 10


def test_summary_and_plot(tmp_path: Path) -> None:
    rows = []
    for scene, rmse in (("a", 0.01), ("b", 0.03), ("c", None)):
        for method in ("steger", "gaussian"):
            rows.append({"config": {"peak_method": method, "roi_bands": True,
                                    "code_length": 16, "resolution": "640x400",
                                    "demod": "block"}, "scene": scene,
                         "ms_per_frame": 5.0, "range_rmse_m": rmse, "valid_fraction": 0.5})
    summary = accuracy.summarise(rows)
    assert len(summary) == 2
    assert summary[0]["range_rmse_m"] == pytest.approx(0.02)
    path = tmp_path / "plot.png"
    accuracy.plot(rows, path)
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
