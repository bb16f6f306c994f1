"""Checkerboard detection of large images on a downscaled copy, refined at full size (saddle points).

References: an analytic blurred X-corner (erf profile, exact sub-pixel position) for :func:`saddle_points`, and the
truth side's projection of the board corners for a full-resolution render of the paper rig.
"""
from __future__ import annotations

import numpy as np
import pytest
from scipy.special import erf

from measurement.calibration.detection import DETECT_MAX_SIDE_PX, detect_checkerboard, saddle_points
from scenes.surfaces.checkerboard import Checkerboard
from workbench.experiments.calibration.views import board_outline_mm, render_board_views
from workbench.poses import random_board_poses
from workbench.rigs import get_rig


def _x_corner(centre, angle1_rad, angle2_rad, blur_px, size=41, noise=0.0, seed=0):
    """Pixel-integrated (3 x 3 supersampled) image of a blurred X-corner whose lines cross at ``centre``."""
    rng = np.random.default_rng(seed)
    sub = (np.arange(3) - 1) / 3.0
    vv, uu = np.mgrid[0:size, 0:size].astype(float)
    img = np.zeros((size, size))
    for du in sub:
        for dv in sub:
            x, y = uu + du - centre[0], vv + dv - centre[1]
            d1 = -np.sin(angle1_rad) * x + np.cos(angle1_rad) * y
            d2 = -np.sin(angle2_rad) * x + np.cos(angle2_rad) * y
            img += 0.5 + 0.4 * erf(d1 / (np.sqrt(2) * blur_px)) * erf(d2 / (np.sqrt(2) * blur_px))
    return 200.0 * img / 9.0 + rng.normal(0.0, noise, img.shape)


@pytest.mark.parametrize("centre,angles", [((20.3, 19.8), (0.1, 1.6)), ((20.71, 20.44), (-0.4, 0.9)),
                                           ((19.52, 20.05), (0.3, 2.2))])
def test_saddle_point_of_an_analytic_corner_within_0_02_px(centre, angles):
    """Noise-free blurred X-corners (including non-orthogonal lines, as under perspective): the saddle point lies
    within 0.02 px of the true crossing, from a start 1.5 px away."""
    img = _x_corner(centre, *angles, blur_px=1.2)
    start = np.array([[centre[0] + 1.2, centre[1] - 0.9]])
    found = saddle_points(img, start, half_px=6, sigma_px=2.0)[0]
    assert np.hypot(*(found - centre)) < 0.02, found


def test_saddle_point_with_noise_is_unbiased_within_0_01_px():
    """With 1 % grey noise the error over 40 noise draws averages below 0.01 px (bias) and scatters < 0.05 px."""
    centre = (20.37, 20.61)
    errs = np.array([saddle_points(_x_corner(centre, 0.2, 1.7, 1.0, noise=2.0, seed=s), np.array([[20.0, 21.0]]),
                                   half_px=6, sigma_px=2.0)[0] - centre for s in range(40)])
    assert np.hypot(*errs.mean(axis=0)) < 0.01
    assert np.sqrt(np.mean(np.sum(errs ** 2, axis=1))) < 0.05


def test_a_corner_that_is_not_a_saddle_keeps_its_start():
    flat = np.full((41, 41), 100.0)
    start = np.array([[20.2, 19.7]])
    np.testing.assert_array_equal(saddle_points(flat + np.linspace(0, 1, 41)[None] ** 2, start, 6, 2.0), start)


@pytest.fixture(scope="module")
def full_size_view():
    """One 2448 x 2048 render of the paper rig's left camera (Mitsuba, 16 spp: Monte-Carlo noise on the edges),
    with the true corner pixels."""
    rig = get_rig("paper", 1.0)
    board = Checkerboard()
    poses = random_board_poses(rig, board_outline_mm(board), 1, seed=11)
    view = next(iter(render_board_views(rig, board, poses, spp=16, seed=11, progress=False, renderer="mitsuba")))
    return np.clip(np.rint(view.image_grey), 0, 255).astype(np.uint8), view.pixels


def test_the_search_pyramid_finds_the_board_on_the_smallest_copy_and_loses_no_accuracy(full_size_view,
                                                                                       monkeypatch):
    """The board is found on the 640 px copy (OpenCV's search costs ~4x less there than at 1280 px) and the
    full-size refinement gives the same corners as from the 1280 px copy: within 0.005 px of them, RMS error
    against the truth below 0.05 px. Where the smallest copy fails, the next size is searched."""
    import measurement.calibration.detection as detection

    image, truth = full_size_view
    seen = []
    real = detection.cv2.findChessboardCornersSB

    def spy(gray, *args, **kwargs):
        seen.append(max(gray.shape))
        return real(gray, *args, **kwargs)

    monkeypatch.setattr(detection.cv2, "findChessboardCornersSB", spy)
    pyramid = detect_checkerboard(image, (11, 8))
    assert seen[0] == 640 and 1280 not in seen
    monkeypatch.setattr(detection, "DETECT_SEARCH_SIDES_PX", ())
    only_1280 = detect_checkerboard(image, (11, 8))
    assert np.max(np.linalg.norm(pyramid - only_1280, axis=1)) < 0.005
    assert np.sqrt(np.mean(np.sum((pyramid - truth) ** 2, axis=1))) < 0.05

    def blind_below_1000(gray, *args, **kwargs):      # a board too small to be found on the 640 px copy
        seen.append(max(gray.shape))
        return (False, None) if max(gray.shape) < 1000 else real(gray, *args, **kwargs)

    monkeypatch.setattr(detection, "DETECT_SEARCH_SIDES_PX", (640, 1280))
    monkeypatch.setattr(detection.cv2, "findChessboardCornersSB", blind_below_1000)
    seen.clear()
    fallback = detect_checkerboard(image, (11, 8))
    assert 640 in seen and 1280 in seen
    assert np.max(np.linalg.norm(fallback - only_1280, axis=1)) < 1e-9


def test_downscaled_detection_is_as_accurate_as_the_full_size_search(full_size_view):
    """The 2448 x 2048 image exceeds DETECT_MAX_SIDE_PX, so detect_checkerboard searches a 1280 px copy and
    refines at full size (saddle points). Against the truth its RMS corner error must be within 0.05 px and no
    worse than the full-size search's (measured on six other renders: 0.018 vs 0.038 px mean, 4-5 x faster)."""
    image, truth = full_size_view
    assert max(image.shape) > DETECT_MAX_SIDE_PX
    down = detect_checkerboard(image, (11, 8))
    full = detect_checkerboard(image, (11, 8), max_side_px=None)
    rms = {k: float(np.sqrt(np.mean(np.sum((c - truth) ** 2, axis=1)))) for k, c in (("down", down), ("full", full))}
    assert rms["down"] < 0.05, rms
    assert rms["down"] <= rms["full"], rms
