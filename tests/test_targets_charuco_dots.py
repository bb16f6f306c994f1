"""ChArUco boards and dot grids: the printed truth (``scenes.surfaces.checkerboard``), detection (``measurement.calibration.
targets``) on rendered views, and stereo calibrations from them scored against the true rig.

Renders: the paper rig at a quarter of its resolution (614 x 514 px), 16 spp, noise-free 8-bit-range floats.
Boards: a 10 x 7-square ChArUco board of 6 mm squares with 4.5 mm DICT_4X4_50 markers (60 x 42 mm, the paper
board's footprint; squares ~43 px, marker cells ~5 px) and an 11 x 8 dot grid of 2.5 mm dots at 5 mm pitch
(dots ~18 px across). The rendered dots are 64-gons (``RENDER_SIDES``, half the render time of the default
352): any even polygon keeps its centroid on the true centre, its edge is within r (1 - cos(pi / 64)) = 1.5 um
(0.01 px here) of the circle, and its imaged centroid differs from the circle's by ~1e-3 of the eccentricity
(second moments), i.e. ~2e-5 px. The truth of every image point is its true 3-D point projected by the *truth side's*
camera (:func:`scenes.optics.projection.project_points`), independent of ``measurement.camera``.

Tolerances
----------
* Order / identity: neighbouring truth points are >= 20 px apart on these views (asserted), so a largest error
  below ``ORDER_TOL_PX`` = 0.5 px proves that every detected point is the right one, in the canonical order.
* ChArUco accuracy: OpenCV's CharucoDetector refines each corner with ``cornerSubPix``; on these renders it is
  off by 0.08-0.09 px RMS, single corners up to ~0.3 px on oblique views: like ``findChessboardCornersSB`` a
  pose-dependent bias (not Monte-Carlo noise), about twice the checkerboard detector's. ``detect_charuco`` then
  refines every corner to its saddle point inside the white margin left by the markers: 0.029 px RMS measured
  (max 0.073 px). ``CHARUCO_RMS_PX`` = 0.05 px leaves ~1.7x room over that, and the refinement must at least
  halve OpenCV's own error on the same views.
* Dot accuracy: the blob centroid is off by ~0.027 px RMS (max ~0.08 px) from the projected true centre. Part
  of it is the perspective eccentricity of the target (the image of a circle's centre is not the centroid of
  the imaged ellipse), computed here exactly from the projected dot outlines and reported (~0.017 px RMS, up
  to ~0.025 px on these views); the rest is the detector's (thresholded regions, ~0.022 px RMS from the
  imaged centroids). ``DOT_RMS_PX`` = 0.05 px is ~2x the measured total.
* Calibration: scored as the rendered-checkerboard protocol is (tests/test_reproduce_calibration.py, same
  scale, same number of calibration views): 3D error after one rigid alignment <= 1/scale um, projection
  agreement <= 0.05 px, and the baseline length within 0.5 mm (tests/test_calibration.py). The reprojection
  RMS is bounded by the *measured* detection error: the true rig is one candidate of the fit and leaves
  exactly the detection errors (the true poses), so a converged fit leaves no more. Focal lengths,
  principal points and tilts are printed with their sigma but not asserted one by one: planar targets do not
  separate tilt from principal point (DESIGN.md §3), and with detector bias (not noise) their errors exceed
  4 sigma for checkerboards too (measured at this scale: cx 78 px off, 37 sigma).
"""
import cv2
import numpy as np
import pytest

from measurement.calibration.stepwise import calibrate_stereo
from measurement.calibration.targets import (CharucoSpec, DotGridSpec, charuco_points_mm, detect_charuco,
                                             detect_dot_grid, dot_grid_points_mm)
from scenes.surfaces.charuco import CharucoBoard
from scenes.surfaces.dot_grid import DotGrid
from scenes.optics.projection import project_points
from workbench.experiments.calibration.run import _as_rig, score_against_truth
from workbench.experiments.calibration.views import board_outline_mm, render_board_views, sensor_spec_for
from workbench.poses import random_board_poses

SCALE = 0.25
ORDER_TOL_PX = 0.5
CHARUCO_RMS_PX = 0.05
DOT_RMS_PX = 0.05
CAL_VIEWS = 14                 # as tests/test_reproduce_calibration.py
VAL_VIEWS = 4
TILT_GUESS = {"left": (0.0, -4.0), "right": (0.0, 4.0)}

