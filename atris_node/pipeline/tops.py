"""Low surfaces whose top no line has seen: a kerb may be an obstacle the lines only graze.

A sample below the ground clearance is ground for the sector verdicts. But a sample that
stands clearly *above* the ground (a kerb's face hit 9 cm up, a dark step whose top the
next line misses) shows a surface rising out of the ground whose top the sample does not
give: it may go on above the clearance, out of this line's reach. Only the lines above it
can tell. Line k's light sheet and an image column meet in a straight line through the
projector (the projector lies on the camera's y axis, which every column plane holds),
so a line k' above k that lands *beyond* the sample in the same column passed over it at
the height of that straight line at the sample's distance: the surface's top there is
below that height. The lines above are walked from k − 1 upwards:

- a line that meets an obstacle point not farther than max(FOOT_REL·d, FOOT_M,
  FOOT_PX·d²/(f·b)) beyond the sample: the surface is seen (the sample is its foot,
  triangulated short by the mixed stripe at the corner), nothing to add;
- a line that lands on the same low surface (not farther than the sample by more than
  SAME_SURFACE_M or SAME_SIGMAS of its σ): it bounds nothing, the next line up is asked;
- a line that lands beyond (on the ground or on anything else): it passed over at
  height h. h at most the clearance: the
  surface is below the clearance, ground. Else its top is unknown;
- a line above seen only beyond the range in the column (within one column either
  side) passed over at its sheet's height there: it lands beyond, where its sheet
  leaves the range;
- any other line above not seen in the column tells nothing: the next line up is asked;
- no line left above: unknown when the rise is more than RISE_PX rows (below); for a
  smaller rise, unknown when a line above that is not seen near the column, and whose
  sheet meets the ground only beyond z_max (what the free verdict takes as nothing in
  its way), passed over it above the clearance. Asked only once the walk found no seen
  line: a line lost in the noise on a wall the lines above it show was stopped by the
  wall, it did not pass. (A low box under a row above the lowest sheet's ground row,
  the sheet above passing over it to the ground beyond z_max, read free before these
  two rules: low_box_within_ground_rows.) A smaller rise that none of this settles and
  that lies more than TOP_ROWS_PX rows off its ground row is *at a foot*: the foot of a
  surface, triangulated short, or a low surface whose top is unknown
  (dark_box_face_at_its_foot: a dark box's face met 3.2 cm up, one row off, the line
  above too dark on it; the box's far side was read).

A sample whose top is unknown is an *unseen top*: something may stand there as tall as
an obstacle, at the sample's range. A sector holding one is not free, and not VALID at a
distance beyond it (:mod:`atris_node.pipeline.evidence` counts it as doubtful and as a
doubt range, as an ambiguous peak is). A rise at a foot is not free either, and lets a
distance stand up to its phantom tolerance beyond it (:func:`foot_reach_m`): a wall's
foot stripe stops no distance of its wall, and a low surface is not read more than the
tolerance beyond.

A sample is clearly above the ground when its height exceeds max(RISE_MIN_M,
RISE_SIGMAS·σ_h), σ_h its height σ (its range σ times the slope of its viewing ray).
Where no line above bounds it, the rise must also lie more than RISE_PX rows from where
its sheet meets the ground (:func:`rows_off_ground`): a stripe half on the ground, half
on a wall's foot peaks up to a pixel off and triangulates short of the wall, a few
centimetres up, and a wall too dark for the line above cannot rule that out. A line
above seen landing beyond the foot does rule it out. Units: metres; arrays (n,).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]
BoolArray = npt.NDArray[np.bool_]

#: a sample this high above the ground plane (m) is a surface, not ground noise: the
#: ground fit's inlier band (obstacles.estimate_ground's threshold)
RISE_MIN_M = 0.03
#: ... and at least this many of its height σ above it
RISE_SIGMAS = 4.0
#: ... and at least this many image rows from where its sheet meets the ground (a stripe
#: half on the ground, half on a wall's foot peaks up to a pixel off: the measured
#: quantity is a row, and a pixel far away is a metre of range and centimetres of height)
RISE_PX = 1.5
#: a rise that lies RISE_PX rows or less from its ground row (see GROUND_ROW_PX) but more
#: than TOP_ROWS_PX, and whose top no line bounds, is either the foot of a surface, its
#: mixed stripe triangulated short, or a low surface whose top is unknown: it lets a
#: distance stand only up to its phantom tolerance beyond it (:func:`foot_reach_m`; a
#: dark box's face met 3.2 cm up at 4.35 m, one row off the ground row, the box's far
#: end at 6.2 m read). Nearer its ground row than this it is the ground's own stripe
TOP_ROWS_PX = 0.5
#: a sample above the clearance but within this many rows of where its sheet meets the
#: ground may be the ground seen a pixel off (a stripe grazing the ground 11 m away, its
#: peak 0.9 rows off, triangulates 3 m short and 12 cm up): it is an obstacle point only
#: where another line meets an obstacle clearly (farther from its ground row) at about
#: its distance in its column (:func:`corroborated`); else a rise whose top is asked of
#: the lines above
GROUND_ROW_PX = RISE_PX
#: a line landing at most this much (m) or SAME_SIGMAS of its range σ beyond the sample
#: is on the same surface and bounds nothing
SAME_SURFACE_M = 0.05
SAME_SIGMAS = 3.0
#: a line above that meets an obstacle at most max(FOOT_REL·d, FOOT_M) beyond the sample
#: shows the surface the sample is the foot of (a stripe at a wall's foot, half on the
#: ground, half on the wall, peaks in between and triangulates short of the wall): seen
#: (the phantom tolerance of a distance)
FOOT_REL = 0.10
FOOT_M = 0.20
#: ... or the range FOOT_PX rows of the stripe make at the sample (d²/(f·b) per row): the
#: mixed stripe's peak is off by up to a pixel, which is metres far away
FOOT_PX = 1.5


def height_sigma_m(range_sigma_m: FloatArray, height_m: FloatArray, camera_height_m: float,
                   distance_m: FloatArray) -> FloatArray:
    """(n,) height σ (m) of samples whose range σ is ``range_sigma_m``, seen from a camera
    ``camera_height_m`` above the ground at horizontal ``distance_m`` (floored at 1 cm)."""
    slope = np.abs(camera_height_m - height_m) / np.maximum(distance_m, 0.01)
    return np.asarray(range_sigma_m * slope, dtype=np.float64)


class Tops(NamedTuple):
    """The low surfaces whose top no line bounds, (n,) each: ``unseen`` rises whose top
    is unknown, and ``at_foot`` rises within RISE_PX (and more than TOP_ROWS_PX) rows of
    their ground row that may be a surface's foot as well (:func:`foot_reach_m`)."""

    unseen: BoolArray
    at_foot: BoolArray


