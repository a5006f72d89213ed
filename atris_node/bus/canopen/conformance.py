"""EDS conformance: the file against CiA 306 and against what the device serves.

:data:`DEVICE_OBJECTS` is the device's side of the contract, written down independently
of the EDS: every object (index, sub-index) the device code serves, with its access and
data type and whether it may be mapped. :func:`problems` lists every way an EDS text
departs from it (an object missing, one too many, another access or type) and from the
CiA 306 file rules (object lists, SubNumber, sub-index 0, limits, PDO counts), and
whether the canopen package loads it. ``atris eds --check`` prints the list.
"""

from __future__ import annotations

import configparser
import re
import tempfile
from pathlib import Path

import canopen
from canopen.objectdictionary import datatypes

U8, U16, U32 = datatypes.UNSIGNED8, datatypes.UNSIGNED16, datatypes.UNSIGNED32
I16, TEXT = datatypes.INTEGER16, datatypes.VISIBLE_STRING
RO, RW, CONST = "ro", "rw", "const"
Spec = tuple[str, int, bool]  # access, data type, mappable


def _tpdo_objects() -> dict[tuple[int, int], Spec]:
    objects: dict[tuple[int, int], Spec] = {}
    for n in range(4):
        comm, mapping = 0x1800 + n, 0x1A00 + n
        objects.update({(comm, 0): (RO, U8, False), (comm, 1): (RW, U32, False),
                        (comm, 2): (RW, U8, False), (comm, 3): (RW, U16, False),
                        (comm, 5): (RW, U16, False), (mapping, 0): (RW, U8, False)})
        objects.update({(mapping, sub): (RW, U32, False) for sub in range(1, 9)})
    return objects


def _process_objects() -> dict[tuple[int, int], Spec]:
    objects: dict[tuple[int, int], Spec] = {}
    for index, kind in ((0x2100, U16), (0x2101, U8)):
        objects[(index, 0)] = (RO, U8, False)
        objects.update({(index, sub): (RO, kind, True) for sub in range(1, 17)})
    nearest = (U16, I16, I16, U16, U8, U8)  # Distance Bearing ClosingSpeed TTC Valid Warning
    status = (U8, U8, U8, U16, U16, U8, U16, U8, U8, U8, U8)
    for index, kinds in ((0x2110, nearest), (0x2120, status)):
        objects[(index, 0)] = (RO, U8, False)
        objects.update({(index, sub): (RO, kind, True) for sub, kind in enumerate(kinds, 1)})
    config = (U8, U8, U16, U16, U8, U16)  # see configuration.WRITABLE_IN
    objects[(0x2000, 0)] = (RO, U8, False)
    objects.update({(0x2000, sub): (RW, kind, False) for sub, kind in enumerate(config, 1)})
    return objects


#: (index, sub-index) -> (access, data type, mappable) of everything the device serves
DEVICE_OBJECTS: dict[tuple[int, int], Spec] = {
    (0x1000, 0): (RO, U32, False), (0x1001, 0): (RO, U8, True), (0x1005, 0): (RW, U32, False),
    (0x1008, 0): (CONST, TEXT, False), (0x1014, 0): (RW, U32, False),
    (0x1017, 0): (RW, U16, False), (0x1018, 0): (RO, U8, False),
    **{(0x1018, sub): (RO, U32, False) for sub in range(1, 5)},
    **_tpdo_objects(), **_process_objects(),
}
MANDATORY = (0x1000, 0x1001, 0x1018)
LISTS = ("MandatoryObjects", "OptionalObjects", "ManufacturerObjects")
ACCESS_TYPES = ("ro", "wo", "rw", "rwr", "rww", "const")


def problems(text: str) -> list[str]:
    """Every departure of EDS ``text`` from CiA 306 and from :data:`DEVICE_OBJECTS`."""
    eds = configparser.ConfigParser(interpolation=None)
    eds.optionxform = str  # type: ignore[assignment,method-assign]
    try:
        eds.read_string(text)
    except configparser.Error as exc:
        return [f"not an EDS: {exc}"]
    found = _load_problems(text)
    try:
        found += _list_problems(eds) + _pdo_count_problems(eds)
        variables = _variables(eds)
        found += _record_problems(eds, variables)
        for key, section in variables.items():
            found += _variable_problems(eds[section], section, key)
    except (ValueError, KeyError) as exc:
        return [*found, f"unreadable entry: {exc}"]
    for key in sorted(set(DEVICE_OBJECTS) - set(variables)):
        found.append(f"0x{key[0]:04X} sub {key[1]}: served by the device, not in the EDS")
    for key in sorted(set(variables) - set(DEVICE_OBJECTS)):
        found.append(f"0x{key[0]:04X} sub {key[1]}: in the EDS, not served by the device")
    return found


def _load_problems(text: str) -> list[str]:
    with tempfile.TemporaryDirectory() as directory:
        path = Path(directory) / "check.eds"
        path.write_text(text, encoding="utf-8")
        try:
            canopen.import_od(str(path), 1)
        except Exception as exc:  # whatever the importer raises is the finding
            return [f"the canopen package does not load it: {exc!r}"]
    return []


def _objects(eds: configparser.ConfigParser) -> list[int]:
    return [int(name, 16) for name in eds.sections() if re.fullmatch(r"[0-9A-Fa-f]{4}", name)]


