"""Low surfaces whose top no line saw (atris_node.pipeline.tops) and what they do to the
sector verdicts, on synthetic columns with known geometry.

The geometry of every case: the projector 0.5 m above flat ground, f·b = 381 px x 0.075 m,
clearance 0.1 m. A sheet falls linearly from 0.5 m at the projector to the ground, so a
sample at distance d and height h lies f·b·h/(d·0.5) rows from its sheet's ground row.

Checked to fail without their protections (each taken out once, the tests run, put
back): with ``unseen_tops`` flagging nothing, the three tests that expect a flag fail;
with the ``reach_m`` condition taken out of ``verdicts._verdict``, the 2 m case of
test_feature_unseen_top_nearer_than_the_distance_makes_it_invalid is VALID at the wall;
with RISE_PX applied to every rise (a version tried first),
test_feature_kerb_before_the_line_passing_over_is_flagged fails (a 0.7-row rise before
a wall the line above reaches: a dark kerb 0.87 m below the unit); with FOOT_PX = 0,
test_feature_stripe_at_a_wall_foot_is_not_a_kerb fails; with a missing line above
ending the walk, test_feature_a_missing_line_above_passes_the_question_up fails.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from atris_node.pipeline.obstacles import SectorSettings
from atris_node.pipeline.sectors import SectorLayout
from atris_node.pipeline.tops import (
    Tops,
    below_ground,
    corroborated,
    foot_reach_m,
    rows_off_ground,
    unseen_tops,
)
from atris_node.pipeline.verdicts import (
    ColumnEvidence,
    ObstaclePoints,
    sector_verdicts,
    top_reach_m,
)
from atris_node.types import SectorState

FB = 381.0 * 0.075
H0 = 0.5
CLEARANCE = 0.1
WIDTH = 40


def _sheet_height(distance: float, ground: float) -> float:
    """Height of a sheet that meets the ground at ``ground`` m, at ``distance`` m."""
    return H0 * (1.0 - distance / ground)


def _column(samples: list[tuple[int, float, float, bool]], columns: int = 10):
    """Samples (line, distance, height, obstacle), repeated over ``columns`` columns."""
    rows = [(k, c, d, h, o) for c in range(columns) for k, d, h, o in samples]
    line, column, d, h, o = (np.array(v) for v in zip(*rows, strict=True))
    return (line.astype(np.int64), column.astype(np.int64), d.astype(float),
            h.astype(float), o.astype(bool))


def _both(samples, columns: int = 10, sigma_m: float = 0.005) -> Tops:
    line, column, d, h, o = _column(samples, columns)
    n = line.size
    return unseen_tops(line, column, d, h, np.full(n, sigma_m), o, np.ones(n, bool),
                       lines=8, width=WIDTH, clearance_m=CLEARANCE, projector_height_m=H0,
                       height_sigma=np.full(n, 0.002),
                       rows_off=rows_off_ground(d, h, H0, FB), focal_baseline_px_m=FB)


def _tops(samples, columns: int = 10, sigma_m: float = 0.005) -> np.ndarray:
    """The samples whose top is unknown (:attr:`Tops.unseen`)."""
    return _both(samples, columns, sigma_m).unseen


def test_feature_kerb_with_no_line_above_is_flagged() -> None:
    """ramp_and_kerb's case: the lowest line meets a kerb face 9 cm up at 1.93 m (2.8
    rows off its ground row) and no line above is seen there."""
    assert rows_off_ground(np.array([1.93]), np.array([0.09]), H0, FB)[0] > 2.5
    flags = _tops([(7, 1.93, 0.09, False)])
    assert flags.all()


def test_feature_kerb_before_the_line_passing_over_is_flagged() -> None:
    """A kerb face hit 7 cm up at 3.5 m (0.7 rows: a small rise) and the line above
    landing on a wall at 4.4 m: that line passed over the kerb 14 cm up, above the
    clearance, so the kerb's top is unknown."""
    above = 0.3  # the wall hit of the line above
    passed = H0 + (3.5 / 4.4) * (above - H0)
    assert passed > CLEARANCE and rows_off_ground(np.array([3.5]), np.array([0.07]), H0,
                                                  FB)[0] < 1.5
    flags = _tops([(6, 3.5, 0.07, False), (5, 4.4, above, True)])
    assert flags[::2].all() and not flags[1::2].any()


