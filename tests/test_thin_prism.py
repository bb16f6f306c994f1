"""Thin-prism distortion (OpenCV's s1-s4), the ``full`` lens model and calibration from partly seen boards.

Every projection is checked against OpenCV's own (``cv2.projectPoints`` with its 12- or 14-term distortion vector,
``cv2.undistortPoints``), an implementation independent of ``measurement.camera``; calibrations are checked against
corners that OpenCV projected from known cameras.
"""
from __future__ import annotations

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from measurement.calibration.formats import load_dice, save_dice
from measurement.calibration.io import CalibratedRig, load_calibration, load_opencv_yaml, save_rig
from measurement.calibration.stepwise import CalibrationError, calibrate_camera, calibrate_stereo, canonical_lens
from measurement.camera import ScheimpflugCamera
from measurement.stereo import projection_jacobian

SIZE = (1280, 1024)
PRISM = dict(s1=1.2e-2, s2=-2e-2, s3=-9e-3, s4=1.5e-2)


def _camera(**extra) -> ScheimpflugCamera:
    return ScheimpflugCamera(fx=2600.0, fy=2598.0, cx=652.0, cy=508.0, k1=-0.12, k2=0.3, p1=4e-4, p2=-3e-4,
                             width=SIZE[0], height=SIZE[1], **extra)


def _opencv(cam: ScheimpflugCamera) -> tuple[np.ndarray, np.ndarray]:
    """K and OpenCV's 14-term vector written out by hand from the documented order (k1 k2 p1 p2 k3 k4 k5 k6 s1 s2
    s3 s4 tau_x tau_y)."""
    K = np.array([[cam.fx, 0.0, cam.cx], [0.0, cam.fy, cam.cy], [0.0, 0.0, 1.0]])
    d = np.zeros(14)
    d[:5] = cam.k1, cam.k2, cam.p1, cam.p2, cam.k3
    d[8:12] = cam.s1, cam.s2, cam.s3, cam.s4
    d[12:] = np.deg2rad(cam.alpha_deg), np.deg2rad(cam.beta_deg)
    return K, d


