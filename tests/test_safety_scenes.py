"""Never publish a distance the data does not support, scene by scene: every sector-frame
of every shipped scene scored against the simulator's truth (atris_node.bench.safety).

Zero near phantoms, zero false free, zero farther-than-truth distances not covered by a
neighbouring sector, and at least 95 % of VALID distances within max(3 %, 5 cm).

Scenes that do not hold this yet are listed in KNOWN_WRONG with what they still do; they
are strict expected failures, so a scene that starts passing fails here until it is taken
off the list. Checked to fail without its protections: the code of commit 974fd91 (0.1-
quantile sectors, no rival test), scored by the same bench, gave indoor_lab 75 % accurate
and window_sun 2 near phantoms in 4 maps; with the rival test but without the identity
made again without the weak peaks (rivals.robust_identity) window_sun had 4 near
phantoms (0.99 m for 1.58 m); with the single-line credibility and the nearer-points rule
of verdicts.py taken out, fleet had one (1.22 m for 2.81 m). On the 17 stress scenes
(launch/scenes/stress) the code of 974fd91 gave 29 near phantoms, 4 far and 4 false free
sector-frames in 4 maps each (dark_box_before_wall 20 phantoms, pole_16cm_far 4 far,
approach_6mps 3 false free); this code none. turned_wall_sun_sphere (a stress scene from
a randomly drawn one) had 2 near phantoms (1.38 m for the wall at 5.77 m) with the
line-wide median as the continuity reference between anchors that disagree (rivals.py of
commit 27efb17); grazing_stripe_dark_ground had one (8.2 m where
nothing stands within 10 m) with every sample over the clearance an obstacle point (the
evidence.py of commit abf41e3); dark_low_box_before_box read the box behind (4.05 m for
1.54 m) in one sector-frame with samples under the ground counted against NO_RETURN only
(commit 45697e6). On the code of commit 3e93d8f, flicker_hidden_top_sheet read free
in 8 sector-frames (a line lost in a noise tile across a flicker step counted as free),
flicker_hidden_pole read the wall 46 % beyond the pole in 2 (a run of columns where the
lines are lost in the noise counted as empty), and
beyond_zmax_stripe had 2 near phantoms (1.53 m for 3.95 m), which came back with either
the rival test's BEYOND_PX cost or the far line-median reference of rivals._reference
put back alone; sunlit_blinded_edge had one (0.30 m where nothing stands: a faint
maximum at the edge of pixels blinded in every sub-frame taken for a clipped stripe);
far_wall_foot had 13-15 on every seed (7.45 m for a wall at 10.2 m: a stripe at the
wall's foot vouched for by the wall's own line) and pole_on_sector_boundary 1-2 far on
every seed (the car behind a pole whose edge alone lies in the sector); comb_beyond_zmax
12-15 near phantoms on every seed (1.6 m for a wall at 9 m), still 6 on seed 1 with
rivals._to_infinity taken out of unique_identity. On the code of commit fc30d83
flicker_step_phantom had 32 near phantoms of 32 sector-frames on every seed (1.1 m for a
wall at 8.5 m: the edge of a flicker residual's step taken for a stripe), and so it has
with peaks.EDGE_RATIO and EDGE_SIGMAS set to 0. On the code of commit 8a5b7f4
clipped_pairs_retro_wall had 3-4 near phantoms on every seed (both clipped stripes of a
near-parallel pair centred half-way between them), and read its wall 4.7 % short with
each stripe centred alone but on the middle of its saturated run. Without
verdicts.shadowed_columns, edge_on_plate_bright_wall read the wall 48 % beyond an
unseen edge-on plate in 4 of 4 maps (3 on seed 2), and with faint.FAINT_SIGMAS set to
infinity dark_turned_wall_near_zmax read free before its wall in 1 sector-frame (2 on
seed 11); with the columns where every sheet meets the ground within z_max not counted
as doubtful (evidence.SectorJudge._evidence), wall_at_last_ground_hit read free in 3
sector-frames (7 on seed 2). With verdicts.missing_on_surface returning 0,
platform_before_wall read its wall for the platform before it in 17 sector-frames of 32
(14 on seed 2); with lines seen beyond the surface up to 3 columns beside a missing
line's run taken as passing under it, near_pole_hidden_sheet read its pole at 0.92 m as
1.9 m in 3 sector-frames on seeds 1 and 2 (its stripes taken one line off).
With the sector distance taken as the least
of the per-line fronts (its σ the standard error of a mean, no limit on it; the code
before the σ-limited front of verdicts.py), parking_pedestrian read the building at 9 m
as 8.55 m (σ 0.10) and pole_16cm_far the wall at 8.92 m as 8.64 m: 94.4 % and 94.7 %
accurate. With the continuity rounds testing again the columns where the prior prefers a
rival by the margin (rivals_kernels.unique before the outranked columns were kept out),
retro_box_shifted_onto_pole read 0.67 m for a box at 4.1 m in 1 sector-frame on seeds 1
and 3 (a pole's line medians settled the box's two stripes one line low). With the lowest
flank value instead of the median in peaks_kernels._flank_floor (the step test),
flicker_step_at_box_foot read 4.09 m VALID where no sheet reaches its box (seed 1).
With min_reflectance 0 (no check of a return's brightness against its range,
pipeline.radiometry), edge_on_glossy_plate_dark_wall read a dark wall's upper stripes at
7.6 m as 0.31 m (sector 4 VALID in map 3) and retro_pole_stray_stripe a hanging sphere's
stripe at 2.05 m as 0.71 m (sector 6 VALID in map 0; tests/test_radiometry.py runs both
ways). low_box_within_ground_rows read free before a low box (sector 1 NO_RETURN in
maps 1 and 4 of 6 on seed 1, the box at 3.73 m) with the lines seen beyond the range or
not at all (tops.unseen_tops without ``passing``) taking no part in the walk up from a
rise near its ground row. clipped_flicker_plateau read 1.31 m VALID where nothing stands
before 14 m (maps 1 and 2) with a saturated run followed 8 rows each way from a noise
maximum of a clipped plateau and its window's middle taken for a stripe's centre (no
peaks_kernels._open_run, no run length limit in line_samples). same_code_comb_on_retro_wall
read 0.56 m VALID for a wall at 6.2 and 7.1 m in sectors 2 and 4 of map 1 (a same-code
unit's two stripes completing a comb with line 0's shifted by two lines) without
pipeline.persistence (the flip check taken out of Pipeline.process).
black_box_top_across_view and black_box_top_across_view_right read 2.83 m VALID for a
black box top 0.88 m ahead (maps 0 and 3; map 2) with a ground line's run that goes on to
the image's edge taken for no hole (verdicts.hole_before's image-edge flank taken out),
and dark_box_face_at_its_foot 6.19 m for a box face at 4.35 m in every map with the rises
at a foot left out of the sectors' reach (evidence.SectorJudge taking tops.unseen only).
hanging_ball_on_sector_boundary read the wall behind a hanging ball (8.0 and 8.8 m for
4.42 m) in 6 sector-frames of 32 with only a neighbour's credible objects counted across
a sector boundary (verdicts.straddles without the points of both sides together).
sphere_nearer_than_the_range read 0.48-0.52 m VALID in sectors 0-3 of every map (16
sector-frames of 32; a sphere met 0.24-0.27 m away, nearer than the range) with the rows
above the bands not read (the chain's near guard taken out; tests/test_near.py runs both
ways). edge_on_plate_one_sheet_on_the_wall read a retro wall at 8.13-8.15 m through a
plate edge-on at 5.96 m in sector 6 of every map (4 far sector-frames) with a lone bright
line's hole counted once (verdicts_kernels.shadowed without ``alone``).
retro_wall_foot_sheet_tail and retro_wall_foot_drawn read a sheet's tail on a retro wall's
foot, a one-row maximum 1.9 px off the sheet's centre, as a stripe (near phantoms in 13-16
and 1-2 sector-frames of 48 on seeds 1-3) with the cut test taken out of
peaks_kernels.line_samples (tests/test_cut_stripes.py runs both ways).
box_top_at_camera_height_drawn read 1.50 m VALID for a box top at 1.09 m (far in 4
sector-frames of 32 on seed 1) with a stripe alone in its column settled by a line's
median row elsewhere (the _lone_stripe condition taken out of
rivals_kernels._continuity_columns).
dark_pole_crossing_drawn and black_pole_crossing_before_wall read the wall behind a black
pole crossing before it (4.79 m for 4.39-4.43 m in every map; 3.49-3.50 m for 3.17-3.19 m
in 2 maps) with a bright line's dim not dropped (tests/test_dimming.py runs both ways).
comb_lost_low_line_before_box_drawn and comb_lost_low_line_steady_lamp read 2.6 m for a
surface at 3.66 m (4 near phantoms of 32 sector-frames each on seed 1) with
rivals.MEDIAN_PX at its former 6 px and a line the column does not hold taking its
median whatever the column holds (both protections taken out; with MEDIAN_PX at 2 px
alone both scenes pass, with the left-out-line rule alone the drawn one;
tests/test_rivals.py checks each rule on its own).
pole_edge_beside_ambiguous_drawn read the wall (2.48 m) for a dark pole at 1.89 m on a
sector boundary (far in 1 sector-frame of 32 on seed 1) with the neighbour's ambiguous
peaks not counted by verdicts.straddles (tests/test_verdicts.py checks the rule alone).
low_crate_comb_read_one_line_up_drawn read 2.27-2.36 m for a low crate at 1.08-1.12 m
(far in 6 sector-frames of 32 on seed 1) with a line's ground return counted only in the
bands no noisier than evidence.CLEAN_NOISE times the tiles (evidence.SectorJudge._returned
of commit 9a59d4e: the crate's bright face raised the noise of the lowest line's band, and
its absence over the crate told nothing; tests/test_pipeline_synthetic.py checks the rule
alone); black_box_face_on_next_sheet_ground_row_drawn read a pole at 3.30 m for a black
box at 1.12 m in map 1 with that rule asking the line's median SNR over the band's noise
ratio to reach HOLE_SNR·snr_min (LOST_SNR·snr_min now: flicker left the bands 2.2-3 times
noisier than the tiles). dark_glossy_post_one_weak_sheet_drawn read the wall at 4.28 m for a
dark post at 3.76 m in every map (4 far sector-frames) with verdicts.dim_hole taken out of
verdicts._verdict (a weak line's hole beside a nearer point; tests/test_verdicts.py checks
the rule alone).
pole_cuts_ground_lines_drawn read a wall at 6.9-7.4 m for a dark pole at 2.74 m in
sectors 2 and 3 of every map with the short holes left out of verdicts.hole_before;
ramp_foot_unresolved_drawn (a known failure) reads a ramp's top edge (2.41-2.48 m) for its
risen part at 2.05-2.12 m in sectors 1-3 of every map: a sample near its ground row lets
no distance stand more than its tolerance or a row of range beyond it
(evidence.SectorJudge.judge), and a row is 0.37 m there; random scene s18145's ramp
(3.56 m read for 3.18 m, 4 of 32) is INVALID with it, and so is ramp_foot_unresolved_drawn
without the row of range (which made a wall behind a foot stripe INVALID in 6 accurate
sector-frames, outdoor_medium_sun among them); bright_pole_flicker_blind_drawn read the wall
at 6.0-7.2 m for a pale pole at 1.49 m in 4 sector-frames of 16 without
verdicts.blind_columns, which also made hanging_sphere_lone_stripe pass (its lone stripe
taken for the lowest line, 0.67 m for 1.32 m in map 1, lies in a sector with 10 or more
columns the flicker blinds; the identity itself is still a guess, docs/pipeline.md).
low_box_at_hidden_foot_drawn read free before a dark box met 0.3 rows off its sheet's
ground row (sector 4 NO_RETURN in map 2) with evidence.hidden_feet returning no column.
"""