def test_feature_a_missing_line_above_passes_the_question_up() -> None:
    """dark_kerb_turned's case: the kerb face 7 cm up at 3.0 m (1.3 rows here, under
    RISE_PX), the line above not seen, the one above that on the wall at 4.2 m, 20 cm
    up: it passed over the kerb 29 cm up, so the kerb's top is unknown. (Stopping at the
    missing line, as a version did, left this small rise unflagged and the wall VALID.)"""
    assert rows_off_ground(np.array([3.0]), np.array([0.07]), H0, FB)[0] < 1.5
    flags = _tops([(6, 3.0, 0.07, False), (4, 4.2, 0.20, True)])
    assert flags[::2].all()


def test_feature_line_passing_low_over_a_bump_bounds_its_top() -> None:
    """A 6 cm bump at 2.0 m, the line above landing on the ground at 2.2 m: at 2.0 m it
    was 4.5 cm up, under the clearance, so the bump is lower than the clearance."""
    assert _sheet_height(2.0, 2.2) < CLEARANCE
    assert not _tops([(6, 2.0, 0.06, False), (5, 2.2, 0.0, False)]).any()


def test_feature_line_passing_high_over_a_bump_leaves_it_unknown() -> None:
    """The same bump, the line above landing on the ground at 4 m: 25 cm up at 2 m."""
    assert _sheet_height(2.0, 4.0) > CLEARANCE
    flags = _tops([(6, 2.0, 0.06, False), (5, 4.0, 0.0, False)])
    assert flags[::2].all()


def test_feature_face_the_line_above_meets_is_seen() -> None:
    """The foot of a box (5 cm up) whose face the line above meets 30 cm up at the same
    distance: the obstacle is seen, nothing to add."""
    assert not _tops([(6, 2.5, 0.05, False), (5, 2.5, 0.30, True)]).any()


def test_feature_stripe_at_a_wall_foot_is_not_a_kerb() -> None:
    """window_sun: line 6 meets the wall at its foot; its stripe, half on the ground,
    triangulates 0.3-0.4 m short of the wall 4 cm up (0.8 rows). The line above meets
    the wall 0.4 m beyond it: more than 10 % of the range, within a pixel and a half of
    range (0.47 m at 3 m), the wall's foot."""
    seen = _both([(6, 3.0, 0.04, False), (5, 3.4, 0.15, True)])
    assert not seen.unseen.any() and not seen.at_foot.any()
    # with no line above, a 0.8-row rise is what such a stripe makes: not a kerb, but
    # it may be one's face as well: it stops a distance beyond its tolerance
    alone = _both([(6, 3.0, 0.04, False)])
    assert not alone.unseen.any() and alone.at_foot.all()


def test_feature_a_rise_at_its_ground_row_stops_a_distance_beyond_its_tolerance() -> None:
    """Random scene s09016's case: a dark box's face met 3.5 cm up by the lowest line
    that reaches it, one row off that line's ground row, no line above seen in its
    columns (the line above too dark on the box): the ground a row off, a wall's foot
    or a low surface whose top is unknown. It is not a top to stop every distance
    beyond it (a wall's foot stripe triangulates short of its wall), but a distance
    more than its phantom tolerance beyond it may be wrong by more than that: the
    sector read the box's far end, 6.19 m, for its face at 4.35 m. A rise within half
    a row of its ground row is the ground's stripe and stops nothing. Checked to fail
    with TOP_ROWS_PX = 1.5 (no rise at a foot); the stress scene
    dark_box_face_at_its_foot fails with the foot reach taken out of evidence."""
    rows = rows_off_ground(np.array([2.0, 6.0]), np.array([0.035, 0.035]), H0, FB)
    assert 0.5 < rows[0] <= 1.5 and rows[1] < 0.5
    rise = _both([(7, 2.0, 0.035, False)])
    assert not rise.unseen.any() and rise.at_foot.all()
    assert not _both([(7, 6.0, 0.035, False)]).at_foot.any()
    reach = foot_reach_m(np.array([2.0]))
    assert reach[0] == pytest.approx(2.2)
    for wall_m, state in [(4.0, SectorState.INVALID), (2.15, SectorState.VALID)]:
        assert _wall_verdict(wall_m, reach).state is state, wall_m


