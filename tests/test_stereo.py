"""Tests for measurement.stereo: triangulation with Scheimpflug tilt and distortion, and plane fitting.

All triangulation tests use the paper's Table 1 rig at full resolution (strong distortion, +-4.5 deg tilts,
~147 mm baseline) and points in the common field of view at the working distance. Run with ``-s`` to see the
measured figures (noise-free error, noisy 3D error, plane-fit RMSE, 100k-point time).
"""
import time

import numpy as np
import pytest

from measurement.camera import ScheimpflugCamera, rotation_x, rotation_y
from measurement.stereo import (
    fit_plane,
    plane_fit_max_deviation_mm,
    plane_fit_rmse_mm,
    projection_jacobian,
    triangulate,
    triangulation_covariance_mm2,
)
from workbench.rigs import paper_rig

PIXEL_SIGMA_PX = 0.05


@pytest.fixture(scope="module")
def rig():
    return paper_rig(1.0)


def _common_view_points(n: int, seed: int) -> np.ndarray:
    """Random left-frame points, X in +-20 mm, Y in +-15 mm, Z in 320-380 mm, shape (n, 3)."""
    rng = np.random.default_rng(seed)
    return np.stack([rng.uniform(-20, 20, n), rng.uniform(-15, 15, n), rng.uniform(320, 380, n)], axis=-1)


def _project_pair(rig, X_left_mm):
    """True pixels of left-frame points in both cameras, ((N, 2), (N, 2))."""
    X_right_mm = X_left_mm @ rig.R_right_from_left.T + rig.T_right_from_left_mm
    return rig.left.project(X_left_mm), rig.right.project(X_right_mm)


def _inside(camera: ScheimpflugCamera, pixels: np.ndarray) -> np.ndarray:
    return ((pixels[:, 0] >= -0.5) & (pixels[:, 0] <= camera.width - 0.5)
            & (pixels[:, 1] >= -0.5) & (pixels[:, 1] <= camera.height - 0.5))


def _triangulate(rig, pixels_left, pixels_right, **kwargs):
    return triangulate(rig.left, rig.right, rig.R_right_from_left, rig.T_right_from_left_mm,
                       pixels_left, pixels_right, **kwargs)


# ---------------------------------------------------------------------------------------------------------
# The Jacobian used by the refinement and the covariance
# ---------------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("side", ["left", "right"])
def test_projection_jacobian_matches_central_differences(rig, side):
    camera = rig.camera(side)
    X = _common_view_points(50, seed=1)
    if side == "right":
        X = X @ rig.R_right_from_left.T + rig.T_right_from_left_mm
    J = projection_jacobian(camera, X)
    h_mm = 1e-4
    J_fd = np.stack([(camera.project(X + h_mm * e) - camera.project(X - h_mm * e)) / (2 * h_mm)
                     for e in np.eye(3)], axis=-1)
    # |J| ~ 30 px/mm; central-difference truncation and rounding are ~1e-9 px/mm here.
    np.testing.assert_allclose(J, J_fd, rtol=0, atol=1e-7 * np.abs(J).max())


# ---------------------------------------------------------------------------------------------------------
# Noise-free and noisy triangulation
# ---------------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("refine", [False, True])
def test_noise_free_triangulation_is_exact(rig, refine):
    X_true = _common_view_points(2000, seed=2)
    pixels_left, pixels_right = _project_pair(rig, X_true)
    # The test points are really in the common view of the Table 1 rig.
    assert _inside(rig.left, pixels_left).all() and _inside(rig.right, pixels_right).all()

    result = _triangulate(rig, pixels_left, pixels_right, refine=refine)

    error_mm = np.linalg.norm(result.X_left_mm - X_true, axis=1)
    print(f"\nnoise-free triangulation (refine={refine}): max 3D error {error_mm.max():.2e} mm, "
          f"max reprojection error {result.reprojection_error_px.max():.2e} px, "
          f"max ray gap {result.ray_gap_mm.max():.2e} mm")
    assert result.valid.all()
    assert error_mm.max() <= 1e-6
    assert result.reprojection_error_px.max() <= 1e-6
    assert result.ray_gap_mm.max() <= 1e-6
    assert result.X_left_mm.shape == (2000, 3)
    assert result.reprojection_error_px.shape == result.ray_gap_mm.shape == result.valid.shape == (2000,)


