"""The cycle publisher: status, quality, nearest-obstacle and sector frames of one unit.

Its own scheduler thread (python-can's ``send_periodic`` dies on the first failed send)
sends one cycle every ``period_s``. A new measurement is sent at once from the thread that
brings it (:meth:`Publisher.update`, the node's loop), without a thread switch and without
ever blocking that thread: when the scheduler thread is sending, during a back-off, or when
a frame cannot be queued at once, the scheduler thread sends the cycle instead.

Data older than ``max_age_s``, or from a unit that is not RUNNING or has a fault that
spoils its distances, goes out as "invalid", never as a stale distance. The owner's
measurement loop reports progress (:meth:`Publisher.update`, :meth:`Publisher.heartbeat`);
when it has not for ``max_age_s`` (it died or hangs) every cycle says FAULT with
DEADLINE_MISS and invalid distances, whatever the last status said. :meth:`Publisher.stop`
sends a final cycle: STOPPED, distances invalid. A failed send
starts a back-off (doubling from one period to ``backoff_cap_s``) during which cycles are
skipped; the thread never dies silently: an unexpected error is logged and kept, and
:meth:`Publisher.check` re-raises it in the owner's loop.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import deque
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, replace

import can

from atris_node.bus.can import payloads
from atris_node.bus.can.config import BusHealth
from atris_node.bus.can.e2e import COUNTER_MODULO
from atris_node.bus.can.frames import FrameCodec
from atris_node.bus.can.ids import DEFAULT_BASE_ID, FrameKind, message_name
from atris_node.errors import ConfigError, NodeFaultError
from atris_node.types import FaultBits, Measurement, UnitState, UnitStatus

logger = logging.getLogger(__name__)

#: late sends kept for a bus watch to pair with (:attr:`Publisher.late_sends`)
LATE_SENDS_KEPT = 256
MIN_PERIOD_S = 0.01


@dataclass
class PublisherStats:
    """Counters of a publisher (read them any time; they only grow)."""

    frames_sent: int = 0
    cycles: int = 0
    deadline_misses: int = 0
    send_errors: int = 0
    bus_off_count: int = 0
    skipped_cycles: int = 0
    #: cycles stamped on time whose first frame (Status) was queued later than period +
    #: tolerance after the last cycle (the thread preempted between its clock reading and
    #: the send): it reaches the bus late without DeadlineMiss, which the sender could not
    #: know in time
    sent_late: int = 0


class Publisher:
    """Publish one unit's frames on ``bus`` from its own thread.

    Args:
        bus: an open python-can bus (the publisher does not shut it down).
        unit_id: 0..15, selects the ID block ``base_id + 4 * unit_id``.
        period_s: cycle period, 0.01..1.0 s.
        max_age_s: data older than this at send time is sent as invalid, s.
        clock: monotonic clock in seconds, the clock of ``Measurement.newest_time_s``.
        sector_count: sectors published before the first measurement (1..16).
        tolerance_s: a cycle later than ``period_s + tolerance_s`` is a deadline miss
            (default a quarter period).
        fd: send CAN FD frames (same 8-byte payloads, bit-rate switch on).
        health: error-frame listener of the bus, if the owner runs a Notifier.
        base_id: first unit frame ID of the fleet (:func:`~atris_node.bus.can.ids.check_base_id`;
            the caller decides whether CANopen IDs are allowed).
    """

    def __init__(self, bus: can.BusABC, unit_id: int, period_s: float = 0.05,
                 max_age_s: float = 0.2, clock: Callable[[], float] = time.monotonic, *,
                 sector_count: int = 8, tolerance_s: float | None = None, fd: bool = False,
                 backoff_cap_s: float = 1.0, health: BusHealth | None = None,
                 base_id: int = DEFAULT_BASE_ID) -> None:
        if not MIN_PERIOD_S <= period_s <= 1.0:
            raise ConfigError(f"publish period must be 0.01..1.0 s, got {period_s}")
        if not max_age_s > 0.0:
            raise ConfigError(f"max_age_s must be > 0, got {max_age_s}")
        self.bus, self.unit_id, self.period_s, self.max_age_s = bus, unit_id, period_s, max_age_s
        self.clock, self.fd, self.backoff_cap_s = clock, fd, backoff_cap_s
        self.tolerance_s = period_s / 4.0 if tolerance_s is None else tolerance_s
        self.health = health or BusHealth()
        #: the owner's check of the handed status at send time (the node: state and code
        #: row from the negotiation as it stands then, :func:`negotiated_status`)
        self.status_at_send: Callable[[UnitStatus], UnitStatus] = payloads.unchanged
        self.stats = PublisherStats()
        self._names = {kind: message_name(unit_id, kind) for kind in FrameKind}
        self._sector_count = payloads.check_sector_count(sector_count)
        self._codec = FrameCodec(base_id=base_id)
        self._counters = dict.fromkeys(self._names.values(), 0)
        self._last_encoded: tuple[str, int] | None = None  # (message, its counter)
        self._measurement: Measurement | None = None
        self._status = UnitStatus(UnitState.INIT, 0, 0, 0.0, 0)
        self._progress_s: float | None = None  # the owner's loop last made progress
        self._lock = threading.Lock()  # the newest measurement and status
        self._send_lock = threading.Lock()  # composing and sending one cycle
        self._next_due_s = 0.0
        self._wake = threading.Event()
        self._stopping = threading.Event()
        self._thread: threading.Thread | None = None
        self._fatal: BaseException | None = None
        self._last_cycle_s: float | None = None
        self._backoff_s = 0.0
        self._retry_at_s = 0.0
        self._first_sent_s = 0.0  # clock once the last cycle's first frame was queued
        #: the clock once the first frame was queued, of the newest LATE_SENDS_KEPT cycles
        #: counted in ``stats.sent_late`` (what a bus watch pairs its late frames with)
        self.late_sends: deque[float] = deque(maxlen=LATE_SENDS_KEPT)
        self._bus_error = False

    # -- owner side -------------------------------------------------------------------
    def start(self) -> None:
        """Start the scheduler thread; again after stop() (a unit re-activated)."""
        if self._thread is not None:
            return
        self._stopping.clear()
        self._wake.clear()
        self._backoff_s, self._retry_at_s = 0.0, 0.0
        self._next_due_s = self.clock()
        self._thread = threading.Thread(target=self._run, name=f"atris-publisher-{self.unit_id}",
                                        daemon=True)
        self._thread.start()

    def stop(self) -> None:
        """Stop and join the thread, then send a final cycle (STOPPED, distances invalid,
        the last fault bits); safe to call more than once (one final cycle)."""
        if self._stopping.is_set():
            return
        self._stopping.set()
        self._wake.set()
        if self._thread is None:
            return
        self._thread.join()
        self._thread = None
        with self._lock:
            self._measurement = None
            self._status = replace(self._status, state=UnitState.STOPPED)
            self._progress_s = None
        try:
            with self._send_lock:
                self._cycle(self.clock(), immediate=True, timeout_s=self.period_s)
        except Exception:
            logger.exception("final cycle of unit %d not sent", self.unit_id)

    def heartbeat(self) -> None:
        """The owner's measurement loop made progress (a sub-frame handled) without a new
        measurement or state to hand over; call it from that loop, never another thread."""
        self._progress_s = self.clock()

    def update(self, measurement: Measurement | None, status: UnitStatus) -> None:
        """Hand over the newest measurement and status; a new measurement or a change of
        state (a fault, the code lost) is sent at once."""
        if measurement is not None:
            payloads.check_sector_count(max(len(measurement.sectors), 1))
        with self._lock:
            fresh = measurement is not None and measurement is not self._measurement
            fresh |= status.state != self._status.state  # e.g. a camera fault: invalid at once
            self._measurement, self._status = measurement, status
            self._progress_s = self.clock()
        if fresh and not self._send_inline():
            self._wake.set()

    def send_now(self) -> None:
        """Send a cycle at once from the scheduler thread: the owner's state changed
        outside its loop (the code lost while the loop is blocked)."""
        if self._thread is not None and not self._stopping.is_set():
            self._wake.set()

    def _send_inline(self) -> bool:
        """Send the cycle of a new measurement from the caller's thread; False, with
        nothing counted, when the scheduler thread should send it (busy sending, in a
        back-off, or a frame that cannot be queued at once). Nothing is sent inline before
        start() or after stop()."""
        if self._thread is None or self._stopping.is_set():
            return False
        if not self._send_lock.acquire(blocking=False):
            return False
        try:
            now = self.clock()
            return now >= self._retry_at_s and self._cycle(now, immediate=True, timeout_s=0.0)
        finally:
            self._send_lock.release()

    def check(self) -> None:
        """Re-raise, as NodeFaultError, an error that stopped the publisher thread."""
        if self._fatal is not None:
            raise NodeFaultError(f"CAN publisher of unit {self.unit_id} failed: "
                                 f"{self._fatal!r}") from self._fatal

    @property
    def send_errors(self) -> int:
        """Frames the bus refused so far (a blocking send that raised)."""
        return self.stats.send_errors

    @property
    def frames_sent(self) -> int:
        """Frames the bus took so far."""
        return self.stats.frames_sent

    @property
    def alive(self) -> bool:
        """True while the scheduler thread runs."""
        return self._thread is not None and self._thread.is_alive()

    # -- scheduler thread ----------------------------------------------------------------
    def _run(self) -> None:
        try:
            self._loop()
        except Exception as exc:
            logger.exception("CAN publisher of unit %d stopped", self.unit_id)
            self._fatal = exc

    def _loop(self) -> None:
        while not self._stopping.is_set():
            woken = self._wake.wait(timeout=max(0.0, self._next_due_s - self.clock()))
            if self._stopping.is_set():
                return
            self._wake.clear()
            with self._send_lock:
                now = self.clock()
                if woken or now >= self._next_due_s:  # else an inline cycle moved the due
                    self._cycle(now, immediate=woken, timeout_s=self.period_s)

    def _late(self, now: float) -> bool:
        """True when a cycle at ``now`` comes later than period + tolerance after the last."""
        return self._last_cycle_s is not None and (
            now - self._last_cycle_s > self.period_s + self.tolerance_s)

    def _next_due(self, due: float, now: float, immediate: bool) -> float:
        """Fixed-rate schedule; an immediate send or a late cycle restarts it from now."""
        if immediate or due + self.period_s <= now:
            return now + self.period_s
        return due + self.period_s

    def _cycle(self, now: float, *, immediate: bool, timeout_s: float) -> bool:
        """One cycle at ``now`` (the send lock held); True when every frame was queued.
        A non-blocking cycle (``timeout_s`` 0, inline) that cannot queue a frame counts
        nothing: the scheduler thread then sends the whole cycle, with new counters."""
        sent, stamp = False, now
        if now < self._retry_at_s:
            late = self._late(stamp)
            self.stats.skipped_cycles += 1
        else:
            with self._lock:
                measurement, status, progress_s = (self._measurement, self._status,
                                                   self._progress_s)
            status = payloads.alive_status(self.status_at_send(status), progress_s, now,
                                           self.max_age_s)
            # lateness as near the send as the sender sees it: waiting for the locks and
            # composing the status took time the bus would see as lateness
            stamp = self.clock()
            late = self._late(stamp)
            sent = self._send_all(self.frames(measurement, status, now, late), timeout_s)
            if not sent and timeout_s == 0.0:
                return False
            if sent and not late and self._late(self._first_sent_s):
                self.stats.sent_late += 1
                self.late_sends.append(self._first_sent_s)
        self._last_cycle_s = stamp
        self.stats.cycles += 1
        self.stats.deadline_misses += int(late)
        self.stats.bus_off_count = self.health.bus_off_count
        self._next_due_s = self._next_due(self._next_due_s, now, immediate)
        return sent

    # -- composing frames ----------------------------------------------------------------
    def usable(self, measurement: Measurement | None, status: UnitStatus, now: float) -> bool:
        """True when ``measurement`` may be published as valid distances at ``now``."""
        age = None if measurement is None else now - measurement.newest_time_s
        return payloads.data_usable(measurement, status, age, self.max_age_s)

    def _faults(self, status: UnitStatus, late: bool) -> FaultBits:
        faults = FaultBits(status.faults)
        if late:
            faults |= FaultBits.DEADLINE_MISS
        if self._bus_error or self.health.take_error():
            faults |= FaultBits.BUS_ERROR
        return faults

    def compose(self, measurement: Measurement | None, status: UnitStatus, now: float,
                late: bool = False) -> list[can.Message]:
        """The frames of one cycle at ``now`` (each call advances the E2E counters)."""
        return list(self.frames(measurement, status, now, late))

    def frames(self, measurement: Measurement | None, status: UnitStatus, now: float,
               late: bool = False) -> Iterator[can.Message]:
        """The frames of one cycle at ``now``, each composed and encoded when it is taken
        (so the first is sent before the others are composed); a frame's E2E counter
        advances when it is encoded."""
        usable = self.usable(measurement, status, now)
        age = None if measurement is None else now - measurement.newest_time_s
        count = len(measurement.sectors) if measurement and measurement.sectors else (
            self._sector_count)
        self._sector_count = count
        if measurement is not None:
            status = replace(status, measurement_counter=measurement.counter)
        faults = self._faults(status, late)
        yield self._encode(FrameKind.STATUS, payloads.status_signals(status, faults, age))
        yield self._encode(FrameKind.QUALITY, payloads.quality_signals(status, count))
        yield self._encode(FrameKind.NEAREST, payloads.nearest_signals(measurement, usable))
        sectors = measurement.sectors if measurement is not None else ()
        for signals in payloads.sectors_signals(sectors, count, usable):
            yield self._encode(FrameKind.SECTORS, signals)

    def _encode(self, kind: FrameKind, signals: payloads.RawSignals) -> can.Message:
        name = self._names[kind]
        counter = self._counters[name]
        self._counters[name] = (counter + 1) % COUNTER_MODULO
        self._last_encoded = (name, counter)
        return self._codec.encode(name, signals, counter, scaling=False, fd=self.fd)

    def _unsend_last(self) -> None:
        """The last frame encoded did not reach the bus: it gives its E2E counter back.
        A message's counter counts its frames on the bus, so a receiver's gap is a frame
        lost there; an inline cycle the transmit queue refused halfway (sent again, whole,
        by the scheduler thread) left a gap that a receiver's E2E check took for a lost
        frame, and a good frame after it for out of sequence."""
        if self._last_encoded is not None:
            name, counter = self._last_encoded
            self._counters[name] = counter
            self._last_encoded = None

    # -- sending -------------------------------------------------------------------------
    def _send_all(self, frames: Iterable[can.Message], timeout_s: float) -> bool:
        """Send ``frames`` in order; False at the first that fails. A failure is a send
        error (back-off) unless the send was non-blocking (``timeout_s`` 0)."""
        for i, msg in enumerate(frames):
            if not self._send(msg, timeout_s):
                self._unsend_last()
                return False
            if i == 0:
                self._first_sent_s = self.clock()
        if self._backoff_s:
            logger.warning("CAN sending of unit %d resumed", self.unit_id)
        self._backoff_s = 0.0
        self._bus_error = False
        return True

    def _send(self, msg: can.Message, timeout_s: float) -> bool:
        try:
            self.bus.send(msg, timeout=timeout_s)
        except (can.CanError, OSError) as exc:
            if timeout_s > 0.0:
                self._on_send_error(exc)
            return False
        self.stats.frames_sent += 1
        return True

    def _on_send_error(self, exc: Exception) -> None:
        self.stats.send_errors += 1
        self._bus_error = True
        self._backoff_s = min(self.backoff_cap_s, max(self.period_s, 2.0 * self._backoff_s))
        self._retry_at_s = self.clock() + self._backoff_s
        logger.error("CAN send of unit %d failed (%s); retry in %.3f s",
                     self.unit_id, exc, self._backoff_s)