def _wall_verdict(wall_m: float, reach: np.ndarray | None):
    """The verdict of one sector holding a wall ``wall_m`` away seen by 4 lines over 15
    columns, with the unseen tops' ``reach`` (None: none)."""
    n = 60
    points = ObstaclePoints(np.full(n, wall_m), np.zeros(n, np.int64), np.ones(n, bool),
                            np.arange(n) % 4, np.arange(n) // 4, np.full(n, 0.01),
                            np.full(n, 20.0))
    layout = SectorLayout(1, math.radians(70.0))
    evidence = ColumnEvidence(np.zeros(WIDTH, np.int64), *(np.zeros(WIDTH, np.int64),) * 3)
    return sector_verdicts(points, evidence, layout, SectorSettings(), np.full(1, np.inf),
                           reach)[0]


def test_feature_ground_noise_is_not_a_rise() -> None:
    """Ground samples 1-2 cm up (under RISE_MIN_M) or under 4 height σ flag nothing."""
    assert not _tops([(7, 2.0, 0.02, False)]).any()
    line, column, d, h, o = _column([(7, 2.0, 0.05, False)])
    n = line.size
    noisy = unseen_tops(line, column, d, h, np.full(n, 0.005), o, np.ones(n, bool),
                        lines=8, width=WIDTH, clearance_m=CLEARANCE,
                        projector_height_m=H0, height_sigma=np.full(n, 0.02),
                        rows_off=rows_off_ground(d, h, H0, FB), focal_baseline_px_m=FB)
    assert not noisy.unseen.any() and not noisy.at_foot.any()


def test_feature_a_lone_stripe_near_its_ground_row_is_not_an_obstacle() -> None:
    """r3_050 of the random scenes: a stripe grazing dark ground 11.8 m away peaks 0.9
    rows off and triangulates at 8.5 m, 12 cm up: over the clearance, but 1.2 rows from
    its sheet's ground row, with no other line seen: not corroborated, so no obstacle
    point (it read 8.2 m in a sector whose truth is 13.4 m). The same sample with a
    second line meeting an obstacle clearly at 8.6 m in its column is a surface.
    (With every sample over the clearance an obstacle point, the code before, the
    sector was VALID at 8.2 m: atris bench safety on that scene, seed 1, map 2.)"""
    assert rows_off_ground(np.array([8.5]), np.array([0.12]), 0.42, 381.0 * 0.098)[0] < 1.5
    line = np.array([3, 1], np.int64)
    column = np.array([160, 160], np.int64)
    distance = np.array([8.5, 8.6])
    ask = np.array([True, False])
    alone = corroborated(line, column, distance, np.array([False, False]), ask, lines=8,
                         width=640, focal_baseline_px_m=381.0 * 0.098)
    assert not alone.any()
    seen = corroborated(line, column, distance, np.array([False, True]), ask, lines=8,
                        width=640, focal_baseline_px_m=381.0 * 0.098)
    assert seen[0]


