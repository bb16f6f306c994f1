"""Thin-lens pixels of flat painted faces without Monte Carlo: a quadrature over the pixel and the aperture.

Through the project's thin lens (:mod:`scenes.optics.camera`) a pixel is the mean radiance, over its square on the
sensor and over the aperture disc, of the rays that leave a point ``a`` of the disc towards the conjugate ``F``
of the sensor point in the plane of sharp focus. Where every such ray of a pixel meets one flat face whose
texture coordinates are an affine map of its plane (a speckled plate, a specimen's flat face), the radiance of a
ray is the texture's bilinear value at its hit, so the pixel is a 4-D integral of a smooth function over
(pixel square) x (disc), with no approximation in the geometry. This module evaluates it with a product rule:

* pixel: ``n_p x n_p`` Gauss-Legendre nodes;
* disc: ``n_r`` rings, Gauss-Legendre in ``r^2`` (the uniform measure Mitsuba samples), ``n_t`` equally spaced
  angles per ring, the angles of pixel node ``j`` turned by ``j / n_p^2`` of a step so that the blur offsets of
  the pixel's nodes interleave.

A ray of the disc lands within the blur radius ``rho`` of the pixel in the pinhole image, so the rule a pixel
needs grows with ``rho``. It is **measured, not assumed**: per blur bin, candidate rules are run on the view's
own texture at its finest scale on the sensor (isotropic, the face's largest texels-per-pixel) against a rule a
few times denser, and the cheapest within ``tolerance_grey`` RMS is used; each bin's rule, node count and
measured error are returned. The whole renderer is checked against converged Mitsuba renders
(``tests/test_defocus_quadrature.py``, ``benchmarks/render_defocus.py``).

Which pixels: a ray of the pixel's bundle meets the face at a point whose pinhole image lies within the blur
radius there; a pixel is made here when every pixel within its blur radius (+ :data:`EDGE_MARGIN_PX`) is wholly
covered by the flat face group (exact coverage, :mod:`scenes.rendering.coverage_raster`) and no other face's footprint,
widened by that face's own blur, reaches it. A face that is smooth but not flat (a deformed specimen, a curved
shell: a patch of triangles joined across edges bent by less than :data:`scenes.rendering.defocus_mesh.CREASE_DEG`, no flat
group of which holds :data:`PLANAR_SHARE` of its area) is integrated with the same rules by walking each node's
ray across its triangles (:mod:`scenes.rendering.defocus_mesh`); there the pixel must be covered by exactly one layer of
the patch. What is left (blurred silhouettes, prints) stays for Mitsuba's adaptive renderer
(:func:`scenes.rendering.adaptive.render_views_auto`).
"""
from __future__ import annotations

import math

import numba
import numpy as np

from scenes.optics.camera import SensorSpec
from scenes.rendering.coverage_raster import accumulate_flat
from scenes.rendering.exact import (MAX_BLUR_PX, NotExactError, closed_surface, facing_distance_mm, project_outlines,
                                    sensor_corner_coordinates)
from scenes.surfaces.textured_surface import TexturedSurface
from scenes.rendering.defocus_rules import (DEFAULT_TOLERANCE_GREY, choose_rule, texture_detail_texels,
                                           texture_fingerprint, thin_lens_rule)
from scenes.rendering.thin_lens_rays import focus_point

#: Name of this module's part of a render.
RENDERER_DEFOCUS = "defocus-quadrature"
#: Name recorded with a thin-lens image made whole without Monte Carlo: the in-focus pixels by
#: :func:`scenes.rendering.exact.render_view_in_focus`, the blurred flat faces here.
RENDERER_THIN_LENS = "in-focus-quadrature+defocus-quadrature"
#: ... and with one whose remaining pixels (blurred silhouettes, faces that are not flat) Mitsuba traced.
RENDERER_THIN_LENS_ADAPTIVE = "in-focus-quadrature+defocus-quadrature+mitsuba-adaptive"
#: Pixels kept between a pixel's blur circle and the edge of its face group (or another face's reach), px.
EDGE_MARGIN_PX = 2.0
#: A pixel's blur circle is taken this much larger where it is kept clear of edges (a tilted sensor
#: stretches the circle into an ellipse by a few per cent).
BLUR_MARGIN = 1.1
#: Upper edges of the blur-radius bins grow by this factor (px): a bin's rule is measured at its upper edge.
BIN_GROWTH = 1.1
#: Smallest bin edge, px (the in-focus renderer takes blur radii <= 0.05 px).
FIRST_BIN_PX = 0.05
#: Largest blur radius a pixel may have here, px (its edge distance is looked for no farther).
MAX_REACH_PX = 200.0
#: Flat face groups tried per surface (the largest by area); a curved mesh's triangles are left to Mitsuba.
MAX_GROUPS = 8
#: Flat face groups whose pinhole image is smaller than this are not tried, px^2 (a 20 px square).
MIN_GROUP_AREA_PX = 400.0
#: A smooth patch is integrated plane by plane where its largest flat group holds at least this share of its
#: area (a plate, a box's face), by walking its triangles (:mod:`scenes.rendering.defocus_mesh`) otherwise.
PLANAR_SHARE = 0.5
#: Side of the pixel tiles integrated in turn, px.
TILE_PX = 32





