"""Deterministic pinhole renders, no Monte Carlo: exact for prints, Gauss-Legendre quadrature for speckle.

A pinhole camera sees a printed target (checkerboard, ChArUco, dot grid: a ``"nearest"``-filtered texture on a
triangle mesh) as a picture that is constant on polygons. The value Mitsuba's box-filtered film converges to is
the mean radiance over each pixel's square on the sensor, i.e. the sum over the picture's polygons of radiance
times the fraction of the pixel each covers. This module computes that sum exactly:

1. every triangle is cut along its texels' boundaries into polygons of one radiance (clipping in texture
   space, mapped to the world by the triangle's affine map);
2. every polygon edge is projected by the truth side's camera (:func:`scenes.optics.projection.project_points`: the same
   tilted sensor and lens distortion as the Mitsuba sensor plugin), split into as many straight pieces as keep
   the projected curve within ``chord_tol_px`` of its chords (distortion bends straight edges);
3. :func:`scenes.rendering.coverage_raster.accumulate_flat` adds radiance x exact covered area per pixel.

A smoothly (bilinearly) interpolated texture, a speckle print, is not constant on polygons: its pixel is the
exact coverage of its triangles times the mean texture over the covered part, the mean by an ``n x n``
Gauss-Legendre rule per pixel (:mod:`scenes.rendering.quadrature_raster`; 6 x 6 by default: ~0.05 grey RMS from converged
Mitsuba renders, ``benchmarks/render_exact_speckle.py``). A closed mesh (the specimen box) is drawn without its
back faces, which its front faces hide.

Through a thin lens, :func:`render_view_in_focus` makes the pixels whose blur circle stays below
:data:`MAX_BLUR_PX` (a face in the plane of sharp focus: the Scheimpflug rig's specimen face) the same way, and
says which pixels it could not make (blurred faces, silhouettes, what they spill on) for Mitsuba's adaptive
renderer to trace alone (:func:`scenes.rendering.adaptive.render_views_auto`).

What it cannot render this way is refused with :class:`NotExactError` naming the reason, for the caller to fall
back to Mitsuba: a thin lens in :func:`render_view_exact` (defocus), surfaces that overlap in the image
(occlusion: detected exactly, as a pixel covered more than once), a surface reaching behind the camera. The
agreement with Mitsuba is measured, not assumed (``tests/test_exact_render.py``).
"""
from __future__ import annotations

import functools

import numpy as np

from scenes.optics.camera import SensorSpec
from scenes.rendering.coverage_raster import accumulate_flat
from scenes.surfaces.textured_surface import TexturedSurface

#: Name recorded with every image of prints only (exact).
RENDERER = "exact-polygon"
#: Name recorded with an image holding a bilinear texture (exact coverage, quadrature of the texture mean).
RENDERER_QUADRATURE = "polygon-quadrature"
#: Name recorded with a thin-lens image whose in-focus pixels are :func:`render_view_in_focus`'s and the rest
#: (the faces it blurs beyond :data:`MAX_BLUR_PX`) Mitsuba's adaptive renders.
RENDERER_IN_FOCUS = "in-focus-quadrature+mitsuba-adaptive"
#: Gauss-Legendre nodes per pixel side for bilinear textures (``tests/test_exact_render.py`` measures the error).
QUADRATURE_ORDER = 6
#: Largest distance allowed between a projected edge and its straight pieces, px.
CHORD_TOL_PX = 1e-4
#: Coverage above 1 by more than this means two surfaces overlap in the image.
OVERLAP_TOL = 1e-6
#: Coverage below 1 by at most this counts as a wholly covered pixel (the exact areas' float rounding).
COVERED_TOL = 1e-6
#: Largest thin-lens blur circle (diameter, px) of a face :func:`render_view_in_focus` draws as sharp.
MAX_BLUR_PX = 0.1
#: A depth step between neighbouring pixel centres above this many pixel footprints is an occluding edge (one
#: surface seen at the 70 deg grazing limit steps ~3 footprints per pixel).
OCCLUSION_JUMP_FOOTPRINTS = 10.0
#: Faces seen more obliquely than this (deg from their normal) are left to Mitsuba by :func:`render_view_occluded`.
OCCLUSION_GRAZING_DEG = 75.0
#: Name recorded with a view whose occluding edges Mitsuba's adaptive renderer traced and the rest is exact.
RENDERER_OCCLUSION = "occlusion-quadrature+mitsuba-adaptive"


