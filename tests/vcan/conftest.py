"""Fixtures for the real-SocketCAN tier: vcan interfaces and units run as separate processes.

Every test here is marked ``vcan``. Without ``vcan0`` and ``vcan1`` they are skipped with a
reason; ``scripts/vcan-tests.sh`` runs them (natively or in a VM) and fails on any skip.
"""

from __future__ import annotations

import socket
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from vcan_support import VCAN_DIR, UnitProcess, Zygote

VCAN_IFACES = ("vcan0", "vcan1")
#: s; each test's own time (pytest-timeout, the test function only: the session's unit
#: zygote, its imports and kernels, is set up outside it, up to ZYGOTE_PRELOAD_S)
TEST_TIMEOUT_S = 300.0
ZYGOTE_PRELOAD_S = 900.0
HOW_TO = ("run scripts/vcan-tests.sh, or create them: sudo modprobe vcan; "
          "sudo ip link add dev vcan0 type vcan; sudo ip link set vcan0 up (same for vcan1)")


def vcan_missing() -> list[str]:
    """Names of the vcan interfaces that do not exist or cannot be bound with AF_CAN."""
    missing = []
    for name in VCAN_IFACES:
        try:
            socket.if_nametoindex(name)
            with socket.socket(socket.AF_CAN, socket.SOCK_RAW, socket.CAN_RAW) as sock:
                sock.bind((name,))
        except OSError:
            missing.append(name)
    return missing


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Skips every test of this package, with a reason, when the vcan interfaces are missing."""
    mine = [item for item in items if Path(str(item.path)).is_relative_to(VCAN_DIR)]
    missing = vcan_missing() if mine else []
    for item in mine if missing else []:
        item.add_marker(pytest.mark.skip(reason=f"no {', '.join(missing)}: {HOW_TO}"))
    for item in [] if missing else mine:  # the session's zygote start is no test's time
        item.add_marker(pytest.mark.timeout(TEST_TIMEOUT_S, func_only=True))


@pytest.fixture(scope="session")
def zygote() -> Iterator[Zygote]:
    """The pre-loaded process every unit of the session is forked from."""
    server = Zygote()
    server.wait_preloaded(ZYGOTE_PRELOAD_S)
    yield server
    server.close()


@pytest.fixture
def spawn(zygote: Zygote) -> Iterator[Any]:
    """``spawn(role, *args)`` starts a ``UnitProcess``; all are ended after the test."""
    started: list[UnitProcess] = []

    def _spawn(role: str, *args: str) -> UnitProcess:
        unit = UnitProcess(zygote, role, *args)
        started.append(unit)
        return unit

    yield _spawn
    for unit in started:
        unit.close()