def test_feature_a_wall_foot_stripe_is_not_vouched_for_by_the_wall() -> None:
    """A stripe at a wall's foot, half on the wall and half on the ground, peaks 1 px
    off; at 10 m with f·b = 30 px·m that is 7.6 m, 19 cm up, one row from its sheet's
    ground row (a dark-ground scene drawn at random, stress scene far_wall_foot: 7.45 m
    VALID in 14 sector-frames for a wall at 10.2 m). The line above meets the wall at
    9.4 m, within the 1.5 rows of range that reach spans at that distance, but farther:
    it shows the wall whose foot the stripe is, not a surface at 7.6 m, so it does not
    corroborate it. A line meeting an obstacle at about its distance still does.
    Checked to fail with the reach taken on both sides (the code before)."""
    fb = 381.0 * 0.079
    assert rows_off_ground(np.array([7.56]), np.array([0.19]), 0.61, fb)[0] < 1.5
    line = np.array([2, 1], np.int64)
    column = np.array([300, 300], np.int64)
    ask, clear = np.array([True, False]), np.array([False, True])
    wall = corroborated(line, column, np.array([7.56, 9.36]), clear, ask, lines=7,
                        width=640, focal_baseline_px_m=fb)
    assert not wall[0]
    box = corroborated(line, column, np.array([7.56, 7.7]), clear, ask, lines=7,
                       width=640, focal_baseline_px_m=fb)
    assert box[0]


def test_feature_a_sample_under_the_ground_is_no_evidence_of_free() -> None:
    """A sample 1.2 m under the ground plane at 4.9 m (a stripe given the wrong line, as
    in r2_049 of the random scenes) or 20 cm under it at 3 m (ground falling away) is
    flagged, and its column then cannot be NO_RETURN (counted doubtful by
    evidence.SectorJudge); ground noise 1 cm under, or 4 cm under at 8 m (within 1.5 rows
    of its ground row: a pixel of peak bias), is not. (Checked to fail with
    below_ground flagging nothing.)"""
    height = np.array([-1.2, -0.2, -0.01, -0.04])
    distance = np.array([4.9, 3.0, 2.0, 8.0])
    rows = rows_off_ground(distance, height, H0, FB)
    flags = below_ground(height, rows, np.full(4, 0.002), np.ones(4, bool))
    assert flags.tolist() == [True, True, False, False]


@pytest.mark.parametrize("top_m, state", [(None, SectorState.VALID),
                                          (2.0, SectorState.INVALID),
                                          (3.95, SectorState.VALID)])
def test_feature_unseen_top_nearer_than_the_distance_makes_it_invalid(top_m, state) -> None:
    """A wall at 4 m; a low surface with an unseen top at 2 m makes the sector INVALID,
    one at 3.95 m (within 3 % of 4 m) leaves the distance standing."""
    reach = None if top_m is None else top_reach_m(np.array([top_m]))
    assert _wall_verdict(4.0, reach).state is state


def test_feature_unseen_top_blocks_free() -> None:
    """Ground only, and one column doubtful for an unseen top: not free."""
    n = 60
    points = ObstaclePoints(np.full(n, 2.0), np.zeros(n, np.int64), np.zeros(n, bool),
                            np.arange(n) % 4, np.arange(n) // 4, np.full(n, 0.01),
                            np.full(n, 20.0))
    layout = SectorLayout(1, math.radians(70.0))
    zero = np.zeros(WIDTH, np.int64)
    free = sector_verdicts(points, ColumnEvidence(zero, zero, zero, zero), layout,
                           SectorSettings())[0]
    assert free.state is SectorState.NO_RETURN
    doubtful = zero.copy()
    doubtful[3] = 1
    blocked = sector_verdicts(points, ColumnEvidence(zero, doubtful, zero, zero), layout,
                              SectorSettings(), None, np.array([2.0]))[0]
    assert blocked.state is SectorState.INVALID