from __future__ import annotations

import math

import pytest

from atris_node.bench.safety import score_scene
from atris_node.sim import shipped_scenes, stress_scenes
from atris_node.types import SectorState

MAPS = 4
#: INVALID fraction of each shipped scene before the never-wrong rules (commit 974fd91,
#: same maps and layout); the mean may rise by at most 5 points
INVALID_BEFORE = {"fleet": 1.0, "flicker_100hz": 0.62, "indoor_lab": 0.0, "jammer_line": 0.0,
                  "outdoor_medium_sun": 0.16, "outdoor_strong_sun": 1.0,
                  "parking_pedestrian": 0.19, "two_units_nonorthogonal": 1.0,
                  "two_units_orthogonal": 0.0, "window_sun": 0.0}

_rows: dict[str, dict] = {}


def _row(name: str) -> dict:
    if name not in _rows:
        _rows[name] = score_scene(name, MAPS).row()
    return _rows[name]


def _assert_never_wrong(row: dict) -> None:
    assert row["near_phantom"] == 0, row
    assert row["false_free"] == 0, row
    assert row["far"] == 0, row
    if row["valid"]:
        assert row["accurate_fraction"] >= 0.95, row


#: scenes the pipeline does not yet get right, and what they still do (strict expected
#: failures: a scene that starts passing fails here until it is taken off)
KNOWN_WRONG: dict[str, str] = {
    "ramp_and_kerb": "far: sector 6 reports the wall (6.2 m) over the 10 deg ramp at 3.19 m: "
                     "lines 82-88 deg, which should meet the ramp or the ground before it, "
                     "are missing over the whole sector, and only line 76 deg is seen, on "
                     "the ramp's foot. Sector 3's kerb (a face only line 76 deg meets, 9 cm "
                     "up, no line seen above) is INVALID since pipeline.tops (far on seed "
                     "11 still: 3 sector-frames of 32, was 4)",
    "crossing_box_swept_in_blank": "far: a box crossing at 5.6 m/s sweeps into 64 of a "
                                   "sector's 93 columns during a map; its partial code "
                                   "window cancels and they are blank; its far part (1.5 m) "
                                   "is read for its nearest point (1.0 m)",
    "box_top_comb_shift": "far: a bright box top 0.47 m ahead, its three stripes the only comb "
                          "in the map, taken four lines off: 1.53 m in map 3",
    "ramp_foot_unresolved_drawn": "far: a 3.1 cm baseline (a row is 0.37 m of range at 2 m); "
                                  "the lines meet a dark ramp's risen part (2.05-2.12 m) "
                                  "within 1.5 rows of their ground rows and its top edge "
                                  "clearly; the top edge (2.41-2.48 m) is read, within a row "
                                  "of range of the risen part, where a wall's foot stripe "
                                  "lies too (every map)",
    "dark_crate_below_unit_comb_read_one_line_up_drawn": "far: a black crate 0.88 m ahead "
                                                         "below the unit, the top sheet "
                                                         "over it; its three stripes read "
                                                         "one line up, 2.3 m (12 of 32)",
    "dark_crate_merged_pair_comb_read_one_line_up_drawn": "far: a dark crate taller than "
                                                          "the unit, a merged pair on its "
                                                          "face; its comb read one line "
                                                          "up, 2.09 m for 1.57 m (4 of 32)",
    "grazing_sheet_ground_stripe_read_as_low_obstacle_drawn": "near: one sheet on the "
                                                              "ground at 8 m, its stripe "
                                                              "1.6 rows off the truth's: "
                                                              "an obstacle at 7.24 m where "
                                                              "none stands (1 of 32)",
    "fast_sphere_smeared_box_behind": "far: a sphere approaching at 6.5 m/s smears over a "
                                      "64-chip map and is not found; the box behind it, "
                                      "8.1 m, is read with the sphere at 4.3-6.0 m (map 1)",
}
#: scenes whose pipeline is handed a calibration error that the tolerance cannot absorb;
#: not a pipeline fault (the unit cannot know its calibration is off), strict expected
#: failures all the same; test_feature_alpha_error_reads_long_as_geometry_predicts checks
#: that their error is the one the geometry predicts and no more (docs/benchmarks.md,
#: "Calibration errors")
CALIBRATION_LIMITED: dict[str, str] = {
    "calib_alpha_0p1deg": "a 0.1 deg error in every alpha reads long by z dA / (b sin^2 a), "
                          "2.3 %/m: 50 % accurate (1 and 1.5 m within 3 %, 2 and 3 m not)",
    "calib_alpha_per_line": "per-line alpha errors of 0.05-0.1 deg: lines disagree by up to "
                            "2.3 %/m each way; 50 % accurate",
}


