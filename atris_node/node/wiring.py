"""Build a unit's components from its configuration.

The node calls these once at ``configure()``; nothing here runs per sub-frame.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import can
import canopen
from can.typechecking import CanFilter

from atris_node.bus.can.config import BusConfig, admit_error_frames
from atris_node.bus.can.ids import check_base_id
from atris_node.bus.can.publisher import Publisher
from atris_node.bus.canopen.device import CanopenDevice
from atris_node.bus.negotiation import name as negotiation_name
from atris_node.bus.negotiation.frames import PREFIX_BITS, PREFIX_MASK
from atris_node.bus.negotiation.machine import Negotiator
from atris_node.bus.negotiation.plan import Plan
from atris_node.calibration import Calibration
from atris_node.config import Config
from atris_node.errors import CalibrationError, ConfigError
from atris_node.mounting import Mounting
from atris_node.pipeline.chain import Pipeline, PipelineConfig
from atris_node.pipeline.sectors import SectorLayout
from drivers import Camera, Projector
from drivers import open_backend as registry_open_backend
from drivers.guard import GuardedProjector
from drivers.watchdog import LeasedProjector

#: default 64-bit NAME when none is configured: a fixed prefix and the unit id
DEFAULT_NAME_PREFIX = 0x0A70_0000_0000_0000
#: CANopen SYNC CAN-ID until 0x1005 says otherwise
DEFAULT_SYNC_ID = 0x080


def driver_settings(config: Config) -> tuple[str, dict[str, Any]]:
    """The backend name and its keyword settings."""
    name = str(config["driver.name"])
    if name == "sim":
        return name, {"scene": config["driver.scene"], "seed": config["driver.seed"],
                      "lag_sub_frames": config["driver.lag_sub_frames"],
                      "realtime": config["driver.realtime"], "unit": config["driver.unit"],
                      "rate_hz": config["driver.rate_hz"] or None}
    if name == "replay":
        if not config["driver.path"]:
            raise ConfigError("driver.path: the replay driver needs a recording directory")
        return name, {"path": config["driver.path"], "realtime": config["driver.realtime"],
                      "loop": config["driver.loop"]}
    return name, {"rate_hz": config["driver.rate_hz"] or 120.0,
                  "code_length": config["code.length"]}


def open_driver(config: Config, opener: Callable[..., tuple[Camera, Projector]] | None = None,
                permit: Callable[[], bool] | None = None,
                clock: Callable[[], float] = time.monotonic) -> tuple[Camera, Projector]:
    """Open the configured camera and projector (laser off). The projector is guarded: it
    takes a strobe only while ``permit()`` says so and goes dark by itself when no strobe
    came for :func:`strobe_lease_s` on ``clock`` (:mod:`drivers.guard`)."""
    name, settings = driver_settings(config)
    camera, projector = (opener or registry_open_backend)(name, **settings)
    if config["driver.projector_state_file"]:
        projector = LeasedProjector(projector, config["driver.projector_state_file"],
                                    config["driver.projector_lease_s"])
    guarded = GuardedProjector(projector, strobe_lease_s(config, camera), clock, permit)
    guarded.off()
    return camera, guarded


def strobe_lease_s(config: Config, camera: Camera) -> float:
    """How long a strobe keeps the projector lit: one sub-frame period (none when the
    camera does not know its rate) plus ``driver.strobe_margin_s``."""
    rate_hz = float(getattr(camera, "rate_hz", 0.0))
    period_s = 1.0 / rate_hz if rate_hz > 0 else 0.0
    return period_s + float(config["driver.strobe_margin_s"])


def mounting_of(config: Config, camera: Camera) -> Mounting:
    """The mounting pose: the driver's (simulator scene) or the configured one."""
    from_driver = getattr(camera, "mounting", None)
    if config["mounting.source"] == "driver" and isinstance(from_driver, Mounting):
        return from_driver
    return Mounting(x_m=config["mounting.x_m"], y_m=config["mounting.y_m"],
                    z_m=config["mounting.z_m"],
                    roll_rad=math.radians(config["mounting.roll_deg"]),
                    pitch_rad=math.radians(config["mounting.pitch_deg"]),
                    yaw_rad=math.radians(config["mounting.yaw_deg"]))


