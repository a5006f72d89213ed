"""The stress scenes (launch/scenes/stress) load by name, render, and state an obstacle
(or, where the scene is about a phantom where nothing stands, state none)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from atris_node.errors import ConfigError
from atris_node.pipeline.sectors import SectorLayout
from atris_node.sim import Simulator, load_scene, shipped_scenes, stress_scenes

LAYOUT = SectorLayout(8, math.radians(70.0))
#: scenes in which no sheet reaches an obstacle by the truth's rules: what they test is a
#: phantom where nothing stands
NOTHING_IN_REACH = {"flicker_step_at_box_foot",
                    "ground_comb_read_one_line_down_noise_anchored_drawn",
                    "grazing_sheet_ground_stripe_read_as_low_obstacle_drawn"}


def test_smoke_there_are_at_least_fifteen_and_they_are_not_shipped_scenes() -> None:
    names = stress_scenes()
    assert len(names) >= 15
    assert not set(names) & set(shipped_scenes())


@pytest.mark.parametrize("name", stress_scenes())
def test_feature_stress_scene_renders_with_an_obstacle_in_view(name: str) -> None:
    sim = Simulator(load_scene(name), seed=1)
    sub = sim.render(0, chip=1)
    camera = sim.scene.camera
    assert sub.pixels.shape == (camera.height_px, camera.width_px)
    assert np.isfinite(sub.pixels).all()
    truth = sim.truth(0, LAYOUT)
    in_reach = any(t is not None for t in truth.sector_distance_m)
    assert in_reach is (name not in NOTHING_IN_REACH), name


def test_exception_unknown_name_lists_the_shipped_scenes() -> None:
    with pytest.raises(ConfigError, match="no scene named"):
        load_scene("no_such_stress_scene")
