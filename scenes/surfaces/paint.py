"""Paint on a specimen's surface: a speckle (or a checker) whose size is given in mm on the surface.

A texture lives in a flat ``(u, v)`` plane measured in mm; how the surface maps to that plane is how the paint was
applied:

* ``"sprayed"``: paint travelling along a direction lands where it meets the surface: ``(u, v)`` is the
  position projected on the plane across that direction. A surface inclined by ``a`` to the spray receives
  speckles stretched by ``1 / cos a`` across the slope (stated, per face and overall), and faces turned more than
  ``max_angle_deg`` away receive none.
* ``"wrapped"``: a printed sheet wrapped on a developable surface keeps its size: on a cylinder (axis point and
  direction given, radius measured from the mesh) ``u`` is the arc length ``r theta`` and ``v`` the position along
  the axis; the seam is put opposite the spray direction (the side the cameras do not see) and the faces across
  it stay unpainted, as do faces turned more than ``max_angle_deg`` from the spray (the sheet covers the side the
  cameras see). On a plane, wrapping is spraying along its normal.

Unpainted faces keep a plain ``base_grey``. Textures are bilinear speckle (:func:`scenes.surfaces.speckle.speckle_pattern`)
or a sharp-edged checker (``"nearest"``: rendered exactly by polygon coverage).
"""
from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

PAINT_KINDS = ("speckle", "checker")
METHODS = ("sprayed", "wrapped")
#: Largest paint texture (texels, as looked up by the renderers): 1.6 GB of float32 (a full-scale cylinder wrapped
#: whole at 5 px speckles needs 370 M).
MAX_TEXELS = 400_000_000
#: Texels per speckle diameter in the texture the renderers look up. A speckle is generated at ``texel_mm``
#: (default speckle / 5) and is, by definition, the band-limited interpolant of those samples; the renderers
#: interpolate a texture bilinearly, which at 5 texels per speckle (about one texel per pixel at the default
#: 5 px speckle) moves the rendered pattern by up to 0.005 px depending on where a pixel falls on the texels: a
#: sub-pixel motion was not rendered exactly (issue 38): 0.010 px RMS against the paint itself. At 20 texels per
#: speckle the texture is the paint's Fourier interpolant sampled 4 times finer and that error is 0.0006 px at every
#: phase (``workbench.experiments.subpixel``; 15 texels: 0.0010 px, 25: 0.0004 px).
LOOKUP_TEXELS_PER_SPECKLE = 20.0


