"""Run units: one in the foreground (``atris run``), or a launch file's units as threads on
one in-process bus or as supervised processes on a real bus (``atris launch``).

Process supervision escalates SIGINT -> SIGTERM -> SIGKILL (as ROS 2 launch does) and
restarts a unit that exits when the launch file asks for it, after a back-off that doubles
with each respawn (RESPAWN_BACKOFF_S). A unit that exits and is not (or no longer)
restarted is a failed unit: ``ProcessRun.failed`` names it and ``atris launch`` exits 1.
"""

from __future__ import annotations

import logging
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any

import can

from atris_node.bus.can import config as busconfig
from atris_node.config import Config
from atris_node.node.launch import LaunchSpec
from atris_node.node.unit import Unit
from atris_node.node.wiring import bus_settings

logger = logging.getLogger(__name__)

#: seconds to wait after SIGINT, then after SIGTERM, before the next signal
ESCALATION_S = (3.0, 2.0)
#: first respawn delay and its cap, seconds; the delay doubles with each respawn
RESPAWN_BACKOFF_S = (0.5, 8.0)


def open_bus(config: Config, **extra: Any) -> can.BusABC:
    """Open the python-can bus of a unit: its ``bus.*`` parameters that were set, then
    python-can's sources, then the defaults (:func:`wiring.bus_settings`)."""
    return busconfig.open_bus(bus_settings(config), **extra)


