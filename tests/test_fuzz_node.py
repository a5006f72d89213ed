"""A running unit fed malformed frames keeps running: random identifiers and payloads
(its own frame IDs, other units', negotiation IDs, error and remote frames) arrive from a
second node on the bus while the unit measures; afterwards ``check()`` passes and it
still publishes every cycle.
"""

from __future__ import annotations

import collections
import time
from collections.abc import Iterator

import can
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from atris_node import config as cfg
from atris_node.bus.can.ids import FrameKind, frame_id, unit_of
from atris_node.bus.negotiation import frames as nf
from atris_node.node.unit import Unit

EXAMPLES = 300
COUNTS: collections.Counter[str] = collections.Counter()

negotiation_ids = st.builds(
    lambda kind, reserved, unit, field: nf.make_id(kind, nf.Identity(unit), field) | reserved,
    st.sampled_from(list(nf.FrameKind)), st.sampled_from([0, 0x10, nf.RESERVED_MASK]),
    st.integers(0, 15),
    st.integers(0, nf.MAX_FIELD))
unit_ids = st.builds(frame_id, st.integers(0, 15), st.sampled_from(list(FrameKind)))
frames = st.builds(
    lambda can_id, data, error, remote: can.Message(
        arbitration_id=can_id, data=b"" if remote else data, is_extended_id=can_id > 0x7FF,
        is_error_frame=error, is_remote_frame=remote, dlc=len(data)),
    st.one_of(negotiation_ids, unit_ids, st.integers(0, 0x7FF), st.integers(0, 0x1FFFFFFF)),
    st.binary(max_size=8), st.integers(0, 9).map(lambda n: n == 0),
    st.integers(0, 9).map(lambda n: n == 0))


class StatusCount(can.Listener):
    """Arrival times of unit 0's status frames."""

    def __init__(self) -> None:
        self.times: list[float] = []

    def on_message_received(self, msg: can.Message) -> None:
        found = None if msg.is_extended_id else unit_of(msg.arbitration_id)
        if found == (0, FrameKind.STATUS):
            self.times.append(time.monotonic())

    def on_error(self, exc: Exception) -> None:
        raise exc


@pytest.fixture
def running_unit(request: pytest.FixtureRequest) -> Iterator[tuple[Unit, can.BusABC,
                                                                    StatusCount]]:
    channel = f"fuzz-node-{request.node.name}"
    unit_bus = can.Bus(interface="virtual", channel=channel)
    fuzz_bus = can.Bus(interface="virtual", channel=channel)
    watch_bus = can.Bus(interface="virtual", channel=channel)
    status = StatusCount()
    notifier = can.Notifier(watch_bus, [status], timeout=0.01)
    overrides = ["code.length=8", "negotiation.window_s=0.1", "negotiation.reannounce_s=0.5",
                 "negotiation.silence_timeout_s=1.5"]
    unit = Unit(cfg.load(environ={}, overrides=overrides), unit_bus)
    unit.configure()
    unit.activate(threaded=True)
    try:
        yield unit, fuzz_bus, status
    finally:
        unit.shutdown()
        notifier.stop()
        for bus in (unit_bus, fuzz_bus, watch_bus):
            bus.shutdown()


def test_running_unit_survives_malformed_frames(
        running_unit: tuple[Unit, can.BusABC, StatusCount]) -> None:
    unit, fuzz_bus, status = running_unit
    deadline = time.monotonic() + 10.0
    while unit.stats.measurements < 2:
        assert time.monotonic() < deadline, "the unit did not start measuring"
        time.sleep(0.02)

    @settings(max_examples=EXAMPLES, deadline=None, derandomize=True,
              suppress_health_check=[HealthCheck.too_slow])
    @given(st.lists(frames, min_size=1, max_size=30))
    def feed(batch: list[can.Message]) -> None:
        for msg in batch:
            fuzz_bus.send(msg)
            COUNTS["frames"] += 1
        COUNTS["examples"] += 1
        unit.check()

    feed()
    end_of_fuzz = time.monotonic()
    time.sleep(0.6)
    unit.check()
    period_s = float(unit.config["publish.period_s"])
    after = [t for t in status.times if t > end_of_fuzz]
    assert len(after) >= 0.6 / period_s * 0.6, f"only {len(after)} status frames after the fuzz"
    assert unit.lifecycle == "active" and unit.stats.sub_frames > 0
    negotiator = unit.negotiator
    assert negotiator.malformed_frames > 0, "no malformed frame reached the negotiator"
    print(f"\nfuzz examples: {dict(COUNTS)}, malformed negotiation frames counted "
          f"{negotiator.malformed_frames}")
