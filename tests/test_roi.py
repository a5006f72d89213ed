"""ROI narrowing (atris_node.pipeline.roi): the line search skips rows where no line was lately, and
the samples and sector distances stay exactly those of the whole-band search."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from pipeline_scenes import Box, Scene, oak_calibration, render

from atris_node import codes
from atris_node.bench.accuracy import scaled
from atris_node.demod import BlockDemodulator
from atris_node.errors import ConfigError
from atris_node.mounting import Mounting
from atris_node.pipeline.bands import Band
from atris_node.pipeline.chain import Pipeline, PipelineConfig, PipelineResult
from atris_node.pipeline.peaks import LineSamples, extract_lines
from atris_node.pipeline.roi import RoiSettings, RoiTracker
from atris_node.sim import Simulator, load_scene
from atris_node.types import DistortionMap

CONFIG = PipelineConfig(peak_method="steger", stripe_sigma_px=1.2, z_min_m=0.5)
NARROW = replace(CONFIG, roi_narrowing=True, roi_full_every=6)


def _approach(distances_m: list[float]) -> list[DistortionMap]:
    """One map per box distance: a box coming at the unit over a wall at 6 m."""
    maps = []
    for i, d in enumerate(distances_m):
        scene = Scene(oak_calibration((88.0, 85.0, 82.0)), Mounting(z_m=0.5),
                      boxes=(Box(6.0, -20.0, 20.0, 4.0), Box(d, -0.4, 0.4)))
        maps.append(render(scene, np.random.default_rng(i))[0])
    return maps


def _both(maps: list[DistortionMap], pipe_of: object) -> tuple[
        list[PipelineResult], list[PipelineResult], Pipeline]:
    full = Pipeline(CONFIG, *pipe_of)  # type: ignore[misc]
    narrow = Pipeline(NARROW, *pipe_of)  # type: ignore[misc]
    return [full.process(m) for m in maps], [narrow.process(m) for m in maps], narrow


def assert_same(a: PipelineResult, b: PipelineResult) -> None:
    assert a.measurement.sectors == b.measurement.sectors
    for name in ("line", "row_px", "col_px", "snr", "sigma_u_px", "saturated"):
        assert np.array_equal(getattr(a.samples, name), getattr(b.samples, name)), name


def _scene_parts() -> tuple[object, ...]:
    cal = oak_calibration((88.0, 85.0, 82.0))
    return cal, Mounting(z_m=0.5), CONFIG.layout()


def test_a_box_coming_closer_gives_the_same_results_as_the_whole_search() -> None:
    distances = [4.0] * 12 + [3.0, 2.2, 1.6] + [0.8] * 6  # steps, then a jump
    full, narrow, pipe = _both(_approach(distances), _scene_parts())
    for a, b in zip(full, narrow, strict=True):
        assert_same(a, b)
    assert pipe.roi is not None
    narrowed = len(distances) - pipe.roi.full_searches
    assert narrowed >= 6, "the static part was never narrowed: nothing was left out"


def test_a_line_outside_the_recent_rows_forces_the_whole_search() -> None:
    near, far = _approach([1.0, 5.0])
    pipe = Pipeline(CONFIG, *_scene_parts())  # type: ignore[arg-type]
    rows = pipe.process(far).samples.row_px
    search = [(int(rows.min()) - 4, int(rows.max()) + 5)]
    settings = CONFIG.extractor()
    same = extract_lines(far.values, far.saturated, pipe.bands, settings, search=search)
    moved = extract_lines(near.values, near.saturated, pipe.bands, settings, search=search)
    whole = extract_lines(near.values, near.saturated, pipe.bands, settings)
    assert same.narrowed and not moved.narrowed
    assert np.array_equal(moved.samples.row_px, whole.samples.row_px)
    assert whole.samples.row_px.min() < search[0][0]  # the near box is outside the rows


def test_static_simulated_scene_is_narrowed_and_unchanged() -> None:
    scene = scaled(load_scene("indoor_lab"), 320, 200)
    sim = Simulator(scene, chips=codes.walsh_chips(4, 2), seed=1)
    demod = BlockDemodulator(sim.chips, bits=sim.camera.bits)
    maps = [m for m in (demod.push(sim.render(s)) for s in range(4 * 20)) if m is not None]
    parts = (sim.calibration(), sim.mounting, PipelineConfig().layout())
    full = Pipeline(PipelineConfig(), *parts)
    narrow = Pipeline(PipelineConfig(roi_narrowing=True, roi_full_every=8), *parts)
    for m in maps:
        assert_same(full.process(m), narrow.process(m))
    assert narrow.roi is not None and narrow.roi.full_searches < len(maps) - 6


def _samples(line: list[int], row: list[float]) -> LineSamples:
    n = len(line)
    return LineSamples(np.array(line, dtype=np.int64), np.array(row), np.arange(n, dtype=float),
                       np.full(n, 20.0), np.full(n, 0.1), np.zeros(n, dtype=np.bool_))


BANDS = (Band(0, 10, 110), Band(1, 40, 140))


def test_tracker_searches_recent_rows_plus_margin_and_all_rows_when_due() -> None:
    tracker = RoiTracker(BANDS, RoiSettings(history=2, margin_px=3, full_every=4))
    seen = _samples([0, 0, 1], [50.2, 52.7, 90.0])
    searches = []
    for _ in range(8):
        searches.append(tracker.search_rows())
        tracker.update(seen, full=searches[-1] is None, foreign=False)
    assert searches[0] is None and searches[1] is None  # history not filled yet
    assert searches[2] == [(47, 57), (87, 94)]
    assert searches[4] is None  # due: every 4th map
    assert tracker.full_searches == 3


def test_tracker_searches_everything_for_a_missing_line_or_after_foreign_light() -> None:
    tracker = RoiTracker(BANDS, RoiSettings(history=1, full_every=100))
    tracker.update(_samples([0], [50.0]), full=True, foreign=False)
    assert tracker.search_rows() is None  # line 1 not seen: it may be anywhere
    tracker.update(_samples([0, 1], [50.0, 90.0]), full=True, foreign=True)
    assert tracker.search_rows() is None  # foreign peaks may be anywhere
    tracker.update(_samples([0, 1], [50.0, 90.0]), full=True, foreign=False)
    assert tracker.search_rows() is not None


@pytest.mark.parametrize(("field", "value"), [("history", 0), ("full_every", 0),
                                              ("margin_px", -1)])
def test_bad_roi_settings_name_the_field(field: str, value: int) -> None:
    with pytest.raises(ConfigError, match=field):
        RoiSettings(**{field: value})


def test_narrowing_needs_bands_and_is_off_by_default() -> None:
    parts = _scene_parts()
    assert Pipeline(CONFIG, *parts).roi is None  # type: ignore[arg-type]
    assert Pipeline(replace(NARROW, roi_bands=False), *parts).roi is None  # type: ignore[arg-type]
    with pytest.raises(ConfigError, match="roi_full_every"):
        replace(NARROW, roi_full_every=0)


def test_bench_row_reports_identical_results_and_narrowed_maps() -> None:
    from atris_node.bench.skips import roi_row

    row = roi_row(count=24)
    assert row["result_unchanged"] is True
    assert 0 < row["narrowed_maps"] < row["maps"]
    assert row["ms_full"] > 0 and row["ms_skipped"] > 0
