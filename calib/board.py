"""The ChArUco board: its description, detection, and a printable copy (PNG and PDF).

Only the OpenCV >= 4.8 API is used (``CharucoBoard``, ``CharucoDetector.detectBoard``,
``board.matchImagePoints``); OpenCV 5 removed the older ``aruco.detectMarkers`` family.
Board frame: origin at the outer top-left corner of the printed board, x along the
squares' columns, y along their rows, z into the board; metres.
"""

from __future__ import annotations

import logging
from dataclasses import asdict, dataclass
from pathlib import Path

import cv2
import numpy as np
import numpy.typing as npt

from atris_node.errors import CalibrationError

logger = logging.getLogger(__name__)

MM_PER_INCH = 25.4


@dataclass(frozen=True)
class BoardSpec:
    """A ChArUco board: squares across and down, square and marker side in metres."""

    squares_x: int = 10
    squares_y: int = 7
    square_m: float = 0.04
    marker_m: float = 0.03
    dictionary: str = "DICT_5X5_100"

    def __post_init__(self) -> None:
        if self.squares_x < 3 or self.squares_y < 3:
            raise CalibrationError(f"a board needs at least 3x3 squares, got "
                                   f"{self.squares_x}x{self.squares_y}")
        if not 0.0 < self.marker_m < self.square_m:
            raise CalibrationError(f"marker_m must be in (0, square_m={self.square_m}), "
                                   f"got {self.marker_m}")
        if not hasattr(cv2.aruco, self.dictionary):
            raise CalibrationError(f"unknown ArUco dictionary {self.dictionary!r}; accepted: "
                                   "names such as DICT_4X4_50, DICT_5X5_100, DICT_6X6_250")

    @property
    def size_m(self) -> tuple[float, float]:
        """Printed board width and height in metres."""
        return self.squares_x * self.square_m, self.squares_y * self.square_m

    @property
    def corner_count(self) -> int:
        """Number of inner chessboard corners."""
        return (self.squares_x - 1) * (self.squares_y - 1)

    def as_dict(self) -> dict[str, object]:
        """The fields as plain values, for calibration files."""
        return dict(asdict(self))

    def make_board(self) -> cv2.aruco.CharucoBoard:
        """The OpenCV board object."""
        dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, self.dictionary))
        return cv2.aruco.CharucoBoard((self.squares_x, self.squares_y), self.square_m,
                                      self.marker_m, dictionary)


def board_from_dict(values: dict[str, object]) -> BoardSpec:
    """A :class:`BoardSpec` from the ``[board]`` table of a file (unknown keys rejected)."""
    try:
        return BoardSpec(**values)  # type: ignore[arg-type]
    except TypeError as exc:
        raise CalibrationError(f"invalid board description {values}: {exc}") from exc


def texture(spec: BoardSpec, px_per_square: int, margin_px: int = 0) -> npt.NDArray[np.uint8]:
    """The board image, (squares_y·px + 2·margin, squares_x·px + 2·margin) uint8.

    Board point (X, Y) in metres is at texture pixel ``(X, Y)·px_per_square/square_m +
    margin_px`` (column, row).
    """
    size = (spec.squares_x * px_per_square, spec.squares_y * px_per_square)
    image = spec.make_board().generateImage(size, marginSize=0, borderBits=1)
    framed = cv2.copyMakeBorder(image, margin_px, margin_px, margin_px, margin_px,
                                cv2.BORDER_CONSTANT, value=255)
    return np.asarray(framed, dtype=np.uint8)


@dataclass(frozen=True)
class BoardDetection:
    """Board corners found in one image: (N, 3) float32 board points in metres and
    (N, 2) float32 image points (column, row) in pixels."""

    object_points: npt.NDArray[np.float32]
    image_points: npt.NDArray[np.float32]

    @property
    def count(self) -> int:
        """Number of corners."""
        return int(self.object_points.shape[0])