@dataclass(frozen=True)
class Paint:
    """How the surface is painted (module docstring). Lengths in mm on the surface; directions in the specimen frame.

    Parameters
    ----------
    kind : "speckle" or "checker"
    method : "sprayed" or "wrapped"
    speckle_mm : nominal speckle diameter
    texel_mm : the pattern's sample spacing (default: speckle / 5); the paint is the band-limited interpolant of
        those samples, looked up by the renderers at :attr:`lookup_factor` times finer
    density, contrast, mean : see :func:`scenes.surfaces.speckle.speckle_pattern`
    checker_mm : checker square side
    direction : paint travel direction (into the surface); default +z (the specimen frame's cameras look along +z)
    axis_point_mm, axis_direction : the cylinder's axis for ``wrapped`` on a cylinder (None: a plane)
    max_angle_deg : faces whose outer normal is more than this from ``-direction`` stay unpainted
    seam_margin_deg : ``wrapped`` cylinder: faces within this of the seam (opposite ``-direction``) stay unpainted
    base_grey : radiance of unpainted faces, in [0, 1]
    seed : speckle seed
    angle_deg : the pattern turned by this angle in its (u, v) plane (a checker whose lines are not along the
        image axes: corner estimators degrade on axis-aligned edges)
    edge_mm : the speckles' edge width, the sigma of a Gaussian (None: speckle / 6, soft edges as sprayed paint
        has; a sharp paint, e.g. speckle / 40 with ``texel_mm`` small enough to hold it, aliases unless the optics
        low-pass it)
    """

    kind: str = "speckle"
    method: str = "sprayed"
    speckle_mm: float = 0.17
    texel_mm: float | None = None
    density: float = 0.5
    contrast: float = 0.8
    mean: float = 0.5
    checker_mm: float = 2.0
    direction: tuple = (0.0, 0.0, 1.0)
    axis_point_mm: tuple | None = None
    axis_direction: tuple | None = None
    max_angle_deg: float = 80.0
    seam_margin_deg: float = 10.0
    base_grey: float = 0.5
    seed: int = 0
    angle_deg: float = 0.0
    edge_mm: float | None = None

    def __post_init__(self):
        if self.kind not in PAINT_KINDS:
            raise ValueError(f"paint kind {self.kind!r}: choose one of {', '.join(PAINT_KINDS)}")
        if self.method not in METHODS:
            raise ValueError(f"paint method {self.method!r}: choose one of {', '.join(METHODS)}")
        for name in ("speckle_mm", "checker_mm"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v > 0):
                raise ValueError(f"paint {name} must be positive, got {v!r}")
        if self.texel_mm is not None and not (np.isfinite(self.texel_mm) and 0 < self.texel_mm <= self.speckle_mm / 2):
            raise ValueError(f"paint texel_mm must be in (0, speckle_mm / 2], got {self.texel_mm!r}")
        d = np.asarray(self.direction, float)
        if d.shape != (3,) or not np.all(np.isfinite(d)) or np.linalg.norm(d) == 0:
            raise ValueError(f"paint direction must be a non-zero 3-vector, got {self.direction!r}")
        if (self.axis_point_mm is None) != (self.axis_direction is None):
            raise ValueError("paint: give both axis_point_mm and axis_direction (a cylinder), or neither")
        if not 0 < self.max_angle_deg < 90:
            raise ValueError(f"paint max_angle_deg must be in (0, 90), got {self.max_angle_deg!r}")
        if self.edge_mm is not None and not (np.isfinite(self.edge_mm) and self.edge_mm >= 0):
            raise ValueError(f"paint edge_mm must be >= 0, got {self.edge_mm!r}")
        if not 0.0 <= self.base_grey <= 1.0:
            raise ValueError(f"paint base_grey must be in [0, 1], got {self.base_grey!r}")

    @property
    def texel(self) -> float:
        """Texture resolution in mm (checker: one texel per square)."""
        if self.kind == "checker":
            return float(self.checker_mm)
        return float(self.texel_mm) if self.texel_mm is not None else float(self.speckle_mm) / 5.0

    @property
    def lookup_factor(self) -> int:
        """Texels of the renderers' texture per pattern texel, along each axis (:data:`LOOKUP_TEXELS_PER_SPECKLE`;
        1 for a checker, whose texels are its squares)."""
        if self.kind == "checker":
            return 1
        return max(1, int(np.ceil(LOOKUP_TEXELS_PER_SPECKLE * self.texel / self.speckle_mm - 1e-9)))

    def to_dict(self) -> dict:
        return {k: (list(v) if isinstance(v, tuple) else v) for k, v in asdict(self).items()}


@dataclass(frozen=True)
class PaintLayout:
    """Where the paint lies on a tessellation.

    Attributes
    ----------
    uv_mm : (V, 2) texture-plane coordinates of every tessellation vertex, mm
    painted : (T,) bool, triangles that carry the paint
    origin_mm : (2,) texture corner (u, v) of texel (0, 0)
    shape : (rows, cols) of the texture
    stretch : (T,) how much a speckle is stretched on each triangle (1: true size; NaN unpainted)
    size_mm : (2,) the texture's extent along u and v (mm)
    radius_mm : the wrapping cylinder's radius (None: sprayed or a plane)
    """

    uv_mm: np.ndarray
    painted: np.ndarray
    origin_mm: np.ndarray
    shape: tuple
    stretch: np.ndarray
    size_mm: np.ndarray
    radius_mm: float | None = None

    def uv(self) -> np.ndarray:
        """(V, 2) texture coordinates in [0, 1] over the texture (``u`` along columns, ``v`` along rows)."""
        return (self.uv_mm - self.origin_mm) / self.size_mm

    def with_texture_frame(self, shape: tuple, origin_mm, size_mm) -> "PaintLayout":
        """The same layout for a texture of ``shape`` covering ``origin_mm + [0, size_mm]`` (a texture of one's own:
        a photographed pattern, or the built-in beam's)."""
        from dataclasses import replace

        return replace(self, shape=tuple(int(v) for v in shape), origin_mm=np.asarray(origin_mm, float).reshape(2),
                       size_mm=np.asarray(size_mm, float).reshape(2))

    def summary(self) -> dict:
        s = self.stretch[self.painted]
        return {"painted_triangles": int(self.painted.sum()), "triangles": int(len(self.painted)),
                "texture_shape": list(self.shape),     # pattern texels (the renderers' texture: x lookup_factor)
                "stretch_max": float(np.max(s)) if len(s) else None,
                "stretch_mean": float(np.mean(s)) if len(s) else None,
                "stretch_over_1_5_fraction": float(np.mean(s > 1.5)) if len(s) else None}