CHARUCO = dict(squares=(10, 7), square_mm=6.0, marker_mm=4.5, dictionary="DICT_4X4_50")
DOTS = dict(pattern_size=(11, 8), pitch_mm=5.0, diameter_mm=2.5)
RENDER_SIDES = 64


def _rms(e):
    return float(np.sqrt(np.mean(np.asarray(e) ** 2)))


def _truth_pixels(rig, view):
    """The true points of a rendered view projected by the truth side's camera, (N, 2) px."""
    return project_points(sensor_spec_for(rig, view.camera), np.eye(3), np.zeros(3), view.points_cam_mm)


def _min_spacing_px(pixels, pattern):
    grid = pixels.reshape(pattern[1], pattern[0], 2)
    return float(min(np.linalg.norm(np.diff(grid, axis=1), axis=-1).min(),
                     np.linalg.norm(np.diff(grid, axis=0), axis=-1).min()))


def _render(rig, board, n_views, seed):
    """CAL_VIEWS + VAL_VIEWS poses (validation poses are not rendered) and the rendered calibration views."""
    poses = random_board_poses(rig, board_outline_mm(board), n_views + VAL_VIEWS, seed=seed)
    views = list(render_board_views(rig, board, poses[:n_views], spp=16, seed=seed, progress=False))
    return poses, views


@pytest.fixture(scope="module")
def charuco(paper_rig_quarter):
    board, spec = CharucoBoard(**CHARUCO), CharucoSpec(**CHARUCO)
    poses, views = _render(paper_rig_quarter, board, CAL_VIEWS, seed=11)
    return board, spec, poses, views, [detect_charuco(v.image_grey, spec) for v in views]


@pytest.fixture(scope="module")
def dots(paper_rig_quarter):
    board, spec = DotGrid(**DOTS, polygon_sides=RENDER_SIDES), DotGridSpec(**DOTS)
    poses, views = _render(paper_rig_quarter, board, CAL_VIEWS, seed=12)
    return board, spec, poses, views, [detect_dot_grid(v.image_grey, spec) for v in views]


# ------------------------------------------------------------------------------------------------------------
# Truth side: the printed patterns
@pytest.mark.parametrize("squares, square_mm, marker_mm, dictionary", [
    ((10, 7), 6.0, 4.5, "DICT_4X4_50"), ((9, 6), 5.0, 3.5, "DICT_5X5_100"), ((5, 8), 4.0, 3.0, "DICT_6X6_50")])
def test_charuco_print_is_opencvs_board(squares, square_mm, marker_mm, dictionary):
    """The truth side draws the board itself (layout, ids, marker placement); OpenCV's own generator, on the
    same texel grid, must give the same picture, pixel for pixel."""
    board = CharucoBoard(squares=squares, square_mm=square_mm, marker_mm=marker_mm, dictionary=dictionary,
                         margin_squares=0)
    assert board.markers_on_texels
    n = board.texels_per_square
    mine = np.where(board.texture() < 0.5 * (board.dark + board.light), 0, 255)
    ref = cv2.aruco.CharucoBoard(squares, square_mm, marker_mm,
                                 cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, dictionary)))
    theirs = ref.generateImage((squares[0] * n, squares[1] * n), marginSize=0, borderBits=1)
    assert mine.shape == theirs.shape
    assert np.count_nonzero(mine != theirs) == 0
    # The board frame's truth points are OpenCV's ChArUco corners moved to the first inner corner, and the
    # instrument's points are the same numbers.
    spec = CharucoSpec(squares, square_mm, marker_mm, dictionary)
    np.testing.assert_allclose(board.true_corners_board_mm(),
                               np.asarray(ref.getChessboardCorners(), float) - [square_mm, square_mm, 0], atol=1e-12)
    np.testing.assert_allclose(charuco_points_mm(spec), board.true_corners_board_mm(), atol=1e-12)


