"""EDS conformance: the shipped file passes the checker, the checker catches each kind of
departure, and a canopen master finds the running device serving exactly the EDS."""

from __future__ import annotations

from pathlib import Path

import canopen
import pytest
from canopen.objectdictionary import ODVariable, datatypes
from canopen.sdo import SdoAbortedError
from canopen_pair import NODE_ID, Pair

from atris_node.bus.canopen.conformance import DEVICE_OBJECTS, problems
from atris_node.bus.canopen.device import eds_path, eds_text

#: objects a CANopen device often has that this one does not
NOT_SERVED = (0x1002, 0x1003, 0x1006, 0x1010, 0x1011, 0x1012, 0x1016, 0x1200, 0x1400,
              0x1600, 0x1804, 0x1A04, 0x2001, 0x2102, 0x2111, 0x6000)




def test_shipped_eds_conforms_and_loads() -> None:
    """The shipped EDS against DEVICE_OBJECTS (drop 0x1014 from it and this fails)."""
    assert problems(eds_text()) == []
    od = canopen.import_od(str(eds_path()), NODE_ID)
    assert od[0x1014].default == 0x80 + NODE_ID


def _without_section(text: str, name: str) -> str:
    start = text.index(f"[{name}]\n")
    end = text.index("\n[", start + 1) + 1
    return text[:start] + text[end:]


@pytest.mark.parametrize(("change", "finding"), [
    (lambda t: _without_section(t, "1014").replace("3=0x1014\n", ""),
     "0x1014 sub 0: served by the device, not in the EDS"),
    (lambda t: t.replace("[2000sub1]\nParameterName=CodeLength\nObjectType=0x7\n"
                         "DataType=0x0005\nAccessType=rw",
                         "[2000sub1]\nParameterName=CodeLength\nObjectType=0x7\n"
                         "DataType=0x0005\nAccessType=ro"),
     "0x2000 sub 1 (2000sub1): access, type, mappable ('ro'"),
    (lambda t: t.replace("[2110sub2]\nParameterName=Bearing_cdeg\nObjectType=0x7\n"
                         "DataType=0x0003", "[2110sub2]\nParameterName=Bearing_cdeg\n"
                         "ObjectType=0x7\nDataType=0x0006"),
     "0x2110 sub 2 (2110sub2): access, type, mappable ('ro', '0x6'"),
    (lambda t: t + "\n[2200]\nParameterName=Extra\nObjectType=0x7\nDataType=0x0005\n"
                   "AccessType=ro\nDefaultValue=0\nPDOMapping=0\n",
     "0x2200 has a section but is listed 0 times"),
    (lambda t: t + "\n[2200]\nParameterName=Extra\nObjectType=0x7\nDataType=0x0005\n"
                   "AccessType=ro\nDefaultValue=0\nPDOMapping=0\n",
     "0x2200 sub 0: in the EDS, not served by the device"),
    (lambda t: t.replace("SubNumber=7\n\n[2000sub0]", "SubNumber=6\n\n[2000sub0]"),
     "0x2000: SubNumber=6 but 7 sub-indexes"),
    (lambda t: t.replace("[2120sub0]\nParameterName=Highest sub-index supported\n"
                         "ObjectType=0x7\nDataType=0x0005\nAccessType=ro\nDefaultValue=11",
                         "[2120sub0]\nParameterName=Highest sub-index supported\n"
                         "ObjectType=0x7\nDataType=0x0005\nAccessType=ro\nDefaultValue=12"),
     "0x2120 sub 0: 12, the highest sub-index is 11"),
    (lambda t: t.replace("SupportedObjects=12", "SupportedObjects=11"),
     "[OptionalObjects] SupportedObjects=11 but 12 listed"),
    (lambda t: t.replace("NrOfTXPDO=4", "NrOfTXPDO=3"), "[DeviceInfo] NrOfTXPDO=3 but 4"),
    (lambda t: t.replace("DefaultValue=200\nPDOMapping=0\nLowLimit=10",
                         "DefaultValue=5\nPDOMapping=0\nLowLimit=10"),
     "0x2000 sub 4 (2000sub4): DefaultValue 5 outside 10..5000"),
    (lambda t: t.replace("1=0x2000\n", "1=0x1000\n"),
     "[ManufacturerObjects] lists 0x1000, which belongs elsewhere"),
    (lambda t: t.replace("DataType=0x0009", "DataType=0x00ZZ"),
     "the canopen package does not load it"),
])
def test_the_checker_finds_each_departure(change: object, finding: str) -> None:
    """Each broken copy of the shipped EDS gets its finding (and the shipped one none:
    the checker is no constant)."""
    found = problems(change(eds_text()))  # type: ignore[operator]
    assert any(line.startswith(finding) for line in found), found