class NotExactError(ValueError):
    """A view this renderer cannot make exactly; the message says why (the caller falls back to Mitsuba)."""


def _clip_polygon(poly: np.ndarray, a: np.ndarray, b: np.ndarray, inside_sign: float) -> np.ndarray:
    """Sutherland-Hodgman: the part of ``poly`` (K, 2) on the ``inside_sign`` side of the line a -> b."""
    if len(poly) == 0:
        return poly
    d = b - a
    side = inside_sign * (d[0] * (poly[:, 1] - a[1]) - d[1] * (poly[:, 0] - a[0]))
    out = []
    n = len(poly)
    for i in range(n):
        j = (i + 1) % n
        p, q, sp, sq = poly[i], poly[j], side[i], side[j]
        if sp >= 0:
            out.append(p)
        if (sp >= 0) != (sq >= 0):
            t = sp / (sp - sq)
            out.append(p + t * (q - p))
    return np.array(out) if out else np.zeros((0, 2))


def _texel_polygons(surface: TexturedSurface, faces: np.ndarray) -> tuple[list[np.ndarray], np.ndarray, np.ndarray]:
    """World polygons of one radiance: each triangle of ``faces`` cut along its texels (nearest filter).

    Returns the polygons (K, 3) in mm, their radiance and the index of the triangle each came from. A triangle
    inside one texel (every face of a per-square patch mesh) is one polygon; only those spanning texels are cut.
    """
    tex = np.asarray(surface.texture, dtype=np.float64)
    rows, cols = tex.shape
    V = np.asarray(surface.vertices_mm, dtype=np.float64)
    T_all = np.asarray(surface.uv, dtype=np.float64)[faces] * np.array([cols, rows])   # (F, 3, 2), texel units
    lo = np.clip(np.floor(T_all.min(axis=1) + 1e-9).astype(int), 0, [cols - 1, rows - 1])
    hi = np.clip(np.floor(T_all.max(axis=1) - 1e-9).astype(int), 0, [cols - 1, rows - 1])
    single = np.all(lo == hi, axis=1)
    polys = list(V[faces[single]])
    values = list(tex[lo[single, 1], lo[single, 0]])
    owner = list(np.flatnonzero(single))
    for f_index in np.flatnonzero(~single):
        P, T = V[faces[f_index]], T_all[f_index]
        M = np.column_stack([T[1] - T[0], T[2] - T[0]])
        if abs(np.linalg.det(M)) < 1e-14:
            raise NotExactError("a triangle spans several texels with a degenerate texture mapping")
        Minv = np.linalg.inv(M)
        e1, e2 = T[1] - T[0], T[2] - T[0]
        orient = 1.0 if e1[0] * e2[1] - e1[1] * e2[0] > 0 else -1.0
        # clamp-to-edge: the outermost texels extend to whatever part of the triangle lies beyond them (just
        # beyond the triangle's box: a far-away bound would cost the clipped points their precision)
        far_lo, far_hi = T.min(axis=0) - 1.0, T.max(axis=0) + 1.0
        for r in range(lo[f_index, 1], hi[f_index, 1] + 1):
            for c in range(lo[f_index, 0], hi[f_index, 0] + 1):
                x0 = c if c > 0 else min(0.0, far_lo[0])
                x1 = c + 1 if c < cols - 1 else max(float(cols), far_hi[0])
                y0 = r if r > 0 else min(0.0, far_lo[1])
                y1 = r + 1 if r < rows - 1 else max(float(rows), far_hi[1])
                poly = np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]], dtype=np.float64)
                for k in range(3):
                    poly = _clip_polygon(poly, T[k], T[(k + 1) % 3], orient)
                    if len(poly) < 3:
                        break
                if len(poly) < 3:
                    continue
                bary = (poly - T[0]) @ Minv.T                   # (K, 2): weights of P1 - P0 and P2 - P0
                polys.append(P[0] + bary[:, :1] * (P[1] - P[0]) + bary[:, 1:] * (P[2] - P[0]))
                values.append(float(tex[r, c]))
                owner.append(int(f_index))
    return polys, np.asarray(values, dtype=np.float64), np.asarray(owner, dtype=np.int64)