def test_feature_a_line_with_no_return_within_the_range_passed_over_the_rise() -> None:
    """low_box_within_ground_rows' case: a rise 0.9 rows off its ground row (a low box's
    face, or the ground a pixel off: one line cannot tell), and the line above with no
    return within the range (its sheet meets the ground at 12 m, beyond z_max = 8 m, and
    leaves the range 17 cm up): it passed over the rise 33 cm up, above the clearance, so
    the rise's top is unknown. Where the sheet is not known to pass (nan), nothing
    changes. Checked to fail without the protection: with the passing sheets left out
    (None, as before: such a line counted as not seen), the rise is taken for ground and
    flags nothing, and the stress scene read free before its box."""
    rise_d, rise_h, far_d = 4.0, 0.06, 8.0
    far_h = _sheet_height(far_d, 12.0)
    assert rows_off_ground(np.array([rise_d]), np.array([rise_h]), H0, FB)[0] < 1.5
    assert H0 + (rise_d / far_d) * (far_h - H0) > CLEARANCE
    line, column, d, h, o = _column([(7, rise_d, rise_h, False)])
    n = line.size
    unknown = np.full((8, WIDTH), np.nan)
    observed = np.zeros((8, WIDTH), bool)
    passing = (unknown.copy(), unknown.copy(), observed)
    passing[0][6], passing[1][6] = far_d, far_h

    def tops(passing: tuple[np.ndarray, np.ndarray, np.ndarray] | None) -> np.ndarray:
        return unseen_tops(line, column, d, h, np.full(n, 0.005), o, np.ones(n, bool),
                           lines=8, width=WIDTH, clearance_m=CLEARANCE, projector_height_m=H0,
                           height_sigma=np.full(n, 0.002),
                           rows_off=rows_off_ground(d, h, H0, FB), focal_baseline_px_m=FB,
                           passing=passing).unseen

    assert not tops(None).any()
    assert not tops((unknown, unknown, observed)).any()
    assert tops(passing).all()
    # seen beyond the range: the same
    assert tops((passing[0], passing[1], np.isfinite(passing[0]))).all()
    # a sheet leaving the range low (under the clearance at the rise) bounds it
    low = (passing[0].copy(), passing[1].copy(), observed)
    low[1][6] = -0.5
    assert H0 + (rise_d / far_d) * (-0.5 - H0) < CLEARANCE
    assert not tops(low).any()


def test_feature_a_line_lost_on_the_wall_above_a_foot_stripe_is_not_passing() -> None:
    """thin_pole_5cm's case: line 7's stripe at a wall's foot (6.04 m, 7 cm up, 0.7 rows
    off its ground row), line 6 not seen (too faint on the wall, though its sheet would
    leave the range beyond z_max), line 5 on the wall at 6.07 m: line 6 was blocked by
    the wall line 5 shows, it did not pass over; the foot is seen. Checked: with the
    lines not seen taken as passing within the walk (a version tried first), the foot
    was an unseen top and the wall's sector INVALID in 3 sector-frames on seed 1 and 6
    on seed 2 of thin_pole_5cm."""
    assert rows_off_ground(np.array([6.04]), np.array([0.07]), H0, FB)[0] < 1.5
    line, column, d, h, o = _column([(7, 6.04, 0.07, False), (5, 6.07, 0.4, True)])
    n = line.size
    passing = (np.full((8, WIDTH), np.nan), np.full((8, WIDTH), np.nan),
               np.zeros((8, WIDTH), bool))
    passing[0][6], passing[1][6] = 10.0, _sheet_height(10.0, 14.0)
    flags = unseen_tops(line, column, d, h, np.full(n, 0.005), o, np.ones(n, bool), lines=8,
                        width=WIDTH, clearance_m=CLEARANCE, projector_height_m=H0,
                        height_sigma=np.full(n, 0.002), rows_off=rows_off_ground(d, h, H0, FB),
                        focal_baseline_px_m=FB, passing=passing)
    assert not flags.unseen.any() and not flags.at_foot.any()


