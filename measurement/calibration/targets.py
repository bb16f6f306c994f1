"""ChArUco and dot-grid (circle-grid) calibration targets: specs, board points and detection in canonical order.

The instrument side of the targets. The specs are what an experimenter knows about a printed target (its
numbers); they are independent of the renderer's target models (``scenes.surfaces.checkerboard``), with which they agree by
numbers only (squares, sizes, dictionary name).

Board frames (mm, z = 0 on the printed face, z into the board, as :func:`measurement.calibration.detection.
board_points_mm`):

* ChArUco: origin at the first (top-left) inner chessboard corner, x along a row of corners, y along a column;
  point ``k`` is OpenCV's ChArUco corner id ``k`` (row by row, x fastest), at ``(k % nx, k // nx) * square_mm``
  with ``nx = columns - 1``. The markers identify every corner, so the order is the same in every camera and
  partial views give the corners they see (NaN rows for the others).
* Dot grid: origin at the centre of the first dot, point ``k = i cols + j`` at ``(j, i) * pitch_mm``. A
  symmetric grid has no orientation mark; the order is fixed by the image (see :func:`detect_dot_grid`).

A dot's detected position is the centroid of its image, which under perspective is not the image of its
centre (the eccentricity error, a few hundredths of a pixel on tilted views, see ``scenes.surfaces.dot_grid.DotGrid``);
this module does not correct it.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from measurement.calibration.detection import to_gray8, saddle_points


def _positive(name: str, value) -> float:
    """``value`` as a float, or ValueError naming the option when it is not a positive finite number."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)) \
            or not math.isfinite(float(value)) or not float(value) > 0:
        raise ValueError(f"{name} must be a positive finite number, got {value!r}")
    return float(value)


def _count_pair(name: str, value, minimum: int) -> tuple[int, int]:
    """``value`` as a (columns, rows) pair of integers >= minimum, or ValueError naming the option."""
    ok = (isinstance(value, (tuple, list)) and len(value) == 2
          and all(isinstance(c, (int, np.integer)) and not isinstance(c, (bool, np.bool_)) and c >= minimum
                  for c in value))
    if not ok:
        raise ValueError(f"{name} must be (columns, rows), integers >= {minimum}, got {value!r}")
    return int(value[0]), int(value[1])


def aruco_dictionary(name: str):
    """OpenCV's predefined dictionary ``cv2.aruco.<name>`` (e.g. ``"DICT_4X4_50"``), or ValueError naming
    ``dictionary`` and listing the known names."""
    if not (isinstance(name, str) and name.startswith("DICT_") and isinstance(getattr(cv2.aruco, name, None), int)):
        known = ", ".join(sorted(n for n in dir(cv2.aruco) if n.startswith("DICT_")))
        raise ValueError(f"dictionary must name one of OpenCV's predefined ArUco dictionaries ({known}), got {name!r}")
    return cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, name))


@dataclass(frozen=True)
class CharucoSpec:
    """A ChArUco board as printed by OpenCV (``cv2.aruco.CharucoBoard``, non-legacy pattern: the top-left
    square is black, markers in the white squares, ids 0, 1, ... row by row).

    Parameters
    ----------
    squares : (columns, rows)
        Chessboard squares, each >= 3; ``(columns - 1) * (rows - 1)`` inner corners.
    square_mm : float, mm
        Edge of one square.
    marker_mm : float, mm
        Side of one marker including its black border, ``0 < marker_mm < square_mm``.
    dictionary : str
        OpenCV predefined dictionary name, holding at least ``columns * rows // 2`` markers.
    """

    squares: tuple[int, int]
    square_mm: float
    marker_mm: float
    dictionary: str = "DICT_4X4_50"

    def __post_init__(self):
        _count_pair("squares", self.squares, 3)
        square = _positive("square_mm", self.square_mm)
        marker = _positive("marker_mm", self.marker_mm)
        if not marker < square:
            raise ValueError(f"marker_mm must be smaller than square_mm ({square:g} mm), got {marker:g} mm")
        size = len(aruco_dictionary(self.dictionary).bytesList)
        needed = self.squares[0] * self.squares[1] // 2
        if needed > size:
            raise ValueError(f"dictionary {self.dictionary} holds {size} markers, squares {tuple(self.squares)} "
                             f"need {needed}")

    @property
    def inner_corners(self) -> tuple[int, int]:
        """(columns, rows) of inner corners (ChArUco corners)."""
        return self.squares[0] - 1, self.squares[1] - 1

    @property
    def n_points(self) -> int:
        nx, ny = self.inner_corners
        return nx * ny

    def opencv_board(self):
        """The ``cv2.aruco.CharucoBoard`` of this spec (its own frame: origin at the outer top-left corner)."""
        return cv2.aruco.CharucoBoard(tuple(int(c) for c in self.squares), float(self.square_mm),
                                      float(self.marker_mm), aruco_dictionary(self.dictionary))


