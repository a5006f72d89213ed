"""Decode and aggregate everything on a bus: the library half of ``atris monitor``.

:class:`BusMonitor` is a python-can listener. It decodes every frame with the shipped
DBC, checks E2E per arbitration ID, and keeps per unit the last status, quality,
nearest obstacle and sector distances, plus frame rates. Frames of other DBC messages
(the code-negotiation frames) are decoded generically and kept by message name.
:meth:`BusMonitor.snapshot` returns plain data (JSON-able); :func:`render_table` turns
it into text. Timestamps are the frames' own (``msg.timestamp``), so a recorded log
replays exactly as it was seen.
"""

from __future__ import annotations

import collections
import contextlib
import logging
import threading
from dataclasses import dataclass, field
from typing import Any

import can

from atris_node.bus.can.e2e import E2EChecker, E2EState
from atris_node.bus.can.frames import DecodedFrame, FrameCodec
from atris_node.bus.can.ids import DEFAULT_BASE_ID, FrameKind, unit_of
from atris_node.errors import FrameDecodeError

logger = logging.getLogger(__name__)

RATE_WINDOW_S = 2.0


@dataclass
class UnitView:
    """What the monitor knows about one unit."""

    unit_id: int
    last: dict[str, dict[str, Any]] = field(default_factory=dict)  # kind -> signals
    sectors: dict[int, tuple[Any, Any]] = field(default_factory=dict)  # index -> (d, conf)
    times: collections.deque[float] = field(default_factory=collections.deque)
    frames: int = 0


@dataclass
class OtherView:
    """A non-unit DBC message (e.g. a negotiation frame) seen on the bus."""

    count: int = 0
    arbitration_id: int = 0
    last: dict[str, Any] = field(default_factory=dict)


