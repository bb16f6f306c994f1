"""Thin-lens pixels of smooth (curved, deformed) meshes without Monte Carlo: each aperture ray walked across the
triangles.

:mod:`scenes.rendering.defocus_quadrature` integrates a pixel over its square and the aperture disc where every ray of the
pixel meets one flat face. A deformed specimen's painted face is not flat: already its first FE step tilts its
1 248 triangles against one another by ~5e-6 rad and moves them ~1 µm off a common plane, so no flat group
of them holds a blur circle, and a curved specimen (the pressurised cylinder) has none at all. The geometry
stays exact all the same: the surface Mitsuba renders *is* the triangle mesh, and a ray of the pixel's bundle
meets it near where the pixel's chief ray does. So each node's ray is intersected with the plane of a triangle,
and where the hit lies outside that triangle the walk steps to the neighbour across the edge it left by (the
most negative barycentric coordinate), until the hit is inside (barycentric slack :data:`INSIDE_TOL`). The
walk of a pixel starts from the triangle its chief ray meets (:func:`scenes.specimens.ray_surface.cast_rays`) and each
node starts from where the previous one ended. The hit's texel is the triangle's barycentric blend of its
vertices' texture coordinates (Mitsuba's), looked up bilinearly with clamping to the edge.

The rule per blur bin is chosen as for a flat face (:func:`scenes.rendering.defocus_rules.choose_rule`), on the local
triangle's affine texel map. A pixel is made only where every node's walk ends inside the patch in at most
:data:`MAX_STEPS` steps and in front of the lens; otherwise it is left for Mitsuba (``NaN`` from the kernel).
Which pixels are tried (whole coverage by the patch, one layer, clear of other faces by their blur) is the
caller's (:func:`scenes.rendering.defocus_quadrature.fill_defocused_faces`). Arithmetic is float64: the walk compares
barycentric coordinates of points ~10^3 mm from the lens.
"""
from __future__ import annotations

import math

import numba
import numpy as np

from scenes.rendering.thin_lens_rays import bilinear_lookup, focus_point

#: Barycentric slack of "inside a triangle" (rays through a shared edge end in either triangle).
INSIDE_TOL = 1e-9
#: Most triangles one node's walk may cross before its pixel is left for Mitsuba.
MAX_STEPS = 64
#: Largest angle between the normals of two triangles that meet along an edge for the walk to cross it, deg:
#: a sharper crease (a box's edge) bounds the smooth patch.
CREASE_DEG = 30.0
#: Columns of :func:`triangle_table`.
TABLE_COLUMNS = 20


def triangle_table(V_cam_mm: np.ndarray, faces: np.ndarray, uv: np.ndarray, texture_shape: tuple[int, int]
                   ) -> np.ndarray:
    """Per triangle, what a ray's walk needs (camera frame, float64): (T, :data:`TABLE_COLUMNS`) rows of the unit
    normal n and offset d (``n . X = d``), the dual edge vectors g1, g2 with ``g . A`` (barycentric coordinates
    ``b_k = g_k . X - g_k . A`` of a point X of the plane; A the first corner), and the affine texel map's two rows
    (``texel_u = Mu . X + mu``, ``texel_v = Mv . X + mv``; texel centres at integers, as Mitsuba's lookup).

    Parameters
    ----------
    V_cam_mm : (V, 3) float, vertices in the camera frame
    faces : (T, 3) int
    uv : (V, 2) float, texture coordinates in [0, 1]
    texture_shape : (rows, cols) of the texture
    """
    V = np.asarray(V_cam_mm, dtype=np.float64)
    F = np.asarray(faces, dtype=np.int64)
    rows, cols = texture_shape
    A, B, C = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    e1, e2 = B - A, C - A
    n = np.cross(e1, e2)
    norm = np.linalg.norm(n, axis=1)
    if np.any(norm == 0):
        raise ValueError(f"{int(np.sum(norm == 0))} degenerate (zero-area) triangles in the patch")
    n /= norm[:, None]
    g11 = np.einsum("ij,ij->i", e1, e1)
    g12 = np.einsum("ij,ij->i", e1, e2)
    g22 = np.einsum("ij,ij->i", e2, e2)
    det = g11 * g22 - g12 * g12
    g1 = (g22[:, None] * e1 - g12[:, None] * e2) / det[:, None]
    g2 = (g11[:, None] * e2 - g12[:, None] * e1) / det[:, None]
    T = np.asarray(uv, dtype=np.float64)[F] * np.array([cols, rows]) - 0.5          # (T, 3, 2) texels
    dT1, dT2 = T[:, 1] - T[:, 0], T[:, 2] - T[:, 0]
    # texel = T0 + b1 dT1 + b2 dT2 = (dT1 g1 + dT2 g2) . X + (T0 - dT1 g1.A - dT2 g2.A)
    c1 = np.einsum("ij,ij->i", g1, A)
    c2 = np.einsum("ij,ij->i", g2, A)
    Mu = dT1[:, :1] * g1 + dT2[:, :1] * g2
    Mv = dT1[:, 1:] * g1 + dT2[:, 1:] * g2
    mu = T[:, 0, 0] - dT1[:, 0] * c1 - dT2[:, 0] * c2
    mv = T[:, 0, 1] - dT1[:, 1] * c1 - dT2[:, 1] * c2
    table = np.column_stack([n, np.einsum("ij,ij->i", n, A), g1, c1, g2, c2, Mu, mu, Mv, mv])
    return np.ascontiguousarray(table)


