"""Bus faults: every fault the wrapper injects is flagged by the E2E checker."""

from __future__ import annotations

import time
from collections.abc import Iterator

import can
import pytest

from atris_node.bus.can.e2e import COUNTER_MODULO, E2EChecker, E2EState, protect
from atris_node.testing.faultbus import Babbler, Faults, FaultyBus

DATA_ID = 0x0123
FRAMES = 600


@pytest.fixture
def pair(request: pytest.FixtureRequest) -> Iterator[tuple[can.BusABC, FaultyBus]]:
    channel = f"faults-{request.node.name}"
    tx = can.Bus(interface="virtual", channel=channel)
    rx = FaultyBus(can.Bus(interface="virtual", channel=channel), Faults(), seed=3)
    yield tx, rx
    tx.shutdown()
    rx.shutdown()


def _send_sequence(tx: can.BusABC, count: int) -> None:
    for i in range(count):
        payload = protect(bytes([0, 0, i & 0xFF, 1, 2, 3, 4, 5]), DATA_ID, i % COUNTER_MODULO)
        tx.send(can.Message(arbitration_id=0x501, data=payload, is_extended_id=False))


def _receive_all(rx: can.BusABC, checker: E2EChecker) -> list[E2EState]:
    states = []
    while (msg := rx.recv(timeout=0.05)) is not None:
        states.append(checker.check(bytes(msg.data), time.monotonic()))
    return states


def _flags(states: list[E2EState], kind: E2EState) -> int:
    return sum(1 for s in states if s is kind)


def test_clean_bus_gives_no_flags(pair: tuple[can.BusABC, FaultyBus]) -> None:
    tx, rx = pair
    _send_sequence(tx, FRAMES)
    states = _receive_all(rx, E2EChecker(DATA_ID))
    assert len(states) == FRAMES
    assert states[0] is E2EState.INITIAL
    assert all(s is E2EState.OK for s in states[1:])


def test_every_corrupted_frame_is_wrong_crc(pair: tuple[can.BusABC, FaultyBus]) -> None:
    tx, rx = pair
    rx.faults.corrupt_rx = 0.1
    _send_sequence(tx, FRAMES)
    states = _receive_all(rx, E2EChecker(DATA_ID))
    assert rx.counts.corrupted > 20
    assert _flags(states, E2EState.WRONG_CRC) == rx.counts.corrupted


def test_every_duplicate_is_repeated(pair: tuple[can.BusABC, FaultyBus]) -> None:
    tx, rx = pair
    rx.faults.duplicate_rx = 0.1
    _send_sequence(tx, FRAMES)
    states = _receive_all(rx, E2EChecker(DATA_ID))
    assert rx.counts.duplicated > 20
    assert _flags(states, E2EState.REPEATED) == rx.counts.duplicated


def test_every_drop_is_a_skipped_sequence(pair: tuple[can.BusABC, FaultyBus]) -> None:
    tx, rx = pair
    rx.faults.drop_rx = 0.05
    _send_sequence(tx, FRAMES)
    states = _receive_all(rx, E2EChecker(DATA_ID))
    assert rx.counts.dropped_rx > 10
    # consecutive drops make one jump; a run of 14 or more could alias, not at this rate
    assert 0 < _flags(states, E2EState.WRONG_SEQUENCE) <= rx.counts.dropped_rx
    assert len(states) == FRAMES - rx.counts.dropped_rx


def test_every_reordered_frame_is_flagged(pair: tuple[can.BusABC, FaultyBus]) -> None:
    tx, rx = pair
    rx.faults.reorder_rx = 0.05
    _send_sequence(tx, FRAMES)
    checker = E2EChecker(DATA_ID)
    counters, states = [], []
    while (msg := rx.recv(timeout=0.05)) is not None:
        counters.append(msg.data[1] & 0x0F)
        states.append(checker.check(bytes(msg.data), time.monotonic()))
    out_of_order = [i for i in range(1, len(counters))
                    if counters[i] != (counters[i - 1] + 1) % COUNTER_MODULO]
    flagged = [i for i, s in enumerate(states) if s is E2EState.WRONG_SEQUENCE]
    assert rx.counts.reordered > 10
    assert len(out_of_order) >= 2 * rx.counts.reordered
    assert flagged == out_of_order


def test_silence_is_a_timeout() -> None:
    checker = E2EChecker(DATA_ID, timeout_s=0.1)
    checker.check(protect(bytes(8), DATA_ID, 0), now_s=10.0)
    assert checker.poll(10.05) is None
    assert checker.poll(10.2) is E2EState.TIMEOUT


def test_bus_off_fails_sends_and_error_frames_arrive(pair: tuple[can.BusABC, FaultyBus]) -> None:
    _, rx = pair
    rx.faults.bus_off = True
    with pytest.raises(can.CanOperationError, match="bus-off"):
        rx.send(can.Message(arbitration_id=0x10, data=b"\x00"))
    assert rx.counts.failed_sends == 1
    rx.faults.error_frame_rate = 1.0
    msg = rx.recv(timeout=0.1)
    assert msg is not None and msg.is_error_frame


def test_babbler_sends_at_its_rate_and_stops() -> None:
    tx = can.Bus(interface="virtual", channel="babble")
    rx = can.Bus(interface="virtual", channel="babble")
    babbler = Babbler(tx, rate_hz=500.0).start()
    time.sleep(0.3)
    babbler.stop()
    tx.shutdown()
    received = 0
    while rx.recv(timeout=0.0) is not None:
        received += 1
    rx.shutdown()
    assert babbler.errors == 0
    assert received == babbler.sent and 50 < babbler.sent < 200
