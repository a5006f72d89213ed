"""The EMCY producer of the device: error register 0x1001 and the COB-ID of 0x1014.

EMCY goes out in PRE-OPERATIONAL and OPERATIONAL only (CiA 301) and not while 0x1014
has bit 31 (not valid) set; the error register records the error either way.
"""

from __future__ import annotations

import logging
from collections.abc import Callable

import can
import canopen

from atris_node.bus.canopen import nmt
from atris_node.bus.canopen.objects import ERROR_REGISTER

logger = logging.getLogger(__name__)

NOT_VALID, CAN_ID_MASK = 1 << 31, 0x7FF
SENDING_STATES = (nmt.PRE_OPERATIONAL, nmt.OPERATIONAL)


class EmcyService:
    """EMCY of ``node`` (a canopen LocalNode) while ``nmt_state()`` allows it."""

    def __init__(self, node: canopen.LocalNode, nmt_state: Callable[[], str]) -> None:
        self.node, self.nmt_state = node, nmt_state
        self.error_register = 0
        self.valid = True
        self.send_errors = 0  # EMCYs the bus refused

    def set_cob_id(self, cob_id: int) -> None:
        """0x1014 written (already checked): its CAN-ID and valid bit from now on."""
        self.node.emcy.cob_id = cob_id & CAN_ID_MASK
        self.valid = not cob_id & NOT_VALID

    def error(self, code: int, register_bits: int) -> None:
        """EMCY ``code`` with ``register_bits`` added to the error register."""
        self._register(self.error_register | register_bits)
        logger.warning("CANopen EMCY 0x%04X (error register 0x%02X)", code, self.error_register)
        self._send(code)

    def reset(self) -> None:
        """EMCY 0x0000: all errors cleared."""
        self._register(0)
        self._send(0)

    def _register(self, value: int) -> None:
        self.error_register = value
        od = self.node.object_dictionary[ERROR_REGISTER]
        assert isinstance(od, canopen.objectdictionary.ODVariable)
        self.node.data_store.setdefault(ERROR_REGISTER, {})[0] = od.encode_raw(value)

    def _send(self, code: int) -> None:
        if not self.valid or self.nmt_state() not in SENDING_STATES:
            logger.info("EMCY 0x%04X not sent (NMT %s)", code, self.nmt_state())
            return
        try:
            self.node.emcy.send(code, self.error_register)
        except can.CanError as exc:
            logger.error("EMCY 0x%04X not sent: %s", code, exc)
            self.send_errors += 1
