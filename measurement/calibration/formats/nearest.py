"""The camera of a more limited model that projects like a given one: the honest part of format conversion.

Other DIC tools hold fewer camera terms than :class:`~measurement.camera.ScheimpflugCamera` (VIC-3D: no tilt and no
tangential terms; MatchID: no tilt; DICe: OpenCV's tilt but not the paper's rotation order). Converting a camera
into such a model is a fit, not a copy: :func:`nearest_camera` chooses the target model's parameters by least
squares (``scipy.optimize.least_squares``) so that the same rays project to the same pixels, and reports what is
left, in pixels, over the whole image.

The rays are those of a 41 x 41 grid of pixels spanning the image (centres of the corner pixels included),
back-projected through the source camera; the cost is evaluated on a second, denser grid (101 x 101, corners
included, most points between those of the first, so a fit cannot hide error between its own points): ``mean_px``
and ``max_px`` are the mean and largest distance between where the source camera and the converted one put the
same ray. When the target model holds the camera exactly (same terms, a single-axis RMM tilt into OpenCV's tilt,
...) the parameters are mapped directly and the cost is rounding only (< 1e-9 px).

``frame_rotation=True`` also lets the camera frame rotate (the rotation is returned, and the stereo extrinsics must
absorb it, :func:`nearest_rig`). A Scheimpflug tilt is, up to the order of distortion and tilt, a rotated pinhole
(``A R_S^T`` is an affine map after a rotation), so a tilt the target cannot hold costs far less with a rotated
frame; and the paper's two-axis RMM tilt is exactly OpenCV's tilt after a rotation about the optical axis (which
commutes with radial distortion and turns (p1, p2) with it).
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace

import cv2
import numpy as np
from scipy.optimize import least_squares

from measurement.camera import MAX_TILT_DEG, THIN_PRISM_NAMES, ScheimpflugCamera, tilt_homography

__all__ = ["TargetModel", "ConversionCost", "nearest_camera", "nearest_rig", "projection_cost_px",
           "DICE_MODEL", "VIC3D_MODEL", "MATCHID_MODEL", "EXACT_PX"]

#: A conversion whose largest pixel distance is at most this is called exact (double rounding is ~1e-12 px).
EXACT_PX = 1e-6
#: Points per image side of the fitting grid and of the (denser) grid the cost is evaluated on.
FIT_GRID_N = 41
EVAL_GRID_N = 101


@dataclass(frozen=True)
class TargetModel:
    """Which camera terms a target format can hold.

    Attributes
    ----------
    name : str
        Human-readable description of the model (used in reports).
    tilt : str
        ``"none"`` (pinhole) or ``"opencv"`` (OpenCV's CALIB_TILTED_MODEL, tau_x and tau_y).
    radial_terms : int
        2 (k1, k2) or 3 (k1, k2, k3), all on even powers of the ideal normalised radius.
    tangential : bool
        Whether p1, p2 (Brown decentering, OpenCV's convention) exist.
    skew : bool
        Whether a skew ``K[0, 1]`` (px) exists.
    thin_prism : bool
        Whether OpenCV's thin-prism terms s1-s4 exist (none of the DIC tools' formats has them).
    """

    name: str
    tilt: str = "none"
    radial_terms: int = 3
    tangential: bool = True
    skew: bool = True
    thin_prism: bool = False

    def __post_init__(self):
        if self.tilt not in ("none", "opencv"):
            raise ValueError(f"tilt must be 'none' or 'opencv', got {self.tilt!r}")
        if self.radial_terms not in (2, 3):
            raise ValueError(f"radial_terms must be 2 or 3, got {self.radial_terms!r}")

    def lacks(self, camera: ScheimpflugCamera) -> list[str]:
        """What of ``camera`` this model cannot hold as it is (empty: a direct, exact mapping exists)."""
        missing = []
        if camera.is_tilted:
            if self.tilt == "none":
                missing.append("the Scheimpflug tilt")
            elif camera.tilt_model == "rmm" and camera.alpha_deg != 0.0 and camera.beta_deg != 0.0:
                missing.append("the two-axis RMM tilt (OpenCV's tilt rotates in the other order)")
        if self.radial_terms < 3 and camera.k3 != 0.0:
            missing.append("k3")
        if not self.tangential and (camera.p1 != 0.0 or camera.p2 != 0.0):
            missing.append("the tangential terms p1, p2")
        if not self.skew and camera.skew != 0.0:
            missing.append("the skew")
        if not self.thin_prism and camera.has_thin_prism:
            missing.append("the thin prism s1-s4")
        return missing


#: DICe's OPENCV_LENS_DISTORTION (K1-K3, P1, P2, T1, T2 = OpenCV tau_x, tau_y) with its skew FS.
DICE_MODEL = TargetModel("OpenCV distortion (k1 k2 p1 p2 k3) + OpenCV tilt (tau_x, tau_y) + skew", tilt="opencv")
#: VIC-3D's calibration: cx cy fx fy fs and three radial terms, no tilt, no tangential terms.
VIC3D_MODEL = TargetModel("pinhole + radial k1 k2 k3 + skew (no tangential, no tilt)", tangential=False)
#: MatchID's .caldat: Kappa 1-3, P1, P2, Fs, no tilt.
MATCHID_MODEL = TargetModel("pinhole + Brown k1 k2 k3 p1 p2 + skew (no tilt)")


@dataclass(frozen=True)
class ConversionCost:
    """How far the converted camera projects from the source one, over the image.

    Attributes
    ----------
    mean_px, max_px : float
        Mean and largest distance (px) between the two projections of the same rays (evaluation grid).
    exact : bool
        ``max_px <= EXACT_PX``.
    lacks : tuple of str
        What the target model could not hold as it was (empty for a direct mapping).
    R_new_from_old : (3, 3) array
        Rotation of the converted camera's frame: it projects ``R_new_from_old @ X_cam`` (identity unless
        ``frame_rotation=True``).
    """

    mean_px: float
    max_px: float
    exact: bool
    lacks: tuple[str, ...] = ()
    R_new_from_old: np.ndarray = field(default_factory=lambda: np.eye(3))

    @property
    def rotation_deg(self) -> float:
        """Angle of ``R_new_from_old`` in degrees."""
        return float(np.rad2deg(np.linalg.norm(cv2.Rodrigues(np.asarray(self.R_new_from_old, float))[0])))


# --------------------------------------------------------------------------------------------------------
def _grid_pixels(camera: ScheimpflugCamera, n: int) -> np.ndarray:
    """``n x n`` pixels spanning the image, corner pixel centres included; shape (n*n, 2), px."""
    w, h = camera.width, camera.height
    if w < 2 or h < 2:
        raise ValueError(f"the camera needs an image size of at least 2 x 2 px to be converted, got {w} x {h}")
    t = np.linspace(0.0, 1.0, n)
    u, v = np.meshgrid(t * (w - 1), t * (h - 1))
    return np.column_stack([u.ravel(), v.ravel()])


def _rays(camera: ScheimpflugCamera, pixels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Camera-frame points ``(x_n, y_n, 1)`` seen at ``pixels`` and those pixels, where the back-projection exists."""
    xy = camera.backproject(pixels)
    ok = np.all(np.isfinite(xy), axis=1)
    if ok.sum() < 0.9 * len(pixels):
        raise ValueError(f"the camera's distortion cannot be inverted over {np.sum(~ok)} of {len(pixels)} grid "
                         f"pixels: it folds over inside its own image")
    return np.column_stack([xy[ok], np.ones(ok.sum())]), pixels[ok]