def _scenes(names: list[str]) -> list:
    reasons = {**KNOWN_WRONG, **CALIBRATION_LIMITED}
    return [pytest.param(n, marks=pytest.mark.xfail(reason=reasons[n], strict=True))
            if n in reasons else n for n in names]


@pytest.mark.parametrize("name", _scenes(shipped_scenes()))
def test_feature_shipped_scene_never_wrong(name: str) -> None:
    _assert_never_wrong(_row(name))


def test_feature_invalid_fraction_rises_at_most_five_points() -> None:
    """Blanking everything is not a solution: the mean INVALID fraction over the shipped
    scenes stays within 5 points of what it was before these rules."""
    names = sorted(INVALID_BEFORE)
    now = sum(_row(n)["invalid_fraction"] for n in names) / len(names)
    before = sum(INVALID_BEFORE.values()) / len(names)
    assert now <= before + 0.05, (now, before)


@pytest.mark.parametrize("seed", [2, 11])
def test_feature_dark_panel_edge_is_not_read_as_the_wall_behind(seed: int) -> None:
    """glossy_dark_panels on two more noise seeds: the black panel at 2.5 m is lit in
    sector 2 only; its dark edge in sector 3 stands before the wall at 3.5 m. Checked to
    fail without verdicts.unseen_columns: seed 11 read the wall in sector 3 (3.49 m,
    39 % beyond the panel, not covered), seed 2 was 94.4 % accurate (3.49 m in sector 3
    too, covered by sector 2)."""
    _assert_never_wrong(score_scene("glossy_dark_panels", MAPS, seed=seed).row())