def test_noisy_triangulation_is_optimal_and_at_the_predicted_scale(rig):
    n = 4000
    X_true = _common_view_points(n, seed=3)
    pixels_left, pixels_right = _project_pair(rig, X_true)
    rng = np.random.default_rng(4)
    noisy_left = pixels_left + rng.normal(0.0, PIXEL_SIGMA_PX, pixels_left.shape)
    noisy_right = pixels_right + rng.normal(0.0, PIXEL_SIGMA_PX, pixels_right.shape)

    midpoint = _triangulate(rig, noisy_left, noisy_right, refine=False)
    optimal = _triangulate(rig, noisy_left, noisy_right, refine=True)
    assert midpoint.valid.all() and optimal.valid.all()

    # The refinement minimises the reprojection error per point: never worse than its midpoint start.
    assert np.all(optimal.reprojection_error_px <= midpoint.reprojection_error_px + 1e-12)
    assert optimal.reprojection_error_px.mean() < midpoint.reprojection_error_px.mean()
    # 4 residuals, 3 unknowns: the minimal summed squared residual is sigma^2 chi^2_1, so the per-point RMS
    # over the two images has mean square sigma^2 / 2 (statistical spread here ~2 %).
    rms_reprojection_px = np.sqrt(np.mean(optimal.reprojection_error_px ** 2))
    assert rms_reprojection_px == pytest.approx(PIXEL_SIGMA_PX / np.sqrt(2), rel=0.08)

    # 3D error against first-order propagation sigma^2 (J^T J)^-1 at the true points (spread ~1.5 %).
    cov = triangulation_covariance_mm2(rig.left, rig.right, rig.R_right_from_left, rig.T_right_from_left_mm,
                                       X_true, PIXEL_SIGMA_PX)
    predicted_rms_mm = np.sqrt(np.mean(np.trace(cov, axis1=1, axis2=2)))
    predicted_axis_mm = np.sqrt(np.mean(np.diagonal(cov, axis1=1, axis2=2), axis=0))
    error = optimal.X_left_mm - X_true
    rms_mm = np.sqrt(np.mean(np.sum(error ** 2, axis=1)))
    rms_axis_mm = np.sqrt(np.mean(error ** 2, axis=0))
    rms_midpoint_mm = np.sqrt(np.mean(np.sum((midpoint.X_left_mm - X_true) ** 2, axis=1)))
    print(f"\nsigma = {PIXEL_SIGMA_PX} px: optimal RMS 3D error {rms_mm * 1e3:.2f} um "
          f"(X, Y, Z: {', '.join(f'{v * 1e3:.2f}' for v in rms_axis_mm)} um; "
          f"predicted {predicted_rms_mm * 1e3:.2f} um), "
          f"midpoint {rms_midpoint_mm * 1e3:.2f} um; mean reprojection error optimal "
          f"{optimal.reprojection_error_px.mean():.7f} px, midpoint {midpoint.reprojection_error_px.mean():.7f} px")
    assert rms_mm == pytest.approx(predicted_rms_mm, rel=0.08)
    np.testing.assert_allclose(rms_axis_mm, predicted_axis_mm, rtol=0.1)
    # Depth is the weak direction of a ~23 deg convergent pair.
    assert rms_axis_mm[2] > 2 * max(rms_axis_mm[0], rms_axis_mm[1])