class BusMonitor(can.Listener):
    """Aggregate decoded frames; feed it with :meth:`feed` or as a Notifier listener."""

    def __init__(self, codec: FrameCodec | None = None, e2e_timeout_s: float = 0.2,
                 base_id: int = DEFAULT_BASE_ID) -> None:
        self.base_id = base_id  # the units' ID block starts here (bus.base_id)
        self.codec = codec or FrameCodec(base_id=base_id)
        self.e2e_timeout_s = e2e_timeout_s
        self.units: dict[int, UnitView] = {}
        self.others: dict[str, OtherView] = {}
        self.checkers: dict[int, E2EChecker] = {}
        self.last_e2e: dict[int, E2EState] = {}
        self.unknown_frames = 0
        self.error_frames = 0
        self.latest_time_s = 0.0
        self._lock = threading.Lock()

    def on_message_received(self, msg: can.Message) -> None:
        self.feed(msg)

    def on_error(self, exc: Exception) -> None:
        logger.error("CAN receive failed in the monitor: %s", exc)

    def feed(self, msg: can.Message) -> None:
        """Take one frame (thread safe)."""
        with self._lock:
            self.latest_time_s = max(self.latest_time_s, msg.timestamp)
            if msg.is_error_frame:
                self.error_frames += 1
                return
            try:
                frame = self.codec.decode_message(msg)
            except FrameDecodeError as exc:
                self.unknown_frames += 1
                logger.debug("undecodable frame: %s", exc)
                return
            self._check_e2e(frame, bytes(msg.data), msg.timestamp)
            self._keep(frame, msg.timestamp)

    def _check_e2e(self, frame: DecodedFrame, data: bytes, time_s: float) -> None:
        if frame.data_id is None:
            return
        checker = self.checkers.setdefault(
            frame.arbitration_id, E2EChecker(frame.data_id, self.e2e_timeout_s))
        self.last_e2e[frame.arbitration_id] = checker.check(data, time_s)

    def _keep(self, frame: DecodedFrame, time_s: float) -> None:
        owner = None if frame.is_extended_id else unit_of(frame.arbitration_id, self.base_id)
        if owner is None:
            other = self.others.setdefault(frame.name, OtherView())
            other.count, other.arbitration_id, other.last = (
                other.count + 1, frame.arbitration_id, frame.signals)
            return
        unit_id, kind = owner
        view = self.units.setdefault(unit_id, UnitView(unit_id))
        view.frames += 1
        view.times.append(time_s)
        while view.times and view.times[0] < time_s - RATE_WINDOW_S:
            view.times.popleft()
        if self.last_e2e.get(frame.arbitration_id, E2EState.OK).valid:
            view.last[kind.suffix] = frame.signals
            if kind is FrameKind.SECTORS:
                self._keep_sectors(view, frame.signals)

    @staticmethod
    def _keep_sectors(view: UnitView, signals: dict[str, Any]) -> None:
        first = int(signals["SectorIndex"])
        view.sectors[first] = (signals["Distance0"], signals["Confidence0"])
        if signals["Distance1"] != "no_sector":
            view.sectors[first + 1] = (signals["Distance1"], signals["Confidence1"])

    # -- reporting -----------------------------------------------------------------------
    def snapshot(self, now_s: float | None = None) -> dict[str, Any]:
        """Plain-data summary at ``now_s`` (default: the newest frame's timestamp)."""
        with self._lock:
            now = self.latest_time_s if now_s is None else now_s
            return {
                "units": {str(u): self._unit_summary(v, now)
                          for u, v in sorted(self.units.items())},
                "others": {n: {"id": f"0x{o.arbitration_id:X}", "count": o.count,
                               "last": o.last} for n, o in sorted(self.others.items())},
                "unknown_frames": self.unknown_frames,
                "error_frames": self.error_frames,
            }

    def _unit_summary(self, view: UnitView, now: float) -> dict[str, Any]:
        status = view.last.get("Status", {})
        return {
            "state": status.get("State"),
            "code_row": status.get("CodeRow"),
            "code_length": status.get("CodeLength"),
            "chip_rate_hz": status.get("ChipRate"),
            "data_age_s": status.get("DataAge"),
            "faults": sorted(k[6:] for k, v in status.items() if k.startswith("Fault_") and v),
            "quality": view.last.get("Quality", {}),
            "nearest": view.last.get("Nearest", {}),
            "sectors": [[i, *view.sectors[i]] for i in sorted(view.sectors)],
            "frames": view.frames,
            "rate_hz": self._rate(view, now),
            "e2e": self._e2e_summary(view.unit_id, now),
        }

    @staticmethod
    def _rate(view: UnitView, now: float) -> float:
        recent = [t for t in view.times if t >= now - RATE_WINDOW_S]
        if len(recent) < 2:
            return 0.0
        return round((len(recent) - 1) / max(recent[-1] - recent[0], 1e-3), 1)

    def _e2e_summary(self, unit_id: int, now: float) -> dict[str, Any]:
        summary = {}
        for arbitration_id, checker in sorted(self.checkers.items()):
            owner = unit_of(arbitration_id, self.base_id)
            if owner is None or owner[0] != unit_id:
                continue
            state = checker.poll(now) or self.last_e2e[arbitration_id]
            counts = {s.value: n for s, n in checker.counts.items() if n}
            summary[owner[1].suffix] = {"state": state.value, "counts": counts}
        return summary


def _fmt_distance(value: Any) -> str:
    return f"{value:.2f}" if isinstance(value, float) else str(value)


def render_table(snapshot: dict[str, Any]) -> str:
    """A fixed-width text table of a :meth:`BusMonitor.snapshot`."""
    lines = [f"{'unit':>4} {'state':<11} {'code':>7} {'chip Hz':>8} {'age s':>6} "
             f"{'rate':>6} {'nearest m':>10}  e2e / faults / sectors (m)"]
    for unit, view in snapshot["units"].items():
        code = f"{view['code_row']}/{view['code_length']}"
        e2e = ",".join(f"{k}:{v['state']}" for k, v in view["e2e"].items())
        sectors = " ".join(_fmt_distance(d) for _, d, _ in view["sectors"])
        nearest = _fmt_distance(view["nearest"].get("Distance", "-"))
        lines.append(f"{unit:>4} {view['state']!s:<11} {code:>7} {view['chip_rate_hz']!s:>8} "
                     f"{view['data_age_s']!s:>6} {view['rate_hz']:>6} {nearest:>10}  {e2e}")
        lines.append(f"{'':>4} faults: {','.join(view['faults']) or '-'}  sectors: {sectors}")
    for name, other in snapshot["others"].items():
        lines.append(f"{name} ({other['id']}) x{other['count']}: {other['last']}")
    lines.append(f"unknown frames: {snapshot['unknown_frames']}  "
                 f"error frames: {snapshot['error_frames']}")
    return "\n".join(lines)