def _unit(v) -> np.ndarray:
    v = np.asarray(v, float)
    return v / np.linalg.norm(v)


def _cylinder_frame(paint: Paint):
    """(axis point c, axis a, e0 towards the paint's source, e1 = a x e0) of a paint wrapped round a cylinder."""
    d = _unit(paint.direction)
    a = _unit(paint.axis_direction)
    c = np.asarray(paint.axis_point_mm, float)
    e0 = -d - (-d @ a) * a
    if np.linalg.norm(e0) < 1e-9:
        raise ValueError("the paint direction is along the cylinder axis; the seam cannot be placed")
    e0 = _unit(e0)
    return c, a, e0, np.cross(a, e0)


def paint_coordinates_mm(paint: Paint, X_mm, radius_mm: float | None = None) -> np.ndarray:
    """(u, v) of the paint's plane at surface points X (N, 3), specimen frame: the projection across the spray
    (sprayed, or wrapped on a plane), or arc length ``radius * theta`` and axial position (wrapped on a cylinder of
    ``radius_mm``: :attr:`PaintLayout.radius_mm`). The one formula of the layout's vertices and of the truth."""
    X = np.asarray(X_mm, float).reshape(-1, 3)
    if paint.method == "wrapped" and paint.axis_direction is not None:
        c, a, e0, e1 = _cylinder_frame(paint)
        rel = X - c
        uv = np.column_stack([float(radius_mm) * np.arctan2(rel @ e1, rel @ e0), rel @ a])
    else:
        d = _unit(paint.direction)
        e1 = np.array([1.0, 0.0, 0.0]) - d[0] * d
        if np.linalg.norm(e1) < 1e-6:
            e1 = np.array([0.0, 1.0, 0.0]) - d[1] * d
        e1 = _unit(e1)
        uv = np.column_stack([X @ e1, X @ np.cross(d, e1)])
    if paint.angle_deg:
        c, s = np.cos(np.radians(paint.angle_deg)), np.sin(np.radians(paint.angle_deg))
        uv = uv @ np.array([[c, s], [-s, c]])               # the pattern turned by +angle
    return uv


