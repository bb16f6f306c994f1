"""Camera terms k3 and skew, the nearest-model conversion, and the DICe / VIC-3D / MatchID calibration files.

Every reference is independent of the code under test: ``cv2.projectPoints`` (OpenCV's 5- and 14-term models), the
projection formulas written out here (DICe's ``sensor_to_image`` as in its source, the skew as ``K[0][1]``), finite
differences for the Jacobian, and sample files from DICe's repository (``tests/data/calibration``, see its README)
with the numbers DICe itself gives for them. Tolerances are in the test names or docstrings.
"""
from __future__ import annotations

import dataclasses
import json
import math
import re
from pathlib import Path

import cv2
import numpy as np
import pytest

from measurement.calibration import formats
from measurement.calibration.formats import (DICE_MODEL, MATCHID_MODEL, VIC3D_MODEL, load_any_calibration,
                                             load_dice, load_matchid, load_vic3d, nearest_camera, save_calibration_as,
                                             save_dice, save_matchid, save_vic3d)
from measurement.calibration.io import (CalibratedRig, load_calibration, load_opencv_yaml, opencv_distortion_cost_px,
                                        save_rig)
from measurement.camera import ScheimpflugCamera
from labio.schema import FileFormatError
from measurement.stereo import projection_jacobian

DATA = Path(__file__).parent / "data" / "calibration"

#: A camera with every term on (k3 and skew included), no tilt.
FULL = ScheimpflugCamera(fx=4800.0, fy=4790.0, cx=1221.3, cy=1030.7, k1=-0.21, k2=0.35, p1=8e-4, p2=-6e-4, k3=-1.7,
                         skew=1.3, width=2448, height=2048)


def _R(rvec) -> np.ndarray:
    return cv2.Rodrigues(np.asarray(rvec, float))[0]


def _points(rng, n=400, z=(350.0, 450.0), half_angle=0.22) -> np.ndarray:
    """(n, 3) camera-frame points (mm) within ``half_angle`` (normalised radius) of the axis."""
    zz = rng.uniform(*z, n)
    return np.column_stack([rng.uniform(-half_angle, half_angle, n) * zz, rng.uniform(-half_angle, half_angle, n) * zz,
                            zz])


def _image_grid(cam: ScheimpflugCamera, n=31) -> np.ndarray:
    u, v = np.meshgrid(np.linspace(0, cam.width - 1, n), np.linspace(0, cam.height - 1, n))
    return np.column_stack([u.ravel(), v.ravel()])


def _paper_rig() -> CalibratedRig:
    from workbench.rigs import get_rig
    rig = get_rig("paper", 1.0)
    return CalibratedRig("rmm", rig.left, rig.right, rig.R_right_from_left, rig.T_right_from_left_mm)


def _rig(left, right, rvec=(0.01, 0.38, -0.02), T=(-140.0, 1.5, 28.0), model="pinhole") -> CalibratedRig:
    return CalibratedRig(model, left, right, _R(rvec), np.array(T, float))


def _distance_px(source: ScheimpflugCamera, other: ScheimpflugCamera, R_other_from_source=np.eye(3), n=101):
    """(mean, max) px between ``source`` and ``other`` seeing the same rays over an ``n x n`` grid of the image."""
    pixels = _image_grid(source, n)
    rays = np.column_stack([source.backproject(pixels), np.ones(len(pixels))])
    d = np.linalg.norm(other.project(rays @ np.asarray(R_other_from_source).T) - pixels, axis=1)
    return float(d.mean()), float(d.max())


# ============================================================================================================
# 1. k3 and skew in the camera
# ============================================================================================================
def test_projection_with_k3_equals_opencv_five_term_model_to_1e9_px(rng):
    cam = dataclasses.replace(FULL, skew=0.0)
    X = _points(rng)
    ref = cv2.projectPoints(X, np.zeros(3), np.zeros(3), cam.K, np.array([cam.k1, cam.k2, cam.p1, cam.p2, cam.k3]))
    assert np.max(np.abs(cam.project(X) - ref[0].reshape(-1, 2))) < 1e-9


def test_projection_with_k3_and_opencv_tilt_equals_opencv_fourteen_term_model_to_1e9_px(rng):
    cam = dataclasses.replace(FULL, skew=0.0, alpha_deg=1.2, beta_deg=-3.9, tilt_model="opencv")
    X = _points(rng)
    d = np.zeros(14)
    d[:5] = cam.k1, cam.k2, cam.p1, cam.p2, cam.k3
    d[12:] = np.deg2rad([cam.alpha_deg, cam.beta_deg])
    ref = cv2.projectPoints(X, np.zeros(3), np.zeros(3), cam.K, d)[0].reshape(-1, 2)
    assert np.max(np.abs(cam.project(X) - ref)) < 1e-9


def test_skew_is_the_k01_entry_of_K(rng):
    """u = fx x_t + skew y_t + cx: the skewed camera is the unskewed one plus skew (v - cy) / fy (to 1e-9 px)."""
    X = _points(rng)
    plain = dataclasses.replace(FULL, skew=0.0).project(X)
    skewed = FULL.project(X)
    expected_u = plain[:, 0] + FULL.skew * (plain[:, 1] - FULL.cy) / FULL.fy
    assert np.max(np.abs(skewed[:, 0] - expected_u)) < 1e-9
    assert np.max(np.abs(skewed[:, 1] - plain[:, 1])) < 1e-12
    assert FULL.K[0, 1] == FULL.skew