def _points(n=400, seed=0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.column_stack([rng.uniform(-60, 60, n), rng.uniform(-50, 50, n), rng.uniform(380, 460, n)])


@pytest.mark.parametrize("tilt", [(0.0, 0.0), (1.5, -2.5)])
def test_thin_prism_projects_as_opencv_within_1e_9_px(tilt):
    """With s1-s4 (and k3, and OpenCV's tilt for the tilted case) the camera projects as cv2.projectPoints."""
    cam = _camera(k3=0.8, alpha_deg=tilt[0], beta_deg=tilt[1], tilt_model="opencv", **PRISM)
    X = _points()
    K, d = _opencv(cam)
    ref = cv2.projectPoints(X, np.zeros(3), np.zeros(3), K, d)[0].reshape(-1, 2)
    np.testing.assert_allclose(cam.project(X), ref, atol=1e-9)
    # and the prism matters: without it the same points move by pixels
    assert np.max(np.linalg.norm(_camera(k3=0.8, alpha_deg=tilt[0], beta_deg=tilt[1], tilt_model="opencv").project(X)
                                 - ref, axis=1)) > 0.5


def test_thin_prism_backprojection_reprojects_through_opencv_within_1e_9_px():
    """backproject inverts the distortion with the prism terms: its rays, projected by cv2.projectPoints (OpenCV's
    forward model, independent of ours), land on the pixels they came from."""
    cam = _camera(k3=0.8, **PRISM)
    pixels = np.stack(np.meshgrid(np.linspace(0, SIZE[0] - 1, 9), np.linspace(0, SIZE[1] - 1, 7)), -1).reshape(-1, 2)
    K, d = _opencv(cam)
    rays = np.column_stack([cam.backproject(pixels), np.ones(len(pixels))])
    assert np.all(np.isfinite(rays))
    back = cv2.projectPoints(rays, np.zeros(3), np.zeros(3), K, d)[0].reshape(-1, 2)
    np.testing.assert_allclose(back, pixels, atol=1e-9)


def test_projection_jacobian_with_thin_prism_equals_central_differences():
    """The analytic Jacobian with s1-s4 against central differences of project (step 1e-4 mm; the difference
    error is ~1e-9 px/mm here, so 1e-6 relative is a real check)."""
    cam = _camera(k3=0.8, alpha_deg=2.0, beta_deg=-1.0, **PRISM)
    X = _points(50, seed=1)
    J = projection_jacobian(cam, X)
    h = 1e-4
    for b in range(3):
        e = np.zeros(3)
        e[b] = h
        num = (cam.project(X + e) - cam.project(X - e)) / (2 * h)
        np.testing.assert_allclose(J[:, :, b], num, rtol=1e-6, atol=1e-6)


def test_plain_opencv_yaml_with_12_terms_loads_and_projects_as_opencv(tmp_path):
    """A cv2.stereoCalibrate-style file with CALIB_THIN_PRISM_MODEL's 12 terms loads (it used to be refused)."""
    K1 = np.array([[2600.0, 0.0, 652.0], [0.0, 2598.0, 508.0], [0.0, 0.0, 1.0]])
    D1 = np.array([[-0.12, 0.3, 4e-4, -3e-4, 0.8, 0.0, 0.0, 0.0, *PRISM.values()]])
    R, T = cv2.Rodrigues(np.array([0.0, 0.3, 0.0]))[0], np.array([[-150.0], [0.0], [30.0]])
    fs = cv2.FileStorage(str(tmp_path / "prism.yaml"), cv2.FILE_STORAGE_WRITE)
    for key, value in (("K1", K1), ("D1", D1), ("K2", K1), ("D2", D1[:, :5]), ("R", R), ("T", T)):
        fs.write(key, value)
    fs.write("image_width", SIZE[0])
    fs.write("image_height", SIZE[1])
    fs.release()
    rig = load_opencv_yaml(tmp_path / "prism.yaml")
    assert (rig.left.s1, rig.left.s2, rig.left.s3, rig.left.s4) == tuple(PRISM.values())
    assert not rig.right.has_thin_prism
    X = _points()
    np.testing.assert_allclose(rig.left.project(X), cv2.projectPoints(X, np.zeros(3), np.zeros(3), K1, D1)[0]
                               .reshape(-1, 2), atol=1e-9)


def test_thin_prism_survives_json_and_opencv_yaml_round_trips(tmp_path):
    cam = _camera(k3=0.8, skew=0.7, **PRISM)
    rig = CalibratedRig("pinhole", cam, _camera(**PRISM), Rotation.from_rotvec([0, 0.3, 0]).as_matrix(),
                        np.array([-150.0, 0.0, 30.0]))
    X = _points()
    for name in ("rig.json", "rig.yaml", "rig.xml"):
        save_rig(rig, tmp_path / name)
        back = load_calibration(tmp_path / name)
        assert back.left == rig.left and back.right == rig.right, name
        np.testing.assert_array_equal(back.left.project(X), cam.project(X))


def test_dice_writer_reports_what_dropping_the_thin_prism_costs(tmp_path):
    """DICe's model has no thin prism: the writer says so, and the px it reports equal the distance between the
    source camera and the camera read back from the file, measured here on a grid of our own."""
    cam = _camera(**PRISM)
    rig = CalibratedRig("pinhole", cam, _camera(), Rotation.from_rotvec([0, 0.3, 0]).as_matrix(),
                        np.array([-150.0, 0.0, 30.0]))
    report = save_dice(rig, tmp_path / "cal.xml")
    left = report.cameras[0]
    assert not left.exact and "the thin prism s1-s4" in " ".join(left.notes)
    back = load_dice(tmp_path / "cal.xml").left
    pixels = np.stack(np.meshgrid(np.linspace(0, SIZE[0] - 1, 41), np.linspace(0, SIZE[1] - 1, 33)), -1).reshape(-1, 2)
    rays = np.column_stack([cam.backproject(pixels), np.ones(len(pixels))])
    d = np.linalg.norm(back.project(rays) - pixels, axis=1)
    assert d.max() == pytest.approx(left.max_px, rel=0.05)
    assert left.max_px > 0.05            # the prism here moves the corners by ~1 px; the best DICe camera cannot


# ------------------------------------------------------------------------------------------------------------
def _board(nx=13, ny=10, square=6.0) -> np.ndarray:
    jj, ii = np.meshgrid(np.arange(nx), np.arange(ny))
    return np.column_stack([jj.ravel() * square, ii.ravel() * square, np.zeros(nx * ny)])


def _views(cam: ScheimpflugCamera, board: np.ndarray, n_views=14, seed=3, noise_px=0.02):
    """Corners of a board in ``n_views`` poses projected by OpenCV (the camera as its K and 14 terms) + noise."""
    rng = np.random.default_rng(seed)
    K, d = _opencv(cam)
    centre = board.mean(axis=0)
    pts = []
    for _ in range(n_views):
        rvec = Rotation.from_euler("xyz", rng.uniform(-25, 25, 3), degrees=True).as_rotvec()
        R = Rotation.from_rotvec(rvec).as_matrix()
        t = np.array([rng.uniform(-25, 25), rng.uniform(-20, 20), rng.uniform(380, 440)]) - R @ centre
        p = cv2.projectPoints(board, rvec, t, K, d)[0].reshape(-1, 2)
        pts.append(p + rng.normal(0, noise_px, p.shape))
    return np.array(pts)


def test_full_lens_recovers_a_true_thin_prism_within_4_sigma():
    """Corners OpenCV projected through a lens with s1-s4 and 0.02 px noise: ``lens="full"`` finds s1-s4 within 4
    of their own sigmas and leaves the noise (RMS < 1.2 x 0.02 sqrt(2) px). ``brown4`` absorbs most of the prism
    in the principal point and p1, p2 (measured: cx 53 px off, RMS 1.34 x the noise): it must leave more than
    1.25 x the noise and move cx by more than 10 px, which is why the term is offered."""
    truth = _camera(**PRISM)
    board = _board()
    pts = _views(truth, board)
    full = calibrate_camera(pts, board, SIZE, model="pinhole", lens="full")
    four = calibrate_camera(pts, board, SIZE, model="pinhole", lens="k1k2p1p2")
    assert full.lens == "full" and four.lens == "brown4"
    noise_rms = 0.02 * np.sqrt(2)
    assert full.rms_px < 1.2 * noise_rms
    assert four.rms_px > 1.25 * noise_rms
    assert abs(four.camera.cx - truth.cx) > 10.0
    for n, v in PRISM.items():
        assert abs(getattr(full.camera, n) - v) < 4 * full.sigma[n], (n, getattr(full.camera, n), full.sigma[n])
    assert abs(full.camera.skew) < 4 * full.sigma["skew"]


def test_calibration_with_missing_points_agrees_with_the_full_data_within_sigma():
    """A stereo pair where 25 % of the corners (random, per camera) are missing (NaN, as a partly seen ChArUco
    board gives): the calibration uses the rest and agrees with the truth within 4 sigma; RMS and sigma count only
    the points found."""
    board = _board()
    left = _camera()
    right = ScheimpflugCamera(fx=2590.0, fy=2589.0, cx=640.0, cy=515.0, k1=-0.1, k2=0.25, width=SIZE[0],
                              height=SIZE[1])
    R_rl = Rotation.from_euler("y", -20, degrees=True).as_matrix()
    T_rl = np.array([150.0, 0.0, 30.0])
    rng = np.random.default_rng(5)
    pts_l = _views(left, board, seed=7)
    # the right camera sees the same boards: project the left-frame corners through the stereo pose
    K_l, d_l = _opencv(left)
    K_r, d_r = _opencv(right)
    pts_r = []
    for v in range(len(pts_l)):
        ok, rvec, t = cv2.solvePnP(board, pts_l[v], K_l, d_l)
        X_left = board @ cv2.Rodrigues(rvec)[0].T + t.ravel()
        p = cv2.projectPoints(X_left @ R_rl.T + T_rl, np.zeros(3), np.zeros(3), K_r, d_r)[0].reshape(-1, 2)
        pts_r.append(p + rng.normal(0, 0.02, p.shape))
    pts_r = np.array(pts_r)
    for p in (pts_l, pts_r):
        p[rng.random(p.shape[:2]) < 0.25] = np.nan
    cal = calibrate_stereo(pts_l, pts_r, board, SIZE, model="pinhole")
    for side, truth in (("left", left), ("right", right)):
        c = getattr(cal, side)
        for n in ("fx", "fy", "cx", "cy", "k1", "k2"):
            assert abs(getattr(c.camera, n) - getattr(truth, n)) < 4 * c.sigma[n], (side, n)
        assert np.isfinite(c.rms_px) and c.rms_px < 1.2 * 0.02 * np.sqrt(2)
        assert np.all(np.isfinite(c.per_view_rms_px))
    assert np.linalg.norm(cal.T_right_from_left_mm - T_rl) < 4 * np.linalg.norm(cal.sigma_stereo["T_mm"])


def test_a_view_with_too_few_points_is_refused_by_number():
    board = _board()
    pts = _views(_camera(), board, n_views=4)
    pts[2, 5:] = np.nan
    with pytest.raises(CalibrationError, match=r"camera: view\(s\) 2 have fewer than 6 points found; drop them"):
        calibrate_camera(pts, board, SIZE)
    pts[1, 0, 0] = np.nan
    with pytest.raises(CalibrationError, match=r"a point has one NaN coordinate and one number"):
        calibrate_camera(pts, board, SIZE)


def test_lens_aliases_name_the_canonical_models():
    assert canonical_lens("k1k2p1p2") == "brown4" and canonical_lens("k1k2k3p1p2") == "brown5"
    assert canonical_lens("full") == "full"
    with pytest.raises(CalibrationError, match=r"unknown lens model 'k1k2'; choose one of brown4, brown5, full"):
        canonical_lens("k1k2")


def test_truth_side_projection_of_a_camera_with_k3_and_thin_prism_equals_the_instruments():
    """camera_to_sensor_spec carries k3 and s1-s4 to the renderer's description; the truth side's projection
    (scenes.optics.projection, its own implementation) then equals measurement.camera's within 1e-9 px, tilt included."""
    from scenes.optics.projection import project_points
    from workbench.experiments.calibration.views import camera_to_sensor_spec

    cam = _camera(k3=0.8, alpha_deg=0.6, beta_deg=-4.5, **PRISM)
    X = _points()
    truth = project_points(camera_to_sensor_spec(cam), np.eye(3), np.zeros(3), X)
    np.testing.assert_allclose(truth, cam.project(X), atol=1e-9)
    with pytest.raises(ValueError, match=r"the renderer has no skew term; this camera has skew = 0\.5 px"):
        camera_to_sensor_spec(_camera(skew=0.5))
