"""Which material point every pixel sees: pixel rays against a curved FE surface, no renderer involved.

Truth side, independent of Mitsuba. Two steps:

1. **Nearest flat piece per pixel ray** (:func:`cast_rays`): the surface's tessellation
   (:meth:`scenes.specimens.surface_mesh.SurfaceMesh.tessellate`) is scan-converted in the camera's *ideal* image plane.
   A chief ray is ``(x_n, y_n, 1)`` in the camera frame (:func:`scenes.optics.projection.ideal_coordinates` undoes tilt and
   distortion), and a flat triangle maps to a triangle of that plane, so each triangle visits only the pixels of
   its projected bounding box (projected through the distorting camera, widened by a margin for its curved
   edges) and each visit is an exact ray-triangle test (Moller-Trumbore); the nearest hit wins (a z-buffer).
   That is an exact ray cast of every pixel centre at the cost of a rasteriser: ~1 s for a 5 MP view.
2. **Onto the curved face** (:func:`refine_on_surface`): the hit on the flat piece gives the face and ``(s, t)``;
   Newton on ``X(s, t) + u(s, t) = lambda d`` moves it onto the curved FE surface (quadratic faces), so the
   truth is the FE surface's, not the tessellation's.

Visibility (:func:`visible_from`) is read from another view's depth buffer: a material point is seen by a camera
when nothing lies nearer along its line of sight than a depth tolerance of a few pixel footprints; points near an
occluding edge are counted hidden (never a wrong truth, only a lost point).
"""
from __future__ import annotations

import functools
from dataclasses import dataclass

import numba
import numpy as np

from scenes.optics.camera import SensorSpec

#: Pixels added around each triangle's projected box (its edges bend by the lens distortion; px).
BOX_MARGIN_PX = 2.0
#: Barycentric slack so that rays through a shared edge hit one of its two triangles (no cracks).
EDGE_TOL = 1e-10


@dataclass(frozen=True)
class RayHits:
    """Nearest hit of every pixel's chief ray. Arrays (H, W); ``triangle`` is -1 where the ray hits nothing.

    Attributes
    ----------
    triangle : int, the tessellation triangle hit
    bary : (H, W, 2) float, its barycentric coordinates (of corners 1 and 2) at the hit
    depth_mm : float, camera-frame z of the hit (inf where nothing is hit)
    front : bool, the ray meets the triangle's outer (emitting) side
    """

    triangle: np.ndarray
    bary: np.ndarray
    depth_mm: np.ndarray
    front: np.ndarray


@functools.lru_cache(maxsize=4)
def pixel_centre_rays(spec: SensorSpec) -> np.ndarray:
    """Ideal coordinates ``(x_n, y_n)`` of every pixel centre, (H, W, 2), read-only (cached per camera)."""
    from scenes.optics.projection import ideal_coordinates

    X, Y = np.meshgrid(np.arange(spec.width, dtype=float), np.arange(spec.height, dtype=float))
    xy = ideal_coordinates(spec, np.column_stack([X.ravel(), Y.ravel()])).reshape(spec.height, spec.width, 2)
    xy.setflags(write=False)
    return xy


@numba.njit(cache=True)
def _scan(A, B, C, boxes, rays, tri_out, bary_out, depth_out, front_out, tol):
    H, W = depth_out.shape
    for k in range(A.shape[0]):
        ax, ay, az = A[k, 0], A[k, 1], A[k, 2]
        e1x, e1y, e1z = B[k, 0] - ax, B[k, 1] - ay, B[k, 2] - az
        e2x, e2y, e2z = C[k, 0] - ax, C[k, 1] - ay, C[k, 2] - az
        x0, y0, x1, y1 = boxes[k, 0], boxes[k, 1], boxes[k, 2], boxes[k, 3]
        for r in range(max(y0, 0), min(y1, H)):
            for c in range(max(x0, 0), min(x1, W)):
                dx, dy = rays[r, c, 0], rays[r, c, 1]
                if dx != dx:
                    continue
                # p = d x e2 (d = (dx, dy, 1))
                px = dy * e2z - e2y
                py = e2x - dx * e2z
                pz = dx * e2y - dy * e2x
                det = e1x * px + e1y * py + e1z * pz
                if det == 0.0:
                    continue
                inv = 1.0 / det
                tx, ty, tz = -ax, -ay, -az
                u = (tx * px + ty * py + tz * pz) * inv
                if u < -tol or u > 1.0 + tol:
                    continue
                qx = ty * e1z - tz * e1y
                qy = tz * e1x - tx * e1z
                qz = tx * e1y - ty * e1x
                v = (dx * qx + dy * qy + qz) * inv
                if v < -tol or u + v > 1.0 + tol:
                    continue
                depth = (e2x * qx + e2y * qy + e2z * qz) * inv
                if depth <= 0.0 or depth >= depth_out[r, c]:
                    continue
                depth_out[r, c] = depth
                tri_out[r, c] = k
                bary_out[r, c, 0] = u
                bary_out[r, c, 1] = v
                # det = -d . (e1 x e2): positive when the ray meets the outer side
                front_out[r, c] = det > 0.0


