"""The sub-frame recording format: what ``atris record`` writes and the replay backend reads.

A recording is a directory of three files::

    meta.json       {"format": "atris-subframes", "version": 1, "height": H, "width": W,
                     "dtype": "uint8" | "uint16", "bits": 8..16, "count": K,
                     "rate_hz": sub-frame rate or 0.0, "source": backend name,
                     "code_length": N, "code_row": 1-based Walsh row (0 = not known)}
    subframes.npy   (K, H, W) pixels, a standard NumPy .npy file (memory-mappable)
    index.csv       one row per sub-frame, in order:
                    sequence,device_time_s,host_time_s,exposure_us,chip
                    (floats written with ``repr`` so they read back bit-exact; chip is
                    0, 1 or empty when the backend did not know it)

``subframes.npy`` has a fixed 128-byte header, rewritten with the final count when the
writer closes, so frames stream to disk without knowing K in advance. ``meta.json`` is
written last: a recording without it was not finished and is refused on load.
"""

from __future__ import annotations

import csv
import json
import logging
import struct
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from types import TracebackType
from typing import IO, Any

import numpy as np
import numpy.typing as npt

from atris_node.errors import ConfigError, DriverError
from atris_node.types import SubFrame
from drivers.base import Camera, Projector

logger = logging.getLogger(__name__)

FORMAT_NAME = "atris-subframes"
FORMAT_VERSION = 1
META_FILE = "meta.json"
PIXELS_FILE = "subframes.npy"
INDEX_FILE = "index.csv"
INDEX_COLUMNS = ("sequence", "device_time_s", "host_time_s", "exposure_us", "chip")
#: bytes of the .npy header, a multiple of 64 as the .npy format asks
NPY_HEADER_BYTES = 128
_NPY_MAGIC = b"\x93NUMPY\x01\x00"
_DTYPES: dict[str, np.dtype[Any]] = {"uint8": np.dtype(np.uint8), "uint16": np.dtype(np.uint16)}


def npy_header(dtype: np.dtype[Any], shape: tuple[int, ...]) -> bytes:
    """A .npy version 1.0 header of exactly NPY_HEADER_BYTES for a C-order array."""
    text = f"{{'descr': '{dtype.str}', 'fortran_order': False, 'shape': {shape!r}, }}"
    room = NPY_HEADER_BYTES - len(_NPY_MAGIC) - 2
    if len(text) >= room:
        raise DriverError(f"shape {shape} does not fit a {NPY_HEADER_BYTES}-byte .npy header")
    return _NPY_MAGIC + struct.pack("<H", room) + text.encode("latin1").ljust(room - 1) + b"\n"


def _chip_text(chip: int | None) -> str:
    return "" if chip is None else str(int(chip))


def _index_row(sub: SubFrame) -> list[str]:
    return [str(sub.sequence), repr(float(sub.device_time_s)), repr(float(sub.host_time_s)),
            repr(float(sub.exposure_us)), _chip_text(sub.chip)]


class RecordingWriter:
    """Streams sub-frames into a new recording directory.

    The first sub-frame fixes the shape, dtype and bits; later ones must match. Call
    ``close()`` (or use ``with``) to finish the recording; it is safe to call twice.
    """

    def __init__(self, directory: str | Path, rate_hz: float = 0.0, source: str = "",
                 code: tuple[int, int] = (0, 0)) -> None:
        self.directory = Path(directory)
        self.rate_hz = float(rate_hz)
        self.source = source
        self.code = code  # (N, 1-based Walsh row) strobed while recording; (0, 0) if none
        self.count = 0
        self._first: SubFrame | None = None
        self._pixels: IO[bytes] | None = None
        self._index: IO[str] | None = None
        self._closed = False
        self._prepare_directory()

    def _prepare_directory(self) -> None:
        if self.directory.exists() and any(self.directory.iterdir()):
            raise ConfigError(f"recording directory {self.directory} is not empty; "
                              "accepted: a new or empty directory")
        self.directory.mkdir(parents=True, exist_ok=True)

    def _open_files(self, sub: SubFrame) -> None:
        self._first = sub
        self._pixels = open(self.directory / PIXELS_FILE, "wb")  # noqa: SIM115 - kept open
        self._pixels.write(npy_header(sub.pixels.dtype, (0, *sub.pixels.shape)))
        self._index = open(self.directory / INDEX_FILE, "w", newline="")  # noqa: SIM115
        csv.writer(self._index).writerow(INDEX_COLUMNS)

    def _check_like_first(self, sub: SubFrame) -> None:
        first = self._first
        assert first is not None
        same = (sub.pixels.shape == first.pixels.shape and sub.pixels.dtype == first.pixels.dtype
                and sub.bits == first.bits)
        if not same:
            raise DriverError(
                f"sub-frame {sub.sequence} is {sub.pixels.shape} {sub.pixels.dtype} "
                f"bits={sub.bits}; this recording holds {first.pixels.shape} "
                f"{first.pixels.dtype} bits={first.bits}")

    def write(self, sub: SubFrame) -> None:
        """Append one sub-frame (pixels, sequence, times, exposure, chip)."""
        if self._closed:
            raise DriverError(f"recording {self.directory} is closed")
        if self._first is None:
            self._open_files(sub)
        self._check_like_first(sub)
        assert self._pixels is not None and self._index is not None
        self._pixels.write(np.ascontiguousarray(sub.pixels).data)
        self._index.write(",".join(_index_row(sub)) + "\n")
        self.count += 1

    def _meta(self) -> dict[str, Any]:
        first = self._first
        height, width = first.pixels.shape if first is not None else (0, 0)
        return {"format": FORMAT_NAME, "version": FORMAT_VERSION, "height": int(height),
                "width": int(width), "dtype": str(first.pixels.dtype) if first else "uint8",
                "bits": first.bits if first else 8, "count": self.count,
                "rate_hz": self.rate_hz, "source": self.source,
                "code_length": self.code[0], "code_row": self.code[1]}

    def close(self) -> None:
        """Finish the recording: final .npy header, index flushed, meta.json written."""
        if self._closed:
            return
        self._closed = True
        if self._pixels is not None and self._first is not None:
            self._pixels.seek(0)
            self._pixels.write(npy_header(self._first.pixels.dtype,
                                          (self.count, *self._first.pixels.shape)))
            self._pixels.close()
        if self._index is not None:
            self._index.close()
        meta = json.dumps(self._meta(), indent=1) + "\n"
        (self.directory / META_FILE).write_text(meta, encoding="utf-8")
        logger.info("recorded %d sub-frames to %s", self.count, self.directory)

    def __enter__(self) -> RecordingWriter:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()


