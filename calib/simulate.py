"""``atris calib simulate``: a complete capture set with its truth, without hardware.

What is written (see :mod:`calib.captures` for the layout):

- ChArUco views for the intrinsics: the board texture warped through the true camera
  (:func:`calib.synthetic.render_board_view`), blur and noise;
- flat-target captures at several distances (and one more for ``verify``): sub-frames
  strobed with the scene's Walsh code and demodulated over one code period. For a scene
  of the simulator (``atris_node.sim``) the scene is rebuilt with only a wall
  perpendicular to the optical axis at the distance and a pole in front of it (its
  columns are outliers), and rendered by :class:`atris_node.sim.Simulator`, demodulated by
  :class:`atris_node.demod.BlockDemodulator`. The built-in ``synthetic`` scene draws
  Gaussian stripes with ambient light, noise and laser glints (outliers) instead;
- board-with-laser views: the board view plus a distortion map whose lines are the
  intersections of the true light planes with the board plane, drawn from the geometry
  (the simulator has no textured board);
- ``truth.calib.toml``: the true calibration, in the unit file format.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import cv2
import numpy as np
import numpy.typing as npt

from atris_node import codes
from atris_node.calibration import Calibration, CameraModel, LaserCalibration
from atris_node.errors import CalibrationError
from atris_node.progress import progress
from atris_node.sim import Scene, Simulator, load_scene
from atris_node.sim.raycast import Box, Plane, Shape
from calib.board import BoardSpec
from calib.captures import BoardLaserCapture, CaptureSet, FlatCapture, write_manifest
from calib.files import save_calibration
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


@dataclass(frozen=True)
class SceneSource:
    """Where flat-target maps come from: the simulator's scene, or the built-in drawing."""

    truth: Calibration
    settings: SimulationSettings
    scene: Scene | None = None

    def flat_map(self, distance_m: float, rng: np.random.Generator) -> npt.NDArray[np.int32]:
        """Demodulated map of a flat target at ``distance_m``."""
        if self.scene is None:
            return flat_target_map(self.truth, distance_m, self.settings, rng)
        seed = self.settings.seed * 100_000 + round(distance_m * 1000)
        return simulated_flat_map(self.scene, distance_m, seed)


def built_in_truth() -> Calibration:
    """The truth of the ``synthetic`` scene."""
    camera = CameraModel(1280, 800, 763.0, 641.3, 398.2)
    laser = LaserCalibration(0.075, tuple(float(a) for a in np.radians([92.0, 90.0, 88.0])))
    return Calibration(camera=camera, laser=laser)


def scene_source(scene: str, settings: SimulationSettings) -> SceneSource:
    """The truth and flat-target renderer of ``scene`` (built in, or a simulator scene)."""
    if scene == BUILT_IN_SCENE:
        return SceneSource(built_in_truth(), settings)
    loaded = load_scene(scene)
    return SceneSource(Simulator(loaded, seed=settings.seed).calibration(), settings, loaded)


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


def wall_scene(scene: Scene, distance_m: float, pole: bool = True) -> Scene:
    """``scene`` with only a wall perpendicular to unit 0's optical axis at ``distance_m``
    (camera frame, m) and, with ``pole``, a thin pole at 0.8·distance (outliers)."""
    mounting = scene.mountings[0]
    axis = mounting.rotation[:, 2]
    wall = Plane(albedo=0.7, name="calibration wall", normal=tuple(-axis),
                 point_m=tuple(mounting.camera_to_vehicle([0.0, 0.0, distance_m])))
    shapes: list[Shape] = [wall]
    if pole:
        near = 0.8 * distance_m
        x_m = 0.5 * near * (scene.camera.width_px / 2) / scene.camera.focal_px
        centre = mounting.camera_to_vehicle([x_m, 0.0, near])
        shapes.append(Box(albedo=0.5, name="pole", center_m=tuple(centre),
                          size_m=(0.03, 0.02 * distance_m, 10.0)))
    return replace(scene, shapes=tuple(shapes), mountings=(mounting,), interferers=())


def simulated_flat_map(scene: Scene, distance_m: float, seed: int) -> npt.NDArray[np.int32]:
    """Demodulated (H, W) int32 map of :func:`wall_scene`, from the simulator."""
    from atris_node.demod import BlockDemodulator

    chips = codes.walsh_chips(scene.code_length, scene.code_row)
    simulator = Simulator(wall_scene(scene, distance_m), chips=chips, seed=seed)
    demodulator = BlockDemodulator(chips, bits=scene.camera.bits, lag=0)
    for sequence in range(len(chips)):
        distortion_map = demodulator.push(simulator.render(sequence))
    if distortion_map is None:
        raise CalibrationError("the demodulator gave no map after one code period")
    return np.asarray(distortion_map.values, dtype=np.int32)