@dataclass(frozen=True)
class DotGridSpec:
    """A symmetric grid of round dots.

    Parameters
    ----------
    pattern_size : (cols, rows)
        Dots per row and per column, each >= 2 (OpenCV's ``patternSize``).
    pitch_mm : float, mm
        Centre-to-centre distance of neighbouring dots.
    diameter_mm : float, mm
        Dot diameter, ``0 < diameter_mm < pitch_mm``: sizes the blob detector's area window.
    dark_dots : bool
        True: dark dots on a light sheet; False: light dots on a dark sheet.
    """

    pattern_size: tuple[int, int]
    pitch_mm: float
    diameter_mm: float
    dark_dots: bool = True

    def __post_init__(self):
        _count_pair("pattern_size", self.pattern_size, 2)
        pitch = _positive("pitch_mm", self.pitch_mm)
        d = _positive("diameter_mm", self.diameter_mm)
        if not d < pitch:
            raise ValueError(f"diameter_mm must be smaller than pitch_mm ({pitch:g} mm), got {d:g} mm")
        if not isinstance(self.dark_dots, (bool, np.bool_)):
            raise ValueError(f"dark_dots must be True or False, got {self.dark_dots!r}")

    @property
    def n_points(self) -> int:
        return int(self.pattern_size[0]) * int(self.pattern_size[1])


# ------------------------------------------------------------------------------------------------------------
# Board points
def charuco_points_mm(spec: CharucoSpec) -> np.ndarray:
    """ChArUco corners in the board frame in id order, (N, 3) mm, z = 0 (origin at the first inner corner).

    Taken from OpenCV's board (``getChessboardCorners``, whose origin is the outer top-left corner) and moved by
    one square, so that they are :func:`measurement.calibration.detection.board_points_mm` of the inner corners.
    """
    corners = np.asarray(spec.opencv_board().getChessboardCorners(), dtype=float).reshape(-1, 3)
    return corners - np.array([spec.square_mm, spec.square_mm, 0.0])


def dot_grid_points_mm(spec: DotGridSpec) -> np.ndarray:
    """Dot centres in the board frame in the canonical order, (N, 3) mm, z = 0 (row by row, x fastest)."""
    nx, ny = spec.pattern_size
    jj, ii = np.meshgrid(np.arange(nx), np.arange(ny))
    return np.stack([jj.ravel() * spec.pitch_mm, ii.ravel() * spec.pitch_mm, np.zeros(nx * ny)], axis=1)


# ------------------------------------------------------------------------------------------------------------
# Detection
def _corner_spacing_px(points: np.ndarray, nx: int) -> float:
    """Median distance (px) between found ChArUco corners that are neighbours in a row or a column (ids k, k + 1
    in one row; k, k + nx); NaN if none."""
    found = np.all(np.isfinite(points), axis=1)
    ids = np.arange(len(points))
    d = []
    for step, same_row in ((1, True), (nx, False)):
        a = ids[:-step]
        pair = found[a] & found[a + step] & ((a % nx != nx - 1) if same_row else True)
        d.append(np.linalg.norm(points[a + step][pair] - points[a][pair], axis=1))
    d = np.concatenate(d)
    return float(np.median(d)) if d.size else float("nan")


