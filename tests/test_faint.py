"""Faint returns (atris_node.pipeline.faint): a line under the per-column threshold that
still shows as a stripe averaged along its columns makes a would-be free sector INVALID.

The scene-level case is the stress scene dark_turned_wall_near_zmax (tests/
test_safety_scenes.py): with faint.FAINT_SIGMAS set to infinity it read free before a
dark wall at 8.9 m in 1 sector-frame of 32 on seeds 1, 2 and 3 and 2 on seed 11."""

from __future__ import annotations

import numpy as np

from atris_node.pipeline.bands import Band
from atris_node.pipeline.faint import FAINT_COLUMNS, faint_columns, faint_sectors
from atris_node.pipeline.peaks import LineSamples

WIDTH = 400
BAND = Band(0, 20, 100)


def _map(rng: np.random.Generator, stripe_dn: float, offset_dn: float = 0.0) -> np.ndarray:
    """Noise of σ 3 DN on ``offset_dn``, a stripe of ``stripe_dn`` (σ 1 px) at rows
    49-51 of columns 100-199: SNR ``stripe_dn``/3 in each column."""
    values = rng.normal(offset_dn, 3.0, (120, WIDTH))
    values[49:52, 100:200] += stripe_dn * np.array([0.6, 1.0, 0.6])[:, None]
    return np.round(values).astype(np.int16)


def _samples(line: int, row: float, cols: np.ndarray) -> LineSamples:
    n = cols.size
    return LineSamples(np.full(n, line, np.int64), np.full(n, row), cols.astype(np.float64),
                       np.full(n, 20.0), np.full(n, 0.1), np.zeros(n, bool))


NONE = _samples(1, 0.0, np.zeros(0, np.int64))


def test_feature_a_stripe_under_the_threshold_shows_averaged() -> None:
    """A stripe at SNR 3 per column (under every peak threshold) is found in nearly all
    of its 100 columns; noise alone and a constant offset in 100 others in none.
    Checked to fail with FAINT_SIGMAS set to infinity (0 columns)."""
    values = _map(np.random.default_rng(3), 9.0, offset_dn=5.0)
    stripe = np.arange(100 + FAINT_COLUMNS, 200 - FAINT_COLUMNS, dtype=np.int64)
    assert faint_columns(values, BAND, NONE, stripe) >= 0.9 * stripe.size
    assert faint_columns(values, BAND, NONE, np.arange(250, 350, dtype=np.int64)) == 0


def test_feature_another_lines_stripe_is_no_faint_return() -> None:
    """The same stripe is another line's, sampled there: it is left out of the band."""
    values = _map(np.random.default_rng(4), 9.0)
    stripe = np.arange(100, 200, dtype=np.int64)
    assert faint_columns(values, BAND, _samples(1, 50.0, stripe), stripe) == 0


def test_feature_faint_sectors_only_where_free() -> None:
    """Only sectors about to be free are looked into: with none, the map is not read
    (it is None here); with the stripe's sector free, that sector is INVALID."""
    column_sector = (np.arange(WIDTH) // 100).astype(np.int64)
    assert faint_sectors(None, (BAND,), NONE, column_sector, set(), 5) == set()  # type: ignore[arg-type]
    values = _map(np.random.default_rng(5), 9.0)
    assert faint_sectors(values, (BAND,), NONE, column_sector, {1, 3}, 5) == {1}