def test_dot_grid_mesh_is_exact():
    """Mesh against closed forms: faces toward the camera side (-z), dark area = dots x the inscribed N-gon's
    area ``N r^2 sin(2 pi / N) / 2``, total area = the sheet, each dot's area centroid at its true centre."""
    grid = DotGrid(**DOTS)
    verts, faces, uv, texture = grid.board_mesh()
    a, b, c = verts[faces[:, 0]], verts[faces[:, 1]], verts[faces[:, 2]]
    nz = np.cross(b - a, c - a)[:, 2]
    assert np.all(nz < 0)
    area = -0.5 * nz
    dark = np.isclose(uv[faces[:, 0], 0], 0.25)
    n, r = grid.sides(), grid.radius_mm
    assert n % 8 == 0 and r * (1 - np.cos(np.pi / n)) <= 5e-5
    assert area[dark].sum() == pytest.approx(grid.pattern_size[0] * grid.pattern_size[1] * 0.5 * n * r * r
                                             * np.sin(2 * np.pi / n), rel=1e-12)
    x0, x1, y0, y1 = grid.extent_board_mm()
    assert area.sum() == pytest.approx((x1 - x0) * (y1 - y0), rel=1e-12)
    centroids = ((a + b + c) / 3)[dark] * area[dark, None]
    per_dot = centroids.reshape(-1, n, 3).sum(axis=1) / area[dark].reshape(-1, n).sum(axis=1)[:, None]
    np.testing.assert_allclose(per_dot, grid.true_corners_board_mm(), atol=1e-12)
    np.testing.assert_array_equal(texture, np.array([[grid.dark, grid.light]], dtype=np.float32))
    # Nominal print: dark at the centres, light at the cell corners (white-on-dark: the other way round).
    centres = grid.true_corners_board_mm()
    assert np.all(grid.is_dark(centres[:, 0], centres[:, 1]))
    assert not np.any(grid.is_dark(centres[:, 0] + 2.5, centres[:, 1] + 2.5))
    inverse = DotGrid(**DOTS, dark_dots=False)
    assert not np.any(inverse.is_dark(centres[:, 0], centres[:, 1]))


# ------------------------------------------------------------------------------------------------------------
# Detection on rendered views against the truth projection
def test_charuco_corners_on_rendered_views(paper_rig_quarter, charuco):
    board, spec, _, views, found = charuco
    nx, ny = spec.inner_corners
    errors = []
    print()
    for v, f in zip(views, found):
        truth = _truth_pixels(paper_rig_quarter, v)
        assert f.shape == (nx * ny, 2)
        assert _min_spacing_px(truth, (nx, ny)) > 40 * ORDER_TOL_PX
        ok = np.all(np.isfinite(f), axis=1)
        e = np.linalg.norm(f[ok] - truth[ok], axis=1)
        print(f"charuco view {v.view:2d} {v.camera:5s}: {ok.sum()}/{len(f)} corners, rms {_rms(e):.3f} px, "
              f"max {e.max():.3f} px")
        assert ok.sum() >= 0.9 * len(f), f"view {v.view} {v.camera}: only {ok.sum()} corners"
        assert e.max() < ORDER_TOL_PX, f"view {v.view} {v.camera}: a corner with the wrong id"
        errors.append(e)
    e = np.concatenate(errors)
    raw = np.concatenate([np.linalg.norm(r[np.isfinite(r).all(1)] - _truth_pixels(paper_rig_quarter, v)
                                         [np.isfinite(r).all(1)], axis=1)
                          for v in views for r in [detect_charuco(v.image_grey, spec, refine=False)]])
    print(f"charuco: {len(e)} corners in {len(views)} images, rms {_rms(e):.4f} px, max {e.max():.3f} px "
          f"(OpenCV's own corners: rms {_rms(raw):.4f} px, max {raw.max():.3f} px)")
    assert _rms(e) <= CHARUCO_RMS_PX
    assert _rms(e) <= 0.5 * _rms(raw)


def test_charuco_partial_view_gives_nan_rows_and_right_ids(paper_rig_quarter, charuco):
    """Cover the left 45 % of a view with the sheet's white: the corners there are NaN rows, the others keep
    their ids (same accuracy), and the covered ones are the ones the truth puts there."""
    _, spec, _, views, _ = charuco
    v = views[0]
    truth = _truth_pixels(paper_rig_quarter, v)
    image = v.image_grey.copy()
    cut = int(0.45 * image.shape[1])
    image[:, :cut] = float(np.percentile(v.image_grey, 99))
    f = detect_charuco(image, spec)
    ok = np.all(np.isfinite(f), axis=1)
    assert 0 < ok.sum() < len(f)
    assert np.all(np.isnan(f[~ok]))
    assert np.linalg.norm(f[ok] - truth[ok], axis=1).max() < ORDER_TOL_PX
    # Nothing is found under the cover (a corner needs its neighbouring markers, a square away).
    assert np.all(truth[ok, 0] > cut)