def test_triangulated_checkerboards_plane_fit_rmse_matches_noise_model(rig):
    """The paper's calibration check: reconstruct planar targets, fit planes, look at the RMSE.

    With pixel noise only, the plane-fit RMSE must equal the out-of-plane triangulation uncertainty predicted
    by first-order propagation (times sqrt((M - 3) / M) for the 3 fitted plane parameters).
    """
    rng = np.random.default_rng(5)
    gx, gy = np.meshgrid(np.arange(11) * 4.0 - 20.0, np.arange(9) * 4.0 - 16.0)
    board_mm = np.stack([gx.ravel(), gy.ravel(), np.zeros(gx.size)], axis=-1)  # 11 x 9 corners, 4 mm pitch
    m = len(board_mm)
    observed_ms, predicted_ms, max_deviation_mm = [], [], []
    for _ in range(20):
        R_board = (rotation_y(np.deg2rad(rng.uniform(-20, 20)))
                   @ rotation_x(np.deg2rad(rng.uniform(-20, 20))))
        centre_mm = np.array([rng.uniform(-3, 3), rng.uniform(-3, 3), rng.uniform(335, 365)])
        X_true = board_mm @ R_board.T + centre_mm
        pixels_left, pixels_right = _project_pair(rig, X_true)
        assert _inside(rig.left, pixels_left).all() and _inside(rig.right, pixels_right).all()
        result = _triangulate(rig, pixels_left + rng.normal(0, PIXEL_SIGMA_PX, pixels_left.shape),
                              pixels_right + rng.normal(0, PIXEL_SIGMA_PX, pixels_right.shape))
        assert result.valid.all()
        normal, _, distances_mm = fit_plane(result.X_left_mm)
        assert np.degrees(np.arccos(abs(normal @ R_board[:, 2]))) < 0.1
        observed_ms.append(np.mean(distances_mm ** 2))
        max_deviation_mm.append(plane_fit_max_deviation_mm(result.X_left_mm))
        cov = triangulation_covariance_mm2(rig.left, rig.right, rig.R_right_from_left,
                                           rig.T_right_from_left_mm, X_true, PIXEL_SIGMA_PX)
        n_true = R_board[:, 2]
        predicted_ms.append(np.mean(np.einsum("i,nij,j->n", n_true, cov, n_true)) * (m - 3) / m)
    observed_rmse_mm, predicted_rmse_mm = np.sqrt(np.mean(observed_ms)), np.sqrt(np.mean(predicted_ms))
    print(f"\nplane-fit RMSE of 20 triangulated boards at sigma = {PIXEL_SIGMA_PX} px: "
          f"{observed_rmse_mm * 1e3:.2f} um (predicted {predicted_rmse_mm * 1e3:.2f} um), "
          f"max deviation {max(max_deviation_mm) * 1e3:.2f} um (paper, real calibration: 13.3 um / 30 um)")
    assert observed_rmse_mm == pytest.approx(predicted_rmse_mm, rel=0.1)


# ---------------------------------------------------------------------------------------------------------
# Points that cannot be triangulated
# ---------------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("refine", [False, True])
def test_nan_pixels_give_invalid_points_without_affecting_others(rig, refine):
    X_true = _common_view_points(200, seed=6)
    pixels_left, pixels_right = _project_pair(rig, X_true)
    rng = np.random.default_rng(7)
    pixels_left = pixels_left + rng.normal(0, PIXEL_SIGMA_PX, pixels_left.shape)
    pixels_right = pixels_right + rng.normal(0, PIXEL_SIGMA_PX, pixels_right.shape)
    clean = _triangulate(rig, pixels_left, pixels_right, refine=refine)

    broken_left, broken_right = pixels_left.copy(), pixels_right.copy()
    broken_left[3] = np.nan
    broken_right[7, 1] = np.nan
    broken_left[11, 0] = np.inf
    bad = np.zeros(200, dtype=bool)
    bad[[3, 7, 11]] = True
    result = _triangulate(rig, broken_left, broken_right, refine=refine)

    assert not result.valid[bad].any()
    assert np.isnan(result.X_left_mm[bad]).all()
    assert np.isnan(result.reprojection_error_px[bad]).all()
    assert np.isnan(result.ray_gap_mm[bad]).all()
    assert result.valid[~bad].all()
    np.testing.assert_allclose(result.X_left_mm[~bad], clean.X_left_mm[~bad], rtol=0, atol=1e-12)
    np.testing.assert_allclose(result.reprojection_error_px[~bad], clean.reprojection_error_px[~bad],
                               rtol=0, atol=1e-12)


@pytest.mark.parametrize("refine", [False, True])
def test_rays_meeting_behind_both_cameras_are_invalid(rig, refine):
    # P lies behind both cameras; the pixels are those of the forward half of the lines through P.
    P_left_mm = np.array([[5.0, 3.0, -350.0], [-8.0, 2.0, -330.0]])
    P_right_mm = P_left_mm @ rig.R_right_from_left.T + rig.T_right_from_left_mm
    assert (P_left_mm[:, 2] < 0).all() and (P_right_mm[:, 2] < 0).all()
    pixels_left, pixels_right = rig.left.project(-P_left_mm), rig.right.project(-P_right_mm)
    good_left, good_right = _project_pair(rig, _common_view_points(1, seed=8))

    result = _triangulate(rig, np.vstack([pixels_left, good_left]), np.vstack([pixels_right, good_right]),
                          refine=refine)

    # The lines do meet (gap ~ 0): the point is refused because the meeting point is behind the cameras.
    assert result.ray_gap_mm[:2].max() < 1e-9
    assert not result.valid[:2].any()
    assert np.isnan(result.X_left_mm[:2]).all()
    assert result.valid[2]


