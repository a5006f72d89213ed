"""A python-can bus that injects the faults of a real bus, for tests and soak runs.

:class:`FaultyBus` wraps any open bus and, by seeded random draws or explicit switches,
drops, duplicates, reorders and delays frames, injects error frames, and fails sends as a
bus-off controller does. :class:`Babbler` is a node that floods the bus with
high-priority frames. A virtual bus does not model arbitration or bit timing: these
faults are the ones a receiver sees, not a model of the physical layer.
"""

from __future__ import annotations

import heapq
import itertools
import random
import threading
import time
from dataclasses import dataclass, field
from typing import Any

import can

#: socketcan error-frame class bits (linux/can/error.h)
CAN_ERR_FLAG = 0x20000000
CAN_ERR_BUSOFF = 0x40


@dataclass
class Faults:
    """Fault rates (0..1 per frame) and switches; all off by default."""

    drop_tx: float = 0.0
    drop_rx: float = 0.0
    duplicate_rx: float = 0.0
    reorder_rx: float = 0.0
    delay_rx_s: float = 0.0
    delay_rx_rate: float = 0.0
    corrupt_rx: float = 0.0
    error_frame_rate: float = 0.0
    bus_off: bool = False
    drop_ids: set[int] = field(default_factory=set)


@dataclass
class FaultCounts:
    """How many faults of each kind were injected."""

    dropped_tx: int = 0
    dropped_rx: int = 0
    duplicated: int = 0
    reordered: int = 0
    delayed: int = 0
    corrupted: int = 0
    error_frames: int = 0
    failed_sends: int = 0


def _flip_bit(msg: can.Message, bit: int) -> can.Message:
    """A copy of ``msg`` with one payload bit inverted."""
    data = bytearray(msg.data)
    if data:
        data[bit // 8 % len(data)] ^= 1 << (bit % 8)
    return can.Message(arbitration_id=msg.arbitration_id, data=bytes(data),
                       is_extended_id=msg.is_extended_id, timestamp=msg.timestamp,
                       is_fd=msg.is_fd)


class FaultyBus(can.BusABC):
    """Wrap ``inner`` and inject :class:`Faults`; shutting it down shuts ``inner`` down."""

    def __init__(self, inner: can.BusABC, faults: Faults | None = None, seed: int = 0,
                 **kwargs: Any) -> None:
        self.inner = inner
        self.faults = faults or Faults()
        self.counts = FaultCounts()
        self._random = random.Random(seed)
        self._pending: list[tuple[float, int, can.Message]] = []
        self._order = itertools.count()
        self._held: can.Message | None = None
        self._lock = threading.Lock()
        self.channel_info = f"faulty({inner.channel_info})"
        super().__init__(channel=str(getattr(inner, "channel", "faulty")), **kwargs)

    def _hit(self, rate: float) -> bool:
        return rate > 0.0 and self._random.random() < rate

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        """Send through ``inner`` unless a fault drops or fails the frame."""
        if self.faults.bus_off:
            self.counts.failed_sends += 1
            raise can.CanOperationError("injected bus-off: transmit failed")
        if msg.arbitration_id in self.faults.drop_ids or self._hit(self.faults.drop_tx):
            self.counts.dropped_tx += 1
            return
        self.inner.send(msg, timeout)

    def _queue(self, msg: can.Message, delay_s: float) -> None:
        heapq.heappush(self._pending, (time.monotonic() + delay_s, next(self._order), msg))

    def _due(self) -> can.Message | None:
        if self._pending and self._pending[0][0] <= time.monotonic():
            return heapq.heappop(self._pending)[2]
        return None

    def _error_frame(self) -> can.Message:
        self.counts.error_frames += 1
        return can.Message(arbitration_id=CAN_ERR_BUSOFF, is_error_frame=True,
                           is_extended_id=True, timestamp=time.time(), dlc=8)

    def _fault_rx(self, msg: can.Message) -> None:
        """Apply receive faults to ``msg``: drop, delay, reorder or duplicate it."""
        f = self.faults
        if msg.arbitration_id in f.drop_ids or self._hit(f.drop_rx):
            self.counts.dropped_rx += 1
        elif self._hit(f.corrupt_rx):
            self.counts.corrupted += 1
            self._queue(_flip_bit(msg, self._random.randrange(8 * max(len(msg.data), 1))), 0.0)
        elif self._hit(f.delay_rx_rate):
            self.counts.delayed += 1
            self._queue(msg, f.delay_rx_s)
        elif self._held is None and self._hit(f.reorder_rx):
            self.counts.reordered += 1
            self._held = msg
        else:
            self._queue(msg, 0.0)
            if self._held is not None:
                self._queue(self._held, 0.0)
                self._held = None
            if self._hit(f.duplicate_rx):
                self.counts.duplicated += 1
                self._queue(msg, 0.0)

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        with self._lock:
            due = self._due()
            if due is not None:
                return due, False
            if self._hit(self.faults.error_frame_rate):
                return self._error_frame(), False
        msg = self.inner.recv(timeout=min(timeout, 0.01) if timeout is not None else 0.01)
        with self._lock:
            if msg is not None:
                self._fault_rx(msg)
            return self._due(), False

    def shutdown(self) -> None:
        """Shut down the wrapper and the wrapped bus; idempotent."""
        if not self._is_shutdown:
            self.inner.shutdown()
        super().shutdown()


class Babbler:
    """A node that sends ``rate_hz`` frames with a high-priority ID, from its own thread.

    At 500 kbit/s an 8-byte frame with an 11-bit ID is at most 135 bits (about 0.27 ms),
    so ``rate_hz = 0.9 * 500000 / 135`` loads a real bus to about 90 %. On a virtual bus it
    only loads the receivers' queues and threads.
    """

    def __init__(self, bus: can.BusABC, rate_hz: float, arbitration_id: int = 0x001,
                 payload: bytes = b"\xff" * 8) -> None:
        self.bus, self.rate_hz = bus, rate_hz
        self.arbitration_id, self.payload = arbitration_id, payload
        self.sent = 0
        self.errors = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="atris-babbler", daemon=True)

    def start(self) -> Babbler:
        self._thread.start()
        return self

    def stop(self) -> None:
        """Stop and join; idempotent."""
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join()

    def _run(self) -> None:
        period = 1.0 / self.rate_hz
        next_t = time.monotonic()
        msg = can.Message(arbitration_id=self.arbitration_id, data=self.payload,
                          is_extended_id=False)
        while not self._stop.is_set():
            try:
                self.bus.send(msg)
                self.sent += 1
            except can.CanError:
                self.errors += 1
            next_t += period
            delay = next_t - time.monotonic()
            if delay > 0:
                self._stop.wait(delay)
            else:
                next_t = time.monotonic()
