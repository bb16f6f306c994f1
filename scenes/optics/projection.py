"""Exact per-pixel geometric truth (truth side, numpy, no Monte Carlo, never imports ``measurement/``).

The renderer (:mod:`scenes.optics.camera`) traces rays through a tilted sensor; this module evaluates the same
geometry in float64 numpy so that the truth of a DIC point does not depend on sampling:

* :func:`pixel_rays` -- the ray of a (sub)pixel in the world frame. For the pinhole it is the ray through
  the pinhole; for the thin lens it is the *chief ray* (through the lens centre), which is what the
  position of a DIC point means: the renderer's thin-lens rays all converge on the chief ray's in-focus
  point, so the chief ray is the axis of the blur cone. Both are ``(x_n, y_n, 1)`` from the camera centre.
* :func:`project_points` -- the inverse: world points to pixels (used for in-view checks and to predict
  where a material point appears).
* :func:`intersect_front_face` / :func:`material_point_positions` / :func:`points_of_interest_truth` -- the
  DESIGN of the stereo-DIC truth: the left reference pixel's chief ray hits the undeformed specimen at the
  material point ``X0``; its truth in state k is ``R_k X0 + t_k`` (plus ``u_k(X0)`` once specimens deform).
* :func:`focal_length_for_focus_mm` / :func:`defocus_blur_px` -- thin-lens focusing on a world point and
  the blur-circle size of other points, from the renderer's focus rule ``1/z_o + 1/z_i = 1/F`` with the
  image distance ``z_i = v * p_z`` varying over the tilted sensor.

Conventions (README): camera frame x right, y down, z forward; ``X_cam = R_cam_from_world X_world + t``;
pixel centres at integer coordinates (OpenCV); lengths in mm. Sensor geometry (see :mod:`scenes.optics.camera`):
a pixel (u, v) sits at ``p = (0, 0, 1) + (u - cx)/fx e1 + (v - cy)/fy e2`` (units of the image distance),
``(x_d, y_d) = (p_x, p_y) / p_z`` is the distorted ideal-plane point and the lens model (Brown k1, k2, p1,
p2, plus OpenCV's k3 and thin prism s1..s4, which the instrument does not model) maps the undistorted
``(x_n, y_n)`` to it.
"""
from __future__ import annotations

from typing import Callable, Sequence

import numpy as np

from scenes.optics.camera import SensorSpec, distortion_terms

#: Fixed-point undistortion stops when the update is below this (ideal-plane units, ~1e-12 px).
_UNDISTORT_TOL = 1e-15
_UNDISTORT_MAX_ITERATIONS = 100


# ------------------------------------------------------------------------------------------------------------
# Sensor geometry
def _as_points(a, name: str, dim: int) -> np.ndarray:
    a = np.asarray(a, dtype=float)
    if a.ndim == 1 and a.shape[0] == dim:
        a = a[None]
    if a.ndim != 2 or a.shape[1] != dim:
        raise ValueError(f"{name} must be (N, {dim}), got shape {a.shape}")
    return a


def _pose(R, t_mm) -> tuple[np.ndarray, np.ndarray]:
    """Validated (3, 3) rotation and (3,) translation of a pose (any pair of frames)."""
    R = np.asarray(R, dtype=float)
    t = np.asarray(t_mm, dtype=float).reshape(-1)
    if R.shape != (3, 3) or t.shape != (3,):
        raise ValueError(f"pose must be a (3, 3) rotation and a (3,) translation, got {R.shape} and {t.shape}")
    if not np.allclose(R @ R.T, np.eye(3), atol=1e-9) or np.linalg.det(R) < 0:
        raise ValueError("a pose's R must be a proper rotation matrix")
    return R, t


