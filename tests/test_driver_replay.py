"""The recording format, the replay backend and ``atris record`` / ``atris replay``."""

from __future__ import annotations

import itertools
import json
from pathlib import Path

import numpy as np
import pytest

import drivers
from atris_node.cli import main
from atris_node.errors import CameraLostError, ConfigError, DriverError
from atris_node.types import SubFrame
from drivers.base import Camera
from drivers.recording import (
    INDEX_FILE,
    META_FILE,
    PIXELS_FILE,
    Recording,
    RecordingWriter,
    record,
)
from drivers.replay import EndOfRecordingError, ReplayProjector, open_backend

CHIPS = (0, 1, 1, 0)


class PatternCamera(Camera):
    """A deterministic 10-bit camera: pixels and times follow from the sequence number.

    ``skip`` lists sequence numbers that are dropped (never delivered).
    """

    rate_hz = 100.0
    bits = 10

    def __init__(self, shape: tuple[int, int] = (6, 9), first: int = 1000,
                 skip: tuple[int, ...] = ()) -> None:
        self.shape, self.next_sequence, self.skip = shape, first, skip
        self.delivered: list[SubFrame] = []

    def _read(self, timeout_s: float) -> SubFrame:
        while self.next_sequence in self.skip:
            self.next_sequence += 1
        seq = self.next_sequence
        self.next_sequence += 1
        pixels = (np.arange(np.prod(self.shape)).reshape(self.shape) * 7 + seq * 13) % 1024
        sub = SubFrame(pixels=pixels.astype(np.uint16), sequence=seq,
                       device_time_s=seq / 300.0 + 1e-9 / 3, host_time_s=5000.0 + seq / 100.0,
                       exposure_us=500.0 + seq % 3 / 7, bits=self.bits)
        self.delivered.append(sub)
        return sub


def assert_same(a: SubFrame, b: SubFrame) -> None:
    """Every field equal, pixels bit-exact with the same dtype."""
    assert a.pixels.dtype == b.pixels.dtype and np.array_equal(a.pixels, b.pixels)
    assert (a.sequence, a.device_time_s, a.host_time_s, a.exposure_us, a.bits, a.chip) == (
        b.sequence, b.device_time_s, b.host_time_s, b.exposure_us, b.bits, b.chip)


def make_recording(directory: Path, count: int = 12, skip: tuple[int, ...] = ()) -> PatternCamera:
    camera, projector = PatternCamera(skip=skip), ReplayProjector()
    with RecordingWriter(directory, rate_hz=camera.rate_hz, source="pattern") as writer:
        record(camera, projector, writer, count, chips=CHIPS)
    assert not projector.is_lit
    return camera


def test_feature_replay_yields_identical_sub_frames(tmp_path: Path) -> None:
    source = make_recording(tmp_path / "rec", skip=(1004,))
    camera, projector = open_backend(tmp_path / "rec")
    with camera, projector:
        replayed = list(camera.frames())
    assert len(replayed) == 12 and camera.rate_hz == 100.0 and camera.bits == 10
    assert camera.size == (9, 6)
    for original, copy in zip(source.delivered, replayed, strict=True):
        # no chip was commanded for the first sub-frame, nor for the one after the drop
        unknown = original.sequence in (1000, 1005)
        expected_chip = None if unknown else CHIPS[original.sequence % 4]
        assert copy.chip == expected_chip
        assert_same(SubFrame(**{**original.__dict__, "chip": expected_chip}), copy)


def test_feature_pixels_file_is_a_plain_memory_mappable_npy(tmp_path: Path) -> None:
    source = make_recording(tmp_path / "rec", count=5)
    pixels = np.load(tmp_path / "rec" / PIXELS_FILE, mmap_mode="r")
    assert pixels.shape == (5, 6, 9) and pixels.dtype == np.uint16
    assert np.array_equal(pixels[3], source.delivered[3].pixels)
    meta = json.loads((tmp_path / "rec" / META_FILE).read_text())
    assert (meta["count"], meta["bits"], meta["dtype"], meta["source"]) == (5, 10, "uint16",
                                                                           "pattern")