def detect_charuco(image: np.ndarray, spec: CharucoSpec, *, refine: bool = True) -> np.ndarray:
    """Sub-pixel ChArUco corners, row ``k`` for corner id ``k``; NaN rows for corners not found.

    Parameters
    ----------
    image : (H, W) or (H, W, 3) array, 8- or 16-bit or float grey levels
        Converted to 8 bits over the data's own range, as :func:`measurement.calibration.detection.
        detect_checkerboard` does.
    spec : CharucoSpec

    Returns
    -------
    (N, 2) float array, px (OpenCV convention), N = ``spec.n_points``, in the order of
    :func:`charuco_points_mm`; all NaN if no corner is found.

    ``cv2.aruco.CharucoDetector`` (OpenCV >= 4.7): markers are detected and identified (their corners refined
    by ``CORNER_REFINE_SUBPIX``), each chessboard corner next to found markers is located from them and refined
    by ``cornerSubPix`` on the image. Measured on rendered views (``tests/test_targets_charuco_dots.py``): about
    0.08 px RMS from the true corners, up to ~0.3 px on oblique views, i.e. about twice the error of
    :func:`measurement.calibration.detection.detect_checkerboard` on the same rig (the markers inside the
    white squares sit in ``cornerSubPix``'s window). ``refine`` (default) then moves each corner to the saddle
    point of the image (:func:`measurement.calibration.detection.saddle_points`) in a window that stays inside the
    white margin between the corner and the markers (3/4 of it, 3-12 px half-width): 0.029 px RMS (max 0.08 px)
    instead of 0.079 px (max 0.32 px) on the same views (14 quarter-scale stereo views of the paper rig).
    """
    if not isinstance(spec, CharucoSpec):
        raise ValueError(f"spec must be a CharucoSpec, got {type(spec).__name__}")
    if not hasattr(cv2.aruco, "CharucoDetector"):
        raise RuntimeError(f"ChArUco detection needs OpenCV >= 4.7 (cv2.aruco.CharucoDetector); this is "
                           f"{cv2.__version__}")
    gray = to_gray8(image)
    # Sub-pixel marker corners give the corner interpolation a better start: 0.090 px instead of 0.104 px RMS
    # against the truth on rendered views (cv2's default, no marker refinement).
    markers = cv2.aruco.DetectorParameters()
    markers.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    detector = cv2.aruco.CharucoDetector(spec.opencv_board(), cv2.aruco.CharucoParameters(), markers)
    corners, ids, _, _ = detector.detectBoard(gray)
    out = np.full((spec.n_points, 2), np.nan)
    if ids is None or corners is None or len(ids) == 0:
        return out
    ids = np.asarray(ids).reshape(-1).astype(int)
    out[ids] = np.asarray(corners, dtype=float).reshape(-1, 2)
    if refine:
        spacing = _corner_spacing_px(out, spec.squares[0] - 1)
        if np.isfinite(spacing):
            margin_px = spacing * (spec.square_mm - spec.marker_mm) / (2.0 * spec.square_mm)
            half = int(np.clip(np.floor(0.75 * margin_px), 3, 12))
            found = np.all(np.isfinite(out), axis=1)
            out[found] = saddle_points(image, out[found], half, sigma_px=half / 3.0)
    return out


def _blob_detector(spec: DotGridSpec, image_shape: tuple[int, int], min_area_px: float) -> cv2.SimpleBlobDetector:
    """A blob detector for the spec's dots: polarity from ``dark_dots``, area from ``min_area_px`` up to the
    largest a dot can be (the image shared by ``cols * rows`` dots at ``(diameter / pitch)^2`` of their cell)."""
    params = cv2.SimpleBlobDetector_Params()
    params.blobColor = 0 if spec.dark_dots else 255
    params.filterByArea = True
    params.minArea = float(min_area_px)
    cell_px2 = image_shape[0] * image_shape[1] / spec.n_points
    params.maxArea = float(max(min_area_px + 1.0, cell_px2 * (spec.diameter_mm / spec.pitch_mm) ** 2 * math.pi / 4))
    params.filterByCircularity = False
    params.filterByConvexity = True
    params.minConvexity = 0.9
    params.filterByInertia = True
    params.minInertiaRatio = 0.1                     # oblique views make ellipses; 0.1 allows ~84 deg of tilt
    params.minDistBetweenBlobs = 2.0
    return cv2.SimpleBlobDetector_create(params)