@pytest.mark.parametrize("tilt", [dict(), dict(alpha_deg=0.8, beta_deg=-4.2), dict(alpha_deg=1.1, beta_deg=3.0,
                                                                                    tilt_model="opencv")],
                         ids=["untilted", "rmm", "opencv"])
def test_backproject_then_project_is_the_identity_to_1e9_px(tilt):
    cam = dataclasses.replace(FULL, **tilt)
    pixels = _image_grid(cam)
    rays = np.column_stack([cam.backproject(pixels), np.ones(len(pixels))])
    assert np.max(np.abs(cam.project(rays) - pixels)) < 1e-9


@pytest.mark.parametrize("tilt", [dict(alpha_deg=0.8, beta_deg=-4.2), dict(alpha_deg=1.1, beta_deg=3.0,
                                                                          tilt_model="opencv")], ids=["rmm", "opencv"])
def test_projection_jacobian_matches_finite_differences_with_k3_skew_and_either_tilt_model(tilt, rng):
    """Central differences (h = 1e-4 mm) agree to 1e-6 relative; the former code used the RMM homography for every
    camera, which this fails for tilt_model="opencv" by ~1e-3 relative."""
    cam = dataclasses.replace(FULL, **tilt)
    X = _points(rng, n=50)
    J = projection_jacobian(cam, X)
    h = 1e-4
    for b in range(3):
        dX = np.zeros(3)
        dX[b] = h
        fd = (cam.project(X + dX) - cam.project(X - dX)) / (2 * h)
        assert np.max(np.abs(J[:, :, b] - fd)) <= 1e-6 * np.max(np.abs(fd)) + 1e-9


def test_scaling_keeps_k3_and_scales_the_skew_with_the_image(rng):
    """scaled(s) sees every ray at u' + 0.5 = s (u + 0.5) (to 1e-9 px), skew included."""
    X = _points(rng)
    small = FULL.scaled(0.5)
    assert small.k3 == FULL.k3 and small.skew == 0.5 * FULL.skew
    assert np.max(np.abs((small.project(X) + 0.5) - 0.5 * (FULL.project(X) + 0.5))) < 1e-9


def test_camera_dicts_hold_k3_and_skew_only_when_non_zero():
    plain = ScheimpflugCamera(fx=1000.0, fy=1000.0, cx=50.0, cy=40.0, width=100, height=80)
    assert set(plain.to_dict()) == {"fx", "fy", "cx", "cy", "alpha_deg", "beta_deg", "k1", "k2", "p1", "p2", "width",
                                    "height", "tilt_model"}
    assert ScheimpflugCamera.from_dict(FULL.to_dict()) == FULL
    assert FULL.to_dict()["k3"] == FULL.k3 and ScheimpflugCamera.from_dict({**plain.to_dict(), "skew_px": 2.0}).skew == 2


# ============================================================================================================
# 1b. this instrument's own files keep k3 and skew
# ============================================================================================================
@pytest.mark.parametrize("suffix", [".json", ".yaml", ".xml"])
def test_own_files_keep_k3_and_skew(tmp_path, rng, suffix):
    right = dataclasses.replace(FULL, cx=1250.0, k3=2.2, skew=-0.7)
    rig = _rig(FULL, right)
    save_rig(rig, tmp_path / f"rig{suffix}")
    back = load_calibration(tmp_path / f"rig{suffix}")
    X = _points(rng)
    for a, b in ((rig.left, back.left), (rig.right, back.right)):
        assert (b.k3, b.skew) == (a.k3, a.skew)
        assert np.max(np.abs(a.project(X) - b.project(X))) < 1e-9


def test_own_json_without_k3_or_skew_has_no_new_keys(tmp_path):
    plain = dataclasses.replace(FULL, k3=0.0, skew=0.0)
    save_rig(_rig(plain, plain), tmp_path / "rig.json")
    d = json.loads((tmp_path / "rig.json").read_text())
    assert "extra_intrinsics" not in d["left"] and "extra_intrinsics_convention" not in d
    save_rig(_rig(plain, plain), tmp_path / "rig.yaml")
    assert "_k3" not in (tmp_path / "rig.yaml").read_text() and "_skew" not in (tmp_path / "rig.yaml").read_text()


@pytest.mark.parametrize("edit, message", [
    (lambda d: d["left"]["extra_intrinsics"].update(k3=1e5), r"key 'left.extra_intrinsics.k3': must be in \(-10000, "),
    (lambda d: d["right"]["extra_intrinsics"].update(skew="2"), r"key 'right.extra_intrinsics.skew': must be a number"),
    (lambda d: d["left"]["extra_intrinsics"].update(k4=0.1), r"key 'left.extra_intrinsics': unknown key\(s\) 'k4'"),
])
def test_own_json_extra_terms_are_validated(tmp_path, edit, message):
    save_rig(_rig(FULL, dataclasses.replace(FULL, skew=0.4)), tmp_path / "rig.json")
    d = json.loads((tmp_path / "rig.json").read_text())
    edit(d)
    (tmp_path / "bad.json").write_text(json.dumps(d))
    with pytest.raises(FileFormatError, match=message):
        load_calibration(tmp_path / "bad.json")


