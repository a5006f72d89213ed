"""ROI narrowing: look for each line only near the rows where it was found recently.

A line's band covers every range from z_min to z_max, but in a scene that changes slowly
each line sits on a few rows. :class:`RoiTracker` keeps, per line, the rows of its samples
in the last ``history`` maps and hands :func:`atris_node.pipeline.peaks.extract_lines` those rows
widened by ``margin_px`` as the rows to search for peaks. It asks for a full search

- every ``full_every``-th map (a line may appear where it was not seen),
- while any line has no recent samples (it may be anywhere in its band),
- while the last full search saw foreign light (its peaks may be anywhere).

:func:`atris_node.pipeline.peaks.extract_lines` itself searches every row when any pixel outside the
recent rows reaches the peak threshold (one comparison per pixel instead of the maximum
search): every peak it keeps reaches that threshold, so a narrowed search finds exactly the
peaks of the full search, whatever the scene does. Noise statistics, line identity and the
foreign-light checks always use the whole bands, so samples and sector distances are
identical with and without narrowing (``tests/test_roi.py``); what is left out is the
maximum search on rows where no line can be.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from atris_node.errors import ConfigError
from atris_node.pipeline.bands import Band
from atris_node.pipeline.peaks import LineSamples


@dataclass(frozen=True)
class RoiSettings:
    """How narrowing behaves; rows in px, counts in maps.

    Attributes:
        history: maps whose sample rows make a line's recent rows.
        margin_px: rows searched beyond the recent rows on each side.
        full_every: every this many maps the whole bands are searched.
    """

    history: int = 8
    margin_px: int = 6
    full_every: int = 16

    def __post_init__(self) -> None:
        for name in ("history", "full_every"):
            if getattr(self, name) < 1:
                raise ConfigError(f"roi {name} must be >= 1, got {getattr(self, name)}")
        if self.margin_px < 0:
            raise ConfigError(f"roi margin_px must be >= 0, got {self.margin_px}")


class RoiTracker:
    """Recent rows of every line and the search rows they give.

    Args:
        bands: the full band of every line (:func:`atris_node.pipeline.bands.line_bands`).
        settings: :class:`RoiSettings`.
    """

    def __init__(self, bands: tuple[Band, ...], settings: RoiSettings) -> None:
        self.bands = bands
        self.settings = settings
        self._recent: deque[tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]] = deque(
            maxlen=settings.history)
        self._maps = 0
        self._foreign = True
        self.full_searches = 0

    def search_rows(self) -> list[tuple[int, int]] | None:
        """Row intervals to search in the next map, or None for the whole bands."""
        due = self._maps % self.settings.full_every == 0
        if due or self._foreign or len(self._recent) < self.settings.history:
            return None
        low = np.min([lo for lo, _ in self._recent], axis=0)
        high = np.max([hi for _, hi in self._recent], axis=0)
        if not np.isfinite(low[[not b.empty for b in self.bands]]).all():
            return None  # a line without recent samples may be anywhere in its band
        return self._intervals(low, high)

    def _intervals(self, low: npt.NDArray[np.float64], high: npt.NDArray[np.float64]
                   ) -> list[tuple[int, int]]:
        m = self.settings.margin_px
        spans = sorted((max(int(np.floor(lo)) - m, b.row_lo), min(int(np.ceil(hi)) + m + 1,
                                                                 b.row_hi))
                       for b, lo, hi in zip(self.bands, low, high, strict=True)
                       if not b.empty)
        return [(lo, hi) for lo, hi in spans if hi > lo]

    def update(self, samples: LineSamples, full: bool, foreign: bool) -> None:
        """Record the samples of the map just used; ``full``: from a whole-band search
        (due, or forced by a pixel outside the recent rows); ``foreign``: that map showed
        foreign light."""
        count = len(self.bands)
        low, high = np.full(count, np.inf), np.full(count, -np.inf)
        np.minimum.at(low, samples.line, samples.row_px)
        np.maximum.at(high, samples.line, samples.row_px)
        self._recent.append((low, high))
        if full:
            self.full_searches += 1
            self._foreign = foreign
        else:
            self._foreign = self._foreign or foreign
        self._maps += 1
