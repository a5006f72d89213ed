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
        assert row["sectors_valid"] > 0 and row["no_surface_samples"] >= 0
        assert row["near_phantom"] + row["far"] <= row["sectors_valid"]
        assert 0.0 <= row["invalid_fraction"] <= 1.0


def test_feature_a_misidentified_sample_is_an_error_not_skipped() -> None:
    """``range_rmse_m`` scores every valid sample against the true surface of its column,
    whatever line it was given: a sample given a line the truth does not have in its
    column, and a range 1.5 m off, counts with its full error.

    Checked against the former metric (:func:`accuracy.range_errors`, the true point of
    the sample's own line, skipped where the truth lacks that line): it skipped the sample
    (the last assertion, run with it, failed)."""
    import dataclasses
    import math

    import numpy as np

    from atris_node.codes import walsh_chips
    from atris_node.demod import BlockDemodulator
    from atris_node.pipeline.chain import Pipeline, PipelineConfig
    from atris_node.sim import Simulator

    scene = load_scene("indoor_lab")
    chips = walsh_chips(scene.code_length, scene.code_row)
    sim = Simulator(scene, chips=chips, seed=1)
    config = PipelineConfig()
    pipe = Pipeline(config, sim.calibration(), sim.mounting, config.layout())
    demod = BlockDemodulator(chips, bits=scene.camera.bits, lag=0)
    dmap = next(m for m in (demod.push(sim.render(i)) for i in range(chips.size))
                if m is not None)
    result = pipe.process(dmap)
    truth = sim.truth((dmap.first_sequence + dmap.last_sequence) // 2, config.layout())
    clean, none = accuracy.surface_errors(result, truth)
    assert none == 0 and float(np.sqrt(np.mean(clean**2))) < 0.05
    first = int(np.flatnonzero(result.valid)[0])
    col = int(result.samples.col_px[first])
    absent = int(np.flatnonzero(~truth.line_visible[:, col])[0])
    lines = result.samples.line.copy()
    lines[first] = absent  # identified as a line that does not reach this column
    points = result.points_camera_m.copy()
    points[0, 2] += 1.5  # and triangulated 1.5 m too far with that line's angle
    wrong = dataclasses.replace(result, points_camera_m=points,
                                samples=dataclasses.replace(result.samples, line=lines))
    errors, _ = accuracy.surface_errors(wrong, truth)
    assert math.isclose(float(np.abs(errors).max()), 1.5, abs_tol=0.2)


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
