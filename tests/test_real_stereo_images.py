"""The instrument on REAL stereo images (OpenCV's 640 x 480 sample, tests/data/real/opencv_stereo), checked
against an independent implementation, OpenCV, on the same images and the same detected points.

Figures measured when these tests were written (OpenCV 5.0.0) are quoted beside each bound; every bound leaves
a margin over them. The board's square size is unknown (see the data README): 1 mm, so lengths are in squares.
"""
import glob
import json
import subprocess
import sys
import warnings
from pathlib import Path

import cv2
import numpy as np
import pytest
from scipy.optimize import least_squares
from scipy.spatial import Delaunay
from scipy.spatial.transform import Rotation

from measurement.calibration.detection import board_points_mm, refine_corners_saddle
from measurement.calibration.formats import load_any_calibration
from measurement.calibration.images import detect_pairs
from measurement.calibration.io import load_calibration
from measurement.calibration.stepwise import calibrate_camera, calibrate_stereo

DATA = Path(__file__).parent / "data" / "real" / "opencv_stereo"
PATTERN = (9, 6)
SIZE = (640, 480)
INTRINSICS = ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2")
#: cornerSubPix half-window: a 15 x 15 px window, inside the smallest square of these images (~21 px). OpenCV's
#: stereo_calib sample uses 11 (23 x 23 px): on the far, foreshortened rows that window reaches the next corner or
#: the board's edge and pulls corners by up to 7.7 px (left02), so it is no reference there.
SUBPIX_HALF_WINDOW = 7
_EDGE = np.zeros((PATTERN[1], PATTERN[0]), bool)
_EDGE[[0, -1], :] = True
_EDGE[:, [0, -1]] = True
EDGE = _EDGE.ravel()       # the outer ring of corners (next to the board's margin)


def _files(side):
    return sorted(glob.glob(str(DATA / f"{side}*.jpg")))


def _opencv_corners(path, ours):
    """OpenCV's classic detector + cornerSubPix, put in our corner order (it may start from either end)."""
    grey = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    found, corners = cv2.findChessboardCorners(grey, PATTERN, cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE)
    assert found, path
    criteria = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 100, 1e-4)
    w = SUBPIX_HALF_WINDOW
    corners = cv2.cornerSubPix(grey, corners, (w, w), (-1, -1), criteria).reshape(-1, 2).astype(float)
    if np.linalg.norm(corners - ours, axis=1).mean() > np.linalg.norm(corners[::-1] - ours, axis=1).mean():
        corners = corners[::-1].copy()
    return corners


@pytest.fixture(scope="module")
def pairs():
    left, right = _files("left"), _files("right")
    assert len(left) == len(right) == 13
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        p = detect_pairs(left, right, pattern_size=PATTERN, progress=False)
    # No pair dropped ("board not found"), no corner-order warning (10 x 7 squares are orderable).
    assert not [w for w in caught if "board" in str(w.message)], [str(w.message) for w in caught]
    return p


@pytest.fixture(scope="module")
def board():
    return board_points_mm(PATTERN, 1.0)


@pytest.fixture(scope="module")
def opencv_stereo(pairs, board):
    """OpenCV's calibration of the same points: calibrateCamera per camera (k1 k2 p1 p2, CALIB_FIX_K3), then
    stereoCalibrate refining every intrinsic with the stereo pose (as this project's joint step)."""
    obj = [board.astype(np.float32)] * len(pairs.points_left)
    img_l = [p.astype(np.float32).reshape(-1, 1, 2) for p in pairs.points_left]
    img_r = [p.astype(np.float32).reshape(-1, 1, 2) for p in pairs.points_right]
    _, K1, D1, _, _ = cv2.calibrateCamera(obj, img_l, SIZE, None, None, flags=cv2.CALIB_FIX_K3)
    _, K2, D2, _, _ = cv2.calibrateCamera(obj, img_r, SIZE, None, None, flags=cv2.CALIB_FIX_K3)
    criteria = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 200, 1e-12)
    rms, K1, D1, K2, D2, R, T, *_ = cv2.stereoCalibrate(
        obj, img_l, img_r, K1, D1, K2, D2, SIZE, flags=cv2.CALIB_USE_INTRINSIC_GUESS | cv2.CALIB_FIX_K3,
        criteria=criteria)
    def values(K, D):
        d = D.ravel()
        return dict(fx=K[0, 0], fy=K[1, 1], cx=K[0, 2], cy=K[1, 2], k1=d[0], k2=d[1], p1=d[2], p2=d[3], k3=d[4])
    return {"left": values(K1, D1), "right": values(K2, D2), "R": R, "T": T.ravel(), "rms": rms}