def test_feature_end_of_recording_and_loop(tmp_path: Path) -> None:
    make_recording(tmp_path / "rec", count=4)
    camera, _ = open_backend(tmp_path / "rec")
    for _ in range(4):
        camera.read()
    with pytest.raises(EndOfRecordingError, match="end of recording"):
        camera.read()
    assert issubclass(EndOfRecordingError, CameraLostError)
    looped, _ = open_backend(tmp_path / "rec", loop=True)
    subs = [looped.read() for _ in range(10)]
    assert [s.sequence for s in subs] == list(range(1000, 1010))
    assert np.array_equal(subs[4].pixels, subs[0].pixels)
    assert subs[4].host_time_s == pytest.approx(subs[0].host_time_s + 0.04)
    assert all(b.host_time_s > a.host_time_s for a, b in itertools.pairwise(subs))


def test_feature_realtime_paces_by_recorded_host_times(tmp_path: Path) -> None:
    make_recording(tmp_path / "rec", count=4, skip=(1002,))
    sleeps: list[float] = []
    camera, _ = open_backend(tmp_path / "rec", realtime=True)
    camera._sleep, camera._clock = sleeps.append, lambda: 0.0
    for _ in range(4):
        camera.read()
    assert sleeps == pytest.approx([0.01, 0.03, 0.04])


def test_smoke_registry_opens_replay(tmp_path: Path) -> None:
    make_recording(tmp_path / "rec", count=3)
    camera, projector = drivers.open_backend("replay", path=str(tmp_path / "rec"))
    with camera, projector:
        projector.strobe(1, 7)
        assert isinstance(projector, ReplayProjector)
        assert projector.is_lit and projector.commanded == {7: 1}
        projector.off()
        assert not projector.is_lit
        assert camera.read().sequence == 1000


def test_exception_writer_refuses_used_directory_and_mixed_frames(tmp_path: Path) -> None:
    make_recording(tmp_path / "rec", count=2)
    with pytest.raises(ConfigError, match="not empty"):
        RecordingWriter(tmp_path / "rec")
    with RecordingWriter(tmp_path / "other") as writer:
        writer.write(PatternCamera(shape=(4, 4)).read())
        with pytest.raises(DriverError, match=r"this recording holds \(4, 4\)"):
            writer.write(PatternCamera(shape=(4, 5)).read())


def _corrupt(directory: Path, name: str) -> None:
    if name == "truncated pixels":
        path = directory / PIXELS_FILE
        path.write_bytes(path.read_bytes()[:-10])
    elif name == "missing meta":
        (directory / META_FILE).unlink()
    elif name == "bad meta":
        (directory / META_FILE).write_text("{\"format\": \"atris-subframes\", \"version\": 1")
    elif name == "short index":
        lines = (directory / INDEX_FILE).read_text().splitlines()
        (directory / INDEX_FILE).write_text("\n".join(lines[:-1]) + "\n")
    elif name == "bad chip":
        text = (directory / INDEX_FILE).read_text().splitlines()
        text[2] = text[2].rsplit(",", 1)[0] + ",7"
        (directory / INDEX_FILE).write_text("\n".join(text) + "\n")


@pytest.mark.parametrize(("damage", "file_name"), [
    ("truncated pixels", PIXELS_FILE), ("missing meta", META_FILE), ("bad meta", META_FILE),
    ("short index", INDEX_FILE), ("bad chip", INDEX_FILE)])
def test_exception_corrupt_recording_names_the_file(tmp_path: Path, damage: str,
                                                    file_name: str) -> None:
    make_recording(tmp_path / "rec", count=4)
    _corrupt(tmp_path / "rec", damage)
    with pytest.raises(ConfigError, match=file_name):
        Recording(tmp_path / "rec")


