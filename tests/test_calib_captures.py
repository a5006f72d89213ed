"""Capture-set manifests and per-column line rows on distortion maps."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from atris_node.errors import CalibrationError
from calib.board import BoardSpec
from calib.captures import (
    BoardLaserCapture,
    CaptureSet,
    FlatCapture,
    load_capture_set,
    load_map,
    write_manifest,
)
from calib.peaks import find_line_rows
from calib.synthetic import render_line_map


def _set(root: Path) -> CaptureSet:
    return CaptureSet(root, 3, BoardSpec(squares_x=8), "lab", "truth.calib.toml",
                      ("intrinsics/a.png",), (FlatCapture(0.6, "flat/a.npy"),),
                      (FlatCapture(1.75, "verify/a.npy"),),
                      (BoardLaserCapture("b/p.png", "b/p.npy"),))


def test_manifest_round_trip(tmp_path: Path) -> None:
    write_manifest(_set(tmp_path))
    assert load_capture_set(tmp_path) == _set(tmp_path)


def test_manifest_errors_are_clear(tmp_path: Path) -> None:
    with pytest.raises(CalibrationError, match="cannot read the capture manifest"):
        load_capture_set(tmp_path)
    path = write_manifest(_set(tmp_path))
    path.write_text(path.read_text().replace("lines = 3", "lines = 0"))
    with pytest.raises(CalibrationError, match="lines must be a positive integer"):
        load_capture_set(tmp_path)
    path.write_text(path.read_text().replace("lines = 0", "lines = 3")
                    .replace("distance_m = 0.6", "distance = 0.6"))
    with pytest.raises(CalibrationError, match=r"each \[\[flat\]\] needs distance_m and map"):
        load_capture_set(tmp_path)


def test_maps_must_be_2d_integer_arrays(tmp_path: Path) -> None:
    np.save(tmp_path / "ok.npy", np.arange(12, dtype=np.int16).reshape(3, 4))
    np.save(tmp_path / "float.npy", np.zeros((3, 4)))
    assert load_map(tmp_path / "ok.npy").dtype == np.int32
    with pytest.raises(CalibrationError, match="integer array"):
        load_map(tmp_path / "float.npy")
    with pytest.raises(CalibrationError, match="cannot read distortion map"):
        load_map(tmp_path / "missing.npy")


def test_line_rows_are_sub_pixel_and_ordered_top_first() -> None:
    rng = np.random.default_rng(1)
    truth = np.stack([np.linspace(100.3, 110.7, 320), np.full(320, 200.25),
                      np.linspace(300.0, 290.0, 320)])
    rows = find_line_rows(render_line_map(truth, 400, rng, noise_dn=4.0), 3)
    assert rows.valid.all()
    assert np.abs(rows.rows - truth).max() < 0.1


def test_glints_and_gaps_drop_columns_not_shift_lines() -> None:
    rng = np.random.default_rng(2)
    truth = np.stack([np.full(320, 120.0), np.full(320, 160.0)])
    truth[1, 200:240] = -1.0  # line 1 missing: these columns must not count
    distortion_map = render_line_map(truth, 300, rng)
    distortion_map[60:63, 80:84] += 5000  # a glint above both lines
    rows = find_line_rows(distortion_map, 2)
    assert not rows.valid[:, 200:240].any()
    assert not rows.valid[:, 80:84].any()
    good = rows.valid[0]
    assert good.sum() > 250
    assert np.abs(rows.rows[:, good] - truth[:, good]).max() < 0.2