@pytest.fixture(scope="module")
def ours(pairs, board):
    # The points as OpenCV got them (float32; findChessboardCornersSB's output is float32 anyway).
    pl, pr = (p.astype(np.float32).astype(float) for p in (pairs.points_left, pairs.points_right))
    return {m: calibrate_stereo(pl, pr, board, pairs.image_size, model=m) for m in ("pinhole", "rmm")}


def _stereo_rms(cal):
    """OpenCV's stereoCalibrate RMS: over both cameras' corners, sqrt(mean |residual|^2)."""
    return float(np.sqrt((cal.rms_px["left"] ** 2 + cal.rms_px["right"] ** 2) / 2))


# --------------------------------------------------------------------------------------------------------------
def test_every_pair_is_kept_and_its_corners_are_where_opencv_finds_them(pairs):
    """All 13 pairs are kept (OpenCV's classic detector also finds every board). Against OpenCV's
    findChessboardCorners + cornerSubPix on the same JPEGs: mean distance 0.19 px over all 1404 corners; 0.125 px
    mean, 0.48 px max over the interior ones. The outer ring is worse (up to 1.6 px: see the next test), and two
    sub-pixel estimators on these blurred 640 x 480 JPEGs do not agree to 0.1 px even inside the board."""
    assert pairs.dropped == [] and len(pairs.left_files) == 13 and pairs.image_size == SIZE
    assert [Path(f).name for f in pairs.right_files] == [Path(f).name.replace("left", "right") for f in pairs.left_files]
    dist = []
    for files, points in ((pairs.left_files, pairs.points_left), (pairs.right_files, pairs.points_right)):
        for f, p in zip(files, points):
            dist.append(np.linalg.norm(_opencv_corners(f, p) - p, axis=1))
    dist = np.array(dist)                                   # (26 images, 54 corners)
    assert dist.mean() < 0.25, dist.mean()
    assert dist[:, ~EDGE].mean() < 0.16 and dist[:, ~EDGE].max() < 0.7, (dist[:, ~EDGE].mean(), dist[:, ~EDGE].max())


def test_saddle_refinement_moves_the_outer_corners_to_where_cornersubpix_puts_them(pairs):
    """findChessboardCornersSB puts some outer-ring corners of these blurred images 1.4-1.6 px from where
    cornerSubPix finds them; the saddle fit (--refine-corners) lands within 0.42 px of cornerSubPix on the four
    worst images (it used to refuse any move over 1 px and kept the SB position there; on all 26 images the fix
    lowers OpenCV's calibration RMS on the refined corners from 0.23 to 0.16 px)."""
    worst = ("left02.jpg", "left13.jpg", "right02.jpg", "right13.jpg")
    before, after = [], []
    for files, points in ((pairs.left_files, pairs.points_left), (pairs.right_files, pairs.points_right)):
        for f, p in zip(files, points):
            if Path(f).name not in worst:
                continue
            reference = _opencv_corners(f, p)
            refined = refine_corners_saddle(cv2.imread(f, cv2.IMREAD_GRAYSCALE), p, PATTERN)
            before.append(np.linalg.norm(p - reference, axis=1))
            after.append(np.linalg.norm(refined - reference, axis=1))
    before, after = np.array(before), np.array(after)
    assert len(before) == 4
    assert before.max() > 1.3                               # the SB outliers are there (1.64 px measured)
    assert after.max() < 0.7, after.max()                   # 0.42 px measured
    assert after.mean() < 0.8 * before.mean(), (after.mean(), before.mean())     # 0.10 vs 0.19 px