def _plain_yaml(path, D1, D2, K=None):
    K = np.array([[2400.0, 0, 1210.5], [0, 2395.0, 1020.25], [0, 0, 1]]) if K is None else K
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    fs.write("image_width", 2448)
    fs.write("image_height", 2048)
    for key, value in (("K1", K), ("D1", D1), ("K2", K), ("D2", D2), ("R", _R([0.0, 0.38, 0.0])),
                       ("T", np.array([[-140.0], [1.0], [28.0]]))):
        fs.write(key, np.asarray(value, np.float64))
    fs.release()
    return K


def test_plain_opencv_yaml_with_k3_and_tau_loads_and_projects_as_opencv(tmp_path, rng):
    D1 = np.array([[-0.12, 0.08, 0.0011, -0.0007, 0.45]])
    D2 = np.zeros((1, 14))
    D2[0, [0, 1, 4, 12, 13]] = -0.1, 0.05, -0.3, 0.02, -0.05
    K = _plain_yaml(tmp_path / "p.yaml", D1, D2)
    rig = load_opencv_yaml(tmp_path / "p.yaml")
    assert rig.model == "opencv-tilt" and rig.right.tilt_model == "opencv"
    X = _points(rng)
    for cam, D in ((rig.left, D1), (rig.right, D2)):
        ref = cv2.projectPoints(X, np.zeros(3), np.zeros(3), K, D)[0].reshape(-1, 2)
        assert np.max(np.abs(cam.project(X) - ref)) < 1e-6


def test_plain_opencv_yaml_with_k4_is_refused_with_its_pixel_cost(tmp_path):
    D = np.zeros((1, 8))
    D[0, [0, 1, 4, 5]] = -0.1, 0.05, 0.3, 0.2
    K = _plain_yaml(tmp_path / "k4.yaml", D, D[:, :5])
    # the cost, computed here with OpenCV: the corner pixels' rays projected with and without k4
    corners = np.array([[[0.0, 0.0]], [[2447.0, 0.0]], [[0.0, 2047.0]], [[2447.0, 2047.0]]])
    rays = np.column_stack([cv2.undistortPoints(corners, K, D).reshape(-1, 2), np.ones(4)])
    kept = D.copy()
    kept[0, 5] = 0.0
    cost = np.max(np.linalg.norm(cv2.projectPoints(rays, np.zeros(3), np.zeros(3), K, D)[0].reshape(-1, 2)
                                 - cv2.projectPoints(rays, np.zeros(3), np.zeros(3), K, kept)[0].reshape(-1, 2), axis=1))
    with pytest.raises(FileFormatError, match=rf"k4\.yaml: key 'D1': has k4 = 0\.2: this instrument's lens model has "
                                              rf"k1, k2, p1, p2, k3, s1-s4 .*up to {cost:.3g} px"):
        load_opencv_yaml(tmp_path / "k4.yaml")


# ============================================================================================================
# 2. nearest model
# ============================================================================================================
@pytest.mark.parametrize("camera, model", [
    (dataclasses.replace(FULL, beta_deg=-4.5), DICE_MODEL),                               # single-axis RMM: tau_y
    (dataclasses.replace(FULL, alpha_deg=2.5), DICE_MODEL),                               # single-axis RMM: tau_x
    (dataclasses.replace(FULL, alpha_deg=0.6, beta_deg=-4.5, tilt_model="opencv"), DICE_MODEL),
    (FULL, MATCHID_MODEL),
    (dataclasses.replace(FULL, p1=0.0, p2=0.0), VIC3D_MODEL),
], ids=["rmm-beta", "rmm-alpha", "opencv-two-axis", "matchid", "vic3d"])
def test_nearest_camera_is_exact_where_the_model_holds_the_camera(camera, model):
    """Cost <= 1e-6 px by the module's measure and, independently, over a 101 x 101 grid."""
    converted, cost = nearest_camera(camera, model)
    assert cost.exact and cost.max_px <= 1e-6 and not cost.lacks
    assert _distance_px(camera, converted)[1] <= 1e-6
    if camera.is_tilted and camera.tilt_model == "rmm":
        assert (converted.alpha_deg, converted.beta_deg) == (camera.alpha_deg, camera.beta_deg)


def test_nearest_camera_of_the_paper_two_axis_tilt_in_opencv_tilt_costs_what_opencv_itself_measures():
    """Paper left camera -> DICe's model: cost > 0.1 px; the converted K, D projected by cv2.projectPoints (an
    independent projection) agree with the reported max within 5 %; the fit beats copying tau = (alpha, beta)."""
    cam = _paper_rig().left
    converted, cost = nearest_camera(cam, DICE_MODEL)
    assert cost.max_px > 0.1 and not cost.exact and cost.lacks
    pixels = _image_grid(cam, 101)
    rays = np.column_stack([cam.backproject(pixels), np.ones(len(pixels))])
    d = np.zeros(14)
    d[:5] = converted.k1, converted.k2, converted.p1, converted.p2, converted.k3
    d[12:] = np.deg2rad([converted.alpha_deg, converted.beta_deg])
    K = converted.K.copy()
    K[0, 1] = 0.0                                                   # projectPoints ignores it: apply it by hand
    ref = cv2.projectPoints(rays, np.zeros(3), np.zeros(3), K, d)[0].reshape(-1, 2)
    ref[:, 0] += converted.skew * (ref[:, 1] - converted.cy) / converted.fy
    independent_max = float(np.max(np.linalg.norm(ref - pixels, axis=1)))
    assert abs(independent_max - cost.max_px) <= 0.05 * cost.max_px
    assert cost.max_px < opencv_distortion_cost_px(cam, n=101)


