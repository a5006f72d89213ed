"""Shared fixtures. Every test is checked for leaked threads and open python-can buses."""

from __future__ import annotations

import threading
import time
import weakref
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import can
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


#: every python-can bus created in this process, registered by its constructor
_BUSES: weakref.WeakSet[can.BusABC] = weakref.WeakSet()
_bus_init = can.BusABC.__init__


def _registering_init(self: can.BusABC, *args: Any, **kwargs: Any) -> None:
    _BUSES.add(self)
    _bus_init(self, *args, **kwargs)


can.BusABC.__init__ = _registering_init  # type: ignore[method-assign]


@pytest.fixture(autouse=True)
def no_leaked_buses() -> Iterator[None]:
    """Fail a test that leaves a python-can bus open."""
    yield
    open_buses = [b for b in list(_BUSES) if not getattr(b, "_is_shutdown", True)]
    for bus in open_buses:
        bus.shutdown()
    assert not open_buses, f"test left {len(open_buses)} python-can bus(es) open"


#: python-can's configuration variables (can.util.load_environment_config)
CAN_VARIABLES = ("CAN_INTERFACE", "CAN_CHANNEL", "CAN_BITRATE", "CAN_CONFIG")


@pytest.fixture(autouse=True)
def no_python_can_config(monkeypatch: pytest.MonkeyPatch,
                         tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Keep the python-can configuration of the machine running the tests out of them (the
    node and the monitor read it for the bus settings a test leaves open): no CAN_*
    variables, HOME an empty folder (also for child processes), and of python-can's config
    files only those under HOME. Returns that HOME, for tests that write a ~/.canrc."""
    for name in CAN_VARIABLES:
        monkeypatch.delenv(name, raising=False)
    home = tmp_path_factory.mktemp("home")
    monkeypatch.setenv("HOME", str(home))
    monkeypatch.setattr(can.util, "CONFIG_FILES",
                        [path for path in can.util.CONFIG_FILES if path.startswith("~")])
    return home


def pytest_ignore_collect(collection_path: Path, config: pytest.Config) -> bool | None:
    """Host runs (``-m 'not vcan ...'``) do not even import the SocketCAN tier."""
    if collection_path.name == "vcan" and "not vcan" in str(config.getoption("markexpr")):
        return True
    return None


@pytest.fixture
def pair() -> Iterator[Any]:
    """A canopen master and the CANopen device on one virtual bus (tests/canopen_pair.py),
    closed after the test."""
    from canopen_pair import Pair

    p = Pair()
    try:
        yield p
    finally:
        p.close()
