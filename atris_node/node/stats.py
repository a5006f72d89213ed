"""Counters a unit keeps about its own run (status frame, logs, launch summary)."""

from __future__ import annotations

from dataclasses import dataclass, field

#: sub-frames of strobe history kept (the older half is dropped when full)
HISTORY_KEPT = 20000


@dataclass
class NodeStats:
    """Counters a node reports (status frame, logs, launch summary)."""

    sub_frames: int = 0
    maps: int = 0
    measurements: int = 0
    dropped_sub_frames: int = 0
    deadline_misses: int = 0
    #: maps a newer map replaced before the map thread took them
    maps_skipped: int = 0
    #: measurements not published: the loop had gone invalid while they were measured
    stale_maps: int = 0
    camera_faults: int = 0
    bad_sub_frames: int = 0
    #: maps the pipeline raised on (published as invalid distances; see Unit._measure_map)
    pipeline_errors: int = 0
    reconnects: int = 0
    laser_faults: int = 0
    #: times the projector went dark by itself (no strobe for its lease: a stalled loop)
    strobe_lapses: int = 0
    bus_errors: int = 0
    strobe_lit_while_not_allowed: int = 0
    last_lag: int = 0
    history: list[tuple[float, bool, int | None]] = field(default_factory=list)

    def record_strobe(self, now: float, lit: bool, allowed: bool, row: int | None) -> None:
        """One sub-frame's laser state: lit, whether the negotiation allowed it, the row."""
        if lit and not allowed:
            self.strobe_lit_while_not_allowed += 1
        self.history.append((now, lit, row if allowed else None))
        if len(self.history) > HISTORY_KEPT:
            del self.history[:HISTORY_KEPT // 2]