def test_frame_rotation_makes_the_two_axis_rmm_tilt_exact_in_opencv_tilt():
    """A turn about the optical axis commutes with radial distortion, so RMM = OpenCV tilt after it: <= 1e-6 px,
    checked with cv2.projectPoints given the rotation as rvec."""
    cam = _paper_rig().right
    converted, cost = nearest_camera(cam, DICE_MODEL, frame_rotation=True)
    assert cost.exact and 0.0 < cost.rotation_deg < 1.0
    rvec = cv2.Rodrigues(cost.R_new_from_old)[0]
    assert abs(rvec[0, 0]) < 1e-12 and abs(rvec[1, 0]) < 1e-12               # about the optical axis only
    pixels = _image_grid(cam, 51)
    rays = np.column_stack([cam.backproject(pixels), np.ones(len(pixels))])
    d = np.zeros(14)
    d[:5] = converted.k1, converted.k2, converted.p1, converted.p2, converted.k3
    d[12:] = np.deg2rad([converted.alpha_deg, converted.beta_deg])
    ref = cv2.projectPoints(rays, rvec, np.zeros(3), converted.K, d)[0].reshape(-1, 2)
    assert abs(converted.skew) < 1e-9 and np.max(np.abs(ref - pixels)) < 1e-6


# ============================================================================================================
# 3. the formats: round trips
# ============================================================================================================
_EXACT = {
    "dice": (FULL, dataclasses.replace(FULL, alpha_deg=0.9, beta_deg=-3.5, tilt_model="opencv", cx=1300.0), "opencv-tilt"),
    "vic3d": (dataclasses.replace(FULL, p1=0.0, p2=0.0), dataclasses.replace(FULL, p1=0.0, p2=0.0, k3=3.1), "pinhole"),
    "matchid": (FULL, dataclasses.replace(FULL, cx=1300.0, k3=0.8, skew=-2.0), "pinhole"),
}
_LOAD = {"dice": load_dice, "vic3d": load_vic3d, "matchid": lambda p: load_matchid(p, (2448, 2048))}
_SUFFIX = {"dice": ".xml", "vic3d": ".xml", "matchid": ".caldat"}


@pytest.mark.parametrize("fmt", list(_EXACT))
def test_a_rig_the_format_can_express_round_trips_within_1e6_px(tmp_path, fmt, rng):
    left, right, model = _EXACT[fmt]
    rig = _rig(left, right, model=model)
    path = tmp_path / f"cal{_SUFFIX[fmt]}"
    report = save_calibration_as(rig, path, fmt)
    assert report.exact and all(c.exact and not c.notes for c in report.cameras)
    back = _LOAD[fmt](path)
    X_left = _points(rng)
    X_right = X_left @ rig.R_right_from_left.T + rig.T_right_from_left_mm
    assert np.max(np.abs(back.left.project(X_left) - left.project(X_left))) < 1e-6
    X_right_back = X_left @ back.R_right_from_left.T + back.T_right_from_left_mm
    assert np.max(np.abs(back.right.project(X_right_back) - right.project(X_right))) < 1e-6
    assert load_any_calibration(path, image_size_px=(2448, 2048)).right == back.right


@pytest.mark.parametrize("fmt, lacking", [("dice", "two-axis RMM tilt"), ("vic3d", "Scheimpflug tilt"),
                                          ("matchid", "Scheimpflug tilt")])
def test_the_paper_rig_reports_a_cost_that_the_written_file_confirms(tmp_path, fmt, lacking):
    """The reported max (px) agrees within 5 % with an independent evaluation of the reloaded file over a 101 x 101
    grid, is > 0.1 px, and the notes say what could not be expressed."""
    rig = _paper_rig()
    path = tmp_path / f"paper{_SUFFIX[fmt]}"
    report = save_calibration_as(rig, path, fmt)
    back = _LOAD[fmt](path) if fmt != "matchid" else load_matchid(path, (rig.left.width, rig.left.height))
    for cam_report, source, loaded in zip(report.cameras, (rig.left, rig.right), (back.left, back.right)):
        mean, worst = _distance_px(source, loaded)
        assert cam_report.max_px > 0.1 and not cam_report.exact
        assert abs(worst - cam_report.max_px) <= 0.05 * cam_report.max_px
        assert any(lacking in note and f"{cam_report.max_px:.3g} px" in note for note in cam_report.notes)
    # the extrinsics are untouched without a frame rotation
    np.testing.assert_allclose(back.R_right_from_left, rig.R_right_from_left, atol=1e-12)
    np.testing.assert_allclose(back.T_right_from_left_mm, rig.T_right_from_left_mm, atol=1e-9)


