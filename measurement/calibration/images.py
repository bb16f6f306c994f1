"""Calibrate a stereo pair from image files (real or rendered): read, detect, pair, calibrate."""
from __future__ import annotations

import itertools
import os
import warnings
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from tqdm import tqdm

from measurement.calibration.detection import board_points_mm, detect_checkerboard, refine_corners_saddle
from measurement.calibration.stepwise import (MIN_POINTS_PER_VIEW, CalibrationError, StereoCalibration,
                                              calibrate_stereo)
from measurement.calibration.targets import (CharucoSpec, DotGridSpec, charuco_points_mm, detect_charuco,
                                             detect_dot_grid, dot_grid_points_mm)
from measurement.image_io import read_grey

#: Fewest stereo views the stepwise procedure accepts (Zhang's initialisation needs >= 3 homographies).
MIN_VIEWS = 3


def target_points_mm(target, pattern_size=(11, 8), square_mm: float = 5.0) -> np.ndarray:
    """The board points (N, 3) mm of ``target``: a checkerboard's inner corners (``pattern_size``, ``square_mm``)
    for ``None``, else a :class:`~measurement.calibration.targets.CharucoSpec` or
    :class:`~measurement.calibration.targets.DotGridSpec`."""
    if target is None:
        return board_points_mm(pattern_size, square_mm)
    if isinstance(target, CharucoSpec):
        return charuco_points_mm(target)
    if isinstance(target, DotGridSpec):
        return dot_grid_points_mm(target)
    raise TypeError(f"target must be None, a CharucoSpec or a DotGridSpec, got {type(target).__name__}")


def _target_name(target, pattern_size) -> str:
    if isinstance(target, CharucoSpec):
        return f"{target.squares[0]} x {target.squares[1]}-square ChArUco board ({target.dictionary})"
    if isinstance(target, DotGridSpec):
        return f"{target.pattern_size[0]} x {target.pattern_size[1]} dot grid"
    return f"{pattern_size[0]} x {pattern_size[1]}-corner board"