@contextmanager
def stop_on_signals(stop: threading.Event) -> Iterator[None]:
    """Set ``stop`` on SIGINT/SIGTERM while the block runs (main thread only)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    for sig in previous:
        signal.signal(sig, lambda *_: stop.set())
    try:
        yield
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)


def run_unit(config: Config, duration_s: float | None = None,
             stop: threading.Event | None = None, snapshot_dir: str | None = None) -> Unit:
    """Run one unit in the calling thread until ``duration_s`` passes or a signal arrives.

    The laser is off when this returns, whatever happened.
    """
    stop = stop or threading.Event()
    bus = open_bus(config)
    unit = Unit(config, bus)
    try:
        with stop_on_signals(stop):
            unit.configure()
            unit.activate(threaded=False)
            end = None if duration_s is None else time.monotonic() + duration_s
            while not stop.is_set() and (end is None or time.monotonic() < end):
                unit.step()
                unit.check()
    finally:
        if snapshot_dir:
            unit.snapshot(snapshot_dir)
        unit.shutdown()
        bus.shutdown()
    return unit


def _shifted(strobe: Callable[[float, float], float], shift_s: float
             ) -> Callable[[float, float], float]:
    return lambda t0, t1: strobe(t0 + shift_s, t1 + shift_s)


def couple_simulated_units(units: list[Unit]) -> int:
    """Let every simulated unit see the other units' projectors, as they really strobe.

    Each camera renders the others' line sheets with their recorded strobe timelines
    (shifted from their simulated clocks to this one's), so a code collision between
    units shows in the distortion maps. Returns the number of couplings made.
    """
    sims: list[Any] = [u.camera for u in units if hasattr(u.camera, "simulator")]
    made = 0
    for target in sims:
        for source in sims:
            if source is target:
                continue
            shift = target.time_origin_s - source.time_origin_s
            strobe = _shifted(source.projector.strobe_function(), shift)
            target.simulator.add_interferer(
                source.simulator.true_mounting, source.simulator.scene.projector,
                strobe, name=f"unit {source.simulator.unit}")
            made += 1
    return made


@dataclass
class FleetRun:
    """Units of a launch file running as threads on one in-process bus."""

    spec: LaunchSpec
    units: list[Unit] = field(default_factory=list)
    buses: list[can.BusABC] = field(default_factory=list)

    def start(self) -> None:
        """Configure every unit (laser off), then activate them all."""
        for config in self.spec.units:
            bus = open_bus(config)
            self.buses.append(bus)
            self.units.append(Unit(config, bus))
        for unit in self.units:
            unit.configure()
        couple_simulated_units(self.units)
        for unit in self.units:
            unit.activate(threaded=True)

    def check(self) -> None:
        """Re-raise a fault of any unit."""
        for unit in self.units:
            unit.check()

    def stop(self) -> None:
        """Shut every unit down (laser off) and close the buses; idempotent."""
        for unit in self.units:
            unit.shutdown()
        for bus in self.buses:
            bus.shutdown()
        self.buses.clear()


def unit_command(config: Config) -> list[str]:
    """The ``atris run`` command line of one unit of a launch file."""
    sets = [f"{k}={v}" for k, v, s in config.describe() if s != "default"]
    command = [sys.executable, "-m", "atris_node", "run"]
    for item in sets:
        command += ["--set", item]
    return command


@dataclass
class Supervised:
    """One unit process, its respawn count, when it may be respawned (monotonic s, None
    while it runs) and the exit code it ended with when it stays down."""

    config: Config
    process: subprocess.Popen[bytes] | None = None
    respawns: int = 0
    respawn_at_s: float | None = None
    gave_up: int | None = None

    @property
    def label(self) -> str:
        return str(self.config["unit.label"])


def respawn_delay(respawns: int) -> float:
    """Seconds before respawn number ``respawns + 1``: doubling from the first delay."""
    first, cap = RESPAWN_BACKOFF_S
    return float(min(cap, first * 2.0 ** min(respawns, 16)))


def escalate(process: subprocess.Popen[bytes], waits: tuple[float, float] = ESCALATION_S) -> int:
    """Stop a process: SIGINT, then SIGTERM, then SIGKILL; returns its exit code."""
    for sig, wait in ((signal.SIGINT, waits[0]), (signal.SIGTERM, waits[1])):
        if process.poll() is not None:
            break
        process.send_signal(sig)
        try:
            return process.wait(timeout=wait)
        except subprocess.TimeoutExpired:
            logger.warning("pid %d ignored %s", process.pid, signal.Signals(sig).name)
    if process.poll() is None:
        process.kill()
    return process.wait()


@dataclass
class ProcessRun:
    """Units of a launch file as supervised ``atris run`` processes."""

    spec: LaunchSpec
    spawn: Callable[[list[str]], subprocess.Popen[bytes]] = subprocess.Popen
    children: list[Supervised] = field(default_factory=list)

    def start(self) -> None:
        self.children = [Supervised(config) for config in self.spec.units]
        for child in self.children:
            child.process = self.spawn(unit_command(child.config))

    def supervise(self, now: float | None = None) -> None:
        """Respawn exited units within the launch file's limits, each after its back-off."""
        now = time.monotonic() if now is None else now
        for child in self.children:
            process = child.process
            if process is None or process.poll() is None or child.gave_up is not None:
                continue
            if not self.spec.respawn or child.respawns >= self.spec.max_respawns:
                child.gave_up = int(process.returncode)
                logger.error("unit %s exited with %s and stays down (%d of %d respawns used)",
                             child.label, process.returncode, child.respawns,
                             self.spec.max_respawns if self.spec.respawn else 0)
            elif child.respawn_at_s is None:
                child.respawn_at_s = now + respawn_delay(child.respawns)
                logger.warning("unit %s exited with %s; respawn %d of %d in %.1f s",
                               child.label, process.returncode, child.respawns + 1,
                               self.spec.max_respawns, child.respawn_at_s - now)
            elif now >= child.respawn_at_s:
                child.respawns += 1
                child.respawn_at_s = None
                child.process = self.spawn(unit_command(child.config))

    @property
    def failed(self) -> list[str]:
        """Labels of the units that exited and stay down."""
        return [child.label for child in self.children if child.gave_up is not None]

    def check(self) -> None:
        self.supervise()

    def stop(self) -> None:
        for child in self.children:
            if child.process is not None:
                escalate(child.process)
