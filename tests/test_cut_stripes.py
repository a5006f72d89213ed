"""Stripes cut by an edge (atris_node.pipeline.peaks.narrowest_stripe_px): a maximum
narrower than any whole stripe of the unit's calibrated width is dropped, on synthetic
maps and on the stress scenes whose sheet's tail on a retro-reflective wall's foot was
read as a stripe 1.9 px off its centre."""

from __future__ import annotations

import math

import numpy as np
import pytest

from atris_node.bench import safety
from atris_node.bench.safety import score_scene
from atris_node.calibration import LaserCalibration
from atris_node.errors import CalibrationError, ConfigError
from atris_node.pipeline import chain
from atris_node.pipeline.bands import Band
from atris_node.pipeline.peaks import (
    NARROWING,
    ExtractorSettings,
    extract_lines,
    narrowest_stripe_px,
)
from atris_node.sim import load_scene
from atris_node.sim.optics import stripe_sigma_px

#: the simulated stripes of the stress scenes: 2.2 mrad at f 625 px, σ about 0.65 px
SIGMA_PX = 0.65
HEIGHT, WIDTH, ROW = 60, 40, 30
BANDS = (Band(0, 10, 50),)


def _map(profile: dict[int, float], noise_dn: float = 10.0, seed: int = 1) -> np.ndarray:
    """(H, W) int32 map: noise of σ ``noise_dn``, and ``profile`` (row offset from ROW ->
    DN) in every column."""
    values = np.random.default_rng(seed).normal(0.0, noise_dn, (HEIGHT, WIDTH))
    for d, dn in profile.items():
        values[ROW + d] += dn
    return np.rint(values).astype(np.int32)


def _stripe(centre: float, peak_dn: float, sigma_px: float = SIGMA_PX) -> dict[int, float]:
    """A whole stripe: a Gaussian of ``sigma_px`` whose maximum is ``peak_dn``, centred
    ``centre`` px from ROW, sampled at the rows."""
    return {d: peak_dn * math.exp(-0.5 * ((d - centre) / sigma_px) ** 2) for d in range(-4, 5)}


def _rows(values: np.ndarray, narrowest: float, method: str = "gaussian") -> np.ndarray:
    settings = ExtractorSettings(method, unique=False, narrowest_sigma_px=narrowest)
    samples = extract_lines(values, np.zeros(values.shape, dtype=np.bool_), BANDS, settings,
                            roi_bands=False).samples
    return samples.row_px


def test_the_narrowest_stripe_is_the_calibrated_one_narrowed() -> None:
    """No width measured: no test (0.0); else the calibrated width over NARROWING. Bad
    settings and calibrations say what is accepted."""
    assert narrowest_stripe_px(0.0) == 0.0
    assert narrowest_stripe_px(SIGMA_PX) == pytest.approx(SIGMA_PX / NARROWING)
    with pytest.raises(ConfigError, match="narrowest_sigma_px"):
        ExtractorSettings(narrowest_sigma_px=-1.0)
    with pytest.raises(CalibrationError, match="stripe_sigma_px"):
        LaserCalibration(0.1, (1.4,), stripe_sigma_px=float("nan"))


def test_a_one_sided_maximum_is_dropped_as_cut() -> None:
    """The profile the retro wall's foot left (104, 3177, 5 DN: the last lit row of a
    sheet's tail) gives a sample 0.15 px above its maximum without the test, and none
    with it. Checked to fail with the test taken out of line_samples (40 samples kept)."""
    cut = _map({-1: 104.0, 0: 3177.0, 1: 5.0}, noise_dn=1.0)
    assert _rows(cut, 0.0).size == WIDTH
    assert np.allclose(_rows(cut, 0.0), ROW - 0.15, atol=0.05)
    assert _rows(cut, narrowest_stripe_px(SIGMA_PX)).size == 0


def test_a_noiseless_one_row_peak_is_cut_a_whole_stripe_kept() -> None:
    """A noiseless map (nothing beside the peak, no noise): one lit row is cut, a whole
    stripe of the calibrated width kept, with the parabolic method (which, unlike the
    Gaussian one, takes a peak without positive neighbours); no division by zero."""
    lone = _map({0: 1000.0}, noise_dn=0.0)
    assert _rows(lone, 0.0, "parabolic").size == WIDTH
    assert _rows(lone, narrowest_stripe_px(SIGMA_PX), "parabolic").size == 0
    whole = _map(_stripe(0.2, 1000.0), noise_dn=0.0)
    assert _rows(whole, narrowest_stripe_px(SIGMA_PX), "parabolic").size == WIDTH


@pytest.mark.parametrize("centre", [-0.5, -0.25, 0.0, 0.3, 0.5])
@pytest.mark.parametrize("peak_dn", [150.0, 600.0, 30_000.0])
def test_whole_stripes_are_kept(centre: float, peak_dn: float) -> None:
    """A whole stripe of the calibrated width, anywhere between two rows and from the SNR
    threshold (150 DN in noise of σ 10 DN) to 3,000 times the noise, loses no sample to
    the test: the samples are those kept without it; so does one 1.5 times narrower (a
    surface seen more obliquely than lit)."""
    for sigma in (SIGMA_PX, SIGMA_PX / 1.5):
        for seed in (1, 2, 3):
            values = _map(_stripe(centre, peak_dn, sigma), seed=seed)
            without = _rows(values, 0.0)
            assert without.size > 0
            with_test = _rows(values, narrowest_stripe_px(SIGMA_PX))
            assert np.array_equal(with_test, without), (sigma, seed)


def test_the_simulators_stripe_width_is_what_the_fit_reads() -> None:
    """The width the simulator hands the pipeline (optics.stripe_sigma_px, in its
    calibration) is the median three-point Gaussian σ of the strong stripes it renders,
    within 10 % (indoor_lab, one map)."""
    from calib.radiometry import stripe_width_px

    scene = load_scene("indoor_lab")
    sim, maps = safety.block_maps(scene, 1)
    dmap = next(iter(maps))
    calibration = sim.calibration()
    assert calibration.laser.stripe_sigma_px == pytest.approx(
        stripe_sigma_px(sim.camera, scene.projector))
    bands = chain.Pipeline(chain.PipelineConfig(), calibration, sim.mounting,
                           safety.LAYOUT).bands
    samples = extract_lines(dmap.values, dmap.saturated, bands,
                            ExtractorSettings(unique=False)).samples
    strong = (samples.snr > 50) & ~samples.saturated
    width = stripe_width_px(dmap.values, samples.row_px[strong],
                            samples.col_px[strong].astype(np.int64))
    assert width == pytest.approx(calibration.laser.stripe_sigma_px, rel=0.1)


@pytest.mark.parametrize("name", ["retro_wall_foot_sheet_tail", "retro_wall_foot_drawn"])
def test_a_sheets_tail_on_a_retro_wall_is_no_stripe(name: str,
                                                   monkeypatch: pytest.MonkeyPatch) -> None:
    """Both retro-wall stress scenes, seed 2, 6 maps: without the cut test the sheet's tail
    reads near phantoms (13 and 2 sector-frames of 48); with it none. The scenes run with
    the test in test_safety_scenes (seed 1)."""
    with_test = score_scene(name, 6, seed=2).row()
    monkeypatch.setattr(chain, "narrowest_stripe_px", lambda sigma_px: 0.0)
    without = score_scene(name, 6, seed=2).row()
    assert without["near_phantom"] > 0, without
    assert with_test["near_phantom"] == 0 and with_test["far"] == 0, with_test
