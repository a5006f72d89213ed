"""Shared fixtures. Every test is checked for leaked threads and open python-can buses."""

from __future__ import annotations

import gc
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

DATA_DIR = Path(__file__).parent / "data"
REPO_ROOT = Path(__file__).resolve().parent.parent
#: threads owned by libraries that live for the whole process
IGNORED_THREADS = ("ThreadPoolExecutor", "asyncio", "pydevd")


def _live_threads() -> set[threading.Thread]:
    return {t for t in threading.enumerate() if t.is_alive()}


@pytest.fixture(autouse=True)
def no_leaked_threads() -> Iterator[None]:
    """Fail a test that leaves a thread of its own running."""
    before = _live_threads()
    yield
    deadline = time.monotonic() + 2.0
    leaked = _live_threads() - before
    while leaked and time.monotonic() < deadline:
        time.sleep(0.02)
        leaked = {t for t in leaked if t.is_alive()}
    names = sorted(t.name for t in leaked if not t.name.startswith(IGNORED_THREADS))
    assert not names, f"test leaked threads: {names}"


@pytest.fixture(autouse=True)
def no_leaked_buses() -> Iterator[None]:
    """Fail a test that leaves a python-can bus open."""
    import can

    yield
    gc.collect()
    open_buses = [
        o for o in gc.get_objects()
        # type(), not isinstance(): canopen's network placeholder raises on __class__
        if issubclass(type(o), can.BusABC) and not getattr(o, "_is_shutdown", True)
    ]
    for bus in open_buses:
        bus.shutdown()
    assert not open_buses, f"test left {len(open_buses)} python-can bus(es) open"


def pytest_ignore_collect(collection_path: Path, config: pytest.Config) -> bool | None:
    """Host runs (``-m 'not vcan ...'``) do not even import the SocketCAN tier."""
    if collection_path.name == "vcan" and "not vcan" in str(config.getoption("markexpr")):
        return True
    return None