def to_gray8(image: npt.NDArray[np.generic]) -> npt.NDArray[np.uint8]:
    """(H, W) or (H, W, 3) uint8/uint16 image as (H, W) uint8 (16-bit scaled to its max)."""
    if image.ndim == 3:
        image = np.asarray(cv2.cvtColor(np.asarray(image, dtype=image.dtype),
                                        cv2.COLOR_BGR2GRAY))
    if image.dtype == np.uint8:
        return np.asarray(image, dtype=np.uint8)
    scale = 255.0 / max(float(image.max()), 1.0)
    return np.clip(image.astype(np.float32) * scale, 0, 255).astype(np.uint8)


def detect(spec: BoardSpec, image: npt.NDArray[np.generic],
           board: cv2.aruco.CharucoBoard | None = None) -> BoardDetection | None:
    """Find the board's inner corners in ``image``; None when no corner is found."""
    board = spec.make_board() if board is None else board
    corners, ids, _, _ = cv2.aruco.CharucoDetector(board).detectBoard(to_gray8(image))
    if ids is None or len(ids) == 0:
        return None
    object_points, image_points = board.matchImagePoints(corners, ids)  # type: ignore[call-overload]
    return BoardDetection(object_points.reshape(-1, 3).astype(np.float32),
                          image_points.reshape(-1, 2).astype(np.float32))


def write_printable(spec: BoardSpec, png_path: str | Path, pdf_path: str | Path | None,
                    dpi: int = 300) -> tuple[Path, Path | None]:
    """Write the board at true size: a PNG at ``dpi`` and a one-page PDF (print at 100 %)."""
    px_per_square = round(spec.square_m * 1000.0 / MM_PER_INCH * dpi)
    image = texture(spec, px_per_square, margin_px=px_per_square // 2)
    png = Path(png_path)
    png.parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(png), image):
        raise CalibrationError(f"cannot write the board image {png}")
    logger.info("board %s written to %s (%d px per square)", spec, png, px_per_square)
    return png, (None if pdf_path is None else _write_pdf(image, Path(pdf_path), dpi, spec))


def _write_pdf(image: npt.NDArray[np.uint8], path: Path, dpi: int, spec: BoardSpec) -> Path:
    """One page the size of the board image, drawn 1:1, with its dimensions as a caption."""
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.backends.backend_pdf import PdfPages
    from matplotlib.figure import Figure

    height_in, width_in = image.shape[0] / dpi, image.shape[1] / dpi
    figure = Figure(figsize=(width_in, height_in + 0.4))
    axes = figure.add_axes((0.0, 0.4 / (height_in + 0.4), 1.0, height_in / (height_in + 0.4)))
    axes.imshow(image, cmap="gray", vmin=0, vmax=255, interpolation="nearest")
    axes.set_axis_off()
    figure.text(0.02, 0.1 / (height_in + 0.4), f"ChArUco {spec.squares_x}x{spec.squares_y}, "
                f"square {spec.square_m * 1000:.1f} mm, marker {spec.marker_m * 1000:.1f} mm, "
                f"{spec.dictionary}; print at 100 %", fontsize=8)
    path.parent.mkdir(parents=True, exist_ok=True)
    with PdfPages(path) as pdf:
        pdf.savefig(figure, dpi=dpi)
    return path


def estimate_pose(spec: BoardSpec, camera_matrix: npt.NDArray[np.float64],
                  distortion: npt.NDArray[np.float64], image: npt.NDArray[np.generic],
                  min_corners: int = 8) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """Board-to-camera pose (rvec (3,), tvec (3,) in m) from one view, by ``solvePnP``."""
    detection = detect(spec, image)
    if detection is None or detection.count < min_corners:
        found = 0 if detection is None else detection.count
        raise CalibrationError(f"board pose needs at least {min_corners} corners, found {found}")
    ok, rvec, tvec = cv2.solvePnP(detection.object_points, detection.image_points,
                                  camera_matrix, distortion)
    if not ok:
        raise CalibrationError("solvePnP found no board pose for this view")
    return (np.asarray(rvec, dtype=np.float64).ravel(),
            np.asarray(tvec, dtype=np.float64).ravel())