def edge_neighbours(faces: np.ndarray, V_cam_mm: np.ndarray | None = None, crease_deg: float = CREASE_DEG
                    ) -> np.ndarray:
    """(T, 3) int: the triangle across the edge opposite each corner (-1 at the patch's boundary, at an edge
    shared by more than two triangles, or at a crease sharper than ``crease_deg`` when ``V_cam_mm`` is given).
    Edges are matched by vertex index."""
    F = np.asarray(faces, dtype=np.int64)
    T = len(F)
    out = np.full((T, 3), -1, dtype=np.int64)
    if T == 0:
        return out
    # the edge opposite corner k joins corners k+1 and k+2
    a = np.concatenate([F[:, 1], F[:, 2], F[:, 0]])
    b = np.concatenate([F[:, 2], F[:, 0], F[:, 1]])
    tri = np.tile(np.arange(T), 3)
    corner = np.repeat(np.arange(3), T)
    key = np.minimum(a, b) * (int(F.max()) + 1) + np.maximum(a, b)
    order = np.argsort(key, kind="stable")
    ks = key[order]
    first = np.concatenate([[True], ks[1:] != ks[:-1]])
    group = np.cumsum(first) - 1
    counts = np.bincount(group)
    pair = counts[group] == 2
    idx = order[pair]
    idx = idx.reshape(-1, 2)                      # consecutive members of one edge
    i, j = idx[:, 0], idx[:, 1]
    if V_cam_mm is not None and len(i):
        V = np.asarray(V_cam_mm, dtype=np.float64)
        nrm = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
        nrm /= np.linalg.norm(nrm, axis=1)[:, None]
        cos = np.einsum("ij,ij->i", nrm[tri[i]], nrm[tri[j]])
        keep = cos >= math.cos(math.radians(crease_deg))
        i, j = i[keep], j[keep]
    out[tri[i], corner[i]] = tri[j]
    out[tri[j], corner[j]] = tri[i]
    return out


def smooth_components(faces: np.ndarray, neighbours: np.ndarray) -> list[np.ndarray]:
    """Indices of ``faces`` in each connected set joined by :func:`edge_neighbours`, largest first."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    T = len(faces)
    if T == 0:
        return []
    i, k = np.nonzero(neighbours >= 0)
    graph = coo_matrix((np.ones(len(i)), (i, neighbours[i, k])), shape=(T, T))
    n, label = connected_components(graph, directed=False)
    sizes = np.bincount(label, minlength=n)
    return [np.flatnonzero(label == g) for g in np.argsort(-sizes, kind="stable")]


@numba.njit(cache=True, inline="always")
def _plane_point(tab, k, X, Y, Z):
    """(lambda, texel u, texel v) of the chief ray through (X, Y, Z) on triangle k's plane."""
    den = tab[k, 0] * X + tab[k, 1] * Y + tab[k, 2] * Z
    lam = tab[k, 3] / den if den != 0.0 else -1.0
    u = lam * (tab[k, 12] * X + tab[k, 13] * Y + tab[k, 14] * Z) + tab[k, 15]
    v = lam * (tab[k, 16] * X + tab[k, 17] * Y + tab[k, 18] * Z) + tab[k, 19]
    return lam, u, v


