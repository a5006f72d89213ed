"""Bus settings in python-can's order for ``atris monitor`` and the node alike: arguments >
CAN_CHANNEL (and the other CAN_* variables) > CAN_CONFIG > ~/.canrc > defaults.

HOME is an empty folder in every test (conftest), so the machine's own ~/.canrc stays out.
"""

from __future__ import annotations

import json
import uuid
from pathlib import Path

import can
import pytest

from atris_node import config as cfg
from atris_node.bus.can.config import (
    DEFAULT_BITRATE,
    DEFAULT_CHANNEL,
    DEFAULT_INTERFACE,
    BusConfig,
    resolve,
)
from atris_node.bus.can.publisher import Publisher
from atris_node.cli import main
from atris_node.node.runner import open_bus
from atris_node.node.wiring import bus_settings
from atris_node.types import UnitState, UnitStatus

#: lowest first
LEVELS = ("defaults", "canrc", "CAN_CONFIG", "CAN_CHANNEL", "arguments")
UNIT_ID = 5


def _configure(levels: tuple[str, ...], home: Path, monkeypatch: pytest.MonkeyPatch
               ) -> tuple[dict[str, str], str]:
    """A channel of its own at each of ``levels`` (none of them names an interface); the
    channel expected, the highest level's. Returns the channels and the expected one."""
    channels = {level: f"{level}-{uuid.uuid4().hex[:8]}" for level in levels}
    channels["defaults"] = DEFAULT_CHANNEL
    if "canrc" in levels:
        (home / ".canrc").write_text(f"[default]\nchannel = {channels['canrc']}\n")
    if "CAN_CONFIG" in levels:
        monkeypatch.setenv("CAN_CONFIG", json.dumps({"channel": channels["CAN_CONFIG"]}))
    if "CAN_CHANNEL" in levels:
        monkeypatch.setenv("CAN_CHANNEL", channels["CAN_CHANNEL"])
    return channels, channels[levels[-1]]


def _up_to(highest: str) -> tuple[str, ...]:
    return LEVELS[:LEVELS.index(highest) + 1]


@pytest.mark.parametrize("highest", LEVELS)
def test_monitor_listens_where_the_highest_level_says(
        highest: str, no_python_can_config: Path, monkeypatch: pytest.MonkeyPatch,
        capsys: pytest.CaptureFixture[str]) -> None:
    """A unit publishes on the channel of the highest level configured; ``atris monitor``
    sees it only if it listens there and not on a lower level's channel. With nothing
    configured it opens virtual/atris (it failed with 'Unknown interface type None').
    Checked by reading python-can's config files before its environment: the CAN_CONFIG
    and CAN_CHANNEL cases failed, for the monitor and the node."""
    channels, expected = _configure(_up_to(highest), no_python_can_config, monkeypatch)
    argv = ["monitor", "--duration", "0.3", "--json"]
    if highest == "arguments":
        argv += ["--channel", channels["arguments"]]
    with can.Bus(interface="virtual", channel=expected) as tx:
        publisher = Publisher(tx, UNIT_ID, period_s=0.02)
        publisher.update(None, UnitStatus(UnitState.INIT, 0, 0, 0.0, 0))
        publisher.start()
        try:
            code = main(argv)
        finally:
            publisher.stop()
    assert code == 0
    assert str(UNIT_ID) in json.loads(capsys.readouterr().out)["units"]


def _node_config(levels: tuple[str, ...], channels: dict[str, str]) -> cfg.Config:
    overrides = [f"bus.channel={channels['arguments']}"] if "arguments" in levels else []
    return cfg.load(environ={}, overrides=overrides)


@pytest.mark.parametrize("highest", LEVELS)
def test_node_opens_the_bus_the_highest_level_names(
        highest: str, no_python_can_config: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The node follows the same order; its ``bus.*`` parameters count as arguments only
    when they were set (here with --set), not with their default values. Checked by
    passing every bus.* parameter (defaults included) as arguments: the node stayed on
    'atris' whatever CAN_CHANNEL, CAN_CONFIG and ~/.canrc said."""
    levels = _up_to(highest)
    channels, expected = _configure(levels, no_python_can_config, monkeypatch)
    with open_bus(_node_config(levels, channels)) as bus:
        assert bus.channel_info == f"Virtual bus channel {expected}"


def test_every_bus_parameter_set_for_the_node_is_an_argument(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """A config file, a launch file's table, ATRIS_* variables and --set all give the
    node's bus settings, over python-can's CAN_* variables."""
    monkeypatch.setenv("CAN_CHANNEL", "from-can-channel")
    monkeypatch.setenv("CAN_BITRATE", "125000")
    node = cfg.load(environ={"ATRIS_BUS__CHANNEL": "from-atris-env"},
                    table={"bus": {"interface": "virtual", "bitrate": 250000}})
    assert bus_settings(node) == BusConfig("virtual", "from-atris-env", 250000)
    assert resolve(bus_settings(node))["channel"] == "from-atris-env"
    assert resolve(bus_settings(cfg.load(environ={})))["channel"] == "from-can-channel"


def test_canrc_values_are_typed_and_kept_key_by_key(no_python_can_config: Path,
                                                    monkeypatch: pytest.MonkeyPatch) -> None:
    """Each key comes from the highest level that has it: the interface and bit rate of
    ~/.canrc (a number, not the text of the file), the channel of CAN_CHANNEL; the same
    for the monitor's settings and the node's."""
    (no_python_can_config / ".canrc").write_text(
        "[default]\ninterface = udp_multicast\nchannel = ignored\nbitrate = 250000\n")
    monkeypatch.setenv("CAN_CHANNEL", "239.74.163.2")
    monitor = resolve(BusConfig())
    assert monitor == {"interface": "udp_multicast", "channel": "239.74.163.2",
                       "bitrate": 250000}
    assert resolve(bus_settings(cfg.load(environ={}))) == monitor
    monkeypatch.setenv("CAN_INTERFACE", "socketcan")
    assert resolve(BusConfig(interface="virtual"))["interface"] == "virtual"
    assert resolve(BusConfig())["interface"] == "socketcan"


def test_other_python_can_settings_reach_the_node_bus(monkeypatch: pytest.MonkeyPatch) -> None:
    """Keys the node has no parameter for come from python-can's sources too: here
    CAN_CONFIG's receive_own_messages, so the node's bus hears its own frame."""
    monkeypatch.setenv("CAN_CONFIG", json.dumps({"receive_own_messages": True}))
    channel = f"own-{uuid.uuid4().hex[:8]}"
    with open_bus(cfg.load(environ={}, overrides=[f"bus.channel={channel}"])) as bus:
        bus.send(can.Message(arbitration_id=0x123, is_extended_id=False))
        assert bus.recv(timeout=0.0) is not None


def test_node_defaults_are_the_bus_defaults() -> None:
    """The node's declared bus parameters say what the bus defaults are."""
    defaults = cfg.defaults()
    assert (defaults["bus.interface"], defaults["bus.channel"], defaults["bus.bitrate"]) == (
        DEFAULT_INTERFACE, DEFAULT_CHANNEL, DEFAULT_BITRATE)
