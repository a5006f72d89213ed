"""The CiA 301 NMT slave state machine and the heartbeat producer of the device.

Power-on and both resets pass through INITIALISING: the reset hooks restore the
parameters of their area, one boot-up message (0x700 + node ID, data 0x00) goes out and
the device enters PRE-OPERATIONAL by itself. Commands (0x000, ``[command, node ID]``,
node ID 0 for all)::

    0x01 start                  PRE-OPERATIONAL / STOPPED -> OPERATIONAL
    0x02 stop                   -> STOPPED
    0x80 enter pre-operational  -> PRE-OPERATIONAL
    0x81 reset node             application + communication reset, boot-up -> PRE-OPERATIONAL
    0x82 reset communication    communication reset, boot-up -> PRE-OPERATIONAL

Other command specifiers are ignored. The heartbeat (0x700 + node ID, the state byte) is
sent from :meth:`NmtSlave.tick`, at once after the boot-up and then every 0x1017 ms.
"""

from __future__ import annotations

import logging
import math
import struct
import threading
from collections.abc import Callable

import can
import canopen

logger = logging.getLogger(__name__)

INITIALISING, STOPPED = "INITIALISING", "STOPPED"
OPERATIONAL, PRE_OPERATIONAL = "OPERATIONAL", "PRE-OPERATIONAL"
#: NMT state -> its heartbeat byte (CiA 301)
STATE_CODES = {INITIALISING: 0x00, STOPPED: 0x04, OPERATIONAL: 0x05, PRE_OPERATIONAL: 0x7F}
CMD_START, CMD_STOP, CMD_PRE_OPERATIONAL = 0x01, 0x02, 0x80
CMD_RESET_NODE, CMD_RESET_COMMUNICATION = 0x81, 0x82
NMT_COB_ID, HEARTBEAT_BASE = 0x000, 0x700
NMT_COMMAND = struct.Struct("<BB")
ResetHook = Callable[[], None]


class NmtSlave:
    """NMT state, commands and heartbeat of node ``node_id`` on ``network``.

    Args:
        network: the connected canopen Network the device sends on.
        node_id: CANopen node ID (1..127).
        heartbeat_ms: returns the producer heartbeat time (0x1017), 0 = off.
        reset_communication: restores the communication parameters (0x1000-0x1FFF).
        reset_application: restores the application parameters (0x2000-0x9FFF).
    """

    def __init__(self, network: canopen.Network, node_id: int, *,
                 heartbeat_ms: Callable[[], int], reset_communication: ResetHook,
                 reset_application: ResetHook) -> None:
        self.network, self.node_id = network, node_id
        self.heartbeat_ms = heartbeat_ms
        self.reset_communication, self.reset_application = reset_communication, reset_application
        self.state = INITIALISING
        self.boot_ups = 0  # boot-up messages sent
        self.send_errors = 0  # boot-ups and heartbeats the bus refused
        self._last_heartbeat_s = -math.inf
        self._lock = threading.Lock()

    def boot(self, *, application: bool = True) -> None:
        """INITIALISING: the resets (the application's too unless ``application`` is
        False), one boot-up message, then PRE-OPERATIONAL with the heartbeat due at once."""
        with self._lock:
            self.state = INITIALISING
            if application:
                self.reset_application()
            self.reset_communication()
            self._send(bytes([STATE_CODES[INITIALISING]]))
            self.boot_ups += 1
            self.state = PRE_OPERATIONAL
            self._last_heartbeat_s = -math.inf
        logger.info("CANopen node %d booted, PRE-OPERATIONAL", self.node_id)

    def on_command(self, can_id: int, data: bytearray, timestamp: float) -> None:
        """NMT command frame (canopen subscriber callback)."""
        try:
            if len(data) < NMT_COMMAND.size:
                return
            command, node_id = NMT_COMMAND.unpack_from(data)
            if node_id in (0, self.node_id):
                self.command(command)
        except Exception:
            logger.exception("NMT command of node %d failed", self.node_id)

    def command(self, command: int) -> None:
        """Carry out NMT command specifier ``command`` (unknown ones are ignored)."""
        if command == CMD_RESET_NODE:
            self.boot(application=True)
        elif command == CMD_RESET_COMMUNICATION:
            self.boot(application=False)
        elif command in (CMD_START, CMD_STOP, CMD_PRE_OPERATIONAL):
            self._enter({CMD_START: OPERATIONAL, CMD_STOP: STOPPED,
                         CMD_PRE_OPERATIONAL: PRE_OPERATIONAL}[command])
        else:
            logger.warning("NMT command 0x%02X for node %d ignored", command, self.node_id)

    def _enter(self, state: str) -> None:
        with self._lock:
            if state != self.state:
                logger.info("CANopen node %d: NMT %s -> %s", self.node_id, self.state, state)
            self.state = state

    def tick(self, now: float) -> None:
        """Send the heartbeat when one is due at ``now`` (seconds, monotonic)."""
        period_ms = self.heartbeat_ms()
        with self._lock:
            if not period_ms or now - self._last_heartbeat_s < period_ms / 1000.0:
                return
            self._last_heartbeat_s = now
            self._send(bytes([STATE_CODES[self.state]]))

    def _send(self, data: bytes) -> None:
        try:
            self.network.send_message(HEARTBEAT_BASE + self.node_id, data)
        except can.CanError as exc:
            logger.error("NMT message of node %d not sent: %s", self.node_id, exc)
            self.send_errors += 1
