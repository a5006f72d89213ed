"""A starved receive thread must not let a unit strobe over a claim it has not read yet.

The contest window only protects a code if every frame received during it was handled. On
SocketCAN the negotiator polls the bus socket before it promotes a claim; here the socket is
a pipe the test fills ("frames wait unread") on a real python-can virtual bus, because this
machine's kernel has no CAN (the same path runs on vcan0 in tests/vcan). Frames are handed
to the negotiator by hand, as a receive thread that finally gets the CPU would.
"""

from __future__ import annotations

import itertools
import os
import time
from collections.abc import Iterator

import can
import pytest
from can.interfaces.virtual import VirtualBus

from atris_node.bus.negotiation import frames as nf
from atris_node.bus.negotiation.machine import NegotiationState, Negotiator
from atris_node.bus.negotiation.plan import Plan
from atris_node.bus.negotiation.rx import ReceiveBarrier, bus_descriptor

PLAN = Plan(code_length=16, chip_rate_hz=480.0)
_channels = itertools.count()


class SocketLikeBus(VirtualBus):
    """A virtual bus with a pollable descriptor: a pipe standing in for the CAN socket."""

    def __init__(self, channel: str) -> None:
        super().__init__(channel=channel)
        self.read_end, self.write_end = os.pipe()

    def fileno(self) -> int:
        return self.read_end

    def frame_waits(self) -> None:
        os.write(self.write_end, b"f")

    def frame_read(self) -> None:
        os.read(self.read_end, 1)

    def shutdown(self) -> None:
        os.close(self.read_end)
        os.close(self.write_end)
        super().shutdown()


class Rig:
    """One negotiator on ``bus`` with a fake clock; frames reach it only through ``hand``."""

    def __init__(self, bus: can.BusABC) -> None:
        self.t = [0.0]
        self.bus = bus
        self.quiet = can.Bus(interface="virtual", channel=f"rx-quiet-{next(_channels)}")
        self.notifier = can.Notifier(self.quiet, [])
        self.unit = Negotiator(bus, name=0x20, plan=PLAN, unit_id=2,
                               clock=lambda: self.t[0], notifier=self.notifier)

    def run_until(self, end_s: float, step_s: float = 0.02) -> None:
        while self.t[0] < end_s - 1e-9:
            self.t[0] = round(self.t[0] + step_s, 6)
            self.unit.tick()

    def hand(self, frame: nf.RawFrame, stamp_s: float) -> None:
        msg = can.Message(arbitration_id=frame.can_id, data=frame.data, is_extended_id=True,
                          timestamp=stamp_s)
        self.unit.on_message(msg, self.t[0])

    def strobed_row(self, row: int) -> bool:
        return any(may and r == row for _, may, r in self.unit.timeline)

    def close(self) -> None:
        self.unit.stop()
        self.notifier.stop()
        self.quiet.shutdown()
        self.bus.shutdown()


@pytest.fixture
def socket_rig() -> Iterator[Rig]:
    rig = Rig(SocketLikeBus(f"rx-{next(_channels)}"))
    yield rig
    rig.close()


@pytest.fixture
def plain_rig() -> Iterator[Rig]:
    rig = Rig(can.Bus(interface="virtual", channel=f"rx-{next(_channels)}"))
    yield rig
    rig.close()


def lower_name_claim(row: int) -> nf.RawFrame:
    return nf.encode_claim(0x10, 1, row)


def test_the_hazard_a_claim_handled_after_the_window_lets_both_strobe(plain_rig: Rig) -> None:
    """Without a socket to poll, a claim handled late comes after the unit strobed: this is
    what the barrier prevents where the bus has a socket."""
    plain_rig.unit.start()
    plain_rig.run_until(0.2)
    assert plain_rig.unit.code_row == 2
    sent_s = time.time()
    plain_rig.run_until(0.6)  # the lower NAME's claim sits unread all this time
    plain_rig.hand(lower_name_claim(2), sent_s)
    assert plain_rig.strobed_row(2)
    assert plain_rig.unit.code_row != 2


def test_a_claim_unread_in_the_socket_is_handled_before_the_unit_strobes(
        socket_rig: Rig) -> None:
    socket_rig.unit.start()
    socket_rig.run_until(0.2)
    assert socket_rig.unit.code_row == 2
    socket_rig.bus.frame_waits()  # type: ignore[attr-defined]
    sent_s = time.time()
    socket_rig.run_until(1.5)
    assert socket_rig.unit.state is NegotiationState.CLAIMING
    assert not socket_rig.strobed_row(2)
    assert socket_rig.unit.receive.deferrals > 0
    socket_rig.bus.frame_read()  # type: ignore[attr-defined]
    socket_rig.hand(lower_name_claim(2), sent_s)
    assert socket_rig.unit.code_row != 2
    socket_rig.run_until(2.0)
    assert socket_rig.unit.may_strobe and socket_rig.unit.code_row != 2
    assert not socket_rig.strobed_row(2)


def test_listening_ends_only_after_the_frames_heard_meanwhile_are_handled(
        socket_rig: Rig) -> None:
    socket_rig.unit.start()
    socket_rig.bus.frame_waits()  # type: ignore[attr-defined]
    sent_s = time.time()
    socket_rig.run_until(0.5)
    assert socket_rig.unit.code_row is None  # still listening: no row chosen blind
    socket_rig.bus.frame_read()  # type: ignore[attr-defined]
    socket_rig.hand(lower_name_claim(2), sent_s)
    socket_rig.run_until(0.54)
    assert socket_rig.unit.code_row == 3  # row 2 is known to be taken


def test_under_steady_traffic_a_frame_newer_than_the_barrier_releases_it(
        socket_rig: Rig) -> None:
    """A busy bus keeps the socket readable; handling a frame stamped after the barrier
    shows everything that waited before it was handled (frames are handled in order)."""
    socket_rig.unit.start()
    socket_rig.run_until(0.2)
    socket_rig.bus.frame_waits()  # type: ignore[attr-defined]
    socket_rig.run_until(0.5)
    assert not socket_rig.unit.may_strobe
    other = nf.encode_claim(0x40, 4, 5)
    socket_rig.hand(other, time.time() + 1e-3)
    socket_rig.run_until(0.54)
    assert socket_rig.unit.may_strobe and socket_rig.unit.code_row == 2


def test_barrier_without_a_descriptor_always_passes() -> None:
    barrier = ReceiveBarrier(None)
    assert barrier.caught_up() and barrier.deferrals == 0


def test_virtual_bus_has_no_descriptor_and_a_closed_socket_counts_as_drained() -> None:
    bus = can.Bus(interface="virtual", channel=f"rx-{next(_channels)}")
    try:
        assert bus_descriptor(bus) is None
    finally:
        bus.shutdown()
    read_end, write_end = os.pipe()
    os.write(write_end, b"f")
    barrier = ReceiveBarrier(read_end)
    assert not barrier.caught_up()
    os.close(read_end)
    os.close(write_end)
    assert barrier.caught_up()
