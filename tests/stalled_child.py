"""Children for the map process that stall halfway through the pipe protocol, as a child
stopped (SIGSTOP) or wedged at the wrong moment does. A test puts one in place of
``atris_node.node.mapprocess.serve``; the spawned child imports it from here."""

from __future__ import annotations

import os
import signal
import struct
import time
from multiprocessing.connection import Connection
from typing import Any

import numpy as np


def _wait_for_ever() -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    while True:
        time.sleep(3600.0)


def answers_half(conn: Connection, parts: Any, map_name: str) -> None:
    """Ready; at the first map, the first 1000 bytes of a 1 MB answer, then nothing: the
    unit's poll sees bytes, its ``recv`` waits for the rest. (A Connection message is a
    4-byte big-endian length, then the pickled bytes.)"""
    conn.send(("ready", None))
    conn.recv()
    fd = conn.fileno()
    chunk = struct.pack("!i", 1 << 20) + bytes(1000)
    while chunk:
        chunk = chunk[os.write(fd, chunk):]
    _wait_for_ever()


def asks_and_stops_reading(conn: Connection, parts: Any, map_name: str) -> None:
    """Ready; at the first map, asks for the window's values at every pixel (the unit's
    answer is megabytes, more than the pipe's buffer), then reads nothing more."""
    conn.send(("ready", None))
    notice = conn.recv()
    height, width = notice.shape
    conn.send(("series", np.arange(height * width, dtype=np.int64)))
    _wait_for_ever()
