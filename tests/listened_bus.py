"""A sending virtual bus and a listener on a second bus object of the same channel."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

import can


@contextmanager
def listened_bus(channel: str, listener: can.Listener,
                 timeout_s: float = 0.02) -> Iterator[can.BusABC]:
    """The bus a unit sends on; ``listener`` hears every frame on it (its own Notifier).
    Both buses and the Notifier are closed on exit."""
    tx = can.Bus(interface="virtual", channel=channel)
    rx = can.Bus(interface="virtual", channel=channel)
    notifier = can.Notifier(rx, [listener], timeout=timeout_s)
    try:
        yield tx
    finally:
        notifier.stop()
        rx.shutdown()
        tx.shutdown()
