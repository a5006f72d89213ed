"""Sector verdicts: the nearest credible obstacle, and "free" only when earned
(atris_node.pipeline.verdicts), on synthetic points with known truth."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from atris_node.pipeline.identity import VisibilityPrior
from atris_node.pipeline.obstacles import SectorSettings
from atris_node.pipeline.sectors import SectorLayout
from atris_node.pipeline.verdicts import (
    ColumnEvidence,
    ObstaclePoints,
    nearest_credible,
    sector_verdicts,
)
from atris_node.types import SectorState

LAYOUT = SectorLayout(2, math.radians(70.0))
SETTINGS = SectorSettings(min_points=5, min_confidence=0.6, snr_min=6.0)
WIDTH = 64


def _points(ranges, lines, columns, obstacle=True, sector=0):
    n = len(ranges)
    return ObstaclePoints(np.asarray(ranges, float), np.full(n, sector, np.int64),
                          np.full(n, obstacle, bool), np.asarray(lines, np.int64),
                          np.asarray(columns, np.int64), np.full(n, 0.01), np.full(n, 20.0))


def _join(*parts):
    return ObstaclePoints(*(np.concatenate([getattr(p, f) for p in parts]) for f in (
        "range_m", "sector", "obstacle", "line", "column", "sigma_m", "snr")))


def _evidence(**counts):
    zero = np.zeros(WIDTH, np.int64)
    sector = np.where(np.arange(WIDTH) < WIDTH // 2, 0, 1).astype(np.int64)
    return ColumnEvidence(sector, counts.get("doubtful", zero), counts.get("ambiguous", zero),
                          counts.get("missing", zero))


def _wall(range_m=3.0, n=300):
    rng = np.random.default_rng(1)
    return _points(range_m + rng.uniform(0, 0.3, n), rng.integers(0, 6, n),
                   rng.integers(0, 32, n))


def test_feature_thin_pole_in_front_of_a_wall_is_the_distance() -> None:
    """Six samples of a pole (two lines, three columns) at 1.67 m in front of 300 wall
    samples at 3-3.3 m: the old 0.1-quantile reported the wall; the nearest credible
    cluster is the pole."""
    pole = _points([1.66, 1.67, 1.67, 1.68, 1.67, 1.66], [2, 2, 2, 3, 3, 3], [10, 11, 12] * 2)
    found = nearest_credible(_join(pole, _wall()), np.ones(306, bool), 5)
    assert found is not None and found.distance_m == pytest.approx(1.67, abs=0.02)
    assert found.support == 6 and found.nearer == 0


def test_feature_short_run_of_one_line_blocks_the_wall_behind() -> None:
    """Six near samples of one line over six columns (a wrong identity looks like this,
    and so does a sliver): not credible, so no distance at 0.9 m; nor is the wall behind
    them the distance: the sector is INVALID. (With the nearer count ignored in _verdict
    this test failed: VALID at the wall, 3.0 m, farther than what stands there.)"""
    run = _points([0.9] * 6, [4] * 6, [5, 6, 7, 8, 9, 10])
    found = nearest_credible(_join(run, _wall()), np.ones(306, bool), 5)
    assert found is not None and found.distance_m > 2.9 and found.nearer == 6
    out = sector_verdicts(_join(run, _wall()), _evidence(), LAYOUT, SETTINGS)
    assert out[0].state is SectorState.INVALID and out[0].distance_m == 0.0


def test_feature_long_run_of_one_line_is_credible() -> None:
    """A sliver hit by one line over 15 columns is an obstacle in its own right."""
    run = _points([0.9] * 15, [4] * 15, np.arange(15))
    out = sector_verdicts(_join(run, _wall()), _evidence(), LAYOUT, SETTINGS)
    assert out[0].state is SectorState.VALID
    assert out[0].distance_m == pytest.approx(0.9, abs=0.01)


def test_feature_noisy_far_surface_is_its_centre() -> None:
    """A wall at 9 m whose points scatter by σ = 0.5 m: the window spans the noise and
    the distance is its centre, not its nearest noise."""
    rng = np.random.default_rng(2)
    n = 40
    wall = ObstaclePoints(9.0 + rng.normal(0, 0.5, n), np.zeros(n, np.int64),
                          np.ones(n, bool), rng.integers(0, 3, n), rng.integers(0, 32, n),
                          np.full(n, 0.5), np.full(n, 20.0))
    found = nearest_credible(wall, np.ones(n, bool), 5)
    assert found is not None and abs(found.distance_m - 9.0) < 0.27
    assert 0.0 < found.sigma_m < 0.5


def test_feature_noise_outliers_make_no_phantom() -> None:
    """Four scattered near outliers (fewer than min_points in any window) move nothing."""
    noise = _points([0.5, 0.9, 1.3, 1.7], [0, 1, 2, 3], [1, 9, 17, 25])
    found = nearest_credible(_join(noise, _wall()), np.ones(304, bool), 5)
    assert found is not None and found.distance_m == pytest.approx(3.0, abs=0.08)
    out = sector_verdicts(_join(noise, _wall()), _evidence(), LAYOUT, SETTINGS)
    assert out[0].state is SectorState.VALID


def _ground(sector=0, n=60):
    cols = np.arange(n) % 32 + (0 if sector == 0 else 32)
    return _points(np.full(n, 2.0), np.arange(n) % 4, cols, obstacle=False, sector=sector)


@pytest.mark.parametrize("blocker", ["ambiguous", "doubtful", "missing"])
def test_feature_free_must_be_earned(blocker: str) -> None:
    """Ground samples alone give NO_RETURN; one ambiguous, doubtful (dropped, lone,
    saturated, foreign) or missing-where-expected sample in the sector makes it INVALID.
    (Protection removed once - the doubtful/missing counts ignored in _verdict - and this
    test failed for "doubtful" and "missing"; ambiguity ignored, it failed for
    "ambiguous".)"""
    points = _join(_ground(0), _ground(1))
    free = sector_verdicts(points, _evidence(), LAYOUT, SETTINGS)
    assert [s.state for s in free] == [SectorState.NO_RETURN] * 2
    counts = np.zeros(WIDTH, np.int64)
    counts[3] = 1  # a column of sector 0
    blocked = sector_verdicts(points, _evidence(**{blocker: counts}), LAYOUT, SETTINGS)
    assert blocked[0].state is SectorState.INVALID
    assert blocked[1].state is SectorState.NO_RETURN


def test_feature_ambiguous_sample_makes_a_valid_sector_invalid() -> None:
    """An ambiguous sample may be the nearest obstacle: no distance is published."""
    counts = np.zeros(WIDTH, np.int64)
    counts[40] = 1
    out = sector_verdicts(_join(_wall(), _points([2.0] * 20, np.arange(20) % 3,
                                                 32 + np.arange(20), sector=1)),
                          _evidence(ambiguous=counts), LAYOUT, SETTINGS)
    assert out[0].state is SectorState.VALID and out[1].state is SectorState.INVALID
    assert out[1].distance_m == 0.0


def test_feature_valid_distance_carries_sigma() -> None:
    out = sector_verdicts(_wall(), _evidence(), LAYOUT, SETTINGS)
    assert out[0].state is SectorState.VALID
    assert 0.0 < out[0].sigma_m < 0.2 and math.isfinite(out[0].sigma_m)
    assert out[1].state is SectorState.INVALID and out[1].sigma_m == 0.0


def test_feature_few_or_weak_points_lower_confidence_to_invalid() -> None:
    """Six wall points (a credible cluster, but 6 of the 15 that give full confidence)
    are not trusted with a distance; 300 are. Peaks below snr_min (which the extraction
    never lets through) would lower it too."""
    few = _wall(n=6)
    assert sector_verdicts(few, _evidence(), LAYOUT, SETTINGS)[0].state is SectorState.INVALID
    faint = _wall()
    faint = ObstaclePoints(faint.range_m, faint.sector, faint.obstacle, faint.line,
                           faint.column, faint.sigma_m, np.full(faint.snr.size, 4.0))
    assert sector_verdicts(faint, _evidence(), LAYOUT, SETTINGS)[0].state is (
        SectorState.INVALID)
    assert sector_verdicts(_wall(), _evidence(), LAYOUT, SETTINGS)[0].state is (
        SectorState.VALID)


def _noisy_wall(rng, range_of_column, sigma_m: float, n: int, lines: int = 2
                ) -> ObstaclePoints:
    """``n`` points of a surface whose true range at column c is ``range_of_column(c)``,
    scattered by ``sigma_m`` (also their stated triangulation σ)."""
    cols = rng.integers(0, 60, n)
    return ObstaclePoints(range_of_column(cols) + rng.normal(0, sigma_m, n),
                          np.zeros(n, np.int64), np.ones(n, bool), rng.integers(0, lines, n),
                          cols.astype(np.int64), np.full(n, sigma_m), np.full(n, 20.0))


def test_feature_noisy_far_wall_is_unbiased_and_its_sigma_honest() -> None:
    """A flat wall at 9 m seen by 30 points of σ = 0.5 m, 400 draws: the distance is not
    pulled near (mean error under 4 cm) and its σ is what it claims (within 2σ of the
    truth in at least 90 % of the draws). Checked to fail with the estimator it replaced
    (the least of the per-line fronts, a slope counted at 2 residual standard errors, σ
    of the mean): mean error -0.11 m, 293 of 400 within 2σ (this code: -0.016 m, 370)."""
    rng = np.random.default_rng(7)
    errors, covered = [], 0
    for _ in range(400):
        wall = _noisy_wall(rng, lambda c: np.full(c.shape, 9.0), 0.5, 30)
        found = nearest_credible(wall, np.ones(30, bool), 5)
        assert found is not None and math.isfinite(found.sigma_m) and found.sigma_m > 0
        errors.append(found.distance_m - 9.0)
        covered += abs(found.distance_m - 9.0) <= 2.0 * found.sigma_m
    assert abs(float(np.mean(errors))) < 0.04, np.mean(errors)
    assert covered >= 0.9 * 400, covered


def test_feature_slanted_wall_reads_at_its_nearest_column() -> None:
    """A wall slanting from 6.0 m (column 0) to 7.2 m (column 60), σ = 0.15 m, 60 points
    over three lines: the distance is its near end, within max(3 %, 5 cm), in at least
    19 of 20 draws. Checked to fail without following the surface along its slope
    (verdicts_kernels._follow skipped): the range window cut the wall short, the fit
    flattened, 16 of 20 within, up to 6.38 m. The estimator this replaced: 17 of 20."""
    rng = np.random.default_rng(3)
    hits = 0
    for _ in range(20):
        wall = _noisy_wall(rng, lambda c: 6.0 + 0.02 * c, 0.15, 60, lines=3)
        found = nearest_credible(wall, np.ones(60, bool), 5)
        assert found is not None
        hits += abs(found.distance_m - 6.0) <= 0.18
    assert hits >= 19, hits


def test_feature_distance_the_points_do_not_pin_down_is_invalid() -> None:
    """Twelve points of σ = 0.5 m at 9 m pin the distance down to about 0.15 m, more than
    half the 3 % it is held to (0.135 m): INVALID; allowed 5 %, the same points give
    VALID. Checked to fail with the σ limit taken out of _verdict."""
    rng = np.random.default_rng(5)
    far = _noisy_wall(rng, lambda c: np.full(c.shape, 9.0), 0.5, 12)
    strict = sector_verdicts(far, _evidence(), LAYOUT, SETTINGS)[0]
    loose = sector_verdicts(far, _evidence(), LAYOUT, SectorSettings(
        min_points=5, min_confidence=0.6, snr_min=6.0, max_sigma_rel=0.05))[0]
    assert strict.state is SectorState.INVALID and strict.distance_m == 0.0
    assert loose.state is SectorState.VALID and loose.sigma_m > 0.135


def _hole_scene(right_m: float, through_m: float | None = None, snr: float = 40.0,
                dropout: int = 0):
    """Lines 0-4 on a wall at 3.5 m in columns 0-24 (sector 0), none in columns 25-31,
    a surface at ``right_m`` in columns 32-63 (sector 1); ``through_m``: line 0 also seen
    at that range in the hole's columns. Strong lines (SNR ``snr``, 40 by default);
    ``dropout``: every line missing on the wall in every ``dropout``-th column (0: none),
    as a line near its threshold drops out."""
    wall = [(3.5, k, c) for k in range(5) for c in range(25) if not dropout or c % dropout]
    right = [(right_m, k, c) for k in range(5) for c in range(32, 64)]
    through = [] if through_m is None else [(through_m, 0, c) for c in range(25, 32)]
    rows = np.array(wall + right + through)
    n = len(rows)
    points = ObstaclePoints(rows[:, 0], np.where(rows[:, 2] < 32, 0, 1).astype(np.int64),
                            np.ones(n, bool), rows[:, 1].astype(np.int64),
                            rows[:, 2].astype(np.int64), np.full(n, 0.01), np.full(n, snr))
    seen = np.zeros((5, WIDTH), bool)
    seen[points.line, points.column] = True
    zero = np.zeros(WIDTH, np.int64)
    evidence = ColumnEvidence(_evidence().sector, zero, zero, zero, seen=seen)
    return points, evidence


def test_feature_lines_at_two_and_a_half_snr_min_make_a_hole() -> None:
    """Random scene s22017: a black crate's edge (albedo 0.019) between a person at
    2.24 m and a crate at 3.15 m; every line stops over 14 columns, flanked by the
    crate's lit part at 1.38 m. The lines' median SNR on the person was 17.9 and 16.4,
    under 3·snr_min (18): no line was strong, no hole counted, and the person was read
    for the crate (2.24 m for 1.44 m in 2 of 4 maps). A line at 2.5·snr_min or more is
    strong (verdicts.GAP_SNR: it would be seen on a surface 40 % as bright): with the
    lines at SNR 16 sector 0 is INVALID; at SNR 14, dropping out in every third column of
    the wall (no steady line: verdicts.dim_hole), the hole is no evidence and the wall's
    3.5 m stands. Checked to fail with GAP_SNR 3.0 (VALID at 3.5 m with SNR 16)."""
    points, evidence = _hole_scene(2.5, snr=16.0, dropout=3)
    assert sector_verdicts(points, evidence, LAYOUT, SETTINGS)[0].state is SectorState.INVALID
    points, evidence = _hole_scene(2.5, snr=14.0, dropout=3)
    out = sector_verdicts(points, evidence, LAYOUT, SETTINGS)[0]
    assert out.state is SectorState.VALID and out.distance_m == pytest.approx(3.5)


@pytest.mark.parametrize("snr", [8.0, 14.0])
def test_feature_a_steady_weak_line_s_hole_beside_a_nearer_surface_blocks_it(
        snr: float) -> None:
    """verdicts.dim_hole: lines at SNR 8 and 14 (1.3 and 2.3·snr_min, not strong) seen
    on the wall at 3.5 m in every one of the 25 columns beside a 7-column hole whose
    other flank is a surface at 2.5 m: noise does not drop a line that shows in every
    column for 7 columns running, so the nearer surface may go on there, too dark for
    the lines, and sector 0 is INVALID (random scene s24003: a dark glossy post 3.4 m
    away before a wall at 3.8 m returned the only sheet, at SNR 8-10, in 3 of its 60
    columns, and the wall was read, 4.28 m for 3.76 m, in every map). Dropping out in
    every third column of the wall, the same lines make no such hole, and the wall's
    3.5 m stands. Checked to fail with dim_hole taken out of verdicts._verdict (VALID at
    3.5 m at both SNRs)."""
    points, evidence = _hole_scene(2.5, snr=snr)
    assert sector_verdicts(points, evidence, LAYOUT, SETTINGS)[0].state is SectorState.INVALID
    points, evidence = _hole_scene(2.5, snr=snr, dropout=3)
    out = sector_verdicts(points, evidence, LAYOUT, SETTINGS)[0]
    assert out.state is SectorState.VALID and out.distance_m == pytest.approx(3.5)


def test_feature_nearer_surface_going_dark_blocks_the_wall_behind() -> None:
    """glossy_dark_panels: a black panel at 2.5 m returns the lines in the next sector
    and none at its edge, which stands in front of a wall at 3.5 m. The lines stop over
    seven columns of sector 0 between the wall and the panel: the panel may go on there,
    so sector 0 is INVALID, not the wall's 3.5 m; sector 1 is the panel. Checked to fail
    with unseen_columns taken out of _verdict (sector 0 VALID at 3.5 m, as seeds 2 and 11
    of the scene read: a far sector-frame 39 % beyond the panel)."""
    points, evidence = _hole_scene(2.5)
    out = sector_verdicts(points, evidence, LAYOUT, SETTINGS)
    assert out[0].state is SectorState.INVALID
    assert out[1].state is SectorState.VALID and out[1].distance_m == pytest.approx(2.5)


@pytest.mark.parametrize("right_m, through_m", [(6.0, None), (2.5, 9.0)])
def test_feature_line_ending_at_a_farther_surface_or_seen_through_is_no_hole(
        right_m: float, through_m: float | None) -> None:
    """The same lines stopping between the wall and a farther surface (a wall's edge),
    or with a line seen at 9 m in the stopped columns (open at its height): sector 0
    reads the wall."""
    points, evidence = _hole_scene(right_m, through_m)
    out = sector_verdicts(points, evidence, LAYOUT, SETTINGS)
    assert out[0].state is SectorState.VALID and out[0].distance_m == pytest.approx(3.5)


def test_feature_bright_lines_stopping_together_mid_surface_block_it() -> None:
    """Five lines seen with SNR 80 (over 10 snr_min) on both sides stop together over
    seven columns of one wall at 3.5 m: something stands in all their rays there (a
    plate seen edge-on, a thin dark pole), at any range before the wall, so sector 0 is
    INVALID (stress scene edge_on_plate_bright_wall: the wall read 48 % beyond the plate
    in 4 of 4 maps). Lines of SNR 40 stopping so (a sparse return, glossy_dark_panels)
    and bright lines stopping at a depth edge (the wall's end before a farther surface)
    leave the wall's distance. Checked to fail with shadowed_columns taken out of
    _verdict (sector 0 VALID at 3.5 m)."""
    points, evidence = _hole_scene(3.5, snr=80.0)
    assert sector_verdicts(points, evidence, LAYOUT, SETTINGS)[0].state is SectorState.INVALID
    points, evidence = _hole_scene(3.5, snr=40.0)
    assert sector_verdicts(points, evidence, LAYOUT, SETTINGS)[0].state is SectorState.VALID
    points, evidence = _hole_scene(6.0, snr=80.0)
    out = sector_verdicts(points, evidence, LAYOUT, SETTINGS)[0]
    assert out.state is SectorState.VALID and out.distance_m == pytest.approx(3.5)


def _one_line_on_a_wall(others_on_wall: bool):
    """Sector 0 (columns 0-31): line 0 on a wall at 8 m (SNR 80) in every column but 12-16
    (its hole, nothing in them); lines 1-2 on the ground at 2.5 m (weak, no obstacle
    points), or, with ``others_on_wall``, on the wall too (SNR 20) in every column."""
    cols = [c for c in range(32) if not 12 <= c <= 16]
    wall = _points(np.full(len(cols), 8.0), np.zeros(len(cols)), cols)
    wall = ObstaclePoints(wall.range_m, wall.sector, wall.obstacle, wall.line, wall.column,
                          wall.sigma_m, np.full(len(cols), 80.0))
    ground = _points(np.full(64, 2.5), np.arange(64) % 2 + 1, np.arange(64) % 32,
                     obstacle=False)
    parts = [wall, ground]
    if others_on_wall:
        on = _points(np.full(64, 8.0), np.arange(64) % 2 + 1, np.arange(64) % 32)
        parts.append(ObstaclePoints(on.range_m, on.sector, on.obstacle, on.line, on.column,
                                    on.sigma_m, np.full(64, 20.0)))
    points = _join(*parts)
    seen = np.zeros((3, WIDTH), bool)
    seen[points.line, points.column] = True
    zero = np.zeros(WIDTH, np.int64)
    return points, ColumnEvidence(_evidence().sector, zero, zero, zero, seen=seen)


def test_feature_the_only_bright_line_on_a_surface_stopping_blocks_it() -> None:
    """A two-sheet unit: the top line alone meets a wall at 8 m (the other on the ground)
    and stops over five columns of it with SNR 80 on both sides: something edge-on stands
    in its rays there (s12155 of a random batch: a pale plate 6 m ahead seen edge-on,
    the wall at 8.15 m read in 4 maps), so sector 0 is INVALID. With the other lines on
    the wall too and not stopping there, the hole is one line's dropout: the wall stands.
    Checked to fail with a lone line's hole counted once (verdicts_kernels.shadowed
    without ``alone``: sector 0 VALID at 8 m)."""
    points, evidence = _one_line_on_a_wall(others_on_wall=False)
    assert sector_verdicts(points, evidence, LAYOUT, SETTINGS)[0].state is SectorState.INVALID
    points, evidence = _one_line_on_a_wall(others_on_wall=True)
    out = sector_verdicts(points, evidence, LAYOUT, SETTINGS)[0]
    assert out.state is SectorState.VALID and out.distance_m == pytest.approx(8.0)


def test_feature_a_line_lost_in_noise_is_no_evidence_of_free() -> None:
    """Line 0 meets nothing within z_max (it is not expected on the ground) and is not
    seen: that says nothing stands in its way only where its band is quiet enough to
    show it. With its band too noisy over sector 0's columns (flicker left in the map
    across a step, flicker_hidden_top_sheet: a dark wall at 7-8 m read free in every
    map), sector 0 is INVALID; sector 1, quiet, stays NO_RETURN. Checked to fail with
    ``evidence.unclean`` left out of the doubtful count in sector_verdicts."""
    points = _join(_ground(0), _ground(1))
    seen = np.zeros((5, WIDTH), bool)
    seen[points.line, points.column] = True
    expected = seen.copy()
    noisy = np.zeros((5, WIDTH), bool)
    noisy[4, :32] = True  # line 4 (not on the ground) in sector 0
    zero = np.zeros(WIDTH, np.int64)
    quiet = ColumnEvidence(_evidence().sector, zero, zero, zero, seen=seen,
                           noisy=np.zeros_like(noisy), expected=expected)
    lost = ColumnEvidence(_evidence().sector, zero, zero, zero, seen=seen, noisy=noisy,
                          expected=expected)
    assert [s.state for s in sector_verdicts(points, quiet, LAYOUT, SETTINGS)] == [
        SectorState.NO_RETURN] * 2
    out = sector_verdicts(points, lost, LAYOUT, SETTINGS)
    assert [s.state for s in out] == [SectorState.INVALID, SectorState.NO_RETURN]


def test_feature_a_run_lost_in_noise_blocks_the_surface_behind() -> None:
    """The lines stop over seven columns between two parts of one wall at 3.5 m: no
    nearer surface ends there, so it is no hole (the wall reads 3.5 m). With the lines'
    band too noisy over those columns the run is not known to be empty (a pole before a
    wall under a threshold raised by flicker, flicker_hidden_pole: the wall read 46 %
    beyond the pole): sector 0 is INVALID. Checked to fail with ``holes.noisy`` left out
    of unseen_columns."""
    points, evidence = _hole_scene(3.5)
    assert sector_verdicts(points, evidence, LAYOUT, SETTINGS)[0].state is SectorState.VALID
    noisy = np.zeros((5, WIDTH), bool)
    noisy[:, 25:32] = True
    lost = ColumnEvidence(evidence.sector, evidence.doubtful, evidence.ambiguous,
                          evidence.missing, seen=evidence.seen, noisy=noisy,
                          expected=np.zeros((5, WIDTH), bool))
    assert sector_verdicts(points, lost, LAYOUT, SETTINGS)[0].state is SectorState.INVALID


def test_feature_a_pole_on_a_sector_boundary_stands_in_both_sectors() -> None:
    """A thin pole at 1.15 m straddles the boundary: its edge leaves two points in
    sector 0, too few to be credible there, the rest in sector 1 (two lines, columns
    32-37). Sector 0 must not read the car behind it at 2.5 m (a randomly drawn scene:
    2.47 m for the pole at 1.15 m, sector 1 being INVALID so nothing covered it): it
    is INVALID. Without the pole's points across the boundary sector 0 reads the car.
    Checked to fail with ``straddles`` taken out of _verdict."""
    car = _points([2.5] * 150, np.arange(150) % 3, np.arange(150) % 28)
    edge = _points([1.15, 1.16], [1, 3], [30, 31])
    pole = _points([1.14] * 12, np.arange(12) % 2, 32 + np.arange(12) % 6, sector=1)
    alone = sector_verdicts(_join(car, edge), _evidence(), LAYOUT, SETTINGS)[0]
    assert alone.state is SectorState.VALID and alone.distance_m == pytest.approx(2.5, abs=0.05)
    out = sector_verdicts(_join(car, edge, pole), _evidence(), LAYOUT, SETTINGS)[0]
    assert out.state is SectorState.INVALID


def test_feature_an_edge_beside_ambiguous_samples_stands_in_its_sector() -> None:
    """A surface at 1.15 m straddles the boundary: two points of one line in sector 0,
    too few to be credible there; on the other side its peaks could not be identified
    (six ambiguous peaks in columns 32-37, their nearest hypothesis 1.0 m): sector 0
    must not read the car behind at 2.5 m (s15003 of a random batch: 2.48 m for a
    surface at 1.89 m, its other side ambiguous, that sector INVALID). Where the
    ambiguous peaks may stand no nearer than 2 m they do not vouch for the edge, and
    sector 0 reads the car. Checked to fail with the ambiguous count taken out of
    verdicts.straddles (sector 0 VALID at 2.5 m)."""
    car = _points([2.5] * 150, np.arange(150) % 3, np.arange(150) % 28)
    edge = _points([1.15, 1.16], [1, 1], [30, 31])
    ambiguous = np.zeros(WIDTH, np.int64)
    ambiguous[32:38] = 1
    evidence = _evidence(ambiguous=ambiguous)
    out = sector_verdicts(_join(car, edge), evidence, LAYOUT, SETTINGS,
                          doubt_m=np.array([np.inf, 1.0]))[0]
    assert out.state is SectorState.INVALID
    far = sector_verdicts(_join(car, edge), evidence, LAYOUT, SETTINGS,
                          doubt_m=np.array([np.inf, 2.0]))[0]
    assert far.state is SectorState.VALID and far.distance_m == pytest.approx(2.5, abs=0.05)


def _wall_over_a_low_box(lowest_ground_m: float, lowest_columns: range,
                         other_columns: range = range(32), lowest_beyond_m: float | None = None,
                         under: int = 0, lowest_snr: float = 20.0, beyond_column: int = 16
                         ) -> tuple[ObstaclePoints, ColumnEvidence]:
    """Sector 0 (columns 0-31): lines 0-4 seen on a wall at 4 m (depth 4 m, SNR 20) in
    ``other_columns``; line 5, the lowest, in ``lowest_columns`` only (and at
    ``lowest_beyond_m`` in ``beyond_column`` when given). Lines 0-4 never meet the ground, line
    5 at ``lowest_ground_m`` (f = 400 px, b = 0.1 m: at 8 m it would meet the wall 5
    rows above its ground row, at 4.1 m 0.24 rows), its points of SNR ``lowest_snr``.
    With ``under``, that many lines below the lowest (never seen, meeting the ground at
    9 m) are added."""
    cells = [(k, c) for k in range(5) for c in other_columns]
    cells += [(5, c) for c in lowest_columns]
    ranges = [4.0] * len(cells)
    if lowest_beyond_m is not None:
        cells.append((5, beyond_column))
        ranges.append(lowest_beyond_m)
    line, column = (np.array(v, np.int64) for v in zip(*cells, strict=True))
    n = line.size
    points = ObstaclePoints(np.asarray(ranges), np.zeros(n, np.int64), np.ones(n, bool),
                            line, column, np.full(n, 0.01),
                            np.where(line == 5, lowest_snr, 20.0), np.asarray(ranges))
    lines = 6 + under
    seen = np.zeros((lines, WIDTH), bool)
    seen[line, column] = True
    ground = np.full((lines, WIDTH), 9.0)
    ground[:5] = np.inf
    ground[5] = lowest_ground_m
    prior = VisibilityPrior(np.linspace(0.0, 0.05 * (lines - 1), lines), 400.0, 200.0, 400,
                            0.1, 10.0, ground)
    zero = np.zeros(WIDTH, np.int64)
    return points, ColumnEvidence(_evidence().sector, zero, zero, zero, seen=seen,
                                  prior=prior)


def test_feature_a_line_missing_from_the_surface_blocks_it() -> None:
    """A dark low box before a wall at 4 m: the five upper lines pass over it and are
    seen on the wall in all 32 columns; the lowest line would meet the wall 5 rows above
    its ground row (it meets the ground at 8 m) and is missing over 24 columns (the
    box's width): something stands in its way, lower than the line above, and sector 0
    is INVALID (a randomly drawn 27 cm platform before a wall read 3.95 m for 2.41 m in
    every map). Where the lowest line is seen all along, meets the ground before the
    wall (0.24 rows: on the grazed floor, no return is due), is seen beyond the wall in
    the run (it passes under a surface that does not reach the ground), where the
    other lines are patchy (found in half their columns: a run of noise), or where the
    lowest line fades into the run (SNR 8 beside it, under 2·snr_min: a glossy wall
    turning its lobe from that sheet), the wall's 4 m stands. Checked to fail with
    missing_on_surface taken out of _verdict (sector 0 VALID at 4 m), the fading
    line with _abrupt always True (INVALID), and two weak points with FADE_POINTS 2 (the
    rule before: VALID)."""
    box = range(4, 28)
    outside = [c for c in range(32) if c not in box]
    points, evidence = _wall_over_a_low_box(8.0, outside)
    assert sector_verdicts(points, evidence, LAYOUT, SETTINGS)[0].state is SectorState.INVALID
    for args in [(8.0, range(32)), (4.1, outside), (8.0, outside, range(32), 6.0),
                 (8.0, outside, range(0, 32, 2)), (8.0, outside, range(32), None, 0, 8.0)]:
        points, evidence = _wall_over_a_low_box(*args)
        out = sector_verdicts(points, evidence, LAYOUT, SETTINGS)[0]
        assert out.state is SectorState.VALID and out.distance_m == pytest.approx(4.0), args
    points, evidence = _wall_over_a_low_box(8.0, range(0))  # the lowest line never seen
    assert sector_verdicts(points, evidence, LAYOUT, SETTINGS)[0].state is SectorState.INVALID
    # two weak points beside a run of 30 columns are no fade (verdicts.FADE_POINTS: a
    # dark platform's edge let the wall 2.3 m behind it be read); three are
    points, evidence = _wall_over_a_low_box(8.0, range(2), range(32), None, 0, 8.0)
    assert sector_verdicts(points, evidence, LAYOUT, SETTINGS)[0].state is SectorState.INVALID
    points, evidence = _wall_over_a_low_box(8.0, range(3), range(32), None, 0, 8.0)
    assert sector_verdicts(points, evidence, LAYOUT, SETTINGS)[0].state is SectorState.VALID


def _plate_past_a_boundary(hole: range, plate: range = range(34, 46), on: int = 5
                           ) -> tuple[ObstaclePoints, ColumnEvidence]:
    """Lines 0-5 but ``on`` on a wall at 4 m in every column of sectors 0 (columns 0-31)
    and 1 (32-63); line ``on`` (5, the lowest, by default) on a plate at 1.5 m in
    ``plate`` and on the wall in the other columns but those of ``hole``, where it is
    seen nowhere. Line 5 meets the ground at 9 m (the wall would show it); SNR 20 (f =
    400 px, b = 0.1 m)."""
    cells = [(k, c, 4.0) for k in range(6) if k != on for c in range(WIDTH)]
    cells += [(on, c, 1.5 if c in plate else 4.0) for c in range(WIDTH) if c not in hole]
    line, column = (np.array(v, np.int64) for v in list(zip(*cells, strict=True))[:2])
    ranges = np.array([r for _, _, r in cells])
    n = line.size
    points = ObstaclePoints(ranges, np.where(column < 32, 0, 1).astype(np.int64),
                            np.ones(n, bool), line, column, np.full(n, 0.01),
                            np.full(n, 20.0), ranges)
    seen = np.zeros((6, WIDTH), bool)
    seen[line, column] = True
    ground = np.full((6, WIDTH), np.inf)
    ground[5] = 9.0
    prior = VisibilityPrior(np.linspace(0.0, 0.25, 6), 400.0, 200.0, 400, 0.1, 10.0, ground)
    zero = np.zeros(WIDTH, np.int64)
    return points, ColumnEvidence(_evidence().sector, zero, zero, zero, seen=seen,
                                  prior=prior)


def test_feature_a_hole_cut_by_a_sector_boundary_counts_whole() -> None:
    """Random scene s19152 (stress scene plate_edge_on_past_a_boundary): a dark plate
    seen nearly edge-on, its near part lit by the lowest line at 1.5 m in sector 1; the
    lowest line is missing over its far part, five columns, three of them in sector 0,
    while the lines above pass over the plate to the wall at 4 m. Sector 0 read the wall
    (2.56 m for 1.71 m in every map of the drawn scene): the hole's three columns in it
    were fewer than min_points, and the lines above, seen on the wall there, cleared
    them. A hole counts whole where it enters a sector, and no other line clears its
    columns (verdicts._unseen_whole): sector 0 is INVALID. A hole of four
    columns (under min_points), the lowest line seen all along, or a hole that does not
    reach sector 0 leave the wall's 4 m standing. Checked to fail with _unseen_whole
    returning 0 (sector 0 VALID at 4 m, and the stress scene far in 4 of 32
    sector-frames)."""
    points, evidence = _plate_past_a_boundary(range(29, 34))
    assert sector_verdicts(points, evidence, LAYOUT, SETTINGS)[0].state is SectorState.INVALID
    for hole in (range(30, 34), range(0), range(33, 38)):
        points, evidence = _plate_past_a_boundary(hole, range(38 if hole else 34, 46))
        out = sector_verdicts(points, evidence, LAYOUT, SETTINGS)[0]
        assert out.state is SectorState.VALID and out.distance_m == pytest.approx(4.0), hole


def test_feature_a_hole_ending_at_a_low_surface_s_foot_counts() -> None:
    """Random scene s27022 (stress scene sphere_hole_to_car_foot_drawn): a sphere
    approaching at 5.3 m/s on the ground, its stripe of one line seen at 1.7 m in one
    sector and missing over 10 columns, 3 of them in the next, where the line goes on on
    a car's foot at 2.76 m, 3 cm up (below the clearance, off its ground row). With
    obstacle points only the hole had one flank, and the line no strong points in the
    car's sector: the car was read, 2.73 m for the sphere at 1.72 m. Here line 5 is on a
    plate at 1.5 m in sector 1, missing over columns 29-33, and in sector 0 on a low
    surface's foot at 4 m, below the clearance (``low``): sector 0 is INVALID; taken for
    the ground's return (not ``low``), the hole has one flank and the wall's 4 m stands.
    Checked to fail with the low flank taken out of verdicts_kernels.line_holes, and
    again with the line's strength taken on obstacle points only (verdicts._returns
    returning ``inside`` without the low points): VALID at 4 m both times."""
    for low, state in ((True, SectorState.INVALID), (False, SectorState.VALID)):
        points, evidence = _plate_past_a_boundary(range(29, 34))
        foot = (points.line == 5) & (points.column < 29)
        points = dataclasses.replace(points, obstacle=points.obstacle & ~foot, low=foot & low)
        out = sector_verdicts(points, evidence, LAYOUT, SETTINGS)[0]
        assert out.state is state, low
        if not low:
            assert out.distance_m == pytest.approx(4.0)


def test_feature_lines_below_a_hole_seen_beyond_do_not_clear_it() -> None:
    """Random scene s22038 (stress scene hanging_ball_limb_before_car_drawn): a dark ball
    hanging 0.47-1.10 m up, 1.1 m ahead; the two upper lines on it in the next sector,
    missing over its unlit limb for 9-15 columns, the two lower lines passing under it to
    a car at 2.23 m in those columns. The lower lines' points at the distance found
    cleared the upper lines' hole (a surface standing on the ground meets the lower
    sheets first; a hanging one need not), and the sector read the car: 2.23 m for
    1.13 m in 3 of 4 maps. Here the top line (0) is on a surface at 1.5 m in sector 1
    and missing over five columns, three of them in sector 0, lines 1-5 on the wall at
    4 m everywhere: sector 0 is INVALID; with the top line seen all along, or a hole of
    four columns, the wall's 4 m stands. Checked to fail with the columns cleared again
    where a line at or below the missing one shows a point no farther than the distance
    (the unseen_whole kernel before): sector 0 VALID at 4 m."""
    points, evidence = _plate_past_a_boundary(range(29, 34), on=0)
    assert sector_verdicts(points, evidence, LAYOUT, SETTINGS)[0].state is SectorState.INVALID
    for hole in (range(0), range(30, 34)):
        points, evidence = _plate_past_a_boundary(hole, on=0)
        out = sector_verdicts(points, evidence, LAYOUT, SETTINGS)[0]
        assert out.state is SectorState.VALID and out.distance_m == pytest.approx(4.0), hole


def test_feature_lines_passing_under_a_surface_are_not_missing_from_it() -> None:
    """A surface that does not reach the ground (a sphere, a vehicle's body) at 4 m,
    lines 0-4 on it: line 5 passes under it and is seen beyond, at 6 m; line 6, lower
    still, is seen nowhere (the floor it lands on is too grazed to return it). It passes
    under too: sector 0 reads the surface's 4 m (a sphere hanging 1.2-1.8 m up, met by
    one line, lost its accurate distance in three of four maps of a randomly drawn
    scene). With line 5 not seen beyond either, nothing says the surface does not stand
    on the ground, and the absence of lines 5 and 6 makes sector 0 INVALID; so does a
    line seen beyond only beside the run, not under the surface (a pole hiding the
    wall's stripe of the sheet above the two that light it: the wall beside the pole is
    no sign that the lines pass under the pole; stress scene near_pole_hidden_sheet).
    Checked to fail with only the missing line itself taken as passing under (line 6
    counted missing: INVALID), and with lines seen beyond within 3 columns beside the
    run taken as passing under (VALID)."""
    points, evidence = _wall_over_a_low_box(8.0, range(0), range(32), 6.0, under=1)
    out = sector_verdicts(points, evidence, LAYOUT, SETTINGS)[0]
    assert out.state is SectorState.VALID and out.distance_m == pytest.approx(4.0)
    points, evidence = _wall_over_a_low_box(8.0, range(0), range(32), None, under=1)
    assert sector_verdicts(points, evidence, LAYOUT, SETTINGS)[0].state is SectorState.INVALID
    points, evidence = _wall_over_a_low_box(8.0, range(0), range(4, 28), 6.0, under=1,
                                            beyond_column=30)
    assert sector_verdicts(points, evidence, LAYOUT, SETTINGS)[0].state is SectorState.INVALID


def test_feature_a_dropout_beside_the_hole_leaves_a_bright_line_bright() -> None:
    """clipped_pairs_retro_wall: the bright lines stopping together over a dark box in
    front of the wall: four of the five miss one more column, two columns beside the hole
    (clipped stripes on a retro-reflective wall drop out now and then). They are still bright
    lines stopping on one surface: sector 0 is INVALID, as without the dropout. Checked
    to fail with every one of the GAP_RUN columns beside the hole asked to be bright
    (verdicts_kernels.line_holes before): VALID at the wall, 3.5 m (the scene read its
    wall at 7.9-8.0 m for the box at 2.94 m in one sector-frame each on seeds 1 and 2)."""
    points, evidence = _hole_scene(3.5, snr=80.0)
    keep = ~((points.column == 23) & (points.line < 4))  # lines 0-3 drop out there
    points = points.take(np.flatnonzero(keep))
    seen = np.zeros((5, WIDTH), bool)
    seen[points.line, points.column] = True
    evidence = ColumnEvidence(evidence.sector, evidence.doubtful, evidence.ambiguous,
                              evidence.missing, seen=seen)
    assert sector_verdicts(points, evidence, LAYOUT, SETTINGS)[0].state is SectorState.INVALID


def _wall_behind_a_lost_ground_line(ground_m: float, shown: range,
                                    returned: bool = True) -> tuple[ObstaclePoints,
                                                                    ColumnEvidence]:
    """Sector 0 (columns 0-31): lines 0-2 on a wall at 4 m in every column; line 3, whose
    sheet meets the ground clearance at ``ground_m`` in every column, seen (on the ground)
    in the ``shown`` columns. ``returned``: the ground returns line 3 elsewhere in the map
    (evidence.SectorJudge._returned); otherwise it is not known to."""
    cells = [(k, c) for k in range(3) for c in range(32)]
    line, column = (np.array(v, np.int64) for v in zip(*cells, strict=True))
    points = _points([4.0] * line.size, line, column)
    seen = np.zeros((4, WIDTH), bool)
    seen[line, column] = True
    seen[3, list(shown)] = True
    returned_m = np.full((4, WIDTH), np.inf)
    if returned:
        returned_m[3] = ground_m
    zero = np.zeros(WIDTH, np.int64)
    return points, ColumnEvidence(_evidence().sector, zero, zero, zero, seen=seen,
                                  returned_m=returned_m)


def test_feature_a_ground_line_lost_over_the_sector_blocks_the_surface_behind() -> None:
    """A black platform before a wall at 4 m: the upper lines pass over it to the wall;
    the lowest would meet the ground at 2 m, and the ground returns it elsewhere in the
    map, but it is seen in none of the sector's columns: something that returns no
    light stands in its way, and sector 0 is INVALID (stress scene
    black_platform_steep_lines_lost read the wall at 3.4-3.7 m for the platform at 1.9-2.1
    m). Seen on the ground along the sector, not known to be returned by the ground at
    all, meeting the ground within the margin of the wall, or lost in only a part of the
    sector (missing_on_surface's case), the wall's 4 m stands. Checked to fail with
    lost_before taken out of _verdict (sector 0 VALID at 4 m)."""
    points, evidence = _wall_behind_a_lost_ground_line(2.0, range(0))
    assert sector_verdicts(points, evidence, LAYOUT, SETTINGS)[0].state is SectorState.INVALID
    points, evidence = _wall_behind_a_lost_ground_line(2.0, range(1))  # one stray sample
    assert sector_verdicts(points, evidence, LAYOUT, SETTINGS)[0].state is SectorState.INVALID
    for args in [(2.0, range(32)), (2.0, range(0), False), (3.7, range(0)),
                 (2.0, range(8, 32))]:
        points, evidence = _wall_behind_a_lost_ground_line(*args)
        out = sector_verdicts(points, evidence, LAYOUT, SETTINGS)[0]
        assert out.state is SectorState.VALID and out.distance_m == pytest.approx(4.0), args


@pytest.mark.parametrize(("front_m", "state"), [(0.32, SectorState.INVALID),
                                                (0.34, SectorState.VALID)])
def test_feature_a_surface_at_the_near_end_of_the_range_is_not_its_distance(
        front_m: float, state: SectorState) -> None:
    """A dark car's flank slanting towards the unit from 0.45 m to ``front_m``, three
    lines over 30 columns, with the operating range starting at 0.3 m (camera z): within
    10 % of the near end, the flank may go on nearer, where no band is read (a randomly
    drawn scene read 0.32 m for the flank at 0.21 m): INVALID; 0.34 m is its distance.
    Checked to fail with at_the_near_end taken out of _verdict (VALID 0.32 m)."""
    columns = np.tile(np.arange(30), 3)
    ranges = front_m + (0.45 - front_m) * columns / 29.0
    lines = np.repeat(np.arange(3), 30)
    points = _points(ranges, lines, columns)
    points = ObstaclePoints(*(getattr(points, f) for f in (
        "range_m", "sector", "obstacle", "line", "column", "sigma_m", "snr")), ranges)
    settings = SectorSettings(min_points=5, min_confidence=0.6, snr_min=6.0, z_min_m=0.3)
    out = sector_verdicts(points, _evidence(), LAYOUT, settings)[0]
    assert out.state is state
    if state is SectorState.VALID:
        assert out.distance_m == pytest.approx(front_m, abs=0.01)


def test_feature_a_surface_one_line_shows_across_the_boundary_stands_in_both() -> None:
    """A box at 2.71 m that one line alone shows (a two-sheet unit, the other sheet on the
    ground) over 20 columns of sector 1 up to the boundary, and over 3 columns of sector
    0, too few to be credible there; a wall at 5 m behind. The box is credible in sector
    1 (one line over 20 columns), so its 3 points in sector 0 are its edge: sector 0 is
    INVALID, not the wall (a randomly drawn scene read 5.0 m for the box at 2.71 m in
    sector 0's place, 2 of 4 maps). A single line's points beside the boundary at a range
    where sector 1 has no credible cluster do not make it so (sector 0 reads the wall).
    Checked to fail with only more than one line vouching for the object (VALID 5 m)."""
    wall = _points([5.0] * 60, np.zeros(60), np.arange(30).repeat(2))
    edge = _points([2.71, 2.72, 2.71], [0, 0, 0], [29, 30, 31])
    box = _points([2.71 + 0.001 * i for i in range(20)], [0] * 20, 32 + np.arange(20),
                  sector=1)
    out = sector_verdicts(_join(wall, edge, box), _evidence(), LAYOUT, SETTINGS)[0]
    assert out.state is SectorState.INVALID
    far_box = _points([3.6 + 0.001 * i for i in range(20)], [0] * 20, 32 + np.arange(20),
                      sector=1)
    out = sector_verdicts(_join(wall, edge, far_box), _evidence(), LAYOUT, SETTINGS)[0]
    assert out.state is SectorState.VALID and out.distance_m == pytest.approx(5.0, abs=0.05)


def test_feature_few_points_on_both_sides_of_a_boundary_make_both_invalid() -> None:
    """Random scene s11090's case: a ball 0.27 m wide hanging 4.4 m ahead, met by one
    line, leaves 4 points in sector 0 and 4 in sector 1 at its boundary, a wall at 8 m
    behind in both. In one sector 8 such points nearer than the wall, not credible (one
    line over 8 columns), would make it INVALID; split 4 and 4, both sectors read the
    wall (8.0 and 8.8 m for the ball at 4.42 m, in 6 sector-frames of 32). Together
    they stand in both sectors' edges: both INVALID. Two points on each side (4 in all,
    under min_points) leave the wall standing. Checked to fail with only the
    neighbour's credible objects counted (the rule before: VALID 8 m)."""
    wall = _join(_points([8.0] * 64, np.arange(64) % 2, np.arange(64) % 32),
                 _points([8.0] * 64, np.arange(64) % 2, 32 + np.arange(64) % 32, sector=1))

    def verdicts(per_side: int):
        left = _points([4.42 + 0.01 * i for i in range(per_side)], [0] * per_side,
                       31 - np.arange(per_side))
        right = _points([4.42 + 0.01 * i for i in range(per_side)], [0] * per_side,
                        32 + np.arange(per_side), sector=1)
        return sector_verdicts(_join(wall, left, right), _evidence(), LAYOUT, SETTINGS)

    assert [v.state for v in verdicts(4)] == [SectorState.INVALID] * 2
    for out in verdicts(2):
        assert out.state is SectorState.VALID and out.distance_m == pytest.approx(8.0, abs=0.05)


def _wall_behind_a_ground_line_hole(shown: list[int], snr: float = 30.0,
                                    ground_m: float = 2.0) -> tuple[ObstaclePoints,
                                                                     ColumnEvidence]:
    """:func:`_wall_behind_a_lost_ground_line`, line 3 returned by the ground in the
    ``shown`` columns (of all 64) on its ground rows at ``snr``."""
    points, evidence = _wall_behind_a_lost_ground_line(ground_m, range(0))
    assert evidence.seen is not None
    seen = evidence.seen.copy()
    seen[3, shown] = True
    ground_snr = np.zeros((4, WIDTH))
    ground_snr[3, shown] = snr
    return points, dataclasses.replace(evidence, seen=seen, ground_snr=ground_snr)


def test_feature_a_hole_in_a_bright_ground_line_blocks_the_surface_behind() -> None:
    """A dark box before a wall at 4 m: the lowest line, which would meet the ground at
    2 m, is returned by the ground at SNR 30 on both sides of a 12-column run of sector 0
    and seen at no row in it: something that returns no light stands in its way there,
    and the sector is INVALID (a randomly drawn scene read the wall at 4.45 m for a dark
    object at 0.63 m, 4 maps of 4). The wall's 4 m stands for a run of 2 columns (under
    GAP_RUN: a dropout), flanks at SNR 12 (a weak ground line drops out near its
    threshold), a run open on one side (the fan's edge, or the ground line fading), and a
    ground hit within the wall's margin. Checked to fail with hole_before taken out of
    _verdict (VALID 4 m)."""
    hole = [c for c in range(WIDTH) if not 10 <= c < 22]
    points, evidence = _wall_behind_a_ground_line_hole(hole)
    assert sector_verdicts(points, evidence, LAYOUT, SETTINGS)[0].state is SectorState.INVALID
    for args in [([c for c in range(WIDTH) if not 10 <= c < 12],),
                 (hole, 12.0), (list(range(20)),), (hole, 30.0, 3.7)]:
        points, evidence = _wall_behind_a_ground_line_hole(*args)
        out = sector_verdicts(points, evidence, LAYOUT, SETTINGS)[0]
        assert out.state is SectorState.VALID and out.distance_m == pytest.approx(4.0), args


def test_feature_a_short_hole_between_steady_bright_ground_returns_blocks_the_surface() -> None:
    """Random scene s17142's case: a dark glossy pole 4.5 cm thick, 2.74 m ahead on a
    sector boundary, cuts the ground lines over 6-7 columns (4 on one side of the
    boundary, 2-3 on the other), a wall at 7 m read through it over the pole (the top
    sheet passes over the pole): far in both sectors, every map. A hole of GAP_RUN or
    more columns, fewer than LOST_RUN·min_points, in a line the ground returns at
    HOLE_SNR·snr_min in each of the GAP_RUN columns on both sides, makes every sector
    holding a column of it INVALID. The wall stands when one flank column is weak (a
    ground line near its threshold drops out for a few columns) and for a 2-column
    dropout. Checked to fail with the short holes left out of hole_before (VALID 4 m in
    both cases)."""
    for hole in (range(10, 16), range(30, 36)):  # inside the sector; 2 of 6 columns in it
        shown = [c for c in range(WIDTH) if c not in hole]
        points, evidence = _wall_behind_a_ground_line_hole(shown)
        out = sector_verdicts(points, evidence, LAYOUT, SETTINGS)[0]
        assert out.state is SectorState.INVALID, hole
    for shown in ([c for c in range(WIDTH) if not 10 <= c < 12],
                  [c for c in range(WIDTH) if not 8 <= c < 16 and c != 7]):
        points, evidence = _wall_behind_a_ground_line_hole(shown)
        assert evidence.ground_snr is not None
        if 7 not in shown:  # column 7 seen, but weak
            ground_snr = evidence.ground_snr.copy()
            ground_snr[3, 7] = 12.0
            seen = evidence.seen.copy() if evidence.seen is not None else None
            assert seen is not None
            seen[3, 7] = True
            evidence = dataclasses.replace(evidence, ground_snr=ground_snr, seen=seen)
        out = sector_verdicts(points, evidence, LAYOUT, SETTINGS)[0]
        assert out.state is SectorState.VALID and out.distance_m == pytest.approx(4.0), shown


def test_feature_a_ground_line_lost_to_the_image_edge_blocks_the_surface_behind() -> None:
    """Random scene s10176's case: a black box top across most of the view 0.88 m
    ahead takes the lowest line from the image's left edge to column 20, where the
    ground returns it at SNR 30 (it would meet the ground at 2 m); the lines above show
    in every column of the run (the fan reaches there): something that returns no light
    stands in the lowest line's way, and the wall at 4 m is not the nearest obstacle
    (the scene read 2.83 m for the box at 0.88 m). Where no other line shows in the run
    (the fan's edge), or the flank is weak (a ground line fading out), the wall's 4 m
    stands. Checked to fail with the image's edge taken for no flank (the rule before:
    VALID 4 m)."""
    def verdict(fan: bool, snr: float = 30.0):
        points, evidence = _wall_behind_a_ground_line_hole(list(range(20, WIDTH)), snr)
        assert evidence.seen is not None
        seen = evidence.seen.copy()
        seen[:3, :20] = fan
        return sector_verdicts(points, dataclasses.replace(evidence, seen=seen), LAYOUT,
                               SETTINGS)[0]

    assert verdict(True).state is SectorState.INVALID
    for out in (verdict(False), verdict(True, 12.0)):
        assert out.state is SectorState.VALID and out.distance_m == pytest.approx(4.0)


def test_feature_columns_where_no_line_can_be_seen_block_the_distance_beside_them() -> None:
    """Random scene s18026's case: a bright pole 1.5 m ahead under a lamp flickering at
    100 Hz; the flicker's residual on it raises the noise of every line's band over 90
    columns of two sectors and no line is found there, while the wall at 6-7 m is seen
    in the sector's other columns and was read (far, 4 sector-frames of 16). Sector 0
    (columns 0-31) holds lines 0-2 on a dim wall at 4 m (SNR 10: too weak for
    unseen_columns to ask what stops them) except in 6 blind columns (every line unseen,
    every band noisy): INVALID. The wall stands with 4 blind columns (under
    min_points), and where only two of the three bands are noisy (the third line, not
    seen with a quiet band, passed nothing: the other rules' case). Checked to fail with
    blind_columns taken out of _verdict (VALID 4 m)."""
    def verdict(blind: range, noisy_lines: int = 3):
        cells = [(k, c) for k in range(3) for c in range(32) if c not in blind]
        line, column = (np.array(v, np.int64) for v in zip(*cells, strict=True))
        seen = np.zeros((3, WIDTH), bool)
        seen[line, column] = True
        noisy = np.zeros((3, WIDTH), bool)
        noisy[:noisy_lines, list(blind)] = True
        zero = np.zeros(WIDTH, np.int64)
        evidence = ColumnEvidence(_evidence().sector, zero, zero, zero, seen=seen,
                                  noisy=noisy)
        wall = dataclasses.replace(_points([4.0] * line.size, line, column),
                                   snr=np.full(line.size, 10.0))
        return sector_verdicts(wall, evidence, LAYOUT, SETTINGS)[0]

    assert verdict(range(10, 16)).state is SectorState.INVALID
    for out in (verdict(range(10, 14)), verdict(range(10, 16), noisy_lines=2)):
        assert out.state is SectorState.VALID and out.distance_m == pytest.approx(4.0)