def projection_cost_px(source: ScheimpflugCamera, converted: ScheimpflugCamera,
                       R_new_from_old: np.ndarray | None = None, n: int = EVAL_GRID_N) -> tuple[float, float]:
    """Mean and largest distance (px) between ``source`` and ``converted`` (seeing ``R_new_from_old @ X``) over an
    ``n x n`` grid of the source image, its corners included."""
    X, pixels = _rays(source, _grid_pixels(source, n))
    if R_new_from_old is not None:
        X = X @ np.asarray(R_new_from_old, float).T
    d = np.linalg.norm(converted.project(X) - pixels, axis=1)
    if not np.all(np.isfinite(d)):
        return float("inf"), float("inf")
    return float(d.mean()), float(d.max())


# --------------------------------------------------------------------------------------------------------
def _direct(camera: ScheimpflugCamera, model: TargetModel) -> ScheimpflugCamera:
    """The target model's camera with every term it can hold copied (the exact answer when nothing is lacking)."""
    keep_tilt = model.tilt == "opencv" and camera.is_tilted
    return ScheimpflugCamera(
        fx=camera.fx, fy=camera.fy, cx=camera.cx, cy=camera.cy,
        alpha_deg=camera.alpha_deg if keep_tilt else 0.0, beta_deg=camera.beta_deg if keep_tilt else 0.0,
        k1=camera.k1, k2=camera.k2, k3=camera.k3 if model.radial_terms == 3 else 0.0,
        p1=camera.p1 if model.tangential else 0.0, p2=camera.p2 if model.tangential else 0.0,
        skew=camera.skew if model.skew else 0.0, width=camera.width, height=camera.height,
        tilt_model="opencv" if model.tilt == "opencv" else "rmm",
        **({n: getattr(camera, n) for n in THIN_PRISM_NAMES} if model.thin_prism else {}))


