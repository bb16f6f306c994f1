"""Stereo triangulation with Scheimpflug tilt and lens distortion (the paper's §3), and plane fitting.

Frames and units
----------------
The left camera frame is the reference ("world") frame. A point ``X_left_mm`` in that frame is at

    X_right_mm = R_right_from_left @ X_left_mm + T_right_from_left_mm

in the right camera frame (OpenCV's ``stereoCalibrate`` convention). Lengths are in mm, image coordinates in
pixels (OpenCV convention, see :mod:`measurement.camera`).

Method
------
1. *Midpoint.* Each pixel is back-projected to its ray with
   :meth:`~measurement.camera.ScheimpflugCamera.backproject`, which undoes the intrinsics, the Scheimpflug tilt
   and the Brown distortion exactly. The initial estimate is the midpoint of the shortest segment between the
   left and right rays, expressed in the left frame; that segment's length is ``ray_gap_mm``.
2. *Optimal (reprojection) refinement.* Starting from the midpoint, the point minimising::

       |project_left(X) - p_left|^2 + |project_right(R X + T) - p_right|^2

   is found with a few Gauss-Newton iterations per point (analytic 4 x 3 Jacobians, 3 x 3 normal equations
   solved in closed form, all points at once). This is the "optimal" / bundle-adjustment triangulation of the
   paper: with Gaussian pixel noise it is the maximum-likelihood estimate of the point.

A point that cannot be triangulated (non-finite pixels, rays that do not back-project, (near-)parallel rays,
an intersection behind either camera, a refinement that does not converge) comes back as NaN with
``valid = False``; it never produces a silently wrong number, and it never affects the other points.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from measurement.camera import ScheimpflugCamera, tilt_homography

#: Rays meeting at a smaller angle than this (degrees) are treated as parallel: the point is not triangulated.
DEFAULT_MIN_RAY_ANGLE_DEG = 0.1
#: Gauss-Newton stops for a point once its update is shorter than this (mm): 1 nm, far below any DIC precision.
#: (1e-9 mm, the old value, sits at the rounding level of a point 400 mm away: on real images with 0.1-1 px
#: residuals 15-27 % of the points never got there and were dropped as not converged.)
DEFAULT_XTOL_MM = 1e-6
#: ... or once the decrease of the squared reprojection error its update promises is below this fraction of
#: that error (float64 rounding: no step can do better; the cost test would only see rounding noise).
_RELATIVE_DECREASE_TOL = 1e-12
#: Gauss-Newton iterations after which a point that still moves is declared not converged.
DEFAULT_MAX_ITER = 20
#: Step halvings tried when a Gauss-Newton step would increase a point's reprojection cost.
_MAX_STEP_HALVINGS = 12
#: Rotation matrices further than this from orthonormal (max |R^T R - I|) are refused.
_ROTATION_TOL = 1e-6


@dataclass(frozen=True)
class TriangulationResult:
    """Output of :func:`triangulate`.

    Attributes
    ----------
    X_left_mm : ndarray, shape (N, 3)
        Triangulated points in the left camera frame, mm; NaN rows where ``valid`` is False.
    reprojection_error_px : ndarray, shape (N,)
        Per-point RMS of the two reprojection residuals, ``sqrt((|r_left|^2 + |r_right|^2) / 2)``, px;
        NaN where ``valid`` is False.
    ray_gap_mm : ndarray, shape (N,)
        Distance between the left and right rays at closest approach, mm (independent of refinement).
        Finite wherever both rays exist and are not parallel, even if the point is invalid for another
        reason (e.g. it lies behind a camera); NaN otherwise.
    valid : ndarray of bool, shape (N,)
        True where the point was triangulated.
    """

    X_left_mm: np.ndarray
    reprojection_error_px: np.ndarray
    ray_gap_mm: np.ndarray
    valid: np.ndarray


# --------------------------------------------------------------------------------------------------------
# Input checks
# --------------------------------------------------------------------------------------------------------
def _check_points(name: str, points, n_cols: int) -> np.ndarray:
    """``points`` as a float array of shape (N, n_cols); ValueError naming ``name`` otherwise."""
    points = np.asarray(points, dtype=float)
    if points.ndim != 2 or points.shape[1] != n_cols:
        raise ValueError(f"{name} must have shape (N, {n_cols}), got {points.shape}")
    return points


def check_stereo_pose(R_right_from_left, T_right_from_left_mm) -> tuple[np.ndarray, np.ndarray]:
    """Validated ``(R (3, 3), T_mm (3,))``: R a proper rotation, both finite."""
    R = np.asarray(R_right_from_left, dtype=float)
    T = np.asarray(T_right_from_left_mm, dtype=float)
    if R.shape != (3, 3):
        raise ValueError(f"R_right_from_left must have shape (3, 3), got {R.shape}")
    if T.shape != (3,):
        raise ValueError(f"T_right_from_left_mm must have shape (3,), got {T.shape}")
    if not (np.all(np.isfinite(R)) and np.all(np.isfinite(T))):
        raise ValueError("R_right_from_left and T_right_from_left_mm must be finite")
    orthonormality = np.max(np.abs(R.T @ R - np.eye(3)))
    if orthonormality > _ROTATION_TOL or np.linalg.det(R) <= 0:
        raise ValueError(
            f"R_right_from_left is not a proper rotation (max |R^T R - I| = {orthonormality:.2e}, "
            f"det = {np.linalg.det(R):.6f})")
    if not np.linalg.norm(T) > 0:
        raise ValueError("T_right_from_left_mm is zero: the two camera centres coincide (no baseline)")
    return R, T


def _check_pixel_pair(pixels_left, pixels_right) -> tuple[np.ndarray, np.ndarray]:
    """Validated (N, 2) float pixel arrays of equal length."""
    pixels_left = _check_points("pixels_left", pixels_left, 2)
    pixels_right = _check_points("pixels_right", pixels_right, 2)
    if len(pixels_left) != len(pixels_right):
        raise ValueError(
            f"pixels_left and pixels_right must have the same number of points, got {len(pixels_left)} "
            f"and {len(pixels_right)}")
    return pixels_left, pixels_right


# --------------------------------------------------------------------------------------------------------
# Rays and the midpoint
# --------------------------------------------------------------------------------------------------------
def _camera_rays(camera: ScheimpflugCamera, pixels_px: np.ndarray) -> np.ndarray:
    """Unit rays through ``pixels_px`` in that camera's frame, (N, 2) -> (N, 3); NaN for non-finite pixels."""
    rays = np.full((len(pixels_px), 3), np.nan)
    finite = np.all(np.isfinite(pixels_px), axis=1)
    if finite.any():
        rays[finite] = camera.rays(pixels_px[finite])
    return rays


