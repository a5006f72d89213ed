"""Soak run: the simulated fleet for minutes, with its resource use measured.

Reported after a warm-up (the first fifth of the run, at most 60 s): resident memory growth
in MB, thread count at the start and the end, the fraction of publisher cycles that missed
their deadline, and frames whose E2E check failed. What went out is also checked on the
bus itself (:class:`CycleWatch`): a unit's Status frame that came later than its period
plus tolerance after the one before is a late cycle, and one later than that by more than
SEND_JITTER_S must carry DeadlineMiss. The sender judges its lateness at its last clock
reading before the send; a thread preempted between that reading and the bus's timestamp
(the GIL, a loaded machine) reaches the bus later than it could know, by a few ms, or by
a whole stall of the process that falls in between. The senders count such cycles
themselves (their clock read again once the Status frame is queued:
``PublisherStats.sent_late``, reported as ``sent_late_cycles``, each kept in
``Publisher.late_sends``): an unflagged late cycle on the bus that no sender's late send
pairs with (same unit, from its bus timestamp to the unit's next Status frame) is
``unexplained_late_cycles``, a sender that did not flag a lateness it knew.
"""

from __future__ import annotations

import math
import sys
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import asdict, dataclass
from typing import Any

import can
import psutil

from atris_node.bus.can.frames import FrameCodec
from atris_node.bus.can.ids import FrameKind, message_name
from atris_node.bus.can.monitor import BusMonitor, e2e_errors_by_unit
from atris_node.errors import FrameDecodeError
from atris_node.node.launch import LaunchSpec, load_launch
from atris_node.node.runner import FleetRun, open_bus

#: s a Status frame may reach the bus after the sender's last clock reading (preemption
#: between the reading and the send) before a late cycle without DeadlineMiss counts
SEND_JITTER_S = 0.010
#: s a sender's clock, once its Status frame was queued, may read before the frame's bus
#: timestamp and still be that send (the two clocks are converted, not one)
PAIR_S = 0.010
WARMUP_FRACTION = 0.2
WARMUP_MAX_S = 60.0
#: GIL switch interval during a soak, s: four units share one interpreter here (a vehicle
#: runs one process per unit), so a publisher thread must not wait 5 ms turns behind
#: four renderers and pipelines
SWITCH_INTERVAL_S = 0.001


@dataclass(frozen=True)
class SoakReport:
    """What a soak run measured (fields are relied on by other tools)."""

    minutes: float
    units: int
    rss_start_mb: float
    rss_end_mb: float
    rss_growth_mb: float
    threads_start: int
    threads_end: int
    cycles: int
    deadline_misses: int
    deadline_miss_fraction: float
    e2e_errors: int
    measurements: int
    late_cycles_on_bus: int
    unflagged_late_cycles: int
    sent_late_cycles: int
    unexplained_late_cycles: int

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)


class CycleWatch(can.Listener):
    """Late Status cycles as the bus saw them, per frame's send timestamp, and how many of
    them lack the DeadlineMiss bit. ``limits`` maps a Status frame's name to the largest
    gap, s, its unit's cycles may have (period + tolerance)."""

    def __init__(self, limits: dict[str, float], base_id: int) -> None:
        self.limits = limits
        self.late = 0
        self.unflagged = 0
        #: (frame name, bus timestamp) of each late cycle counted in ``unflagged``
        self.unflagged_at: list[tuple[str, float]] = []
        #: bus timestamp of the same unit's next Status frame, for each of ``unflagged_at``
        #: (inf until it came)
        self.unflagged_until: list[float] = []
        self._waiting: dict[str, int] = {}  # frame name -> its unflagged cycle's index
        self._codec = FrameCodec(base_id=base_id)
        self._last: dict[str, float] = {}

    def on_message_received(self, msg: can.Message) -> None:
        try:
            frame = self._codec.decode_message(msg)
        except FrameDecodeError:
            return
        limit = self.limits.get(frame.name)
        if limit is None:
            return
        last, self._last[frame.name] = self._last.get(frame.name), msg.timestamp
        waiting = self._waiting.pop(frame.name, None)
        if waiting is not None:
            self.unflagged_until[waiting] = msg.timestamp
        if last is not None and msg.timestamp - last > limit:
            self.late += 1
            if (msg.timestamp - last > limit + SEND_JITTER_S
                    and not frame.signals.get("Fault_DeadlineMiss")):
                self.unflagged += 1
                self._waiting[frame.name] = len(self.unflagged_at)
                self.unflagged_at.append((frame.name, msg.timestamp))
                self.unflagged_until.append(math.inf)