def check_lines_in_view(truth: Calibration, distance_m: float, margin_px: float = 5.0) -> None:
    """Refuse a target distance at which a line falls outside the image."""
    rows = flat_rows(truth, distance_m)[:, 0]
    if rows.min() < margin_px or rows.max() > truth.camera.height_px - 1 - margin_px:
        raise CalibrationError(f"at {distance_m} m line rows {np.round(rows, 1).tolist()} "
                               f"leave the {truth.camera.height_px}-row image; choose other "
                               "distances")


def _save_png(path: Path, image: npt.NDArray[np.uint8]) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(path), image):
        raise CalibrationError(f"cannot write {path}")


def _save_map(path: Path, values: npt.NDArray[np.int32]) -> None:
    """Save a map as int16 when every value fits (half the size), else int32."""
    path.parent.mkdir(parents=True, exist_ok=True)
    small = int(np.abs(values).max(initial=0)) <= np.iinfo(np.int16).max
    np.save(path, values.astype(np.int16) if small else values, allow_pickle=False)


def board_distances_m(spec: BoardSpec, camera: CameraModel) -> tuple[float, float]:
    """Board distances (m) at which the board spans 75 % down to 34 % of the image width."""
    near = camera.focal_px * spec.size_m[0] / (0.75 * camera.width_px)
    return near, 2.2 * near


def _intrinsic_views(out: Path, spec: BoardSpec, camera: CameraModel,
                     settings: SimulationSettings, rng: np.random.Generator) -> list[str]:
    names = []
    poses = random_poses(spec, camera, settings.intrinsic_views, rng,
                         distance_m=board_distances_m(spec, camera))
    for index, pose in enumerate(progress(poses, "board views", "view")):
        name = f"intrinsics/view_{index:03d}.png"
        _save_png(out / name, render_board_view(spec, camera, pose, rng))
        names.append(name)
    return names


def _flat_captures(out: Path, source: SceneSource, distances: Sequence[float],
                   rng: np.random.Generator, *, folder: str) -> list[FlatCapture]:
    captures = []
    for distance in progress(distances, f"{folder} target", "distance"):
        check_lines_in_view(source.truth, distance)
        name = f"{folder}/z_{distance:.3f}m.npy"
        _save_map(out / name, source.flat_map(distance, rng))
        captures.append(FlatCapture(float(distance), name))
    return captures


def _laser_board_distances_m(spec: BoardSpec, truth: Calibration) -> tuple[float, float]:
    """Board distances (m) at which the whole line fan fits on 70 % of the board height."""
    near, far = board_distances_m(spec, truth.camera)
    cot = 1.0 / np.tan(np.asarray(truth.laser.alpha_rad))
    fan = float(np.ptp(cot))
    far = min(far, 0.7 * spec.size_m[1] / fan) if fan > 0 else far
    if far < 1.1 * near:
        raise CalibrationError(f"the board ({spec.size_m[1]:.2f} m high) is too small for "
                               f"the line fan ({np.degrees(fan):.1f}° of cot α) in view; "
                               "use a larger --square-mm")
    return near, far


def _poses_with_every_line(spec: BoardSpec, truth: Calibration, count: int,
                           rng: np.random.Generator) -> list[BoardPose]:
    """Board poses on which every line crosses the board over a quarter of the width."""
    cot = 1.0 / np.tan(np.asarray(truth.laser.alpha_rad))
    aim = (float(np.mean(cot)), -truth.laser.baseline_m)  # the middle of the fan
    poses: list[BoardPose] = []
    for _ in range(50):
        for pose in random_poses(spec, truth.camera, count, rng, tilt_deg=20.0, aim_y=aim,
                                 distance_m=_laser_board_distances_m(spec, truth)):
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
    source = scene_source(scene, settings)
    truth = source.truth
    save_calibration(root / "truth.calib.toml", truth, {"method": "simulation truth",
                                                        "scene": scene})
    captures = CaptureSet(
        root, len(truth.laser.alpha_rad), spec, scene, "truth.calib.toml",
        tuple(_intrinsic_views(root, spec, truth.camera, settings, rng)),
        tuple(_flat_captures(root, source, settings.distances_m, rng, folder="flat")),
        tuple(_flat_captures(root, source, [settings.verify_distance_m], rng,
                             folder="verify")),
        tuple(_board_laser_captures(root, spec, truth, settings, rng)))
    write_manifest(captures)
    logger.info("capture set of scene %s written to %s", scene, root)
    return captures