def closest_approach(centre_a_mm, direction_a, centre_b_mm, direction_b):
    """Closest approach of two families of lines ``c + s d`` (unit ``d``).

    Parameters
    ----------
    centre_a_mm, centre_b_mm : array, shape (3,) or (N, 3), mm
        Points on the lines (the camera centres).
    direction_a, direction_b : ndarray, shape (N, 3)
        Unit direction vectors.

    Returns
    -------
    midpoint_mm : ndarray, shape (N, 3)
        Midpoint of the shortest segment between the two lines, mm.
    gap_mm : ndarray, shape (N,)
        Length of that segment, mm.
    s_mm, u_mm : ndarray, shape (N,)
        Signed distances along ``direction_a`` and ``direction_b`` from the centres to the segment's ends, mm
        (negative: the closest point lies behind the centre).
    sin2_angle : ndarray, shape (N,)
        ``sin^2`` of the angle between the lines (0 for parallel lines, where the other outputs are inf/NaN).
    """
    w = np.asarray(centre_a_mm, float) - np.asarray(centre_b_mm, float)
    b = np.sum(direction_a * direction_b, axis=-1)
    d = np.sum(direction_a * w, axis=-1)
    e = np.sum(direction_b * w, axis=-1)
    sin2_angle = 1.0 - b * b
    with np.errstate(divide="ignore", invalid="ignore"):
        s_mm = (b * e - d) / sin2_angle
        u_mm = (e - b * d) / sin2_angle
        end_a = centre_a_mm + s_mm[:, None] * direction_a
        end_b = centre_b_mm + u_mm[:, None] * direction_b
        return 0.5 * (end_a + end_b), np.linalg.norm(end_a - end_b, axis=-1), s_mm, u_mm, sin2_angle