def project_outlines(spec: SensorSpec, R: np.ndarray, t: np.ndarray, polys: list[np.ndarray],
                      chord_tol_px: float) -> tuple[np.ndarray, np.ndarray]:
    """Every world polygon's outline in pixels, each edge split so its projection stays within the tolerance
    of its straight pieces; flat: (N, 2) vertices and (P + 1,) starts."""
    from scenes.optics.projection import project_points

    sizes = np.array([len(p) for p in polys], dtype=np.int64)
    starts = np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64)
    A = np.concatenate(polys)
    nxt = np.arange(len(A)) + 1
    nxt[starts[1:] - 1] = starts[:-1]
    B = A[nxt]
    ends = project_points(spec, R, t, np.concatenate([A, 0.5 * (A + B)]))
    if not np.all(np.isfinite(ends)):
        raise NotExactError("a surface reaches behind the camera (or parallel to the sensor)")
    pa, pm = ends[:len(A)], ends[len(A):]
    # the sagitta of a smooth projected curve falls as 1 / n^2 with n pieces
    sagitta = np.linalg.norm(pm - 0.5 * (pa + pa[nxt]), axis=1)
    pieces = np.maximum(1, np.ceil(np.sqrt(sagitta / chord_tol_px))).astype(np.int64)
    if np.all(pieces == 1):
        return pa, starts
    # edge e contributes its start and pieces[e] - 1 inner points, in order
    edge = np.repeat(np.arange(len(A)), pieces)
    k = np.arange(edge.size) - np.repeat(np.cumsum(pieces) - pieces, pieces)
    s = (k / pieces[edge])[:, None]
    xy = np.empty((edge.size, 2))
    first = k == 0
    xy[first] = pa[edge[first]]
    inner = ~first
    xy[inner] = project_points(spec, R, t, A[edge[inner]] + s[inner] * (B[edge[inner]] - A[edge[inner]]))
    per_polygon = np.add.reduceat(pieces, starts[:-1])
    return xy, np.concatenate([[0], np.cumsum(per_polygon)]).astype(np.int64)


def closed_surface(surfaces: list[TexturedSurface]) -> bool:
    """True when the surfaces together form a closed, consistently oriented mesh (every edge, matched by its
    vertices' exact coordinates, used once in each direction): seen from outside, its back faces are hidden
    behind its front faces, so they can be left out of the image instead of being detected as an overlap."""
    V = np.ascontiguousarray(np.concatenate([np.asarray(s.vertices_mm, dtype=float) for s in surfaces]))
    offsets = np.cumsum([0] + [len(s.vertices_mm) for s in surfaces[:-1]])
    F = np.concatenate([np.asarray(s.faces, dtype=np.int64) + o for s, o in zip(surfaces, offsets)])
    # one id per distinct vertex position (rows compared as raw bytes: exact coordinates)
    _, ids = np.unique(V.view(np.dtype((np.void, V.dtype.itemsize * 3))).ravel(), return_inverse=True)
    F = ids.reshape(-1)[F]
    a = np.concatenate([F[:, 0], F[:, 1], F[:, 2]])
    b = np.concatenate([F[:, 1], F[:, 2], F[:, 0]])
    if np.any(a == b):
        return False
    n = np.int64(ids.max() + 1)
    directed = a * n + b
    unique_directed, counts = np.unique(directed, return_counts=True)
    if np.any(counts != 1):
        return False
    return bool(np.all(np.isin(b * n + a, unique_directed)))


def _corner_rays(spec: SensorSpec, x0: int, y0: int, w: int, h: int) -> np.ndarray:
    """(h + 1, w + 1, 3) camera-frame ray directions ``(x_n, y_n, 1)`` through the corners of a crop's pixels."""
    xy = sensor_corner_coordinates(spec)[y0:y0 + h + 1, x0:x0 + w + 1]
    if not np.all(np.isfinite(xy)):
        raise NotExactError("the lens distortion cannot be inverted over the textured surface's pixels")
    return np.concatenate([xy, np.ones(xy.shape[:2] + (1,))], axis=2)


@functools.lru_cache(maxsize=4)
def sensor_corner_coordinates(spec: SensorSpec) -> np.ndarray:
    """Ideal (undistorted) coordinates of every pixel corner of the sensor, (H + 1, W + 1, 2), read-only.

    Undistorting is the costliest part of a view that is not the quadrature itself (~1 s for a 5 MP crop), and
    the same for every state and seed a camera renders: computed once per camera (frozen, hashable spec)."""
    from scenes.optics.projection import ideal_coordinates

    xs = np.arange(spec.width + 1) - 0.5
    ys = np.arange(spec.height + 1) - 0.5
    X, Y = np.meshgrid(xs, ys)
    xy = ideal_coordinates(spec, np.column_stack([X.ravel(), Y.ravel()])).reshape(spec.height + 1, spec.width + 1, 2)
    xy.setflags(write=False)
    return xy