def test_charuco_half_turned_image_keeps_the_ids(paper_rig_quarter, charuco):
    """np.rot90(img, 2) maps pixel (u, v) to (W - 1 - u, H - 1 - v); the markers identify the corners, so row k
    is still corner k, now at the mapped truth."""
    _, spec, _, views, _ = charuco
    v = views[1]
    h, w = v.image_grey.shape
    truth = _truth_pixels(paper_rig_quarter, v)
    f = detect_charuco(np.rot90(v.image_grey, 2), spec)
    ok = np.all(np.isfinite(f), axis=1)
    assert ok.sum() >= 0.9 * len(f)
    turned = np.stack([w - 1 - truth[:, 0], h - 1 - truth[:, 1]], axis=1)
    assert np.linalg.norm(f[ok] - turned[ok], axis=1).max() < ORDER_TOL_PX


def _imaged_centroids(rig, view, board, points_per_dot=720):
    """Area centroids of the dots' images: each true circle's outline projected by the truth camera, as a
    polygon (shoelace), (N, 2) px. What a centroid detector would find without any detector error."""
    outline = board.dot_outlines_board_mm(points_per_dot)
    X = outline.reshape(-1, 3) @ view.R_cam_from_board.T + view.t_cam_from_board_mm
    p = project_points(sensor_spec_for(rig, view.camera), np.eye(3), np.zeros(3), X).reshape(len(outline), -1, 2)
    q = np.roll(p, -1, axis=1)
    cross = p[..., 0] * q[..., 1] - q[..., 0] * p[..., 1]
    area = 0.5 * cross.sum(axis=1)
    return np.stack([((p[..., 0] + q[..., 0]) * cross).sum(axis=1),
                     ((p[..., 1] + q[..., 1]) * cross).sum(axis=1)], axis=1) / (6.0 * area[:, None])


def test_dot_centres_on_rendered_views_and_the_eccentricity(paper_rig_quarter, dots):
    """Every dot found, in the canonical order, within DOT_RMS_PX of the projected true centres; the
    eccentricity of the target (imaged centroid - projected centre) is computed and reported beside it."""
    board, spec, _, views, found = dots
    n = spec.n_points
    to_truth, to_centroid, eccentricity = [], [], []
    print()
    for v, f in zip(views, found):
        assert f is not None, f"view {v.view} {v.camera}: grid not found"
        assert f.shape == (n, 2) and np.all(np.isfinite(f))
        truth = _truth_pixels(paper_rig_quarter, v)
        assert _min_spacing_px(truth, spec.pattern_size) > 40 * ORDER_TOL_PX
        centroid = _imaged_centroids(paper_rig_quarter, v, board)
        e, ec, ecc = (np.linalg.norm(a - b, axis=1) for a, b in ((f, truth), (f, centroid), (centroid, truth)))
        print(f"dots view {v.view:2d} {v.camera:5s}: vs truth rms {_rms(e):.4f} max {e.max():.4f} px; vs imaged "
              f"centroid rms {_rms(ec):.4f} px; eccentricity rms {_rms(ecc):.4f} max {ecc.max():.4f} px")
        assert e.max() < ORDER_TOL_PX, f"view {v.view} {v.camera}: not in the canonical order"
        to_truth.append(e)
        to_centroid.append(ec)
        eccentricity.append(ecc)
    e, ec, ecc = (np.concatenate(a) for a in (to_truth, to_centroid, eccentricity))
    print(f"dots: {len(e)} centres in {len(views)} images: vs truth rms {_rms(e):.4f} px, max {e.max():.4f} px; "
          f"vs imaged centroid rms {_rms(ec):.4f} px, max {ec.max():.4f} px; eccentricity rms {_rms(ecc):.4f} px, "
          f"max {ecc.max():.4f} px")
    assert _rms(e) <= DOT_RMS_PX
    # The eccentricity is real, below its scale f r^2 / Z^2 (first order: f r^2 sin(theta) cos(theta) / Z^2 for a
    # tilt theta, at most half of it; ~0.035 px here with the nearest dot's Z), and the detector measures it:
    # its centroids are closer to the imaged centroids than to the projected true centres.
    f_px = max(paper_rig_quarter.left.fx, paper_rig_quarter.right.fy)
    z_min = min(v.points_cam_mm[:, 2].min() for v in views)
    scale_px = f_px * board.radius_mm ** 2 / z_min ** 2
    print(f"eccentricity scale f r^2 / Z_min^2 = {scale_px:.4f} px")
    assert 0.002 < _rms(ecc) and ecc.max() < scale_px
    assert _rms(ec) < _rms(e)


