"""The whole chain on synthetic scenes with exact truth: sectors, free space, ground,
closing speed, optional objects and export, configuration errors."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from pipeline_scenes import Box, Scene, as_map, oak_calibration, render

from atris_node.errors import ConfigError
from atris_node.mounting import Mounting
from atris_node.pipeline import evidence
from atris_node.pipeline import objects as objects_mod
from atris_node.pipeline.chain import Pipeline, PipelineConfig, PipelineResult
from atris_node.pipeline.geometry import range_sigma
from atris_node.types import SectorState

LEVEL = Mounting(z_m=0.5)
PITCHED = Mounting(z_m=0.8, pitch_rad=np.deg2rad(4.0))
SCENES = {
    "boxes_one_line": Scene(oak_calibration((84.5,)), LEVEL,
                            boxes=(Box(3.0, -0.5, 0.3), Box(6.0, 0.8, 2.5, 0.6))),
    "boxes_three_lines": Scene(oak_calibration((88.0, 85.0, 82.0)), LEVEL,
                               boxes=(Box(2.0, -1.0, -0.2), Box(4.5, 0.3, 1.5, 0.4))),
    "near_wall_distorted": Scene(oak_calibration((86.0, 83.0),
                                                 distortion=(-0.08, 0.02, 0.0, 0.0)),
                                 PITCHED, boxes=(Box(1.2, -0.3, 0.4, 1.0),)),
    "free_floor": Scene(oak_calibration((84.0, 81.0)), PITCHED),
}
CONFIG = PipelineConfig(peak_method="steger", stripe_sigma_px=1.2, z_min_m=0.5)


def _run(scene: Scene, config: PipelineConfig = CONFIG, seed: int = 1) -> tuple[
        PipelineResult, list[float | None]]:
    dmap, truth = render(scene, np.random.default_rng(seed))
    pipe = Pipeline(config, scene.calibration, scene.mounting, config.layout())
    result = pipe.process(dmap)
    return result, truth.sector_distance(config.layout(), config.ground_clearance_m,
                                         config.z_max_m)


def _sigma_u(result: PipelineResult) -> float:
    return float(np.sqrt(np.mean(result.samples.sigma_u_px**2) + CONFIG.sigma_u_px**2))


@pytest.mark.parametrize("name", sorted(SCENES))
def test_sector_distances_match_the_truth(name: str) -> None:
    scene = SCENES[name]
    result, truth = _run(scene)
    sigma_u = _sigma_u(result)
    cal = scene.calibration
    for sector, true_m in zip(result.measurement.sectors, truth, strict=True):
        if true_m is None:
            assert sector.state is not SectorState.VALID, f"{name}: phantom in {sector}"
            continue
        if sector.state is SectorState.VALID:
            sigma_z = float(range_sigma(true_m, sigma_u, cal.camera.focal_px,
                                        cal.laser.baseline_m))
            assert abs(sector.distance_m - true_m) <= max(0.03 * true_m, 2 * sigma_z), (
                name, sector, true_m)
    assert not result.diagnostics.interference and result.diagnostics.ambiguous == 0
    seen = sum(t is not None for t in truth)
    valid = sum(s.state is SectorState.VALID for s in result.measurement.sectors)
    assert valid >= seen - 1, f"{name}: only {valid} of {seen} obstacle sectors valid"


def test_free_floor_is_free_in_every_sector_within_the_sheets_reach(
        caplog: pytest.LogCaptureFixture) -> None:
    """Both sheets meet the floor (at 3.4 and 4.4 m of camera range): within z_max 3.0 m
    neither meets anything and both show the range free, so every sector is NO_RETURN.
    Within z_max 4.0 m the lower one meets the floor at 3.4 m, where a face it met would
    lie under half a row off its ground row and the upper sheet passes higher than the
    clearance: an obstacle in that gap would be met only at its unresolved foot
    (evidence.hidden_feet), so every sector is INVALID (it was NO_RETURN before that
    rule). With the default z_max (10 m) both meet the floor nearer: nothing beyond
    4.4 m is looked at, and "free up to 10 m" is not known, so every sector is INVALID
    (stress scene wall_at_last_ground_hit: a dark wall at the top sheet's ground hit read
    free). Checked to fail with the unprobed columns not counted doubtful in
    evidence.SectorJudge._evidence (NO_RETURN at 10 m). The pipeline says so when it is
    made."""
    result, truth = _run(SCENES["free_floor"], replace(CONFIG, z_max_m=3.0))
    assert "no sector can be reported free" not in caplog.text
    assert all(t is None for t in truth)
    assert {s.state for s in result.measurement.sectors} == {SectorState.NO_RETURN}
    assert result.measurement.nearest is None
    foot, _ = _run(SCENES["free_floor"], replace(CONFIG, z_max_m=4.0))
    assert {s.state for s in foot.measurement.sectors} == {SectorState.INVALID}
    far, _ = _run(SCENES["free_floor"])
    assert {s.state for s in far.measurement.sectors} == {SectorState.INVALID}
    assert "no sector can be reported free" in caplog.text


@pytest.mark.parametrize(("wall_m", "baseline_scale", "z_max_m", "states"), [
    (2.95, 1.03, 3.0, {SectorState.INVALID}), (3.6, 1.03, 3.0, {SectorState.NO_RETURN}),
    (None, 1.0, 4.9, {SectorState.INVALID})])
def test_feature_a_return_just_beyond_the_range_is_no_evidence_of_free(
        wall_m: float | None, baseline_scale: float, z_max_m: float,
        states: set[SectorState]) -> None:
    """The free floor (its sheets meet it at 3.4 and 4.4 m) with a wall across the view and
    the baseline handed 3 % long, so that every range reads 3 % long: a wall 5 cm inside
    z_max 3 m returns just beyond it and may stand within the range: not free (stress
    scenes wall_at_range_edge_*); a wall beyond z_max by more than the margin
    (max(10 %, 20 cm, 3 sigma)) still shows the range free. With a 2 cm clearance (the
    upper sheet crosses it at 4.87 m) the floor itself 0.11 m beyond z_max 4.9 m (within
    that margin) is ground; the range is not free there all the same, since the lower
    sheet meets the floor at 3.4 m with a foot no row resolves under the upper sheet
    (evidence.hidden_feet; it was NO_RETURN before that rule). Checked to fail with
    evidence.SectorJudge._at_the_edge returning no column (the wall at 2.95 m went out
    NO_RETURN in every sector)."""
    scene = SCENES["free_floor"]
    if wall_m is not None:
        scene = replace(scene, boxes=(Box(wall_m, -20.0, 20.0),))
    laser = scene.calibration.laser
    handed = replace(scene.calibration,
                     laser=replace(laser, baseline_m=baseline_scale * laser.baseline_m))
    config = replace(CONFIG, z_max_m=z_max_m, ground_clearance_m=0.02)
    dmap, _ = render(scene, np.random.default_rng(1))
    result = Pipeline(config, handed, scene.mounting, config.layout()).process(dmap)
    assert {s.state for s in result.measurement.sectors} == states


def _free_floor_judge():
    """The sector judge and prior of a unit over the free floor (z_max 6 m, both sheets
    meet it within the range), and (K, W) where each line is expected on the ground."""
    scene = SCENES["free_floor"]
    config = replace(CONFIG, z_max_m=6.0)
    pipe = Pipeline(config, scene.calibration, scene.mounting, config.layout())
    judge, prior = pipe._judge, pipe._prior
    return judge, prior, judge._expected_on_ground(prior)


def test_feature_a_line_counts_as_returned_by_the_ground_only_where_it_is() -> None:
    """evidence.SectorJudge._returned: on the free floor (z_max 6 m, both sheets meet it
    within the range), a line found on the ground in 30 % of the columns where it is
    expected there, at SNR 20, is returned by the ground: its ground hits (m) are handed
    to the verdicts (verdicts.lost_before). Found in 10 % of them (under
    verdicts.LOST_RETURNED, a line near its threshold that noise drops), or at SNR 8
    (under LOST_SNR·snr_min), or nowhere, it is not, and its absence tells nothing.
    Checked to fail with the fraction test and with the SNR test taken out (each
    admitted its case)."""
    judge, prior, quiet = _free_floor_judge()
    columns = np.flatnonzero(quiet[1])
    assert columns.size > 100

    def returned(fraction: float, snr: float):
        some = columns[:int(fraction * columns.size)]
        on_ground = (np.ones(some.size, np.int64), some, np.full(some.size, snr))
        return judge._returned(prior, quiet, evidence._Noise(None, None, quiet & False),
                               on_ground, evidence._ground_snr(quiet.shape, on_ground) > 0.0)

    hits = returned(0.3, 20.0)
    assert hits is not None and np.all(np.isinf(hits[0]))
    assert np.all(np.isfinite(hits[1, columns])) and np.all(hits[1, columns] > 0.5)
    assert returned(0.1, 20.0) is None and returned(0.3, 8.0) is None
    assert returned(0.0, 20.0) is None



def test_feature_a_returned_line_counts_where_its_return_outshines_the_band_noise() -> None:
    """evidence.SectorJudge._returned with the bands' noise measured: a line the ground
    returns at SNR 400 raises its own band's noise (ratio 3 to the tile noise, over
    evidence.CLEAN_NOISE, where it is found), and is still returned: the columns where it
    is found count as ones where it could be. Where it is not found, a band 5 times
    noisier than the map's tiles still shows it (400 / 5 >= verdicts.LOST_SNR·snr_min),
    so its ground hits there are handed to the verdicts (a low crate's face lit at SNR
    1000 raised the noise over the crate, the lowest line was missing there without
    counting, and the face's comb read one line up gave 2.3 m for 1.1 m:
    low_crate_comb_read_one_line_up_drawn); a band 200 times noisier, or blinded, does
    not. Checked to fail with the found columns left out of the count (no line returned)
    and with only the quiet bands showing a return (the hits inf under the noisy band)."""
    judge, prior, expected = _free_floor_judge()
    columns = np.flatnonzero(expected[1])
    found, lost = columns[:int(0.3 * columns.size)], columns[int(0.3 * columns.size):]
    on_ground = (np.ones(found.size, np.int64), found, np.full(found.size, 400.0))
    on = evidence._ground_snr(expected.shape, on_ground) > 0.0

    def hits(lost_ratio: float, blinded: bool = False):
        ratio = np.ones(expected.shape)
        ratio[1, found], ratio[1, lost] = 3.0, lost_ratio
        noisy = ratio > evidence.CLEAN_NOISE
        blind = np.zeros(expected.shape, dtype=np.bool_)
        blind[1, lost] = blinded
        return judge._returned(prior, expected, evidence._Noise(noisy | blind, ratio, blind),
                               on_ground, on)

    shown = hits(5.0)
    assert shown is not None and np.all(np.isfinite(shown[1, columns]))
    hidden = hits(200.0)
    assert hidden is not None and np.all(np.isinf(hidden[1, lost]))
    assert np.all(np.isfinite(hidden[1, found]))
    blinded = hits(5.0, blinded=True)
    assert blinded is not None and np.all(np.isinf(blinded[1, lost]))

def test_measurement_carries_the_map_sequence_and_time() -> None:
    scene = SCENES["boxes_one_line"]
    dmap, _ = render(scene, np.random.default_rng(2))
    pipe = Pipeline(CONFIG, scene.calibration, scene.mounting, CONFIG.layout())
    first, second = pipe.process(dmap), pipe.process(dmap)
    assert (first.measurement.counter, second.measurement.counter) == (0, 1)
    assert first.measurement.newest_sequence == dmap.last_sequence
    assert first.measurement.newest_time_s == dmap.last_time_s
    assert first.diagnostics.valid_fraction > 0.9
    assert first.points_vehicle_m.shape == (int(first.valid.sum()), 3)


def test_roi_bands_read_fewer_rows_for_the_same_result() -> None:
    scene = SCENES["boxes_three_lines"]
    with_roi, _ = _run(scene)
    without, _ = _run(scene, replace(CONFIG, roi_bands=False))
    assert with_roi.diagnostics.rows_read < without.diagnostics.rows_read
    # the same verdicts and distances; σ follows each sample's SNR, whose noise tiles
    # cover the rows read, so it may differ a little, and the sub-pixel fit is over the
    # tiles' background, so the distances differ by far less than a micrometre
    same = [replace(s, sigma_m=0.0, distance_m=0.0) for s in with_roi.measurement.sectors]
    assert same == [replace(s, sigma_m=0.0, distance_m=0.0)
                    for s in without.measurement.sectors]
    for a, b in zip(with_roi.measurement.sectors, without.measurement.sectors, strict=True):
        assert a.sigma_m == pytest.approx(b.sigma_m, rel=0.2)
        assert a.distance_m == pytest.approx(b.distance_m, abs=1e-6)


def test_estimated_ground_removes_a_mounting_pitch_error() -> None:
    truth_mount = Mounting(z_m=0.5, pitch_rad=np.deg2rad(3.0))
    scene = Scene(oak_calibration((87.0, 85.0)), truth_mount, boxes=(Box(2.5, -0.3, 0.3),))
    dmap, _ = render(scene, np.random.default_rng(3))
    for mode, phantoms in (("calibrated", True), ("estimate", False)):
        config = replace(CONFIG, ground_plane=mode, ground_clearance_m=0.08)
        pipe = Pipeline(config, scene.calibration, LEVEL, config.layout())  # pitch unknown
        result = pipe.process(dmap)
        valid = [s for s in result.measurement.sectors if s.state is SectorState.VALID]
        assert (len(valid) > 2) is phantoms, (mode, valid)
    assert result.diagnostics.ground.normal[2] < 0.9995


def test_closing_speed_and_time_to_collision_over_frames() -> None:
    cal = oak_calibration((84.5,))
    config = replace(CONFIG, z_max_m=8.0)
    pipe = Pipeline(config, cal, LEVEL, config.layout())
    rng = np.random.default_rng(4)
    for i in range(6):
        t = 0.1 * i
        scene = Scene(cal, LEVEL, boxes=(Box(4.0 - 1.5 * t, -0.5, 0.5),))
        dmap, _ = render(scene, rng)
        m = pipe.process(replace(dmap, first_time_s=t - 0.03, last_time_s=t)).measurement
    assert m.closing_speed_mps == pytest.approx(1.5, rel=0.1)
    assert m.time_to_collision_s == pytest.approx((4.0 - 0.75) / 1.5, rel=0.15)


def test_objects_and_export_run_only_when_enabled(tmp_path: Path,
                                                  monkeypatch: pytest.MonkeyPatch) -> None:
    calls: list[str] = []
    real_cluster, real_export = objects_mod.cluster_objects, objects_mod.export_cloud

    def cluster(*args: object, **kwargs: object) -> tuple[objects_mod.ObjectBox, ...]:
        calls.append("cluster")
        return real_cluster(*args, **kwargs)  # type: ignore[arg-type]

    def export(*args: object, **kwargs: object) -> Path:
        calls.append("export")
        return real_export(*args, **kwargs)  # type: ignore[arg-type]

    monkeypatch.setattr(objects_mod, "cluster_objects", cluster)
    monkeypatch.setattr(objects_mod, "export_cloud", export)
    scene = SCENES["boxes_one_line"]
    off, _ = _run(scene)
    assert calls == [] and off.objects is None
    on, _ = _run(scene, replace(CONFIG, objects=True, export_dir=tmp_path))
    assert calls == ["cluster", "export"]
    assert on.objects is not None and len(on.objects) >= 1
    assert on.objects[0].distance_m == pytest.approx(3.0, rel=0.05)
    assert len(list(tmp_path.glob("cloud_*.ply"))) == 1


@pytest.mark.parametrize(("field", "value"), [
    ("peak_method", "centroid"), ("z_min_m", 20.0), ("min_confidence", 1.5), ("min_points", 0),
    ("ground_plane", "magic"), ("snr_min", 0.0), ("sigma_u_px", -1.0)])
def test_bad_settings_are_config_errors_naming_the_field(field: str, value: object) -> None:
    with pytest.raises(ConfigError, match=field):
        PipelineConfig(**{field: value})


def test_a_map_of_the_wrong_size_is_refused() -> None:
    scene = SCENES["boxes_one_line"]
    pipe = Pipeline(CONFIG, scene.calibration, scene.mounting, CONFIG.layout())
    with pytest.raises(ConfigError, match="640x400"):
        pipe.process(as_map(np.zeros((800, 1280))))