def render_view_exact(spec: SensorSpec, R_cam_from_world: np.ndarray, t_cam_from_world_mm: np.ndarray,
                      surfaces: list[TexturedSurface], *, exposure_grey: float = 255.0,
                      chord_tol_px: float = CHORD_TOL_PX, quadrature_order: int = QUADRATURE_ORDER
                      ) -> tuple[np.ndarray, dict]:
    """The box-filtered image of ``surfaces`` through a pinhole camera, without Monte Carlo.

    ``"nearest"`` surfaces (prints) are exact: the sum of their texel polygons' covered areas. ``"bilinear"``
    surfaces (speckle) are their exact coverage times the mean texture over the covered part, the mean by a
    Gauss-Legendre rule of ``quadrature_order ** 2`` nodes per pixel (:mod:`scenes.rendering.quadrature_raster`). A closed
    mesh (:func:`closed_surface`) is drawn without its back faces.

    Parameters
    ----------
    spec : SensorSpec (``lens == "pinhole"``)
    R_cam_from_world, t_cam_from_world_mm : the camera pose, ``X_cam = R X_world + t``
    surfaces : TexturedSurface
    exposure_grey : grey levels per unit radiance
    quadrature_order : Gauss-Legendre nodes per pixel side for bilinear textures

    Returns
    -------
    image_grey : (height, width) float32, noise-free grey levels (0 where no surface is seen)
    info : dict with ``renderer`` (:data:`RENDERER` for prints only, :data:`RENDERER_QUADRATURE` with a
        bilinear texture), ``polygons``, ``crop`` (x0, y0, width, height), the largest pixel coverage (1 where a
        surface covers a whole pixel), ``quadrature_nodes`` and ``back_faces_culled``

    Raises
    ------
    NotExactError
        When the view is outside what this renderer makes exactly (module docstring).
    """
    if spec.lens != "pinhole":
        raise NotExactError(f"the {spec.lens} lens blurs (defocus): only a pinhole image has no blur")
    if not surfaces:
        raise ValueError("nothing to render: no surfaces given")
    R = np.asarray(R_cam_from_world, dtype=float)
    t = np.asarray(t_cam_from_world_mm, dtype=float).reshape(3)
    cull = closed_surface(surfaces)
    drawn, emitting = [], []
    for surface in surfaces:
        facing = facing_distance_mm(surface, -R.T @ t) > 0          # the emitting side is seen
        drawn.append(facing if cull else np.ones(len(facing), dtype=bool))
        emitting.append(facing)
    image, coverage, info = _draw(spec, R, t, surfaces, drawn, emitting, exposure_grey, chord_tol_px,
                                  quadrature_order)
    info["back_faces_culled"] = bool(cull)
    return image, info


