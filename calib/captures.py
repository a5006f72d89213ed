"""A capture set: the images and distortion maps one calibration run works on.

A folder with a manifest ``captures.toml`` (written by ``atris calib simulate``, or by
hand for captures from a real unit)::

    format = "atris-captures"
    version = 1
    scene = "indoor_lab"          # where the captures came from (free text)
    lines = 3                     # projected lines visible on every target
    truth = "truth.calib.toml"    # optional: the true calibration (simulated sets)
    intrinsics = ["intrinsics/view_000.png", ...]   # ChArUco views, projector off

    [board]                       # the ChArUco board (calib.board.BoardSpec fields)
    squares_x = 10
    ...

    [[flat]]                      # flat target perpendicular to the optical axis
    distance_m = 0.6
    map = "flat/z_0.600m.npy"     # distortion map, (H, W) int16/int32 .npy

    [[verify]]                    # same, kept apart for `atris calib verify`
    ...

    [[board_laser]]               # the board at one pose: view (laser off) + map
    image = "board_laser/pose_000.png"
    map = "board_laser/pose_000.npy"

Paths are relative to the folder.
"""

from __future__ import annotations

import tomllib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import numpy.typing as npt

from atris_node.errors import CalibrationError
from calib.board import BoardSpec, board_from_dict
from calib.files import toml_table, toml_value

FORMAT = "atris-captures"
VERSION = 1
MANIFEST = "captures.toml"


@dataclass(frozen=True)
class FlatCapture:
    """A distortion map of a flat target at ``distance_m`` metres."""

    distance_m: float
    map: str


@dataclass(frozen=True)
class BoardLaserCapture:
    """A board view (projector off) and the distortion map at the same pose."""

    image: str
    map: str


@dataclass(frozen=True)
class CaptureSet:
    """The manifest of a capture set; file names are relative to ``root``."""

    root: Path
    lines: int
    board: BoardSpec
    scene: str = ""
    truth: str = ""
    intrinsics: tuple[str, ...] = ()
    flat: tuple[FlatCapture, ...] = ()
    verify: tuple[FlatCapture, ...] = ()
    board_laser: tuple[BoardLaserCapture, ...] = field(default_factory=tuple)

    def path(self, name: str) -> Path:
        """Absolute path of a file of the set."""
        return self.root / name


def load_map(path: str | Path) -> npt.NDArray[np.int32]:
    """A distortion map from a ``.npy`` file: (H, W) integer array, returned as int32."""
    try:
        values = np.load(Path(path), allow_pickle=False)
    except (OSError, ValueError) as exc:
        raise CalibrationError(f"cannot read distortion map {path}: {exc}") from exc
    if values.ndim != 2 or not np.issubdtype(values.dtype, np.integer):
        raise CalibrationError(f"{path}: a distortion map must be a (H, W) integer array, "
                               f"got {values.dtype} {values.shape}")
    return values.astype(np.int32)


def _entries(items: tuple[FlatCapture, ...] | tuple[BoardLaserCapture, ...], name: str) -> str:
    out = ""
    for item in items:
        out += f"\n[[{name}]]\n" + "".join(
            f"{k} = {toml_value(v, name)}\n" for k, v in vars(item).items())
    return out


def write_manifest(captures: CaptureSet) -> Path:
    """Write ``captures.toml`` into ``captures.root``."""
    text = (f'format = "{FORMAT}"\nversion = {VERSION}\n'
            f"scene = {toml_value(captures.scene, 'scene')}\nlines = {captures.lines}\n"
            f"truth = {toml_value(captures.truth, 'truth')}\n"
            f"intrinsics = {toml_value(list(captures.intrinsics), 'intrinsics')}\n\n"
            + toml_table("board", captures.board.as_dict())
            + _entries(captures.flat, "flat") + _entries(captures.verify, "verify")
            + _entries(captures.board_laser, "board_laser"))
    path = captures.root / MANIFEST
    path.write_text(text, encoding="utf-8")
    return path


def _flat(doc: dict[str, object], name: str, where: Path) -> tuple[FlatCapture, ...]:
    try:
        return tuple(FlatCapture(float(e["distance_m"]), str(e["map"]))
                     for e in doc.get(name, []))  # type: ignore[attr-defined]
    except (KeyError, TypeError, ValueError) as exc:
        raise CalibrationError(f"{where}: each [[{name}]] needs distance_m and map") from exc


def _board_laser(doc: dict[str, object], where: Path) -> tuple[BoardLaserCapture, ...]:
    try:
        return tuple(BoardLaserCapture(str(e["image"]), str(e["map"]))
                     for e in doc.get("board_laser", []))  # type: ignore[attr-defined]
    except (KeyError, TypeError) as exc:
        raise CalibrationError(f"{where}: each [[board_laser]] needs image and map") from exc


def load_capture_set(root: str | Path) -> CaptureSet:
    """Read and check the manifest of the capture set in folder ``root``."""
    folder = Path(root)
    where = folder / MANIFEST
    try:
        doc = tomllib.loads(where.read_text(encoding="utf-8"))
    except (OSError, tomllib.TOMLDecodeError) as exc:
        raise CalibrationError(f"cannot read the capture manifest {where}: {exc}") from exc
    if doc.get("format") != FORMAT or doc.get("version") != VERSION:
        raise CalibrationError(f"{where}: expected format {FORMAT!r} version {VERSION}")
    lines = doc.get("lines")
    if not isinstance(lines, int) or lines < 1:
        raise CalibrationError(f"{where}: lines must be a positive integer, got {lines!r}")
    return CaptureSet(folder, lines, board_from_dict(dict(doc.get("board", {}))),
                      str(doc.get("scene", "")), str(doc.get("truth", "")),
                      tuple(str(p) for p in doc.get("intrinsics", [])),
                      _flat(doc, "flat", where), _flat(doc, "verify", where),
                      _board_laser(doc, where))
