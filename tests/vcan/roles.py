"""Roles a vcan test runs as separate processes: ``python roles.py ROLE ARGS...``.

Each role opens its own python-can ``socketcan`` bus, prints JSON lines on stdout
(``{"event": "ready"}`` once its bus is open, ``{"event": "done", ...}`` at the end) and
runs until it has finished its work or, for open-ended roles, until its stdin is closed.
Times are ``time.time()`` seconds, the clock SocketCAN stamps received frames with.
"""

from __future__ import annotations

import importlib
import json
import logging
import os
import selectors
import signal
import struct
import sys
import time
import traceback
from collections.abc import Callable
from typing import Any

import can

SEQ_FRAME = struct.Struct("<IHxx")  # sequence number, sender's unit id


def emit(event: str, **fields: Any) -> None:
    """Prints one JSON line for the parent test and flushes it."""
    print(json.dumps({"event": event, **fields}), flush=True)


class StdinWatch:
    """Non-blocking check whether the parent closed our stdin (the stop request)."""

    def __init__(self) -> None:
        self._selector = selectors.DefaultSelector()
        self._selector.register(sys.stdin, selectors.EVENT_READ)
        self.closed = False

    def poll(self, timeout_s: float = 0.0) -> bool:
        """True once stdin reached end of file; waits at most ``timeout_s`` seconds."""
        if not self.closed and self._selector.select(timeout_s):
            self.closed = sys.stdin.readline() == ""
        return self.closed


def open_bus(channel: str, *filters: int) -> can.BusABC:
    """A socketcan bus on ``channel``; with ``filters``, only those standard ids arrive."""
    can_filters = [{"can_id": i, "can_mask": 0x7FF, "extended": False} for i in filters]
    return can.Bus(interface="socketcan", channel=channel, can_filters=can_filters or None)


def sender(channel: str, arb_id: str, count: str, period_s: str) -> None:
    """Sends ``count`` sequence frames every ``period_s``; reports each send time."""
    sent: list[float] = []
    with open_bus(channel) as bus:
        emit("ready")
        for seq in range(int(count)):
            sent.append(time.time())
            bus.send(can.Message(arbitration_id=int(arb_id, 0), is_extended_id=False,
                                 data=SEQ_FRAME.pack(seq, 0)))
            time.sleep(float(period_s))
    emit("done", sent=sent)


def echo(channel: str, rx_id: str, tx_id: str) -> None:
    """Answers every frame with id ``rx_id`` by the same data on ``tx_id``, until stopped."""
    stop, answered = StdinWatch(), 0
    with open_bus(channel, int(rx_id, 0)) as bus:
        emit("ready")
        while not stop.poll():
            msg = bus.recv(0.05)
            if msg is not None:
                bus.send(can.Message(arbitration_id=int(tx_id, 0), is_extended_id=False,
                                     data=msg.data))
                answered += 1
    emit("done", answered=answered)


def babbler(channel: str, arb_id: str) -> None:
    """Floods the bus with ``arb_id`` frames as fast as it can (cangen -g 0), until stopped."""
    stop, sent, errors, start = StdinWatch(), 0, 0, time.monotonic()
    msg = can.Message(arbitration_id=int(arb_id, 0), is_extended_id=False, data=bytes(8))
    with open_bus(channel, 0x7FF) as bus:
        emit("ready")
        while not (sent % 256 == 0 and stop.poll()):
            try:
                bus.send(msg, timeout=0.01)
                sent += 1
            except can.CanOperationError:
                errors += 1
    elapsed = time.monotonic() - start
    emit("done", sent=sent, errors=errors, frames_per_s=sent / elapsed)


def periodic(channel: str, arb_id: str, period_s: str) -> None:
    """Sends sequence frames on an absolute schedule, measuring its own send period."""
    stop, period, errors = StdinWatch(), float(period_s), 0
    periods: list[float] = []
    with open_bus(channel, 0x7FF) as bus:
        emit("ready")
        seq, next_at, last = 0, time.monotonic(), None
        while not stop.poll(max(next_at - time.monotonic(), 0.0)):
            now = time.monotonic()
            if now < next_at:
                continue
            try:
                bus.send(can.Message(arbitration_id=int(arb_id, 0), is_extended_id=False,
                                     data=SEQ_FRAME.pack(seq, 0)), timeout=period)
            except can.CanOperationError:
                errors += 1
            periods += [] if last is None else [now - last]
            seq, last, next_at = seq + 1, now, next_at + period
    emit("done", sent=seq, errors=errors, periods=periods)


def sector_distance_m(index: int, counter: int) -> float:
    """The distance the publisher role reports for sector ``index`` of measurement ``counter``."""
    return 2.0 + 0.25 * index + 0.001 * counter