def render_view_in_focus(spec: SensorSpec, R_cam_from_world: np.ndarray, t_cam_from_world_mm: np.ndarray,
                         surfaces: list[TexturedSurface], *, max_blur_px: float = MAX_BLUR_PX,
                         exposure_grey: float = 255.0, chord_tol_px: float = CHORD_TOL_PX,
                         quadrature_order: int = QUADRATURE_ORDER) -> tuple[np.ndarray, np.ndarray, dict]:
    """The pixels of a view that need no Monte Carlo, through a pinhole *or a thin lens*, and which ones they are.

    A pinhole view is :func:`render_view_exact` whole (every pixel known). Through a thin lens, the rays of a
    pixel converge on its chief ray in the plane of sharp focus and spread around it by the blur circle of the
    depth they meet: where that circle is at most ``max_blur_px`` across, the thin-lens pixel is the pinhole
    pixel convolved with a disc of radius ``<= max_blur_px / 2``, an error of ``r^2 / 8`` times the image's
    Laplacian (about 0.01 grey on the paper's speckle at 0.1 px; measured in ``tests/test_exact_render.py``).
    A pixel is *known* when

    * every pixel of its 3 x 3 neighbourhood is wholly covered by such sharp faces (the disc cannot reach
      past them), and no other face (blurred beyond the limit, or seen edge-on from part of the aperture) lies
      within its own blur radius + 1 px; or
    * no face at all lies within reach (sharp faces: 1 px; the others: their blur radius + 1 px): it is 0.

    The rest (blurred side faces, silhouettes, what they spill on) is for Mitsuba
    (:func:`scenes.rendering.adaptive.render_views_adaptive` with ``known=``).

    Parameters
    ----------
    spec, R_cam_from_world, t_cam_from_world_mm, surfaces, exposure_grey, chord_tol_px, quadrature_order :
        as :func:`render_view_exact`
    max_blur_px : largest blur circle diameter of a face drawn as sharp, px

    Returns
    -------
    image_grey : (height, width) float32, the known pixels' grey levels (0 elsewhere)
    known : (height, width) bool
    info : :func:`render_view_exact`'s, with ``known_fraction`` (of the pixels where any surface is seen or
        spills, ``reached_pixels`` of them), ``max_blur_px`` and ``sharp_faces`` / ``blurred_faces``

    Raises
    ------
    NotExactError
        A surface behind the camera, or sharp faces that overlap in the image.
    """
    if spec.lens == "pinhole":
        image, info = render_view_exact(spec, R_cam_from_world, t_cam_from_world_mm, surfaces,
                                        exposure_grey=exposure_grey, chord_tol_px=chord_tol_px,
                                        quadrature_order=quadrature_order)
        info.update(known_fraction=1.0, max_blur_px=0.0, reached_pixels=int(image.size))
        return image, np.ones(image.shape, dtype=bool), info
    if not surfaces:
        raise ValueError("nothing to render: no surfaces given")
    if not max_blur_px >= 0:
        raise ValueError(f"max_blur_px must be >= 0, got {max_blur_px}")
    from scipy.ndimage import maximum_filter, minimum_filter

    from scenes.optics.projection import defocus_blur_px

    R = np.asarray(R_cam_from_world, dtype=float)
    t = np.asarray(t_cam_from_world_mm, dtype=float).reshape(3)
    centre = -R.T @ t
    aperture_radius_mm = 0.5 * spec.focal_length_mm / spec.f_number
    cull = closed_surface(surfaces)
    sharp, emitting, other = [], [], []
    other_blur_px = 0.0
    for surface in surfaces:
        distance = facing_distance_mm(surface, centre)
        # a face whose plane passes through the aperture is seen from one side by part of it: never sharp
        front, back = distance > aperture_radius_mm, distance < -aperture_radius_mm
        faces = np.asarray(surface.faces, dtype=int)
        blur = defocus_blur_px(spec, R, t, surface.vertices_mm)[faces].max(axis=1)
        seen = ~back if cull else np.ones(len(faces), dtype=bool)
        ok = (front | back) & (blur <= max_blur_px) & seen              # NaN blur (behind the lens) is not ok
        sharp.append(ok)
        emitting.append(ok & front)
        other.append(seen & ~ok)
        if (seen & ~ok).any():
            other_blur_px = max(other_blur_px, float(np.nanmax(np.where(seen & ~ok, blur, 0.0))))
    image, coverage, info = _draw(spec, R, t, surfaces, sharp, emitting, exposure_grey, chord_tol_px,
                                  quadrature_order)
    reach_other = int(np.ceil(0.5 * other_blur_px)) + 1
    near_other = np.zeros(image.shape, dtype=bool)
    if any(o.any() for o in other):
        tris = [np.asarray(s.vertices_mm, dtype=float)[np.asarray(s.faces, dtype=int)[o]]
                for s, o in zip(surfaces, other)]
        polys = list(np.concatenate([tri for tri in tris if len(tri)]))
        xy, starts = project_outlines(spec, R, t, polys, max(chord_tol_px, 0.05))
        # a blurred face just outside the sensor spills onto its edge: the window reaches past the sensor
        r = reach_other + 1
        x0 = int(np.clip(np.floor(xy[:, 0].min()) - r, -r, spec.width + r))
        y0 = int(np.clip(np.floor(xy[:, 1].min()) - r, -r, spec.height + r))
        x1 = int(np.clip(np.ceil(xy[:, 0].max()) + r + 1, -r, spec.width + r))
        y1 = int(np.clip(np.ceil(xy[:, 1].max()) + r + 1, -r, spec.height + r))
        if x1 > x0 and y1 > y0:
            cov = accumulate_flat(xy, starts, np.ones(len(polys)), (y1 - y0, x1 - x0), (x0, y0))
            near = maximum_filter(np.abs(cov) > 0, size=2 * reach_other + 1)
            ix0, iy0 = max(x0, 0), max(y0, 0)
            ix1, iy1 = min(x1, spec.width), min(y1, spec.height)
            if ix1 > ix0 and iy1 > iy0:
                near_other[iy0:iy1, ix0:ix1] = near[iy0 - y0:iy1 - y0, ix0 - x0:ix1 - x0]
    whole = coverage >= 1.0 - COVERED_TOL
    lit = coverage > 0
    # beyond the sensor's edge nothing is known (cval): its edge pixels are Mitsuba's where a surface is seen
    known = ((minimum_filter(whole, size=3, mode="constant", cval=False)
              | ~maximum_filter(lit, size=3, mode="constant", cval=True)) & ~near_other)
    image[~known] = 0.0
    reached = ~known | lit
    info.update(renderer=RENDERER_QUADRATURE if info.get("quadrature_nodes") else RENDERER,
                back_faces_culled=bool(cull), max_blur_px=float(max_blur_px),
                sharp_faces=int(sum(int(s.sum()) for s in sharp)),
                blurred_faces=int(sum(int(o.sum()) for o in other)),
                known_fraction=float((known & reached).sum() / max(int(reached.sum()), 1)),
                reached_pixels=int(reached.sum()))
    return image, known, info