def _canonical_grid_order(centres: np.ndarray, pattern_size: tuple[int, int]) -> np.ndarray:
    """Reorder an OpenCV grid (row by row, any of its symmetries) so that rows run left to right and the
    rows top to bottom in the image: point 0 is the top-left dot as seen.

    Returns (N, 2). The row direction (mean step along a row) is made to point within 90 deg of +x and the
    column direction within 90 deg of +y; on a square grid, rows are also chosen as the direction closer to x.
    """
    nx, ny = pattern_size
    grid = centres.reshape(ny, nx, 2)
    if nx == ny:
        row_step = np.mean(np.diff(grid, axis=1), axis=(0, 1))
        col_step = np.mean(np.diff(grid, axis=0), axis=(0, 1))
        if abs(col_step[0]) > abs(row_step[0]):      # OpenCV's rows run down the image: transpose
            grid = grid.transpose(1, 0, 2)
    if np.mean(np.diff(grid, axis=1), axis=(0, 1))[0] < 0:
        grid = grid[:, ::-1]
    if np.mean(np.diff(grid, axis=0), axis=(0, 1))[1] < 0:
        grid = grid[::-1]
    return np.ascontiguousarray(grid).reshape(-1, 2)


#: Most blob candidates handed to ``cv2.findCirclesGrid``, per dot of the grid: its grid search grows faster than
#: linearly with the candidates (0.02 s for a clean view, 0.1 s with 100 clutter blobs, minutes for the 6000
#: blobs of a noise image), so an image with more is refused (``None``) before the search.
MAX_CANDIDATES_PER_DOT = 10


def detect_dot_grid(image: np.ndarray, spec: DotGridSpec, *, min_area_px: float = 8.0) -> np.ndarray | None:
    """Dot centres of a symmetric dot grid, in the canonical order; ``None`` if the grid is not found whole.

    Parameters
    ----------
    image : (H, W) or (H, W, 3) array, 8- or 16-bit or float grey levels (converted as :func:`detect_charuco`)
    spec : DotGridSpec
    min_area_px : float, px^2
        Smallest blob area accepted as a dot (> 0).

    Returns
    -------
    (cols * rows, 2) float array, px (OpenCV convention), or ``None`` (also when the blob detector finds fewer
    blobs than dots, or more than :data:`MAX_CANDIDATES_PER_DOT` per dot: a cluttered or noise image).

    ``cv2.findCirclesGrid`` with ``CALIB_CB_SYMMETRIC_GRID`` on blobs of a ``SimpleBlobDetector`` tuned to the
    spec (polarity, area window); a blob's position is the centroid of its thresholded region, averaged over
    thresholds. Order: a symmetric grid looks the same after a half turn (and a quarter turn if square), so
    point 0 is the dot that is top-left *in the image* and rows run left to right (see
    :func:`_canonical_grid_order`). Both cameras of a stereo rig then agree as long as neither sees the board
    turned by 90 deg or more (45 deg for a square grid) in its image plane (random calibration poses here
    spin it by at most 20 deg);
    past that, use a ChArUco board.
    """
    if not isinstance(spec, DotGridSpec):
        raise ValueError(f"spec must be a DotGridSpec, got {type(spec).__name__}")
    min_area = _positive("min_area_px", min_area_px)
    gray = to_gray8(image)
    nx, ny = int(spec.pattern_size[0]), int(spec.pattern_size[1])
    detector = _blob_detector(spec, gray.shape, min_area)
    candidates = len(detector.detect(gray))
    if not nx * ny <= candidates <= MAX_CANDIDATES_PER_DOT * nx * ny:
        return None
    found, centres = cv2.findCirclesGrid(gray, (nx, ny), flags=cv2.CALIB_CB_SYMMETRIC_GRID, blobDetector=detector)
    if not found or centres is None or len(centres) != nx * ny:
        found, centres = cv2.findCirclesGrid(gray, (nx, ny),
                                             flags=cv2.CALIB_CB_SYMMETRIC_GRID | cv2.CALIB_CB_CLUSTERING,
                                             blobDetector=detector)
    if not found or centres is None or len(centres) != nx * ny:
        return None
    return _canonical_grid_order(np.asarray(centres, dtype=float).reshape(-1, 2), (nx, ny))