def test_dot_grid_half_turned_image_is_ordered_by_the_image(paper_rig_quarter, dots):
    """A symmetric grid has no orientation mark: point 0 is the top-left dot *as seen*. After a half turn that
    is the board's last dot, so the detections are the mapped truth in reverse order."""
    _, spec, _, views, _ = dots
    v = views[2]
    h, w = v.image_grey.shape
    truth = _truth_pixels(paper_rig_quarter, v)
    f = detect_dot_grid(np.rot90(v.image_grey, 2), spec)
    assert f is not None
    turned = np.stack([w - 1 - truth[:, 0], h - 1 - truth[:, 1]], axis=1)[::-1]
    assert np.linalg.norm(f - turned, axis=1).max() < ORDER_TOL_PX


def test_white_dots_on_a_dark_sheet(paper_rig_quarter):
    """``dark_dots=False`` on both sides: rendered light dots on a dark sheet are found, and a dark-dot spec
    finds nothing on them."""
    board = DotGrid(**DOTS, dark_dots=False, polygon_sides=RENDER_SIDES)
    poses = random_board_poses(paper_rig_quarter, board_outline_mm(board), 1, seed=5)
    for v in render_board_views(paper_rig_quarter, board, poses, spp=16, seed=5, progress=False):
        truth = _truth_pixels(paper_rig_quarter, v)
        f = detect_dot_grid(v.image_grey, DotGridSpec(**DOTS, dark_dots=False))
        assert f is not None, v.camera
        e = np.linalg.norm(f - truth, axis=1)
        print(f"\nwhite dots {v.camera}: rms {_rms(e):.4f} px, max {e.max():.4f} px")
        assert e.max() < ORDER_TOL_PX and _rms(e) <= DOT_RMS_PX
        assert detect_dot_grid(v.image_grey, DotGridSpec(**DOTS)) is None


def test_imperfect_charuco_print_is_detected_where_it_really_is(paper_rig_quarter):
    """A ChArUco print 1 % too large: its markers follow their squares (the patch mesh), and the detected
    corners are the true (scaled) ones, not the nominal ones (>= 0.3 mm, i.e. > 2 px, away at the far corner)."""
    board = CharucoBoard(**CHARUCO, print_scale_error=0.01)
    spec = CharucoSpec(**CHARUCO)
    assert np.abs(board.true_corners_board_mm() - board.corners_board_mm()).max() >= 0.3
    poses = random_board_poses(paper_rig_quarter, board_outline_mm(board), 1, seed=8)
    for v in render_board_views(paper_rig_quarter, board, poses, spp=16, seed=8, progress=False):
        truth = _truth_pixels(paper_rig_quarter, v)
        nominal = project_points(sensor_spec_for(paper_rig_quarter, v.camera), np.eye(3), np.zeros(3),
                                 board.corners_board_mm() @ v.R_cam_from_board.T + v.t_cam_from_board_mm)
        f = detect_charuco(v.image_grey, spec)
        ok = np.all(np.isfinite(f), axis=1)
        assert ok.sum() >= 0.9 * len(f)
        e = np.linalg.norm(f[ok] - truth[ok], axis=1)
        assert e.max() < ORDER_TOL_PX and _rms(e) <= CHARUCO_RMS_PX
        assert np.linalg.norm(f[ok] - nominal[ok], axis=1).max() > 2.0


def test_no_board_gives_nan_or_none():
    shape = (514, 614)
    noise = np.random.default_rng(7).uniform(0, 255, shape).astype(np.uint8)
    for image in (np.full(shape, 128.0), noise):
        assert np.all(np.isnan(detect_charuco(image, CharucoSpec(**CHARUCO))))
        assert detect_dot_grid(image, DotGridSpec(**DOTS)) is None