def cast_rays(spec: SensorSpec, R_cam_from_world, t_cam_from_world_mm, vertices_world_mm, triangles) -> RayHits:
    """Nearest flat triangle hit by every pixel centre's chief ray (module docstring, step 1).

    Parameters
    ----------
    spec : SensorSpec, the camera as rendered (a thin lens' chief ray is the pinhole ray)
    R_cam_from_world, t_cam_from_world_mm : pose, ``X_cam = R X_world + t``
    vertices_world_mm : (V, 3) float
    triangles : (T, 3) int, counter-clockwise seen from the outer side

    Raises
    ------
    ValueError
        A triangle reaches behind the camera (its vertices at Z_cam <= 0): no pinhole image holds it whole.
    """
    from scenes.optics.projection import project_points

    R = np.asarray(R_cam_from_world, float)
    t = np.asarray(t_cam_from_world_mm, float).reshape(3)
    V = np.asarray(vertices_world_mm, float) @ R.T + t
    T = np.asarray(triangles, np.int64)
    H, W = spec.height, spec.width
    tri = np.full((H, W), -1, np.int64)
    bary = np.zeros((H, W, 2))
    depth = np.full((H, W), np.inf)
    front = np.zeros((H, W), bool)
    if not len(T):
        return RayHits(tri, bary, depth, front)
    behind = V[T, 2].min(axis=1) <= 0
    if np.any(behind & (V[T, 2].max(axis=1) > 0)):
        raise ValueError(f"{int(np.sum(behind))} surface triangles reach behind the camera (Z_cam <= 0)")
    T = T[~behind]
    keep = np.flatnonzero(~behind)
    # projected boxes: corners and edge midpoints through the distorting camera
    A, B, C = V[T[:, 0]], V[T[:, 1]], V[T[:, 2]]
    pts = np.concatenate([A, B, C, 0.5 * (A + B), 0.5 * (B + C), 0.5 * (C + A)])
    xy = project_points(spec, np.eye(3), np.zeros(3), pts).reshape(6, len(T), 2)
    lo = np.nanmin(xy, axis=0)
    hi = np.nanmax(xy, axis=0)
    ok = np.all(np.isfinite(lo), axis=1) & np.all(np.isfinite(hi), axis=1) & (hi[:, 0] >= -BOX_MARGIN_PX) \
        & (hi[:, 1] >= -BOX_MARGIN_PX) & (lo[:, 0] <= W - 1 + BOX_MARGIN_PX) & (lo[:, 1] <= H - 1 + BOX_MARGIN_PX)
    boxes = np.column_stack([np.floor(lo[:, 0] - BOX_MARGIN_PX), np.floor(lo[:, 1] - BOX_MARGIN_PX),
                             np.ceil(hi[:, 0] + BOX_MARGIN_PX) + 1, np.ceil(hi[:, 1] + BOX_MARGIN_PX) + 1])
    boxes = np.clip(np.nan_to_num(boxes), -1, max(H, W) + 1).astype(np.int64)
    sel = np.flatnonzero(ok)
    rays = pixel_centre_rays(spec)
    local = np.full((H, W), -1, np.int64)
    _scan(A[sel], B[sel], C[sel], boxes[sel], rays, local, bary, depth, front, EDGE_TOL)
    hit = local >= 0
    tri[hit] = keep[sel[local[hit]]]
    return RayHits(tri, bary, depth, front)


