"""The CAN database built in code from the frame table (:mod:`atris_node.bus.can.layouts`).

:func:`build_database` makes the cantools database for a base ID: every unit's four
frames, the negotiation frames, the cycle times and the E2E attributes.
:func:`generate_text` writes it as DBC text in the usual section order (all ``BO_``, then
``CM_``, ``BA_DEF_``, ``BA_DEF_DEF_``, ``BA_``, ``VAL_``). The shipped ``atris.dbc`` is
``generate_text()`` for the default base; ``atris dbc --generate`` rewrites it and
``atris dbc --base-id 0x...`` prints the database of another base.

E2E attributes (message ``BO_`` and signal ``SG_`` attributes):

- ``E2EProfile``: ``Profile1`` for protected messages, else ``None``;
- ``E2EDataID``: the 16-bit data ID (the frame's CAN ID);
- ``E2EDataIDMode``: how the data ID enters the CRC, AUTOSAR's E2E_P01DataIDMode
  (``BOTH`` 0, ``ALT`` 1, ``LOW`` 2, ``NIBBLE`` 3); the node uses ``BOTH``;
- ``E2ESignalRole`` (signals): ``CRC`` or ``Counter``; the CRC's start bit is Profile 1's
  CRC offset, the counter's its counter offset.
"""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Iterator

from cantools.database.can import Bus, Database, Message, Node, Signal
from cantools.database.can.formats.dbc import (
    DbcAttribute,
    DbcAttributeDefinition,
    DbcSpecifics,
)
from cantools.database.conversion import BaseConversion

from atris_node.bus.can.ids import (
    DEFAULT_BASE_ID,
    MAX_UNIT_ID,
    SECTORS_PER_FRAME,
    FrameKind,
    frame_id,
    message_name,
)
from atris_node.bus.can.layouts import (
    NEGOTIATION_MESSAGES,
    UNIT_MESSAGES,
    MessageSpec,
    SignalSpec,
)
from atris_node.bus.negotiation import frames as nf

VERSION = "atris 2"
CONTROLLER = "Controller"
#: DBC's name for "any node": the receivers of negotiation frames are the other units
ANY_NODE = "Vector__XXX"
#: default publish period of the node, ms
CYCLE_MS = 50
#: default sector count: Sectors frames per cycle = DEFAULT_SECTORS / SECTORS_PER_FRAME
DEFAULT_SECTORS = 8
#: messages re-announced once a second by the negotiation
NEGOTIATION_CYCLE_MS = 1000
E2E_DATA_ID_MODES = ("BOTH", "ALT", "LOW", "NIBBLE")
E2E_MODE = "BOTH"
E2E_PROFILE = "Profile1"
COMMENT = (
    "ATRIS node CAN database, generated from the frame table of atris_node.bus.can.layouts. "
    "Unit frames: 11-bit IDs base + 4 * unit_id + offset (Status +0, Quality +1, Nearest +2, "
    "Sectors +3). Messages with E2EProfile Profile1 are protected by AUTOSAR E2E Profile 1 "
    "(E2EDataID, E2EDataIDMode; the signals with E2ESignalRole CRC and Counter). Negotiation "
    "frames: 29-bit IDs, one message per unit, kind and claimed row; see "
    "docs/negotiation.md")


def _definition(name: str, kind: str, type_name: str, default: int | str,
                *, limits: tuple[int, int] | None = None,
                choices: tuple[str, ...] = ()) -> DbcAttributeDefinition:
    lo, hi = limits if limits is not None else (None, None)
    return DbcAttributeDefinition(name, default_value=default, kind=kind, type_name=type_name,
                                  minimum=lo, maximum=hi, choices=list(choices) or None)


DEFINITIONS = OrderedDict((d.name, d) for d in (
    _definition("GenMsgCycleTime", "BO_", "INT", 0, limits=(0, 65535)),
    _definition("E2EProfile", "BO_", "ENUM", "None", choices=("None", E2E_PROFILE)),
    _definition("E2EDataID", "BO_", "INT", 0, limits=(0, 0xFFFF)),
    _definition("E2EDataIDMode", "BO_", "ENUM", E2E_MODE, choices=E2E_DATA_ID_MODES),
    _definition("E2ESignalRole", "SG_", "ENUM", "None", choices=("None", "CRC", "Counter")),
))


def _attribute(name: str, value: int | str) -> DbcAttribute:
    """Attribute ``name``; an ENUM value goes in by name and out as its index, as DBC
    files write ENUM values."""
    definition = DEFINITIONS[name]
    if isinstance(value, str):
        value = (definition.choices or []).index(value)
    return DbcAttribute(value, definition)


def _attributes(**values: int | str) -> OrderedDict[str, DbcAttribute]:
    return OrderedDict((name, _attribute(name, value)) for name, value in values.items())


