"""Stripes nearer than the operating range (atris_node.pipeline.near): the rows above every
band, on synthetic maps, and the stress scene whose lower sheet's stripe from a surface
nearer than z_min was read as the upper sheet farther away."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from atris_node.bench import safety
from atris_node.calibration import CameraModel, LaserCalibration
from atris_node.pipeline import chain, near
from atris_node.pipeline.bands import line_bands
from atris_node.pipeline.chain import Pipeline, PipelineConfig
from atris_node.pipeline.peaks import ExtractorSettings, read_padding
from atris_node.pipeline.radiometry import MIN_REFLECTANCE
from atris_node.sim import load_scene

CAMERA = CameraModel(160, 200, 200.0, 79.5, 99.5)
#: b 10 cm; line 0 at z_min 0.3 m on row 69 (cot α 0.1835), line 1 lower
LASER = LaserCalibration(0.1, (float(np.arctan2(1.0, 0.1835)), float(np.arctan2(1.0, 0.35))),
                         return_dn_m2=500.0, return_exposure_us=1000.0)
SETTINGS = ExtractorSettings()
BANDS = line_bands(CAMERA, LASER, 0.3, 5.0, 3.0)
CODE_LENGTH = 8
SCENE = "sphere_nearer_than_the_range"


def _map(row: float, columns: range, peak_dn: float, seed: int = 1) -> np.ndarray:
    """(H, W) int32 map: noise of σ 2 DN and a stripe of σ 1.5 px, ``peak_dn`` high, centred
    on ``row`` in ``columns``."""
    rng = np.random.default_rng(seed)
    values = rng.normal(0.0, 2.0, (CAMERA.height_px, CAMERA.width_px))
    rows = np.arange(CAMERA.height_px, dtype=np.float64)[:, None]
    stripe = peak_dn * np.exp(-0.5 * ((rows - row) / 1.5) ** 2)
    values[:, columns.start:columns.stop] += stripe
    return np.rint(values).astype(np.int32)


def _near(values: np.ndarray, min_reflectance: float = MIN_REFLECTANCE
          ) -> tuple[np.ndarray, np.ndarray]:
    return near.near_stripes(values, np.zeros(values.shape, dtype=np.bool_), BANDS, SETTINGS,
                             CAMERA, LASER, code_length=CODE_LENGTH, exposure_us=None,
                             min_reflectance=min_reflectance)


def test_the_guard_is_the_rows_above_every_band() -> None:
    """The guard ends the read padding above the topmost band; a band that reaches the
    image's top leaves no guard (nothing is read: left out)."""
    top = near.topmost(BANDS)
    assert top is not None and top.line == 0 and top.row_lo > 40
    assert near.guard_span(BANDS, SETTINGS) == (0, top.row_lo - read_padding(SETTINGS))
    reaching = line_bands(CAMERA, LASER, 0.1, 5.0, 3.0)
    assert near.guard_span(reaching, SETTINGS) is None
    assert near.near_stripes(np.full((200, 160), 10_000, np.int32),
                             np.zeros((200, 160), bool), reaching, SETTINGS, CAMERA, LASER,
                             code_length=8, exposure_us=None, min_reflectance=0.0)[0].size == 0


def test_feature_a_bright_stripe_above_every_band_is_kept() -> None:
    """A stripe on row 40 over 30 columns (line 0 at 0.21 m, ρ cos i about 0.02): every
    column of it is kept, on its row."""
    row, col = _near(_map(40.0, range(60, 90), 1000.0))
    assert sorted(set(col.tolist())) == list(range(60, 90))
    assert set(row.tolist()) == {40}


def test_a_short_run_dim_stripe_or_noise_is_no_near_surface() -> None:
    """Fewer than NEAR_RUN columns (a lamp's residue), a stripe too dark for the range
    line 0 gives it (ρ cos i about 7·10⁻⁴, SNR 15: kept when brightness is not looked at),
    and noise alone: nothing."""
    assert _near(_map(40.0, range(60, 60 + near.NEAR_RUN - 1), 1000.0))[0].size == 0
    dim = _map(40.0, range(60, 90), 30.0)
    assert _near(dim)[0].size == 0
    assert _near(dim, min_reflectance=0.0)[0].size == 30
    for seed in range(5):
        assert _near(_map(40.0, range(0), 0.0, seed=seed))[0].size == 0