@pytest.mark.parametrize("side", ["left", "right"])
def test_single_camera_pinhole_and_its_sigma_match_opencv(pairs, board, side):
    """calibrate_camera (pinhole) vs cv2.calibrateCameraExtended (CALIB_FIX_K3) on the same points: the same
    least-squares minimum (parameters within 1e-3 sigma; measured < 1e-5 sigma) and the same standard
    uncertainties (OpenCV's stdDeviationsIntrinsics; measured to 1e-4 relative)."""
    pts = getattr(pairs, f"points_{side}").astype(np.float32)
    cal = calibrate_camera(pts.astype(float), board, SIZE, model="pinhole", name=side)
    rms, K, D, _, _, sd, _, _ = cv2.calibrateCameraExtended([board.astype(np.float32)] * len(pts),
                                                            [p.reshape(-1, 1, 2) for p in pts], SIZE, None, None,
                                                            flags=cv2.CALIB_FIX_K3)
    d, sd = D.ravel(), sd.ravel()
    ref = dict(fx=K[0, 0], fy=K[1, 1], cx=K[0, 2], cy=K[1, 2], k1=d[0], k2=d[1], p1=d[2], p2=d[3])
    for i, n in enumerate(INTRINSICS):
        ours = getattr(cal.camera, n)
        assert abs(ours - ref[n]) < 1e-3 * sd[i], (n, ours, ref[n], sd[i])
        assert cal.sigma[n] == pytest.approx(sd[i], rel=0.01), n
    assert cal.rms_px == pytest.approx(rms, rel=1e-6)      # 0.2351 px both cameras


def test_stereo_pinhole_matches_opencv_stereocalibrate(ours, opencv_stereo):
    """calibrate_stereo (pinhole, joint) vs cv2.stereoCalibrate on the same points. Measured: every intrinsic
    within 3e-4 px (< 1e-3 of our sigma: fx 532.84 +- 0.37, 535.38 +- 0.39; cx 342.49 +- 0.54, 325.85 +- 0.58;
    cy 234.28 +- 0.54, 249.63 +- 0.53; k1 -0.3051, -0.2931; k2 0.139, 0.102), |T| 3.3141 squares within 4e-8,
    R within 1e-6 deg, RMS 0.2551 px within 1e-10 relative. Bounds: 0.01 sigma, 1e-5, 1e-4 deg, 1e-5."""
    cal = ours["pinhole"]
    for side in ("left", "right"):
        c = getattr(cal, side)
        assert c.camera.alpha_deg == 0 and c.camera.beta_deg == 0
        for n in INTRINSICS:
            assert c.sigma[n] > 0, (side, n)
            assert abs(getattr(c.camera, n) - opencv_stereo[side][n]) < 0.01 * c.sigma[n], (side, n)
        assert opencv_stereo[side]["k3"] == 0
    T, T_cv = cal.T_right_from_left_mm, opencv_stereo["T"]
    assert np.linalg.norm(T) == pytest.approx(np.linalg.norm(T_cv), rel=1e-5)
    assert np.all(np.abs(T - T_cv) < 0.01 * np.asarray(cal.sigma_stereo["T_mm"]))
    angle = np.degrees(np.linalg.norm(Rotation.from_matrix(cal.R_right_from_left @ opencv_stereo["R"].T).as_rotvec()))
    assert angle < 1e-4
    assert _stereo_rms(cal) == pytest.approx(opencv_stereo["rms"], rel=1e-5)
    assert 0.2 < opencv_stereo["rms"] < 0.3                 # corners consistently ordered in both cameras