def foot_reach_m(distance_m: FloatArray) -> FloatArray:
    """(n,) the farthest distance (m) a rise at ``distance_m`` that may be a surface's
    foot lets stand: its phantom tolerance beyond it, max(FOOT_REL·d, FOOT_M) (the foot
    of the surface reported, triangulated short; or, for a low surface whose top is
    unknown, a distance no farther than the tolerance of a distance)."""
    return np.asarray(distance_m + np.maximum(FOOT_REL * distance_m, FOOT_M),
                      dtype=np.float64)


def unseen_tops(line: IntArray, column: IntArray, distance_m: FloatArray, height_m: FloatArray,
                sigma_m: FloatArray, obstacle: BoolArray, valid: BoolArray, *, lines: int,
                width: int, clearance_m: float, projector_height_m: float,
                height_sigma: FloatArray, rows_off: FloatArray, focal_baseline_px_m: float,
                passing: tuple[FloatArray, FloatArray, BoolArray] | None = None
                ) -> Tops:
    """The valid samples that stand clearly above the ground, below ``clearance_m``,
    and whose top no line above them bounds (see the module docstring), as :class:`Tops`.

    Args:
        line, column: (n,) the sample's line (0 = top of the image) and image column.
        distance_m: (n,) horizontal distance (m) from the projector.
        height_m: (n,) height (m) above the ground plane.
        sigma_m: (n,) range σ (m); height_sigma: (n,) height σ (m).
        rows_off: (n,) rows from the sheet's ground row (:func:`rows_off_ground`).
        focal_baseline_px_m: f·b (px·m): a surface at distance d moves a stripe f·b/d²
            rows per metre of range.
        obstacle, valid: (n,) above the clearance; triangulated at all.
        projector_height_m: the projector's height (m) above the ground plane.
        passing: (K, W) distance and height (m) of each line's sheet where it leaves the
            operating range in each column, nan where the line is not known to pass over
            there, and (K, W) where it was seen beyond the range: such a line passed over
            the rise at its sheet's height, and lands there in the walk. A line not seen
            where its sheet meets the ground only beyond the range (what the free
            verdict takes as nothing in its way) is asked after the walk, for the rises
            within RISE_PX rows of their ground row that no seen line bounds. None:
            such lines tell nothing.
    """
    n = line.size
    rise = valid & ~obstacle & (height_m > _off_ground_m(height_sigma))
    strong = rows_off > RISE_PX
    out = np.zeros(n, dtype=np.bool_)
    at_foot = np.zeros(n, dtype=np.bool_)
    idx = np.flatnonzero(rise)
    if idx.size == 0:
        return Tops(out, at_foot)
    grid_d, grid_h, grid_o = _grids(line[valid], column[valid], distance_m[valid],
                                    height_m[valid], obstacle[valid], lines, width)
    k, c, sure = line[idx], column[idx], strong[idx]
    d, same = distance_m[idx], np.maximum(SAME_SURFACE_M, SAME_SIGMAS * sigma_m[idx])
    foot = np.maximum(np.maximum(FOOT_REL * d, FOOT_M), FOOT_PX * d * d / focal_baseline_px_m)
    unknown = np.zeros(idx.size, dtype=np.bool_)
    pending = np.ones(idx.size, dtype=np.bool_)
    exhausted = np.zeros(idx.size, dtype=np.bool_)
    for step in range(1, lines + 1):
        above = k - step
        ended = pending & (above < 0)
        exhausted |= ended
        pending &= ~ended
        if not pending.any():
            break
        j = np.flatnonzero(pending)
        dist, high, hit = _nearest_in_column(grid_d, grid_h, grid_o, above[j], c[j])
        if passing is not None:  # seen beyond the range: it passed over
            _passing_where_missing(dist, high, passing, passing[2], above[j], c[j])
        missing = ~np.isfinite(dist)
        hit &= ~missing & (dist <= d[j] + foot[j])
        beyond = ~missing & ~hit & (dist > d[j] + same[j])
        unknown[j[beyond & (_passed_m(d[j], dist, high, projector_height_m)
                            > clearance_m)]] = True
        pending[j[hit | beyond]] = False  # missing or on the same surface: ask the next
    unknown |= exhausted & sure
    if passing is not None:
        weak = np.flatnonzero(exhausted & ~sure)
        unknown[weak] |= _passed_unseen(k[weak], c[weak], d[weak], same[weak],
                                       (grid_d, grid_h, grid_o), passing,
                                       projector_height_m, clearance_m)
    out[idx[unknown]] = True
    at_foot[idx[exhausted & ~unknown & (rows_off[idx] > TOP_ROWS_PX)]] = True
    return Tops(out, at_foot)


