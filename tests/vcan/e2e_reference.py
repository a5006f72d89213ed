"""An E2E Profile 1 checker written from the AUTOSAR specification, independent of atris_node.

E2E_P01Protect computes, with the CRC library's ``Crc_CalculateCRC8`` (SAE J1850: poly
0x1D, init 0xFF, xor-out 0xFF, no reflection), the chain

    crc = Crc_CalculateCRC8(&DataID_low, 1, 0xFF, FALSE)
    crc = Crc_CalculateCRC8(&DataID_high, 1, crc, FALSE)
    crc = Crc_CalculateCRC8(&Data[1], len - 1, crc, FALSE)
    Data[0] = crc ^ 0xFF

and writes the alive counter 0..14 into the low nibble of byte 1 (counter offset 8).
This module models that chain literally, bit by bit, so a bug in the table-driven
implementation of the node cannot hide in a shared helper.
"""

from __future__ import annotations

from dataclasses import dataclass, field

J1850_POLY = 0x1D
COUNTER_WRAP = 15


def crc_calculate_crc8(data: bytes, start_value: int, is_first_call: bool) -> int:
    """AUTOSAR ``Crc_CalculateCRC8`` (SAE J1850), computed bit by bit."""
    crc = 0xFF if is_first_call else start_value ^ 0xFF
    for byte in data:
        crc ^= byte
        for _ in range(8):
            crc = ((crc << 1) ^ J1850_POLY) & 0xFF if crc & 0x80 else (crc << 1) & 0xFF
    return crc ^ 0xFF


def p01_crc(data_id: int, data: bytes) -> int:
    """The CRC E2E_P01Protect writes into byte 0 of ``data`` (data ID mode BOTH)."""
    crc = crc_calculate_crc8(bytes([data_id & 0xFF]), 0xFF, False)
    crc = crc_calculate_crc8(bytes([data_id >> 8]), crc, False)
    crc = crc_calculate_crc8(bytes(data[1:]), crc, False)
    return crc ^ 0xFF


@dataclass
class P01Receiver:
    """Receiver state of one message: CRC, then the alive counter against the last one.

    ``check`` answers ``"ok"``, ``"initial"``, ``"repeated"``, ``"wrong_sequence"``,
    ``"wrong_crc"``; a gap longer than ``timeout_s`` between frames is counted in
    ``timeouts`` and the next counter starts a new sequence (``"initial"``).
    """

    data_id: int
    timeout_s: float = 0.2
    last_counter: int | None = None
    last_time_s: float | None = None
    timeouts: int = 0
    verdicts: list[str] = field(default_factory=list)

    def check(self, data: bytes, time_s: float) -> str:
        verdict = self._classify(bytes(data), time_s)
        if verdict != "wrong_crc":
            self.last_counter, self.last_time_s = data[1] & 0x0F, time_s
        self.verdicts.append(verdict)
        return verdict

    def _classify(self, data: bytes, time_s: float) -> str:
        if data[0] != p01_crc(self.data_id, data):
            return "wrong_crc"
        if self.last_time_s is not None and time_s - self.last_time_s > self.timeout_s:
            self.timeouts += 1
            self.last_counter = None
        counter = data[1] & 0x0F
        if counter >= COUNTER_WRAP:
            return "wrong_sequence"
        if self.last_counter is None:
            return "initial"
        delta = (counter - self.last_counter) % COUNTER_WRAP
        return {0: "repeated", 1: "ok"}.get(delta, "wrong_sequence")