def _list_problems(eds: configparser.ConfigParser) -> list[str]:
    found, listed = [], []
    for name in LISTS:
        entries = dict(eds[name]) if eds.has_section(name) else {}
        count = int(entries.pop("SupportedObjects", "0"), 0)
        if count != len(entries):
            found.append(f"[{name}] SupportedObjects={count} but {len(entries)} listed")
        indexes = [int(value, 0) for value in entries.values()]
        found += [f"[{name}] lists 0x{i:04X}, which belongs elsewhere"
                  for i in indexes if _list_of(i) != name]
        listed += indexes
    objects = _objects(eds)
    found += [f"0x{i:04X} listed but has no section" for i in listed if i not in objects]
    found += [f"0x{i:04X} has a section but is listed {listed.count(i)} times"
              for i in objects if listed.count(i) != 1]
    return found


def _list_of(index: int) -> str:
    """The object list of CiA 306 that ``index`` belongs in."""
    if index in MANDATORY:
        return LISTS[0]
    return LISTS[1] if index < 0x2000 else LISTS[2]


def _pdo_count_problems(eds: configparser.ConfigParser) -> list[str]:
    objects = _objects(eds)
    found = []
    for key, base in (("NrOfTXPDO", 0x1800), ("NrOfRXPDO", 0x1400)):
        declared = int(eds["DeviceInfo"].get(key, "0"), 0) if eds.has_section("DeviceInfo") else 0
        present = sum(1 for i in objects if base <= i < base + 0x200)
        if declared != present:
            found.append(f"[DeviceInfo] {key}={declared} but {present} objects")
    return found


def _variables(eds: configparser.ConfigParser) -> dict[tuple[int, int], str]:
    """(index, sub-index) -> section of every variable; sub-index lists checked too."""
    out: dict[tuple[int, int], str] = {}
    for index in _objects(eds):
        name = f"{index:04X}"
        section = eds[name] if eds.has_section(name) else eds[name.lower()]
        if int(section.get("ObjectType", "0x7"), 0) == 7:
            out[(index, 0)] = section.name
            continue
        subs = {int(m.group(1), 16): s for s in eds.sections()
                if (m := re.fullmatch(rf"{section.name}sub([0-9A-Fa-f]+)", s, re.I))}
        out.update({(index, sub): s for sub, s in subs.items()})
    return out


def _record_problems(eds: configparser.ConfigParser,
                     variables: dict[tuple[int, int], str]) -> list[str]:
    """Arrays and records: SubNumber counts the sub-indexes, sub-index 0 holds the
    highest one (the number of entries in force for PDO mappings)."""
    found = []
    for index in _objects(eds):
        section = eds[f"{index:04X}"]
        if int(section.get("ObjectType", "0x7"), 0) == 7:
            continue
        subs = sorted(sub for i, sub in variables if i == index)
        declared = int(section.get("SubNumber", "0"), 0)
        if declared != len(subs):
            found.append(f"0x{index:04X}: SubNumber={declared} but {len(subs)} sub-indexes")
        if not subs or subs[0] != 0:
            found.append(f"0x{index:04X}: no sub-index 0")
            continue
        highest = int(eds[variables[(index, 0)]].get("DefaultValue", "-1"), 0)
        mapping = 0x1600 <= index < 0x1800 or 0x1A00 <= index < 0x1C00
        if not (highest <= subs[-1] if mapping else highest == subs[-1]):
            found.append(f"0x{index:04X} sub 0: {highest}, the highest sub-index is {subs[-1]}")
    return found


def _variable_problems(section: configparser.SectionProxy, name: str,
                       key: tuple[int, int]) -> list[str]:
    where = f"0x{key[0]:04X} sub {key[1]} ({name})"
    access = section.get("AccessType", "").lower()
    kind = int(section.get("DataType", "0"), 0)
    mappable = section.get("PDOMapping", "0").strip() == "1"
    found = []
    if access not in ACCESS_TYPES:
        found.append(f"{where}: AccessType {access!r}")
    if mappable and access in ("wo", "const"):
        found.append(f"{where}: PDOMapping=1 on a {access} object")
    spec = DEVICE_OBJECTS.get(key)
    if spec is not None and (access, kind, mappable) != spec:
        found.append(f"{where}: access, type, mappable {(access, hex(kind), mappable)}, "
                     f"the device serves {(spec[0], hex(spec[1]), spec[2])}")
    return found + _value_problems(section, where, kind)


def _value_problems(section: configparser.SectionProxy, where: str, kind: int) -> list[str]:
    """The default within the type's range and LowLimit..HighLimit (numbers only)."""
    if kind not in datatypes.INTEGER_TYPES:
        return []
    default = section.get("DefaultValue", "0")
    value = sum(int(part, 0) for part in re.sub(r"\$NODEID", "0x7F", default, flags=re.I)
                .split("+"))  # the highest node ID: the widest value the default can take
    bits = {U8: 8, U16: 16, U32: 32, I16: 16}.get(kind, 64)
    lo, hi = (-(1 << (bits - 1)), (1 << (bits - 1)) - 1) if kind in datatypes.SIGNED_TYPES \
        else (0, (1 << bits) - 1)
    lo = max(lo, int(section.get("LowLimit", str(lo)), 0))
    hi = min(hi, int(section.get("HighLimit", str(hi)), 0))
    return [] if lo <= value <= hi else [f"{where}: DefaultValue {default} outside {lo}..{hi}"]
