"""Tests for measurement.camera: the paper's rotation-matrix Scheimpflug camera model (eqs 1-7).

Checks, in order:

1. agreement with OpenCV's ``CALIB_TILTED_MODEL`` for single-axis tilts (where the two parametrisations
   coincide), and a demonstration that they differ when both angles are non-zero;
2. agreement with an explicit ray / tilted-plane intersection written independently here, for general
   (alpha, beta);
3. the pixel -> ray -> pixel round trip over the whole sensor;
4. ``scaled``;
5. input validation;
6. eq (5)'s matrix A against OpenCV's construction from the rotation's third column.

Run with ``-s`` to see the measured maximum deviations.
"""
import math
import zlib

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from measurement.camera import (
    INTRINSIC_NAMES,
    ScheimpflugCamera,
    opencv_tilted_model,
    scheimpflug_matrix,
    scheimpflug_rotation,
    tilt_homography,
)
from workbench.rigs import paper_rig, paper_values

WIDTH, HEIGHT = 2456, 2058
TABLE1 = paper_values()["table1_calibration"]


def _table1_camera(side: str, **overrides) -> ScheimpflugCamera:
    t = TABLE1[side]
    params = dict(fx=t["fx_px"], fy=t["fy_px"], cx=t["cx_px"], cy=t["cy_px"],
                  alpha_deg=t["alpha_deg"], beta_deg=t["beta_deg"],
                  k1=t["k1"], k2=t["k2"], p1=t["p1"], p2=t["p2"], width=WIDTH, height=HEIGHT)
    params.update(overrides)
    return ScheimpflugCamera(**params)


def _points_inside_image(camera: ScheimpflugCamera, n: int, seed: int) -> np.ndarray:
    """Random camera-frame points at Z in [300, 450] mm whose projections fall inside the image, (M, 3).

    The points are drawn in a normalised-coordinate box somewhat larger than the field of view and then
    filtered by the camera's own projection (the filter only selects points; it does not decide the test).
    """
    rng = np.random.default_rng(seed)
    xn = rng.uniform(-0.12, 0.22, n)
    yn = rng.uniform(-0.14, 0.14, n)
    z = rng.uniform(300.0, 450.0, n)
    X = np.stack([xn * z, yn * z, z], axis=-1)
    uv = camera.project(X)
    inside = ((uv[:, 0] >= -0.5) & (uv[:, 0] <= camera.width - 0.5)
              & (uv[:, 1] >= -0.5) & (uv[:, 1] <= camera.height - 0.5))
    return X[inside]


def _opencv_project(X: np.ndarray, K: np.ndarray, dist: np.ndarray) -> np.ndarray:
    uv, _ = cv2.projectPoints(np.ascontiguousarray(X, dtype=np.float64), np.zeros(3), np.zeros(3),
                              np.asarray(K, dtype=np.float64), np.asarray(dist, dtype=np.float64))
    return uv.reshape(-1, 2)


# --------------------------------------------------------------------------------------------------------
# 1. OpenCV's tilted model
# --------------------------------------------------------------------------------------------------------
SINGLE_AXIS_TILTS = [
    (0.0, 0.0),
    (TABLE1["left"]["alpha_deg"], 0.0),
    (TABLE1["right"]["alpha_deg"], 0.0),
    (10.0, 0.0),
    (-10.0, 0.0),
    (0.0, TABLE1["left"]["beta_deg"]),
    (0.0, TABLE1["right"]["beta_deg"]),
    (0.0, 10.0),
    (0.0, -10.0),
]


@pytest.mark.parametrize("side", ["left", "right"])
@pytest.mark.parametrize("alpha_deg, beta_deg", SINGLE_AXIS_TILTS)
def test_project_matches_opencv_tilted_model_for_single_axis_tilts(side, alpha_deg, beta_deg):
    camera = _table1_camera(side, alpha_deg=alpha_deg, beta_deg=beta_deg)
    X = _points_inside_image(camera, 6000, seed=zlib.crc32(repr((side, alpha_deg, beta_deg)).encode()))
    assert len(X) >= 2000, f"only {len(X)} test points landed inside the image"

    K, dist = opencv_tilted_model(camera)
    assert dist.shape == (14,)
    # CALIB_TILTED_MODEL layout: (k1, k2, p1, p2, k3, k4, k5, k6, s1, s2, s3, s4, tau_x, tau_y)
    np.testing.assert_array_equal(dist[:4], [camera.k1, camera.k2, camera.p1, camera.p2])
    np.testing.assert_array_equal(dist[4:12], 0.0)
    assert dist[12] == pytest.approx(math.radians(alpha_deg), abs=1e-15)
    assert dist[13] == pytest.approx(math.radians(beta_deg), abs=1e-15)
    np.testing.assert_array_equal(K, [[camera.fx, 0, camera.cx], [0, camera.fy, camera.cy], [0, 0, 1]])

    ours = camera.project(X)
    theirs = _opencv_project(X, K, dist)
    err = np.abs(ours - theirs).max()
    print(f"\n[opencv] {side} alpha={alpha_deg:+.4f} beta={beta_deg:+.4f}: "
          f"{len(X)} pts, max |diff| = {err:.3e} px")
    assert np.all(np.isfinite(ours))
    assert err <= 1e-6