def measurement(counter: int, sector_count: int, newest_time_s: float) -> Any:
    """A Measurement whose sector distances follow :func:`sector_distance_m`."""
    from atris_node.types import Measurement, SectorDistance, SectorState

    sectors = tuple(SectorDistance(i, 0.1 * (sector_count / 2 - i), SectorState.VALID,
                                   sector_distance_m(i, counter), 0.9, 40)
                    for i in range(sector_count))
    return Measurement(counter, sectors, newest_time_s, 16 * counter, nearest=sectors[0])


def publisher(channel: str, unit_id: str, period_s: str, update_s: str) -> None:
    """A unit's Publisher fed a new measurement every ``update_s``, until stopped.

    Emits ``measurement`` events with the wall-clock time of the measurement's newest
    sub-frame, so the test can compare it with the kernel receive timestamps.
    """
    from atris_node.bus.can.publisher import Publisher
    from atris_node.types import UnitState, UnitStatus

    stop, counter = StdinWatch(), 0
    status = UnitStatus(UnitState.RUNNING, 3, 16, 480.0, 0)
    with open_bus(channel, 0x7FF) as bus:
        status_sent = record_status_sends(bus, int(unit_id))
        pub = Publisher(bus, int(unit_id), period_s=float(period_s), sector_count=4)
        pub.start()
        emit("ready")
        try:
            while not stop.poll(float(update_s)):
                wall_s, newest_s = time.time(), time.monotonic()
                pub.update(measurement(counter, 4, newest_s), status)
                emit("measurement", counter=counter, sub_frame_wall_s=wall_s)
                counter += 1
        finally:
            pub.stop()
    pub.check()
    emit("done", frames_sent=pub.stats.frames_sent, send_errors=pub.stats.send_errors,
         status_sent=status_sent, late_sends=list(pub.late_sends))


def record_status_sends(bus: can.BusABC, unit_id: int) -> list[tuple[float, int]]:
    """Wraps ``bus.send``: each of the unit's Status frames the bus took is noted as
    (``time.monotonic()`` of the call, its fault byte 2); returns the list it fills."""
    from atris_node.bus.can.ids import FrameKind, frame_id

    status_id, sent, send = frame_id(unit_id, FrameKind.STATUS), list[tuple[float, int]](), bus.send

    def recorded(msg: can.Message, timeout: float | None = None) -> None:
        handed_s = time.monotonic()
        send(msg, timeout)  # a frame the bus refused (raised) is not noted
        if msg.arbitration_id == status_id:
            sent.append((handed_s, int(msg.data[2])))

    bus.send = recorded  # type: ignore[method-assign]
    return sent


def canopen_slave(channel: str, node_id: str, update_s: str) -> None:
    """The unit as a CANopen slave (CanopenDevice) fed a measurement every ``update_s``."""
    import canopen

    from atris_node.bus.canopen.device import CanopenDevice
    from atris_node.types import UnitState, UnitStatus

    stop, counter = StdinWatch(), 0
    network = canopen.Network()
    network.connect(interface="socketcan", channel=channel)
    device = CanopenDevice(network, int(node_id, 0))
    try:
        device.start()
        emit("ready")
        while not stop.poll(float(update_s)):
            status = UnitStatus(UnitState.RUNNING, 3, 16, 480.0, counter)
            device.update(measurement(counter, 4, time.monotonic()), status)
            counter += 1
    finally:
        device.stop()
        network.disconnect()
    device.check()
    emit("done", nmt_state=device.nmt_state, updates=counter)


class Stall(can.Listener):
    """Blocks the receive thread on its first frame for ``seconds``: a starved thread."""

    def __init__(self, seconds: float) -> None:
        self.seconds, self.done = seconds, seconds <= 0.0

    def on_message_received(self, msg: can.Message) -> None:
        if not self.done:
            self.done = True
            time.sleep(self.seconds)


def negotiator(channel: str, name: str, unit_id: str, code_length: str,
               stall_s: str = "0") -> None:
    """A unit's Negotiator on its own socketcan bus; emits every change of what it may do.
    With ``stall_s`` its receive thread stalls that long on the first frame it gets."""
    from atris_node.bus.negotiation.machine import Negotiator
    from atris_node.bus.negotiation.plan import Plan
    from atris_node.errors import BusError

    stop, reported, bus_errors = StdinWatch(), 0, 0
    with can.Bus(interface="socketcan", channel=channel) as bus:
        notifier = can.Notifier(bus, [Stall(float(stall_s))], timeout=0.1)
        unit = Negotiator(bus, int(name, 0), Plan(int(code_length), 480.0), int(unit_id),
                          notifier=notifier)
        unit.start()
        emit("ready")
        try:
            while not stop.poll(0.02):
                try:
                    unit.tick()
                except BusError as exc:  # laser already off; the negotiation goes on
                    bus_errors += 1
                    emit("bus_error", t=time.monotonic(), error=str(exc))
                reported = _emit_timeline(unit, reported)
        finally:
            unit.stop()
            notifier.stop()
    _emit_timeline(unit, reported)
    emit("done", hops=unit.hop_count, malformed=unit.malformed_frames,
         deferrals=unit.receive.deferrals, bus_errors=bus_errors)


