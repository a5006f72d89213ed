"""E2E Profile 1 against AUTOSAR reference values, and the receiver's state machine."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from atris_node.bus.can import e2e
from atris_node.bus.can.e2e import E2EChecker, E2EState
from atris_node.errors import FrameDecodeError

# AUTOSAR SWS CRC Library, CRC8 SAE J1850 check values
J1850_REFERENCE = [
    ("00000000", 0x59), ("F20183", 0x37), ("0FAA0055", 0x79), ("00FF5511", 0xB8),
    ("332255AABBCCDDEEFF", 0xCB), ("926B55", 0x8C), ("FFFFFFFF", 0x74),
]


def test_crc8_sae_j1850_check_value() -> None:
    assert e2e.crc8_sae_j1850(b"123456789") == 0x4B


@pytest.mark.parametrize(("data", "crc"), J1850_REFERENCE)
def test_crc8_sae_j1850_autosar_table(data: str, crc: int) -> None:
    assert e2e.crc8_sae_j1850(bytes.fromhex(data)) == crc


def test_profile1_reference_frames() -> None:
    """AUTOSAR Profile 1 example: data ID 0x123, mode BOTH, 8 zero bytes."""
    assert e2e.protect(bytes(8), 0x123, 0) == bytes.fromhex("cc00000000000000")
    assert e2e.protect(bytes(8), 0x123, 1) == bytes.fromhex("9101000000000000")


def test_protect_keeps_high_nibble_and_payload() -> None:
    frame = e2e.protect(bytes.fromhex("00a0112233445566"), 0x532, 7)
    assert frame[1] == 0xA7 and frame[2:] == bytes.fromhex("112233445566")
    assert frame[0] == e2e.profile1_crc(0x532, frame)


@pytest.mark.parametrize("counter", [-1, 15, 16])
def test_protect_rejects_counter_out_of_range(counter: int) -> None:
    with pytest.raises(FrameDecodeError, match=r"0\.\.14"):
        e2e.protect(bytes(8), 0x500, counter)


def _frames(data_id: int, counters: list[int]) -> list[bytes]:
    return [e2e.protect(bytes(8), data_id, c) for c in counters]


def test_checker_sequence_states() -> None:
    checker = E2EChecker(0x500, timeout_s=0.2)
    frames = _frames(0x500, [0, 1, 1, 4, 5, 14, 0])
    states = [checker.check(f, 0.01 * i) for i, f in enumerate(frames)]
    assert states == [E2EState.INITIAL, E2EState.OK, E2EState.REPEATED,
                      E2EState.WRONG_SEQUENCE, E2EState.OK, E2EState.WRONG_SEQUENCE,
                      E2EState.OK]
    assert checker.counts[E2EState.OK] == 3


def test_checker_wrong_crc_and_wrong_data_id() -> None:
    checker = E2EChecker(0x500)
    frame = bytearray(_frames(0x500, [3])[0])
    frame[5] ^= 0x01
    assert checker.check(bytes(frame), 0.0) is E2EState.WRONG_CRC
    assert checker.check(_frames(0x510, [3])[0], 0.0) is E2EState.WRONG_CRC
    assert checker.check(_frames(0x500, [3])[0], 0.0) is E2EState.INITIAL


def test_checker_counter_15_is_never_valid() -> None:
    frame = bytearray(8)
    frame[1] = 0x0F
    frame[0] = e2e.profile1_crc(0x500, bytes(frame))
    assert E2EChecker(0x500).check(bytes(frame), 0.0) is E2EState.WRONG_SEQUENCE


def test_checker_timeout() -> None:
    checker = E2EChecker(0x500, timeout_s=0.2)
    assert checker.poll(1.0) is None
    checker.check(_frames(0x500, [0])[0], 1.0)
    assert checker.poll(1.15) is None
    assert checker.poll(1.25) is E2EState.TIMEOUT


def test_checker_tolerates_loss_up_to_max_delta() -> None:
    checker = E2EChecker(0x500, max_delta_counter=3)
    states = [checker.check(f, 0.0) for f in _frames(0x500, [13, 1, 5])]
    assert states == [E2EState.INITIAL, E2EState.OK, E2EState.WRONG_SEQUENCE]


@given(st.binary(max_size=16), st.integers(0, 0xFFFF))
def test_checker_never_crashes(data: bytes, data_id: int) -> None:
    assert isinstance(E2EChecker(data_id).check(data, 0.0), E2EState)


@given(st.binary(min_size=2, max_size=64), st.integers(0, 0xFFFF), st.integers(0, 14))
def test_protected_frames_always_check(data: bytes, data_id: int, counter: int) -> None:
    assert E2EChecker(data_id).check(e2e.protect(data, data_id, counter), 0.0).valid
