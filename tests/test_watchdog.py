"""The lease between a node and the laser's enable line (drivers/watchdog.py), in-process.

The process-level test (a node killed or hung under ``atris watchdog``) is in
tests/test_node_process.py; here the rules themselves, on an explicit clock.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from atris_node.errors import DriverError
from drivers.base import Projector
from drivers.watchdog import LeasedProjector, LeaseWatchdog, read_lit_until


class ChipLog(Projector):
    """The chip line of a host-driven laser: what the node commanded last."""

    def __init__(self) -> None:
        self.chip = 0

    def _strobe(self, chip: int, sequence: int) -> None:
        self.chip = chip

    def _off(self) -> None:
        self.chip = 0


@pytest.fixture()
def lease(tmp_path: Path) -> Iterator[tuple[LeasedProjector, LeaseWatchdog]]:
    projector = LeasedProjector(ChipLog(), tmp_path / "state", lease_s=0.05)
    yield projector, LeaseWatchdog(tmp_path / "state", tmp_path / "enable", poll_s=0.005)
    projector.close()


def test_feature_the_line_follows_the_lease(lease: tuple[LeasedProjector, LeaseWatchdog]
                                            ) -> None:
    """Set while a strobe renewed the lease, clear once it ran out or the node said off.

    Checked by making ``step`` ignore the lease end (``lease_end > 0``): the expiry
    assertion failed (the line stayed 1)."""
    projector, watchdog = lease
    assert not watchdog.step() and watchdog.enable_line.read_text() == "0"
    projector.strobe(1, 0)
    end = read_lit_until(watchdog.state_file)
    assert watchdog.step(end - 0.01) and watchdog.enable_line.read_text() == "1"
    assert not watchdog.step(end) and watchdog.enable_line.read_text() == "0"  # ran out
    projector.strobe(1, 1)
    assert watchdog.step()
    projector.off()
    assert not watchdog.step() and watchdog.enable_line.read_text() == "0"
    assert [on for _, on, _ in watchdog.transitions] == [False, True, False, True, False]


def test_feature_no_state_file_is_no_lease(tmp_path: Path) -> None:
    watchdog = LeaseWatchdog(tmp_path / "missing", tmp_path / "enable")
    assert not watchdog.step() and watchdog.enable_line.read_text() == "0"


def test_feature_run_clears_the_line_when_stopped(lease: tuple[LeasedProjector,
                                                               LeaseWatchdog]) -> None:
    projector, watchdog = lease
    stop = threading.Event()
    runner = threading.Thread(target=watchdog.run, args=(stop,))
    runner.start()
    deadline = time.monotonic() + 5.0
    while not (watchdog.enable_line.exists() and watchdog.enable_line.read_text() == "1"):
        projector.strobe(1, 0)
        assert time.monotonic() < deadline, "the running watchdog never set the line"
        time.sleep(0.001)
    stop.set()
    runner.join(timeout=5.0)
    assert watchdog.enable_line.read_text() == "0"


@pytest.mark.parametrize("poll_s", [0.0, -1.0, 2.0])
def test_exception_bad_poll_period(tmp_path: Path, poll_s: float) -> None:
    with pytest.raises(DriverError, match=r"poll period must be in \(0, 1\] s"):
        LeaseWatchdog(tmp_path / "s", tmp_path / "e", poll_s)


def test_exception_unwritable_line(tmp_path: Path) -> None:
    watchdog = LeaseWatchdog(tmp_path / "s", tmp_path / "no" / "such" / "line")
    with pytest.raises(DriverError, match="cannot drive the laser enable line"):
        watchdog.step()