def _signal(spec: SignalSpec, receivers: list[str]) -> Signal:
    role = _attributes(E2ESignalRole=spec.role) if spec.role else None
    return Signal(spec.name, spec.start, spec.length, is_signed=spec.signed,
                  conversion=BaseConversion.factory(spec.scale, spec.offset,
                                                    OrderedDict(spec.choices) or None),
                  minimum=spec.minimum, maximum=spec.maximum, unit=spec.unit or None,
                  comment=spec.comment, receivers=receivers,
                  dbc_specifics=None if role is None else DbcSpecifics(attributes=role))


def _message(spec: MessageSpec, can_id: int, name: str, sender: str, comment: str, *,
             extended: bool = False, cycle_ms: int | None = None,
             attributes: OrderedDict[str, DbcAttribute] | None = None) -> Message:
    receivers = [ANY_NODE] if extended else [CONTROLLER]
    return Message(can_id, name, 8, [_signal(s, receivers) for s in spec.signals],
                   comment=comment, senders=[sender], cycle_time=cycle_ms,
                   is_extended_frame=extended, strict=True,
                   dbc_specifics=DbcSpecifics(attributes=attributes or OrderedDict()))


def unit_cycle_ms(kind: FrameKind) -> int:
    """GenMsgCycleTime of a unit frame: the publish period, and for Sectors, sent
    DEFAULT_SECTORS / 2 times per cycle, the mean interval, rounded down (a bus-load
    estimate from the DBC stays on the safe side)."""
    if kind is not FrameKind.SECTORS:
        return CYCLE_MS
    return CYCLE_MS * SECTORS_PER_FRAME // DEFAULT_SECTORS


def unit_messages(base_id: int) -> Iterator[Message]:
    """The four frames of each of the sixteen units."""
    for unit_id in range(MAX_UNIT_ID + 1):
        for kind, spec in UNIT_MESSAGES.items():
            can_id = frame_id(unit_id, kind, base_id)
            e2e = _attributes(E2EProfile=E2E_PROFILE, E2EDataID=can_id,
                              E2EDataIDMode=E2E_MODE) if spec.e2e else None
            yield _message(spec, can_id, message_name(unit_id, kind), f"Atris{unit_id}",
                           f"Unit {unit_id} {spec.comment}", cycle_ms=unit_cycle_ms(kind),
                           attributes=e2e)


def negotiation_name(unit_id: int, kind: nf.FrameKind, field: int) -> str:
    """DBC name of a negotiation frame, e.g. ``Negotiation3_Claim5`` (row 5),
    ``Negotiation3_Leaving`` (the CANNOT_CLAIM of a unit that stops)."""
    suffix = NEGOTIATION_MESSAGES[kind].suffix
    if kind is nf.FrameKind.CLAIM:
        suffix += str(field)
    elif kind is nf.FrameKind.CANNOT_CLAIM and field == nf.LEAVING:
        suffix = "Leaving"
    return f"Negotiation{unit_id}_{suffix}"


def _negotiation_comment(spec: MessageSpec, unit_id: int, kind: nf.FrameKind,
                         field: int) -> str:
    detail = f", row {field}" if kind is nf.FrameKind.CLAIM else (
        ", leaving: it stops" if kind is nf.FrameKind.CANNOT_CLAIM and field else "")
    return f"Unit {unit_id}{detail}. {spec.comment}"


def negotiation_messages() -> Iterator[Message]:
    """One message per identifier a unit sends in code negotiation (every unit_id, kind
    and field value of :data:`~atris_node.bus.negotiation.frames.FIELDS`)."""
    repeated = (nf.FrameKind.CLAIM, nf.FrameKind.PLAN)
    for unit_id in range(MAX_UNIT_ID + 1):
        identity = nf.Identity(unit_id)
        for kind, spec in NEGOTIATION_MESSAGES.items():
            for field in nf.FIELDS[kind]:
                yield _message(spec, nf.make_id(kind, identity, field),
                               negotiation_name(unit_id, kind, field), f"Atris{unit_id}",
                               _negotiation_comment(spec, unit_id, kind, field),
                               extended=True,
                               cycle_ms=NEGOTIATION_CYCLE_MS if kind in repeated else None)


def build_database(base_id: int = DEFAULT_BASE_ID) -> Database:
    """The CAN database of a fleet whose unit frames start at ``base_id``."""
    nodes = [Node(f"Atris{u}") for u in range(MAX_UNIT_ID + 1)] + [Node(CONTROLLER)]
    messages = [*unit_messages(base_id), *negotiation_messages()]
    specifics = DbcSpecifics(attribute_definitions=OrderedDict(DEFINITIONS))
    return Database(messages, nodes, [Bus("", comment=COMMENT)], version=VERSION,
                    dbc_specifics=specifics, strict=True, sort_signals=None)


def generate_text(base_id: int = DEFAULT_BASE_ID) -> str:
    """DBC text of :func:`build_database` (``\\n`` line ends)."""
    text = build_database(base_id).as_dbc_string(sort_signals=None)
    return text.replace("\r\n", "\n")