# ------------------------------------------------------------------------------------------------------------
# Calibration from rendered views, scored against the true rig
def _score_calibration(rig, board, poses, views, found, points_mm, label, *, complete_only=True):
    """Calibrate from the detections of the rendered views and score the result against the true rig.

    ``complete_only``: use only the stereo views in which every point is found in both images; otherwise all
    views, missing points as NaN rows (a view not found at all is left out).
    """
    n = len(points_mm)
    sides = ("left", "right")
    pts = {s: [np.full((n, 2), np.nan) if f is None else f for v, f in zip(views, found) if v.camera == s]
           for s in sides}
    truth = {s: [_truth_pixels(rig, v) for v in views if v.camera == s] for s in sides}
    keep = [k for k in range(len(pts["left"]))
            if all(np.isfinite(pts[s][k]).all() if complete_only else np.isfinite(pts[s][k]).any() for s in sides)]
    assert len(keep) >= CAL_VIEWS - 2, f"{label}: only {len(keep)} usable stereo views"
    pl, pr = (np.array([pts[s][k] for k in keep]) for s in sides)
    # The detection error of exactly these points, against the truth projection.
    det_err = np.concatenate([(np.array([pts[s][k] for k in keep]) - np.array([truth[s][k] for k in keep]))
                              .reshape(-1, 2) for s in sides])
    det_err = det_err[np.isfinite(det_err).all(axis=1)]
    det_rms = _rms(np.linalg.norm(det_err, axis=1))
    cal = calibrate_stereo(pl, pr, points_mm, (rig.left.width, rig.left.height), model="rmm",
                           tilt_guess_left_deg=TILT_GUESS["left"], tilt_guess_right_deg=TILT_GUESS["right"])
    R_l, t_l = rig.pose("left")
    val = np.array([(board.true_corners_board_mm() @ Rw.T + tw) @ R_l.T + t_l for Rw, tw in poses[CAL_VIEWS:]])
    score = score_against_truth(_as_rig(cal), rig, val)
    baseline_err = float(np.linalg.norm(cal.T_right_from_left_mm) - np.linalg.norm(rig.T_right_from_left_mm))
    counts = {s: int(np.isfinite(p).all(axis=-1).sum()) for s, p in zip(sides, (pl, pr))}
    pooled = float(np.sqrt(sum(counts[s] * cal.rms_px[s] ** 2 for s in sides) / sum(counts.values())))
    print(f"\n{label}: {len(keep)} views, {counts['left']} + {counts['right']} points, detection error {det_rms:.4f} "
          f"px RMS; reprojection left {cal.rms_px['left']:.4f} right {cal.rms_px['right']:.4f} px; 3D aligned "
          f"{score['rms_3d_aligned_um']:.2f} um (max {score['max_3d_aligned_um']:.2f}), projection "
          f"{score['projection_rms_px']:.4f} px, baseline {baseline_err:+.3f} mm, T error "
          f"{np.round(cal.T_right_from_left_mm - rig.T_right_from_left_mm, 3)} mm "
          f"(sigma {np.round(cal.sigma_stereo['T_mm'], 3)})")
    for side in sides:
        est, true, sigma = getattr(cal, side).camera, rig.camera(side), getattr(cal, side).sigma
        print(f"  {side:5s} " + ", ".join(f"{n} {getattr(est, n) - getattr(true, n):+.3f} ({sigma[n]:.3f})"
                                          for n in ("fx", "fy", "cx", "cy", "alpha_deg", "beta_deg")))
    assert score["valid"] == score["points"]
    assert pooled <= det_rms * (1 + 1e-6)
    assert score["rms_3d_aligned_um"] <= 1.0 / SCALE
    assert score["projection_rms_px"] <= 0.05
    assert abs(baseline_err) < 0.5
    return cal, score


def test_calibration_from_rendered_charuco_views(paper_rig_quarter, charuco):
    board, spec, poses, views, found = charuco
    _, score = _score_calibration(paper_rig_quarter, board, poses, views, found, charuco_points_mm(spec), "charuco")
    assert score["rms_3d_aligned_um"] <= 1.0 / SCALE          # (and the other bounds, inside _score_calibration)