@pytest.mark.parametrize("alpha_deg, beta_deg", [(0.6156, -4.5583), (-0.1, 0.1), (7.0, -12.0)])
def test_opencv_tilted_model_refuses_two_axis_tilt(alpha_deg, beta_deg):
    camera = _table1_camera("left", alpha_deg=alpha_deg, beta_deg=beta_deg)
    with pytest.raises(ValueError, match="single-axis"):
        opencv_tilted_model(camera)


def test_naive_opencv_tau_differs_from_paper_model_when_both_angles_nonzero():
    """tau_x = alpha, tau_y = beta is *not* the paper's camera when both angles are non-zero.

    OpenCV rotates by R_Y(-tau_y) R_X(-tau_x), the paper by R_S^T = R_X(-alpha) R_Y(-beta); for Table 1's
    left camera the two disagree by more than a pixel at the image corners.
    """
    camera = paper_rig(1.0).left
    assert camera.alpha_deg != 0.0 and camera.beta_deg != 0.0
    W, H = camera.width, camera.height
    corners = np.array([[-0.5, -0.5], [W - 0.5, -0.5], [-0.5, H - 0.5], [W - 0.5, H - 0.5]])
    xy_n = camera.backproject(corners)
    X = np.concatenate([xy_n, np.ones((4, 1))], axis=-1) * 400.0
    np.testing.assert_allclose(camera.project(X), corners, atol=1e-6)  # the corners really are the corners

    dist = np.zeros(14)
    dist[:4] = camera.k1, camera.k2, camera.p1, camera.p2
    dist[12], dist[13] = camera.alpha_rad, camera.beta_rad
    naive = _opencv_project(X, camera.K, dist)
    diff = np.linalg.norm(naive - corners, axis=-1)
    print(f"\n[opencv naive tau] Table 1 left, corner differences: {np.array2string(diff, precision=3)} px")
    assert np.all(diff > 1.0)              # measured 1.13, 1.60, 1.18, 1.63 px
    # ... while the principal ray is unaffected by either parametrisation (both keep it at (cx, cy))
    centre = _opencv_project(np.array([[0.0, 0.0, 400.0]]), camera.K, dist)
    np.testing.assert_allclose(centre[0], [camera.cx, camera.cy], atol=1e-9)
    np.testing.assert_allclose(camera.project([0.0, 0.0, 400.0])[0], [camera.cx, camera.cy], atol=1e-9)