# --- the view ---------------------------------------------------------------------------------------------
@numba.njit(cache=True, parallel=True)
def _blur_and_scale(xy, r0, r1, c0, c1, cx, cy, fx, fy, e1z, e2z, v_mm, F_mm, A_mm, n, d, M, m):
    """Per pixel of rows [r0, r1) x cols [c0, c1): the blur radius (px, largest at its corners) of the plane's
    point on each corner's chief ray, the largest singular value of d texel / d pixel (texels per px) and
    that Jacobian ([[du/dx, du/dy], [dv/dx, dv/dy]], flat)."""
    h, w = r1 - r0, c1 - c0
    rho = np.empty((h + 1, w + 1))
    tu = np.empty((h + 1, w + 1))
    tv = np.empty((h + 1, w + 1))
    for i in numba.prange(h + 1):
        for j in range(w + 1):
            X, Y, Z = focus_point(xy, r0 + i, c0 + j, cx, cy, fx, fy, e1z, e2z, v_mm, F_mm)
            den = n[0] * X + n[1] * Y + n[2] * Z
            lam = d / den if den != 0.0 else -1.0
            if lam <= 0.0:
                rho[i, j] = np.inf
                tu[i, j] = np.nan
                tv[i, j] = np.nan
                continue
            rho[i, j] = A_mm * abs(lam - 1.0) * fx / (lam * Z)
            tu[i, j] = lam * (M[0, 0] * X + M[0, 1] * Y + M[0, 2] * Z) + m[0]
            tv[i, j] = lam * (M[1, 0] * X + M[1, 1] * Y + M[1, 2] * Z) + m[1]
    out_rho = np.empty((h, w))
    out_scale = np.empty((h, w))
    out_J = np.empty((h, w, 4), dtype=np.float32)
    for i in numba.prange(h):
        for j in range(w):
            out_rho[i, j] = max(max(rho[i, j], rho[i, j + 1]), max(rho[i + 1, j], rho[i + 1, j + 1]))
            a = 0.5 * (tu[i, j + 1] - tu[i, j] + tu[i + 1, j + 1] - tu[i + 1, j])
            b = 0.5 * (tu[i + 1, j] - tu[i, j] + tu[i + 1, j + 1] - tu[i, j + 1])
            cc = 0.5 * (tv[i, j + 1] - tv[i, j] + tv[i + 1, j + 1] - tv[i + 1, j])
            dd = 0.5 * (tv[i + 1, j] - tv[i, j] + tv[i + 1, j + 1] - tv[i, j + 1])
            # largest singular value of [[a, b], [cc, dd]]
            s1 = a * a + b * b + cc * cc + dd * dd
            det = a * dd - b * cc
            out_scale[i, j] = math.sqrt(0.5 * (s1 + math.sqrt(max(s1 * s1 - 4 * det * det, 0.0))))
            out_J[i, j, 0], out_J[i, j, 1], out_J[i, j, 2], out_J[i, j, 3] = a, b, cc, dd
    return out_rho, out_scale, out_J


def _node_table(rule: np.ndarray, A_mm: float, n: np.ndarray, M: np.ndarray) -> np.ndarray:
    """Per node of a rule, what does not depend on the pixel, as float32 rows (structure of arrays, (8, N)): its
    four corner weights, ``n . a``, the texel map's linear part ``M a`` (a: the node's aperture point, mm) and
    its weight."""
    px, py = rule[:, 0], rule[:, 1]
    ax, ay = A_mm * rule[:, 2], A_mm * rule[:, 3]
    return np.ascontiguousarray(np.vstack([(1 - px) * (1 - py), px * (1 - py), (1 - px) * py, px * py,
                                           n[0] * ax + n[1] * ay, M[0, 0] * ax + M[0, 1] * ay,
                                           M[1, 0] * ax + M[1, 1] * ay, rule[:, 4]]), dtype=np.float32)