def test_exception_missing_directory(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="not a directory"):
        drivers.open_backend("replay", path=str(tmp_path / "nothing"))


def test_feature_cli_record_from_a_recording_and_errors(tmp_path: Path,
                                                        capsys: pytest.CaptureFixture[str]) -> None:
    make_recording(tmp_path / "rec", count=6)
    argv = ["record", "--driver", "replay", "--path", str(tmp_path / "rec"), "--frames", "5",
            "--row", "0", "--out", str(tmp_path / "copy")]
    assert main(argv) == 0
    assert "recorded 5 sub-frames" in capsys.readouterr().out
    original, copy = Recording(tmp_path / "rec"), Recording(tmp_path / "copy")
    for i in range(5):
        assert_same(original.sub_frame(i), copy.sub_frame(i))
    assert main(argv) == 1
    assert "not empty" in capsys.readouterr().err


def test_feature_cli_record_sim_then_replay(tmp_path: Path,
                                            capsys: pytest.CaptureFixture[str]) -> None:
    pytest.importorskip("drivers.sim")
    pytest.importorskip("atris_node.demod")
    argv = ["record", "--driver", "sim", "--scene", "indoor_lab", "--frames", "64",
            "--code-length", "16", "--row", "3", "--out", str(tmp_path / "sim")]
    assert main(argv) == 0
    recording = Recording(tmp_path / "sim")
    assert len(recording) == 64 and set(recording.index.chip[1:]) == {0, 1}
    assert (recording.meta.code_length, recording.meta.code_row) == (16, 3)
    capsys.readouterr()
    assert main(["replay", str(tmp_path / "sim"), "--json"]) == 0
    rows = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    assert rows and all(r["last_sequence"] - r["first_sequence"] == 15 for r in rows)
    assert all(r["lag"] == 0 and r["snr"] > 2.0 for r in rows)


class StripeCamera(Camera):
    """A camera looking at a lit stripe: row 3 brightens when the chip commanded for
    ``lag`` sub-frames earlier was 1 (the strobe lands late, as on an OAK)."""

    bits = 8
    rate_hz = 100.0

    def __init__(self, projector: ReplayProjector, lag: int) -> None:
        self.projector, self.lag, self.sequence = projector, lag, 0

    def _read(self, timeout_s: float) -> SubFrame:
        seq, self.sequence = self.sequence, self.sequence + 1
        pixels = np.full((8, 8), 40 + seq % 5, np.uint8)
        pixels[3] += np.uint8(90 * self.projector.commanded.get(seq - self.lag, 0))
        return SubFrame(pixels=pixels, sequence=seq, device_time_s=seq / 100.0,
                        host_time_s=seq / 100.0, exposure_us=1000.0)


def test_feature_cli_replay_demodulates(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    codes = pytest.importorskip("atris_node.codes")
    pytest.importorskip("atris_node.demod")
    chips = [int(c) for c in codes.walsh_chips(4, 3)]
    projector = ReplayProjector()
    with RecordingWriter(tmp_path / "rec", rate_hz=100.0) as writer:
        record(StripeCamera(projector, lag=1), projector, writer, 80, chips=chips)
    recording = Recording(tmp_path / "rec")
    from atris_node.cli.replay import infer_code

    assert infer_code(recording.index) == (4, 3)
    assert main(["replay", str(tmp_path / "rec"), "--json"]) == 0
    rows = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    assert len(rows) >= 8
    assert all(r["last_sequence"] - r["first_sequence"] == 3 and r["lag"] == 1 for r in rows)
    assert all(r["snr"] > 1.0 and r["saturated_fraction"] == 0.0 for r in rows)
    assert main(["replay", str(tmp_path / "rec"), "--code-length", "4", "--row", "3"]) == 0
    assert capsys.readouterr().out.startswith("seq ")
