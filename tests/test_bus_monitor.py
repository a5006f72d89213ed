"""The monitor on a recorded exchange, and ``cantools decode`` on the log it writes."""

from __future__ import annotations

import json
import subprocess
import sys
import time
import uuid
from pathlib import Path

import can
import cantools
import pytest
from unit_frames import measurement, status

from atris_node.bus.can.frames import FrameCodec, dbc_text
from atris_node.bus.can.ids import unit_of
from atris_node.bus.can.monitor import BusMonitor, render_table
from atris_node.bus.can.publisher import Publisher
from atris_node.cli import main

EXTRA_MESSAGE = """
BO_ 2566879955 Other_Claim: 8 Atris0
 SG_ CodeRow : 0|8@1+ (1,0) [0|255] "" Controller
"""




def _record(path: Path, channel: str, duration_s: float) -> None:
    """Two units publishing on a virtual bus, recorded with can.Logger while they run (the
    final STOPPED cycles of their stop() are not part of the recording)."""
    with can.Bus(interface="virtual", channel=channel) as rx, \
            can.Bus(interface="virtual", channel=channel) as tx:
        logger = can.Logger(str(path))
        notifier = can.Notifier(rx, [logger], timeout=0.05)
        publishers = [Publisher(tx, unit, period_s=0.02, max_age_s=5.0) for unit in (1, 4)]
        for unit, publisher in zip((1, 4), publishers, strict=True):
            publisher.update(measurement(unit), status(unit + 1))
            publisher.start()
        time.sleep(duration_s)
        notifier.stop()
        logger.stop()
        for publisher in publishers:
            publisher.stop()


def test_monitor_decodes_a_recorded_exchange(tmp_path: Path) -> None:
    path = tmp_path / "exchange.log"
    _record(path, f"mon-{uuid.uuid4().hex}", 0.3)
    frames = list(can.LogReader(str(path)))
    corrupted = can.Message(arbitration_id=frames[5].arbitration_id, is_extended_id=False,
                            data=bytes([frames[5].data[0] ^ 0xFF, *frames[5].data[1:]]),
                            timestamp=frames[-1].timestamp + 0.001)
    monitor = BusMonitor()
    unknown = can.Message(arbitration_id=0x7FF, is_extended_id=False, data=bytes(2))
    for msg in [*frames, corrupted, unknown]:
        monitor.feed(msg)
    snapshot = monitor.snapshot()
    assert set(snapshot["units"]) == {"1", "4"}
    unit4 = snapshot["units"]["4"]
    assert unit4["state"] == "RUNNING" and unit4["code_row"] == 5
    assert [s[1] for s in unit4["sectors"]] == [4.0, 5.0, 6.0, 7.0]
    assert unit4["nearest"]["Distance"] == 4.0 and unit4["nearest"]["Valid"] == 1
    fed = [m.timestamp for m in [*frames, corrupted]
           if (owner := unit_of(m.arbitration_id)) is not None and owner[0] == 4]
    assert len(fed) > 2  # the rate is the unit's frames over their own time span
    assert unit4["rate_hz"] == pytest.approx((len(fed) - 1) / (fed[-1] - fed[0]), abs=0.05)
    owner = unit_of(corrupted.arbitration_id)
    assert owner is not None
    e2e = snapshot["units"][str(owner[0])]["e2e"][owner[1].suffix]
    assert e2e["state"] == "wrong_crc" and e2e["counts"]["ok"] > 5
    assert snapshot["unknown_frames"] == 1
    assert "RUNNING" in render_table(snapshot)
    later = monitor.snapshot(frames[-1].timestamp + 1.0)
    assert all(v["state"] == "timeout" for v in later["units"]["1"]["e2e"].values())


def test_monitor_shows_non_unit_messages_generically() -> None:
    db = cantools.database.load_string(dbc_text() + EXTRA_MESSAGE, database_format="dbc")
    monitor = BusMonitor(FrameCodec(db))
    for _ in range(2):
        monitor.feed(can.Message(arbitration_id=0x18FF7AD3, is_extended_id=True,
                                 data=bytes([7, 0, 0, 0, 0, 0, 0, 0])))
    monitor.feed(can.Message(arbitration_id=0x18FF0000, is_extended_id=True, data=bytes(8)))
    snapshot = monitor.snapshot()
    claim = snapshot["others"]["Other_Claim"]
    assert claim["last"] == {"CodeRow": 7} and claim["count"] == 2 and claim["id"] == "0x18FF7AD3"
    assert snapshot["unknown_frames"] == 1


def test_atris_monitor_log_is_read_by_cantools_decode(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    channel, log = f"cli-{uuid.uuid4().hex}", tmp_path / "monitor.log"
    with can.Bus(interface="virtual", channel=channel) as tx:
        # the data must stay fresh while the monitor starts and listens: with the 0.2 s
        # default a loaded machine saw only frames sent after it aged (invalid, FAULT)
        publisher = Publisher(tx, 7, period_s=0.02, max_age_s=30.0)
        publisher.update(measurement(2.0), status(9))
        publisher.start()
        try:
            code = main(["monitor", "--interface", "virtual", "--channel", channel,
                         "--duration", "0.3", "--json", "--log", str(log)])
        finally:
            publisher.stop()
    assert code == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["units"]["7"]["code_row"] == 9
    dbc = tmp_path / "atris.dbc"
    dbc.write_text(dbc_text())
    decoded = subprocess.run([sys.executable, "-m", "cantools", "decode", "--single-line",
                              str(dbc)], stdin=log.open(), capture_output=True, text=True,
                             check=True, timeout=60).stdout
    assert "Atris7_Status(" in decoded and "State: RUNNING" in decoded
    assert "Atris7_Sectors(" in decoded and "Distance0: 2.0 m" in decoded


def test_feature_monitor_follows_the_units_base_id() -> None:
    """A unit publishing from another ``bus.base_id`` is a unit to a monitor told that base
    (``atris monitor --base-id``) and unknown frames to one on the default base.

    Checked by making BusMonitor ignore its base (``unit_of`` on the default base): the
    monitor told base 0x100 saw no unit and the test failed."""
    frames = Publisher(can.Bus(interface="virtual", channel=f"b-{uuid.uuid4().hex}"), 2,
                       base_id=0x100).compose(measurement(1.0), status(3), time.monotonic())
    told, default = BusMonitor(base_id=0x100), BusMonitor()
    for msg in frames:
        told.feed(msg)
        default.feed(msg)
    assert set(told.snapshot()["units"]) == {"2"}
    assert told.snapshot()["units"]["2"]["code_row"] == 3
    assert default.snapshot()["units"] == {} and default.snapshot()["unknown_frames"] == len(
        frames)


def test_exception_monitor_refuses_a_base_id_out_of_range(
        capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exit_info:
        main(["monitor", "--base-id", "0x7F0", "--replay", "x.log"])
    assert exit_info.value.code == 2 and "base ID" in capsys.readouterr().err