@pytest.mark.parametrize("refine", [False, True])
def test_rays_meeting_behind_one_camera_are_invalid(refine):
    # Both cameras look along +Z; the right one stands 200 mm in front of the left one, so P at Z = 100 mm is
    # in front of the left camera but behind the right one (pixels of the right camera: the line through P).
    camera = ScheimpflugCamera(fx=2000.0, fy=2000.0, cx=500.0, cy=400.0, alpha_deg=3.0, beta_deg=-4.0,
                               k1=-0.2, k2=0.3, width=1000, height=800)
    R, T_mm = np.eye(3), np.array([0.0, 0.0, -200.0])
    P_left_mm = np.array([[10.0, 5.0, 100.0], [10.0, 5.0, 300.0]])  # behind / in front of the right camera
    P_right_mm = P_left_mm @ R.T + T_mm
    pixels_left = camera.project(P_left_mm)
    pixels_right = camera.project(np.sign(P_right_mm[:, 2:3]) * P_right_mm)

    result = triangulate(camera, camera, R, T_mm, pixels_left, pixels_right, refine=refine)

    assert result.ray_gap_mm.max() < 1e-9
    assert not result.valid[0] and np.isnan(result.X_left_mm[0]).all()
    assert result.valid[1]
    np.testing.assert_allclose(result.X_left_mm[1], P_left_mm[1], atol=1e-8)


@pytest.mark.parametrize("refine", [False, True])
def test_parallel_rays_are_invalid(rig, refine):
    direction_left = np.array([[0.02, -0.01, 1.0], [0.0, 0.0, 1.0]])
    pixels_left = rig.left.project(direction_left)
    # The same direction seen from the right camera: the rays are parallel, 147 mm apart.
    pixels_right = rig.right.project(direction_left @ rig.R_right_from_left.T)
    X_true = _common_view_points(1, seed=9)
    good_left, good_right = _project_pair(rig, X_true)

    result = _triangulate(rig, np.vstack([pixels_left, good_left]), np.vstack([pixels_right, good_right]),
                          refine=refine)

    assert not result.valid[:2].any()
    assert np.isnan(result.X_left_mm[:2]).all()
    assert result.valid[2]
    np.testing.assert_allclose(result.X_left_mm[2], X_true[0], atol=1e-6)


# ---------------------------------------------------------------------------------------------------------
# Input validation
# ---------------------------------------------------------------------------------------------------------
def test_mismatched_pixel_counts_raise(rig):
    pixels_left, pixels_right = _project_pair(rig, _common_view_points(5, seed=10))
    with pytest.raises(ValueError, match="same number of points.*5 and 4"):
        _triangulate(rig, pixels_left, pixels_right[:4])


@pytest.mark.parametrize("bad_left, message", [
    (np.zeros((5, 3)), r"pixels_left must have shape \(N, 2\), got \(5, 3\)"),
    (np.zeros(2), r"pixels_left must have shape \(N, 2\), got \(2,\)"),
    (np.zeros((1, 5, 2)), r"pixels_left must have shape \(N, 2\), got \(1, 5, 2\)"),
])
def test_wrong_pixel_shapes_raise(rig, bad_left, message):
    with pytest.raises(ValueError, match=message):
        _triangulate(rig, bad_left, np.zeros((5, 2)))


def test_bad_stereo_pose_raises(rig):
    pixels_left, pixels_right = _project_pair(rig, _common_view_points(3, seed=11))
    R, T = rig.R_right_from_left, rig.T_right_from_left_mm
    with pytest.raises(ValueError, match="not a proper rotation"):
        triangulate(rig.left, rig.right, 1.01 * R, T, pixels_left, pixels_right)
    with pytest.raises(ValueError, match="not a proper rotation"):
        triangulate(rig.left, rig.right, R @ np.diag([1.0, 1.0, -1.0]), T, pixels_left, pixels_right)
    with pytest.raises(ValueError, match=r"T_right_from_left_mm must have shape \(3,\)"):
        triangulate(rig.left, rig.right, R, T[:2], pixels_left, pixels_right)
    with pytest.raises(ValueError, match="no baseline"):
        triangulate(rig.left, rig.right, R, np.zeros(3), pixels_left, pixels_right)


def test_empty_input_gives_empty_result(rig):
    result = _triangulate(rig, np.zeros((0, 2)), np.zeros((0, 2)))
    assert result.X_left_mm.shape == (0, 3) and result.valid.shape == (0,)