def calibration_of(config: Config, camera: Camera) -> Calibration:
    """The unit's calibration: its file, else what the device knows (simulator truth)."""
    size = getattr(camera, "size", None)
    if config["calibration.file"]:
        from calib.files import load_calibration

        return load_calibration(config["calibration.file"], expected_size=size)
    factory = camera.factory_calibration()
    if factory is None:
        raise CalibrationError("calibration.file is empty and the driver "
                               f"{config['driver.name']!r} has no calibration of its own; "
                               "run 'atris calib laser' and set calibration.file")
    return factory


def pipeline_config(config: Config) -> PipelineConfig:
    """The pipeline settings from the ``pipeline.*`` parameters."""
    p = config.section("pipeline")
    return PipelineConfig(peak_method=p["peak_method"], snr_min=p["snr_min"],
                          z_min_m=p["z_min_m"], z_max_m=p["z_max_m"],
                          roi_bands=p["roi_bands"], sector_count=p["sector_count"],
                          fov_deg=p["fov_deg"], min_points=p["min_points"],
                          objects=p["objects"], roi_narrowing=p["roi_narrowing"],
                          roi_full_every=p["roi_full_every"], identity=p["identity"],
                          invalid_on_interference=p["invalid_on_interference"],
                          min_reflectance=p["min_reflectance"],
                          tied_reflectance=p["tied_reflectance"])


def make_pipeline(config: Config, camera: Camera) -> Pipeline:
    """The line-to-sector pipeline for this unit's calibration and mounting."""
    p = pipeline_config(config)
    layout = SectorLayout(p.sector_count, math.radians(p.fov_deg))
    return Pipeline(p, calibration_of(config, camera), mounting_of(config, camera), layout)


#: the unit parameters that are python-can bus settings, and their python-can names
BUS_SETTINGS = {"bus.interface": "interface", "bus.channel": "channel",
                "bus.bitrate": "bitrate", "bus.fd": "fd"}


def bus_settings(config: Config) -> BusConfig:
    """The ``bus.*`` parameters that were set (file, launch file, environment, --set) as
    python-can arguments; the others are left to python-can's sources and then to the
    defaults, as for ``atris monitor`` (:mod:`atris_node.bus.can.config`)."""
    given = {key: value for key, value, source in config.describe()
             if source != "default" and key in BUS_SETTINGS}
    return BusConfig(**{BUS_SETTINGS[key]: value for key, value in given.items()})


@dataclass
class BusServices:
    """The unit's one Notifier on its bus, and the canopen Network in CANopen mode."""

    notifier: can.Notifier
    network: canopen.Network | None = None

    def stop(self) -> None:
        """Stop receiving; the bus itself belongs to the caller. Idempotent."""
        self.notifier.stop()


def receive_filters(config: Config, sync_id: int = DEFAULT_SYNC_ID) -> list[CanFilter]:
    """The frames a unit reads: the negotiation frames (29-bit, their prefix), and in
    CANopen mode NMT, SYNC (on ``sync_id``, 0x1005) and the SDO requests to its node ID.
    Everything else (other units' distances, a babbling node) is dropped by the interface
    (in the kernel on SocketCAN) and cannot crowd the negotiation frames out of the
    receive queue. Error frames are no identifiers and always come through
    (:func:`make_bus_services`)."""
    filters: list[CanFilter] = [
        {"can_id": PREFIX_BITS, "can_mask": PREFIX_MASK, "extended": True}]
    if config["bus.protocol"] == "canopen":
        filters += [{"can_id": can_id, "can_mask": 0x7FF, "extended": False}
                    for can_id in (0x000, sync_id, 0x600 + int(config["bus.node_id"]))]
    return filters