def test_feature_a_platform_edge_line_is_no_fade() -> None:
    """platform_before_wall on seed 2: a dark 42 cm platform before a wall; its lowest
    line, missing over 60 columns of sector 5 where the wall would show it, has two weak
    points (SNR 9) beside the run, which counted as the line fading into it (a glossy
    surface turning its lobe away), and the wall 2.3 m behind the platform was read
    (3.54 m for 2.34 m, map 1). A fade needs verdicts.FADE_POINTS (3) points. Checked to
    fail with FADE_POINTS 2 (far)."""
    _assert_never_wrong(score_scene("platform_before_wall", MAPS, seed=2).row())


def test_feature_a_step_that_passed_the_step_test_in_part_is_no_obstacle() -> None:
    """flicker_step_at_box_foot on seed 2: the flicker's step at the box's foot, one row
    above the middle sheet's ground row; the step test set aside its maxima in 14 of the
    sector's columns and passed them in 21 others, where they read as a 13 cm obstacle at
    4.1 m (sector 5 VALID in map 0, where no sheet reaches the box). A line's run among
    set-aside step maxima at its row is the step (peaks.off_step_runs). Checked to fail
    with STEP_SHARE 1.1 (near phantom)."""
    _assert_never_wrong(score_scene("flicker_step_at_box_foot", MAPS, seed=2).row())