@numba.njit(cache=True, inline="always")
def _corner(xy, r, c, cx, cy, fx, fy, e1z, e2z, v_mm, F_mm, n, M):
    """n . F, M F (the texel map's linear part) of sensor corner (r, c)'s focus point F (float64 scalars)."""
    X, Y, Z = focus_point(xy, r, c, cx, cy, fx, fy, e1z, e2z, v_mm, F_mm)
    return (n[0] * X + n[1] * Y + n[2] * Z, M[0, 0] * X + M[0, 1] * Y + M[0, 2] * Z,
            M[1, 0] * X + M[1, 1] * Y + M[1, 2] * Z)


@numba.njit(cache=True, parallel=True, fastmath=True)
def _integrate_pixels(rows, cols, bins, starts, nodes, xy, cx, cy, fx, fy, e1z, e2z, v_mm, F_mm, n, d, M, m,
                      margin, texture, out):
    """Each listed pixel's mean texture over its square and the aperture (bin ``bins[i]``'s nodes, as
    :func:`_node_table`), in float32 arithmetic (Mitsuba's own) on small, well-conditioned numbers.

    The ray from aperture point a towards the pixel point's conjugate F meets the plane ``n . X = d`` at
    ``F + kappa (F - a)``, ``kappa = (d - n . F) / (n . F - n . a)``; its texel is ``(M F + m) + kappa (M F - M a)``.
    ``n . F``, ``d - n . F`` and ``M F`` are linear in F, so they are taken at the pixel's corners once (float64)
    and blended per node. The texel position is kept relative to an integer texel ``margin`` texels (more than
    the blur's reach) before the pixel's chief-ray texel, so it is positive and small: its fraction keeps float32's precision
    (an absolute position of ~10^4 texels would keep only ~10^-3 texel) and truncation is the floor."""
    trows, tcols = texture.shape
    W0, W1, W2, W3 = nodes[0], nodes[1], nodes[2], nodes[3]
    NA, UA, VA, WT = nodes[4], nodes[5], nodes[6], nodes[7]
    for i in numba.prange(len(rows)):
        r, c = rows[i], cols[i]
        p0, P0, Q0 = _corner(xy, r, c, cx, cy, fx, fy, e1z, e2z, v_mm, F_mm, n, M)
        p1, P1, Q1 = _corner(xy, r, c + 1, cx, cy, fx, fy, e1z, e2z, v_mm, F_mm, n, M)
        p2, P2, Q2 = _corner(xy, r + 1, c, cx, cy, fx, fy, e1z, e2z, v_mm, F_mm, n, M)
        p3, P3, Q3 = _corner(xy, r + 1, c + 1, cx, cy, fx, fy, e1z, e2z, v_mm, F_mm, n, M)
        # the integer texel (iu, iv): margin texels before corner 0's chief-ray hit (a = 0) on the plane
        k0 = (d - p0) / p0
        iu = math.floor(P0 * (1.0 + k0) + m[0]) - margin
        iv = math.floor(Q0 * (1.0 + k0) + m[1]) - margin
        ou, ov = m[0] - iu, m[1] - iv
        n0, n1, n2, n3 = np.float32(p0), np.float32(p1), np.float32(p2), np.float32(p3)
        d0, d1, d2, d3 = np.float32(d - p0), np.float32(d - p1), np.float32(d - p2), np.float32(d - p3)
        U0, U1, U2, U3 = np.float32(P0), np.float32(P1), np.float32(P2), np.float32(P3)
        V0, V1, V2, V3 = np.float32(Q0), np.float32(Q1), np.float32(Q2), np.float32(Q3)
        a0, a1, a2, a3 = np.float32(P0 + ou), np.float32(P1 + ou), np.float32(P2 + ou), np.float32(P3 + ou)
        b0, b1, b2, b3 = np.float32(Q0 + ov), np.float32(Q1 + ov), np.float32(Q2 + ov), np.float32(Q3 + ov)
        # Mitsuba's clamp to the edge texels, in relative coordinates (exact integers in float32)
        xlo, xhi = np.float32(-iu), np.float32(tcols - 1 - iu)
        ylo, yhi = np.float32(-iv), np.float32(trows - 1 - iv)
        acc = np.float32(0.0)
        k = bins[i]
        for j in range(starts[k], starts[k + 1]):
            w0, w1, w2, w3 = W0[j], W1[j], W2[j], W3[j]
            kappa = (w0 * d0 + w1 * d1 + w2 * d2 + w3 * d3) / (w0 * n0 + w1 * n1 + w2 * n2 + w3 * n3 - NA[j])
            x = w0 * a0 + w1 * a1 + w2 * a2 + w3 * a3 + kappa * (w0 * U0 + w1 * U1 + w2 * U2 + w3 * U3 - UA[j])
            y = w0 * b0 + w1 * b1 + w2 * b2 + w3 * b3 + kappa * (w0 * V0 + w1 * V1 + w2 * V2 + w3 * V3 - VA[j])
            x = min(max(x, xlo), xhi)
            y = min(max(y, ylo), yhi)
            ix = min(iu + int(x), tcols - 2)
            jy = min(iv + int(y), trows - 2)
            tx = x - np.float32(ix - iu)
            ty = y - np.float32(jy - iv)
            t00 = texture[jy, ix]
            t01 = texture[jy, ix + 1]
            t10 = texture[jy + 1, ix]
            t11 = texture[jy + 1, ix + 1]
            top = t00 + tx * (t01 - t00)
            bottom = t10 + tx * (t11 - t10)
            acc += WT[j] * (top + ty * (bottom - top))
        out[i] = acc