def render_view_occluded(spec: SensorSpec, R_cam_from_world: np.ndarray, t_cam_from_world_mm: np.ndarray,
                         surfaces: list[TexturedSurface], *, exposure_grey: float = 255.0,
                         chord_tol_px: float = CHORD_TOL_PX, quadrature_order: int = QUADRATURE_ORDER
                         ) -> tuple[np.ndarray, np.ndarray, dict]:
    """A pinhole view of surfaces that hide one another (a tube's far wall, a hole's bore, a notch), without Monte
    Carlo wherever no occlusion edge passes.

    The truth side's ray cast (:func:`scenes.specimens.ray_surface.cast_rays`) gives the nearest depth at every pixel centre;
    a face no pixel-centre ray hits and whose plane lies behind that depth at every pixel of its widened projected box
    is hidden and dropped (:func:`scenes.specimens.ray_surface.possibly_visible`). The rest is drawn exactly as by
    :func:`render_view_exact`, overlaps allowed: a pixel is *known* unless its 3 x 3 neighbourhood holds a pixel
    covered more than once (an occluding edge over the surface behind it) or a depth jump of more than
    :data:`OCCLUSION_JUMP_FOOTPRINTS` pixel footprints between neighbouring pixel centres (an occluding edge over
    the background), or a face seen more obliquely than :data:`OCCLUSION_GRAZING_DEG` (a limb). Unknown pixels are
    for Mitsuba (:func:`scenes.rendering.adaptive.render_views_adaptive` with
    ``known=``).

    Returns ``(image_grey, known, info)`` as :func:`render_view_in_focus`; ``info`` adds ``hidden_faces``.
    """
    from scipy.ndimage import maximum_filter

    from scenes.specimens.ray_surface import cast_rays, possibly_visible

    if spec.lens != "pinhole":
        raise NotExactError(f"the {spec.lens} lens blurs (defocus): occlusion is drawn for a pinhole only")
    if not surfaces:
        raise ValueError("nothing to render: no surfaces given")
    R = np.asarray(R_cam_from_world, dtype=float)
    t = np.asarray(t_cam_from_world_mm, dtype=float).reshape(3)
    cull = closed_surface(surfaces)
    centre = -R.T @ t
    facing = [facing_distance_mm(s, centre) > 0 for s in surfaces]
    candidates = [f if cull else np.ones(len(f), dtype=bool) for f in facing]
    V = np.concatenate([np.asarray(s.vertices_mm, dtype=float) for s in surfaces])
    offsets = np.cumsum([0] + [len(s.vertices_mm) for s in surfaces[:-1]])
    F = np.concatenate([np.asarray(s.faces, dtype=np.int64)[c] + o for s, c, o in zip(surfaces, candidates, offsets)])
    try:
        hits = cast_rays(spec, R, t, V, F)
    except ValueError as err:                     # a surface behind the camera
        raise NotExactError(str(err)) from None
    visible = possibly_visible(spec, R, t, V, F, hits.depth_mm, hits.triangle)
    drawn, start = [], 0
    for c in candidates:
        d = np.zeros(len(c), dtype=bool)
        d[np.flatnonzero(c)] = visible[start:start + int(c.sum())]
        start += int(c.sum())
        drawn.append(d)
    emitting = [d & f for d, f in zip(drawn, facing)]
    image, coverage, info = _draw(spec, R, t, surfaces, drawn, emitting, exposure_grey, chord_tol_px,
                                  quadrature_order, allow_overlap=True)
    depth = hits.depth_mm
    finite = np.isfinite(depth)
    limit = OCCLUSION_JUMP_FOOTPRINTS * np.where(finite, depth, 0.0) / min(spec.fx, spec.fy)
    jump = np.zeros(depth.shape, dtype=bool)
    for a, b, la in ((depth[:, 1:], depth[:, :-1], limit[:, 1:]), (depth[1:], depth[:-1], limit[1:])):
        both = np.isfinite(a) & np.isfinite(b)
        j = both & (np.abs(a - np.where(both, b, 0.0)) > la)
        if a.shape[1] != depth.shape[1]:
            jump[:, 1:] |= j
            jump[:, :-1] |= j
        else:
            jump[1:] |= j
            jump[:-1] |= j
    # a face seen nearly edge-on (a tube's limb): the quadrature's node hits are ill-conditioned there
    grazing = np.zeros(depth.shape, dtype=bool)
    hit = hits.triangle >= 0
    if hit.any():
        Vc = V @ R.T + t
        tri = F[hits.triangle[hit]]
        n = np.cross(Vc[tri[:, 1]] - Vc[tri[:, 0]], Vc[tri[:, 2]] - Vc[tri[:, 0]])
        from scenes.specimens.ray_surface import pixel_centre_rays
        d = np.concatenate([pixel_centre_rays(spec)[hit], np.ones((int(hit.sum()), 1))], axis=1)
        cos = np.abs(np.einsum("ij,ij->i", n, d)) / (np.linalg.norm(n, axis=1) * np.linalg.norm(d, axis=1))
        grazing[hit] = cos < np.cos(np.radians(OCCLUSION_GRAZING_DEG))
    known = ~maximum_filter((coverage > 1.0 + OVERLAP_TOL) | jump | grazing, size=3)
    image[~known] = 0.0
    lit = coverage > 0
    reached = ~known | lit
    info.update(back_faces_culled=bool(cull), hidden_faces=int(sum(int((c & ~d).sum()) for c, d in zip(candidates, drawn))),
                known_fraction=float((known & reached).sum() / max(int(reached.sum()), 1)),
                reached_pixels=int(reached.sum()))
    return image, known, info