# --------------------------------------------------------------------------------------------------------
# 2. Independent geometry: explicit ray / tilted-plane intersection
# --------------------------------------------------------------------------------------------------------
def _rx(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def _ry(b):
    c, s = math.cos(b), math.sin(b)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def _sensor_rotation(alpha_deg, beta_deg):
    """R_S = R_Y(beta) R_X(alpha): scipy's *intrinsic* 'YX' sequence (uppercase = intrinsic)."""
    return Rotation.from_euler("YX", [beta_deg, alpha_deg], degrees=True).as_matrix()


@pytest.mark.parametrize("alpha_deg, beta_deg", [(0.6156, -4.5583), (7.0, -12.0), (-20.0, 30.0)])
def test_scipy_convention_is_ry_beta_times_rx_alpha(alpha_deg, beta_deg):
    a, b = math.radians(alpha_deg), math.radians(beta_deg)
    R = _sensor_rotation(alpha_deg, beta_deg)
    np.testing.assert_allclose(R, _ry(b) @ _rx(a), atol=1e-15)
    # the order matters: the other product (= extrinsic 'YX') is measurably different
    assert np.abs(R - _rx(a) @ _ry(b)).max() > 1e-4
    np.testing.assert_allclose(Rotation.from_euler("xy", [alpha_deg, beta_deg], degrees=True).as_matrix(),
                               R, atol=1e-15)
    np.testing.assert_allclose(scheimpflug_rotation(a, b), R, atol=1e-15)


def _brown(camera, xn, yn):
    """Eq (7), written out independently of ScheimpflugCamera.distort."""
    r2 = xn**2 + yn**2
    radial = 1 + camera.k1 * r2 + camera.k2 * r2**2
    xd = xn * radial + 2 * camera.p1 * xn * yn + camera.p2 * (r2 + 2 * xn**2)
    yd = yn * radial + 2 * camera.p2 * xn * yn + camera.p1 * (r2 + 2 * yn**2)
    return xd, yd


def _project_by_ray_plane_intersection(camera, X):
    R_S = _sensor_rotation(camera.alpha_deg, camera.beta_deg)
    e1, e2, n = R_S[:, 0], R_S[:, 1], R_S[:, 2]
    origin = np.array([0.0, 0.0, 1.0])              # the sensor plane passes through (0, 0, 1)
    xd, yd = _brown(camera, X[:, 0] / X[:, 2], X[:, 1] / X[:, 2])
    d = np.stack([xd, yd, np.ones_like(xd)], axis=-1)   # ray direction through the distorted point
    lam = (origin @ n) / (d @ n)                    # ray lam * d hits the plane n . (p - origin) = 0
    hit = lam[:, None] * d
    assert np.allclose((hit - origin) @ n, 0.0, atol=1e-14)
    s = (hit - origin) @ e1
    t = (hit - origin) @ e2
    return np.stack([camera.fx * s + camera.cx, camera.fy * t + camera.cy], axis=-1)


@pytest.mark.parametrize("side, alpha_deg, beta_deg", [
    ("left", None, None),      # Table 1 left as published
    ("right", None, None),     # Table 1 right as published
    ("left", 7.0, -12.0),
    ("right", -15.0, 9.0),
])
def test_project_matches_explicit_ray_plane_intersection(side, alpha_deg, beta_deg):
    overrides = {} if alpha_deg is None else dict(alpha_deg=alpha_deg, beta_deg=beta_deg)
    camera = _table1_camera(side, **overrides)
    assert camera.alpha_deg != 0.0 and camera.beta_deg != 0.0
    X = _points_inside_image(camera, 6000, seed=7)
    assert len(X) >= 2000
    ours = camera.project(X)
    ref = _project_by_ray_plane_intersection(camera, X)
    err = np.abs(ours - ref).max()
    print(f"\n[ray-plane] {side} alpha={camera.alpha_deg:+.4f} beta={camera.beta_deg:+.4f}: "
          f"{len(X)} pts, max |diff| = {err:.3e} px")
    assert err <= 1e-9
    # the tilt is not a no-op at these angles: an untilted camera lands elsewhere
    flat = _table1_camera(side, alpha_deg=0.0, beta_deg=0.0)
    assert np.abs(flat.project(X) - ours).max() > 1.0


# --------------------------------------------------------------------------------------------------------
# 3. Round trip pixel -> ray -> pixel
# --------------------------------------------------------------------------------------------------------
def _dense_sensor_grid(width, height, step=8):
    us = np.unique(np.concatenate([np.arange(0.0, width, step), [width - 1.0, -0.5, width - 0.5]]))
    vs = np.unique(np.concatenate([np.arange(0.0, height, step), [height - 1.0, -0.5, height - 0.5]]))
    uu, vv = np.meshgrid(us, vs)
    return np.stack([uu.ravel(), vv.ravel()], axis=-1)


@pytest.mark.parametrize("side", ["left", "right"])
def test_backproject_project_round_trip_over_whole_sensor(side):
    camera = paper_rig(1.0).camera(side)
    pixels = _dense_sensor_grid(camera.width, camera.height)
    for corner in ([-0.5, -0.5], [camera.width - 0.5, camera.height - 0.5], [0, 0],
                   [camera.width - 1, camera.height - 1]):
        assert np.any(np.all(pixels == corner, axis=1))

    xy_n = camera.backproject(pixels)
    assert np.all(np.isfinite(xy_n))
    X = np.concatenate([xy_n, np.ones((len(xy_n), 1))], axis=-1)
    back = camera.project(X)
    err = np.abs(back - pixels).max()

    rays = camera.rays(pixels)
    norm_err = np.abs(np.linalg.norm(rays, axis=-1) - 1.0).max()
    # rays point forward and along (x_n, y_n, 1)
    assert np.all(rays[:, 2] > 0)
    np.testing.assert_allclose(rays[:, :2] / rays[:, 2:], xy_n, rtol=0, atol=1e-14)
    ray_err = np.abs(camera.project(rays * 350.0) - pixels).max()
    print(f"\n[round trip] {side}: {len(pixels)} px, max |project(backproject) - px| = {err:.3e} px, "
          f"via rays() = {ray_err:.3e} px, max | |ray| - 1 | = {norm_err:.3e}")
    assert err <= 1e-6
    assert ray_err <= 1e-6
    assert norm_err <= 1e-14


# --------------------------------------------------------------------------------------------------------
# 4. scaled()
# --------------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("scale", [0.25, 1.0 / 3.0, 0.5, 2.0])
def test_scaled_camera_maps_pixel_centres(scale):
    camera = paper_rig(1.0).left
    small = camera.scaled(scale)
    assert small.width == round(scale * camera.width)
    assert small.height == round(scale * camera.height)
    assert (small.alpha_deg, small.beta_deg, small.k1, small.k2, small.p1, small.p2) == \
        (camera.alpha_deg, camera.beta_deg, camera.k1, camera.k2, camera.p1, camera.p2)
    X = _points_inside_image(camera, 3000, seed=3)
    np.testing.assert_allclose(small.project(X), scale * (camera.project(X) + 0.5) - 0.5, rtol=0, atol=1e-9)
    # the image extent (outer pixel edges) maps onto itself
    edges = np.array([[-0.5, -0.5], [camera.width - 0.5, camera.height - 0.5]])
    np.testing.assert_allclose(small.project(np.c_[camera.backproject(edges), np.ones(2)]),
                               scale * (edges + 0.5) - 0.5, atol=1e-6)


def test_paper_rig_scale_uses_scaled():
    full, half = paper_rig(1.0), paper_rig(0.5)
    assert half.left == full.left.scaled(0.5)
    assert half.right == full.right.scaled(0.5)
    assert (half.left.width, half.left.height) == (WIDTH // 2, HEIGHT // 2)


@pytest.mark.parametrize("scale", [0.0, -0.5, float("nan")])
def test_scaled_rejects_non_positive_scale(scale):
    with pytest.raises(ValueError, match="scale"):
        paper_rig(1.0).left.scaled(scale)


# --------------------------------------------------------------------------------------------------------
# 5. Bad input
# --------------------------------------------------------------------------------------------------------
GOOD = dict(fx=10000.0, fy=10000.0, cx=1227.5, cy=1028.5, width=WIDTH, height=HEIGHT)


@pytest.mark.parametrize("name, value, pattern", [
    ("fx", 0.0, r"fx=0\.0"),
    ("fx", -100.0, r"fx=-100"),
    ("fy", 0.0, r"fy=0\.0"),
    ("fy", -1.0, r"fy=-1"),
    ("alpha_deg", 45.0, "alpha_deg"),
    ("alpha_deg", -45.0, "alpha_deg"),
    ("alpha_deg", 60.0, "alpha_deg"),
    ("beta_deg", 45.0, "beta_deg"),
    ("beta_deg", -45.0, "beta_deg"),
    ("beta_deg", -90.0, "beta_deg"),
])
def test_invalid_parameters_raise_naming_the_parameter(name, value, pattern):
    with pytest.raises(ValueError, match=pattern):
        ScheimpflugCamera(**{**GOOD, name: value})


@pytest.mark.parametrize("name", INTRINSIC_NAMES)
@pytest.mark.parametrize("value", [float("nan"), float("inf")])
def test_non_finite_parameters_raise_naming_the_parameter(name, value):
    with pytest.raises(ValueError, match=rf"\b{name}\b"):
        ScheimpflugCamera(**{**GOOD, name: value})


def test_tilts_just_inside_the_limit_are_accepted():
    cam = ScheimpflugCamera(**{**GOOD, "alpha_deg": 44.9, "beta_deg": -44.9})
    assert np.all(np.isfinite(cam.project([[1.0, -2.0, 400.0]])))


@pytest.mark.parametrize("shape", [(5, 2), (2,), (4, 4), (3, 1)])
def test_project_rejects_wrong_shape(shape):
    camera = paper_rig(1.0).left
    with pytest.raises(ValueError, match="shape"):
        camera.project(np.ones(shape))


def test_backproject_rejects_wrong_shape():
    with pytest.raises(ValueError, match="shape"):
        paper_rig(1.0).left.backproject(np.ones((4, 3)))


def test_points_at_or_behind_the_camera_give_nan():
    camera = paper_rig(1.0).left
    X = np.array([[1.0, 2.0, 400.0], [1.0, 2.0, 0.0], [0.0, 0.0, 0.0], [1.0, 2.0, -400.0], [-5.0, 3.0, 350.0]])
    with np.errstate(all="raise"):      # no warnings escape for these points either
        uv = camera.project(X)
    assert uv.shape == (5, 2)
    assert np.all(np.isnan(uv[1:4]))
    assert np.all(np.isfinite(uv[[0, 4]]))
    np.testing.assert_allclose(camera.project(X[[0, 4]]), uv[[0, 4]], rtol=0, atol=0)


def test_single_point_projects_as_one_row():
    camera = paper_rig(1.0).left
    uv = camera.project([0.0, 0.0, 400.0])
    assert uv.shape == (1, 2)
    np.testing.assert_allclose(uv[0], [camera.cx, camera.cy], atol=1e-9)


def test_from_dict_accepts_table1_keys():
    t = TABLE1["left"]
    cam = ScheimpflugCamera.from_dict({**t, "width": WIDTH, "height": HEIGHT})  # incl. reprojection_error_px
    assert cam == paper_rig(1.0).left
    assert cam.fx == t["fx_px"] and cam.cy == t["cy_px"] and cam.beta_deg == t["beta_deg"]
    # plain names round-trip through to_dict
    assert ScheimpflugCamera.from_dict(cam.to_dict()) == cam


def test_from_dict_missing_focal_length_raises_naming_it():
    t = {k: v for k, v in TABLE1["right"].items() if k != "fx_px"}
    with pytest.raises(ValueError, match=r"lacks fx\b"):
        ScheimpflugCamera.from_dict(t)
    t2 = {k: v for k, v in TABLE1["right"].items() if k not in ("cx_px", "cy_px")}
    with pytest.raises(ValueError, match=r"cx, cy"):
        ScheimpflugCamera.from_dict(t2)


# --------------------------------------------------------------------------------------------------------
# 6. Eq (5)
# --------------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("alpha_deg, beta_deg", [
    (0.0, 0.0), (0.6156, -4.5583), (0.3511, 4.4574), (7.0, -12.0), (-30.0, 20.0), (10.0, 0.0), (0.0, -10.0)])