def _best_rotation_agreement(pinhole_cam, rmm_cam, pixels):
    """Rays through ``pixels`` by the pinhole calibration, projected by the rmm one after the camera-frame
    rotation that fits best: (rotation, |residual| px per pixel)."""
    rays = pinhole_cam.rays(pixels)
    res = least_squares(lambda r: (rmm_cam.project(rays @ Rotation.from_rotvec(r).as_matrix().T) - pixels).ravel(),
                        np.zeros(3))
    return Rotation.from_rotvec(res.x).as_matrix(), np.linalg.norm(res.fun.reshape(-1, 2), axis=1)


def test_rmm_on_untilted_cameras_describes_the_same_cameras_as_pinhole(pairs, ours, opencv_stereo):
    """The rmm model on these (nominally untilted) cameras. Its tilt is NOT zero within its sigma: measured
    left (alpha, beta) = (-0.75 +- 0.29, 2.26 +- 0.71) deg, right (-2.04 +- 0.38, -1.40 +- 0.39) deg, with the
    principal point moved by 8-22 px (sigma 3-7 px) and p1, p2 ten times larger: a tilt with a principal-point
    shift is nearly a rotation of the camera frame, which the board poses and the stereo pose absorb. What the
    data do identify:

    - reprojection: rmm (nested: alpha = beta = 0 is pinhole) is no worse, and its two extra parameters per
      camera explain < 5 % of the pinhole RMS (0.2508 vs 0.2551 px measured);
    - projection: over the part of the image the boards covered (46 %), the rmm camera, after the best frame
      rotation (2.5, 2.8 deg measured), projects the pinhole camera's rays within 0.4 px (0.18, 0.29 px max,
      0.07, 0.08 px RMS measured; outside the data, at the image corners, the two differ by up to 14 px);
    - the stereo pose: those two rotations carry the pinhole R, T into rmm's (0.04 deg on T, 0.09 deg on R
      measured), and |T| agrees with OpenCV's (0.03 % measured).
    """
    pin, rmm = ours["pinhole"], ours["rmm"]
    assert _stereo_rms(rmm) <= _stereo_rms(pin) + 1e-6
    assert _stereo_rms(rmm) > 0.95 * _stereo_rms(pin)
    Q = {}
    for side in ("left", "right"):
        cam_p, c_rmm = getattr(pin, side).camera, getattr(rmm, side)
        assert max(abs(c_rmm.camera.alpha_deg), abs(c_rmm.camera.beta_deg)) < 3.0
        assert c_rmm.sigma["alpha_deg"] > 0 and c_rmm.sigma["beta_deg"] > 0
        corners = getattr(pairs, f"points_{side}").reshape(-1, 2)
        grid = np.stack(np.meshgrid(np.arange(0, SIZE[0], 4.0), np.arange(0, SIZE[1], 4.0)), -1).reshape(-1, 2)
        covered = grid[Delaunay(corners).find_simplex(grid) >= 0]
        assert 0.3 < len(covered) / len(grid) < 0.7
        Q[side], err = _best_rotation_agreement(cam_p, c_rmm.camera, covered)
        assert err.max() < 0.4 and np.sqrt(np.mean(err ** 2)) < 0.15, (side, err.max())
    T_p, T_r = pin.T_right_from_left_mm, rmm.T_right_from_left_mm
    carried = Q["right"] @ T_p
    assert np.degrees(np.arccos(carried @ T_r / np.linalg.norm(carried) / np.linalg.norm(T_r))) < 0.2
    R_carried = Q["right"] @ pin.R_right_from_left @ Q["left"].T
    assert np.degrees(np.linalg.norm(Rotation.from_matrix(R_carried @ rmm.R_right_from_left.T).as_rotvec())) < 0.3
    assert np.linalg.norm(T_r) == pytest.approx(np.linalg.norm(opencv_stereo["T"]), rel=3e-3)


def _project_rig(rig, X):
    return rig.left.project(X), rig.right.project(X @ np.asarray(rig.R_right_from_left).T + rig.T_right_from_left_mm)


