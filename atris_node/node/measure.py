"""The per-map work of one unit: sub-frames into a distortion map, the map into a Measurement.

:class:`Measurer` owns the demodulator of the owned code, the sampled foreign-code energy,
the pipeline and the scene adaptation. The unit's loop (:mod:`atris_node.node.unit`) reads
the camera, strobes the projector and hands each sub-frame here; what comes back is the
Measurement to publish. Sub-frames are handled in the loop's thread, maps on the map
thread (:mod:`atris_node.node.worker`) or in the loop; an exposure the adaptation asks for
is set on the camera by the loop (:meth:`Measurer.take_exposure_request`).
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable
from pathlib import Path
from typing import Any

from atris_node.adaptive.assessment import RangeModel, assess
from atris_node.adaptive.controller import AdaptiveController, withheld
from atris_node.codes import code_set, walsh_chips
from atris_node.config import Config
from atris_node.demod import BlockDemodulator, PendingMap, SlidingDemodulator
from atris_node.errors import DemodulationError
from atris_node.node.snapshot import obstacle_map, write_snapshot
from atris_node.node.stats import NodeStats
from atris_node.pipeline.interference import InterferenceReport, InterferenceWatch
from atris_node.types import DistortionMap, FaultBits, Measurement, SubFrame
from drivers import Camera

logger = logging.getLogger(__name__)


class Measurer:
    """Demodulates the sub-frames of the owned code and measures each complete map.

    Args:
        config: the unit's configuration (demodulator kind, interference sampling).
        pipeline: the unit's :class:`~atris_node.pipeline.chain.Pipeline`.
        adaptive: the scene adaptation, or None when it is off.
        negotiator: the unit's negotiator (peers, plan; hears the interference reports
            and the adaptation's plan requests).
        stats: the unit's counters (maps, dropped sub-frames, lag, measurements, late maps).
        clock: seconds, the clock sub-frame host times are on.
    """

    def __init__(self, config: Config, pipeline: Any, adaptive: AdaptiveController | None,
                 negotiator: Any, stats: NodeStats, clock: Callable[[], float]) -> None:
        self.config = config
        self.pipeline = pipeline
        self.adaptive = adaptive
        self.negotiator = negotiator
        self.stats = stats
        self.clock = clock
        self.demod: BlockDemodulator | SlidingDemodulator | None = None
        self.key: tuple[int, int] | None = None  # (N, row) of the demodulator
        self.watch: InterferenceWatch | None = None
        self.interference: InterferenceReport | None = None
        self.last_sub: SubFrame | None = None
        self.last_map: DistortionMap | None = None
        self.last_result: Any = None
        #: the adaptation's LOW_SIGNAL verdict on the last map, None without adaptation
        self.low_signal: bool | None = None
        #: the pipeline's verdict on the last map (FOREIGN_CODE, LOW_SIGNAL); NONE when
        #: the window restarted since
        self.map_faults = FaultBits.NONE
        #: False while the sub-frames do not fit the calibrated camera (CALIBRATION)
        self.fits_calibration = True
        #: an exposure (µs) the adaptation asked for, for the loop to set on the camera
        #: between two reads (the map may be measured on another thread)
        self._exposure_request: float | None = None
        self._request_lock = threading.Lock()

    # ----------------------------------------------------------------- sub-frames
    def set_code(self, key: tuple[int, int], bits: int) -> None:
        """A new demodulator for code ``key`` = (N, row) of ``bits``-bit sub-frames."""
        chips = walsh_chips(*key)
        # the strobe lag is known only for a simulator without lag; otherwise lock to it
        known = self.config["driver.name"] == "sim" and not self.config["driver.lag_sub_frames"]
        lag = 0 if known else None
        kind = SlidingDemodulator if self.config["code.demod"] == "sliding" else BlockDemodulator
        self.demod = kind(chips, bits=bits, lag=lag)
        self.key = key
        self.watch = None
        self.map_faults = FaultBits.NONE

    def reset(self) -> None:
        """Restart the demodulation window (a rejected sub-frame, a camera loss)."""
        self.map_faults = FaultBits.NONE
        if self.demod is not None:
            self.demod.reset()

    def demodulate(self, sub: SubFrame) -> PendingMap | None:
        """Push ``sub``; the pending map when its window is complete, else None (its
        distortion map is built and measured by whoever takes it: the map thread, or the
        loop without one).

        Raises:
            DemodulationError: the sub-frame does not fit the calibration or the window.
        """
        assert self.demod is not None
        self._check_sub_frame(sub)
        pending = self.demod.push_pending(sub)
        self._watch_interference(sub)
        if pending is not None:
            self.stats.maps += 1
            self.stats.dropped_sub_frames += pending.dropped
            self.stats.last_lag = pending.phase
        return pending

    def _check_sub_frame(self, sub: SubFrame) -> None:
        """Reject a sub-frame that does not fit the calibrated camera (and say so in
        ``fits_calibration`` until one fits again)."""
        camera = self.pipeline.calibration.camera
        expected = (camera.height_px, camera.width_px)
        self.fits_calibration = sub.pixels.shape == expected
        if not self.fits_calibration:
            raise DemodulationError(f"sub-frame {sub.sequence} is {sub.pixels.shape[::-1]} "
                                    f"(w, h) but the calibration is for {expected[::-1]}")

    # ----------------------------------------------------------------- interference
    def _peer_rows(self) -> list[int]:
        return [p.code_row for p in self.negotiator.peers.named() if p.code_row]

    def _reference_row(self) -> int | None:
        """A row nobody on the bus uses: its energy is the broadband level (motion trails,
        flicker) that every code sees and that is no sign of a unit on the own code."""
        assert self.key is not None
        n, own = self.key
        taken = {own, *self._peer_rows()}
        free = [r for r in code_set(n, str(self.negotiator.plan.mode)) if r not in taken]
        others = [r for r in range(n, 1, -1) if r not in taken]
        candidates = free or others
        return candidates[0] if candidates else None

    def _rows_to_measure(self) -> list[int]:
        reference = self._reference_row()
        return self._peer_rows() + ([] if reference is None else [reference])

    def _watch_interference(self, sub: SubFrame) -> None:
        """Sampled foreign-code energy; sustained energy on the own code makes us hop."""
        every = int(self.config["interference.every_windows"])
        demod, key = self.demod, self.key
        if not every or demod is None or key is None or not demod.locked:
            return
        if self.watch is None:
            self.watch = InterferenceWatch(key[0], key[1], demod.lag or 0, every,
                                           self._rows_to_measure)
        report = self.watch.push(sub)
        if report is not None:
            self.interference = report
            reference = self._reference_row()
            broadband = report.foreign.get(reference, 0.0) if reference else 0.0
            self.negotiator.report_interference(max(report.own_excess - broadband, 0.0),
                                                report.foreign)

    def foreign_energy(self, extra: dict[str, float]) -> float:
        """Sampled energy of other codes (fraction of the own lines), else the pipeline's."""
        if self.interference is not None:
            return float(self.interference.total)
        return float(extra.get("foreign_code_energy", 0.0))

    # ----------------------------------------------------------------- maps
    def measure(self, dmap: DistortionMap, camera: Camera | None) -> Measurement:
        """The Measurement of a complete map (``camera``: its rate, and the exposure the
        adaptation sets)."""
        self.last_map = dmap
        result = self.pipeline.process(dmap)
        self.last_result = result
        self.map_faults = FaultBits(result.faults)
        self._count_deadline(dmap, camera)
        self.stats.measurements += 1
        return self._adapt(dmap, result, camera)

    def _adapt(self, dmap: DistortionMap, result: Any, camera: Camera | None) -> Measurement:
        """Scene assessment, adaptive exposure and N (docs/adaptive.md); off by default."""
        if self.adaptive is None or camera is None:
            return result.measurement
        diag = result.diagnostics
        dmap.extra["foreign_code_energy"] = diag.foreign_energy
        decision = self.adaptive.on_frame(
            assess(dmap, result.samples.snr, diag.line_snr, diag.foreign_energy,
                   self.last_sub, self._range_model(result)),
            int(self.negotiator.plan.code_length))
        if decision.exposure_us is not None:
            with self._request_lock:
                self._exposure_request = float(decision.exposure_us)
        if decision.code_length is not None:
            self.negotiator.request_plan(decision.code_length)
        self.low_signal = decision.low_signal
        return withheld(result.measurement) if decision.low_signal else result.measurement

    def take_exposure_request(self) -> float | None:
        """The exposure (µs) the adaptation asked for since the last call, or None; the
        loop sets it on the camera between two reads."""
        with self._request_lock:
            request, self._exposure_request = self._exposure_request, None
        return request

    def _range_model(self, result: Any) -> RangeModel:
        """The row sigmas behind the valid samples' range sigma (the error bound)."""
        calibration = self.pipeline.calibration
        return RangeModel(result.samples.sigma_u_px[result.valid],
                          float(self.pipeline.config.sigma_u_px),
                          float(calibration.camera.focal_px * calibration.laser.baseline_m))

    def _count_deadline(self, dmap: DistortionMap, camera: Camera | None) -> None:
        """A map not processed within one output period of its newest sub-frame is late."""
        rate = float(getattr(camera, "rate_hz", 0.0))
        if rate <= 0.0:
            return
        period_s = dmap.code_length / rate
        if self.clock() - dmap.last_time_s > period_s:
            self.stats.deadline_misses += 1

    # ----------------------------------------------------------------- views
    def truth_sector_distances(self, camera: Camera | None) -> tuple[float | None, ...] | None:
        """The simulator's true sector distances for the newest map, or None (hardware)."""
        simulator = getattr(camera, "simulator", None)
        if simulator is None or self.last_map is None:
            return None
        truth = simulator.truth(self.last_map.last_sequence, self.pipeline.layout)
        return tuple(truth.sector_distance_m)

    def snapshot(self, directory: str | Path, label: str, z_max_m: float) -> list[Path]:
        """Write the newest plain sub-frame, distortion map and top-down obstacle map."""
        result = self.last_result
        top_down = obstacle_map(
            None if result is None else result.measurement, self.pipeline.layout,
            None if result is None else result.points_vehicle_m, z_max_m)
        return write_snapshot(directory, label, self.last_sub, self.last_map, top_down)
