"""The configuration object 0x2000: when each entry may be written and which values fit.

=====  ==================  ====================  ==========================================
sub    entry               writable in           takes effect
=====  ==================  ====================  ==========================================
1      CodeLength          PRE-OPERATIONAL       the node asks the bus for that code length
2      SectorCount         PRE-OPERATIONAL       next TPDO: the measured sectors re-binned
3      PublishPeriod_ms    PRE-OP, OPERATIONAL   next event: event-driven TPDOs without
                                                 an event timer of their own
4      MaxDataAge_ms       PRE-OP, OPERATIONAL   next TPDO (older distances go invalid)
5      MinConfidence_pct   PRE-OP, OPERATIONAL   next TPDO (less confident sectors invalid)
6      WarningDistance_mm  PRE-OP, OPERATIONAL   next TPDO (0x2110 sub 6 Warning)
=====  ==================  ====================  ==========================================

No SDO is answered in STOPPED (CiA 301), so no entry is written there. The power-on values
are the node's own settings (:func:`power_on_values`); an NMT reset node restores them.
"""

from __future__ import annotations

from collections.abc import Mapping

from canopen.objectdictionary import ODArray, ODRecord, ODVariable
from canopen.sdo import SdoAbortedError

from atris_node.bus.canopen import nmt
from atris_node.bus.canopen.objects import ABORT_RANGE, ABORT_STATE, ABORT_TOO_HIGH, ABORT_TOO_LOW
from atris_node.errors import ConfigError

LIVE = frozenset({nmt.PRE_OPERATIONAL, nmt.OPERATIONAL})
#: entry -> the NMT states in which an SDO write to it is taken
WRITABLE_IN: dict[str, frozenset[str]] = {
    "CodeLength": frozenset({nmt.PRE_OPERATIONAL}),
    "SectorCount": frozenset({nmt.PRE_OPERATIONAL}),
    "PublishPeriod_ms": LIVE, "MaxDataAge_ms": LIVE, "MinConfidence_pct": LIVE,
    "WarningDistance_mm": LIVE,
}


def check_write(od: ODVariable, value: int, state: str, power_on: Mapping[str, int]) -> None:
    """Raise SdoAbortedError when ``value`` may not be written to entry ``od`` in NMT
    ``state``: 0x08000022 in the wrong state, else as :func:`check_value`."""
    if state not in WRITABLE_IN[od.name]:
        raise SdoAbortedError(ABORT_STATE)
    check_value(od, value, power_on)


def check_value(od: ODVariable, value: int, power_on: Mapping[str, int]) -> None:
    """Raise SdoAbortedError unless ``value`` fits entry ``od``: 0x06090032 below the
    EDS LowLimit, 0x06090031 above the HighLimit or more sectors than the node measures,
    0x06090030 a code length that is no power of two or a sector count that does not
    divide the measured one (the sectors could not be re-binned)."""
    if od.min is not None and value < od.min:
        raise SdoAbortedError(ABORT_TOO_LOW)
    if od.max is not None and value > od.max:
        raise SdoAbortedError(ABORT_TOO_HIGH)
    if od.name == "CodeLength" and value & (value - 1):
        raise SdoAbortedError(ABORT_RANGE)
    if od.name == "SectorCount":
        measured = power_on["SectorCount"]
        if value > measured:
            raise SdoAbortedError(ABORT_TOO_HIGH)
        if measured % value:
            raise SdoAbortedError(ABORT_RANGE)


def power_on_values(record: ODArray | ODRecord | ODVariable,
                    settings: Mapping[str, int]) -> dict[str, int]:
    """The entries of ``record`` (0x2000): the EDS defaults, replaced by ``settings``.

    Raises:
        ConfigError: a name that is no entry, or a value the entry does not accept.
    """
    assert isinstance(record, ODRecord), "0x2000 is a record in the EDS"
    entries = {od.name: od for od in record.values() if od.subindex}
    values = {name: int(od.default) for name, od in entries.items()}
    for name, value in settings.items():
        if name not in entries:
            raise ConfigError(f"CANopen configuration {name!r}: no such entry of 0x2000; "
                              f"known: {', '.join(entries)}")
        values[name] = int(value)
    for name, value in values.items():
        try:
            check_value(entries[name], value, values)
        except SdoAbortedError as exc:
            raise ConfigError(f"CANopen configuration {name} = {value} is not accepted "
                              f"(SDO abort 0x{exc.code:08X})") from exc
    return values