def _status_limits(fleet: FleetRun) -> dict[str, float]:
    return {message_name(u.publisher.unit_id, FrameKind.STATUS):
            u.publisher.period_s + u.publisher.tolerance_s for u in fleet.units}


def _rss_mb() -> float:
    return float(psutil.Process().memory_info().rss) / 1e6


def _publisher_totals(fleet: FleetRun) -> tuple[int, int]:
    cycles = sum(u.publisher.stats.cycles for u in fleet.units)
    misses = sum(u.publisher.stats.deadline_misses for u in fleet.units)
    return cycles, misses


def _sent_late(fleet: FleetRun) -> int:
    return sum(u.publisher.stats.sent_late for u in fleet.units)


def _unexplained(watch: CycleWatch, fleet: FleetRun, wall_minus_clock_s: float) -> int:
    """The unflagged late cycles of ``watch`` that no sender counted as sent late: none of
    its unit's late sends (``Publisher.late_sends``, its clock; ``wall_minus_clock_s``
    converts it to the bus timestamps' wall clock) lies in that cycle, from PAIR_S before
    its bus timestamp to its unit's next Status frame (the next cycle is sent only after
    this one's clock was read: the sender holds its send lock)."""
    sends = {message_name(u.publisher.unit_id, FrameKind.STATUS): u.publisher.late_sends
             for u in fleet.units}
    return sum(not _paired(at, until, [t + wall_minus_clock_s for t in sends.get(name, ())])
               for (name, at), until in zip(watch.unflagged_at, watch.unflagged_until,
                                            strict=True))


def _paired(at: float, until: float, sends: list[float]) -> bool:
    return any(at - PAIR_S <= t < until for t in sends)


def _run_phase(fleet: FleetRun, seconds: float) -> None:
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        time.sleep(min(0.5, max(0.0, end - time.monotonic())))
        fleet.check()


@contextmanager
def _switch_interval(seconds: float) -> Iterator[None]:
    previous = sys.getswitchinterval()
    sys.setswitchinterval(seconds)
    try:
        yield
    finally:
        sys.setswitchinterval(previous)


def soak(minutes: float, spec: LaunchSpec | None = None) -> SoakReport:
    """Run the soak fleet for ``minutes`` and measure it after the warm-up."""
    with _switch_interval(SWITCH_INTERVAL_S):
        return _soak(minutes, spec or load_launch("sim_soak"))


def _soak(minutes: float, spec: LaunchSpec) -> SoakReport:
    total_s = minutes * 60.0
    warmup_s = min(total_s * WARMUP_FRACTION, WARMUP_MAX_S)
    monitor = BusMonitor(e2e_timeout_s=1.0, base_id=int(spec.units[0]["bus.base_id"]))
    fleet = FleetRun(spec)
    with open_bus(spec.units[0]) as bus:  # the units' bus, opened as they open it
        notifier = can.Notifier(bus, [monitor], timeout=0.1)
        try:
            fleet.start()
            _run_phase(fleet, warmup_s)
            watch = CycleWatch(_status_limits(fleet), monitor.base_id)
            # counted from before the watch listens to after the senders stopped: every
            # cycle the watch sees was checked by its sender in between
            sent_late0 = _sent_late(fleet)
            wall_minus_clock_s = time.time() - time.monotonic()  # the units' clock
            notifier.add_listener(watch)
            rss0, threads0 = _rss_mb(), threading.active_count()
            cycles0, misses0 = _publisher_totals(fleet)
            errors0 = sum(e2e_errors_by_unit(monitor).values())
            _run_phase(fleet, total_s - warmup_s)
            rss1, threads1 = _rss_mb(), threading.active_count()
            cycles1, misses1 = _publisher_totals(fleet)
            errors1 = sum(e2e_errors_by_unit(monitor).values())
            measurements = sum(u.stats.measurements for u in fleet.units)
            notifier.remove_listener(watch)
        finally:
            fleet.stop()
            notifier.stop()
    sent_late = _sent_late(fleet) - sent_late0
    unexplained = _unexplained(watch, fleet, wall_minus_clock_s)
    cycles, misses = cycles1 - cycles0, misses1 - misses0
    return SoakReport(
        minutes=minutes, units=len(spec.units), rss_start_mb=round(rss0, 2),
        rss_end_mb=round(rss1, 2), rss_growth_mb=round(rss1 - rss0, 2),
        threads_start=threads0, threads_end=threads1, cycles=cycles,
        deadline_misses=misses, deadline_miss_fraction=misses / cycles if cycles else 0.0,
        e2e_errors=errors1 - errors0, measurements=measurements,
        late_cycles_on_bus=watch.late, unflagged_late_cycles=watch.unflagged,
        sent_late_cycles=sent_late, unexplained_late_cycles=unexplained)