#: frames read from the bus after its Notifier stopped, at most (a busy real bus never
#: falls silent; the virtual bus has only what was queued before)
DRAIN_LIMIT = 100_000


class _Fanout(can.Listener):
    """One Notifier listener passing each frame on to several. A listener that fails on a
    frame (a log writer on a full disk) is logged and counted, and the others still get
    it; stopping the fan-out stops none of them."""

    def __init__(self, listeners: list[can.Listener]) -> None:
        self.listeners = listeners
        self.failures = 0
        self.first_failure = ""

    def on_message_received(self, msg: can.Message) -> None:
        for listener in self.listeners:
            try:
                listener.on_message_received(msg)
            except Exception as exc:
                self._failed(listener, exc)

    def _failed(self, listener: can.Listener, exc: Exception) -> None:
        self.failures += 1
        if not self.first_failure:
            self.first_failure = f"{type(listener).__name__}: {exc!r}"
            logger.exception("%s could not take a frame (the frames it cannot take are "
                             "counted)", type(listener).__name__)

    def on_error(self, exc: Exception) -> None:
        for listener in self.listeners:
            with contextlib.suppress(NotImplementedError):
                listener.on_error(exc)

    def stop(self) -> None:
        """The listeners belong to the BusTap, which stops them itself."""


class BusTap:
    """Every frame of ``bus`` to ``listeners`` (a BusMonitor, a log writer) through one
    Notifier. :meth:`stop` stops the Notifier, passes on the frames still queued on the
    bus (the last frames of units that were just shut down) and then stops each listener
    exactly once: the tap is the listeners' one owner (a log writer closed twice fails).
    """

    def __init__(self, bus: can.BusABC, listeners: list[can.Listener]) -> None:
        self.bus = bus
        self._fanout = _Fanout(listeners)
        self._notifier: can.Notifier | None = can.Notifier(bus, [self._fanout], timeout=0.1)

    def stop(self) -> None:
        """Stop listening, drain the bus, stop the listeners. Idempotent."""
        if self._notifier is None:
            return
        notifier, self._notifier = self._notifier, None
        try:
            notifier.stop()
            self._drain()
        finally:
            for listener in self._fanout.listeners:
                listener.stop()

    @property
    def failures(self) -> int:
        """Frames a listener could not take (each logged or counted, never silent)."""
        return self._fanout.failures

    @property
    def first_failure(self) -> str:
        """The first of those failures, as text ('' if none)."""
        return self._fanout.first_failure

    def _drain(self) -> None:
        for _ in range(DRAIN_LIMIT):
            msg = self.bus.recv(timeout=0.0)
            if msg is None:
                return
            self._fanout.on_message_received(msg)


#: the E2E states that count as errors
E2E_ERRORS = (E2EState.WRONG_CRC, E2EState.WRONG_SEQUENCE, E2EState.REPEATED)


def e2e_errors_by_unit(monitor: BusMonitor) -> dict[int, int]:
    """Frames whose E2E check failed (wrong CRC, skipped or repeated), per unit id."""
    errors: dict[int, int] = {}
    for arbitration_id, checker in monitor.checkers.items():
        owner = unit_of(arbitration_id, monitor.base_id)
        if owner is None:
            continue
        counts = checker.counts or {}
        errors[owner[0]] = errors.get(owner[0], 0) + sum(counts.get(s, 0) for s in E2E_ERRORS)
    return errors