class _Parametrisation:
    """The free parameters of a target model (and optionally a frame rotation) as one vector."""

    def __init__(self, model: TargetModel, template: ScheimpflugCamera, rotation_axes: str):
        names = ["fx", "fy", "cx", "cy", "k1", "k2"]
        if model.radial_terms == 3:
            names.append("k3")
        if model.tangential:
            names += ["p1", "p2"]
        if model.skew:
            names.append("skew")
        if model.tilt == "opencv":
            names += ["alpha_deg", "beta_deg"]
        if model.thin_prism:
            names += list(THIN_PRISM_NAMES)
        self.names, self.template, self.rotation_axes = names, template, rotation_axes

    def vector(self, camera: ScheimpflugCamera, rvec: np.ndarray) -> np.ndarray:
        rot = rvec if self.rotation_axes == "xyz" else rvec[2:] if self.rotation_axes == "z" else np.zeros(0)
        return np.concatenate([[getattr(camera, n) for n in self.names], rot])

    def unpack(self, x: np.ndarray) -> tuple[ScheimpflugCamera, np.ndarray]:
        """The camera (ValueError if invalid) and the frame rotation of parameter vector ``x``."""
        k = len(self.names)
        values = dict(zip(self.names, (float(v) for v in x[:k])))
        rvec = np.zeros(3)
        if self.rotation_axes == "xyz":
            rvec = np.asarray(x[k:k + 3], float)
        elif self.rotation_axes == "z":
            rvec[2] = x[k]
        for name in ("alpha_deg", "beta_deg"):
            if abs(values.get(name, 0.0)) >= MAX_TILT_DEG:
                raise ValueError("tilt out of range")
        return replace(self.template, **values), cv2.Rodrigues(rvec)[0]


def _fit(camera: ScheimpflugCamera, model: TargetModel, rotation_axes: str) -> tuple[ScheimpflugCamera, np.ndarray]:
    """Least-squares fit of the target model (and frame rotation) to the source camera's grid of rays."""
    X, pixels = _rays(camera, _grid_pixels(camera, FIT_GRID_N))
    start = _direct(camera, model)
    rvec0 = np.zeros(3)
    if rotation_axes == "xyz" and camera.is_tilted:
        # a tilted sensor is a rotated pinhole up to the distortion order: start from that rotation
        H = tilt_homography(camera.alpha_rad, camera.beta_rad, camera.tilt_model)
        rvec0 = _rotation_part(H)
    start = _linear_intrinsics(start, X, pixels, cv2.Rodrigues(rvec0)[0], model.skew)
    par = _Parametrisation(model, start, rotation_axes)
    x0 = par.vector(start, rvec0)
    bad = np.full(2 * len(pixels), 1e6)

    def residuals(x):
        try:
            cam, R = par.unpack(x)
        except ValueError:
            return bad
        r = (cam.project(X @ R.T) - pixels).ravel()
        return np.where(np.isfinite(r), r, 1e6)

    fit = least_squares(residuals, x0, method="lm", x_scale="jac", xtol=1e-15, ftol=1e-15, gtol=1e-15,
                        max_nfev=200 * (len(x0) + 1))
    return par.unpack(fit.x)


def _rotation_part(H: np.ndarray) -> np.ndarray:
    """Rotation vector of the rotation in a tilt homography ``H = (affine) @ Q``: Q's rows 0 and 1 are not
    recoverable from H alone, its last row is H's (normalised), which fixes Q up to a turn about z."""
    q3 = H[2] / np.linalg.norm(H[2])
    # the smallest rotation taking e_z to q3 (about an axis in the xy plane)
    axis = np.cross([0.0, 0.0, 1.0], q3)
    s = np.linalg.norm(axis)
    if s < 1e-15:
        return np.zeros(3)
    # Q maps camera rays to the tilted frame: Q^T e_z = q3, so Q = rotation taking q3 to e_z
    return -axis / s * np.arctan2(s, q3[2])