def test_frame_rotation_keeps_dice_and_vic3d_worlds_in_the_left_camera_frame(tmp_path, rng):
    """With frame_rotation the DICe file is exact and both files' camera poses still take points given in this
    instrument's left camera frame to the right pixels (poses read here from the XML, projection by the loaded
    cameras): within 1e-6 px for DICe, within the reported cost for VIC-3D."""
    import xml.etree.ElementTree as ET
    from measurement.calibration.formats._common import rotation_zyx_deg

    rig = _paper_rig()
    X_left = _points(rng, n=2000, half_angle=0.08)
    X_right = X_left @ rig.R_right_from_left.T + rig.T_right_from_left_mm
    truth = (rig.left.project(X_left), rig.right.project(X_right))
    seen = np.all([(p[:, 0] >= 0) & (p[:, 0] <= 2455) & (p[:, 1] >= 0) & (p[:, 1] <= 2057) for p in truth], axis=0)
    assert seen.sum() > 100                                   # the costs hold inside the images
    X_left, truth = X_left[seen], tuple(p[seen] for p in truth)
    report = save_dice(rig, tmp_path / "cal.xml", frame_rotation=True)
    assert report.exact
    back = load_dice(tmp_path / "cal.xml")
    root = ET.parse(tmp_path / "cal.xml").getroot()
    for i, (cam, expected) in enumerate(zip((back.left, back.right), truth)):
        plist = root.find(f"ParameterList[@name='CAMERA {i}']")
        rows = [[float(x) for x in p.get("value").strip("{} ").split(",")]
                for p in plist.find("ParameterList[@name='rotation_3x3_matrix']")]
        T = [float(plist.find(f"Parameter[@name='{n}']").get("value")) for n in ("TX", "TY", "TZ")]
        assert np.max(np.abs(cam.project(X_left @ np.array(rows).T + T) - expected)) < 1e-6
    report = save_vic3d(rig, tmp_path / "vic.xml", frame_rotation=True)
    back = load_vic3d(tmp_path / "vic.xml")
    for i, (cam, expected, cam_report) in enumerate(zip((back.left, back.right), truth, report.cameras)):
        values = ET.parse(tmp_path / "vic.xml").getroot().find(f"calibration/camera[@id='{i}']/orientation").text
        a, b, g, *t = map(float, values.split())
        err = np.linalg.norm(cam.project(X_left @ rotation_zyx_deg(a, b, g).T + t) - expected, axis=1)
        assert np.max(err) <= cam_report.max_px * 1.05
    assert report.max_px < 0.5 * save_vic3d(rig, tmp_path / "vic0.xml").max_px      # the rotation pays


# ============================================================================================================
# 3b. real files from DICe's repository
# ============================================================================================================
def _dice_projection(cam: dict, X: np.ndarray) -> np.ndarray:
    """DICe_Camera.cpp ``sensor_to_image`` for OPENCV_LENS_DISTORTION (K1-K3, P1, P2, T1, T2, FS), written out."""
    x, y = X[:, 0] / X[:, 2], X[:, 1] / X[:, 2]
    r2 = x * x + y * y
    rad = 1 + cam["K1"] * r2 + cam["K2"] * r2 ** 2 + cam["K3"] * r2 ** 3
    ix = x * rad + 2 * cam["P1"] * x * y + cam["P2"] * (r2 + 2 * x * x)
    iy = y * rad + cam["P1"] * (r2 + 2 * y * y) + 2 * cam["P2"] * x * y
    c1, s1, c2, s2 = math.cos(cam["T1"]), math.sin(cam["T1"]), math.cos(cam["T2"]), math.sin(cam["T2"])
    R11, R12, R13, R22, R23, R31, R32, R33 = c2, s1 * s2, -s2 * c1, c1, s1, s2, -c2 * s1, c2 * c1
    S = np.array([[R11 * R33 - R13 * R31, R12 * R33 - R13 * R32, 0.0], [-R23 * R31, R33 * R22 - R23 * R32, 0.0],
                  [R31, R32, R33]])
    n = 1 / (S[2, 0] * ix + S[2, 1] * iy + S[2, 2])
    ix, iy = (ix * S[0, 0] + iy * S[0, 1]) * n, (ix * S[1, 0] + iy * S[1, 1]) * n
    return np.column_stack([ix * cam["FX"] + iy * cam["FS"] + cam["CX"], iy * cam["FY"] + cam["CY"]])


def test_a_dice_file_with_tilt_and_skew_projects_as_dices_own_formula(tmp_path, rng):
    """T1, T2 = OpenCV's tau_x, tau_y (radians) and FS = K[0][1]: the loaded camera equals DICe's sensor_to_image
    written out from its source (to 1e-9 px)."""
    cam = dict(CX=1230.0, CY=1010.0, FX=5200.0, FY=5190.0, FS=2.5, K1=-0.2, K2=0.4, K3=-1.1, P1=6e-4, P2=-3e-4,
               T1=0.012, T2=-0.07)
    params = "".join(f'<Parameter name="{k}" type="double" value="{v!r}" />' for k, v in cam.items())
    (tmp_path / "cal.xml").write_text(
        '<ParameterList><Parameter name="xml_file_format" type="string" value="DICe_xml_camera_system_file" />'
        '<Parameter name="system_type_3D" type="string" value="OPENCV" />'
        + "".join(f'<ParameterList name="CAMERA {i}">{params}<Parameter name="LENS_DISTORTION_MODEL" type="string" '
                  f'value="OPENCV_LENS_DISTORTION" /><Parameter name="TX" type="double" value="{-150.0 * i}" />'
                  f'<Parameter name="IMAGE_HEIGHT_WIDTH" type="string" value="{{ 2048, 2448 }}" /></ParameterList>'
                  for i in (0, 1)) + "</ParameterList>")
    rig = load_dice(tmp_path / "cal.xml")
    X = _points(rng)
    assert rig.model == "opencv-tilt" and np.max(np.abs(rig.left.project(X) - _dice_projection(cam, X))) < 1e-9


