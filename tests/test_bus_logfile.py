"""Log files of ``atris monitor`` and ``atris launch``: every python-can format read back
as it went on the bus, ``atris monitor --replay``, and no log written over by mistake."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import threading
import time
import uuid
from pathlib import Path

import can
import pytest
from can.io.logger import MESSAGE_WRITERS
from can.io.player import MESSAGE_READERS
from unit_frames import measurement, status, two_units

from atris_node.bus.can.frames import FrameCodec
from atris_node.bus.can.logfile import missing_package, open_log_writer
from atris_node.bus.can.monitor import BusTap
from atris_node.bus.can.publisher import Publisher
from atris_node.cli import main

#: exit code of a usage error (as argparse's)
USAGE = 2
UNIT_ID = 6
PERIOD_S = 0.05



def _format(suffix: str) -> pytest.ParameterSet:
    package = missing_package(suffix)
    reason = f"the {suffix} format needs the {package} package, which is not installed"
    return pytest.param(suffix, id=suffix[1:],
                        marks=pytest.mark.skipif(package is not None, reason=reason))


#: every format python-can both writes and reads
FORMATS = [_format(s) for s in sorted(set(MESSAGE_WRITERS) & set(MESSAGE_READERS))]


def _key(msg: can.Message) -> tuple[int, bool, int, bytes]:
    return msg.arbitration_id, msg.is_extended_id, msg.dlc, bytes(msg.data)




def _cycles(count: int, start_s: float = 1000.0) -> list[can.Message]:
    """``count`` publish cycles of unit UNIT_ID (11-bit frames) and a negotiation request
    (29-bit) after each, timestamped every PERIOD_S from ``start_s``."""
    codec = FrameCodec()
    frames = []
    with can.Bus(interface="virtual", channel=f"compose-{uuid.uuid4().hex}") as bus:
        publisher = Publisher(bus, UNIT_ID, period_s=PERIOD_S, max_age_s=1e9)
        for cycle in range(count):
            now = start_s + cycle * PERIOD_S
            request = codec.encode(f"Negotiation{UNIT_ID}_Request",
                                   {"Name": 0x0A70_0000_0000_0000 + cycle})
            for msg in [*publisher.compose(measurement(2.0), status(3), now), request]:
                msg.timestamp = now
                frames.append(msg)
    return frames


class Chatter:
    """Sends publish cycles and negotiation requests on a virtual channel from a thread,
    and keeps every frame it sent, in order: what went on the bus."""

    def __init__(self, channel: str) -> None:
        self.sent: list[can.Message] = []
        self._frames = _cycles(500)
        self._stop = threading.Event()
        self._bus = can.Bus(interface="virtual", channel=channel)
        self._thread = threading.Thread(target=self._run, name="chatter")

    def __enter__(self) -> Chatter:
        self._thread.start()
        return self

    def __exit__(self, *_: object) -> None:
        self._stop.set()
        self._thread.join()
        self._bus.shutdown()

    def _run(self) -> None:
        for msg in self._frames:
            if self._stop.is_set():
                return
            self._bus.send(msg)
            self.sent.append(msg)
            if msg.is_extended_id:
                self._stop.wait(0.002)


def _assert_decodable(frames: list[can.Message]) -> None:
    """Every frame is a frame of the shipped database, E2E protected ones with a good CRC."""
    codec = FrameCodec()
    for msg in frames:
        assert codec.decode_message(msg).crc_ok in (True, None)


@pytest.mark.parametrize("suffix", FORMATS)
def test_monitor_log_reads_back_as_sent(suffix: str, tmp_path: Path,
                                        capsys: pytest.CaptureFixture[str]) -> None:
    """What ``atris monitor --log`` wrote, read back with can.LogReader, is a run of what
    went on the bus, frame for frame (ID, 29-bit flag, DLC, data), and decodes. The
    channel name ends in digits: python-can's BLF writer took it for a channel number too
    large for its 16-bit field and failed on every frame, until LogWriter left it out."""
    channel, log = f"log-{uuid.uuid4().hex}", tmp_path / f"monitor{suffix}"
    with Chatter(channel) as chatter:
        code = main(["monitor", "--interface", "virtual", "--channel", channel,
                     "--duration", "0.3", "--json", "--log", str(log)])
    assert code == 0
    assert json.loads(capsys.readouterr().out)["units"][str(UNIT_ID)]["code_row"] == 3
    logged = [_key(m) for m in can.LogReader(log)]
    sent = [_key(m) for m in chatter.sent]
    assert len(logged) > 20 and logged[0] in sent
    first = sent.index(logged[0])
    assert logged == sent[first:first + len(logged)]
    assert any(extended for _, extended, _, _ in logged)
    _assert_decodable(list(can.LogReader(log)))


@pytest.mark.parametrize("suffix", FORMATS)
def test_launch_log_holds_every_frame(suffix: str, tmp_path: Path,
                                      capsys: pytest.CaptureFixture[str]) -> None:
    """``atris launch --log`` exits 0 with its JSON summary, and its log holds exactly the
    frames a bus listening from before the start to after the end received. Checked by
    stopping the writer a second time after the BusTap (as the launch did): the .blf run
    failed with 'I/O operation on closed file'."""
    channel = f"launch-log-{uuid.uuid4().hex}"
    spec, log = tmp_path / "pair.toml", tmp_path / f"launch{suffix}"
    spec.write_text(two_units(channel))
    with can.Bus(interface="virtual", channel=channel) as listener:
        code = main(["launch", str(spec), "--duration", "1", "--json", "--log", str(log)])
        received = []
        while (msg := listener.recv(timeout=0.0)) is not None:
            received.append(msg)
    assert code == 0
    summary = json.loads(capsys.readouterr().out)
    assert [u["name"] for u in summary["units"]] == ["a", "b"]
    logged = list(can.LogReader(log))
    assert len(logged) > 10
    assert sorted(map(_key, logged)) == sorted(map(_key, received))
    _assert_decodable(logged)


def _write_log(path: Path, frames: list[can.Message]) -> None:
    writer = can.Logger(path)
    for msg in frames:
        writer.on_message_received(msg)
    writer.stop()


@pytest.mark.parametrize("suffix", FORMATS)
def test_monitor_replays_a_log_in_its_own_time(suffix: str, tmp_path: Path,
                                               capsys: pytest.CaptureFixture[str]) -> None:
    """``atris monitor --replay`` feeds a log to the monitor with the log's timestamps: the
    frame rate is the recorded one and the E2E states are those at the log's end. With the
    time of the replay instead, the rate was 0 and every E2E state a timeout."""
    log = tmp_path / f"recorded{suffix}"
    frames = _cycles(60)
    _write_log(log, frames)
    assert main(["monitor", "--replay", str(log), "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    unit = summary["units"][str(UNIT_ID)]
    per_cycle = sum(1 for m in frames[:8] if not m.is_extended_id and m.timestamp == 1000.0)
    assert unit["rate_hz"] == pytest.approx(per_cycle / PERIOD_S, rel=0.1)
    assert unit["frames"] == 60 * per_cycle and unit["code_row"] == 3
    assert {e["state"] for e in unit["e2e"].values()} == {"ok"}
    assert summary["others"][f"Negotiation{UNIT_ID}_Request"]["count"] == 60


def test_monitor_refuses_to_write_over_a_log(tmp_path: Path,
                                             capsys: pytest.CaptureFixture[str]) -> None:
    """An existing --log file is left byte for byte as it was and the command is a usage
    error (exit 2). Checked by removing the refusal in check_log_target: the file was
    replaced by a new log and the exit code was 0."""
    log = tmp_path / "fleet.blf"
    _write_log(log, _cycles(20))
    before = log.read_bytes()
    code = main(["monitor", "--channel", f"x-{uuid.uuid4().hex}", "--duration", "0.1",
                 "--log", str(log)])
    assert code == USAGE and log.read_bytes() == before
    assert "already exists" in capsys.readouterr().err


def test_monitor_overwrites_when_told(tmp_path: Path) -> None:
    log = tmp_path / "old.log"
    log.write_text("not a log\n")
    code = main(["monitor", "--channel", f"x-{uuid.uuid4().hex}", "--duration", "0.1",
                 "--log", str(log), "--overwrite"])
    assert code == 0 and log.read_text() == ""


def test_launch_refuses_to_write_over_a_log(tmp_path: Path,
                                            capsys: pytest.CaptureFixture[str]) -> None:
    """Same for ``atris launch --log``, refused before any unit starts. Checked by
    removing the check in the launch command: the launch ran and replaced the file."""
    spec, log = tmp_path / "pair.toml", tmp_path / "fleet.asc"
    spec.write_text(two_units(f"launch-refused-{uuid.uuid4().hex}"))
    _write_log(log, _cycles(20))
    before = log.read_bytes()
    assert main(["launch", str(spec), "--duration", "1", "--log", str(log)]) == USAGE
    assert log.read_bytes() == before
    assert "--overwrite" in capsys.readouterr().err


@pytest.mark.parametrize(("argv", "message"), [
    (["monitor", "--log", "run.xyz", "--duration", "0"], "accepted: .asc, .blf"),
    (["monitor", "--log", "run.blf.gz", "--duration", "0"], "accepted"),
    (["monitor", "--replay", "run.xyz"], "does not exist"),
    (["monitor", "--replay", "{existing}", "--channel", "can0"], "--channel applies only"),
    (["monitor", "--replay", "{existing}", "--log", "copy.log"], "--log applies only"),
    (["launch", "sim_fleet", "--log", "run.xyz"], "accepted: .asc, .blf"),
])
def test_bad_log_options_are_usage_errors(argv: list[str], message: str, tmp_path: Path,
                                          capsys: pytest.CaptureFixture[str],
                                          monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)
    existing = tmp_path / "existing.log"
    _write_log(existing, _cycles(2))
    assert main([a.format(existing=existing) for a in argv]) == USAGE
    assert message in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["existing.log"]


def test_unreadable_format_names_what_is_accepted(tmp_path: Path,
                                                  capsys: pytest.CaptureFixture[str]) -> None:
    text = tmp_path / "run.txt"
    text.write_text("a printout, not a log\n")
    assert main(["monitor", "--replay", str(text)]) == USAGE
    err = capsys.readouterr().err
    accepted = err.split("accepted: ")[1]
    assert "cannot read log file" in err and ".blf" in accepted and ".txt" not in accepted


def test_a_damaged_log_is_a_clear_error(tmp_path: Path,
                                        capsys: pytest.CaptureFixture[str]) -> None:
    """python-can's own reader error comes out as ``error: ...`` naming the file (exit 1),
    not as a traceback."""
    damaged = tmp_path / "damaged.db"
    damaged.write_bytes(b"not an sqlite database, though named like one")
    assert main(["monitor", "--replay", str(damaged)]) == 1
    assert "damaged.db' cannot be read after frame 0" in capsys.readouterr().err


class Holding(can.Listener):
    """Keeps the frames it takes. Holds the Notifier thread in its first frame until
    ``release`` is set and the Notifier is stopping, so the frames sent meanwhile are still
    queued on the bus when the Notifier thread ends."""

    def __init__(self, bus: can.BusABC) -> None:
        self.bus = bus
        self.frames: list[can.Message] = []
        self.release = threading.Event()
        self.stops = 0

    def on_message_received(self, msg: can.Message) -> None:
        if not self.frames:
            self.release.wait(5.0)
            while not all(n.stopped for n in can.Notifier.find_instances(self.bus)):
                time.sleep(0.001)
        self.frames.append(msg)

    def stop(self) -> None:
        self.stops += 1


class Failing(can.Listener):
    def on_message_received(self, msg: can.Message) -> None:
        raise OSError(28, "No space left on device")


def test_tap_drains_the_bus_and_stops_each_listener_once(tmp_path: Path) -> None:
    """Frames still queued when the Notifier stops reach the listeners, then each listener
    is stopped once, however often the tap is stopped. Checked by leaving the drain out
    of BusTap.stop: the holding listener had 1 frame of 30."""
    channel = f"tap-{uuid.uuid4().hex}"
    with can.Bus(interface="virtual", channel=channel) as bus, \
            can.Bus(interface="virtual", channel=channel) as peer:
        holding = Holding(bus)
        writer = open_log_writer(tmp_path / "tap.blf")
        tap = BusTap(bus, [holding, writer])
        frames = _cycles(5)
        for msg in frames:
            peer.send(msg)
        stopping = threading.Thread(target=tap.stop, name="tap-stop")
        stopping.start()
        holding.release.set()
        stopping.join()
        tap.stop()
    assert [_key(m) for m in holding.frames] == [_key(m) for m in frames]
    assert holding.stops == 1
    assert [_key(m) for m in can.LogReader(tmp_path / "tap.blf")] == [_key(m) for m in frames]


def test_a_failing_listener_is_counted_and_the_others_go_on(
        caplog: pytest.LogCaptureFixture) -> None:
    """A log writer that fails (full disk) does not take the monitor down with it: the
    failures are counted and the first one logged with its cause. Checked by removing the
    catch around each listener in the fan-out: the OSError came out of the tap."""
    channel = f"tap-fail-{uuid.uuid4().hex}"
    frames = _cycles(3)
    with can.Bus(interface="virtual", channel=channel) as bus, \
            can.Bus(interface="virtual", channel=channel) as peer:
        holding = Holding(bus)
        holding.release.set()
        holding.frames.append(frames[0])  # no holding: it has a frame already
        tap = BusTap(bus, [Failing(), holding])
        for msg in frames:
            peer.send(msg)
        tap.stop()
    assert len(holding.frames) == 1 + len(frames)
    assert tap.failures == len(frames) and "No space left" in tap.first_failure
    assert "Failing could not take a frame" in caplog.text


def test_ctrl_c_ends_the_watch_with_the_summary_and_the_log(tmp_path: Path) -> None:
    """SIGINT ends ``atris monitor`` as --duration would: exit 0, the JSON summary, a
    closed log. Checked by letting KeyboardInterrupt through the watch: exit 130, no
    summary."""
    log = tmp_path / "interrupted.blf"
    argv = ["monitor", "--channel", f"int-{uuid.uuid4().hex}", "--json", "--log", str(log)]
    # SIGINT handled as in a terminal, even where the test run itself ignores it
    code = ("import signal, sys; signal.signal(signal.SIGINT, signal.default_int_handler); "
            f"from atris_node.cli import main; sys.exit(main({argv!r}))")
    process = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE,
                               stderr=subprocess.PIPE)
    try:
        deadline = time.monotonic() + 60.0
        while not log.exists() and time.monotonic() < deadline:
            time.sleep(0.05)
        time.sleep(0.5)  # from the log's creation into the watch
        process.send_signal(signal.SIGINT)
        out, err = process.communicate(timeout=60)
    finally:
        process.kill()
    assert process.returncode == 0, err
    assert json.loads(out)["units"] == {}
    assert list(can.LogReader(log)) == []
