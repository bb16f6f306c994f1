"""A photographed speckle image as the texture of a twin scene (the truth side, no Mitsuba).

A digital twin of a user's rig (:mod:`workbench.twin`) needs *their* speckle pattern, as their camera sees
it, on a surface in front of *their* rig. The photograph already carries the camera's optics and pixel
integration, so the twin does not blur it again: the texture is the image itself read as a continuous
function (:class:`ImageTexture`: the band-limited interpolant of the pixel values, which reproduces every pixel
exactly), painted onto a plane through the camera that took it, and every twin pixel *point-samples* it:

* :func:`render_plane_view` -- a camera's view of the textured plane, optionally moved by a displacement
  field given on the plane (in mm): the pixel's chief ray meets the plane at ``x``; the material point is
  ``X`` with ``X + u(X) = x`` (fixed-point iteration), and the pixel shows the texture where the texture
  camera sees ``X``. The texture camera's own view of the unmoved plane is its photograph, pixel for pixel.
* :func:`render_deformed_image` -- the same in the image plane (a 2-D twin without a calibration): pixel
  ``x`` shows the texture at ``X`` with ``X + u(X) = x``, ``u`` in px.

A sub-pixel motion of a photograph is exact when the photograph moves as a band-limited function (the
convention of the DIC Challenge's shifted images): the texture is the photograph's cosine-series (DCT-II)
interpolant -- the Fourier interpolant of its mirrored copy, so no wrap-around at the edges -- sampled
:data:`UPSAMPLE` times finer (the original pixel centres among the samples), and a cubic B-spline through those
samples evaluates it between them. A cubic spline through the pixels themselves shifted a 5 px speckle by up to
0.0012 px depending on the sub-pixel phase (issue 38); through the finer samples its error is below 0.0002 px.
Neither is the instrument's biquintic B-spline of the pixels, so the twin does not hand the instrument its own
interpolant ("inverse crime"). The mirror boundary errs near the image's edges, where a DIC subset rarely sits.
Noise is added by :func:`scenes.sensor.noise.apply_sensor_noise`.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy import ndimage

from scenes.optics.camera import SensorSpec
from scenes.optics.projection import pixel_rays, project_points

#: Points this close to the image's first or last row or column count as on it, px.
EDGE_TOLERANCE_PX = 1e-9
#: Samples of the photograph's band-limited interpolant per pixel along each axis (odd: pixel centres among them).
UPSAMPLE = 3
#: Iterations of the fixed-point solve ``X = x - u(X)`` (displacement gradients of a few 1e-3 converge in 3).
MATERIAL_POINT_ITERATIONS = 8


def dct_upsample(image: np.ndarray, factor: int) -> np.ndarray:
    """An image's cosine-series (DCT-II) interpolant at ``factor`` samples per pixel along each axis, at
    ``x = (k + 0.5) / factor - 0.5`` (an odd factor puts the pixel centres among them, where it equals the image).

    Parameters
    ----------
    image : ndarray, shape (rows, cols)
    factor : int >= 1

    Returns
    -------
    ndarray of float64, shape (rows * factor, cols * factor)
    """
    import scipy.fft

    coefficients = scipy.fft.dctn(np.asarray(image, np.float64), type=2, norm="ortho", workers=-1)
    rows, cols = coefficients.shape
    padded = np.zeros((rows * factor, cols * factor))
    padded[:rows, :cols] = coefficients * factor        # the orthonormal bases' scales differ by sqrt(factor) per axis
    return scipy.fft.idctn(padded, type=2, norm="ortho", workers=-1)


@dataclass(frozen=True, eq=False)
class ImageTexture:
    """An image read as a continuous pattern: its band-limited (DCT-II) interpolant (module docstring).

    Attributes
    ----------
    image : ndarray of float64, shape (rows, cols)
        The pixel values (pixel (row i, col j) centred at ``(x, y) = (j, i)``).
    coefficients : ndarray of float64, shape (rows * UPSAMPLE, cols * UPSAMPLE)
        Cubic B-spline coefficients (half-sample symmetric boundary) of the interpolant sampled at
        ``x = (k + 0.5) / UPSAMPLE - 0.5``.
    fill_grey : float
        Value returned outside the image (its mean).
    """

    image: np.ndarray = field(repr=False)
    coefficients: np.ndarray = field(repr=False)
    fill_grey: float

    @classmethod
    def from_image(cls, image: np.ndarray) -> "ImageTexture":
        """The texture of a grey image (any real dtype, finite, at least 4 x 4)."""
        values = np.asarray(image, dtype=np.float64)
        if values.ndim != 2 or min(values.shape) < 4:
            raise ValueError(f"a texture image must be 2-D and at least 4 x 4 px, got shape {values.shape}")
        if not np.all(np.isfinite(values)):
            raise ValueError("a texture image must be finite everywhere")
        coefficients = ndimage.spline_filter(dct_upsample(values, UPSAMPLE), order=3, mode="reflect")
        return cls(values, coefficients, float(values.mean()))

    @property
    def shape(self) -> tuple[int, int]:
        return self.image.shape

    def __call__(self, x_px, y_px) -> tuple[np.ndarray, np.ndarray]:
        """Values at real points, and where they lie inside the image.

        Returns
        -------
        values : ndarray of float64, shape of ``x_px``
            The spline's value; ``fill_grey`` outside ``[0, cols - 1] x [0, rows - 1]`` or at non-finite points.
        inside : ndarray of bool, shape of ``x_px``
        """
        x = np.asarray(x_px, dtype=np.float64)
        y = np.asarray(y_px, dtype=np.float64)
        rows, cols = self.image.shape
        # A pixel sent through a camera and back lands a few 1e-14 px off its centre: the edge pixels stay inside.
        x = np.where(np.abs(x) < EDGE_TOLERANCE_PX, 0.0, np.where(np.abs(x - (cols - 1)) < EDGE_TOLERANCE_PX,
                                                                cols - 1.0, x))
        y = np.where(np.abs(y) < EDGE_TOLERANCE_PX, 0.0, np.where(np.abs(y - (rows - 1)) < EDGE_TOLERANCE_PX,
                                                                rows - 1.0, y))
        inside = np.isfinite(x) & np.isfinite(y) & (x >= 0) & (y >= 0) & (x <= cols - 1) & (y <= rows - 1)
        coords = np.stack([np.where(inside, y, 0.0).ravel(), np.where(inside, x, 0.0).ravel()])
        coords = (coords + 0.5) * UPSAMPLE - 0.5                    # in samples of the finer grid
        values = ndimage.map_coordinates(self.coefficients, coords, order=3, mode="reflect", prefilter=False)
        return np.where(inside, values.reshape(x.shape), self.fill_grey), inside


@dataclass(frozen=True)
class TexturedPlane:
    """A plane in the world frame carrying the texture as ``texture_camera`` sees it.

    Attributes
    ----------
    point_mm, normal : ndarray, shape (3,)
        A point of the plane and its unit normal, world frame (mm).
    texture : ImageTexture
    texture_spec : SensorSpec
        The camera that photographed the texture.
    texture_pose : (R_cam_from_world, t_cam_from_world_mm)
    """

    point_mm: np.ndarray
    normal: np.ndarray
    texture: ImageTexture
    texture_spec: SensorSpec
    texture_pose: tuple

    def __post_init__(self):
        n = np.asarray(self.normal, dtype=np.float64)
        p = np.asarray(self.point_mm, dtype=np.float64)
        if n.shape != (3,) or p.shape != (3,) or not (np.all(np.isfinite(n)) and np.all(np.isfinite(p))):
            raise ValueError("the plane's point_mm and normal must be finite 3-vectors")
        length = np.linalg.norm(n)
        if length == 0:
            raise ValueError("the plane's normal is zero")
        object.__setattr__(self, "normal", n / length)
        object.__setattr__(self, "point_mm", p)
        if self.texture.shape != (self.texture_spec.height, self.texture_spec.width):
            raise ValueError(f"the texture is {self.texture.shape[1]} x {self.texture.shape[0]} px but its camera is "
                             f"{self.texture_spec.width} x {self.texture_spec.height} px")

    def in_plane_axes(self) -> np.ndarray:
        """Two unit vectors spanning the plane (rows of a (2, 3) array): e1 along the world x axis projected."""
        n = self.normal
        e1 = np.array([1.0, 0.0, 0.0]) - n[0] * n
        if np.linalg.norm(e1) < 1e-6:
            e1 = np.array([0.0, 1.0, 0.0]) - n[1] * n
        e1 /= np.linalg.norm(e1)
        return np.stack([e1, np.cross(n, e1)])


def plane_points(spec: SensorSpec, pose, plane: TexturedPlane, pixels_xy: np.ndarray) -> np.ndarray:
    """Where the chief rays of pixels meet the plane, world frame (mm), shape (N, 3); NaN where they miss it
    (parallel, or behind the camera)."""
    origins, directions = pixel_rays(spec, pose[0], pose[1], pixels_xy)
    denom = directions @ plane.normal
    with np.errstate(divide="ignore", invalid="ignore"):
        s = ((plane.point_mm - origins) @ plane.normal) / denom
    s = np.where(np.isfinite(s) & (s > 0), s, np.nan)
    return origins + s[:, None] * directions


def render_plane_view(spec: SensorSpec, pose, plane: TexturedPlane, displacement_mm=None, *,
                      rows: slice | None = None) -> tuple[np.ndarray, np.ndarray]:
    """A camera's noise-free view of the textured plane, point-sampled at the pixel centres.

    Parameters
    ----------
    spec : SensorSpec
        The viewing camera (its pixel grid).
    pose : (R_cam_from_world, t_cam_from_world_mm)
    plane : TexturedPlane
    displacement_mm : callable, optional
        ``u(X_world_mm (N, 3)) -> (N, 3)`` mm, the displacement of the material point at ``X`` (kept in the
        plane by the caller for an in-plane field; any field is accepted). None: the plane at rest.
    rows : slice, optional
        Only these image rows (the rest of the image is the fill value; for tests and tiles).

    Returns
    -------
    image : ndarray of float64, shape (height, width)
        Grey levels of the texture; the texture's mean where a ray misses the plane or the material point lies
        outside the texture camera's image.
    valid : ndarray of bool, shape (height, width)
        True where the pixel shows the texture.
    """
    image = np.full((spec.height, spec.width), plane.texture.fill_grey)
    valid = np.zeros((spec.height, spec.width), dtype=bool)
    r = range(spec.height)[rows] if rows is not None else range(spec.height)
    # Work in bands of rows: 5 MP at once would hold several (5e6, 3) float64 arrays.
    band = max(1, 400_000 // spec.width)
    row_list = list(r)
    for start in range(0, len(row_list), band):
        rr = np.asarray(row_list[start:start + band])
        yy, xx = np.meshgrid(rr, np.arange(spec.width), indexing="ij")
        pix = np.column_stack([xx.ravel(), yy.ravel()]).astype(np.float64)
        x_world = plane_points(spec, pose, plane, pix)
        X = x_world
        if displacement_mm is not None:
            X = x_world.copy()
            for _ in range(MATERIAL_POINT_ITERATIONS):
                X = x_world - np.asarray(displacement_mm(X), dtype=np.float64)
        uv = project_points(plane.texture_spec, plane.texture_pose[0], plane.texture_pose[1], X)
        values, inside = plane.texture(uv[:, 0], uv[:, 1])
        image[rr[0]:rr[-1] + 1] = values.reshape(len(rr), spec.width)
        valid[rr[0]:rr[-1] + 1] = inside.reshape(len(rr), spec.width)
    return image, valid


def render_deformed_image(texture: ImageTexture, displacement_px=None, shape: tuple[int, int] | None = None,
                          ) -> tuple[np.ndarray, np.ndarray]:
    """The texture moved by a displacement field in the image plane, point-sampled at the pixel centres.

    Parameters
    ----------
    texture : ImageTexture
    displacement_px : callable, optional
        ``(X, Y) -> (U, V)`` px at reference (material) points. None: the texture itself.
    shape : (rows, cols), optional
        Output size; default the texture's.

    Returns
    -------
    image : ndarray of float64, shape (rows, cols)
    valid : ndarray of bool
        True where the material point lies inside the texture.
    """
    rows, cols = texture.shape if shape is None else (int(shape[0]), int(shape[1]))
    y, x = np.mgrid[0:rows, 0:cols].astype(np.float64)
    X, Y = x, y
    if displacement_px is not None:
        X, Y = x.copy(), y.copy()
        for _ in range(MATERIAL_POINT_ITERATIONS * 4):
            U, V = displacement_px(X, Y)
            X_new, Y_new = x - U, y - V
            converged = max(np.max(np.abs(X_new - X)), np.max(np.abs(Y_new - Y))) < 1e-9
            X, Y = X_new, Y_new
            if converged:
                break
    return texture(X, Y)