@pytest.mark.parametrize("name", _scenes(stress_scenes()))
def test_feature_stress_scene_never_wrong(name: str) -> None:
    _assert_never_wrong(_row(name))


def test_feature_fan_split_separates_near_parallel_sheets() -> None:
    """``--groups 2`` (docs/pipeline.md, "Splitting the fan"): with every other line on its
    own code the two sheets at 89.9° and 90.1° no longer merge into one stripe, and the
    sectors the whole fan leaves INVALID are measured, still never wrong."""
    whole, split = score_scene("near_parallel_sheets", 2).row(), score_scene(
        "near_parallel_sheets", 2, groups=2).row()
    assert whole["invalid_fraction"] == 1.0
    assert split["invalid_fraction"] <= 0.25 and split["accurate_fraction"] >= 0.95
    assert split["near_phantom"] == split["far"] == split["false_free"] == 0


def test_feature_fan_split_publishes_conservatively() -> None:
    """A sector is INVALID when any group says so, else the nearest VALID, else NO_RETURN.

    Checked by combining with "the nearest VALID of any group" instead: the first
    assertion failed (VALID 4.0 m where group 0 was INVALID)."""
    from atris_node.bench.safety import _combined
    from atris_node.types import SectorDistance, SectorState

    def sector(state: SectorState, distance_m: float | None = None) -> SectorDistance:
        return SectorDistance(0, 0.0, state, distance_m)

    invalid, free = sector(SectorState.INVALID), sector(SectorState.NO_RETURN)
    assert _combined([(invalid,), (sector(SectorState.VALID, 4.0),)])[0] is invalid
    assert _combined([(sector(SectorState.VALID, 4.0),), (sector(SectorState.VALID, 3.0),)]
                     )[0].distance_m == 3.0
    assert _combined([(free,), (sector(SectorState.VALID, 5.0),)])[0].distance_m == 5.0
    assert _combined([(free,), (free,)])[0] is free


