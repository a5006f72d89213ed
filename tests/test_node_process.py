"""The laser is off when the node process ends: by SIGTERM/SIGINT (the node switches it
off) and by SIGKILL (the projector's watchdog lease runs out)."""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from drivers.watchdog import is_lit_now, read_lit_until

LEASE_S = 0.05


def start_unit(state_file: Path, channel: str) -> subprocess.Popen[bytes]:
    command = [sys.executable, "-m", "atris_node", "run",
               "--set", "code.length=8", "--set", "negotiation.window_s=0.1",
               "--set", f"bus.channel={channel}",
               "--set", f"driver.projector_state_file={state_file}",
               "--set", f"driver.projector_lease_s={LEASE_S}"]
    return subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE)


def wait_until_lit(process: subprocess.Popen[bytes], state_file: Path) -> None:
    deadline = time.monotonic() + 60.0
    while not (state_file.exists() and is_lit_now(state_file)):
        assert process.poll() is None, process.communicate()[1].decode()
        assert time.monotonic() < deadline, "the unit never strobed"
        time.sleep(0.01)


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_signal_switches_laser_off_and_exits_cleanly(tmp_path: Path, sig: int) -> None:
    state = tmp_path / "projector.state"
    process = start_unit(state, f"proc-{sig}")
    try:
        wait_until_lit(process, state)
        process.send_signal(sig)
        assert process.wait(timeout=20) == 0
    finally:
        process.kill()
        process.communicate()
    assert read_lit_until(state) == 0.0


def test_killed_process_leaves_laser_dark_after_the_lease(tmp_path: Path) -> None:
    state = tmp_path / "projector.state"
    process = start_unit(state, "proc-kill")
    try:
        wait_until_lit(process, state)
        process.send_signal(signal.SIGKILL)
        process.wait(timeout=10)
        killed_at = time.monotonic()
    finally:
        process.kill()
        process.communicate()
    lit_until = read_lit_until(state)
    assert lit_until > 0.0, "the node had no chance to switch off: the lease must end it"
    assert lit_until <= killed_at + LEASE_S
    time.sleep(LEASE_S)
    assert not is_lit_now(state)