# --------------------------------------------------------------------------------------------------------
# Projection, its Jacobian, residuals
# --------------------------------------------------------------------------------------------------------
def projection_jacobian(camera: ScheimpflugCamera, X_cam_mm: np.ndarray) -> np.ndarray:
    """Analytic Jacobian of :meth:`ScheimpflugCamera.project` with respect to the camera-frame point.

    Chains normalisation (eq 1), Brown distortion (eq 7, with the r^6 term k3 and the thin prism s1-s4), the
    Scheimpflug homography of the camera's own ``tilt_model`` (eqs 3-6 for ``"rmm"``, OpenCV's for ``"opencv"``) and K with its skew (eq 2).

    Parameters
    ----------
    camera : ScheimpflugCamera
    X_cam_mm : ndarray, shape (N, 3), mm
        Points in the camera frame, ``Z > 0``.

    Returns
    -------
    ndarray, shape (N, 2, 3), px / mm
        ``J[i, a, b] = d pixel_a / d X_b`` at point ``i``; NaN where ``Z <= 0``.
    """
    X_cam_mm = _check_points("X_cam_mm", X_cam_mm, 3)
    X, Y, Z = X_cam_mm[:, 0], X_cam_mm[:, 1], X_cam_mm[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        inv_z = np.where(Z > 0, 1.0 / Z, np.nan)
    x, y = X * inv_z, Y * inv_z
    # distortion: D = d(x_d, y_d) / d(x, y), as in the Newton inversion of measurement.camera
    k1, k2, k3, p1, p2 = camera.k1, camera.k2, camera.k3, camera.p1, camera.p2
    r2 = x * x + y * y
    radial = 1.0 + k1 * r2 + k2 * r2 * r2 + k3 * r2 * r2 * r2
    dradial = 2.0 * k1 + 4.0 * k2 * r2 + 6.0 * k3 * r2 * r2
    D00 = radial + x * dradial * x + 2.0 * p1 * y + 6.0 * p2 * x
    D01 = x * dradial * y + 2.0 * p1 * x + 2.0 * p2 * y
    D10 = y * dradial * x + 2.0 * p2 * y + 2.0 * p1 * x
    D11 = radial + y * dradial * y + 2.0 * p2 * x + 6.0 * p1 * y
    if camera.has_thin_prism:            # x_d += s1 r^2 + s2 r^4, y_d += s3 r^2 + s4 r^4
        gx = 2.0 * camera.s1 + 4.0 * camera.s2 * r2
        gy = 2.0 * camera.s3 + 4.0 * camera.s4 * r2
        D00, D01 = D00 + gx * x, D01 + gx * y
        D10, D11 = D10 + gy * x, D11 + gy * y
    # tilt homography (the camera's own parametrisation), then K:
    # (x_t, y_t) = (h0 / h2, h1 / h2) with h = H [x_d, y_d, 1]; u = fx x_t + skew y_t + cx, v = fy y_t + cy
    xy_d = camera.distort(np.stack([x, y], axis=-1))
    H = tilt_homography(camera.alpha_rad, camera.beta_rad, camera.tilt_model)
    h = xy_d @ H[:, :2].T + H[:, 2]
    inv_h2 = 1.0 / h[:, 2]
    # T[t][c] h2 = d(x_t, y_t)_t / d(x_d, y_d)_c (the common 1 / h2 is applied last, as before skew existed, so
    # that a camera without skew gives bit-identical Jacobians)
    T = [[H[t, c] - h[:, t] * inv_h2 * H[2, c] for c in (0, 1)] for t in (0, 1)]
    K = camera.K
    J = np.empty((len(X), 2, 3))
    for row in (0, 1):
        # M = d(pixel_row) / d(x_d, y_d) = K[row, :2] @ T / h2
        M0 = (K[row, 0] * T[0][0] + K[row, 1] * T[1][0]) * inv_h2
        M1 = (K[row, 0] * T[0][1] + K[row, 1] * T[1][1]) * inv_h2
        # (M D) then the normalisation d(x, y) / d(X, Y, Z) = [[1, 0, -x], [0, 1, -y]] / Z
        MD0 = M0 * D00 + M1 * D10
        MD1 = M0 * D01 + M1 * D11
        J[:, row, 0] = MD0 * inv_z
        J[:, row, 1] = MD1 * inv_z
        J[:, row, 2] = -(MD0 * x + MD1 * y) * inv_z
    return J


def _reprojection_residuals_px(left, right, R, T, X_left_mm, pixels_left, pixels_right) -> np.ndarray:
    """Predicted minus observed pixels, ``[du_l, dv_l, du_r, dv_r]``, shape (N, 4), px."""
    predicted_left = left.project(X_left_mm)
    predicted_right = right.project(X_left_mm @ R.T + T)
    return np.concatenate([predicted_left - pixels_left, predicted_right - pixels_right], axis=1)


def stacked_jacobian(left, right, R, T, X_left_mm) -> np.ndarray:
    """Jacobian of the stacked residuals with respect to ``X_left_mm``, shape (N, 4, 3), px / mm."""
    J_left = projection_jacobian(left, X_left_mm)
    J_right = projection_jacobian(right, X_left_mm @ R.T + T) @ R  # (N, 2, 3) @ (3, 3)
    return np.concatenate([J_left, J_right], axis=1)


def _solve_3x3(A: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Solve ``A x = b`` for a stack of 3 x 3 systems by Cramer's rule, (N, 3, 3), (N, 3) -> (N, 3).

    Rows with a singular (or non-finite) system give NaN instead of raising for the whole stack.
    """
    c0 = np.cross(A[:, 1], A[:, 2])
    c1 = np.cross(A[:, 2], A[:, 0])
    c2 = np.cross(A[:, 0], A[:, 1])
    det = np.sum(A[:, 0] * c0, axis=-1)
    with np.errstate(divide="ignore", invalid="ignore"):
        # inverse of A is [c0 c1 c2] / det (columns), so x = (b0 c0 + b1 c1 + b2 c2) / det
        x = (b[:, 0:1] * c0 + b[:, 1:2] * c1 + b[:, 2:3] * c2) / det[:, None]
    x[~(det != 0)] = np.nan
    return x


def _refine_gauss_newton(left, right, R, T, X_left_mm, pixels_left, pixels_right, xtol_mm, max_iter):
    """Minimise the summed squared reprojection error per point, starting from ``X_left_mm`` (N, 3).

    Parameters: the stereo model as in :func:`triangulate`; ``X_left_mm`` (N, 3) mm start points (finite);
    ``pixels_left``, ``pixels_right`` (N, 2) px observations.

    Returns the refined points (N, 3) mm and a (N,) bool array, True where the iteration converged within
    ``max_iter`` iterations: the full Gauss-Newton update fell below ``xtol_mm``, or the cost decrease it
    promises (``step^T J^T J step``) is at float64 rounding level of the cost (then the point is at its optimum
    and a cost comparison would only compare rounding noise). Points that did not converge are NaN or left at
    their last iterate; the caller must not use them.
    """
    X = X_left_mm.copy()
    converged = np.zeros(len(X), dtype=bool)
    active = np.arange(len(X))
    for _ in range(max_iter):
        if active.size == 0:
            break
        Xa, pl, pr = X[active], pixels_left[active], pixels_right[active]
        r = _reprojection_residuals_px(left, right, R, T, Xa, pl, pr)
        J = stacked_jacobian(left, right, R, T, Xa)
        H = np.einsum("nki,nkj->nij", J, J)
        step = -_solve_3x3(H, np.einsum("nki,nk->ni", J, r))
        gn_step_mm = np.linalg.norm(step, axis=1)
        cost_now = np.sum(r * r, axis=1)
        promised = np.einsum("ni,nij,nj->n", step, H, step)
        # Converged: the full Gauss-Newton update is negligible, or what it could gain is below rounding (apply
        # it; no cost test at rounding level).
        with np.errstate(invalid="ignore"):
            done = (gn_step_mm <= xtol_mm) | (promised <= _RELATIVE_DECREASE_TOL * cost_now)
        X[active[done]] = Xa[done] + step[done]
        converged[active[done]] = True
        # Otherwise take the step, halved where it would increase the cost (never needed near the optimum).
        # A step that no halving makes downhill, or a singular system (NaN step), is a failure.
        search = np.flatnonzero(np.isfinite(gn_step_mm) & ~done)
        cost = cost_now[search]
        scale = 1.0
        accepted = np.zeros(len(active), dtype=bool)
        for _ in range(_MAX_STEP_HALVINGS):
            if search.size == 0:
                break
            trial = Xa[search] + scale * step[search]
            r_trial = _reprojection_residuals_px(left, right, R, T, trial, pl[search], pr[search])
            better = np.sum(r_trial * r_trial, axis=1) <= cost
            X[active[search[better]]] = trial[better]
            accepted[search[better]] = True
            search, cost, scale = search[~better], cost[~better], 0.5 * scale
        failed = ~done & ~accepted
        X[active[failed]] = np.nan
        active = active[~done & ~failed]
    return X, converged


# --------------------------------------------------------------------------------------------------------
# Public API
# --------------------------------------------------------------------------------------------------------
def triangulate(left: ScheimpflugCamera, right: ScheimpflugCamera, R_right_from_left, T_right_from_left_mm,
                pixels_left, pixels_right, refine: bool = True, *,
                min_ray_angle_deg: float = DEFAULT_MIN_RAY_ANGLE_DEG, xtol_mm: float = DEFAULT_XTOL_MM,
                max_iter: int = DEFAULT_MAX_ITER) -> TriangulationResult:
    """Triangulate matched pixels of a Scheimpflug stereo rig into left-frame 3D points.

    Parameters
    ----------
    left, right : ScheimpflugCamera
        The two cameras (tilt and distortion included).
    R_right_from_left : array, shape (3, 3)
        Rotation with ``X_right = R X_left + T``.
    T_right_from_left_mm : array, shape (3,), mm
        Translation of the same transform.
    pixels_left, pixels_right : array, shape (N, 2), px
        Matched image points ``(u, v)`` in the left and right images. Non-finite rows give invalid points.
    refine : bool
        If True (default), refine the ray midpoint by minimising the reprojection error in both images
        (optimal triangulation); if False, return the midpoint.
    min_ray_angle_deg : float, degrees
        Rays meeting at a smaller angle are treated as parallel (invalid point).
    xtol_mm : float, mm
        Gauss-Newton convergence threshold on the per-point update.
    max_iter : int
        Gauss-Newton iterations after which a point that still moves is invalid.

    Returns
    -------
    TriangulationResult
        ``X_left_mm`` (N, 3), ``reprojection_error_px`` (N,), ``ray_gap_mm`` (N,), ``valid`` (N,).

    Raises
    ------
    ValueError
        If the pixel arrays are not (N, 2) or differ in length, or the pose is not a proper rotation and a
        non-zero finite translation.
    """
    R, T = check_stereo_pose(R_right_from_left, T_right_from_left_mm)
    pixels_left, pixels_right = _check_pixel_pair(pixels_left, pixels_right)
    if not 0 < min_ray_angle_deg < 90:
        raise ValueError(f"min_ray_angle_deg must be in (0, 90) degrees, got {min_ray_angle_deg}")
    if not xtol_mm > 0:
        raise ValueError(f"xtol_mm must be positive, got {xtol_mm}")
    if int(max_iter) != max_iter or max_iter < 1:
        raise ValueError(f"max_iter must be a positive integer, got {max_iter}")

    rays_left = _camera_rays(left, pixels_left)
    rays_right_in_left = _camera_rays(right, pixels_right) @ R  # R^T d for each row
    centre_right_in_left_mm = -R.T @ T
    X, gap_mm, s_mm, u_mm, sin2_angle = closest_approach(
        np.zeros(3), rays_left, centre_right_in_left_mm, rays_right_in_left)

    rays_ok = np.all(np.isfinite(rays_left), axis=1) & np.all(np.isfinite(rays_right_in_left), axis=1)
    crossing = rays_ok & (sin2_angle > np.sin(np.deg2rad(min_ray_angle_deg)) ** 2)
    valid = crossing & (s_mm > 0) & (u_mm > 0)
    gap_mm = np.where(crossing, gap_mm, np.nan)
    X[~valid] = np.nan

    if refine and valid.any():
        idx = np.flatnonzero(valid)
        X_refined, converged = _refine_gauss_newton(
            left, right, R, T, X[idx], pixels_left[idx], pixels_right[idx], xtol_mm, int(max_iter))
        X[idx] = X_refined
        valid[idx[~converged]] = False
    # The (refined) point must lie in front of both cameras.
    with np.errstate(invalid="ignore"):
        valid &= (X[:, 2] > 0) & ((X @ R.T + T)[:, 2] > 0)
    X[~valid] = np.nan

    residuals = _reprojection_residuals_px(left, right, R, T, X, pixels_left, pixels_right)
    reprojection_error_px = np.sqrt(0.5 * np.sum(residuals * residuals, axis=1))
    reprojection_error_px[~valid] = np.nan
    return TriangulationResult(X_left_mm=X, reprojection_error_px=reprojection_error_px, ray_gap_mm=gap_mm,
                               valid=valid)


def triangulation_covariance_mm2(left: ScheimpflugCamera, right: ScheimpflugCamera, R_right_from_left,
                                 T_right_from_left_mm, X_left_mm, pixel_sigma_px: float) -> np.ndarray:
    """First-order covariance of optimal triangulation under isotropic Gaussian pixel noise.

    ``Cov = sigma^2 (J^T J)^-1`` with ``J`` the (4, 3) Jacobian of both projections at the point.

    Parameters
    ----------
    left, right : ScheimpflugCamera
    R_right_from_left : array, shape (3, 3)
    T_right_from_left_mm : array, shape (3,), mm
    X_left_mm : array, shape (N, 3), mm
        True (or estimated) points in the left frame.
    pixel_sigma_px : float, px
        Standard deviation of each pixel coordinate in both images.

    Returns
    -------
    ndarray, shape (N, 3, 3), mm^2
        Covariance of each triangulated point in the left frame; NaN for points behind a camera.
    """
    R, T = check_stereo_pose(R_right_from_left, T_right_from_left_mm)
    X_left_mm = _check_points("X_left_mm", X_left_mm, 3)
    if not (np.isfinite(pixel_sigma_px) and pixel_sigma_px >= 0):
        raise ValueError(f"pixel_sigma_px must be finite and non-negative, got {pixel_sigma_px}")
    J = stacked_jacobian(left, right, R, T, X_left_mm)
    normal = np.swapaxes(J, 1, 2) @ J
    cov = np.full(normal.shape, np.nan)
    ok = np.all(np.isfinite(normal), axis=(1, 2))
    if ok.any():
        cov[ok] = pixel_sigma_px ** 2 * np.linalg.inv(normal[ok])
    return cov


def fit_plane(points_mm) -> tuple[np.ndarray, float, np.ndarray]:
    """Total-least-squares plane through 3D points (SVD of the centred points).

    The plane is ``{X : normal . X = d_mm}``. The normal is oriented so that ``d_mm >= 0`` (it points from
    the origin, i.e. the left camera centre, towards the plane; ``d_mm`` is then the plane's distance from
    the origin); for a plane through the origin, so that its largest component is positive.

    Parameters
    ----------
    points_mm : array, shape (N, 3), mm
        Points; rows with a non-finite coordinate are ignored (their distance is NaN).

    Returns
    -------
    normal : ndarray, shape (3,)
        Unit normal.
    d_mm : float, mm
        Offset of the plane along ``normal``.
    signed_distances_mm : ndarray, shape (N,), mm
        ``normal . X_i - d_mm``, NaN for ignored rows.

    Raises
    ------
    ValueError
        If fewer than 3 finite points remain, or they are (nearly) collinear so no plane is defined.
    """
    points_mm = _check_points("points_mm", points_mm, 3)
    finite = np.all(np.isfinite(points_mm), axis=1)
    if finite.sum() < 3:
        raise ValueError(f"fit_plane needs at least 3 finite points, got {int(finite.sum())} of {len(points_mm)}")
    P = points_mm[finite]
    centroid = P.mean(axis=0)
    _, singular_values, Vt = np.linalg.svd(P - centroid, full_matrices=False)
    if not singular_values[1] > 1e-9 * singular_values[0]:
        raise ValueError(
            "fit_plane: the points are (nearly) collinear or coincident, so no plane is defined "
            f"(singular values of the centred points {singular_values})")
    normal = Vt[2]
    d_mm = float(normal @ centroid)
    if d_mm < 0 or (d_mm == 0 and normal[np.argmax(np.abs(normal))] < 0):
        normal, d_mm = -normal, -d_mm
    return normal, d_mm, points_mm @ normal - d_mm


def plane_fit_rmse_mm(points_mm) -> float:
    """RMS of the perpendicular distances of ``points_mm`` (N, 3) to their best-fit plane, mm."""
    distances = fit_plane(points_mm)[2]
    return float(np.sqrt(np.nanmean(distances ** 2)))


def plane_fit_max_deviation_mm(points_mm) -> float:
    """Largest absolute perpendicular distance of ``points_mm`` (N, 3) from their best-fit plane, mm."""
    return float(np.nanmax(np.abs(fit_plane(points_mm)[2])))