# ---------------------------------------------------------------------------------------------------------
# Speed
# ---------------------------------------------------------------------------------------------------------
def test_hundred_thousand_points_are_triangulated_at_the_noise_floor(rig):
    """100k noisy points in one call (the time is printed, never asserted): every point valid and finite, and
    the RMS 3D error equals the first-order prediction sigma^2 (J^T J)^-1 (statistical spread ~0.2 % at this
    count; 3 % allows the first-order approximation, as the 4000-point test allows 8 % for its spread)."""
    n = 100_000
    X_true = _common_view_points(n, seed=12)
    pixels_left, pixels_right = _project_pair(rig, X_true)
    rng = np.random.default_rng(13)
    pixels_left += rng.normal(0, PIXEL_SIGMA_PX, pixels_left.shape)
    pixels_right += rng.normal(0, PIXEL_SIGMA_PX, pixels_right.shape)
    _triangulate(rig, pixels_left[:10], pixels_right[:10])  # JIT warm-up of the undistortion

    start = time.perf_counter()
    result = _triangulate(rig, pixels_left, pixels_right)
    elapsed_s = time.perf_counter() - start

    rms_mm = np.sqrt(np.mean(np.sum((result.X_left_mm - X_true) ** 2, axis=1)))
    cov = triangulation_covariance_mm2(rig.left, rig.right, rig.R_right_from_left, rig.T_right_from_left_mm,
                                       X_true, PIXEL_SIGMA_PX)
    predicted_rms_mm = np.sqrt(np.mean(np.trace(cov, axis1=1, axis2=2)))
    print(f"\n{n} points triangulated (refined) in {elapsed_s:.2f} s; RMS 3D error {rms_mm * 1e3:.2f} um "
          f"(predicted {predicted_rms_mm * 1e3:.2f} um)")
    assert result.valid.all()
    assert np.isfinite(result.X_left_mm).all()
    assert rms_mm == pytest.approx(predicted_rms_mm, rel=0.03)


# ---------------------------------------------------------------------------------------------------------
# Plane fitting
# ---------------------------------------------------------------------------------------------------------
def _plane_points(n: int, normal: np.ndarray, d_mm: float, sigma_mm: float, seed: int) -> np.ndarray:
    """Points scattered over a 60 x 50 mm patch of the plane normal . X = d_mm, with N(0, sigma) along normal."""
    rng = np.random.default_rng(seed)
    e1 = np.cross(normal, [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(normal, e1)
    a, b = rng.uniform(-30, 30, n), rng.uniform(-25, 25, n)
    return (d_mm * normal + a[:, None] * e1 + b[:, None] * e2
            + rng.normal(0.0, sigma_mm, n)[:, None] * normal)


def _tilted_normal() -> np.ndarray:
    normal = np.array([0.2, -0.3, 1.0])
    return normal / np.linalg.norm(normal)


def test_fit_plane_exact_plane():
    normal_true, d_true = _tilted_normal(), 350.0
    points = _plane_points(100, normal_true, d_true, 0.0, seed=14)
    normal, d_mm, distances_mm = fit_plane(points)
    np.testing.assert_allclose(normal, normal_true, atol=1e-12)  # orientation: d_mm >= 0
    assert d_mm == pytest.approx(d_true, abs=1e-10)
    assert np.abs(distances_mm).max() < 1e-10
    # Reversing the orientation convention's input does not flip the answer.
    normal_flipped, d_flipped, _ = fit_plane(points[::-1])
    np.testing.assert_allclose(normal_flipped, normal_true, atol=1e-12)
    assert d_flipped == pytest.approx(d_true, abs=1e-10)


def test_fit_plane_with_gaussian_scatter():
    sigma_mm, n = 0.0133, 5000
    normal_true, d_true = _tilted_normal(), 350.0
    points = _plane_points(n, normal_true, d_true, sigma_mm, seed=15)
    normal, d_mm, distances_mm = fit_plane(points)
    angle_rad = np.arccos(min(1.0, normal @ normal_true))
    rmse_mm = plane_fit_rmse_mm(points)
    max_mm = plane_fit_max_deviation_mm(points)
    print(f"\nplane fit: sigma {sigma_mm * 1e3:.1f} um -> RMSE {rmse_mm * 1e3:.2f} um, max {max_mm * 1e3:.1f} um, "
          f"normal error {angle_rad:.1e} rad")
    # Expected normal error ~ sigma / (17 mm sqrt(n)) ~ 1e-5 rad; offset error ~ sigma / sqrt(n) ~ 2e-4 mm.
    assert angle_rad < 1e-4
    assert d_mm == pytest.approx(d_true, abs=2e-3)
    assert rmse_mm == pytest.approx(sigma_mm, rel=0.05)  # spread of the estimate ~1 %
    assert rmse_mm == pytest.approx(np.sqrt(np.mean(distances_mm ** 2)))
    assert 3 * sigma_mm < max_mm < 5 * sigma_mm


def test_fit_plane_ignores_nan_rows():
    points = _plane_points(50, _tilted_normal(), 350.0, 0.01, seed=16)
    with_nan = np.vstack([points[:10], [[np.nan, 0.0, 0.0]], points[10:]])
    normal, d_mm, distances_mm = fit_plane(with_nan)
    normal_ref, d_ref, distances_ref = fit_plane(points)
    np.testing.assert_allclose(normal, normal_ref, atol=1e-12)
    assert d_mm == pytest.approx(d_ref, abs=1e-10)
    assert np.isnan(distances_mm[10])
    np.testing.assert_allclose(np.delete(distances_mm, 10), distances_ref, atol=1e-10)


def test_fit_plane_rejects_degenerate_input():
    with pytest.raises(ValueError, match="at least 3 finite points"):
        fit_plane(np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 1.0], [np.nan, 0.0, 0.0]]))
    line = np.outer(np.linspace(0, 10, 20), [1.0, 2.0, 3.0])
    with pytest.raises(ValueError, match="collinear"):
        fit_plane(line)
    with pytest.raises(ValueError, match=r"points_mm must have shape \(N, 3\)"):
        fit_plane(np.zeros((10, 2)))