def test_dices_own_stereo_file_loads_to_plausible_values():
    """tests/regression/stereo_rectified/cal.xml: a 2448 x 2048 OpenCV calibration by DICe; camera 1 (DICe's
    stereo_right_suffix "_1") is 173 mm to the right of camera 0 (+x) and 56 mm ahead, its axis turned 35 deg
    towards camera 0's, the axes crossing ~300 mm ahead of camera 0."""
    rig = load_dice(DATA / "dice_stereo_rectified_cal.xml")
    assert (rig.left.width, rig.left.height) == (2448, 2048)
    assert rig.left.fx == pytest.approx(4725.040474193) and rig.right.k3 == pytest.approx(-4.941856327257)
    centre = -rig.R_right_from_left.T @ rig.T_right_from_left_mm
    np.testing.assert_allclose(centre, [173.41, 0.32, 56.47], atol=0.01)
    axis = rig.R_right_from_left.T @ [0, 0, 1.0]
    assert math.degrees(math.acos(axis[2])) == pytest.approx(35.0, abs=0.1) and axis[0] < 0
    z_cross = centre[2] - centre[0] * axis[2] / axis[0]
    assert 280 < z_cross < 330


def test_dice_extrinsics_direction_puts_the_target_in_both_images():
    """tests/regression/epipolar_distortion/cal.xml (extrinsics_relative_camera_to_camera = true): camera 0 has the
    world 15 mm in front (TZ = 15), camera 1 is given camera 0 -> camera 1 (BETA = 20 deg). By DICe's convention
    (DICe_Triangulation.cpp) the world origin is then X_1 = Ry(20) (0, 0, 15) + T_1 in camera 1, near its axis and
    inside its image; reading the pose as world -> camera 1 instead would put it 70 deg off axis."""
    rig = load_dice(DATA / "dice_epipolar_distortion_cal.xml")
    b = math.radians(20.0)
    Ry = np.array([[math.cos(b), 0, math.sin(b)], [0, 1, 0], [-math.sin(b), 0, math.cos(b)]])
    X1 = Ry @ [0, 0, 15.0] + np.array([-4.6984631039, 0.0, 1.7101007166])
    np.testing.assert_allclose(rig.R_right_from_left @ [0, 0, 15.0] + rig.T_right_from_left_mm, X1, atol=1e-9)
    u, v = rig.right.project(X1[None])[0]
    assert 0 <= u < 1920 and 0 <= v < 1080
    assert math.degrees(math.atan2(abs(X1[0]), X1[2])) < 3.0


def test_vic3d_sample_orientations_give_dices_own_camera_to_camera_transform():
    """tests/component/cal/cal_a.xml (VIC-3D) and cal_a.txt (DICe's camera 0 -> camera 1 of the same cameras:
    alpha, beta, gamma (deg) and t (mm), printed to 4-5 digits): world -> camera orientations with
    R = Rz(gamma) Ry(beta) Rx(alpha) reproduce them."""
    rig = load_vic3d(DATA / "vic3d_cal_a_excerpt.xml")
    numbers = [float(line.split("#")[0]) for line in (DATA / "dice_cal_a.txt").read_text().splitlines()
               if line.split("#")[0].strip()]
    alpha, beta, gamma, tx, ty, tz = numbers[16:22]
    R = rig.R_right_from_left
    got = (math.degrees(math.atan2(R[2, 1], R[2, 2])), math.degrees(math.atan2(-R[2, 0], math.hypot(R[0, 0], R[1, 0]))),
           math.degrees(math.atan2(R[1, 0], R[0, 0])))
    np.testing.assert_allclose(got, (alpha, beta, gamma), atol=5e-4)
    np.testing.assert_allclose(rig.T_right_from_left_mm, (tx, ty, tz), rtol=5e-5, atol=5e-5)
    assert (rig.left.width, rig.left.height) == (1280, 800)
    assert rig.left.skew == pytest.approx(-0.1711976745) and rig.left.k1 == pytest.approx(0.06384132162)


def test_vic3d_distortion_with_even_powers_is_plausible_on_a_real_file():
    """stereo_d_spec (VIC-3D, k2 = 0.87, k3 = -26.9): with r^2, r^4, r^6 the corners move by < 2 px; DICe's odd-power
    guess (k1 r + k2 r^2 + k3 r^3, written out here) would move them by > 100 px, which no DIC lens does."""
    rig = load_vic3d(DATA / "vic3d_stereo_d_spec_excerpt.xml")
    cam = rig.left
    corners = np.array([[0, 0], [cam.width - 1, 0], [0, cam.height - 1], [cam.width - 1, cam.height - 1]], float)
    ideal = np.column_stack([(corners[:, 0] - cam.cx) / cam.fx, (corners[:, 1] - cam.cy) / cam.fy])
    even = np.linalg.norm(cam.distort(ideal) - ideal, axis=1) * cam.fx
    r = np.linalg.norm(ideal, axis=1)
    odd = np.abs(cam.k1 * r + cam.k2 * r ** 2 + cam.k3 * r ** 3) * r * cam.fx
    assert np.max(even) < 2.0 and np.min(odd) > 100.0