@numba.njit(cache=True, parallel=True)
def blur_and_scale(xy, rows, cols, seeds, tab, cx, cy, fx, fy, e1z, e2z, v_mm, F_mm, A_mm):
    """Per listed pixel, on its chief ray's triangle's plane: the blur radius (px, the largest at its four
    corners), the largest singular value of d texel / d pixel and that Jacobian (as
    the flat path's ``_blur_and_scale``)."""
    N = len(rows)
    rho = np.empty(N)
    scale = np.empty(N)
    J = np.empty((N, 4), dtype=np.float32)
    for i in numba.prange(N):
        r, c, k = rows[i], cols[i], seeds[i]
        worst = 0.0
        tu = np.empty(4)
        tv = np.empty(4)
        bad = False
        for q in range(4):
            X, Y, Z = focus_point(xy, r + q // 2, c + q % 2, cx, cy, fx, fy, e1z, e2z, v_mm, F_mm)
            lam, u, v = _plane_point(tab, k, X, Y, Z)
            if lam <= 0.0:
                bad = True
                break
            worst = max(worst, A_mm * abs(lam - 1.0) * fx / (lam * Z))
            tu[q], tv[q] = u, v
        if bad:
            rho[i] = np.inf
            scale[i] = np.nan
            J[i, :] = np.nan
            continue
        a = 0.5 * (tu[1] - tu[0] + tu[3] - tu[2])
        b = 0.5 * (tu[2] - tu[0] + tu[3] - tu[1])
        cc = 0.5 * (tv[1] - tv[0] + tv[3] - tv[2])
        dd = 0.5 * (tv[2] - tv[0] + tv[3] - tv[1])
        s1 = a * a + b * b + cc * cc + dd * dd
        det = a * dd - b * cc
        rho[i] = worst
        scale[i] = math.sqrt(0.5 * (s1 + math.sqrt(max(s1 * s1 - 4 * det * det, 0.0))))
        J[i, 0], J[i, 1], J[i, 2], J[i, 3] = a, b, cc, dd
    return rho, scale, J


@numba.njit(cache=True, parallel=True)
def integrate_pixels(rows, cols, seeds, bins, starts, rule, A_mm, xy, cx, cy, fx, fy, e1z, e2z, v_mm, F_mm, tab,
                     neighbours, texture, out):
    """Each listed pixel's mean texture over its square and the aperture (bin ``bins[i]``'s rows of ``rule``:
    px, py in [0, 1], ax, ay on the unit disc, weight), every node's ray walked across the mesh from the pixel's
    chief-ray triangle ``seeds[i]`` (module notes); ``NaN`` where a walk leaves the patch, takes more than
    :data:`MAX_STEPS` steps or meets the plane behind the lens."""
    trows, tcols = texture.shape
    for i in numba.prange(len(rows)):
        r, c = rows[i], cols[i]
        X0, Y0, Z0 = focus_point(xy, r, c, cx, cy, fx, fy, e1z, e2z, v_mm, F_mm)
        X1, Y1, Z1 = focus_point(xy, r, c + 1, cx, cy, fx, fy, e1z, e2z, v_mm, F_mm)
        X2, Y2, Z2 = focus_point(xy, r + 1, c, cx, cy, fx, fy, e1z, e2z, v_mm, F_mm)
        X3, Y3, Z3 = focus_point(xy, r + 1, c + 1, cx, cy, fx, fy, e1z, e2z, v_mm, F_mm)
        k = seeds[i]
        acc = 0.0
        ok = True
        b = bins[i]
        for j in range(starts[b], starts[b + 1]):
            px, py = rule[j, 0], rule[j, 1]
            w0, w1, w2, w3 = (1 - px) * (1 - py), px * (1 - py), (1 - px) * py, px * py
            FX = w0 * X0 + w1 * X1 + w2 * X2 + w3 * X3
            FY = w0 * Y0 + w1 * Y1 + w2 * Y2 + w3 * Y3
            FZ = w0 * Z0 + w1 * Z1 + w2 * Z2 + w3 * Z3
            ax, ay = A_mm * rule[j, 2], A_mm * rule[j, 3]
            steps = 0
            while True:
                nF = tab[k, 0] * FX + tab[k, 1] * FY + tab[k, 2] * FZ
                den = nF - (tab[k, 0] * ax + tab[k, 1] * ay)
                kappa = (tab[k, 3] - nF) / den if den != 0.0 else -2.0
                X = FX + kappa * (FX - ax)
                Y = FY + kappa * (FY - ay)
                Z = FZ * (1.0 + kappa)
                b1 = tab[k, 4] * X + tab[k, 5] * Y + tab[k, 6] * Z - tab[k, 7]
                b2 = tab[k, 8] * X + tab[k, 9] * Y + tab[k, 10] * Z - tab[k, 11]
                b0 = 1.0 - b1 - b2
                if b0 >= -INSIDE_TOL and b1 >= -INSIDE_TOL and b2 >= -INSIDE_TOL:
                    break
                # leave by the edge opposite the most negative coordinate
                e = 0 if (b0 <= b1 and b0 <= b2) else (1 if b1 <= b2 else 2)
                k = neighbours[k, e]
                steps += 1
                if k < 0 or steps > MAX_STEPS:
                    ok = False
                    break
            if not ok or Z <= 0.0:
                ok = False
                break
            u = tab[k, 12] * X + tab[k, 13] * Y + tab[k, 14] * Z + tab[k, 15]
            v = tab[k, 16] * X + tab[k, 17] * Y + tab[k, 18] * Z + tab[k, 19]
            acc += rule[j, 4] * bilinear_lookup(texture, trows, tcols, u, v)
        out[i] = acc if ok else np.nan


__all__ = ["CREASE_DEG", "INSIDE_TOL", "MAX_STEPS", "blur_and_scale", "edge_neighbours", "integrate_pixels",
           "smooth_components", "triangle_table"]
