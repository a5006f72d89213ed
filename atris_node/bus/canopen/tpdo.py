"""TPDO transmission of the device: on SYNC and on the event timers, in OPERATIONAL only.

canopen's ``LocalNode`` keeps the TPDO parameters but sends nothing by itself. On each
SYNC the TPDOs of transmission type 0 go out when new values came since they last did,
those of type 1..240 on every n-th SYNC; event-driven ones (254/255) every event timer
(0x180x sub 5) or, when that is 0, every PublishPeriod_ms, never faster than their
inhibit time. Parameters written over SDO are re-read (``tpdo.read(from_od=False)``)
before the next transmission.
"""

from __future__ import annotations

import logging
import math
import threading
from collections.abc import Callable
from typing import Any

import can
import canopen

logger = logging.getLogger(__name__)

LAST_SYNC_TYPE = 240
EVENT_TYPES = (254, 255)


class TpdoService:
    """Sends the enabled TPDOs of ``node`` on ``network``.

    Args:
        node: the device's LocalNode (its TPDO parameters and mapped values).
        network: the canopen Network to send on.
        lock: held while the values are composed and the mapped data copied.
        compose: writes the values as they may go out now into the object dictionary
            (called with ``lock`` held, once per transmission).
        publish_period_ms: PublishPeriod_ms now (event-driven TPDOs without a timer).
        on_recovered: called when a TPDO gets out after sends the bus refused.
    """

    def __init__(self, node: canopen.LocalNode, network: canopen.Network, *,
                 lock: threading.RLock, compose: Callable[[], None],
                 publish_period_ms: Callable[[], int],
                 on_recovered: Callable[[], None]) -> None:
        self.node, self.network, self.lock = node, network, lock
        self.compose, self.publish_period_ms = compose, publish_period_ms
        self.on_recovered = on_recovered
        self.send_errors = 0  # TPDOs the bus refused
        self.frames_sent = 0  # and those it took
        self.dirty = True  # parameters written since the last read
        self.updates = 0  # new values handed over (transmission type 0)
        self._sent_update: dict[int, int] = {}  # COB-ID -> the update it last carried
        self._sync_count = 0
        self._last_event_s: dict[int, float] = {}
        self._bus_trouble = False

    def reset(self) -> None:
        """Communication reset: SYNC counter and event timers start again."""
        self._sync_count = 0
        self._last_event_s.clear()
        self._sent_update.clear()
        self.dirty = True

    def enabled(self) -> list[Any]:
        """The valid TPDOs, their parameters re-read when written since."""
        with self.lock:
            if self.dirty:
                self.dirty = False
                self.node.tpdo.read(from_od=False)
            maps: Any = self.node.tpdo.map
            return [tpdo for tpdo in maps.values() if tpdo.enabled]

    def on_sync(self) -> None:
        """A SYNC arrived (in OPERATIONAL): send the TPDOs due on it."""
        self._sync_count += 1
        self.transmit([tpdo for tpdo in self.enabled() if self._due_on_sync(tpdo)])

    def _due_on_sync(self, tpdo: Any) -> bool:
        kind = tpdo.trans_type
        if kind == 0:
            return self._sent_update.get(tpdo.cob_id, 0) < self.updates
        return bool(kind is not None and kind <= LAST_SYNC_TYPE and self._sync_count % kind == 0)

    def on_time(self, now: float) -> None:
        """Send the event-driven TPDOs whose period has passed at ``now`` (OPERATIONAL)."""
        due = []
        for tpdo in self.enabled():
            period_s = self._event_period_s(tpdo)
            if period_s is None:
                continue
            if now - self._last_event_s.get(tpdo.cob_id, -math.inf) >= period_s:
                self._last_event_s[tpdo.cob_id] = now
                due.append(tpdo)
        self.transmit(due)

    def _event_period_s(self, tpdo: Any) -> float | None:
        """Seconds between sends of an event-driven TPDO: its event timer (ms), else
        PublishPeriod_ms, never less than its inhibit time (100 us); None for the others."""
        if tpdo.trans_type not in EVENT_TYPES:
            return None
        period_ms = tpdo.event_timer or self.publish_period_ms()
        return max(period_ms / 1000.0, (tpdo.inhibit_time or 0) / 10000.0)

    def transmit(self, tpdos: list[Any]) -> None:
        """Send ``tpdos`` in order, their values composed once, now."""
        if not tpdos:
            return
        with self.lock:
            self.compose()
            frames = []
            for tpdo in tpdos:
                for variable in tpdo.map:
                    variable.set_data(self.node.get_data(variable.index, variable.subindex))
                frames.append((tpdo.cob_id, bytes(tpdo.data)))
                self._sent_update[tpdo.cob_id] = self.updates
        for cob_id, data in frames:
            self._send(cob_id, data)

    def _send(self, cob_id: int, data: bytes) -> None:
        try:
            self.network.send_message(cob_id, data)
        except can.CanError as exc:
            logger.error("TPDO 0x%X not sent: %s", cob_id, exc)
            self.send_errors += 1
            self._bus_trouble = True
            return
        self.frames_sent += 1
        if self._bus_trouble:
            self._bus_trouble = False
            self.on_recovered()