def facing_distance_mm(surface: TexturedSurface, centre_world_mm: np.ndarray) -> np.ndarray:
    """Signed distance of the camera centre from every face's plane, mm (> 0: the emitting side is seen)."""
    faces = np.asarray(surface.faces, dtype=int)
    V = np.asarray(surface.vertices_mm, dtype=float)
    normals = np.cross(V[faces[:, 1]] - V[faces[:, 0]], V[faces[:, 2]] - V[faces[:, 0]])
    length = np.linalg.norm(normals, axis=1)
    return np.einsum("ij,ij->i", normals, centre_world_mm - V[faces[:, 0]]) / np.where(length > 0, length, 1.0)


def _pixel_box(xy: np.ndarray, spec: SensorSpec, margin: int):
    """(x0, y0, x1, y1) pixel window around projected points widened by ``margin``, clipped; None if empty."""
    x0 = int(np.clip(np.floor(xy[:, 0].min()) - margin, 0, spec.width))
    y0 = int(np.clip(np.floor(xy[:, 1].min()) - margin, 0, spec.height))
    x1 = int(np.clip(np.ceil(xy[:, 0].max()) + margin + 1, 0, spec.width))
    y1 = int(np.clip(np.ceil(xy[:, 1].max()) + margin + 1, 0, spec.height))
    return None if x1 <= x0 or y1 <= y0 else (x0, y0, x1, y1)


