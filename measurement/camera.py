"""The paper's Scheimpflug camera model (rotation-matrix model, RMM), eqs (1)-(7).

A camera-frame point ``X_cam = (X, Y, Z)`` (OpenCV frame: x right, y down, z forward, mm) maps to a pixel of
the tilted sensor in four steps:

1. normalise on the ideal image plane I_O:           ``x_n = X / Z, y_n = Y / Z``
2. Brown distortion on I_O (eq 7, written out, with the r^6 term k3 and OpenCV's thin prism s1-s4):
                                                     ``x_d = x_n (1 + k1 r^2 + k2 r^4 + k3 r^6) + 2 p1 x_n y_n + p2 (r^2 + 2 x_n^2) + s1 r^2 + s2 r^4``
                                                     ``y_d = y_n (1 + k1 r^2 + k2 r^4 + k3 r^6) + 2 p2 x_n y_n + p1 (r^2 + 2 y_n^2) + s3 r^2 + s4 r^4``
3. the Scheimpflug tilt (eqs 3, 5, 6):                ``lambda [x_t, y_t, 1]^T = A R_S^T [x_d, y_d, 1]^T``
   with ``R_S = R_Y(beta) R_X(alpha)``
4. the intrinsic matrix K (eq 2):                     ``u = fx x_t + skew y_t + cx, v = fy y_t + cy``

The paper's model has ``k3 = skew = s1..s4 = 0``; the terms exist so that calibrations from other tools (OpenCV's
5-term vector, DICe, VIC-3D, MatchID, which all carry a radial r^6 term and a skew ``K[0, 1]``; OpenCV's 12-term vector
with the thin prism s1-s4, a lens element decentred or tilted) load without loss, and so that the calibration can fit
them where the data call for it (``lens="full"``). They are not part of :data:`INTRINSIC_NAMES` (the ten Table 1
parameters of the paper's calibration).

Pixel coordinates follow OpenCV: the centre of pixel (row i, column j) is at ``(u, v) = (j, i)``.

Geometrically, step 3 intersects the ray through ``(x_d, y_d, 1)`` with the plane through ``(0, 0, 1)``
whose normal is ``R_S e_z`` and expresses the hit in that plane's own axes ``R_S e_x, R_S e_y`` (the paper's
matrix A is exactly that intersection written as a homography). ``tests/test_camera.py`` checks this against
an explicit ray/plane intersection.

OpenCV's ``CALIB_TILTED_MODEL`` uses the same distortion-then-tilt order but the rotation
``R_Y(-tau_y) R_X(-tau_x)`` where the paper uses ``R_S^T = R_X(-alpha) R_Y(-beta)``. The two coincide exactly
when one of the angles is zero (``tau_x = alpha, tau_y = beta``); with both non-zero they are different
parametrisations (about 1 px apart at the image corners for Table 1's left camera), see
:func:`opencv_tilted_model`.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass, fields

import numba
import numpy as np

#: Parameter names of Table 1, in order.
INTRINSIC_NAMES = ("fx", "fy", "cx", "cy", "alpha_deg", "beta_deg", "k1", "k2", "p1", "p2")

#: Camera terms beyond Table 1 (k3: radial r^6; skew: K[0, 1] in px; s1-s4: OpenCV's thin prism), 0 in the paper's
#: model.
EXTRA_NAMES = ("k3", "skew", "s1", "s2", "s3", "s4")
_EXTRA_NAMES = EXTRA_NAMES
#: The thin-prism terms: ``x_d += s1 r^2 + s2 r^4``, ``y_d += s3 r^2 + s4 r^4`` (OpenCV's order and meaning).
THIN_PRISM_NAMES = ("s1", "s2", "s3", "s4")

#: Tilt angles at or beyond this are refused: the tilted plane would be nearly parallel to the rays.
MAX_TILT_DEG = 45.0


def rotation_x(angle_rad: float) -> np.ndarray:
    """Right-handed rotation about X by ``angle_rad`` (the paper's R_X, eq 3), shape (3, 3)."""
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def rotation_y(angle_rad: float) -> np.ndarray:
    """Right-handed rotation about Y by ``angle_rad`` (the paper's R_Y, eq 3), shape (3, 3)."""
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def scheimpflug_rotation(alpha_rad: float, beta_rad: float) -> np.ndarray:
    """The sensor rotation ``R_S = R_Y(beta) R_X(alpha)`` of eq (3), shape (3, 3)."""
    return rotation_y(beta_rad) @ rotation_x(alpha_rad)


def scheimpflug_matrix(alpha_rad: float, beta_rad: float) -> np.ndarray:
    """The Scheimpflug array A of eq (5), shape (3, 3)."""
    ca, sa = np.cos(alpha_rad), np.sin(alpha_rad)
    cb, sb = np.cos(beta_rad), np.sin(beta_rad)
    return np.array([[ca * cb, 0.0, sb], [0.0, ca * cb, -cb * sa], [0.0, 0.0, 1.0]])


#: Tilt parametrisations: the paper's rotation-matrix model and OpenCV's CALIB_TILTED_MODEL.
TILT_MODELS = ("rmm", "opencv")


def tilt_homography(alpha_rad: float, beta_rad: float, tilt_model: str = "rmm") -> np.ndarray:
    """Map distorted ideal-plane coordinates (x_d, y_d, 1) to tilted-plane ones, shape (3, 3).

    ``"rmm"`` (the paper): ``A R_S^T`` with ``R_S = R_Y(beta) R_X(alpha)``. ``"opencv"``: OpenCV's
    ``matProjZ @ matRot`` with ``matRot = R_Y(-tau_y) R_X(-tau_x)``, ``tau_x = alpha``, ``tau_y = beta``. Both
    intersect rays with a tilted plane; they differ in the order of the two rotations.
    """
    if tilt_model == "rmm":
        return scheimpflug_matrix(alpha_rad, beta_rad) @ scheimpflug_rotation(alpha_rad, beta_rad).T
    if tilt_model == "opencv":
        M = rotation_y(-beta_rad) @ rotation_x(-alpha_rad)
        proj = np.array([[M[2, 2], 0.0, -M[0, 2]], [0.0, M[2, 2], -M[1, 2]], [0.0, 0.0, 1.0]])
        return proj @ M
    raise ValueError(f"tilt_model must be one of {TILT_MODELS}, got {tilt_model!r}")


@dataclass(frozen=True)
class ScheimpflugCamera:
    """Intrinsics of one Scheimpflug camera, named as in Table 1 of the paper.

    Parameters
    ----------
    fx, fy : float
        Focal lengths in pixels (> 0).
    cx, cy : float
        Principal point in pixels (OpenCV convention: pixel centres at integers).
    alpha_deg, beta_deg : float
        Sensor tilt about the camera X and Y axes in degrees, ``|angle| < 45``.
    k1, k2, p1, p2 : float
        Radial and tangential distortion on the ideal image plane.
    width, height : int
        Image size in pixels.
    tilt_model : str
        ``"rmm"`` (the paper) or ``"opencv"`` (OpenCV's CALIB_TILTED_MODEL), see :func:`tilt_homography`.
    k3 : float
        Radial r^6 term (OpenCV's k3); 0 in the paper's model.
    skew : float
        Skew in px, the ``K[0, 1]`` entry: ``u = fx x_t + skew y_t + cx``; 0 in the paper's model.
    s1, s2, s3, s4 : float
        Thin-prism distortion (OpenCV's s1-s4): ``x_d += s1 r^2 + s2 r^4``, ``y_d += s3 r^2 + s4 r^4``; 0 in the
        paper's model.
    """

    fx: float
    fy: float
    cx: float
    cy: float
    alpha_deg: float = 0.0
    beta_deg: float = 0.0
    k1: float = 0.0
    k2: float = 0.0
    p1: float = 0.0
    p2: float = 0.0
    width: int = 0
    height: int = 0
    tilt_model: str = "rmm"
    k3: float = 0.0
    skew: float = 0.0
    s1: float = 0.0
    s2: float = 0.0
    s3: float = 0.0
    s4: float = 0.0

    def __post_init__(self):
        if self.tilt_model not in TILT_MODELS:
            raise ValueError(f"tilt_model must be one of {TILT_MODELS}, got {self.tilt_model!r}")
        for f in fields(self):
            if f.name == "tilt_model":
                continue
            value = getattr(self, f.name)
            if not np.isfinite(value):
                raise ValueError(f"camera parameter {f.name} must be finite, got {value!r}")
        if self.fx <= 0 or self.fy <= 0:
            raise ValueError(f"focal lengths must be positive, got fx={self.fx}, fy={self.fy} px")
        for name in ("alpha_deg", "beta_deg"):
            if abs(getattr(self, name)) >= MAX_TILT_DEG:
                raise ValueError(
                    f"{name}={getattr(self, name)} is outside the supported Scheimpflug tilt range "
                    f"|angle| < {MAX_TILT_DEG} deg")
        if self.width < 0 or self.height < 0 or int(self.width) != self.width or int(self.height) != self.height:
            raise ValueError(f"image size must be non-negative integers, got {self.width} x {self.height}")

    # ----------------------------------------------------------------------------------------------------
    @classmethod
    def from_dict(cls, d: dict) -> "ScheimpflugCamera":
        """Build from a dict with Table 1 names; ``fx_px``-style keys with unit suffixes are accepted too."""
        known = {f.name for f in fields(cls)}
        kwargs = {}
        for key, value in d.items():
            name = key[:-3] if key.endswith("_px") and key[:-3] in known else key
            if name in known:
                kwargs[name] = value
        missing = [n for n in ("fx", "fy", "cx", "cy") if n not in kwargs]
        if missing:
            raise ValueError(f"camera description lacks {', '.join(missing)}: got keys {sorted(d)}")
        return cls(**kwargs)

    def to_dict(self) -> dict:
        """Plain dict with Table 1 names plus ``width``, ``height`` and ``tilt_model``; ``k3``, ``skew`` and ``s1``-``s4``
        only when non-zero, so that the dicts (and the hashes of files holding them) of cameras without them are unchanged."""
        d = asdict(self)
        for name in _EXTRA_NAMES:
            if d[name] == 0.0:
                del d[name]
        return d

    def intrinsics(self) -> dict:
        """Only the ten Table 1 parameters, ``{name: value}``."""
        return {name: float(getattr(self, name)) for name in INTRINSIC_NAMES}

    @property
    def alpha_rad(self) -> float:
        return float(np.deg2rad(self.alpha_deg))

    @property
    def beta_rad(self) -> float:
        return float(np.deg2rad(self.beta_deg))

    @property
    def K(self) -> np.ndarray:
        """Intrinsic matrix of eq (2), shape (3, 3)."""
        return np.array([[self.fx, self.skew, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def has_thin_prism(self) -> bool:
        return any(getattr(self, n) != 0.0 for n in THIN_PRISM_NAMES)

    @property
    def is_tilted(self) -> bool:
        return self.alpha_deg != 0.0 or self.beta_deg != 0.0

    def scaled(self, scale: float) -> "ScheimpflugCamera":
        """The same camera with the image shrunk by ``scale``: size and K scale together.

        Pixel centres map as ``u' + 0.5 = scale (u + 0.5)`` so the image edges stay where they were; the skew (px)
        scales with the focal lengths.
        """
        if not scale > 0:
            raise ValueError(f"scale must be positive, got {scale}")
        return ScheimpflugCamera(
            fx=self.fx * scale, fy=self.fy * scale,
            cx=(self.cx + 0.5) * scale - 0.5, cy=(self.cy + 0.5) * scale - 0.5,
            alpha_deg=self.alpha_deg, beta_deg=self.beta_deg,
            k1=self.k1, k2=self.k2, p1=self.p1, p2=self.p2,
            width=int(round(self.width * scale)), height=int(round(self.height * scale)), tilt_model=self.tilt_model,
            k3=self.k3, skew=self.skew * scale, s1=self.s1, s2=self.s2, s3=self.s3, s4=self.s4)

    # ----------------------------------------------------------------------------------------------------
    def distort(self, xy_n: np.ndarray) -> np.ndarray:
        """Apply Brown distortion (eq 7, plus the r^6 term k3 and the thin prism s1-s4) to ideal normalised
        coordinates, (N, 2) -> (N, 2)."""
        xy_n = np.asarray(xy_n, dtype=float)
        x, y = xy_n[..., 0], xy_n[..., 1]
        r2 = x * x + y * y
        # written term by term so that k3 = 0 gives bit-identical results to the former k1, k2 formula
        radial = 1.0 + self.k1 * r2 + self.k2 * r2 * r2 + self.k3 * r2 * r2 * r2
        xd = x * radial + 2.0 * self.p1 * x * y + self.p2 * (r2 + 2.0 * x * x)
        yd = y * radial + 2.0 * self.p2 * x * y + self.p1 * (r2 + 2.0 * y * y)
        if self.has_thin_prism:          # skipped when zero: cameras without it stay bit-identical
            xd = xd + self.s1 * r2 + self.s2 * r2 * r2
            yd = yd + self.s3 * r2 + self.s4 * r2 * r2
        return np.stack([xd, yd], axis=-1)

    def undistort(self, xy_d: np.ndarray, tol: float = 1e-13, max_iter: int = 50) -> np.ndarray:
        """Invert :meth:`distort` by Newton iteration, (N, 2) -> (N, 2).

        ``tol`` is on the normalised residual (1e-13 is ~1e-9 px at fx ~ 1e4). Points that do not converge
        (far outside the calibrated field, where the polynomial folds over) come back as NaN.
        """
        xy_d = np.asarray(xy_d, dtype=float)
        flat = np.ascontiguousarray(xy_d.reshape(-1, 2))
        out = _undistort_newton(flat, self.k1, self.k2, self.k3, self.p1, self.p2, self.s1, self.s2, self.s3, self.s4,
                                tol, max_iter)
        return out.reshape(xy_d.shape)

    # ----------------------------------------------------------------------------------------------------
    def project(self, X_cam: np.ndarray) -> np.ndarray:
        """Project camera-frame points to tilted-sensor pixels.

        Parameters
        ----------
        X_cam : (N, 3) array, mm
            Points in this camera's frame.

        Returns
        -------
        (N, 2) array, px
            Pixel coordinates (u, v), OpenCV convention. Points at or behind the camera (Z <= 0) give NaN.
        """
        X_cam = np.atleast_2d(np.asarray(X_cam, dtype=float))
        if X_cam.shape[-1] != 3:
            raise ValueError(f"X_cam must have shape (N, 3), got {X_cam.shape}")
        z = X_cam[..., 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            xy_n = X_cam[..., :2] / z[..., None]
        xy_n[z <= 0] = np.nan
        return self.project_normalized(xy_n)

    def project_normalized(self, xy_n: np.ndarray) -> np.ndarray:
        """Ideal normalised coordinates (x_n, y_n), (N, 2) -> pixels (N, 2)."""
        xy_d = self.distort(xy_n)
        H = tilt_homography(self.alpha_rad, self.beta_rad, self.tilt_model)
        h = xy_d @ H[:, :2].T + H[:, 2]
        xt = h[..., 0] / h[..., 2]
        yt = h[..., 1] / h[..., 2]
        return np.stack([self.fx * xt + self.skew * yt + self.cx, self.fy * yt + self.cy], axis=-1)

    def backproject(self, pixels: np.ndarray) -> np.ndarray:
        """Pixels to ideal normalised coordinates: the ray through pixel (u, v) is ``(x_n, y_n, 1)``.

        Parameters
        ----------
        pixels : (N, 2) array, px

        Returns
        -------
        (N, 2) array
            ``(x_n, y_n)``; NaN where the undistortion does not converge.
        """
        pixels = np.atleast_2d(np.asarray(pixels, dtype=float))
        if pixels.shape[-1] != 2:
            raise ValueError(f"pixels must have shape (N, 2), got {pixels.shape}")
        yt = (pixels[..., 1] - self.cy) / self.fy
        xt = (pixels[..., 0] - self.cx - self.skew * yt) / self.fx
        Hinv = np.linalg.inv(tilt_homography(self.alpha_rad, self.beta_rad, self.tilt_model))
        h = np.stack([xt, yt], axis=-1) @ Hinv[:, :2].T + Hinv[:, 2]
        xy_d = h[..., :2] / h[..., 2:3]
        return self.undistort(xy_d)

    def rays(self, pixels: np.ndarray) -> np.ndarray:
        """Unit ray directions in the camera frame through ``pixels``, (N, 2) -> (N, 3)."""
        xy = self.backproject(pixels)
        d = np.concatenate([xy, np.ones(xy.shape[:-1] + (1,))], axis=-1)
        return d / np.linalg.norm(d, axis=-1, keepdims=True)


@numba.njit(cache=True)
def _undistort_newton(xy_d, k1, k2, k3, p1, p2, s1, s2, s3, s4, tol, max_iter):
    """Newton inversion of the Brown model (radial to r^6, thin prism s1-s4) per point; NaN where it does not
    converge.

    (N, 2) -> (N, 2)."""
    out = np.empty_like(xy_d)
    for i in range(xy_d.shape[0]):
        xd, yd = xy_d[i, 0], xy_d[i, 1]
        x, y = xd, yd
        ok = False
        for _ in range(max_iter):
            r2 = x * x + y * y
            radial = 1.0 + k1 * r2 + k2 * r2 * r2 + k3 * r2 * r2 * r2
            rx = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x) + s1 * r2 + s2 * r2 * r2 - xd
            ry = y * radial + 2.0 * p2 * x * y + p1 * (r2 + 2.0 * y * y) + s3 * r2 + s4 * r2 * r2 - yd
            if abs(rx) <= tol and abs(ry) <= tol:
                ok = True
                break
            dradial = 2.0 * k1 + 4.0 * k2 * r2 + 6.0 * k3 * r2 * r2  # 2 d(radial)/d(r^2)
            gx = 2.0 * s1 + 4.0 * s2 * r2    # d(s1 r^2 + s2 r^4) / d(r^2), times 2
            gy = 2.0 * s3 + 4.0 * s4 * r2
            j11 = radial + x * dradial * x + 2.0 * p1 * y + 6.0 * p2 * x + gx * x
            j12 = x * dradial * y + 2.0 * p1 * x + 2.0 * p2 * y + gx * y
            j21 = y * dradial * x + 2.0 * p2 * y + 2.0 * p1 * x + gy * x
            j22 = radial + y * dradial * y + 2.0 * p2 * x + 6.0 * p1 * y + gy * y
            det = j11 * j22 - j12 * j21
            x -= (j22 * rx - j12 * ry) / det
            y -= (-j21 * rx + j11 * ry) / det
        if ok:
            out[i, 0], out[i, 1] = x, y
        else:
            out[i, 0], out[i, 1] = np.nan, np.nan
    return out


def opencv_tilted_model(camera: ScheimpflugCamera) -> tuple[np.ndarray, np.ndarray]:
    """OpenCV's ``CALIB_TILTED_MODEL`` form of ``camera``: ``(K, dist)`` with 14 coefficients.

    A camera with ``tilt_model="opencv"`` is OpenCV's model itself (exact for any tilt). For the paper's RMM it is
    exact only for a single-axis tilt (``alpha_deg == 0`` or ``beta_deg == 0``), where ``tau_x = alpha`` and
    ``tau_y = beta``. With both angles non-zero the rotation orders differ (paper ``R_X(-a) R_Y(-b)``,
    OpenCV ``R_Y(-ty) R_X(-tx)``) and no choice of (tau_x, tau_y) reproduces the paper's model, so this
    raises ``ValueError`` instead of returning a silently different camera.

    ``K`` carries the skew as ``K[0, 1]``; note that ``cv2.projectPoints`` ignores ``K[0, 1]`` (it reads fx, fy, cx, cy
    only), so a camera with ``skew != 0`` is reproduced by OpenCV's own projection only up to that term.
    """
    if camera.tilt_model == "opencv":
        pass  # OpenCV's own parametrisation: exact for any (tau_x, tau_y)
    elif camera.alpha_deg != 0.0 and camera.beta_deg != 0.0:
        raise ValueError(
            "OpenCV's tilted model equals the paper's RMM only for a single-axis tilt; this camera has "
            f"alpha={camera.alpha_deg} deg and beta={camera.beta_deg} deg (the rotation orders differ)")
    dist = np.zeros(14)
    dist[[0, 1, 2, 3, 4]] = camera.k1, camera.k2, camera.p1, camera.p2, camera.k3
    dist[8:12] = camera.s1, camera.s2, camera.s3, camera.s4
    dist[12], dist[13] = camera.alpha_rad, camera.beta_rad
    return camera.K, dist