def test_cli_calibrates_the_real_pairs_and_dice_round_trip_is_exact(tmp_path, opencv_stereo):
    """``workbench calibrate`` on the JPEGs (pinhole, --square-mm 1) exits 0 and writes a calibration that
    load_calibration reads and that matches OpenCV's stereoCalibrate of the same corners (0.01 of its sigma, |T|
    to 1e-5); converting it to DICe's cal.xml and back with ``workbench calibration convert`` reprojects within
    1e-6 px (a pinhole rig: DICe's OpenCV model holds it exactly; 17 significant digits are written)."""
    out = tmp_path / "calib.json"
    run = lambda *args: subprocess.run([sys.executable, "-m", "workbench.cli", *map(str, args)],  # noqa: E731
                                       capture_output=True, text=True, timeout=300)
    r = run("calibrate", "--left", DATA / "left*.jpg", "--right", DATA / "right*.jpg", "--pattern", "9x6",
            "--square-mm", "1", "--model", "pinhole", "--out", out)
    assert r.returncode == 0, r.stderr[-2000:]
    assert "from 13 stereo views (0 images dropped)" in r.stdout
    doc = json.loads(out.read_text())
    rig = load_calibration(out)
    assert rig.model == "pinhole" and (rig.left.width, rig.left.height) == SIZE
    for side in ("left", "right"):
        cam, sigma = getattr(rig, side), doc[side]["sigma"]
        for n in INTRINSICS:
            assert abs(getattr(cam, n) - opencv_stereo[side][n]) < 0.01 * sigma[n], (side, n)
    assert np.linalg.norm(rig.T_right_from_left_mm) == pytest.approx(np.linalg.norm(opencv_stereo["T"]), rel=1e-5)

    xml, back = tmp_path / "cal.xml", tmp_path / "back.json"
    r = run("calibration", "convert", out, xml, "--to", "dice")
    assert r.returncode == 0, r.stderr[-2000:]
    assert "DICe_xml_camera_system_file" in xml.read_text()
    r = run("calibration", "convert", xml, back)
    assert r.returncode == 0, r.stderr[-2000:]
    # Points over the whole field of view of the left camera, 5-30 squares away, seen by both.
    u, v = np.meshgrid(np.linspace(0, SIZE[0] - 1, 15), np.linspace(0, SIZE[1] - 1, 11))
    X = rig.left.rays(np.column_stack([u.ravel(), v.ravel()]))
    X = X * np.linspace(5, 30, len(X))[:, None] / X[:, 2:]
    ref_l, ref_r = _project_rig(rig, X)
    assert np.isfinite(ref_l).all() and np.isfinite(ref_r).all()
    for converted in (load_any_calibration(xml), load_any_calibration(back)):
        assert converted.model == "pinhole"
        got_l, got_r = _project_rig(converted, X)
        assert np.abs(got_l - ref_l).max() < 1e-6 and np.abs(got_r - ref_r).max() < 1e-6


@pytest.mark.parametrize("model", ["pinhole", "rmm"])
def test_every_real_board_corner_is_triangulated(pairs, ours, model):
    """All 702 corners of the 13 real pairs (both cameras detected every one) are triangulated with the pair's own
    calibration: none dropped as 'diverged' (the issue's 190 of 702 before the refinement's fix), and each
    reprojects within 3 px (the calibration's RMS is 0.25 px; the worst corners of these blurred JPEGs ~1.6 px)."""
    from measurement.stereo import triangulate

    cal = ours[model]
    pl, pr = pairs.points_left.reshape(-1, 2), pairs.points_right.reshape(-1, 2)
    tri = triangulate(cal.left.camera, cal.right.camera, cal.R_right_from_left, cal.T_right_from_left_mm, pl, pr)
    assert len(pl) == 702
    assert tri.valid.all(), f"{(~tri.valid).sum()} of {len(pl)} corners dropped"
    assert np.nanmax(tri.reprojection_error_px) < 3.0