def _passing_where_missing(dist: FloatArray, high: FloatArray,
                           passing: tuple[FloatArray, FloatArray, BoolArray], use: BoolArray,
                           k: IntArray, c: IntArray) -> None:
    """Where line ``k`` has no return near column ``c`` (``dist`` nan) and ``use`` (K, W)
    holds, the point where its sheet leaves the range (``passing``), in place: a landing
    point beyond, never an obstacle hit."""
    gone = ~np.isfinite(dist)
    gone[gone] = use[k[gone], c[gone]]
    if gone.any():
        dist[gone], high[gone] = passing[0][k[gone], c[gone]], passing[1][k[gone], c[gone]]


def _passed_m(d: FloatArray, landing_m: FloatArray, landing_h: FloatArray,
              projector_height_m: float) -> FloatArray:
    """(m,) the height (m) at distance ``d`` of the sheets that land at ``landing_m``,
    ``landing_h`` (straight from the projector; nan where the landing is unknown)."""
    with np.errstate(invalid="ignore"):
        return np.asarray(projector_height_m + (d / landing_m) * (
            landing_h - projector_height_m), dtype=np.float64)


def _passed_unseen(k: IntArray, c: IntArray, d: FloatArray, same: FloatArray,
                   grids: tuple[FloatArray, FloatArray, BoolArray],
                   passing: tuple[FloatArray, FloatArray, BoolArray],
                   projector_height_m: float, clearance_m: float) -> BoolArray:
    """(m,) rises (line ``k``, column ``c``, distance ``d``) that no seen line above
    bounds but a line above with no return near the column (``grids`` of
    :func:`_grids`) passed over above the clearance, its sheet known to leave the range
    there (``passing``). Asked only after the walk: a line lost in the noise on a
    surface that the lines above it show is blocked, not passing (a wall's foot stripe,
    the line above too faint on the wall)."""
    out = np.zeros(k.size, dtype=np.bool_)
    known = np.isfinite(passing[0])
    for step in range(1, int(k.max(initial=0)) + 1):
        j = np.flatnonzero(k - step >= 0)
        if j.size == 0:
            break
        above = k[j] - step
        dist, high, _ = _nearest_in_column(*grids, above, c[j])
        seen = np.isfinite(dist)
        _passing_where_missing(dist, high, passing, known, above, c[j])
        over = ~seen & (dist > d[j] + same[j]) & (
            _passed_m(d[j], dist, high, projector_height_m) > clearance_m)
        out[j[over]] = True
    return out


def _off_ground_m(height_sigma: FloatArray) -> FloatArray:
    """(n,) how far (m) a sample must stand from the ground plane to be off it:
    max(RISE_MIN_M, RISE_SIGMAS·σ_h)."""
    return np.maximum(RISE_MIN_M, RISE_SIGMAS * height_sigma)


