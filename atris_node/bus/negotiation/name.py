"""The unit's 64-bit NAME: configured, from the camera serial, or a persisted random value.

The NAME orders units (the lowest wins codes and decides the plan), so it must be unique
on a bus and stable across restarts of one unit. A configured non-zero NAME wins; else a
camera serial gives one (BLAKE2b of the serial, 8 bytes); else a random NAME is made once
and kept in a file the caller names (never implicitly under ``$HOME``).

Example:
    >>> name_from_serial("14442C10D13EABCE00") == name_from_serial("14442C10D13EABCE00")
    True
"""

from __future__ import annotations

import hashlib
import logging
import secrets
from pathlib import Path

from atris_node.errors import ConfigError

logger = logging.getLogger(__name__)

MAX_NAME = 2**64 - 1


def name_from_serial(serial: str) -> int:
    """A stable non-zero 64-bit NAME from a camera serial number."""
    if not serial.strip():
        raise ConfigError("camera serial for the NAME must not be empty")
    digest = hashlib.blake2b(serial.strip().encode("utf-8"), digest_size=8).digest()
    return int.from_bytes(digest, "big") or 1


def persisted_name(path: Path) -> int:
    """The NAME kept in ``path`` (hex text); made at random and written on first use."""
    if path.exists():
        text = path.read_text(encoding="utf-8").strip()
        try:
            name = int(text, 16)
        except ValueError as exc:
            raise ConfigError(f"{path}: NAME must be hex digits, got {text!r}") from exc
        if not 0 < name <= MAX_NAME:
            raise ConfigError(f"{path}: NAME must be 1..2**64-1, got {text!r}")
        return name
    name = secrets.randbits(64) or 1
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(f"{name:016x}\n", encoding="utf-8")
    logger.info("new random NAME %#018x kept in %s", name, path)
    return name


def unit_name(configured: int = 0, camera_serial: str | None = None,
              state_path: Path | None = None) -> int:
    """The NAME to negotiate with: configured (non-zero), else serial, else persisted.

    Raises:
        ConfigError: no source gives a NAME, or the configured one is out of range.
    """
    if configured:
        if not 0 < configured <= MAX_NAME:
            raise ConfigError(f"unit.name must be 1..2**64-1, got {configured}")
        return configured
    if camera_serial:
        return name_from_serial(camera_serial)
    if state_path is not None:
        return persisted_name(state_path)
    raise ConfigError("no NAME: configure unit.name, or give a camera serial or a state file")
