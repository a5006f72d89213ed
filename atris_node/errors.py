"""The one exception tree of the project.

Every error raised on purpose is an :class:`AtrisError`. Subclasses also inherit the
matching built-in, so ``except ValueError`` in a caller keeps working, in the way
python-can's ``CanTimeoutError(CanError, TimeoutError)`` does. Vendor errors are wrapped
with ``raise ... from exc``.
"""

from __future__ import annotations


class AtrisError(Exception):
    """Base of every error this project raises on purpose."""


class ConfigError(AtrisError, ValueError):
    """A parameter, launch file, scene file or calibration file is invalid."""


def check_setting(ok: bool, key: str, value: object, accepted: str) -> None:
    """Raise :class:`ConfigError` naming ``key`` (e.g. ``pipeline.snr_min``), the value
    and what is accepted, unless ``ok``."""
    if not ok:
        raise ConfigError(f"{key} = {value!r} is not accepted; it must be {accepted}")


class UsageError(AtrisError, ValueError):
    """A command line that asks for something that cannot be done as given (an existing
    output file, options that exclude each other); the ``atris`` command exits 2 for it,
    as argparse does for its own usage errors."""


class LogFileError(AtrisError, ValueError):
    """A recorded CAN log that cannot be read to its end (damaged or truncated)."""


class CodeError(AtrisError, ValueError):
    """A code length, code row or code set that cannot exist or is not allowed."""


class DemodulationError(AtrisError, ValueError):
    """Sub-frames that cannot be demodulated (wrong shape, dtype or bit depth)."""


class FrameDecodeError(AtrisError, ValueError):
    """Bytes from the bus that are not a valid frame of the shipped database."""


class CalibrationError(AtrisError, ValueError):
    """Calibration input that is degenerate, or a calibration file that does not fit."""


class DriverError(AtrisError, RuntimeError):
    """A camera or projector backend failed or is not available."""


class DeviceNotFoundError(DriverError, LookupError):
    """No device of the requested kind is attached."""


class CameraLostError(DriverError, ConnectionError):
    """The camera stopped delivering sub-frames."""


class BusError(AtrisError, OSError):
    """The CAN bus failed (bus-off, send failure, interface not available)."""


class NegotiationError(AtrisError, RuntimeError):
    """Code negotiation cannot reach a safe assignment (plan conflict, no free code)."""


class NodeFaultError(AtrisError, RuntimeError):
    """A fatal error stored by a background thread and re-raised in the main loop."""


class MapProcessError(AtrisError, RuntimeError):
    """The pipeline raised in the map process; the message carries its traceback there."""


class MapProcessLostError(NodeFaultError):
    """The map process could not start, ended, or did not answer within its deadline:
    no map is measured any more (the unit stops: laser off, FAULT)."""
