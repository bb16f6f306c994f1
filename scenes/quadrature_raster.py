"""Deterministic pixel integrals of smoothly textured triangles: Gauss-Legendre quadrature, no Monte Carlo.

A pinhole pixel of a bilinearly interpolated texture (a speckle print) on a flat triangle is the mean of the
texture over the pixel's footprint on the triangle's plane. This module evaluates that mean with an
``n x n`` Gauss-Legendre rule over the pixel square: the ray of each node is interpolated bilinearly from the
exact rays of the pixel's four corners (the mapping from the sensor to the rays is smooth: across one pixel its
curvature, from the lens distortion, moves a node by ~1e-7 px), intersected with the triangle's plane, and the
texture is read there with Mitsuba's convention (``uv * size - 0.5``, clamp to the edge). Nodes that miss the
triangle are left out: the caller weights the mean of the nodes inside by the triangle set's exact coverage of
the pixel (:mod:`scenes.coverage_raster`), so edges cost no Monte-Carlo-like error.

The rule integrates a smooth texture to high order; a bilinear texture has kinks along its texel lines, where the
error falls as ``n^-2``: ``tests/test_exact_render.py`` and ``benchmarks/render_exact_speckle.py`` measure it
against converged Mitsuba renders.
"""
from __future__ import annotations

import numba
import numpy as np


def gauss_legendre_unit(n: int) -> tuple[np.ndarray, np.ndarray]:
    """Nodes in [0, 1] and weights summing to 1 of the ``n``-point Gauss-Legendre rule."""
    if n < 1:
        raise ValueError(f"quadrature order must be >= 1, got {n}")
    x, w = np.polynomial.legendre.leggauss(int(n))
    return 0.5 * (x + 1.0), 0.5 * w


@numba.njit(cache=True, parallel=True)
def _integrate(P, UV, boxes, D, texture, nodes, weights, S, W):
    """Accumulate ``sum w f`` and ``sum w`` of the nodes inside each triangle into S[thread], W[thread].

    P (T, 3, 3) camera-frame vertices (mm); UV (T, 3, 2) texel coordinates (``uv * size - 0.5``); boxes (T, 4)
    [c0, r0, c1, r1) in crop pixels; D (h + 1, w + 1, 3) corner rays; S, W (threads, h, w)."""
    rows, cols = texture.shape
    n = nodes.size
    for k in numba.prange(P.shape[0]):
        thread = numba.get_thread_id()
        p0 = P[k, 0]
        e1 = P[k, 1] - p0
        e2 = P[k, 2] - p0
        nx = e1[1] * e2[2] - e1[2] * e2[1]
        ny = e1[2] * e2[0] - e1[0] * e2[2]
        nz = e1[0] * e2[1] - e1[1] * e2[0]
        nd = nx * p0[0] + ny * p0[1] + nz * p0[2]
        g11 = e1[0] * e1[0] + e1[1] * e1[1] + e1[2] * e1[2]
        g12 = e1[0] * e2[0] + e1[1] * e2[1] + e1[2] * e2[2]
        g22 = e2[0] * e2[0] + e2[1] * e2[1] + e2[2] * e2[2]
        det = g11 * g22 - g12 * g12
        if det <= 0.0 or nd == 0.0:
            continue
        u0, v0 = UV[k, 0, 0], UV[k, 0, 1]
        du1, dv1 = UV[k, 1, 0] - u0, UV[k, 1, 1] - v0
        du2, dv2 = UV[k, 2, 0] - u0, UV[k, 2, 1] - v0
        for r in range(boxes[k, 1], boxes[k, 3]):
            for c in range(boxes[k, 0], boxes[k, 2]):
                s_acc = 0.0
                w_acc = 0.0
                for a in range(n):
                    t = nodes[a]
                    for b in range(n):
                        s = nodes[b]
                        w = weights[a] * weights[b]
                        dx = ((1 - s) * (1 - t) * D[r, c, 0] + s * (1 - t) * D[r, c + 1, 0]
                              + (1 - s) * t * D[r + 1, c, 0] + s * t * D[r + 1, c + 1, 0])
                        dy = ((1 - s) * (1 - t) * D[r, c, 1] + s * (1 - t) * D[r, c + 1, 1]
                              + (1 - s) * t * D[r + 1, c, 1] + s * t * D[r + 1, c + 1, 1])
                        dz = ((1 - s) * (1 - t) * D[r, c, 2] + s * (1 - t) * D[r, c + 1, 2]
                              + (1 - s) * t * D[r + 1, c, 2] + s * t * D[r + 1, c + 1, 2])
                        den = nx * dx + ny * dy + nz * dz
                        if den == 0.0:
                            continue
                        lam = nd / den
                        if lam <= 0.0:
                            continue
                        qx = lam * dx - p0[0]
                        qy = lam * dy - p0[1]
                        qz = lam * dz - p0[2]
                        h1 = e1[0] * qx + e1[1] * qy + e1[2] * qz
                        h2 = e2[0] * qx + e2[1] * qy + e2[2] * qz
                        b1 = (g22 * h1 - g12 * h2) / det
                        b2 = (g11 * h2 - g12 * h1) / det
                        if b1 < 0.0 or b2 < 0.0 or b1 + b2 > 1.0:
                            continue
                        # texel coordinates, Mitsuba's bilinear lookup with clamp-to-edge
                        x = u0 + b1 * du1 + b2 * du2
                        y = v0 + b1 * dv1 + b2 * dv2
                        xf = np.floor(x)
                        yf = np.floor(y)
                        fx = x - xf
                        fy = y - yf
                        i0 = min(max(int(xf), 0), cols - 1)
                        i1 = min(max(int(xf) + 1, 0), cols - 1)
                        j0 = min(max(int(yf), 0), rows - 1)
                        j1 = min(max(int(yf) + 1, 0), rows - 1)
                        f = ((1 - fx) * (1 - fy) * texture[j0, i0] + fx * (1 - fy) * texture[j0, i1]
                             + (1 - fx) * fy * texture[j1, i0] + fx * fy * texture[j1, i1])
                        s_acc += w * f
                        w_acc += w
                if w_acc > 0.0:
                    S[thread, r, c] += s_acc
                    W[thread, r, c] += w_acc