@pytest.mark.parametrize("pedestal", [-2000, 2000])
def test_feature_a_near_stripe_is_as_bright_as_it_stands_over_a_pedestal(
        pedestal: int) -> None:
    """The bright and the dim stripe above on a pedestal of either sign (light the code
    does not cancel, tests/test_pedestal.py): the bright one is kept in every column,
    the dim one nowhere; brightness is over the guard's local background. Checked by
    removal: read over 0, the bright stripe on -2000 DN was dropped (a near surface
    missed) and the dim one on +2000 DN kept in all 30 columns."""
    _, col = _near(_map(40.0, range(60, 90), 1000.0) + pedestal)
    assert sorted(set(col.tolist())) == list(range(60, 90))
    assert _near(_map(40.0, range(60, 90), 30.0) + pedestal)[0].size == 0


def test_a_blinded_or_huge_guard_gives_no_stripe_and_no_nan() -> None:
    """Extremes: a guard at full scale in every pixel (a sky that saturates every
    sub-frame) has no maximum; a stripe at the int32 map's largest value over 30 columns
    is kept with finite rows and columns (the brightness check takes its clipped value)."""
    flat = np.full((200, 160), 2**31 - 1, np.int32)
    sat = np.ones(flat.shape, dtype=np.bool_)
    assert near.near_stripes(flat, sat, BANDS, SETTINGS, CAMERA, LASER, code_length=8,
                             exposure_us=None, min_reflectance=MIN_REFLECTANCE)[0].size == 0
    huge = _map(40.0, range(60, 90), 0.0)
    huge[40, 60:90] = 2**31 - 1
    row, col = _near(huge)
    assert set(row.tolist()) == {40} and sorted(set(col.tolist())) == list(range(60, 90))


def test_the_flank_of_a_stripe_in_the_topmost_band_is_no_near_stripe() -> None:
    """A bright stripe on the topmost band's first row: its flank rises to the guard's
    last row, which is no maximum of the guard."""
    top = near.topmost(BANDS)
    assert top is not None
    values = _map(float(top.row_lo), range(20, 120), 20_000.0)
    assert _near(values)[0].size == 0


def _sphere_sectors(monkeypatch: pytest.MonkeyPatch | None) -> list[tuple[str, float]]:
    if monkeypatch is not None:
        monkeypatch.setattr(chain, "near_stripes", lambda *a, **k: near._NONE)
    scene = load_scene(SCENE)
    sim, maps = safety.block_maps(scene, 1)
    config = PipelineConfig(sector_count=safety.LAYOUT.count,
                            fov_deg=float(np.degrees(safety.LAYOUT.fov_rad)),
                            **safety.scene_settings(scene))
    pipe = Pipeline(config, sim.calibration(), sim.mounting, safety.LAYOUT)
    result = pipe.process(next(itertools.islice(maps, 1, None)))
    assert (result.diagnostics.near > 200) == (monkeypatch is None), result.diagnostics.near
    return [(s.state.name, s.distance_m or 0.0) for s in result.measurement.sectors[:4]]


def test_feature_a_sphere_nearer_than_the_range_is_not_read_farther(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """sphere_nearer_than_the_range (map 1): both sheets meet a dark sphere 0.24-0.27 m
    away; the lower sheet's stripe lies in the upper one's band. With the near guard the
    sectors that look at it are INVALID and the map counts the stripes; without it (the
    chain's near_stripes taken out, run here) they read 0.48-0.52 m VALID."""
    with_guard = _sphere_sectors(None)
    assert all(state == "INVALID" for state, _ in with_guard), with_guard
    without = _sphere_sectors(monkeypatch)
    assert all(state == "VALID" and 0.4 < d < 0.6 for state, d in without), without