def _detect_all(paths: list[str], size: list, pattern_size, refine: bool, target, progress: bool, per_item: int = 1):
    """:func:`_read_and_detect` of every path, in order (an iterator), on as many threads as the machine has cores:
    OpenCV's detector releases the GIL, and one board is detected on one core. The first image is read alone, so
    every other one is checked against its size. The progress bar counts ``per_item`` paths as one item."""
    bar = tqdm(total=len(paths) // per_item, desc="detecting boards", disable=not progress)
    first = _read_and_detect(paths[0], size, pattern_size, refine, target)
    workers = max(1, min(os.cpu_count() or 1, len(paths) - 1))
    with ThreadPoolExecutor(workers) as pool:
        rest = pool.map(lambda path: _read_and_detect(path, size, pattern_size, refine, target), paths[1:])
        for k, corners in enumerate(itertools.chain([first], rest)):
            if (k + 1) % per_item == 0:
                bar.update(1)
            yield corners
    bar.close()


def _read_and_detect(path: str, size: list, pattern_size, refine: bool, target=None) -> np.ndarray | None:
    """Read one image, check it has the size of the first one (``size``: [] or [(width, height, file)], filled by
    the first call) and detect its board: a checkerboard of ``pattern_size`` (saddle-refined with ``refine``) for
    ``target=None``, else the ChArUco board or dot grid of the spec. A ChArUco view with fewer than
    :data:`~measurement.calibration.stepwise.MIN_POINTS_PER_VIEW` corners counts as not found."""
    img = read_grey(path)
    if not size:
        size.append((img.shape[1], img.shape[0], path))
    elif (img.shape[1], img.shape[0]) != size[0][:2]:
        raise CalibrationError(f"image {path} is {img.shape[1]} x {img.shape[0]} px but {size[0][2]} is "
                               f"{size[0][0]} x {size[0][1]} px: all images must have one size")
    if isinstance(target, CharucoSpec):
        corners = detect_charuco(img, target)
        return corners if np.all(np.isfinite(corners), axis=1).sum() >= MIN_POINTS_PER_VIEW else None
    if isinstance(target, DotGridSpec):
        return detect_dot_grid(img, target)
    corners = detect_checkerboard(img, pattern_size)
    return corners if corners is None or not refine else refine_corners_saddle(img, corners, pattern_size)


@dataclass
class DetectedPairs:
    """Corners found in both images of each usable pair."""

    left_files: list[str]
    right_files: list[str]
    points_left: np.ndarray     # (V, N, 2)
    points_right: np.ndarray    # (V, N, 2)
    image_size: tuple[int, int]
    dropped: list[str]          # files whose board was not found (their pair is dropped)


def detect_pairs(left_files, right_files, pattern_size=(11, 8), progress: bool = True,
                 refine: bool = False, min_views: int = MIN_VIEWS, target=None) -> DetectedPairs:
    """Detect the board in every left/right pair (paired in the given order).

    ``refine``: also fit a blurred saddle model around every corner (:func:`refine_corners_saddle`; ~3x lower
    corner error than OpenCV's on full-resolution renders, ~0.15 s per 5 MP board). ``min_views``: fewest usable
    pairs accepted (calibration needs 3; validation sets may be smaller). ``target``: a ChArUco or dot-grid spec
    instead of the checkerboard of ``pattern_size`` (ChArUco corners not seen are NaN rows).
    """
    left_files, right_files = [str(f) for f in left_files], [str(f) for f in right_files]
    if not left_files:
        raise CalibrationError("no left images given (check the --left pattern)")
    if len(left_files) != len(right_files):
        raise CalibrationError(f"{len(left_files)} left images but {len(right_files)} right images: they must pair up")
    size = []
    pts_l, pts_r, used_l, used_r, dropped = [], [], [], [], []
    found = _detect_all([f for pair in zip(left_files, right_files) for f in pair], size, pattern_size, refine,
                        target, progress, per_item=2)
    for fl, fr in zip(left_files, right_files):
        corners = [next(found), next(found)]
        missing = [f for f, c in zip((fl, fr), corners) if c is None]
        if missing:
            warnings.warn(f"board not found in {', '.join(missing)}: dropping the pair ({Path(fl).name}, "
                          f"{Path(fr).name})", stacklevel=2)
            dropped.extend(missing)
            continue
        pts_l.append(corners[0])
        pts_r.append(corners[1])
        used_l.append(fl)
        used_r.append(fr)
    if len(pts_l) < min_views:
        raise CalibrationError(f"only {len(pts_l)} of {len(left_files)} stereo pairs show the "
                               f"{_target_name(target, pattern_size)} in both images; at least "
                               f"{min_views} are needed (check --pattern and the images)")
    return DetectedPairs(used_l, used_r, np.array(pts_l), np.array(pts_r), size[0][:2], dropped)


def calibrate_from_files(left_files, right_files, *, square_mm: float, pattern_size=(11, 8), model: str = "rmm",
                         tilt_guess_left_deg=(0.0, 0.0), tilt_guess_right_deg=(0.0, 0.0), joint: bool = True,
                         progress: bool = True, refine_corners: bool = False,
                         lens: str = "brown4", target=None) -> tuple[StereoCalibration, DetectedPairs]:
    """Detect the board in every pair and run the stepwise stereo calibration (``lens``: see
    :data:`~measurement.calibration.stepwise.LENSES`; ``target``: see :func:`detect_pairs`)."""
    pairs = detect_pairs(left_files, right_files, pattern_size, progress, refine=refine_corners, target=target)
    cal = calibrate_stereo(pairs.points_left, pairs.points_right, target_points_mm(target, pattern_size, square_mm),
                           pairs.image_size, model=model, tilt_guess_left_deg=tilt_guess_left_deg,
                           tilt_guess_right_deg=tilt_guess_right_deg, joint=joint, lens=lens)
    return cal, pairs


@dataclass
class DetectedViews:
    """Corners found in the images of one camera."""

    files: list[str]
    points: np.ndarray          # (V, N, 2)
    image_size: tuple[int, int]
    dropped: list[str]          # files whose board was not found


def detect_views(files, pattern_size=(11, 8), progress: bool = True, refine: bool = False,
                 min_views: int = MIN_VIEWS, target=None) -> DetectedViews:
    """Detect the board in every image of one camera (single-camera calibration); ``refine`` as in
    :func:`detect_pairs`. Images whose board is not found are dropped with a warning."""
    files = [str(f) for f in files]
    if not files:
        raise CalibrationError("no images given (check the --camera pattern)")
    size = []
    points, used, dropped = [], [], []
    found = _detect_all(files, size, pattern_size, refine, target, progress)
    for f in files:
        corners = next(found)
        if corners is None:
            warnings.warn(f"board not found in {f}: dropping it", stacklevel=2)
            dropped.append(f)
            continue
        points.append(corners)
        used.append(f)
    if len(points) < min_views:
        raise CalibrationError(f"only {len(points)} of {len(files)} images show the "
                               f"{_target_name(target, pattern_size)}; at least {min_views} are needed (check "
                               "--pattern and the images)")
    return DetectedViews(used, np.array(points), size[0][:2], dropped)