def test_unconverged_refinement_gives_invalid_points(rig):
    X_true = _common_view_points(100, seed=17)
    pixels_left, pixels_right = _project_pair(rig, X_true)
    rng = np.random.default_rng(18)
    pixels_left += rng.normal(0, PIXEL_SIGMA_PX, pixels_left.shape)
    pixels_right += rng.normal(0, PIXEL_SIGMA_PX, pixels_right.shape)
    # From the midpoint, the first Gauss-Newton update of a noisy point is ~1e-6 mm, far above a 1e-12 mm xtol
    # and it promises far more than rounding: after a single iteration no point can have been declared
    # converged, so none may be reported.
    one_step = _triangulate(rig, pixels_left, pixels_right, max_iter=1, xtol_mm=1e-12)
    assert not one_step.valid.any()
    assert np.isnan(one_step.X_left_mm).all() and np.isnan(one_step.reprojection_error_px).all()
    # A few iterations suffice for every point.
    assert _triangulate(rig, pixels_left, pixels_right, max_iter=3).valid.all()


def test_inconsistent_rays_of_real_images_are_all_triangulated_at_the_reprojection_optimum():
    """Matches with 0.1-5 px of disagreement between the two cameras (real images: detection noise, an imperfect
    calibration) are every one triangulated, at the least-squares optimum of the reprojection error found
    independently by SciPy's least_squares (within 1e-6 mm; the old 1e-9 mm step test dropped ~15 % at 1 px)."""
    from scipy.optimize import least_squares

    from workbench.rigs import paper_rig

    rig = paper_rig(1.0)
    rng = np.random.default_rng(7)
    X = np.column_stack([rng.uniform(-40, 40, 3000), rng.uniform(-15, 15, 3000), rng.uniform(360, 390, 3000)])
    R, T = rig.R_right_from_left, rig.T_right_from_left_mm
    for noise_px in (0.1, 1.0, 5.0):
        pl = rig.left.project(X) + noise_px * rng.standard_normal((len(X), 2))
        pr = rig.right.project(X @ R.T + T) + noise_px * rng.standard_normal((len(X), 2))
        tri = triangulate(rig.left, rig.right, R, T, pl, pr)
        assert tri.valid.all(), f"{(~tri.valid).sum()} of {len(X)} points dropped at {noise_px} px"
        for i in rng.choice(len(X), 20, replace=False):
            def residual(p):
                return np.concatenate([rig.left.project(p[None])[0] - pl[i],
                                       rig.right.project((p @ R.T + T)[None])[0] - pr[i]])
            ref = least_squares(residual, X[i], xtol=1e-15, ftol=1e-15, gtol=1e-15).x
            assert np.linalg.norm(tri.X_left_mm[i] - ref) < 1e-6