def layout(paint: Paint, vertices_mm: np.ndarray, triangles: np.ndarray, source: str = "<mesh>") -> PaintLayout:
    """Texture coordinates and painted triangles of a tessellation in its reference state (specimen frame).

    Raises ValueError (naming ``source``) when nothing can be painted or the texture would be too large."""
    V = np.asarray(vertices_mm, float)
    T = np.asarray(triangles, np.int64)
    d = _unit(paint.direction)
    n = np.cross(V[T[:, 1]] - V[T[:, 0]], V[T[:, 2]] - V[T[:, 0]])
    area2 = np.linalg.norm(n, axis=1)
    n = n / np.where(area2 > 0, area2, 1.0)[:, None]
    facing = n @ (-d)                                         # cos of the angle to the incoming paint
    painted = (facing >= np.cos(np.radians(paint.max_angle_deg))) & (area2 > 0)
    radius = None
    if paint.method == "wrapped" and paint.axis_direction is not None:
        try:
            c, a, e0, e1 = _cylinder_frame(paint)
        except ValueError as err:
            raise ValueError(f"{source}: {err}") from None
        rel = V - c
        radial = rel - np.outer(rel @ a, a)
        rho = np.linalg.norm(radial, axis=1)
        theta = np.arctan2(rel @ e1, rel @ e0)
        centre = V[T].mean(axis=1) - c
        out = centre - np.outer(centre @ a, a)
        out /= np.maximum(np.linalg.norm(out, axis=1, keepdims=True), 1e-300)
        # the sheet lies on the outside of the cylinder's side: faces looking away from the axis (not its ends, not
        # a tube's bore)
        lateral = np.einsum("ij,ij->i", n, out) > np.cos(np.radians(30.0))
        tri_theta = theta[T]
        seam = np.radians(180.0 - paint.seam_margin_deg)
        across = (np.ptp(tri_theta, axis=1) > np.pi) | (np.abs(tri_theta).max(axis=1) > seam)
        # and, as sprayed paint, only faces within max_angle_deg of the cameras' side: a whole tube's sheet at fine
        # speckles would be a texture too large to hold, for faces no camera measures
        painted = lateral & ~across & (area2 > 0) & (facing >= np.cos(np.radians(paint.max_angle_deg)))
        if not painted.any():
            raise ValueError(f"{source}: no face of the mesh lies on the side of the cylinder around the given axis")
        radius = float(np.median(rho[np.unique(T[painted])]))
        uv = paint_coordinates_mm(paint, V, radius)
        stretch = np.full(len(T), np.nan)
        stretch[painted] = rho[T[painted]].mean(axis=1) / radius
    else:                                         # sprayed, or a sheet wrapped on a plane (= sprayed along its normal)
        uv = paint_coordinates_mm(paint, V)
        stretch = np.full(len(T), np.nan)
        stretch[painted] = 1.0 / facing[painted]
    if not painted.any():
        raise ValueError(f"{source}: no face turns towards the paint direction {tuple(np.round(d, 6))} within "
                         f"{paint.max_angle_deg:g} deg; nothing is painted")
    used = np.unique(T[painted])
    lo, hi = uv[used].min(axis=0), uv[used].max(axis=0)
    texel = paint.texel
    if paint.kind == "checker":
        lo = np.floor(lo / texel) * texel          # squares aligned with u = v = 0 of the texture plane
        hi = np.ceil(hi / texel) * texel
    else:
        lo, hi = lo - 2 * texel, hi + 2 * texel
    cols, rows = (int(np.ceil((hi[i] - lo[i]) / texel - 1e-9)) for i in range(2))
    cols, rows = max(cols, 1), max(rows, 1)
    m = paint.lookup_factor
    if rows * cols * m * m > MAX_TEXELS:
        raise ValueError(f"{source}: a {cols * m} x {rows * m} texel paint texture ({texel / m:g} mm texels over "
                         f"{hi[0] - lo[0]:.1f} x {hi[1] - lo[1]:.1f} mm, {LOOKUP_TEXELS_PER_SPECKLE:g} per speckle) is "
                         f"too large; give a larger speckle_mm or paint less (max_angle_deg)")
    return PaintLayout(uv, painted, lo, (rows, cols), stretch, np.array([cols, rows]) * texel, radius)


def pattern(paint: Paint, shape: tuple) -> np.ndarray:
    """The speckle's samples (rows, cols) float32 at the paint's ``texel`` (the paint is their band-limited
    interpolant, periodic over ``shape``)."""
    from scenes.surfaces.speckle import speckle_pattern

    smoothing = None if paint.edge_mm is None else paint.edge_mm / paint.texel
    return speckle_pattern(tuple(shape), paint.speckle_mm / paint.texel, density=paint.density,
                           contrast=paint.contrast, mean=paint.mean, seed=paint.seed, smoothing_texels=smoothing)


def texture(paint: Paint, shape: tuple, origin_mm) -> np.ndarray:
    """The texture the renderers look up, float32, covering the layout's ``shape`` (rows, cols) of pattern texels
    from ``origin_mm`` (row 0 at ``v = origin_v``, column 0 at ``u = origin_u``): a checker's squares, or the
    speckle's band-limited interpolant at :attr:`Paint.lookup_factor` texels per pattern texel (shape
    ``(rows * m, cols * m)``)."""
    from scenes.surfaces.speckle import fourier_upsample

    rows, cols = shape
    if paint.kind == "checker":
        i0, j0 = (int(round(o / paint.checker_mm)) for o in np.asarray(origin_mm)[::-1])
        r, c = np.meshgrid(np.arange(rows) + i0, np.arange(cols) + j0, indexing="ij")
        return np.where((r + c) % 2 == 0, paint.mean + 0.5 * paint.contrast, paint.mean - 0.5 * paint.contrast
                        ).astype(np.float32)
    return np.clip(fourier_upsample(pattern(paint, shape), paint.lookup_factor), 0.0, 1.0)