def test_feature_a_foot_no_row_resolves_under_a_tall_gap_keeps_the_column_from_free() -> None:
    """Random scene s18195's case: a unit 0.84 m up, f·b = 374 px x 0.057 m, one sheet
    meeting the ground 5 m ahead, the other above the horizon; a dark box 34 cm tall at
    4.7 m is met 5 cm up, 0.3 rows off the sheet's ground row (the ground's own stripe to
    the rows), and the sheet above passes over it: the sector read free. Such a column
    (hidden_feet) counts as doubtful: no free verdict. Where the next sheet passes
    within the clearance over the unresolved foot (dense sheets), or the sheet meets the
    ground beyond the range (not expected), the column is not flagged. The stress scene
    low_box_at_hidden_foot_drawn read free (1 sector-frame of 32) with hidden_feet
    returning no column; here, with the gap test taken out, the dense case fails."""
    from atris_node.pipeline.evidence import hidden_feet

    h0, fb, clearance = 0.84, 374.0 * 0.057, 0.1
    at_clearance = 5.0 * (h0 - clearance) / h0  # camera z where the sheet is 10 cm up
    assert rows_off_ground(np.array([4.7]), np.array([0.05]), h0, fb)[0] < 0.5
    two = np.array([[at_clearance], [np.inf]])
    assert hidden_feet(two, np.array([[True], [False]]), h0, fb, clearance).all()
    assert not hidden_feet(two, np.array([[False], [False]]), h0, fb, clearance).any()
    # each next sheet meets the ground 5 cm farther: under 10 cm over where the foot below
    # it is unresolved (the third meets it beyond the range: not expected)
    dense = np.array([[g * (h0 - clearance) / h0] for g in (5.0, 5.05, 5.1)])
    expected = np.array([[True], [True], [False]])
    assert not hidden_feet(dense, expected, h0, fb, clearance).any()
    assert hidden_feet(dense[:2], expected[:2], h0, fb, clearance).all()  # nothing above


def test_feature_a_foot_hidden_under_a_tall_gap_lets_no_distance_stand_beyond_it() -> None:
    """Random scene s18083's case (stress scene crate_in_the_gap_over_a_hidden_foot): a
    unit 1.05 m up, f·b = 376.75 px x 0.0464 m, one sheet meeting the ground 4.8 m ahead,
    the other above the horizon; a crate 0.95 m tall at 4.67 m is met 3 cm up, a tenth of
    a row off the ground row, and the wall behind was read VALID (7 of 16 sector-frames).
    Where the sheet above passes more than HIDDEN_GAP_M over an unresolved foot, the range
    from which the foot is unresolved is a reach no distance in the column's sector may
    pass (hidden_foot_onset, SectorJudge._foot_reach); under a gap of 0.1-0.5 m the
    column is only kept from being free (hidden_feet). Checked: with _foot_reach left
    out of SectorJudge.judge, the stress scene read the wall in 8 of its 32
    sector-frames on seed 1 (tests/test_safety_scenes.py failed)."""
    from atris_node.pipeline.evidence import (
        HIDDEN_GAP_M,
        TOP_ROWS_PX,
        hidden_feet,
        hidden_foot_onset,
    )

    h0, fb, clearance = 1.053, 376.75 * 0.0464, 0.1
    ground = 4.8
    two = np.array([[ground * (h0 - clearance) / h0], [np.inf]])
    expected = np.array([[True], [False]])
    onset = hidden_foot_onset(two, expected, h0, fb, clearance, HIDDEN_GAP_M)
    assert onset[0, 0] == pytest.approx(1.0 / (1.0 / ground + TOP_ROWS_PX / fb))
    assert onset[0, 0] < 4.67 and np.isinf(onset[1, 0])
    # a sheet above meeting the ground 1 m farther passes about 0.2 m over the lower
    # one's onset: that foot keeps the column from free but sets no reach (the upper
    # sheet's own foot, with nothing above it, does)
    pair = np.vstack([two[:1], [[(ground + 1.0) * (h0 - clearance) / h0]]])
    both = np.array([[True], [True]])
    assert hidden_feet(pair, both, h0, fb, clearance).all()
    assert np.isinf(hidden_foot_onset(pair, both, h0, fb, clearance, HIDDEN_GAP_M)[0, 0])
    assert np.isfinite(hidden_foot_onset(pair, both, h0, fb, clearance, clearance)[0, 0])