def integrate_triangles(P_cam_mm: np.ndarray, uv_texel: np.ndarray, boxes: np.ndarray, corner_rays: np.ndarray,
                        texture: np.ndarray, order: int) -> tuple[np.ndarray, np.ndarray]:
    """Quadrature sums of textured triangles over a crop of pixels.

    Parameters
    ----------
    P_cam_mm : (T, 3, 3) float, the triangles' vertices in the camera frame (pinhole at the origin), mm
    uv_texel : (T, 3, 2) float, their texel coordinates in Mitsuba's convention (``u * cols - 0.5``,
        ``v * rows - 0.5``)
    boxes : (T, 4) int, ``[c0, r0, c1, r1)`` pixel range of each triangle in the crop (clipped to it)
    corner_rays : (h + 1, w + 1, 3) float, ray directions through the crop's pixel corners, camera frame
    texture : (rows, cols) float, radiance
    order : nodes per pixel side (the rule has ``order ** 2`` nodes)

    Returns
    -------
    weighted_sum, weight : (h, w) float64
        ``sum w f`` and ``sum w`` over the nodes of each pixel that fall inside a triangle (weights per pixel
        sum to 1, so ``weight`` is the node estimate of the covered fraction and ``weighted_sum / weight`` the
        mean texture over the covered part).
    """
    h, w = corner_rays.shape[0] - 1, corner_rays.shape[1] - 1
    nodes, weights = gauss_legendre_unit(order)
    threads = numba.get_num_threads()
    S = np.zeros((threads, h, w))
    W = np.zeros((threads, h, w))
    if len(P_cam_mm):
        _integrate(np.ascontiguousarray(P_cam_mm, dtype=np.float64), np.ascontiguousarray(uv_texel, dtype=np.float64),
                   np.ascontiguousarray(boxes, dtype=np.int64), np.ascontiguousarray(corner_rays, dtype=np.float64),
                   np.ascontiguousarray(texture, dtype=np.float64), nodes, weights, S, W)
    return S.sum(axis=0), W.sum(axis=0)


@numba.njit(cache=True)
def fill_from_neighbours(mean: np.ndarray, known: np.ndarray, wanted: np.ndarray) -> np.ndarray:
    """``mean`` where ``known``; elsewhere, where ``wanted``, the average of the known 8-neighbours (a sliver of a
    triangle that no node hit takes its neighbours' texture mean); 0 if none is known."""
    out = mean.copy()
    rows, cols = mean.shape
    for r in range(rows):
        for c in range(cols):
            if known[r, c] or not wanted[r, c]:
                continue
            total = 0.0
            count = 0
            for dr in range(-1, 2):
                for dc in range(-1, 2):
                    rr, cc = r + dr, c + dc
                    if 0 <= rr < rows and 0 <= cc < cols and known[rr, cc]:
                        total += mean[rr, cc]
                        count += 1
            out[r, c] = total / count if count else 0.0
    return out


def warm_up() -> None:
    """Compile (or load from numba's disk cache) the kernels on a tiny input: ``python -m scenes.quadrature_raster``
    runs it, so a long job can fill the cache in another process before it first renders."""
    P = np.array([[[-1.0, -1.0, 10.0], [1.0, -1.0, 10.0], [0.0, 1.0, 10.0]]])
    uv = np.array([[[0.0, 0.0], [1.0, 0.0], [0.5, 1.0]]])
    xs, ys = np.meshgrid(np.linspace(-0.2, 0.2, 5), np.linspace(-0.2, 0.2, 5))
    rays = np.stack([xs, ys, np.ones_like(xs)], axis=-1)
    S, W = integrate_triangles(P, uv, np.array([[0, 0, 4, 4]]), rays, np.ones((2, 2)), 2)
    fill_from_neighbours(np.where(W > 0, S, 0.0), W > 0, np.ones(W.shape, dtype=bool))


if __name__ == "__main__":
    warm_up()