@numba.njit(cache=True)
def _possibly_visible(A, B, C, boxes, rays, depth, keep, rel_tol, abs_tol_mm):
    H, W = depth.shape
    for k in range(A.shape[0]):
        ax, ay, az = A[k, 0], A[k, 1], A[k, 2]
        e1x, e1y, e1z = B[k, 0] - ax, B[k, 1] - ay, B[k, 2] - az
        e2x, e2y, e2z = C[k, 0] - ax, C[k, 1] - ay, C[k, 2] - az
        nx = e1y * e2z - e1z * e2y
        ny = e1z * e2x - e1x * e2z
        nz = e1x * e2y - e1y * e2x
        x0, y0, x1, y1 = boxes[k, 0], boxes[k, 1], boxes[k, 2], boxes[k, 3]
        found = False
        for r in range(max(y0, 0), min(y1, H)):
            for c in range(max(x0, 0), min(x1, W)):
                dx, dy = rays[r, c, 0], rays[r, c, 1]
                if dx != dx:
                    continue
                dn = nx * dx + ny * dy + nz
                if dn == 0.0:
                    continue
                # the triangle's plane along this pixel's ray, anywhere in its (widened) box: a thin sliver covering
                # no pixel centre is still kept where its plane is not behind what the pixel sees
                d_plane = (nx * ax + ny * ay + nz * az) / dn
                if d_plane > 0.0 and d_plane <= depth[r, c] * (1.0 + rel_tol) + abs_tol_mm:
                    found = True
                    break
            if found:
                break
        keep[k] = found


def possibly_visible(spec: SensorSpec, R_cam_from_world, t_cam_from_world_mm, vertices_world_mm, triangles,
                     depth_mm: np.ndarray, hit_triangle: np.ndarray | None = None, abs_tol_mm: float = 1e-3
                     ) -> np.ndarray:
    """(T,) bool: triangles that may show somewhere: hit by a pixel-centre ray (``hit_triangle``, the ray cast's
    triangle ids), or whose plane is not behind the nearest depth ``depth_mm`` (:func:`cast_rays`; tolerance 1e-6
    relative + ``abs_tol_mm``) at some pixel of their projected box widened by :data:`BOX_MARGIN_PX`. The others lie
    behind nearer surfaces wherever they could show (a tube's far wall). Conservative: a face kept needlessly only
    costs its overlap being traced."""
    from scenes.optics.projection import project_points

    R = np.asarray(R_cam_from_world, float)
    t = np.asarray(t_cam_from_world_mm, float).reshape(3)
    V = np.asarray(vertices_world_mm, float) @ R.T + t
    T = np.asarray(triangles, np.int64)
    keep = np.zeros(len(T), bool)
    if not len(T):
        return keep
    A, B, C = V[T[:, 0]], V[T[:, 1]], V[T[:, 2]]
    xy = project_points(spec, np.eye(3), np.zeros(3), np.concatenate([A, B, C, 0.5 * (A + B), 0.5 * (B + C),
                                                                       0.5 * (C + A)])).reshape(6, len(T), 2)
    lo, hi = np.nanmin(xy, axis=0), np.nanmax(xy, axis=0)
    ok = np.all(np.isfinite(lo), axis=1)
    m = BOX_MARGIN_PX
    boxes = np.column_stack([np.floor(lo[:, 0] - m), np.floor(lo[:, 1] - m), np.ceil(hi[:, 0] + m) + 1,
                             np.ceil(hi[:, 1] + m) + 1])
    H, W = depth_mm.shape
    boxes = np.clip(np.nan_to_num(boxes), -1, max(H, W) + 1).astype(np.int64)
    _possibly_visible(A, B, C, boxes, pixel_centre_rays(spec), np.asarray(depth_mm, float), keep, 1e-6,
                      float(abs_tol_mm))
    keep[~ok] = True                          # cannot tell: keep (overlap is then detected and traced)
    if hit_triangle is not None:
        hit = np.asarray(hit_triangle)
        keep[hit[hit >= 0]] = True
    return keep


