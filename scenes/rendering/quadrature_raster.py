"""Deterministic pixel integrals of smoothly textured triangles: Gauss-Legendre quadrature, no Monte Carlo.

A pinhole pixel of a bilinearly interpolated texture (a speckle print) on a flat triangle is the mean of the
texture over the pixel's footprint on the triangle's plane. This module evaluates that mean with an
``n x n`` Gauss-Legendre rule over the pixel square: the ray of each node is interpolated bilinearly from the
exact rays of the pixel's four corners (the mapping from the sensor to the rays is smooth: across one pixel its
curvature, from the lens distortion, moves a node by ~1e-7 px), intersected with the triangle's plane, and the
texture is read there with Mitsuba's convention (``uv * size - 0.5``, clamp to the edge). Nodes that miss the
triangle are left out: the caller weights the mean of the nodes inside by the triangle set's exact coverage of
the pixel (:mod:`scenes.rendering.coverage_raster`), so edges cost no Monte-Carlo-like error.

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
    [c0, r0, c1, r1) in crop pixels; D (h + 1, w + 1, 3) corner rays; S, W (threads, h, w).

    A node's ray is the bilinear blend of its pixel's corner rays, and the barycentric coordinates of its hit on
    the triangle's plane are ``b = nd (alpha . d) / (n . d) + beta``: the three dot products are linear in the
    ray, so they are taken at the four corners once per pixel and blended per node (3 blends and 1 division a
    node instead of a ray blend, an intersection and a projection)."""
    rows, cols = texture.shape
    n = nodes.size
    # per node: the bilinear weights of its pixel's four corners and its quadrature weight
    c00 = np.empty(n * n)
    c01 = np.empty(n * n)
    c10 = np.empty(n * n)
    c11 = np.empty(n * n)
    wn = np.empty(n * n)
    for a in range(n):
        t = nodes[a]
        for b in range(n):
            s = nodes[b]
            m = a * n + b
            c00[m] = (1 - s) * (1 - t)
            c01[m] = s * (1 - t)
            c10[m] = (1 - s) * t
            c11[m] = s * t
            wn[m] = weights[a] * weights[b]
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
        # b1 = (g22 h1 - g12 h2) / det, h_i = e_i . (lam d - p0): b = lam (alpha . d) + beta
        a1x = (g22 * e1[0] - g12 * e2[0]) / det
        a1y = (g22 * e1[1] - g12 * e2[1]) / det
        a1z = (g22 * e1[2] - g12 * e2[2]) / det
        a2x = (g11 * e2[0] - g12 * e1[0]) / det
        a2y = (g11 * e2[1] - g12 * e1[1]) / det
        a2z = (g11 * e2[2] - g12 * e1[2]) / det
        beta1 = -(a1x * p0[0] + a1y * p0[1] + a1z * p0[2])
        beta2 = -(a2x * p0[0] + a2y * p0[1] + a2z * p0[2])
        u0, v0 = UV[k, 0, 0], UV[k, 0, 1]
        du1, dv1 = UV[k, 1, 0] - u0, UV[k, 1, 1] - v0
        du2, dv2 = UV[k, 2, 0] - u0, UV[k, 2, 1] - v0
        for r in range(boxes[k, 1], boxes[k, 3]):
            for c in range(boxes[k, 0], boxes[k, 2]):
                # the three dot products at the pixel's corners: 00 (r, c), 01 (r, c + 1), 10 (r + 1, c), 11
                q00 = D[r, c]
                q01 = D[r, c + 1]
                q10 = D[r + 1, c]
                q11 = D[r + 1, c + 1]
                n00 = nx * q00[0] + ny * q00[1] + nz * q00[2]
                n01 = nx * q01[0] + ny * q01[1] + nz * q01[2]
                n10 = nx * q10[0] + ny * q10[1] + nz * q10[2]
                n11 = nx * q11[0] + ny * q11[1] + nz * q11[2]
                x00 = a1x * q00[0] + a1y * q00[1] + a1z * q00[2]
                x01 = a1x * q01[0] + a1y * q01[1] + a1z * q01[2]
                x10 = a1x * q10[0] + a1y * q10[1] + a1z * q10[2]
                x11 = a1x * q11[0] + a1y * q11[1] + a1z * q11[2]
                y00 = a2x * q00[0] + a2y * q00[1] + a2z * q00[2]
                y01 = a2x * q01[0] + a2y * q01[1] + a2z * q01[2]
                y10 = a2x * q10[0] + a2y * q10[1] + a2z * q10[2]
                y11 = a2x * q11[0] + a2y * q11[1] + a2z * q11[2]
                s_acc = 0.0
                w_acc = 0.0
                for m in range(n * n):
                    den = c00[m] * n00 + c01[m] * n01 + c10[m] * n10 + c11[m] * n11
                    if den == 0.0:
                        continue
                    lam = nd / den
                    if lam <= 0.0:
                        continue
                    b1 = lam * (c00[m] * x00 + c01[m] * x01 + c10[m] * x10 + c11[m] * x11) + beta1
                    b2 = lam * (c00[m] * y00 + c01[m] * y01 + c10[m] * y10 + c11[m] * y11) + beta2
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
                    s_acc += wn[m] * f
                    w_acc += wn[m]
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
                   _texture_array(texture), nodes, weights, S, W)
    return S.sum(axis=0), W.sum(axis=0)


def _texture_array(texture) -> np.ndarray:
    """The texture as the kernel reads it: float32 kept as it is (a 5 MP plate's texture is 400 MB in float64,
    and the values read are the same), anything else as float64."""
    t = np.asarray(texture)
    return np.ascontiguousarray(t if t.dtype == np.float32 else t.astype(np.float64))


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
    """Compile (or load from numba's disk cache) the kernels on a tiny input: ``python -m scenes.rendering.quadrature_raster``
    runs it, so a long job can fill the cache in another process before it first renders."""
    P = np.array([[[-1.0, -1.0, 10.0], [1.0, -1.0, 10.0], [0.0, 1.0, 10.0]]])
    uv = np.array([[[0.0, 0.0], [1.0, 0.0], [0.5, 1.0]]])
    xs, ys = np.meshgrid(np.linspace(-0.2, 0.2, 5), np.linspace(-0.2, 0.2, 5))
    rays = np.stack([xs, ys, np.ones_like(xs)], axis=-1)
    S, W = integrate_triangles(P, uv, np.array([[0, 0, 4, 4]]), rays, np.ones((2, 2)), 2)
    fill_from_neighbours(np.where(W > 0, S, 0.0), W > 0, np.ones(W.shape, dtype=bool))


if __name__ == "__main__":
    warm_up()
