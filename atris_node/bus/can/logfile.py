"""Log files of bus traffic in python-can's formats: written without overwriting, read back.

The format is the file's suffix, as :func:`can.Logger` and :func:`can.LogReader` choose
it: ``.asc``, ``.blf``, ``.csv``, ``.db``, ``.log``, ``.trc``, ``.mf4`` (with the
``asammdf`` package), and the text formats gzip-compressed (``.asc.gz``, ``.log.gz``...).
A writer never replaces an existing file unless asked to (``overwrite=True``): a log given
by mistake as the output of a recording would otherwise be lost.
"""

from __future__ import annotations

import copy
import importlib.util
import logging
from collections.abc import Iterator
from pathlib import Path

import can
from can.io.generic import MessageReader, MessageWriter
from can.io.logger import MESSAGE_WRITERS
from can.io.player import MESSAGE_READERS

from atris_node.errors import LogFileError, UsageError

logger = logging.getLogger(__name__)

#: formats whose python-can reader and writer need a package python-can does not require
OPTIONAL_PACKAGES = {".mf4": "asammdf"}
#: highest channel number a log keeps (BLF: 16 bits; ASC and TRC: small bus numbers)
MAX_LOG_CHANNEL = 255
#: formats python-can does not write gzipped
NOT_GZIPPED = (".blf", ".db")


def missing_package(suffix: str) -> str | None:
    """The package a format still needs (``asammdf`` for ``.mf4``), None if it has all."""
    package = OPTIONAL_PACKAGES.get(suffix.lower())
    if package is None or importlib.util.find_spec(package) is not None:
        return None
    return package


def log_format(path: str | Path) -> str:
    """The format suffix of a log path: ``.blf``, or ``.asc`` for ``run.asc.gz``."""
    suffixes = [s.lower() for s in Path(path).suffixes]
    if suffixes and suffixes[-1] == ".gz":
        return suffixes[-2] if len(suffixes) >= 2 else ".gz"
    return suffixes[-1] if suffixes else ""


def _check_format(path: str | Path, known: dict[str, type], verb: str,
                  not_gzipped: tuple[str, ...] = ()) -> None:
    suffix = log_format(path)
    accepted = ", ".join(sorted(known))
    gzipped = str(path).lower().endswith(".gz")
    if suffix not in known or (gzipped and suffix in not_gzipped):
        raise UsageError(f"cannot {verb} log file {str(path)!r}: its suffix names no format "
                         f"python-can can {verb}; accepted: {accepted} (text formats also "
                         "gzipped, e.g. .asc.gz)")
    package = missing_package(suffix)
    if package is not None:
        raise UsageError(f"cannot {verb} log file {str(path)!r}: the {suffix} format needs "
                         f"the {package} package (pip install {package})")


def check_log_target(path: str | Path, overwrite: bool = False) -> Path:
    """``path`` as a Path if a log may be written there; UsageError if it exists (unless
    ``overwrite``) or its suffix is not a format python-can writes."""
    target = Path(path)
    if target.exists() and not overwrite:
        raise UsageError(f"log file {str(target)!r} already exists and is left as it is; "
                         "choose another path, or pass --overwrite to replace it")
    if target.is_dir():
        raise UsageError(f"log file {str(target)!r} is a directory")
    _check_format(target, MESSAGE_WRITERS, "write", NOT_GZIPPED)
    return target


class LogWriter(can.Listener):
    """A python-can writer, given each frame with the bus's channel only when it names a
    channel number the formats can hold (``can0``, ``PCAN_USBBUS1``, 3): a virtual channel
    such as ``fleet-1795607737`` made the BLF writer fail on every frame (its channel
    field is 16 bits). ``stop()`` closes the file once, however often it is called."""

    def __init__(self, writer: MessageWriter) -> None:
        self.writer = writer
        self._stopped = False

    def on_message_received(self, msg: can.Message) -> None:
        if msg.channel is not None and not _channel_number(msg.channel):
            msg = copy.copy(msg)
            msg.channel = None
        self.writer.on_message_received(msg)

    def stop(self) -> None:
        if not self._stopped:
            self._stopped = True
            self.writer.stop()


def _channel_number(channel: object) -> bool:
    number = can.util.channel2int(channel) if isinstance(channel, int | str) else None
    return number is not None and 0 <= number <= MAX_LOG_CHANNEL


def open_log_writer(path: str | Path, overwrite: bool = False) -> LogWriter:
    """A writer of ``path`` in the format of its suffix (a listener; ``stop()`` closes
    the file); UsageError as :func:`check_log_target` says."""
    target = check_log_target(path, overwrite)
    logger.info("recording frames to %s", target)
    return LogWriter(can.Logger(target))


def open_log_reader(path: str | Path) -> MessageReader:
    """A python-can reader of ``path``: iterate it for the frames, in file order and with
    their recorded timestamps; UsageError if it is missing or not a log python-can reads."""
    source = Path(path)
    if not source.is_file():
        raise UsageError(f"log file {str(source)!r} does not exist or is not a file")
    _check_format(source, MESSAGE_READERS, "read")
    return can.LogReader(source)


def read_log(path: str | Path) -> Iterator[can.Message]:
    """The frames of the log at ``path`` (:func:`open_log_reader`); LogFileError naming
    the place when python-can's reader fails on a damaged or truncated file."""
    count = 0
    with open_log_reader(path) as reader:
        try:
            for msg in reader:
                count += 1
                yield msg
        except Exception as exc:  # each python-can reader fails in its own way
            raise LogFileError(f"log file {str(path)!r} cannot be read after frame {count}: "
                               f"{exc!r}") from exc