def tilted_sensor_axes(alpha_deg: float, beta_deg: float) -> np.ndarray:
    """Sensor axes (e1, e2, normal) as columns in the camera frame: ``R_Y(beta) R_X(alpha)`` in float64.

    The same rotation the plugin builds with Mitsuba's transforms (:func:`scenes.optics.camera.sensor_axes`), which
    are float32: their axes are orthonormal only to ~1e-7, i.e. ~1e-4 px at fx = 10 900 px, so the truth
    uses the exact matrix.
    """
    a, b = np.deg2rad(alpha_deg), np.deg2rad(beta_deg)
    R_x = np.array([[1.0, 0.0, 0.0], [0.0, np.cos(a), -np.sin(a)], [0.0, np.sin(a), np.cos(a)]])
    R_y = np.array([[np.cos(b), 0.0, np.sin(b)], [0.0, 1.0, 0.0], [-np.sin(b), 0.0, np.cos(b)]])
    return R_y @ R_x


def distort(xy_n: np.ndarray, spec: SensorSpec) -> np.ndarray:
    """Lens distortion on the ideal plane (Brown k1, k2, p1, p2 plus OpenCV's k3 and thin prism s1..s4).

    Parameters
    ----------
    xy_n : (N, 2) float, undistorted normalised coordinates ``(X/Z, Y/Z)`` (unitless)
    spec : SensorSpec

    Returns
    -------
    (N, 2) float, distorted normalised coordinates (unitless), exactly OpenCV's ``x''``, ``y''``.
    """
    x, y = xy_n[:, 0], xy_n[:, 1]
    radial, dx, dy = distortion_terms(x, y, spec)
    return np.stack([x * radial + dx, y * radial + dy], axis=1)


def undistort(xy_d: np.ndarray, spec: SensorSpec) -> np.ndarray:
    """Inverse of :func:`distort` by the renderer's fixed-point iteration, run to float64 convergence.

    The error shrinks per step by about the slope of the distortion,
    ``|2 k1 r^2 + 4 k2 r^4 + 6 k3 r^6| + 2 |s| r`` (~0.02 at the paper rig's image corners, ~0.3 for a
    ~9 % wide-angle distortion at r = 0.5), so it converges in well under the iteration cap; points where
    it does not (where the distortion folds over) are NaN.

    Parameters
    ----------
    xy_d : (N, 2) float, distorted normalised coordinates (unitless)
    spec : SensorSpec

    Returns
    -------
    (N, 2) float, undistorted normalised coordinates; NaN rows where the iteration does not converge.
    """
    xd, yd = xy_d[:, 0], xy_d[:, 1]
    xn, yn = xd.copy(), yd.copy()
    for _ in range(_UNDISTORT_MAX_ITERATIONS):
        radial, dx, dy = distortion_terms(xn, yn, spec)
        xn_new, yn_new = (xd - dx) / radial, (yd - dy) / radial
        step = np.maximum(np.abs(xn_new - xn), np.abs(yn_new - yn))
        xn, yn = xn_new, yn_new
        if not np.any(step > _UNDISTORT_TOL):
            break
    out = np.stack([xn, yn], axis=1)
    out[np.any(~np.isfinite(out), axis=1) | (step > 1e-9)] = np.nan
    return out


def sensor_points(spec: SensorSpec, pixels_xy) -> np.ndarray:
    """Point of each pixel on the tilted virtual sensor, camera frame, units of the image distance.

    Parameters
    ----------
    spec : SensorSpec
    pixels_xy : (N, 2) float, px, OpenCV convention (pixel centres at integer coordinates)

    Returns
    -------
    (N, 3) float: ``(0, 0, 1) + (u - cx)/fx e1 + (v - cy)/fy e2``; its z is the relative image distance
    ``p_z`` of the thin lens (the sensor point sits ``v_mm * p_z`` behind the lens).
    """
    px = _as_points(pixels_xy, "pixels_xy", 2)
    axes = tilted_sensor_axes(spec.alpha_deg, spec.beta_deg)
    s = (px[:, 0] - spec.cx) / spec.fx
    t = (px[:, 1] - spec.cy) / spec.fy
    return np.array([0.0, 0.0, 1.0]) + s[:, None] * axes[:, 0] + t[:, None] * axes[:, 1]


