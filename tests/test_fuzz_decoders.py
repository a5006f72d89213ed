"""Fuzzing the bus decoders: every byte string gives a result or an AtrisError, nothing else.

Targets: the DBC frame codec (``FrameCodec.decode`` / ``decode_message``), the negotiation
identifier and payload decoders, and the E2E receiver state machine. The number of
examples tried per target is printed at the end of the module (``pytest -s``) and kept in
docs/reliability.md.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Iterator
from typing import Any

import can
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from atris_node.bus.can.e2e import E2EChecker, E2EState
from atris_node.bus.can.frames import FrameCodec
from atris_node.bus.can.ids import FrameKind, frame_id
from atris_node.bus.negotiation import frames as nf
from atris_node.testing.fuzz import FuzzTally

TALLY = FuzzTally()
settle = TALLY.settle
CODEC = FrameCodec()
FAST = settings(max_examples=2000, deadline=None, derandomize=True,
                suppress_health_check=[HealthCheck.too_slow])
UNIT_IDS = [frame_id(u, k) for u in range(16) for k in FrameKind]
NEGOTIATION_IDS = [nf.make_id(kind, nf.Identity(unit), field) | reserved
                   for kind in nf.FrameKind for reserved in (0, nf.RESERVED_MASK)
                   for unit in (0, 15) for field in (0, 1, 2, 127)]


@pytest.fixture(scope="module", autouse=True)
def report_counts() -> Iterator[None]:
    yield
    print("\n" + TALLY.report())


def finite_signals(signals: dict[str, Any]) -> None:
    """No NaN or inf leaves a decoder."""
    for name, signal in signals.items():
        assert not isinstance(signal, float) or math.isfinite(signal), name


@FAST
@given(st.integers(0, 0x1FFFFFFF), st.binary(max_size=64), st.booleans())
def test_decode_any_identifier_and_payload(can_id: int, data: bytes, extended: bool) -> None:
    decoded = settle("FrameCodec.decode (any ID)", lambda: CODEC.decode(can_id, data, extended))
    if decoded is not None:
        finite_signals(decoded.signals)


@FAST
@given(st.sampled_from(UNIT_IDS + NEGOTIATION_IDS), st.binary(min_size=0, max_size=8),
       st.booleans(), st.booleans())
def test_decode_message_of_known_identifiers(can_id: int, data: bytes, extended: bool,
                                             fd: bool) -> None:
    msg = can.Message(arbitration_id=can_id, data=data, is_extended_id=extended or can_id > 0x7FF,
                      is_fd=fd)
    decoded = settle("FrameCodec.decode_message (DBC IDs)", lambda: CODEC.decode_message(msg))
    if decoded is not None:
        assert decoded.name and decoded.arbitration_id == can_id
        finite_signals(decoded.signals)


@FAST
@given(st.integers(0, 0x1FFFFFFF))
def test_parse_negotiation_identifier(can_id: int) -> None:
    header = settle("negotiation parse_id", lambda: nf.parse_id(can_id))
    if header is not None:
        assert nf.make_id(header.kind, header.identity, header.field) == can_id


@FAST
@given(st.sampled_from(["decode_name", "decode_plan", "decode_sync"]), st.binary(max_size=16))
def test_negotiation_payload_decoders(decoder: str, data: bytes) -> None:
    settle(f"negotiation {decoder}", lambda: getattr(nf, decoder)(data))


@settings(max_examples=500, deadline=None, derandomize=True)
@given(st.lists(st.tuples(st.binary(max_size=10), st.floats(0.0, 1e6)), max_size=40),
       st.integers(0, 0xFFFF))
def test_e2e_checker_on_any_sequence_of_payloads(frames: list[tuple[bytes, float]],
                                                 data_id: int) -> None:
    checker = E2EChecker(data_id)
    for data, now_s in frames:
        check = functools.partial(checker.check, data, now_s)
        state = settle("E2EChecker.check (per frame)", check)
        assert isinstance(state, E2EState)
        assert checker.poll(now_s + 1.0) in (None, E2EState.TIMEOUT)
    assert sum(checker.counts.values()) == len(frames)