def test_calibration_from_partly_seen_charuco_views(paper_rig_quarter, charuco):
    """The same views with one image of every stereo view a third covered (even views: the left third of the
    left image, odd views: the right third of the right image): the corners there are NaN rows (in one
    camera only), calibrate_stereo uses the rest, and the result meets the same bounds."""
    board, spec, poses, views, _ = charuco
    found = []
    for k, v in enumerate(views):
        image = v.image_grey
        if k % 2 == (v.view % 2):
            image = image.copy()
            third = image.shape[1] // 3
            cover = slice(0, third) if (k // 2) % 2 == 0 else slice(image.shape[1] - third, None)
            image[:, cover] = float(np.percentile(v.image_grey, 99))
        found.append(detect_charuco(image, spec))
    missing = sum(int(np.isnan(f).any(axis=1).sum()) for f in found)
    assert missing >= 100, missing
    _score_calibration(paper_rig_quarter, board, poses, views, found, charuco_points_mm(spec), "charuco, partly seen",
                       complete_only=False)


def test_calibration_from_rendered_dot_grid_views(paper_rig_quarter, dots):
    board, spec, poses, views, found = dots
    _, score = _score_calibration(paper_rig_quarter, board, poses, views, found, dot_grid_points_mm(spec),
                                  "dot grid")
    assert score["rms_3d_aligned_um"] <= 1.0 / SCALE          # (and the other bounds, inside _score_calibration)


# ------------------------------------------------------------------------------------------------------------
# Bad input
@pytest.mark.parametrize("kwargs, message", [
    (dict(CHARUCO, dictionary="DICT_9X9_7"), "dictionary must name one of OpenCV's predefined"),
    (dict(CHARUCO, dictionary=4), "dictionary must name"),
    (dict(CHARUCO, marker_mm=6.0), r"marker_mm must be smaller than square_mm \(6 mm\)"),
    (dict(CHARUCO, marker_mm=-1.0), "marker_mm must be a positive finite number"),
    (dict(CHARUCO, square_mm=float("nan")), "square_mm must be a positive finite number"),
    (dict(CHARUCO, squares=(12, 9)), "dictionary DICT_4X4_50 holds 50 markers, squares \\(12, 9\\) need 54"),
    (dict(CHARUCO, squares=(2, 7)), "squares must be \\(columns, rows\\), integers >= 3"),
])
def test_bad_charuco_spec(kwargs, message):
    with pytest.raises(ValueError, match=message):
        CharucoSpec(**kwargs)


@pytest.mark.parametrize("kwargs, message", [
    (dict(DOTS, diameter_mm=5.0), r"diameter_mm must be smaller than pitch_mm \(5 mm\)"),
    (dict(DOTS, pitch_mm=0), "pitch_mm must be a positive finite number"),
    (dict(DOTS, pattern_size=(1, 8)), "pattern_size must be \\(columns, rows\\), integers >= 2"),
    (dict(DOTS, pattern_size=(11.0, 8)), "pattern_size must be"),
    (dict(DOTS, dark_dots="yes"), "dark_dots must be True or False"),
])
def test_bad_dot_grid_spec(kwargs, message):
    with pytest.raises(ValueError, match=message):
        DotGridSpec(**kwargs)


@pytest.mark.parametrize("kwargs, message", [
    (dict(CHARUCO, dictionary="DICT_4X4"), "dictionary must name one of OpenCV's predefined"),
    (dict(CHARUCO, marker_mm=6.5), r"marker_mm must satisfy 0 < marker_mm < square_mm \(6 mm\)"),
    (dict(CHARUCO, squares=(12, 9)), "dictionary DICT_4X4_50 holds 50 markers"),
    (dict(CHARUCO, marker_mm="4"), "marker_mm must be a finite number"),
])
def test_bad_charuco_board(kwargs, message):
    with pytest.raises(ValueError, match=message):
        CharucoBoard(**kwargs)


@pytest.mark.parametrize("kwargs, message", [
    (dict(DOTS, diameter_mm=6.0), r"diameter_mm must satisfy 0 < diameter_mm < pitch_mm \(5 mm\)"),
    (dict(DOTS, pattern_size=(11, 1)), "pattern_size must be"),
    (dict(DOTS, polygon_sides=12), "polygon_sides must be None or a multiple of 8"),
    (dict(DOTS, margin_pitches=-1), "margin_pitches must be an integer >= 0"),
    (dict(DOTS, dark_dots=1), "dark_dots must be True or False"),
])
def test_bad_dot_grid_board(kwargs, message):
    with pytest.raises(ValueError, match=message):
        DotGrid(**kwargs)


def test_bad_detection_calls():
    image = np.zeros((60, 80))
    with pytest.raises(ValueError, match="spec must be a CharucoSpec, got DotGridSpec"):
        detect_charuco(image, DotGridSpec(**DOTS))
    with pytest.raises(ValueError, match="spec must be a DotGridSpec, got CharucoSpec"):
        detect_dot_grid(image, CharucoSpec(**CHARUCO))
    with pytest.raises(ValueError, match="min_area_px must be a positive finite number"):
        detect_dot_grid(image, DotGridSpec(**DOTS), min_area_px=0)
    with pytest.raises(ValueError, match="image has 2 channels"):
        detect_charuco(np.zeros((60, 80, 2)), CharucoSpec(**CHARUCO))
    with pytest.raises(ValueError, match="points_per_dot must be an integer >= 3"):
        DotGrid(**DOTS).dot_outlines_board_mm(2)


# ------------------------------------------------------------------------------------------------------------
# The command line: workbench calibrate --target charuco|dots on the rendered views written as image files
def _write_views(folder, views):
    folder.mkdir(parents=True, exist_ok=True)
    for v in views:
        cv2.imwrite(str(folder / f"{v.camera}_{v.view:03d}.png"),
                    np.clip(np.rint(v.image_grey), 0, 255).astype(np.uint8))
    return str(folder / "left_*.png"), str(folder / "right_*.png")


@pytest.mark.parametrize("kind", ["charuco", "dots"])
def test_cli_calibrate_with_charuco_and_dot_targets_scores_against_the_truth(tmp_path, paper_rig_quarter, charuco,
                                                                              dots, kind):
    """``workbench calibrate --target charuco|dots`` on the rendered views (8-bit PNGs): the calibration file it
    writes meets the rendered-checkerboard protocol's bounds against the true rig (3-D error after alignment
    <= 1 um / scale on validation boards, projection <= 0.05 px, baseline within 0.5 mm)."""
    from measurement.calibration.io import load_calibration
    from workbench.cli import main

    rig = paper_rig_quarter
    board, spec, poses, views, _ = charuco if kind == "charuco" else dots
    left, right = _write_views(tmp_path / kind, views)
    target = (["--target", "charuco", "--squares", "10x7", "--square-mm", "6", "--marker-mm", "4.5",
               "--dictionary", "DICT_4X4_50"] if kind == "charuco" else
              ["--target", "dots", "--pattern", "11x8", "--square-mm", "5", "--dot-mm", "2.5"])
    out = tmp_path / f"{kind}.json"
    assert main(["calibrate", "--left", left, "--right", right, *target, "--tilt-guess-deg", "0,-4",
                 "--out", str(out)]) == 0
    cal = load_calibration(out)
    R_l, t_l = rig.pose("left")
    val = np.array([(board.true_corners_board_mm() @ Rw.T + tw) @ R_l.T + t_l for Rw, tw in poses[CAL_VIEWS:]])
    score = score_against_truth(cal, rig, val)
    assert score["rms_3d_aligned_um"] <= 1.0 / SCALE
    assert score["projection_rms_px"] <= 0.05
    assert abs(np.linalg.norm(cal.T_right_from_left_mm) - np.linalg.norm(rig.T_right_from_left_mm)) < 0.5


def test_cli_target_options_are_checked_before_detection(tmp_path, capsys):
    from workbench.cli import main

    out = str(tmp_path / "c.json")
    assert main(["calibrate", "--left", "a*.png", "--right", "b*.png", "--target", "charuco", "--out", out]) == 2
    assert "--target charuco needs --squares COLSxROWS and --marker-mm" in capsys.readouterr().err
    assert main(["calibrate", "--left", "a*.png", "--right", "b*.png", "--dot-mm", "2", "--out", out]) == 2
    assert "--dot-mm and --white-dots describe a dot grid: add --target dots" in capsys.readouterr().err
    assert main(["calibrate", "--left", "a*.png", "--right", "b*.png", "--target", "dots", "--dot-mm", "2",
                 "--refine-corners", "--out", out]) == 2
    assert "--refine-corners refines checkerboard corners" in capsys.readouterr().err