def ideal_coordinates(spec: SensorSpec, pixels_xy) -> np.ndarray:
    """Undistorted ideal-plane coordinates ``(x_n, y_n)`` of pixels: the chief ray is ``(x_n, y_n, 1)``. (N, 2)."""
    p = sensor_points(spec, pixels_xy)
    with np.errstate(divide="ignore", invalid="ignore"):
        xy_d = p[:, :2] / p[:, 2:3]
    return undistort(xy_d, spec)


def pixel_rays(spec: SensorSpec, R_cam_from_world, t_cam_from_world_mm, pixels_xy
               ) -> tuple[np.ndarray, np.ndarray]:
    """World-frame rays of (sub)pixels: through the pinhole, or the chief ray of the thin lens.

    Parameters
    ----------
    spec : SensorSpec
        The camera as rendered (``spec.lens`` does not change the ray: the thin lens' chief ray passes
        through the lens centre, exactly like the pinhole ray).
    R_cam_from_world : (3, 3)
    t_cam_from_world_mm : (3,)
        Camera pose, ``X_cam = R X_world + t``.
    pixels_xy : (N, 2) float, px
        OpenCV convention: pixel centres at integer coordinates.

    Returns
    -------
    origins_world_mm : (N, 3) float
        The camera (lens) centre ``-R^T t``, repeated.
    directions_world : (N, 3) float
        Unit directions; NaN where the undistortion fails (far outside the image).
    """
    R, t = _pose(R_cam_from_world, t_cam_from_world_mm)
    xy = ideal_coordinates(spec, pixels_xy)
    d_cam = np.concatenate([xy, np.ones((len(xy), 1))], axis=1)
    d_cam /= np.linalg.norm(d_cam, axis=1, keepdims=True)
    origins = np.repeat((-R.T @ t)[None], len(xy), axis=0)
    return origins, d_cam @ R          # rows: R^T d