def _draw(spec, R, t, surfaces, drawn, emitting, exposure_grey, chord_tol_px, quadrature_order,
          allow_overlap: bool = False) -> tuple[np.ndarray, np.ndarray, dict]:
    """Image and coverage of the ``drawn`` faces of every surface (``emitting`` ones with their radiance, the
    rest black but opaque), full sensor; refuses overlapping faces unless ``allow_overlap`` (the caller then
    leaves the pixels covered more than once to a ray tracer)."""
    polys, values, front, smooth = [], [], [], []      # smooth: index of the bilinear surface, -1 for prints
    bilinear = []
    for index, (surface, draw, emit) in enumerate(zip(surfaces, drawn, emitting)):
        faces = np.asarray(surface.faces, dtype=int)
        V = np.asarray(surface.vertices_mm, dtype=float)
        lit, dark = draw & emit, draw & ~emit
        if surface.filter == "bilinear":
            bilinear.append((surface, faces[lit], len(polys), len(polys) + int(lit.sum())))
            polys += list(V[faces[lit]]) + list(V[faces[dark]])
            values.append(np.zeros(int(draw.sum())))
            front.append(np.concatenate([np.ones(int(lit.sum()), dtype=bool), np.zeros(int(dark.sum()), dtype=bool)]))
            smooth.append(np.full(int(draw.sum()), index))
            continue
        p, v, owner = _texel_polygons(surface, faces)
        keep = draw[owner]
        polys += [q for q, k in zip(p, keep) if k]
        values.append(v[keep])
        front.append(emit[owner][keep])
        smooth.append(np.full(int(keep.sum()), -1))
    values, front, smooth = np.concatenate(values), np.concatenate(front), np.concatenate(smooth)
    info = {"renderer": RENDERER_QUADRATURE if bilinear else RENDERER, "polygons": len(polys), "crop": [0, 0, 0, 0],
            "max_coverage": 0.0}
    if bilinear:
        info["quadrature_nodes"] = int(quadrature_order) ** 2
    image = np.zeros((spec.height, spec.width), dtype=np.float32)
    coverage = np.zeros((spec.height, spec.width), dtype=np.float64)
    if not polys:
        return image, coverage, info
    xy, starts = project_outlines(spec, R, t, polys, chord_tol_px)
    box = _pixel_box(xy, spec, 1)
    if box is None:
        return image, coverage, info
    x0, y0, x1, y1 = box
    info["crop"] = [x0, y0, x1 - x0, y1 - y0]
    shape = (y1 - y0, x1 - x0)
    window_coverage = accumulate_flat(xy, starts, np.ones(len(polys)), shape, (x0, y0))
    info["max_coverage"] = float(window_coverage.max())
    if window_coverage.max() > 1.0 + OVERLAP_TOL and not allow_overlap:
        raise NotExactError(f"surfaces overlap in the image (a pixel is covered {window_coverage.max():.4f} times): "
                            "occlusion needs ray tracing")
    weights = np.where(front & (smooth < 0), values * float(exposure_grey), 0.0)
    window = accumulate_flat(xy, starts, weights, shape, (x0, y0))
    if bilinear:
        window += _bilinear_window(spec, R, t, bilinear, xy, starts, (x0, y0), shape, exposure_grey,
                                   quadrature_order)
    image[y0:y1, x0:x1] = window.astype(np.float32)
    coverage[y0:y1, x0:x1] = window_coverage
    return image, coverage, info


def _bilinear_window(spec, R, t, bilinear, xy, starts, origin, shape, exposure_grey, order) -> np.ndarray:
    """Grey levels of the bilinear surfaces over the crop: exact coverage x quadrature mean (see above)."""
    from scenes.rendering.quadrature_raster import fill_from_neighbours, integrate_triangles

    x0, y0 = origin
    h, w = shape
    rays = _corner_rays(spec, x0, y0, w, h)
    out = np.zeros(shape)
    for surface, faces, first, stop in bilinear:
        if stop == first:
            continue
        sel = np.zeros(len(starts) - 1)
        sel[first:stop] = 1.0
        covered = accumulate_flat(xy, starts, sel, shape, (x0, y0))
        V = np.asarray(surface.vertices_mm, dtype=float) @ R.T + t
        tex = np.asarray(surface.texture)
        rows, cols = tex.shape
        uv = np.asarray(surface.uv, dtype=float) * np.array([cols, rows]) - 0.5
        # each triangle's pixel range, from its projected (edge-subdivided) outline
        seg = slice(starts[first], starts[stop])
        local = starts[first:stop] - starts[first]
        lo = np.minimum.reduceat(xy[seg], local, axis=0)
        hi = np.maximum.reduceat(xy[seg], local, axis=0)
        boxes = np.column_stack([np.floor(lo[:, 0] + 0.5) - x0, np.floor(lo[:, 1] + 0.5) - y0,
                                 np.floor(hi[:, 0] + 0.5) + 1 - x0, np.floor(hi[:, 1] + 0.5) + 1 - y0]).astype(np.int64)
        boxes[:, [0, 2]] = np.clip(boxes[:, [0, 2]], 0, w)
        boxes[:, [1, 3]] = np.clip(boxes[:, [1, 3]], 0, h)
        S, Wt = integrate_triangles(V[faces], uv[faces], boxes, rays, tex, order)
        known = Wt > 0
        mean = np.where(known, S / np.where(known, Wt, 1.0), 0.0)
        mean = fill_from_neighbours(mean, known, covered > 0)
        out += float(exposure_grey) * np.clip(covered, 0.0, 1.0) * mean
    return out