def test_matchid_and_dice_carry_the_same_dic_challenge_extrinsics():
    """The DIC Challenge calibration with MatchID keys (values as published in an OpenCorr example) and DICe's
    sim_checkerboard_cal_gold.xml (camera 0 = world) give the same camera 0 -> camera 1 pose (to DICe's printed
    digits); the Cam1/Cam2 numbering and unit-less keys of other writers read the same."""
    text = ("Cam0_Fx [pixels];6673.315918\nCam0_Fy [pixels];6669.302734\nCam0_Fs [pixels];0.0\nCam0_Kappa 1;0.032258954\n"
            "Cam0_Kappa 2;-1.01141417\nCam0_Kappa 3;29.78838921\nCam0_P1;0.0\nCam0_P2;0.0\nCam0_Cx [pixels];872.1577759\n"
            "Cam0_Cy [pixels];579.9553223\nCam1_Fx [pixels];6607.618164\nCam1_Fy [pixels];6602.857422\n"
            "Cam1_Fs [pixels];0.0\nCam1_Kappa 1;0.064598486\nCam1_Kappa 2;-4.531373978\nCam1_Kappa 3;29.78838921\n"
            "Cam1_P1;0.0\nCam1_P2;0.0\nCam1_Cx [pixels];917.9733887\nCam1_Cy [pixels];531.6352539\nTx [mm];122.2488624\n"
            "Ty [mm];1.848889206\nTz [mm];17.62463774\nTheta [deg];0.130689541\nPhi [deg];-19.06769369\n"
            "Psi [deg];0.281404039\n")
    tmp = Path(__import__("tempfile").mkdtemp())
    (tmp / "a.caldat").write_text(text)
    matchid = load_matchid(tmp / "a.caldat", (1920, 1200))
    dice = load_dice(DATA / "dice_sim_checkerboard_cal_gold.xml")
    np.testing.assert_allclose(matchid.R_right_from_left, dice.R_right_from_left, atol=1e-8)
    np.testing.assert_allclose(matchid.T_right_from_left_mm, dice.T_right_from_left_mm, atol=1e-4)
    renumbered = re.sub(r"Cam(\d)", lambda m: f"cam{int(m.group(1)) + 1}", re.sub(r" \[(pixels|mm|deg)\]", "", text))
    (tmp / "b.caldat").write_text(renumbered)
    other = load_matchid(tmp / "b.caldat", (1920, 1200))
    assert other.left == matchid.left and np.array_equal(other.R_right_from_left, matchid.R_right_from_left)


# ============================================================================================================
# 3c. malformed files
# ============================================================================================================
def _dice_text() -> str:
    return (DATA / "dice_stereo_rectified_cal.xml").read_text()


_DICE_DEFECTS = {
    "missing FX": (lambda t: re.sub(r'<Parameter name="FX"[^>]*/>', "", t, count=1), r"key 'CAMERA 0.FX': required key"),
    "non-number": (lambda t: t.replace('value="1.209617441992e+03"', 'value="12O9.6"'),
                   r"key 'CAMERA 0.CX': must be a number, got '12O9.6'"),
    "not a rotation": (lambda t: t.replace("8.198619486301e-01, 3.363391720778e-03", "9.198619486301e-01, 3.363391720778e-03"),
                       r"key 'CAMERA 1.rotation_3x3_matrix': must be a rotation matrix"),
    "short row": (lambda t: t.replace("{ 0.000000000000e+00, 1.000000000000e+00, 0.000000000000e+00 }", "{ 0, 1 }"),
                  r"key 'CAMERA 0.rotation_3x3_matrix.ROW 1': must hold 3 numbers"),
    "no size": (lambda t: re.sub(r'<Parameter name="IMAGE_HEIGHT_WIDTH"[^>]*/>', "", t), r"key 'CAMERA 0.IMAGE_HEIGHT_WIDTH'"),
    "odd powers": (lambda t: t.replace("OPENCV_LENS_DISTORTION", "K1R1_K2R2_K3R3", 1),
                   r"key 'CAMERA 0.LENS_DISTORTION_MODEL': K1R1_K2R2_K3R3 uses odd powers"),
    "ignored terms": (lambda t: t.replace("OPENCV_LENS_DISTORTION", "NO_LENS_DISTORTION", 1),
                      r"key 'CAMERA 0.K1': .* NO_LENS_DISTORTION ignores it"),
    "thin prism": (lambda t: t.replace('<Parameter name="K1"', '<Parameter name="S1" type="double" value="0.002" />'
                                                               '<Parameter name="K1"', 1),
                   r"key 'CAMERA 0.S1': has s1 = 0.002|key 'CAMERA 0.S1': has S1 = 0.002: .* px"),
    "one camera": (lambda t: t[:t.index('<ParameterList name="CAMERA 1">')] + "</ParameterList>",
                   r"key 'CAMERA 1': a stereo file needs exactly"),
    "entity": (lambda t: t.replace("<ParameterList>", '<!DOCTYPE x [<!ENTITY a "b">]><ParameterList>', 1),
               r"declares XML entities"),
    "wrong format": (lambda t: t.replace('value="DICe_xml_camera_system_file"', 'value="other"'),
                     r"key 'xml_file_format': must be 'DICe_xml_camera_system_file'"),
    "broken xml": (lambda t: t[:200], r"is not well-formed XML"),
}


@pytest.mark.parametrize("case", list(_DICE_DEFECTS))
def test_malformed_dice_files_are_refused_naming_the_key(tmp_path, case):
    edit, message = _DICE_DEFECTS[case]
    path = tmp_path / "cal.xml"
    path.write_text(edit(_dice_text()))
    with pytest.raises(FileFormatError, match=re.escape(str(path)) + ".*" + message):
        load_dice(path)


