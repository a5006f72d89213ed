"""With ``invalid_on_interference = False`` only the sectors that look into columns with
foreign light (here the gray trails of a walking pedestrian) go INVALID; no sector is
reported farther than the truth because the nearer obstacle's columns were left out."""

from __future__ import annotations

import math

from atris_node.codes import walsh_chips
from atris_node.demod import BlockDemodulator
from atris_node.pipeline import Pipeline, PipelineConfig, PipelineResult
from atris_node.sectors import SectorLayout
from atris_node.sim import Simulator, load_scene
from atris_node.types import SectorState

N, ROW = 16, 2


def maps_and_truth(frames: int) -> list[tuple[PipelineResult, tuple[float | None, ...]]]:
    sim = Simulator(load_scene("fleet"), seed=3, unit=1)
    chips = walsh_chips(N, ROW)
    demod = BlockDemodulator(chips, bits=sim.camera.bits, lag=0)
    config = PipelineConfig(invalid_on_interference=False)
    layout = SectorLayout(config.sector_count, math.radians(config.fov_deg))
    pipeline = Pipeline(config, sim.calibration(), sim.mounting, layout)
    out = []
    for sequence in range(N * frames):
        dmap = demod.push(sim.render(sequence, int(chips[sequence % N])))
        if dmap is not None:
            truth = sim.truth(dmap.last_sequence, layout).sector_distance_m
            out.append((pipeline.process(dmap), tuple(truth)))
    return out


def test_only_sectors_with_foreign_columns_go_invalid_and_none_reads_too_far() -> None:
    results = maps_and_truth(frames=3)
    flagged = [(r, t) for r, t in results if r.diagnostics.interference]
    assert flagged, "the walking pedestrian's trails should be flagged in this scene"
    for result, truth in results:
        sectors = result.measurement.sectors
        for sector, true_m in zip(sectors, truth, strict=True):
            if sector.state is SectorState.VALID and true_m is not None:
                assert sector.distance_m <= true_m * 1.03 + 0.05, (sector, true_m)
    for result, _ in flagged:
        states = [s.state for s in result.measurement.sectors]
        assert SectorState.INVALID in states and SectorState.VALID in states