@numba.njit(cache=True, parallel=True)
def _newton_family(V, conn, exps, C, rows, st, o, d, tol, iterations, st_out, X_out, n_out, ok_out):
    """Newton on ``X(s, t) = o + lam d_i`` for points on faces ``rows`` of one family (nodes V, connectivity conn,
    monomial exponents and coefficient matrix of its shape functions), per point in parallel."""
    nn = conn.shape[1]
    for i in numba.prange(rows.size):
        r = rows[i]
        s = st[i, 0]
        t = st[i, 1]
        m = np.empty(nn)
        ms = np.empty(nn)
        mt = np.empty(nn)
        X = np.zeros(3)
        Ts = np.zeros(3)
        Tt = np.zeros(3)
        lam = 0.0
        done = False
        for it in range(iterations + 1):
            for k in range(nn):
                es = exps[k, 0]
                et = exps[k, 1]
                ps = s ** es
                pt = t ** et
                m[k] = ps * pt
                ms[k] = (es * s ** (es - 1) if es > 0 else 0.0) * pt
                mt[k] = ps * (et * t ** (et - 1) if et > 0 else 0.0)
            for c in range(3):
                X[c] = 0.0
                Ts[c] = 0.0
                Tt[c] = 0.0
            for a in range(nn):
                Na = 0.0
                Nsa = 0.0
                Nta = 0.0
                for k in range(nn):
                    Na += m[k] * C[k, a]
                    Nsa += ms[k] * C[k, a]
                    Nta += mt[k] * C[k, a]
                node = conn[r, a]
                for c in range(3):
                    X[c] += Na * V[node, c]
                    Ts[c] += Nsa * V[node, c]
                    Tt[c] += Nta * V[node, c]
            if it == 0:
                dd = d[i, 0] * d[i, 0] + d[i, 1] * d[i, 1] + d[i, 2] * d[i, 2]
                lam = ((X[0] - o[i, 0]) * d[i, 0] + (X[1] - o[i, 1]) * d[i, 1] + (X[2] - o[i, 2]) * d[i, 2]) / dd
            if done:
                break
            # J [ds, dt, dlam] = -res, J = [Ts, Tt, -d]
            r0 = -(X[0] - o[i, 0] - lam * d[i, 0])
            r1 = -(X[1] - o[i, 1] - lam * d[i, 1])
            r2 = -(X[2] - o[i, 2] - lam * d[i, 2])
            a00, a01, a02 = Ts[0], Tt[0], -d[i, 0]
            a10, a11, a12 = Ts[1], Tt[1], -d[i, 1]
            a20, a21, a22 = Ts[2], Tt[2], -d[i, 2]
            det = (a00 * (a11 * a22 - a12 * a21) - a01 * (a10 * a22 - a12 * a20) + a02 * (a10 * a21 - a11 * a20))
            if det == 0.0:
                break
            ds = (r0 * (a11 * a22 - a12 * a21) - a01 * (r1 * a22 - a12 * r2) + a02 * (r1 * a21 - a11 * r2)) / det
            dt = (a00 * (r1 * a22 - a12 * r2) - r0 * (a10 * a22 - a12 * a20) + a02 * (a10 * r2 - r1 * a20)) / det
            dl = (a00 * (a11 * r2 - r1 * a21) - a01 * (a10 * r2 - r1 * a20) + r0 * (a10 * a21 - a11 * a20)) / det
            s += ds
            t += dt
            lam += dl
            if abs(ds) < tol and abs(dt) < tol:
                done = True            # one more pass evaluates X and the tangents at the converged point
        ok_out[i] = done
        st_out[i, 0] = s
        st_out[i, 1] = t
        for c in range(3):
            X_out[i, c] = X[c]
        nx = Ts[1] * Tt[2] - Ts[2] * Tt[1]
        ny = Ts[2] * Tt[0] - Ts[0] * Tt[2]
        nz = Ts[0] * Tt[1] - Ts[1] * Tt[0]
        nl = np.sqrt(nx * nx + ny * ny + nz * nz)
        if nl > 0:
            n_out[i, 0] = nx / nl
            n_out[i, 1] = ny / nl
            n_out[i, 2] = nz / nl