_VIC = (DATA / "vic3d_cal_a_excerpt.xml").read_text(encoding="latin-1")
_VIC_DEFECTS = {
    "missing orientation": (lambda t: re.sub(r"<orientation>[^<]*</orientation>", "", t, count=1),
                            r"key 'camera\[0\].orientation': required element is missing"),
    "non-number": (lambda t: t.replace("6.389130236e+02", "six", 1), r"key 'camera\[0\]\[0\]': must be a number"),
    "seven numbers": (lambda t: t.replace(" 0.000000000e+00<orientation>", "<orientation>", 1),
                      r"key 'camera\[0\]': must hold 8 numbers"),
    "camera ids": (lambda t: t.replace('camera id="1"', 'camera id="2"'), r"needs cameras id=0 and id=1"),
    "no size": (lambda t: re.sub(r"<polygonmask[^>]*>", "<polygonmaskx>", t).replace("</polygonmask>", "</polygonmaskx>"),
                r"key 'polygonmask': required element is missing"),
    "bad angle": (lambda t: t.replace("1.799648062e+02", "1.799648062e+05", 1),
                  r"key 'camera\[0\].orientation.alpha': must be an angle"),
}


@pytest.mark.parametrize("case", list(_VIC_DEFECTS))
def test_malformed_vic3d_files_are_refused_naming_the_key(tmp_path, case):
    edit, message = _VIC_DEFECTS[case]
    path = tmp_path / "vic.xml"
    path.write_text(edit(_VIC), encoding="latin-1")
    with pytest.raises(FileFormatError, match=re.escape(str(path)) + ".*" + message):
        load_vic3d(path)


def _matchid_text(tmp_path) -> str:
    save_matchid(_rig(FULL, FULL), tmp_path / "ok.caldat")
    return (tmp_path / "ok.caldat").read_text()


_MATCHID_DEFECTS = {
    "missing key": (lambda t: re.sub(r"Cam1_Kappa 2;[^\n]*\n", "", t), r"key 'Cam1_Kappa 2': required key is missing"),
    "non-number": (lambda t: re.sub(r"Tz \[mm\];[^\n]*", "Tz [mm];28,0", t), r"key 'Tz \[mm\]': must be a number"),
    "wrong unit": (lambda t: t.replace("Cam0_Fx [pixels]", "Cam0_Fx [mm]"), r"key 'Cam0_Fx \[mm\]': has the unit \[mm\]"),
    "duplicate": (lambda t: t + "Psi [deg];1.0\n", r"key 'Psi \[deg\]': appears twice"),
    "unknown": (lambda t: t + "Cam0_Kappa 4;0.1\n", r"key 'Cam0_Kappa 4': unknown key"),
    "no separator": (lambda t: t + "garbage\n", r"key 'line 27': must be 'key;value'"),
    "three cameras": (lambda t: t + "Cam2_Fx [pixels];1000\n", r"numbers its two cameras"),
    "zero baseline": (lambda t: re.sub(r"T([xyz]) \[mm\];[^\n]*", r"T\1 [mm];0", t), r"key 'Tx \[mm\]': the stereo"),
}


@pytest.mark.parametrize("case", list(_MATCHID_DEFECTS))
def test_malformed_matchid_files_are_refused_naming_the_key(tmp_path, case):
    edit, message = _MATCHID_DEFECTS[case]
    path = tmp_path / "bad.caldat"
    path.write_text(edit(_matchid_text(tmp_path)))
    with pytest.raises(FileFormatError, match=re.escape(str(path)) + ".*" + message):
        load_matchid(path, (2448, 2048))


def test_a_matchid_file_needs_the_image_size(tmp_path):
    path = tmp_path / "ok.caldat"
    path.write_text(_matchid_text(tmp_path))
    with pytest.raises(FileFormatError, match=r"holds no image size: pass image_size_px"):
        load_any_calibration(path)


def test_writers_leave_the_old_file_when_the_written_text_would_not_reload(tmp_path, monkeypatch):
    from measurement.calibration.formats import _common

    path = tmp_path / "cal.xml"
    path.write_text("old")

    def refuse(written, expected, where):
        raise FileFormatError(where, "left", "reloads 1 px away (refusing to write it; nothing written)")

    monkeypatch.setattr(_common, "check_reload", refuse)
    with pytest.raises(FileFormatError, match="nothing written"):
        save_dice(_rig(FULL, FULL), path)
    assert path.read_text() == "old" and [p.name for p in tmp_path.iterdir()] == ["cal.xml"]


def test_load_any_calibration_tells_the_formats_apart(tmp_path):
    rig = _rig(FULL, FULL)
    save_dice(rig, tmp_path / "a.xml")
    save_vic3d(_rig(*_EXACT["vic3d"][:2]), tmp_path / "b.xml")
    save_matchid(rig, tmp_path / "c.txt")                      # by content, not suffix
    save_rig(rig, tmp_path / "d.xml")                          # this instrument's OpenCV XML
    assert [formats.detect_format(tmp_path / n) for n in ("a.xml", "b.xml", "c.txt", "d.xml")] == \
        ["dice", "vic3d", "matchid", "native"]
    assert load_any_calibration(tmp_path / "d.xml").left == FULL
    with pytest.raises(ValueError, match="format must be one of"):
        save_calibration_as(rig, tmp_path / "e.xml", "vic")