def make_bus_services(config: Config, bus: can.BusABC) -> BusServices:
    """One Notifier per bus: canopen's own in CANopen mode, else a plain one; the bus
    reads only what the unit needs (:func:`receive_filters`) and every error frame
    (:func:`~atris_node.bus.can.config.admit_error_frames`)."""
    bus.set_filters(receive_filters(config))
    admit_error_frames(bus)
    if config["bus.protocol"] == "canopen":
        network = canopen.Network(bus)
        network.connect()
        assert network.notifier is not None
        return BusServices(network.notifier, network)
    return BusServices(can.Notifier(bus, [], timeout=0.1))


def make_output(config: Config, bus: can.BusABC, services: BusServices,
                clock: Callable[[], float]) -> Publisher | CanopenDevice:
    """The frames of this unit: the DBC cycle publisher (its ``bus.base_id`` checked
    against the CANopen predefined connection set), or a CANopen slave."""
    if services.network is not None:
        return CanopenDevice(services.network, config["bus.node_id"], clock=clock,
                             settings=canopen_settings(config),
                             on_sync_id=lambda sync_id: bus.set_filters(
                                 receive_filters(config, sync_id)))
    check_base_id(config["bus.base_id"], config["bus.allow_canopen_ids"])
    publisher = Publisher(bus, config["unit.unit_id"], period_s=config["publish.period_s"],
                          max_age_s=config["publish.max_age_s"], clock=clock,
                          sector_count=config["pipeline.sector_count"], fd=config["bus.fd"],
                          base_id=config["bus.base_id"])
    services.notifier.add_listener(publisher.health)
    return publisher


def canopen_settings(config: Config) -> dict[str, int]:
    """Power-on values of the CANopen configuration object 0x2000: the node's settings."""
    return {"CodeLength": int(config["code.length"]),
            "SectorCount": int(config["pipeline.sector_count"]),
            "PublishPeriod_ms": round(float(config["publish.period_s"]) * 1000.0),
            "MaxDataAge_ms": round(float(config["publish.max_age_s"]) * 1000.0)}


def connect_output(output: Publisher | CanopenDevice, negotiator: Negotiator,
                   config: Config) -> None:
    """In CANopen mode a CodeLength written over SDO becomes the negotiator's plan
    request (the other entries of 0x2000 the device applies itself)."""
    if not isinstance(output, CanopenDevice):
        return
    max_length = int(config["code.max_length"])

    def on_config(name: str, value: int) -> None:
        if name != "CodeLength":
            return
        if value > max_length:
            raise ConfigError(f"CodeLength {value}: this unit runs codes up to "
                              f"code.max_length = {max_length}")
        negotiator.request_plan(value)
    output.on_config = on_config


def unit_name(config: Config, camera: Camera) -> int:
    """The NAME: configured, else from the camera serial, else persisted in a file, else
    derived from the unit id (simulated units without a name file)."""
    serial = getattr(camera, "serial", None)
    name_file = config["unit.name_file"] or None
    if config["unit.name"] or serial or name_file:
        return negotiation_name.unit_name(config["unit.name"], serial,
                                          None if name_file is None else Path(name_file))
    return DEFAULT_NAME_PREFIX | int(config["unit.unit_id"])


def make_negotiator(config: Config, bus: can.BusABC, camera: Camera,
                    services: BusServices, clock: Callable[[], float] = time.monotonic
                    ) -> Negotiator:
    """The code negotiation service for this unit, on the unit's Notifier and ``clock``
    (seconds; the unit's clock, so that its windows and time-outs run on the time its
    sub-frames are stamped with)."""
    rate = float(camera.rate_hz) or 240.0
    plan = Plan(code_length=config["code.length"], chip_rate_hz=rate, mode=config["code.mode"])
    n = config.section("negotiation")
    return Negotiator(bus, unit_name(config, camera), plan, config["unit.unit_id"],
                      window_s=n["window_s"], reannounce_s=n["reannounce_s"],
                      silence_timeout_s=n["silence_timeout_s"],
                      max_code_length=config["code.max_length"],
                      can_sync=bool(getattr(camera, "can_trigger", False)),
                      notifier=services.notifier, clock=clock)