def refine_on_surface(mesh, face, st, displacement_mm, origins_world_mm, directions_world, R_world_from_specimen,
                      t_world_from_specimen_mm, tol: float = 1e-13, iterations: int = 12, with_normals: bool = False):
    """Newton from ``(face, st)`` onto the curved surface deformed by nodal ``displacement_mm`` along each ray.

    Solves ``R (X(s, t) + u(s, t)) + t0 = o + lambda d`` for ``(s, t, lambda)`` (the face's own polynomial, also a
    little past its edges: a ray whose flat piece lies at a face edge may meet the curved surface just across), in
    the specimen frame, per point in parallel (numba).

    Returns
    -------
    st : (M, 2) refined reference coordinates (NaN where Newton did not converge to ``tol``)
    X_world_mm : (M, 3) the hit on the curved deformed surface
    normals_world : (M, 3) its unit normal (outwards; only with ``with_normals``)
    """
    from scenes.specimens.face_elements import FACE_ELEMENTS

    R = np.asarray(R_world_from_specimen, float)
    t0 = np.asarray(t_world_from_specimen_mm, float).reshape(3)
    face = np.asarray(face, np.int64).reshape(-1)
    st = np.asarray(st, float).reshape(-1, 2)
    o = (np.asarray(origins_world_mm, float).reshape(-1, 3) - t0) @ R      # rows: R^T (o - t0)
    d = np.asarray(directions_world, float).reshape(-1, 3) @ R
    V = np.ascontiguousarray(mesh.points_mm + (0.0 if displacement_mm is None else np.asarray(displacement_mm, float)))
    st_out = np.full((len(face), 2), np.nan)
    X = np.full((len(face), 3), np.nan)
    n = np.full((len(face), 3), np.nan)
    ok = np.zeros(len(face), bool)
    fam = mesh.face_family[face]
    for k, name in enumerate(mesh.families):
        sel = np.flatnonzero(fam == k)
        if not len(sel):
            continue
        el = FACE_ELEMENTS[name]
        s_o, X_o, n_o, ok_o = np.empty((len(sel), 2)), np.empty((len(sel), 3)), np.full((len(sel), 3), np.nan), \
            np.zeros(len(sel), bool)
        _newton_family(V, np.ascontiguousarray(mesh.faces[name]), el.exponents.astype(np.int64),
                       np.ascontiguousarray(el.coefficients), np.ascontiguousarray(mesh.face_row[face[sel]]),
                       np.ascontiguousarray(st[sel]), np.ascontiguousarray(o[sel]), np.ascontiguousarray(d[sel]),
                       float(tol), int(iterations), s_o, X_o, n_o, ok_o)
        st_out[sel[ok_o]] = s_o[ok_o]
        X[sel[ok_o]] = X_o[ok_o]
        n[sel[ok_o]] = n_o[ok_o]
        ok[sel] = ok_o
    X[ok] = X[ok] @ R.T + t0
    n[ok] = n[ok] @ R.T
    if with_normals:
        return st_out, X, n
    return st_out, X


def depth_tolerance_mm(spec: SensorSpec, depth_mm, cos_view) -> np.ndarray:
    """How much nearer than a point another surface must be to hide it: 3 pixel footprints along the line of sight
    (a surface seen at an angle changes depth by footprint / cos over one pixel)."""
    footprint = np.asarray(depth_mm, float) / min(spec.fx, spec.fy)
    return 3.0 * footprint / np.maximum(np.abs(cos_view), 0.2)


def visible_from(spec: SensorSpec, R_cam_from_world, t_cam_from_world_mm, hits: RayHits, X_world_mm,
                 normals_world) -> tuple[np.ndarray, np.ndarray]:
    """Whether points on the surface are seen by a camera whose pixel-ray hits (for the same surface state) are
    ``hits``: in the image, facing the camera, and no nearer surface within :func:`depth_tolerance_mm` at any of
    the four pixel centres around their image (near an occluding edge: hidden).

    Returns
    -------
    visible : (M,) bool
    xy_px : (M, 2) where the points are imaged (NaN behind the camera)
    """
    from scenes.optics.projection import project_points

    R = np.asarray(R_cam_from_world, float)
    t = np.asarray(t_cam_from_world_mm, float).reshape(3)
    X = np.asarray(X_world_mm, float)
    xy = project_points(spec, R, t, X)
    Xc = X @ R.T + t
    centre = -R.T @ t
    view = centre - X
    cos_view = np.einsum("ij,ij->i", view, normals_world) / np.linalg.norm(view, axis=1)
    ok = np.all(np.isfinite(xy), axis=1) & (cos_view > 0)
    H, W = hits.depth_mm.shape
    x0 = np.floor(np.nan_to_num(xy[:, 0], nan=-10)).astype(np.int64)
    y0 = np.floor(np.nan_to_num(xy[:, 1], nan=-10)).astype(np.int64)
    ok &= (x0 >= 0) & (y0 >= 0) & (x0 + 1 < W) & (y0 + 1 < H)
    nearest = np.full(len(X), np.inf)
    for dy in (0, 1):
        for dx in (0, 1):
            yy = np.clip(y0 + dy, 0, H - 1)
            xx = np.clip(x0 + dx, 0, W - 1)
            nearest = np.minimum(nearest, hits.depth_mm[yy, xx])
    tol = depth_tolerance_mm(spec, Xc[:, 2], cos_view)
    visible = ok & (nearest >= Xc[:, 2] - tol)
    return visible, xy