def _emit_timeline(unit: Any, reported: int) -> int:
    """Emits the strobe-timeline entries after the first ``reported``; returns the count.

    Each entry carries the time the negotiator changed it (CLOCK_MONOTONIC, system-wide),
    whichever thread did, not the time this loop noticed.
    """
    timeline = list(unit.timeline)
    for t, strobe, row in timeline[reported:]:
        emit("state", t=t, state=unit.state.name, code_row=row, strobe=strobe)
    return len(timeline)


def atris(*argv: str) -> None:
    """The ``atris`` command itself (e.g. ``run --set bus.interface=socketcan ...``)."""
    from atris_node.cli import main

    emit("ready")
    code = main(list(argv))
    emit("done", exit_code=code)


#: modules the zygote imports once, so forked units start at once
PRELOAD = ("numpy", "can.interfaces.socketcan", "cantools", "canopen", "atris_node.types",
           "atris_node.bus.can.frames", "atris_node.bus.can.publisher",
           "atris_node.bus.canopen.device", "atris_node.bus.negotiation.machine",
           "atris_node.node.runner", "atris_node.cli.run")


def run_pipeline_once() -> None:
    """One simulated block of maps through the pipeline: every numba kernel of the
    simulator, the demodulator and the pipeline is compiled (or loaded from numba's cache)
    and typed for its first call."""
    from atris_node.bench.safety import LAYOUT, block_maps
    from atris_node.pipeline.chain import Pipeline, PipelineConfig
    from atris_node.sim import load_scene

    sim, maps = block_maps(load_scene("indoor_lab"), 1)
    Pipeline(PipelineConfig(), sim.calibration(), sim.mounting, LAYOUT).process(next(maps))


def warm_kernels() -> None:
    """Compile the kernels once, here: forked units inherit them and start at once (in the
    VM numba may find no writable cache, and each unit compiled for 90 s, over 150 s beside
    a CPU-heavy process). ``scripts/vcan-tests.sh`` runs this on the host first (``roles.py
    warm``) into the VM's numba cache, so that in the VM it only loads."""
    started = time.monotonic()
    try:
        run_pipeline_once()
    except Exception as exc:  # the units then compile for themselves, as before
        print(f"zygote: kernels not warmed: {exc!r}", file=sys.stderr)
    print(f"zygote: kernels warmed in {time.monotonic() - started:.1f} s", file=sys.stderr)


def zygote() -> None:
    """Pre-loads PRELOAD, then forks one unit per JSON request line on stdin.

    A request is ``{"id", "role", "args", "stdin", "stdout"}`` (the last two are FIFO
    paths); the answer is ``{"id": ..., "pid": ...}``. Children are reaped at once
    (SIGCHLD ignored). Once preloaded it says so with the answer of id 0.
    """
    for name in PRELOAD:
        try:
            importlib.import_module(name)
        except ImportError as exc:
            print(f"zygote: not preloaded: {name} ({exc})", file=sys.stderr)
    warm_kernels()
    signal.signal(signal.SIGCHLD, signal.SIG_IGN)
    print(json.dumps({"id": 0, "pid": os.getpid()}), flush=True)  # preloaded: ready to fork
    while line := sys.stdin.readline():
        request = json.loads(line)
        pid = os.fork()
        if pid == 0:
            run_child(request)
        print(json.dumps({"id": request["id"], "pid": pid}), flush=True)


def run_child(request: dict[str, Any]) -> None:
    """In a forked unit: FIFOs become stdin/stdout, then the role runs; never returns."""
    code = 1
    try:
        signal.signal(signal.SIGCHLD, signal.SIG_DFL)
        for fd, path, mode in ((0, request["stdin"], os.O_RDONLY),
                               (1, request["stdout"], os.O_WRONLY)):
            opened = os.open(path, mode)
            os.dup2(opened, fd)
            os.close(opened)
        sys.stdin, sys.stdout = open(0, closefd=False), open(1, "w", closefd=False)  # noqa: SIM115
        ROLES[request["role"]](*request["args"])
        code = 0
    except BaseException:
        traceback.print_exc()
    finally:
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(code)


ROLES: dict[str, Callable[..., None]] = {
    "sender": sender, "echo": echo, "babbler": babbler, "periodic": periodic,
    "publisher": publisher, "canopen_slave": canopen_slave, "negotiator": negotiator,
    "atris": atris,
}

if __name__ == "__main__":
    logging.basicConfig(level=logging.INFO, stream=sys.stderr,
                        format="%(process)d %(relativeCreated)8.0f %(name)s: %(message)s")
    if sys.argv[1] == "zygote":
        zygote()
    elif sys.argv[1] == "warm":
        run_pipeline_once()
    else:
        ROLES[sys.argv[1]](*sys.argv[2:])