def _tile_order(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rows and columns of ``mask``'s true pixels, tile by tile (:data:`TILE_PX` square tiles, row-major within
    each): the texels a tile's blur circles read stay in cache."""
    h, w = mask.shape
    T = TILE_PX
    ty, tx = -(-h // T), -(-w // T)
    padded = np.zeros((ty * T, tx * T), dtype=bool)
    padded[:h, :w] = mask
    idx = np.flatnonzero(padded.reshape(ty, T, tx, T).transpose(0, 2, 1, 3))
    tile, within = np.divmod(idx, T * T)
    rows = (tile // tx) * T + within // T
    cols = (tile % tx) * T + within % T
    return rows, cols


@numba.njit(cache=True)
def _bin_members(bins, scale, n_bins):
    """Per bin: its pixel count and the index of its pixel of largest texel scale (-1 when empty)."""
    counts = np.zeros(n_bins, dtype=np.int64)
    finest = -np.ones(n_bins, dtype=np.int64)
    for i in range(len(bins)):
        b = bins[i]
        counts[b] += 1
        if finest[b] < 0 or scale[i] > scale[finest[b]]:
            finest[b] = i
    return counts, finest


def _face_groups(V_cam: np.ndarray, faces: np.ndarray, candidates: np.ndarray) -> list[np.ndarray]:
    """Indices of ``candidates`` faces grouped by plane (unit normal to 1e-9, offset to 1e-6 mm), largest
    area first."""
    idx = np.flatnonzero(candidates)
    if idx.size == 0:
        return []
    P = V_cam[faces[idx]]
    nrm = np.cross(P[:, 1] - P[:, 0], P[:, 2] - P[:, 0])
    area = 0.5 * np.linalg.norm(nrm, axis=1)
    ok = area > 0
    idx, P, nrm, area = idx[ok], P[ok], nrm[ok], area[ok]
    unit = nrm / (2 * area[:, None])
    offset = np.einsum("ij,ij->i", unit, P[:, 0])
    key = np.column_stack([np.round(unit / 1e-9), np.round(offset / 1e-6)])
    _, label = np.unique(key, axis=0, return_inverse=True)
    label = label.reshape(-1)
    totals = np.bincount(label, weights=area)
    order = np.argsort(-totals)
    return [idx[label == g] for g in order[:MAX_GROUPS]]


def _area_mm2(V: np.ndarray, faces: np.ndarray) -> float:
    """Total area of triangles ``faces`` (K, 3) of vertices ``V``, mm^2."""
    P = V[faces]
    return 0.5 * float(np.linalg.norm(np.cross(P[:, 1] - P[:, 0], P[:, 2] - P[:, 0]), axis=1).sum())


def _affine_texel_map(surface: TexturedSurface, V_cam: np.ndarray, faces: np.ndarray):
    """Plane (unit normal n, offset d: n . X = d) and affine map texel = M X + m of a flat face group (camera
    frame), or None when its texture coordinates are not one affine map of the plane."""
    tri = faces[0]
    p0 = V_cam[tri[0]]
    e1 = V_cam[tri[1]] - p0
    e2 = V_cam[tri[2]] - p0
    n = np.cross(e1, e2)
    n /= np.linalg.norm(n)
    b1 = e1 / np.linalg.norm(e1)
    b2 = np.cross(n, b1)
    verts = np.unique(faces.ravel())
    rows, cols = np.asarray(surface.texture).shape
    texel = np.asarray(surface.uv, dtype=float)[verts] * np.array([cols, rows]) - 0.5
    Q = V_cam[verts] - p0
    design = np.column_stack([Q @ b1, Q @ b2, np.ones(len(verts))])
    coef, *_ = np.linalg.lstsq(design, texel, rcond=None)
    if np.abs(design @ coef - texel).max() > 1e-6 * max(rows, cols, 1):
        return None
    # texel = coef[0] (X - p0) . b1 + coef[1] (X - p0) . b2 + coef[2]
    M = np.outer(coef[0], b1) + np.outer(coef[1], b2)
    m = coef[2] - M @ p0
    return n, float(n @ p0), M, m


#: Relative depth by which another face must lie beyond a face group along a chief ray to count as behind it.
BEHIND_REL = 1e-6


def _behind(spec: SensorSpec, R: np.ndarray, t: np.ndarray, own, others: list[tuple[np.ndarray, np.ndarray]]
            ) -> np.ndarray:
    """(H, W) bool: pixels whose chief ray meets the group (``own``: its :class:`scenes.specimens.ray_surface.RayHits`) on its
    emitting side before every face of ``others`` ((vertices, faces) pairs), by more than :data:`BEHIND_REL` of the
    depth. A pixel whose centre misses the group, or where another face comes first, is False."""
    from scenes.specimens.ray_surface import cast_rays

    nearest = np.full(own.depth_mm.shape, np.inf)
    for Vk, fk in others:
        np.minimum(nearest, cast_rays(spec, R, t, Vk, fk).depth_mm, out=nearest)
    return (own.triangle >= 0) & own.front & (nearest > own.depth_mm * (1.0 + BEHIND_REL))


def _ring_open(known: np.ndarray, P: np.ndarray) -> bool:
    """True if an unknown pixel of the sensor's outermost ring lies in the bounding box of the projected points
    ``P`` (..., 2) px: the only pixels of a sharp face group the in-focus pass leaves that this path can make."""
    finite = P[np.all(np.isfinite(P), axis=-1)]
    if finite.size == 0:
        return False
    H, W = known.shape
    x0, y0 = np.floor(finite.min(axis=0) - 1).astype(int)
    x1, y1 = np.ceil(finite.max(axis=0) + 1).astype(int)
    x0, y0, x1, y1 = max(x0, 0), max(y0, 0), min(x1, W - 1), min(y1, H - 1)
    if x1 < x0 or y1 < y0:
        return False
    ring = [known[0, x0:x1 + 1] if y0 == 0 else None, known[H - 1, x0:x1 + 1] if y1 == H - 1 else None,
            known[y0:y1 + 1, 0] if x0 == 0 else None, known[y0:y1 + 1, W - 1] if x1 == W - 1 else None]
    return any(side is not None and not side.all() for side in ring)


def fill_defocused_faces(spec: SensorSpec, R_cam_from_world: np.ndarray, t_cam_from_world_mm: np.ndarray,
                         surfaces: list[TexturedSurface], image_grey: np.ndarray, known: np.ndarray, *,
                         exposure_grey: float = 255.0, tolerance_grey: float = DEFAULT_TOLERANCE_GREY
                         ) -> tuple[np.ndarray, np.ndarray, dict]:
    """Make the unknown pixels of a thin-lens view that flat faces or smooth patches fill wholly (module notes).

    Parameters
    ----------
    spec : SensorSpec with ``lens == "thin"`` (a pinhole view is returned unchanged)
    R_cam_from_world, t_cam_from_world_mm : the camera pose, ``X_cam = R X_world + t``
    surfaces : the scene (as :func:`scenes.rendering.exact.render_view_in_focus` takes it)
    image_grey : (height, width) float, the known pixels' grey levels
    known : (height, width) bool, pixels already made (left as they are)
    exposure_grey : grey levels per unit radiance
    tolerance_grey : largest RMS error of a blur bin's rule against the dense rule

    Returns
    -------
    image_grey : (height, width) float32, with the pixels made here
    known : (height, width) bool, ``known`` or made here
    info : ``defocus_pixels`` (made here), ``defocus_nodes`` (their mean rule size), ``defocus_bins`` (per blur
        bin: upper blur radius px, rule (n_p, n_r, n_t), nodes, measured error grey, pixels), ``defocus_groups``
        (flat face groups used), ``defocus_patches`` (smooth patches walked) and ``defocus_skipped`` (why a group
        or pixel was not used)
    """
    image = np.array(image_grey, dtype=np.float32, copy=True)
    known = np.array(known, dtype=bool, copy=True)
    info = {"defocus_pixels": 0, "defocus_nodes": 0.0, "defocus_bins": [], "defocus_groups": 0,
            "defocus_patches": 0, "defocus_skipped": []}
    if spec.lens != "thin" or known.all() or not surfaces:
        return image, known, info
    from scipy.ndimage import distance_transform_edt, maximum_filter

    from scenes.rendering.defocus_mesh import blur_and_scale as mesh_blur_and_scale
    from scenes.rendering.defocus_mesh import edge_neighbours, smooth_components, triangle_table
    from scenes.rendering.defocus_mesh import integrate_pixels as mesh_integrate_pixels
    from scenes.specimens.ray_surface import cast_rays
    from scenes.optics.projection import defocus_blur_px, project_points, tilted_sensor_axes

    R = np.asarray(R_cam_from_world, dtype=float)
    t = np.asarray(t_cam_from_world_mm, dtype=float).reshape(3)
    centre = -R.T @ t
    A_mm = 0.5 * spec.focal_length_mm / spec.f_number
    cull = closed_surface(surfaces)
    H, W = spec.height, spec.width
    seen, groups = [], []
    for si, surface in enumerate(surfaces):
        faces = np.asarray(surface.faces, dtype=int)
        dist = facing_distance_mm(surface, centre)
        seen.append(dist > -A_mm if cull else np.ones(len(faces), dtype=bool))
        if surface.filter != "bilinear":
            continue
        V_cam = np.asarray(surface.vertices_mm, dtype=float) @ R.T + t
        # faces seen from their emitting side by the whole aperture, in smooth patches (no sharp crease within):
        # a patch that is mostly one plane is integrated plane by plane, any other by walking its triangles
        idx = np.flatnonzero(dist > A_mm)
        for comp in smooth_components(faces[idx], edge_neighbours(faces[idx], V_cam)):
            members = np.zeros(len(faces), dtype=bool)
            members[idx[comp]] = True
            planes = _face_groups(V_cam, faces, members)
            if _area_mm2(V_cam, faces[planes[0]]) >= PLANAR_SHARE * _area_mm2(V_cam, faces[idx[comp]]):
                groups += [("plane", si, g, V_cam) for g in planes]
            else:
                groups.append(("mesh", si, idx[comp], V_cam))
    xy = sensor_corner_coordinates(spec)
    axes = tilted_sensor_axes(spec.alpha_deg, spec.beta_deg)
    optics = (spec.cx, spec.cy, spec.fx, spec.fy, axes[2, 0], axes[2, 1], spec.image_distance_mm,
              spec.focal_length_mm)
    total_nodes = 0.0
    small = 0
    for kind, si, g, V_cam in groups:
        surface = surfaces[si]
        faces = np.asarray(surface.faces, dtype=int)
        # a deformed mesh's "flat groups" are single triangles a few px wide: none holds a blur circle, and each
        # would cost whole-view coverage and distance passes
        P = project_points(spec, R, t, np.asarray(surface.vertices_mm, dtype=float)[faces[g]].reshape(-1, 3))
        P = P.reshape(-1, 3, 2)
        e1, e2 = P[:, 1] - P[:, 0], P[:, 2] - P[:, 0]
        if 0.5 * np.nansum(np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])) < MIN_GROUP_AREA_PX:
            small += 1
            continue
        if kind == "plane":
            plane = _affine_texel_map(surface, V_cam, faces[g])
            if plane is None:
                info["defocus_skipped"].append(f"surface {si}: its flat faces' texture is not one affine map")
                continue
            n, d, M, m = plane
        try:
            Vw = np.asarray(surface.vertices_mm, dtype=float)
            xy_g, st_g = project_outlines(spec, R, t, list(Vw[faces[g]]), 1e-3)
        except NotExactError as err:
            info["defocus_skipped"].append(f"surface {si}: {err}")
            continue
        # whole coverage on the sensor widened by the group's largest blur (its edges beyond the sensor count),
        # a ring of "not covered" around that window: the distance to the group's edge, px
        blur_g = defocus_blur_px(spec, R, t, Vw[np.unique(faces[g])])
        if np.all(blur_g <= MAX_BLUR_PX) and not _ring_open(known, P):
            # a sharp group: the in-focus pass made every pixel of it this path could (its edge and neighbour
            # margins are wider) except on the sensor's outermost ring, where it cannot see the coverage beyond
            # the edge; with no unknown ring pixel under the group, its coverage and distance passes find nothing
            continue
        pad = int(min(np.nanmax(blur_g) if np.isfinite(blur_g).any() else 0.0, MAX_REACH_PX) * BLUR_MARGIN / 2
                  + EDGE_MARGIN_PX + 2)
        wide = accumulate_flat(xy_g, st_g, np.ones(len(g)), (H + 2 * pad, W + 2 * pad), (-pad, -pad))
        # covered once: a curved patch folding over itself (two layers) is not integrated there
        wide = np.pad((wide >= 1.0 - 1e-6) & (wide <= 1.0 + 1e-6), 1, constant_values=False)
        edge_all = distance_transform_edt(wide)[pad + 1:pad + 1 + H, pad + 1:pad + 1 + W]
        whole = edge_all > 0
        # everything else that is seen: the other faces, dilated by their own blur
        near_other = np.zeros((H, W), dtype=bool)
        own_hits = None                      # the group's chief-ray hits, cast once where needed
        other_polys, other_meshes, other_blur = [], [], 0.0
        for k, (s, mask) in enumerate(zip(surfaces, seen)):
            mask = mask.copy()
            if k == si:
                mask[g] = False
            if not mask.any():
                continue
            Vk = np.asarray(s.vertices_mm, dtype=float)
            fk = np.asarray(s.faces, dtype=int)[mask]
            other_polys += list(Vk[fk])
            other_meshes.append((Vk, fk))
            blur = defocus_blur_px(spec, R, t, Vk)[fk].max(axis=1)
            if not np.all(np.isfinite(blur)):
                other_blur = np.inf
                break
            other_blur = max(other_blur, float(blur.max()))
        if not np.isfinite(other_blur):
            info["defocus_skipped"].append(f"surface {si}: another face reaches behind the lens")
            continue
        if other_polys:
            try:
                xy_o, st_o = project_outlines(spec, R, t, other_polys, 0.05)
            except NotExactError as err:
                info["defocus_skipped"].append(f"surface {si}: {err}")
                continue
            foot = np.abs(accumulate_flat(xy_o, st_o, np.ones(len(other_polys)), (H, W))) > 0
            if (foot & whole).any():
                # a face behind the group along a pixel's chief ray hides nothing there (the inner walls of a
                # hollow specimen behind its painted front): only the footprint of what may lie in front counts
                own_hits = cast_rays(spec, R, t, Vw, faces[g])
                foot &= ~_behind(spec, R, t, own_hits, other_meshes)
            reach = int(math.ceil(0.5 * other_blur * BLUR_MARGIN + EDGE_MARGIN_PX))
            near_other = maximum_filter(foot, size=2 * reach + 1)
        todo = whole & ~known & ~near_other
        if not todo.any():
            continue
        tex = np.ascontiguousarray(surface.texture, dtype=np.float32)      # as Mitsuba holds it
        if kind == "plane":
            r_idx, c_idx = np.nonzero(todo)
            r0, r1, c0, c1 = int(r_idx.min()), int(r_idx.max()) + 1, int(c_idx.min()), int(c_idx.max()) + 1
            rho, scale, jac = _blur_and_scale(xy, r0, r1, c0, c1, *optics, A_mm, n, d, M, m)
            edge = edge_all[r0:r1, c0:c1]
            ok = (todo[r0:r1, c0:c1] & (edge > BLUR_MARGIN * rho + EDGE_MARGIN_PX) & np.isfinite(rho)
                  & np.isfinite(scale))
            if not ok.any():
                continue
            rr, cc = _tile_order(ok)
            rho_ok, scale_ok, jac_ok = rho[rr, cc], scale[rr, cc], jac[rr, cc]
            rr, cc = rr + r0, cc + c0
        else:
            tab = triangle_table(V_cam, faces[g], surface.uv, tex.shape)
            hits = own_hits if own_hits is not None else cast_rays(spec, R, t, Vw, faces[g])
            rr, cc = _tile_order(todo & (hits.triangle >= 0) & hits.front)
            if not len(rr):
                continue
            seeds = hits.triangle[rr, cc]
            rho_ok, scale_ok, jac_ok = mesh_blur_and_scale(xy, rr.astype(np.int64), cc.astype(np.int64), seeds,
                                                           tab, *optics, A_mm)
            keep = (edge_all[rr, cc] > BLUR_MARGIN * rho_ok + EDGE_MARGIN_PX) & np.isfinite(rho_ok) \
                & np.isfinite(scale_ok)
            if not keep.any():
                continue
            rr, cc, seeds, rho_ok, scale_ok, jac_ok = (a[keep] for a in (rr, cc, seeds, rho_ok, scale_ok, jac_ok))
        edges = [FIRST_BIN_PX]
        while edges[-1] < rho_ok.max():
            edges.append(edges[-1] * BIN_GROWTH)
        bins = np.searchsorted(np.array(edges), rho_ok)
        rules, starts = [], [0]
        detail_texels = texture_detail_texels(tex)
        fingerprint = texture_fingerprint(tex)
        previous = 0
        counts, finest = _bin_members(bins, scale_ok, len(edges))
        bin_info = []
        for b, edge_px in enumerate(edges):
            count = int(counts[b])
            if count == 0:
                rules.append(np.zeros((0, 5)))
                starts.append(starts[-1])
                continue
            # the bin's rule is measured where its texture is finest on the sensor
            J = jac_ok[finest[b]].astype(np.float64).reshape(2, 2)
            choice = choose_rule(tex, J, edge_px, exposure_grey, tolerance_grey, seed=b,
                                 detail_texels=detail_texels, fingerprint=fingerprint, at_least=previous)
            previous = choice["nodes"]
            rule = thin_lens_rule(*choice["rule"])
            rules.append(rule)
            starts.append(starts[-1] + len(rule))
            bin_info.append({"rho_px": edge_px, "rule": list(choice["rule"]), "nodes": choice["nodes"],
                             "error_grey": choice["error_grey"], "pixels": count, "bin": b})
        out = np.empty(len(rr))
        if kind == "plane":
            # twice as many texels as any ray of these pixels lands from its pixel's chief ray (the texel scale
            # changes across a blur circle on an oblique face)
            margin = int(math.ceil(2.0 * float(scale_ok.max()) * (float(rho_ok.max()) + 2.0))) + 4
            _integrate_pixels(rr.astype(np.int64), cc.astype(np.int64), bins.astype(np.int64),
                              np.array(starts, dtype=np.int64), _node_table(np.concatenate(rules), A_mm, n, M), xy,
                              *optics, n, d, M, m, margin, tex, out)
        else:
            mesh_integrate_pixels(rr.astype(np.int64), cc.astype(np.int64), seeds, bins.astype(np.int64),
                                  np.array(starts, dtype=np.int64), np.ascontiguousarray(np.concatenate(rules)),
                                  A_mm, xy, *optics, tab, edge_neighbours(faces[g], V_cam), tex, out)
        made = np.isfinite(out)
        if not made.all():
            info["defocus_skipped"].append(f"surface {si}: {int((~made).sum())} pixel(s) whose rays left the "
                                           "smooth patch (left for Mitsuba)")
        per_bin = np.bincount(bins[made], minlength=len(edges))
        for row in bin_info:
            row["pixels"] = int(per_bin[row.pop("bin")])
            info["defocus_bins"].append(row)
            total_nodes += row["pixels"] * row["nodes"]
        rr, cc = rr[made], cc[made]
        image[rr, cc] = (float(exposure_grey) * out[made]).astype(np.float32)
        known[rr, cc] = True
        info["defocus_pixels"] += int(len(rr))
        info["defocus_groups" if kind == "plane" else "defocus_patches"] += 1
    if small:
        info["defocus_skipped"].append(f"{small} flat face group(s) under {MIN_GROUP_AREA_PX:g} px^2 in the view")
    if info["defocus_pixels"]:
        info["defocus_nodes"] = total_nodes / info["defocus_pixels"]
    return image, known, info


__all__ = ["DEFAULT_TOLERANCE_GREY", "RENDERER_DEFOCUS", "RENDERER_THIN_LENS", "RENDERER_THIN_LENS_ADAPTIVE",
           "fill_defocused_faces"]