def test_feature_a_phantom_is_judged_against_the_real_obstacle_at_any_range() -> None:
    """The truth for the phantom check is the real obstacle wherever it stands; z_max only
    decides whether NO_RETURN is false free. Before, an obstacle just beyond z_max counted
    as none, so a good reading of it (9.54 m for 10.04 m, z_max 10 m) was a "near phantom":
    that was most of the N = 32 "phantoms" of outdoor_medium_sun in `bench accuracy`.

    Checked by cutting the truth at z_max again: the first assertion failed."""
    from atris_node.bench.safety import score_sector
    from atris_node.types import SectorDistance, SectorState

    def one(state: SectorState, distance_m: float | None = None) -> tuple[SectorDistance]:
        return (SectorDistance(0, 0.0, state, distance_m),)

    beyond = (10.04,)
    assert "near_phantom" not in score_sector(one(SectorState.VALID, 9.54), beyond, 0, 10.0)
    assert "near_phantom" in score_sector(one(SectorState.VALID, 3.0), beyond, 0, 10.0)
    assert "false_free" not in score_sector(one(SectorState.NO_RETURN), beyond, 0, 10.0)
    assert "false_free" in score_sector(one(SectorState.NO_RETURN), (9.5,), 0, 10.0)
    assert "near_phantom" in score_sector(one(SectorState.VALID, 5.0), (None,), 0, 10.0)


def test_feature_alpha_error_reads_long_as_geometry_predicts() -> None:
    """calib_alpha_0p1deg: with every α of the pipeline 0.1° large, a surface at z reads
    z / (1 − z Δα / b) (α = 90°), 2.4 % long at 1 m and 7.5 % at 3 m. Every VALID sector
    lies within 1.5 points of that and never nearer than the truth: the pipeline adds no
    error of its own to the calibration's. The baseline 1 % long reads 1 % long. Three
    maps: since a line's hole counts whole where it enters a sector
    (verdicts._unseen_whole), the 3 m box's sector is INVALID in map 0 (the gap between
    the 2 m and 3 m boxes, 13 columns without lines 0-5 after a far point's, three of
    them in the 3 m sector), and two maps held 5 VALID sectors."""
    import math

    from atris_node.bench import safety
    from atris_node.codes import walsh_chips
    from atris_node.pipeline.chain import PipelineConfig
    from atris_node.sim import Simulator, load_scene

    config = PipelineConfig(sector_count=8, fov_deg=70.0)
    for name, predicted in (("calib_alpha_0p1deg",
                             lambda z: 1.0 / (1.0 - z * math.radians(0.1) / 0.075) - 1.0),
                            ("calib_baseline_1pct", lambda z: 0.01)):
        scene = load_scene(name)
        whole = Simulator(scene, chips=walsh_chips(scene.code_length, scene.code_row))
        valid = 0
        for measurement, _, _, span in safety._measure(scene, 3, config, seed=1):
            truth = safety.sector_truth(whole, span)
            for sector, true_m in zip(measurement.sectors, truth, strict=True):
                if sector.state is not SectorState.VALID:
                    continue
                valid += 1
                true = float(true_m[0])  # type: ignore[index]  # static: (t, t)
                error = sector.distance_m / true - 1.0
                assert abs(error - predicted(true)) < 0.015, (name, sector, true)
        assert valid >= 6, name


def test_feature_a_face_foot_is_not_the_ground_returning_a_line() -> None:
    """parking_pedestrian on seed 2: line 4 (90 deg) is too faint on the dark, grazed
    ground at 3.2 m to be found there, but lands within 10 cm of the ground on the parked
    car's and the pedestrian's faces (met square on, SNR 30-54), a row or so off its
    ground row. Taken for the ground's returns, they made line 4 "returned by the ground"
    and its absence across sector 3 (the building at 9 m, nothing before it) a sign of
    something dark there: map 3 sector 3 went INVALID. Only samples within half a row of
    their sheet's ground row count (evidence.ON_GROUND_ROWS_PX): it stays VALID at 8.9 m.
    Checked to fail without the row test (INVALID)."""
    from atris_node.bench.safety import LAYOUT, _measure, scene_settings
    from atris_node.pipeline.chain import PipelineConfig
    from atris_node.sim import load_scene

    scene = load_scene("parking_pedestrian")
    config = PipelineConfig(sector_count=LAYOUT.count, fov_deg=math.degrees(LAYOUT.fov_rad),
                            **scene_settings(scene))
    sector = _measure(scene, 4, config, seed=2)[3][0].sectors[3]
    assert sector.state is SectorState.VALID and abs(sector.distance_m - 9.0) < 0.27