def _size_bits(od: ODVariable) -> int | None:
    return None if od.data_type not in datatypes.NUMBER_TYPES else len(od)


def test_the_device_serves_every_eds_object_as_declared(pair: Pair) -> None:
    """Every EDS variable reads back with its type's size; ro/const writes get
    0x06010002; rw ones take their own value back, except the TPDO mappings, which
    change only through the CiA 301 procedure (0x08000022). (Refuse a TPDO COB-ID
    written back unchanged and this fails.)"""
    pair.device.start()
    od = pair.master.object_dictionary
    assert {(index, sub) for index, sub in DEVICE_OBJECTS} == {
        (v.index, v.subindex) for v in _variables(od)}
    for variable in _variables(od):
        data = pair.master.sdo.upload(variable.index, variable.subindex)
        bits = _size_bits(variable)
        assert bits is None or len(data) * 8 == bits, variable.name
        code = _write_back(pair, variable, data)
        if variable.access_type in ("ro", "const"):
            assert code == 0x06010002, variable.name
        elif 0x1A00 <= variable.index < 0x1C00:
            assert code == 0x08000022, variable.name
        else:
            assert code is None, (variable.name, hex(code or 0))


def test_the_device_serves_nothing_beyond_the_eds(pair: Pair) -> None:
    """Objects outside the EDS: 0x06020000; sub-indexes past an array's last one:
    0x06090011 (canopen's ODArray answers any sub-index: drop the device's _on_read
    check and sector 16 of 0x2100 reads as 0xFFFF)."""
    pair.device.start()
    for index in NOT_SERVED:
        with pytest.raises(SdoAbortedError) as info:
            pair.master.sdo.upload(index, 0)
        assert info.value.code == 0x06020000, hex(index)
    for index in (0x2100, 0x2101):
        with pytest.raises(SdoAbortedError) as info:
            pair.master.sdo.upload(index, 0x11)
        assert info.value.code == 0x06090011
        with pytest.raises(SdoAbortedError):
            pair.master.sdo.download(index, 0x11, b"\x00\x00")


def test_atris_eds_check(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from atris_node.cli import main

    assert main(["eds", "--check"]) == 0
    assert capsys.readouterr().out == "EDS conforms\n"
    broken = tmp_path / "broken.eds"
    broken.write_text(eds_text().replace("NrOfTXPDO=4", "NrOfTXPDO=2"), encoding="utf-8")
    assert main(["eds", "--check", str(broken)]) == 1
    assert "NrOfTXPDO=2 but 4 objects" in capsys.readouterr().out


def _variables(od: canopen.ObjectDictionary) -> list[ODVariable]:
    out: list[ODVariable] = []
    for entry in od.values():
        out += [entry] if isinstance(entry, ODVariable) else list(entry.values())
    return out


def _write_back(pair: Pair, variable: ODVariable, data: bytes) -> int | None:
    try:
        pair.master.sdo.download(variable.index, variable.subindex, data)
    except SdoAbortedError as exc:
        return int(exc.code)
    return None
