"""``atris calib simulate``: a complete capture set with its truth, without hardware.

What is written (see :mod:`calib.captures` for the layout):

- ChArUco views for the intrinsics: the board texture warped through the true camera
  (:func:`calib.synthetic.render_board_view`), blur and noise;
- flat-target captures at several distances (and one more for ``verify``): strobed
  sub-frames of a wall perpendicular to the optical axis, with ambient light, sensor
  noise and laser glints (outliers), demodulated over one Walsh code period;
- board-with-laser views: the board view plus a distortion map whose lines are the
  intersections of the true light planes with the board plane (drawn from the geometry);
- ``truth.calib.toml``: the true calibration, in the unit file format.

The truth comes from the scene: ``synthetic`` is built in (1280×800, f = 763 px,
b = 75 mm, three lines); other names are looked up with the simulator
(``atris_node.sim.load_scene``) when it is installed.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import numpy.typing as npt

from atris_node import codes
from atris_node.calibration import Calibration, CameraModel, LaserCalibration
from atris_node.errors import CalibrationError
from calib.board import BoardSpec
from calib.captures import BoardLaserCapture, CaptureSet, FlatCapture, write_manifest
from calib.files import save_calibration
from calib.progress import progress
from calib.synthetic import (
    BoardPose,
    laser_rows_on_board,
    random_poses,
    render_board_view,
    render_line_map,
)

logger = logging.getLogger(__name__)

BUILT_IN_SCENE = "synthetic"
DEFAULT_DISTANCES_M = (0.6, 0.8, 1.1, 1.5, 2.0, 2.8)
DEFAULT_VERIFY_M = 1.75


@dataclass(frozen=True)
class SimulationSettings:
    """What to render: counts, distances (m), code, light levels (DN) and noise."""

    intrinsic_views: int = 12
    board_poses: int = 8
    distances_m: tuple[float, ...] = DEFAULT_DISTANCES_M
    verify_distance_m: float = DEFAULT_VERIFY_M
    code_length: int = 16
    code_row: int = 2
    ambient_dn: float = 80.0
    laser_dn: float = 40.0
    stripe_sigma_px: float = 1.3
    noise_dn: float = 3.0
    glints: int = 40
    seed: int = 0


def built_in_truth() -> Calibration:
    """The truth of the ``synthetic`` scene."""
    camera = CameraModel(1280, 800, 763.0, 641.3, 398.2)
    laser = LaserCalibration(0.075, tuple(float(a) for a in np.radians([92.0, 90.0, 88.0])))
    return Calibration(camera=camera, laser=laser)


def scene_truth(scene: str, seed: int) -> Calibration:
    """The true calibration of ``scene`` (built in, or from the simulator)."""
    if scene == BUILT_IN_SCENE:
        return built_in_truth()
    try:
        from atris_node import sim
    except ImportError as exc:
        raise CalibrationError(f"scene {scene!r} needs the simulator (atris_node.sim), which "
                               f"is not available; accepted here: {BUILT_IN_SCENE!r}") from exc
    simulator = sim.Simulator(sim.load_scene(scene), seed=seed)  # type: ignore[attr-defined]
    truth = simulator.calibration()
    if not isinstance(truth, Calibration):
        raise CalibrationError(f"the simulator gave no calibration for scene {scene!r}")
    return truth


def flat_rows(truth: Calibration, distance_m: float) -> npt.NDArray[np.float64]:
    """(K, W) true image rows of every line on a wall at ``distance_m`` (Eq. 1)."""
    camera, laser = truth.camera, truth.laser
    u_px = [camera.focal_px * (1.0 / np.tan(a) - laser.baseline_m / distance_m)
            for a in laser.alpha_rad]
    rows = np.asarray(u_px)[:, None] + camera.cy_px
    return np.repeat(rows, camera.width_px, axis=1)


def _glints(shape: tuple[int, int], count: int, rng: np.random.Generator
            ) -> npt.NDArray[np.float64]:
    """Laser glints off the wall: ``count`` small bright blobs at random places (outliers)."""
    image = np.zeros(shape)
    rows, cols = rng.integers(0, shape[0], count), rng.integers(0, shape[1], count)
    image[rows, cols] = rng.uniform(200.0, 600.0, count)
    return np.asarray(cv2.GaussianBlur(image, (0, 0), 1.5), dtype=np.float64) * 10.0


def flat_target_map(truth: Calibration, distance_m: float, settings: SimulationSettings,
                    rng: np.random.Generator) -> npt.NDArray[np.int32]:
    """Demodulated (H, W) int32 map of a wall at ``distance_m``: N strobed uint8
    sub-frames (ambient + chip·(stripes + glints) + noise) summed with the bipolar code."""
    camera = truth.camera
    stripes = render_line_map(flat_rows(truth, distance_m), camera.height_px, rng,
                              peak_dn=settings.laser_dn, sigma_px=settings.stripe_sigma_px,
                              noise_dn=0.0).astype(np.float64)
    laser = stripes + _glints(stripes.shape, settings.glints, rng)
    chips = codes.walsh_chips(settings.code_length, settings.code_row)
    total = np.zeros(stripes.shape, dtype=np.int32)
    for chip, sign in zip(chips, codes.bipolar(chips), strict=True):
        frame = settings.ambient_dn + chip * laser + rng.normal(0, settings.noise_dn,
                                                                stripes.shape)
        total += int(sign) * np.clip(np.rint(frame), 0, 255).astype(np.int32)
    return total


def _save_png(path: Path, image: npt.NDArray[np.uint8]) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(path), image):
        raise CalibrationError(f"cannot write {path}")


def _save_map(path: Path, values: npt.NDArray[np.int32]) -> None:
    """Save a map as int16 when every value fits (half the size), else int32."""
    path.parent.mkdir(parents=True, exist_ok=True)
    small = int(np.abs(values).max(initial=0)) <= np.iinfo(np.int16).max
    np.save(path, values.astype(np.int16) if small else values, allow_pickle=False)


def _intrinsic_views(out: Path, spec: BoardSpec, camera: CameraModel,
                     settings: SimulationSettings, rng: np.random.Generator) -> list[str]:
    names = []
    poses = random_poses(spec, camera, settings.intrinsic_views, rng)
    for index, pose in enumerate(progress(poses, "board views", "view")):
        name = f"intrinsics/view_{index:03d}.png"
        _save_png(out / name, render_board_view(spec, camera, pose, rng))
        names.append(name)
    return names


def _flat_captures(out: Path, truth: Calibration, distances: Sequence[float],
                   settings: SimulationSettings, rng: np.random.Generator, *,
                   folder: str) -> list[FlatCapture]:
    captures = []
    for distance in progress(distances, f"{folder} target", "distance"):
        name = f"{folder}/z_{distance:.3f}m.npy"
        _save_map(out / name, flat_target_map(truth, distance, settings, rng))
        captures.append(FlatCapture(float(distance), name))
    return captures


def _poses_with_every_line(spec: BoardSpec, truth: Calibration, count: int,
                           rng: np.random.Generator) -> list[BoardPose]:
    """Board poses on which every line crosses the board over at least half its width."""
    poses: list[BoardPose] = []
    for _ in range(50):
        for pose in random_poses(spec, truth.camera, count, rng, distance_m=(0.5, 1.3),
                                 tilt_deg=20.0):
            rows = laser_rows_on_board(spec, truth.camera, truth.laser, pose)
            if np.all((rows >= 0).sum(axis=1) > 0.25 * truth.camera.width_px):
                poses.append(pose)
        if len(poses) >= count:
            break
    return poses[:count]


def _board_laser_captures(out: Path, spec: BoardSpec, truth: Calibration,
                          settings: SimulationSettings,
                          rng: np.random.Generator) -> list[BoardLaserCapture]:
    captures = []
    poses = _poses_with_every_line(spec, truth, settings.board_poses, rng)
    for index, pose in enumerate(progress(poses, "board with laser", "pose")):
        image, name = f"board_laser/pose_{index:03d}.png", f"board_laser/pose_{index:03d}.npy"
        _save_png(out / image, render_board_view(spec, truth.camera, pose, rng))
        rows = laser_rows_on_board(spec, truth.camera, truth.laser, pose)
        peak = settings.laser_dn * settings.code_length / 2
        _save_map(out / name, render_line_map(rows, truth.camera.height_px, rng, peak_dn=peak,
                                              sigma_px=settings.stripe_sigma_px,
                                              noise_dn=4.0 * settings.noise_dn))
        captures.append(BoardLaserCapture(image, name))
    return captures


def simulate_capture_set(scene: str, out: str | Path, settings: SimulationSettings,
                         spec: BoardSpec | None = None) -> CaptureSet:
    """Render a capture set of ``scene`` into folder ``out`` and write its manifest."""
    root, spec = Path(out), spec or BoardSpec()
    root.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(settings.seed)
    truth = scene_truth(scene, settings.seed)
    save_calibration(root / "truth.calib.toml", truth, {"method": "simulation truth",
                                                        "scene": scene})
    captures = CaptureSet(
        root, len(truth.laser.alpha_rad), spec, scene, "truth.calib.toml",
        tuple(_intrinsic_views(root, spec, truth.camera, settings, rng)),
        tuple(_flat_captures(root, truth, settings.distances_m, settings, rng,
                             folder="flat")),
        tuple(_flat_captures(root, truth, [settings.verify_distance_m], settings, rng,
                             folder="verify")),
        tuple(_board_laser_captures(root, spec, truth, settings, rng)))
    write_manifest(captures)
    logger.info("capture set of scene %s written to %s", scene, root)
    return captures
