"""Compiled passes that replaced numpy steps give the numpy steps' numbers, bitwise, on
simulated maps: the numpy forms are kept here as the reference."""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt
import pytest

from atris_node.codes import walsh_chips
from atris_node.demod import BlockDemodulator
from atris_node.pipeline import peaks
from atris_node.pipeline.bands import line_bands, read_rows
from atris_node.pipeline.noise import NOISE_TILE_PX, NoiseMap, noise_map
from atris_node.sim import Simulator, load_scene
from atris_node.types import DistortionMap

SCENES = ("indoor_lab", "window_sun", "jammer_line")


def _first_map(name: str) -> tuple[DistortionMap, Any]:
    scene = load_scene(name)
    chips = walsh_chips(scene.code_length, scene.code_row)
    sim = Simulator(scene, chips=chips, seed=1)
    demod = BlockDemodulator(chips, bits=scene.camera.bits, lag=0)
    sequence = 0
    while True:
        dmap = demod.push(sim.render(sequence))
        sequence += 1
        if dmap is not None:
            return dmap, sim.calibration()


@pytest.fixture(scope="module", params=SCENES)
def scene_map(request: pytest.FixtureRequest) -> tuple[DistortionMap, list[tuple[int, int]],
                                                          NoiseMap]:
    dmap, calibration = _first_map(request.param)
    bands = line_bands(calibration.camera, calibration.laser, 0.3, 10.0, 3.0)
    spans = read_rows(bands, peaks.read_padding(peaks.ExtractorSettings()),
                      dmap.values.shape[0])
    return dmap, spans, noise_map(dmap.values, spans)


def _peak_snr_numpy(values: npt.NDArray[Any], local: NoiseMap,
                    rows: npt.NDArray[np.int64]) -> npt.NDArray[np.float64]:
    """The numpy form peaks._peak_snr had before its compiled pass."""
    width = rows.shape[1]
    cols = np.broadcast_to(np.arange(width), rows.shape)
    at = np.maximum(rows, 0)
    tile_row = local.tile_row[at]
    tile_col = cols // NOISE_TILE_PX
    value = values[at, cols].astype(np.float64)
    snr = (value - local.background_tiles[tile_row, tile_col]) / local.sigma_tiles[
        tile_row, tile_col]
    return np.where(rows >= 0, snr, 0.0)


def test_smoke_peak_snr_is_the_numpy_form(scene_map: tuple[Any, Any, NoiseMap]) -> None:
    dmap, spans, local = scene_map
    found = peaks.strong_maxima(dmap.values, spans, local, 6.0, 3, 12)
    rng = np.random.default_rng(0)
    height, width = dmap.values.shape
    anywhere = rng.integers(-1, height, (4, width))  # rows outside the bands read too
    for rows in (found, anywhere):
        want = _peak_snr_numpy(dmap.values, local, rows)
        got = peaks._peak_snr(dmap.values, local, rows)
        assert got.dtype == want.dtype and got.shape == want.shape
        np.testing.assert_array_equal(got, want)
    assert (found >= 0).sum() > 100