def below_ground(height_m: FloatArray, rows_off: FloatArray, height_sigma: FloatArray,
                 valid: BoolArray) -> BoolArray:
    """(n,) valid samples clearly *below* the ground plane: deeper than max(RISE_MIN_M,
    RISE_SIGMAS·σ_h) and more than RISE_PX rows beyond where their sheet meets the
    ground. Light does not go on under the ground: such a sample is a stripe given the
    wrong line, or the ground falls away (a ditch, a drop): either way its column is not
    free."""
    deep = height_m < -_off_ground_m(height_sigma)
    return np.asarray(valid & deep & (rows_off < -RISE_PX), dtype=np.bool_)


def corroborated(line: IntArray, column: IntArray, distance_m: FloatArray, clear: BoolArray,
                 ask: BoolArray, *, lines: int, width: int, focal_baseline_px_m: float
                 ) -> BoolArray:
    """(n,) True for the ``ask`` samples whose column (or a neighbour) holds a ``clear``
    sample of another line from max(FOOT_REL·d, FOOT_M, FOOT_PX·d²/(f·b)) nearer to
    max(FOOT_REL·d, FOOT_M) farther than their distance: a surface two lines meet, not
    one line's stripe on the ground. A line meeting an obstacle farther than that (but
    within the rows' reach) shows the wall whose foot the stripe lies at: half on the
    ground, it peaks off and triangulates short (a wall at 10.2 m read at 7.5 m from
    its foot), and it vouches for nothing nearer than the wall."""
    out = np.zeros(line.size, dtype=np.bool_)
    idx = np.flatnonzero(ask)
    if idx.size == 0:
        return out
    grid = np.full((lines, width), np.nan)
    keep = clear & (line >= 0) & (line < lines)
    grid[line[keep], column[keep]] = distance_m[keep]
    d = distance_m[idx]
    same = np.maximum(FOOT_REL * d, FOOT_M)
    reach = np.maximum(same, FOOT_PX * d * d / focal_baseline_px_m)
    for shift in (-1, 0, 1):
        near = grid[:, np.clip(column[idx] + shift, 0, width - 1)] - d[None, :]  # (K, m)
        other = np.arange(lines)[:, None] != line[idx][None, :]
        with np.errstate(invalid="ignore"):
            out[idx] |= (other & (near >= -reach[None, :]) & (near <= same[None, :])).any(axis=0)
    return out


def rows_off_ground(distance_m: FloatArray, height_m: FloatArray, projector_height_m: float,
                    focal_baseline_px_m: float) -> FloatArray:
    """(n,) how many image rows a sample at ``distance_m`` from the projector and
    ``height_m`` above the ground lies from where its sheet meets the ground: the sheet
    falls linearly from the projector's height to 0 at d_g = d·h0/(h0 − h), and a stripe
    moves f·b/r² rows per metre, so f·b·(1/d − 1/d_g) = f·b·h/(d·h0)."""
    h0 = max(projector_height_m, 1e-3)
    return np.asarray(focal_baseline_px_m * height_m / (np.maximum(distance_m, 1e-3) * h0),
                      dtype=np.float64)


def _grids(line: IntArray, column: IntArray, distance_m: FloatArray, height_m: FloatArray,
           obstacle: BoolArray, lines: int, width: int
           ) -> tuple[FloatArray, FloatArray, BoolArray]:
    """(K, W) distance (nan where no sample), height and obstacle per line and column."""
    grid_d = np.full((lines, width), np.nan)
    grid_h = np.zeros((lines, width))
    grid_o = np.zeros((lines, width), dtype=np.bool_)
    keep = (line >= 0) & (line < lines) & (column >= 0) & (column < width)
    k, c = line[keep], column[keep]
    grid_d[k, c], grid_h[k, c], grid_o[k, c] = distance_m[keep], height_m[keep], obstacle[keep]
    return grid_d, grid_h, grid_o


def _nearest_in_column(grid_d: FloatArray, grid_h: FloatArray, grid_o: BoolArray,
                       k: IntArray, c: IntArray) -> tuple[FloatArray, FloatArray, BoolArray]:
    """Line ``k``'s sample in column ``c``, else in c − 1, else in c + 1: (distance (nan:
    none), height, obstacle), (m,) each."""
    width = grid_d.shape[1]
    dist = np.full(k.size, np.nan)
    high = np.zeros(k.size)
    hit = np.zeros(k.size, dtype=np.bool_)
    for shift in (0, -1, 1):
        col = np.clip(c + shift, 0, width - 1)
        take = ~np.isfinite(dist) & np.isfinite(grid_d[k, col])
        dist[take], high[take], hit[take] = grid_d[k, col][take], grid_h[k, col][take], (
            grid_o[k, col][take])
    return dist, high, hit
