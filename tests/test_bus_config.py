"""Bus configuration in python-can's terms, and bus health from error frames."""

from __future__ import annotations

import time
import uuid

import can
import pytest

from atris_node.bus.can.config import (
    CAN_ERR_BUSOFF,
    CAN_ERR_CRTL,
    BusConfig,
    BusHealth,
    admit_error_frames,
    open_bus,
    resolve,
)
from atris_node.bus.can.frames import FrameCodec
from atris_node.bus.can.publisher import Publisher
from atris_node.bus.negotiation.frames import PREFIX_BITS, PREFIX_MASK
from atris_node.errors import BusError
from atris_node.testing.faultbus import Faults, FaultyBus


def test_virtual_is_the_embedded_default() -> None:
    assert resolve(BusConfig()) == {"interface": "virtual", "channel": "atris"}


def test_given_values_win() -> None:
    config = BusConfig("socketcan", "vcan1", 250000, True)
    assert resolve(config) == {"interface": "socketcan", "channel": "vcan1",
                               "bitrate": 250000, "fd": True}


def test_an_interface_with_a_bit_rate_gets_the_default_one() -> None:
    """500 kbit/s for an interface that has a bit rate, none for a virtual bus; the
    channel of a named interface is its backend's own default (None), ``atris`` only for
    the virtual bus."""
    kwargs = resolve(BusConfig("socketcan"))
    assert kwargs["bitrate"] == 500000 and kwargs["channel"] is None
    assert "bitrate" not in resolve(BusConfig("udp_multicast"))
    assert resolve(BusConfig("virtual")) == {"interface": "virtual", "channel": "atris"}


def test_unknown_interface_is_a_bus_error(monkeypatch: pytest.MonkeyPatch) -> None:
    with pytest.raises(BusError, match="accepted interfaces"):
        open_bus(BusConfig("no-such-interface", "x"))
    monkeypatch.setenv("CAN_INTERFACE", "no-such-interface")
    with pytest.raises(BusError, match=r"no-such-interface.*accepted interfaces"):
        resolve(BusConfig())


def test_bad_can_config_is_a_bus_error(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("CAN_CONFIG", "{not json")
    with pytest.raises(BusError, match="CAN_CONFIG is not a JSON object"):
        resolve(BusConfig())


def test_open_bus_opens_a_virtual_bus() -> None:
    with open_bus(BusConfig(channel=f"cfg-{uuid.uuid4().hex}")) as bus:
        assert isinstance(bus, can.BusABC)


def _error_frame(error_class: int) -> can.Message:
    return can.Message(arbitration_id=error_class, is_error_frame=True, is_extended_id=False,
                       data=bytes(8))


def test_health_counts_error_frames_and_bus_off() -> None:
    health = BusHealth()
    health.on_message_received(can.Message(arbitration_id=0x123, is_extended_id=False))
    assert not health.take_error()
    health.on_message_received(_error_frame(CAN_ERR_CRTL))
    health.on_message_received(_error_frame(CAN_ERR_BUSOFF))
    assert health.error_frames == 2 and health.bus_off_count == 1
    assert health.take_error() and not health.take_error()


@pytest.mark.parametrize("admitted", [False, True])
def test_software_filters_pass_error_frames_once_admitted(admitted: bool) -> None:
    """python-can filters a virtual bus (and FaultyBus) in software, by identifier, so an
    error frame (its identifier is its error class) is dropped by the node's negotiation
    filter unless :func:`admit_error_frames` let it through; other frames still are."""
    channel = f"err-filter-{uuid.uuid4().hex}"
    with can.Bus(interface="virtual", channel=channel) as peer:
        bus = FaultyBus(can.Bus(interface="virtual", channel=channel), Faults())
        try:
            bus.set_filters([{"can_id": PREFIX_BITS, "can_mask": PREFIX_MASK,
                              "extended": True}])
            if admitted:
                admit_error_frames(bus)
                admit_error_frames(bus)  # idempotent
            peer.send(can.Message(arbitration_id=0x123, is_extended_id=False))
            peer.send(_error_frame(CAN_ERR_CRTL))  # a peer's error frame (virtual bus)
            from_peer = _receive_all(bus)
            bus.faults.error_frame_rate = 1.0  # FaultyBus's own bus-off reports
            injected = [bus.recv(timeout=0.05) for _ in range(2)]
        finally:
            bus.shutdown()
    assert [m.arbitration_id for m in from_peer] == ([CAN_ERR_CRTL] if admitted else [])
    assert all(m.is_error_frame for m in from_peer)
    assert all((m is not None) is admitted for m in injected)


def _receive_all(bus: can.BusABC) -> list[can.Message]:
    received = []
    while (msg := bus.recv(timeout=0.05)) is not None:
        received.append(msg)
    return received


def test_publisher_reports_error_frames_in_status() -> None:
    channel = f"err-{uuid.uuid4().hex}"
    health = BusHealth()
    with can.Bus(interface="virtual", channel=channel) as bus, \
            can.Bus(interface="virtual", channel=channel) as peer:
        notifier = can.Notifier(bus, [health], timeout=0.02)
        publisher = Publisher(bus, 3, period_s=0.02, health=health)
        publisher.start()
        peer.send(_error_frame(CAN_ERR_BUSOFF))
        time.sleep(0.15)
        publisher.stop()
        notifier.stop()
        codec = FrameCodec()
        statuses = []
        while (msg := peer.recv(timeout=0.0)) is not None:
            frame = codec.decode_message(msg)
            if frame.name == "Atris3_Status":
                statuses.append(frame.signals["Fault_BusError"])
    assert publisher.stats.bus_off_count == 1
    assert 1 in statuses and statuses[-1] == 0


def test_fd_frames_carry_the_same_payload() -> None:
    channel = f"fd-{uuid.uuid4().hex}"
    with can.Bus(interface="virtual", channel=channel) as bus, \
            can.Bus(interface="virtual", channel=channel) as peer:
        publisher = Publisher(bus, 0, period_s=0.05, fd=True)
        publisher.start()
        msg = peer.recv(timeout=1.0)
        publisher.stop()
    assert msg is not None and msg.is_fd and msg.bitrate_switch and len(msg.data) == 8
    assert FrameCodec().decode_message(msg).crc_ok