@dataclass(frozen=True)
class RecordingMeta:
    """The content of ``meta.json``; see the module docstring for the fields."""

    height: int
    width: int
    dtype: str
    bits: int
    count: int
    rate_hz: float = 0.0
    source: str = ""
    code_length: int = 0
    code_row: int = 0


@dataclass(frozen=True)
class RecordingIndex:
    """The columns of ``index.csv`` as arrays of length K; chip is -1 where unknown."""

    sequence: npt.NDArray[np.int64]
    device_time_s: npt.NDArray[np.float64]
    host_time_s: npt.NDArray[np.float64]
    exposure_us: npt.NDArray[np.float64]
    chip: npt.NDArray[np.int8]


def _meta_error(path: Path, what: str) -> ConfigError:
    return ConfigError(f"{path}: {what}; accepted: a meta.json written by 'atris record' "
                       f"(format {FORMAT_NAME!r} version {FORMAT_VERSION})")


def _load_meta_json(path: Path) -> dict[str, Any]:
    if not path.is_file():
        raise _meta_error(path, "missing (the recording was not finished or is not one)")
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise _meta_error(path, f"unreadable ({exc})") from exc
    if not isinstance(data, dict):
        raise _meta_error(path, "not a JSON object")
    return data


def _checked_meta(path: Path, data: dict[str, Any]) -> RecordingMeta:
    if data.get("format") != FORMAT_NAME or data.get("version") != FORMAT_VERSION:
        raise _meta_error(path, f"format {data.get('format')!r} version {data.get('version')!r}")
    try:
        meta = RecordingMeta(int(data["height"]), int(data["width"]), str(data["dtype"]),
                             int(data["bits"]), int(data["count"]),
                             float(data.get("rate_hz", 0.0)), str(data.get("source", "")),
                             int(data.get("code_length", 0)), int(data.get("code_row", 0)))
    except (KeyError, TypeError, ValueError) as exc:
        raise _meta_error(path, f"missing or invalid field {exc}") from exc
    bits_ok = 1 <= meta.bits <= _DTYPES.get(meta.dtype, np.dtype(np.uint8)).itemsize * 8
    if meta.dtype not in _DTYPES or not bits_ok or min(meta.height, meta.width, meta.count) < 0:
        raise _meta_error(path, f"dtype {meta.dtype!r}, bits {meta.bits}, shape "
                                f"({meta.count}, {meta.height}, {meta.width}) do not fit")
    return meta


def read_meta(directory: Path) -> RecordingMeta:
    """Read and check ``meta.json``; raise ConfigError naming the file when it is bad."""
    path = directory / META_FILE
    return _checked_meta(path, _load_meta_json(path))