def project_points(spec: SensorSpec, R_cam_from_world, t_cam_from_world_mm, X_world_mm) -> np.ndarray:
    """Pixels (OpenCV convention) where world points are imaged along their chief ray.

    Parameters
    ----------
    X_world_mm : (N, 3) float, mm

    Returns
    -------
    (N, 2) float, px; NaN for points at or behind the lens plane (Z_cam <= 0).
    """
    R, t = _pose(R_cam_from_world, t_cam_from_world_mm)
    X = _as_points(X_world_mm, "X_world_mm", 3) @ R.T + t
    with np.errstate(divide="ignore", invalid="ignore"):
        xy_n = np.where(X[:, 2:3] > 0, X[:, :2] / X[:, 2:3], np.nan)
    xy_d = distort(xy_n, spec)
    # The distorted ray (x_d, y_d, 1) meets the tilted sensor plane n . (p - (0,0,1)) = 0.
    axes = tilted_sensor_axes(spec.alpha_deg, spec.beta_deg)
    e1, e2, n = axes[:, 0], axes[:, 1], axes[:, 2]
    ray = np.concatenate([xy_d, np.ones((len(xy_d), 1))], axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        lam = np.where(ray @ n > 0, n[2] / (ray @ n), np.nan)   # rays parallel to the sensor never reach it
    q = lam[:, None] * ray - np.array([0.0, 0.0, 1.0])
    return np.stack([spec.cx + spec.fx * (q @ e1), spec.cy + spec.fy * (q @ e2)], axis=1)


# ------------------------------------------------------------------------------------------------------------
# Thin-lens focus
def focal_length_for_focus_mm(spec: SensorSpec, R_cam_from_world, t_cam_from_world_mm, X_focus_world_mm) -> float:
    """Lens focal length F that images ``X_focus_world_mm`` sharply on this (tilted) sensor.

    The renderer focuses the sensor point ``p`` on depth ``z_o = 1 / (1/F - 1/(v p_z))`` along its chief
    ray (``v = fx * pixel_pitch_mm``). Solving at the pixel where the point is imaged gives
    ``F = 1 / (1/Z + 1/(v p_z))`` with Z the point's camera depth: exact even off the optical axis.

    Returns
    -------
    float, mm
    """
    X = _as_points(X_focus_world_mm, "X_focus_world_mm", 3)
    if len(X) != 1:
        raise ValueError("focus on one point")
    R, t = _pose(R_cam_from_world, t_cam_from_world_mm)
    Z = float((X @ R.T + t)[0, 2])
    if Z <= 0:
        raise ValueError(f"the focus point is behind the camera (Z = {Z:.3f} mm)")
    p_z = sensor_points(spec, project_points(spec, R, t, X))[0, 2]
    return 1.0 / (1.0 / Z + 1.0 / (spec.image_distance_mm * p_z))


def in_focus_points_world_mm(spec: SensorSpec, R_cam_from_world, t_cam_from_world_mm, pixels_xy) -> np.ndarray:
    """Points imaged sharply at the given pixels by the thin lens (its tilted plane of sharp focus), (N, 3) mm.

    The renderer's rule: pixel p focuses depth ``z_o = 1 / (1/F - 1/(v p_z))`` along its chief ray
    ``(x_n, y_n, 1)``. Without distortion these points lie on one plane (Scheimpflug); world frame.
    """
    if spec.lens != "thin":
        raise ValueError("only a thin lens has a plane of sharp focus")
    R, t = _pose(R_cam_from_world, t_cam_from_world_mm)
    p_z = sensor_points(spec, pixels_xy)[:, 2]
    z_o = 1.0 / (1.0 / spec.focal_length_mm - 1.0 / (spec.image_distance_mm * p_z))
    xy = ideal_coordinates(spec, pixels_xy)
    X_cam = np.concatenate([xy, np.ones((len(xy), 1))], axis=1) * z_o[:, None]
    return (X_cam - t) @ R           # rows: R^T (X_cam - t)


def defocus_blur_px(spec: SensorSpec, R_cam_from_world, t_cam_from_world_mm, X_world_mm) -> np.ndarray:
    """Diameter of the thin lens' blur circle of world points, in pixels (0 for a pinhole).

    The rays of the aperture (diameter ``F / N``) converge on the chief ray at the in-focus depth ``z_o``
    of the pixel where the point is imaged; at the point's own depth Z the cone is
    ``(F/N) |Z - z_o| / z_o`` mm wide, i.e. that times ``fx / Z`` pixels (object-side estimate that
    ignores the sensor tilt's few-percent stretch of the circle into an ellipse).

    Returns
    -------
    (N,) float, px
    """
    X = _as_points(X_world_mm, "X_world_mm", 3)
    if spec.lens != "thin":
        return np.zeros(len(X))
    R, t = _pose(R_cam_from_world, t_cam_from_world_mm)
    Z = (X @ R.T + t)[:, 2]
    p_z = sensor_points(spec, project_points(spec, R, t, X))[:, 2]
    z_in_focus = 1.0 / (1.0 / spec.focal_length_mm - 1.0 / (spec.image_distance_mm * p_z))
    aperture_mm = spec.focal_length_mm / spec.f_number
    return aperture_mm * np.abs(Z - z_in_focus) / z_in_focus * spec.fx / Z


# ------------------------------------------------------------------------------------------------------------
# Specimen truth
def intersect_front_face(origins_world_mm, directions_world, specimen, R_world_from_specimen,
                         t_world_from_specimen_mm) -> tuple[np.ndarray, np.ndarray]:
    """Where rays hit the undeformed front (speckled) face of a specimen; NaN where they miss it.

    The front face is the rectangle ``|x| <= length/2, |y| <= height/2, z = 0`` of the specimen frame,
    seen from ``z < 0`` (the rest of the solid lies at ``z >= 0``, so nothing can hide a hit). A ray
    counts only if it travels forwards (``lambda > 0``) and enters the face from the front.

    Parameters
    ----------
    origins_world_mm, directions_world : (N, 3) float
        Rays in the world frame (directions need not be unit).
    specimen : object with ``length_mm`` and ``height_mm`` (e.g. :class:`scenes.specimens.beam.BendingSpecimen`)
    R_world_from_specimen : (3, 3)
    t_world_from_specimen_mm : (3,)
        Pose ``X_world = R X_specimen + t``.

    Returns
    -------
    X_world_mm : (N, 3) float
    X_specimen_mm : (N, 3) float
        The material point (``z = 0``); both NaN for misses.
    """
    o = _as_points(origins_world_mm, "origins_world_mm", 3)
    d = _as_points(directions_world, "directions_world", 3)
    if len(o) != len(d):
        raise ValueError(f"{len(o)} origins but {len(d)} directions")
    R, t = _pose(R_world_from_specimen, t_world_from_specimen_mm)
    o_s = (o - t) @ R            # rows: R^T (o - t), specimen frame
    d_s = d @ R
    with np.errstate(divide="ignore", invalid="ignore"):
        lam = -o_s[:, 2] / d_s[:, 2]
    X_s = o_s + lam[:, None] * d_s
    X_s[:, 2] = 0.0               # exactly on the face (removes rounding of order 1e-14 mm)
    hit = (d_s[:, 2] > 0) & (o_s[:, 2] < 0) & (lam > 0) \
        & (np.abs(X_s[:, 0]) <= 0.5 * specimen.length_mm) & (np.abs(X_s[:, 1]) <= 0.5 * specimen.height_mm)
    X_s[~hit] = np.nan
    return X_s @ R.T + t, X_s


Pose = tuple[np.ndarray, np.ndarray]
Displacement = Callable[[np.ndarray], np.ndarray]


def material_point_positions(X_specimen_mm, poses: Sequence[Pose],
                             displacements_mm: Sequence[Displacement | None] | None = None) -> np.ndarray:
    """True world positions of material points in every state.

    Parameters
    ----------
    X_specimen_mm : (N, 3) float
        Material points in the (undeformed) specimen frame; NaN rows stay NaN.
    poses : sequence of K ``(R_world_from_specimen (3, 3), t_world_from_specimen_mm (3,))``
    displacements_mm : None, or K callables (or None entries) ``u(X_specimen (N, 3)) -> (N, 3)`` mm in the
        specimen frame, applied before the pose: ``X_world = R (X + u(X)) + t`` (same rule as
        :meth:`scenes.specimens.beam.BendingSpecimen.surfaces`).

    Returns
    -------
    (K, N, 3) float, mm, world frame
    """
    X = _as_points(X_specimen_mm, "X_specimen_mm", 3)
    if displacements_mm is not None and len(displacements_mm) != len(poses):
        raise ValueError(f"{len(poses)} poses but {len(displacements_mm)} displacement fields")
    out = np.empty((len(poses), len(X), 3))
    for k, (R, t) in enumerate(poses):
        R, t = np.asarray(R, float), np.asarray(t, float).reshape(3)
        u = displacements_mm[k] if displacements_mm is not None else None
        moved = X if u is None else X + np.asarray(u(X), float).reshape(X.shape)
        out[k] = moved @ R.T + t
    return out


def points_of_interest_truth(spec: SensorSpec, R_cam_from_world, t_cam_from_world_mm, pixels_xy, specimen,
                             poses: Sequence[Pose], reference_state: int = 0,
                             displacements_mm: Sequence[Displacement | None] | None = None
                             ) -> tuple[np.ndarray, np.ndarray]:
    """The truth of DIC points of interest defined in a reference image.

    The chief ray of each reference pixel hits the specimen (in ``poses[reference_state]``, undeformed:
    the reference state's displacement, if any, is taken to be zero) at the material point X0; its truth
    in state k is ``R_k (X0 + u_k(X0)) + t_k``.

    Parameters
    ----------
    spec, R_cam_from_world, t_cam_from_world_mm : the reference camera (normally the left one)
    pixels_xy : (N, 2) float, px, in the reference image
    specimen : :class:`scenes.specimens.beam.BendingSpecimen` (or anything with length_mm, height_mm)
    poses : K specimen poses ``(R_world_from_specimen, t_world_from_specimen_mm)``

    Returns
    -------
    X_specimen_mm : (N, 3) float, material points (NaN where the pixel does not see the front face)
    X_world_mm : (K, N, 3) float, their true world positions per state
    """
    if not 0 <= reference_state < len(poses):
        raise ValueError(f"reference_state {reference_state} is not one of the {len(poses)} states")
    o, d = pixel_rays(spec, R_cam_from_world, t_cam_from_world_mm, pixels_xy)
    _, X_s = intersect_front_face(o, d, specimen, *poses[reference_state])
    return X_s, material_point_positions(X_s, poses, displacements_mm)


def intersect_deformed_front_face(origins_world_mm, directions_world, specimen, R_world_from_specimen,
                                  t_world_from_specimen_mm, field, tol_mm: float = 1e-12,
                                  max_iterations: int = 20) -> tuple[np.ndarray, np.ndarray]:
    """Where rays hit the front face *deformed* by a displacement field: the material points they see.

    Solves ``R (X + u(X)) + t = o + lambda d`` for the material point ``X = (x, y, 0)`` of the undeformed
    face by Gauss-Newton on the ray's perpendicular residual ``(I - d d^T)(R (X + u(X)) + t - o)``, starting
    from the undeformed intersection. The Jacobian uses the field's exact gradient, so it converges
    quadratically (displacements of tens of um and gradients of ~1e-3 need two or three steps).

    Parameters
    ----------
    origins_world_mm, directions_world : (N, 3) rays, world frame
    specimen : object with ``length_mm`` and ``height_mm``
    R_world_from_specimen, t_world_from_specimen_mm : pose of the undeformed specimen
    field : object with ``displacement_mm(X (N, 3)) -> (N, 3)`` and ``gradient(X) -> (N, 3, 3)`` (specimen
        frame), or None (then this is :func:`intersect_front_face`)

    Returns
    -------
    X_world_mm : (N, 3) where the ray meets the deformed face
    X_specimen_mm : (N, 3) the material point (z = 0); NaN rows where the ray misses the face, or where the
        iteration does not converge to ``tol_mm`` (never a wrong point)
    """
    X_world, X_s = intersect_front_face(origins_world_mm, directions_world, specimen, R_world_from_specimen,
                                        t_world_from_specimen_mm)
    if field is None:
        return X_world, X_s
    R, t = _pose(R_world_from_specimen, t_world_from_specimen_mm)
    o = _as_points(origins_world_mm, "origins_world_mm", 3)
    d = _as_points(directions_world, "directions_world", 3)
    d = d / np.linalg.norm(d, axis=1, keepdims=True)
    ok = np.all(np.isfinite(X_s), axis=1)
    X = X_s[ok].copy()
    o, d = o[ok], d[ok]
    P = np.eye(3)[None] - d[:, :, None] * d[:, None, :]          # projector perpendicular to each ray
    converged = np.zeros(len(X), dtype=bool)
    for _ in range(max_iterations):
        r = np.einsum("nij,nj->ni", P, (X + field.displacement_mm(X)) @ R.T + t - o)
        J = np.einsum("nij,jk,nkl->nil", P, R, np.eye(3)[None] + field.gradient(X))[:, :, :2]
        JtJ = np.einsum("nki,nkj->nij", J, J)
        Jtr = np.einsum("nki,nk->ni", J, r)
        delta = -np.linalg.solve(JtJ, Jtr[:, :, None])[:, :, 0]
        X[:, :2] += delta
        converged = np.max(np.abs(delta), axis=1) < tol_mm
        if np.all(converged):
            break
    inside = (np.abs(X[:, 0]) <= 0.5 * specimen.length_mm) & (np.abs(X[:, 1]) <= 0.5 * specimen.height_mm)
    X[~(converged & inside)] = np.nan
    X_s = np.full_like(X_s, np.nan)
    X_s[ok] = X
    X_world = np.full_like(X_s, np.nan)
    good = np.all(np.isfinite(X_s), axis=1)
    X_world[good] = (X_s[good] + field.displacement_mm(X_s[good])) @ R.T + t
    return X_world, X_s
