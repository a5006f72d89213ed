"""The ``sim`` driver backend: strobe timing and lag, strobe log, faults, units seeing units."""

from __future__ import annotations

import copy
from typing import Any

import numpy as np
import pytest

import drivers
from atris_node.errors import CameraLostError, ConfigError
from atris_node.sim import Simulator
from atris_node.sim.scene import parse_scene
from drivers.sim import SimCamera, SimProjector, open_backend

SMALL: dict[str, Any] = {
    "camera": {"width_px": 64, "height_px": 48, "focal_px": 40.0, "rate_hz": 200.0,
               "exposure_us": 1000.0},
    "projector": {"baseline_m": 0.075, "alpha_deg": [86.0, 89.0], "power_w": 0.1},
    "mounting": [{"y_m": 0.3, "z_m": 0.5}, {"y_m": -0.3, "z_m": 0.5}],
    "plane": [{"point_m": [2.0, 0.0, 0.0], "normal": [-1.0, 0.0, 0.0], "albedo": 0.8}],
    "ambient": {"lamp": {"lux": 100.0}},
    "noise": {"enabled": False},
}


def small_scene() -> Any:
    return parse_scene(copy.deepcopy(SMALL), name="small")


def test_smoke_registry_opens_sim_backend() -> None:
    camera, projector = drivers.open_backend("sim", scene="indoor_lab", seed=3)
    with camera, projector:
        assert isinstance(camera, SimCamera) and isinstance(projector, SimProjector)
        assert camera.rate_hz == 240.0 and camera.size == (640, 400) and camera.bits == 10
        sub = camera.read()
        assert sub.sequence == 0 and sub.chip is None and sub.pixels.shape == (400, 640)
        assert camera.factory_calibration().camera.focal_px == 381.0


def test_feature_strobe_lag_and_log() -> None:
    camera, projector = open_backend(small_scene(), lag_sub_frames=1)
    with camera, projector:
        for sequence in range(4):
            projector.strobe(1 if sequence % 2 == 0 else 0, sequence)
            sub = camera.read()
            assert sub.chip == (1 if sequence % 2 == 0 else 0)  # commanded
        assert [chip for _, _, chip in projector.strobe_log] == [0, 1, 0, 1]  # emitted
        assert projector.strobe_log[2][1] == pytest.approx(2 / 200.0)


def test_feature_off_darkens_at_once() -> None:
    camera, projector = open_backend(small_scene(), lag_sub_frames=2)
    with camera, projector:
        projector.strobe(1, 0)
        lit = [camera.read() for _ in range(3)][-1]
        projector.strobe(1, 3)  # would land on sequence 5
        projector.off()
        dark = [camera.read() for _ in range(4)]
        assert projector.strobe_log[2][2] == 1
        assert all(chip == 0 for _, _, chip in projector.strobe_log[3:])
        assert not projector.is_lit
        assert lit.pixels.sum() > dark[-1].pixels.sum()


def test_feature_timestamps_and_realtime_pacing() -> None:
    now = [100.0]
    sleeps: list[float] = []
    sim = Simulator(small_scene())
    projector = SimProjector(sim)
    camera = SimCamera(sim, projector, realtime=True, sleep=sleeps.append,
                       clock=lambda: now[0])
    with camera, projector:
        subs = [camera.read() for _ in range(3)]
    assert [s.sequence for s in subs] == [0, 1, 2]
    assert subs[1].device_time_s - subs[0].device_time_s == pytest.approx(1 / 200.0)
    assert camera.time_origin_s == 100.0
    assert subs[2].host_time_s == 100.0  # arrival on the (frozen) host clock
    assert sleeps == pytest.approx([0.005, 0.010])


def test_feature_fault_injection_drop_disconnect_reconnect() -> None:
    camera, projector = open_backend(small_scene())
    with camera, projector:
        camera.read()
        camera.drop(2)
        assert camera.read().sequence == 3
        camera.disconnect()
        with pytest.raises(CameraLostError):
            camera.read()
        camera.reconnect()
        assert camera.read().sequence == 4
    with pytest.raises(CameraLostError):
        camera.read()


def test_feature_units_see_each_other_through_strobe_logs() -> None:
    scene = small_scene()
    cam_a, proj_a = open_backend(scene, unit=0)
    cam_b, proj_b = open_backend(scene, unit=1)
    with cam_a, proj_a, cam_b, proj_b:
        cam_a.simulator.add_interferer(cam_b.mounting, scene.projector,
                                       proj_b.strobe_function(), name="unit 1")
        proj_b.strobe(1, 0)
        cam_b.read()  # unit 1 emits in its sub-frame 0
        seen = cam_a.read().pixels.astype(np.int64)
        proj_b.off()
        cam_b.read()
        quiet = cam_a.read().pixels.astype(np.int64)
    assert proj_a.strobe_log[0][2] == 0 and (seen - quiet).max() > 5


def test_exception_bad_settings() -> None:
    with pytest.raises(ConfigError, match="unknown settings"):
        open_backend(small_scene(), colour=True)
    with pytest.raises(ConfigError, match="no scene named"):
        open_backend("nowhere")
    with pytest.raises(ConfigError, match="lag_sub_frames must be >= 0"):
        open_backend(small_scene(), lag_sub_frames=-1)
    with pytest.raises(ConfigError, match="exposure_us must be in"):
        open_backend(small_scene(), rate_hz=2000.0)  # 1000 µs does not fit 500 µs