def _linear_intrinsics(start: ScheimpflugCamera, X: np.ndarray, pixels: np.ndarray, R: np.ndarray,
                       skew: bool) -> ScheimpflugCamera:
    """``start`` with fx, fy, cx, cy (and the skew where the model has one) refitted linearly to ``pixels``."""
    Xr = X @ R.T
    xy_t = start.distort(Xr[:, :2] / Xr[:, 2:3])
    if start.is_tilted:
        H = tilt_homography(start.alpha_rad, start.beta_rad, start.tilt_model)
        h = xy_t @ H[:, :2].T + H[:, 2]
        xy_t = h[:, :2] / h[:, 2:3]
    ones = np.ones(len(xy_t))
    a_u = np.column_stack([xy_t[:, 0], xy_t[:, 1], ones]) if skew else np.column_stack([xy_t[:, 0], ones])
    coef_u, *_ = np.linalg.lstsq(a_u, pixels[:, 0], rcond=None)
    (fy, cy), *_ = np.linalg.lstsq(np.column_stack([xy_t[:, 1], ones]), pixels[:, 1], rcond=None)
    fx, s, cx = (coef_u[0], coef_u[1], coef_u[2]) if skew else (coef_u[0], 0.0, coef_u[1])
    if not (fx > 0 and fy > 0 and np.all(np.isfinite([fx, s, cx, fy, cy]))):
        return start
    return replace(start, fx=float(fx), fy=float(fy), cx=float(cx), cy=float(cy), skew=float(s))


def nearest_camera(camera: ScheimpflugCamera, model: TargetModel, *,
                   frame_rotation: bool = False) -> tuple[ScheimpflugCamera, ConversionCost]:
    """The camera of ``model`` that projects the same rays closest to where ``camera`` does.

    Parameters
    ----------
    camera : ScheimpflugCamera
        The source camera (its image size defines where the cost is measured).
    model : TargetModel
        The terms the target format can hold.
    frame_rotation : bool
        Also fit a rotation of the camera frame (returned as ``cost.R_new_from_old``; a stereo rig must absorb it
        in its extrinsics, :func:`nearest_rig`). Rotations about x and y are fitted only for a model without tilt
        (with one they would duplicate the tilt); about the optical axis always.

    Returns
    -------
    camera_in_model : ScheimpflugCamera
        ``tilt_model="opencv"`` for a model with OpenCV's tilt, else an untilted ``"rmm"`` camera.
    cost : ConversionCost
        Mean and largest pixel distance over the image (exact cases: < 1e-9 px).
    """
    lacks = tuple(model.lacks(camera))
    direct = _direct(camera, model)
    direct_mean, direct_worst = projection_cost_px(camera, direct)
    if not lacks and direct_worst <= EXACT_PX:
        return direct, ConversionCost(direct_mean, direct_worst, True, lacks)
    axes = ("xyz" if model.tilt == "none" else "z") if frame_rotation else ""
    fitted, R = _fit(camera, model, axes)
    mean, worst = projection_cost_px(camera, fitted, R)
    if not worst <= direct_worst:            # a fit that went astray never beats copying the terms it can hold
        return direct, ConversionCost(direct_mean, direct_worst, direct_worst <= EXACT_PX, lacks)
    return fitted, ConversionCost(mean, worst, worst <= EXACT_PX, lacks, R)


def nearest_rig(left: ScheimpflugCamera, right: ScheimpflugCamera, R_right_from_left, T_right_from_left_mm,
                model: TargetModel, *, frame_rotation: bool = False):
    """Both cameras of a stereo pair converted into ``model`` and the extrinsics in the converted frames.

    Returns
    -------
    (left', right', R', T', cost_left, cost_right)
        ``X_right' = R' X_left' + T'`` with ``X_left' = R_L X_left`` and ``X_right' = R_R X_right`` (the
        ``R_new_from_old`` of each cost; identity without ``frame_rotation``): ``R' = R_R R R_L^T``, ``T' = R_R T``.
    """
    new_left, cost_left = nearest_camera(left, model, frame_rotation=frame_rotation)
    new_right, cost_right = nearest_camera(right, model, frame_rotation=frame_rotation)
    R_L, R_R = cost_left.R_new_from_old, cost_right.R_new_from_old
    R = R_R @ np.asarray(R_right_from_left, float) @ R_L.T
    T = R_R @ np.asarray(T_right_from_left_mm, float).ravel()
    return new_left, new_right, R, T, cost_left, cost_right