def test_scheimpflug_matrix_equals_projection_from_rotation_third_column(alpha_deg, beta_deg):
    a, b = math.radians(alpha_deg), math.radians(beta_deg)
    Rt = _sensor_rotation(alpha_deg, beta_deg).T            # R_S^T, built independently with scipy
    r13, r23, r33 = Rt[:, 2]
    A_ref = np.array([[r33, 0.0, -r13], [0.0, r33, -r23], [0.0, 0.0, 1.0]])
    np.testing.assert_allclose(scheimpflug_matrix(a, b), A_ref, rtol=0, atol=1e-15)
    np.testing.assert_allclose(tilt_homography(a, b), A_ref @ Rt, rtol=0, atol=1e-15)
    # the homography keeps the principal ray on the principal point
    h = tilt_homography(a, b) @ np.array([0.0, 0.0, 1.0])
    np.testing.assert_allclose(h[:2] / h[2], 0.0, atol=1e-15)


def test_tilt_homography_is_identity_without_tilt():
    np.testing.assert_array_equal(tilt_homography(0.0, 0.0), np.eye(3))
    np.testing.assert_array_equal(scheimpflug_matrix(0.0, 0.0), np.eye(3))
    # and an untilted camera is plain pinhole + Brown
    cam = _table1_camera("left", alpha_deg=0.0, beta_deg=0.0)
    assert not cam.is_tilted
    X = _points_inside_image(cam, 2000, seed=5)
    xd, yd = _brown(cam, X[:, 0] / X[:, 2], X[:, 1] / X[:, 2])
    np.testing.assert_allclose(cam.project(X), np.stack([cam.fx * xd + cam.cx, cam.fy * yd + cam.cy], -1),
                               rtol=0, atol=1e-9)