def load_pixels(directory: Path, meta: RecordingMeta) -> npt.NDArray[Any]:
    """Memory-map ``subframes.npy`` read-only and check it against ``meta``."""
    path = directory / PIXELS_FILE
    shape = (meta.count, meta.height, meta.width)
    expected = NPY_HEADER_BYTES + int(np.prod(shape)) * _DTYPES[meta.dtype].itemsize
    size = path.stat().st_size if path.is_file() else -1
    if size != expected:
        raise ConfigError(f"{path}: {size} bytes, expected {expected} for {shape} {meta.dtype} "
                          "(truncated, missing or not from this recording)")
    try:
        pixels = np.load(path, mmap_mode="r", allow_pickle=False)
    except (OSError, ValueError) as exc:
        raise ConfigError(f"{path}: not a readable .npy file ({exc})") from exc
    if pixels.shape != shape or pixels.dtype != _DTYPES[meta.dtype]:
        raise ConfigError(f"{path}: holds {pixels.shape} {pixels.dtype}, meta.json says "
                          f"{shape} {meta.dtype}")
    return pixels


_IndexRow = tuple[int, float, float, float, int]


def _parse_index_row(path: Path, line: int, row: list[str]) -> _IndexRow:
    try:
        if len(row) != len(INDEX_COLUMNS):
            raise ValueError(f"{len(row)} columns, expected {len(INDEX_COLUMNS)}")
        chip = -1 if row[4] == "" else int(row[4])
        values = (int(row[0]), float(row[1]), float(row[2]), float(row[3]), chip)
    except ValueError as exc:
        raise ConfigError(f"{path} line {line}: {exc}; accepted: {','.join(INDEX_COLUMNS)} "
                          "with an integer sequence, finite times and chip 0, 1 or empty"
                          ) from exc
    if chip not in (-1, 0, 1) or not np.all(np.isfinite(values[1:4])):
        raise ConfigError(f"{path} line {line}: chip {row[4]!r} or a time is not valid")
    return values


def load_index(directory: Path, meta: RecordingMeta) -> RecordingIndex:
    """Read and check ``index.csv``: header, one valid row per sub-frame."""
    path = directory / INDEX_FILE
    try:
        with open(path, newline="", encoding="utf-8") as stream:
            rows = list(csv.reader(stream))
    except OSError as exc:
        raise ConfigError(f"{path}: cannot be read ({exc})") from exc
    if not rows or tuple(rows[0]) != INDEX_COLUMNS:
        raise ConfigError(f"{path}: header must be {','.join(INDEX_COLUMNS)}")
    if len(rows) - 1 != meta.count:
        raise ConfigError(f"{path}: {len(rows) - 1} rows, meta.json says {meta.count}")
    parsed = [_parse_index_row(path, n + 2, row) for n, row in enumerate(rows[1:])]
    columns = list(zip(*parsed, strict=True)) if parsed else [()] * 5
    return RecordingIndex(np.array(columns[0], np.int64), np.array(columns[1], np.float64),
                          np.array(columns[2], np.float64), np.array(columns[3], np.float64),
                          np.array(columns[4], np.int8))


class Recording:
    """A finished recording opened for reading; ``sub_frame(i)`` rebuilds sub-frame i."""

    def __init__(self, directory: str | Path) -> None:
        self.directory = Path(directory)
        if not self.directory.is_dir():
            raise ConfigError(f"recording {self.directory} is not a directory; accepted: a "
                              "directory written by 'atris record'")
        self.meta = read_meta(self.directory)
        self.pixels = load_pixels(self.directory, self.meta)
        self.index = load_index(self.directory, self.meta)

    def __len__(self) -> int:
        return self.meta.count

    def sub_frame(self, i: int) -> SubFrame:
        """Sub-frame ``i`` (0 <= i < len) exactly as it was written; pixels are a copy."""
        chip = int(self.index.chip[i])
        return SubFrame(pixels=np.array(self.pixels[i]), sequence=int(self.index.sequence[i]),
                        device_time_s=float(self.index.device_time_s[i]),
                        host_time_s=float(self.index.host_time_s[i]),
                        exposure_us=float(self.index.exposure_us[i]), bits=self.meta.bits,
                        chip=None if chip < 0 else chip)


def record(camera: Camera, projector: Projector, writer: RecordingWriter, count: int, *,
           chips: Sequence[int] | None = None, timeout_s: float = 1.0) -> int:
    """Read ``count`` sub-frames from ``camera`` into ``writer``; return how many were written.

    With ``chips`` (a code, 0/1 per sub-frame) the projector is strobed with
    ``chips[sequence % N]`` for each next sub-frame, as the node does, and that commanded
    chip is stored for sub-frames whose backend does not report one. The projector is
    switched off at the end, also on error.
    """
    commanded: dict[int, int] = {}
    next_sequence: int | None = None
    try:
        for _ in range(count):
            if chips is not None and next_sequence is not None:
                commanded[next_sequence] = int(chips[next_sequence % len(chips)])
                projector.strobe(commanded[next_sequence], next_sequence)
            sub = camera.read(timeout_s)
            chip = commanded.pop(sub.sequence, None)
            if sub.chip is None and chip is not None:
                sub = replace(sub, chip=chip)
            commanded.clear()  # commands for sub-frames that were dropped
            writer.write(sub)
            next_sequence = sub.sequence + 1
    finally:
        projector.off()
    return writer.count
