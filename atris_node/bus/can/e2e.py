"""AUTOSAR E2E Profile 1 protection and the receiver-side checker.

Layout (E2E Profile 1, data ID mode BOTH, CRC offset 0, counter offset 8): byte 0 is the
CRC-8 SAE J1850 (poly 0x1D) over the data ID low byte, the data ID high byte and payload
bytes 1..n-1; the low nibble of byte 1 is the alive counter 0..14 (15 is never sent).

Profile 1 calls the AUTOSAR CRC library's ``Crc_CalculateCRC8`` (init 0xFF, xor-out 0xFF)
with start value 0xFF and "not first call", which undoes the library's init and xor-out:
the CRC that ends up in byte 0 is the J1850 polynomial with start 0x00 and no final XOR.
:func:`profile1_crc` reproduces that call sequence, so it matches AUTOSAR's reference
values (data ID 0x123, zero payload: 0xCC with counter 0, 0x91 with counter 1).

The data ID of each message is the ``E2EDataID`` attribute of the DBC, so any receiver
can check a frame from the DBC alone.
"""

from __future__ import annotations

import enum
import logging
from dataclasses import dataclass, field

from atris_node.errors import FrameDecodeError

logger = logging.getLogger(__name__)

CRC8_POLY = 0x1D
CRC8_INIT = 0xFF
CRC8_XOR_OUT = 0xFF
#: the alive counter runs 0..14 and wraps to 0
COUNTER_MODULO = 15


def _crc8_table() -> tuple[int, ...]:
    table = []
    for byte in range(256):
        crc = byte
        for _ in range(8):
            crc = ((crc << 1) ^ CRC8_POLY) & 0xFF if crc & 0x80 else (crc << 1) & 0xFF
        table.append(crc)
    return tuple(table)


_TABLE = _crc8_table()


def crc8_sae_j1850(data: bytes, start: int = CRC8_INIT) -> int:
    """CRC-8 SAE J1850 of ``data`` (0..255); ``crc8_sae_j1850(b"123456789") == 0x4B``."""
    crc = start
    for byte in data:
        crc = _TABLE[crc ^ byte]
    return crc ^ CRC8_XOR_OUT


def profile1_crc(data_id: int, data: bytes) -> int:
    """E2E Profile 1 CRC of frame ``data`` (its byte 0, the CRC itself, is skipped)."""
    if not 0 <= data_id <= 0xFFFF:
        raise FrameDecodeError(f"E2E data ID must be 0..0xFFFF, got {data_id}")
    covered = bytes((data_id & 0xFF, data_id >> 8)) + bytes(data[1:])
    # Crc_CalculateCRC8(..., start=0xFF, first=False) starts from 0xFF ^ 0xFF = 0x00, and
    # Profile 1 XORs the library's result with 0xFF once more.
    return crc8_sae_j1850(covered, start=CRC8_INIT ^ CRC8_XOR_OUT) ^ CRC8_XOR_OUT


def counter_of(data: bytes) -> int:
    """Alive counter of a protected frame (low nibble of byte 1)."""
    return data[1] & 0x0F


def protect(data: bytes, data_id: int, counter: int) -> bytes:
    """``data`` (at least 2 bytes) with ``counter`` (0..14) and the CRC written in."""
    if len(data) < 2:
        raise FrameDecodeError(f"an E2E frame needs at least 2 bytes, got {len(data)}")
    if not 0 <= counter < COUNTER_MODULO:
        raise FrameDecodeError(f"E2E counter must be 0..14, got {counter}")
    out = bytearray(data)
    out[1] = (out[1] & 0xF0) | counter
    out[0] = profile1_crc(data_id, bytes(out))
    return bytes(out)


class E2EState(enum.Enum):
    """Receiver verdict on one frame (AUTOSAR E2E_P01CheckStatusType, in plain words)."""

    OK = "ok"
    INITIAL = "initial"  # first valid frame: nothing to compare the counter with
    REPEATED = "repeated"  # same counter as the last valid frame
    WRONG_SEQUENCE = "skipped"  # counter jumped by more than max_delta_counter, or 15
    WRONG_CRC = "wrong_crc"
    TIMEOUT = "timeout"  # no new frame within timeout_s

    @property
    def valid(self) -> bool:
        """True when the frame's content may be used."""
        return self in (E2EState.OK, E2EState.INITIAL)


@dataclass
class E2EChecker:
    """State machine of one receiver for one message (one data ID).

    ``check(data, now_s)`` classifies a received frame; ``poll(now_s)`` answers TIMEOUT
    when nothing new arrived for ``timeout_s`` seconds. Counts of each verdict are kept
    in ``counts``.
    """

    data_id: int
    timeout_s: float = 0.2
    max_delta_counter: int = 1
    last_counter: int | None = None
    last_time_s: float | None = None
    counts: dict[E2EState, int] = field(default_factory=lambda: dict.fromkeys(E2EState, 0))

    def check(self, data: bytes, now_s: float) -> E2EState:
        """Classify one received frame ``data`` that arrived at ``now_s`` (seconds)."""
        state = self._classify(bytes(data))
        if state is not E2EState.WRONG_CRC:
            self.last_counter = counter_of(data)
            self.last_time_s = now_s
        self._count(state)
        return state

    def poll(self, now_s: float) -> E2EState | None:
        """TIMEOUT when the last good frame is older than ``timeout_s``, else None."""
        if self.last_time_s is None or now_s - self.last_time_s <= self.timeout_s:
            return None
        return E2EState.TIMEOUT

    def _classify(self, data: bytes) -> E2EState:
        if len(data) < 2 or data[0] != profile1_crc(self.data_id, data):
            return E2EState.WRONG_CRC
        counter = counter_of(data)
        if counter >= COUNTER_MODULO:
            return E2EState.WRONG_SEQUENCE
        if self.last_counter is None:
            return E2EState.INITIAL
        delta = (counter - self.last_counter) % COUNTER_MODULO
        if delta == 0:
            return E2EState.REPEATED
        return E2EState.OK if delta <= self.max_delta_counter else E2EState.WRONG_SEQUENCE

    def _count(self, state: E2EState) -> None:
        self.counts[state] += 1
        if not state.valid:
            logger.debug("E2E data ID 0x%04X: %s", self.data_id, state.value)
