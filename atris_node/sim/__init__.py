"""The physically based simulator: scene files, renderer and ground truth.

    >>> from atris_node.sim import Simulator, load_scene          # doctest: +SKIP
    >>> sim = Simulator(load_scene("indoor_lab"), seed=1)         # doctest: +SKIP
    >>> sub_frame = sim.render(0, chip=1)                         # doctest: +SKIP

Modules: ``scene`` (TOML loading and validation), ``raycast`` (shapes), ``optics``
(radiometry), ``layers`` (per-pixel rates), ``sensor`` (noise, quantisation), ``strobe``
(interferer strobes, flicker), ``render`` (:class:`Simulator`), ``truth``.
"""

from __future__ import annotations

from atris_node.sim.render import Simulator, Source
from atris_node.sim.scene import LinePattern, Scene, load_scene, shipped_scenes, stress_scenes
from atris_node.sim.truth import Truth

__all__ = ["LinePattern", "Scene", "Simulator", "Source", "Truth", "load_scene",
           "shipped_scenes", "stress_scenes"]
