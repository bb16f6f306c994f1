"""Exact area coverage of polygons on the pixel grid (truth side, numba, no sampling).

The box-filtered value of a pixel under a piecewise-constant picture is the sum, over the picture's polygons,
of each polygon's value times the fraction of the pixel's square it covers. That fraction is computed exactly
here, for any polygon with straight edges, by the signed-area accumulation of font rasterisers (Levien's
font-rs; the same identity as the shoelace formula): every edge adds, to each pixel cell it crosses, the
signed area of the cell lying to the right of it within the rows it spans, and a running sum along each row
turns those increments into the covered fraction. Edges of a closed polygon cancel outside it, so nothing
but the edges is visited: the cost is the edges' length in pixels plus one pass over the image.

Conventions: pixel (row i, column j) is the square ``[j - 0.5, j + 0.5] x [i - 0.5, i + 0.5]`` in OpenCV pixel
coordinates (centres at integers). A polygon contributes ``weight * area / 1 px^2`` where it covers a pixel,
whatever the order of its vertices; contributions add linearly, so overlapping polygons sum and a hole is a
polygon of opposite weight. A self-intersecting polygon counts each region with its winding number.
"""
from __future__ import annotations

import numba
import numpy as np


def polygon_signed_area_px2(xy: np.ndarray) -> float:
    """Shoelace area of a closed polygon (vertices in order, the first not repeated), px^2: positive for
    vertices counter-clockwise in (x, y) axes (clockwise on an image whose y points down)."""
    x, y = np.asarray(xy, float).T
    return float(0.5 * np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))


@numba.njit(cache=True)
def _add_piece(acc, row, xa, ya, xb, yb, w):
    """One edge piece within a pixel row (ya, yb inside [row, row + 1]): split at integer x, add to the cells."""
    cols = acc.shape[1]
    dy = (yb - ya) * w
    if dy == 0.0:
        return
    x_lo = min(xa, xb)
    x_hi = max(xa, xb)
    if x_hi <= 0.0:                       # wholly left of the image: every pixel of the row is to its right
        acc[row, 0] += dy
        return
    if x_lo >= cols:                      # wholly right of the image: covers nothing in it
        return
    c0 = int(np.floor(x_lo))
    c1 = int(np.floor(x_hi))
    if c0 == c1 or x_hi == x_lo:
        _add_cell(acc, row, c0, 0.5 * (xa + xb), dy)
        return
    # crosses columns: walk the integer x boundaries from xa to xb
    step = 1 if xb > xa else -1
    inv = (yb - ya) / (xb - xa)
    x_prev, y_prev = xa, ya
    c = int(np.floor(xa)) if step > 0 else int(np.ceil(xa)) - 1
    while True:
        boundary = c + 1 if step > 0 else c
        if (step > 0 and boundary >= xb) or (step < 0 and boundary <= xb):
            _add_cell(acc, row, c, 0.5 * (x_prev + xb), (yb - y_prev) * w)
            break
        y_cross = ya + (boundary - xa) * inv
        _add_cell(acc, row, c, 0.5 * (x_prev + boundary), (y_cross - y_prev) * w)
        x_prev, y_prev = float(boundary), y_cross
        c += step


@numba.njit(cache=True)
def _add_cell(acc, row, c, x_mid, dy):
    """Area of cell ``c`` to the right of a piece with mean x ``x_mid`` and height ``dy``; the rest to c + 1."""
    cols = acc.shape[1]
    if c < 0:
        acc[row, 0] += dy
        return
    if c >= cols:
        return
    right = dy * (c + 1.0 - x_mid)
    acc[row, c] += right
    if c + 1 < cols:
        acc[row, c + 1] += dy - right


@numba.njit(cache=True)
def _accumulate(acc, xs, ys, starts, weights):
    """Edges of every polygon k (vertices ``starts[k]:starts[k+1]``, closed) into ``acc`` with ``weights[k]``."""
    rows = acc.shape[0]
    for k in range(starts.size - 1):
        w = weights[k]
        a, b = starts[k], starts[k + 1]
        for i in range(a, b):
            j = i + 1 if i + 1 < b else a
            x0, y0, x1, y1 = xs[i], ys[i], xs[j], ys[j]
            if y0 == y1:
                continue
            lo, hi = min(y0, y1), max(y0, y1)
            if hi <= 0.0 or lo >= rows:
                continue
            r0 = max(int(np.floor(lo)), 0)
            r1 = min(int(np.ceil(hi)) - 1, rows - 1)
            slope = (x1 - x0) / (y1 - y0)
            for r in range(r0, r1 + 1):
                ya = min(max(y0, float(r)), float(r + 1)) if y0 < y1 else max(min(y0, float(r + 1)), float(r))
                yb = min(max(y1, float(r)), float(r + 1)) if y0 < y1 else max(min(y1, float(r + 1)), float(r))
                if ya == yb:
                    continue
                xa = x0 + (ya - y0) * slope
                xb = x0 + (yb - y0) * slope
                _add_piece(acc, r, xa, ya, xb, yb, w)


def accumulate_polygons(polygons_px: list[np.ndarray], weights, shape: tuple[int, int],
                        origin_px: tuple[float, float] = (0.0, 0.0)) -> np.ndarray:
    """Box-filtered sum of weighted polygons on a pixel grid.

    Parameters
    ----------
    polygons_px : list of (K, 2) float arrays
        Closed polygons (first vertex not repeated), OpenCV pixel coordinates of the full image.
    weights : (P,) float
        Value of each polygon (e.g. radiance times exposure).
    shape : (rows, cols)
        Size of the window to fill.
    origin_px : (x0, y0)
        Pixel coordinates of the window's first pixel centre (a crop of a larger image).

    Returns
    -------
    (rows, cols) float64
        ``sum_k weights[k] * area(polygon_k ∩ pixel) / 1 px^2`` for every pixel.
    """
    weights = np.asarray(weights, dtype=np.float64).reshape(-1)
    if len(polygons_px) != weights.size:
        raise ValueError(f"{len(polygons_px)} polygons but {weights.size} weights")
    if not polygons_px:
        return np.zeros((int(shape[0]), int(shape[1])), dtype=np.float64)
    polygons = [np.asarray(p, dtype=np.float64).reshape(-1, 2) for p in polygons_px]
    starts = np.concatenate([[0], np.cumsum([len(p) for p in polygons])]).astype(np.int64)
    return accumulate_flat(np.concatenate(polygons), starts, weights, shape, origin_px)


def accumulate_flat(xy_px: np.ndarray, starts: np.ndarray, weights, shape: tuple[int, int],
                    origin_px: tuple[float, float] = (0.0, 0.0)) -> np.ndarray:
    """:func:`accumulate_polygons` for polygons stored flat: vertices ``xy_px[starts[k]:starts[k + 1]]`` make
    polygon k ((N, 2) vertices, (P + 1,) starts)."""
    rows, cols = (int(v) for v in shape)
    xy = np.ascontiguousarray(xy_px, dtype=np.float64).reshape(-1, 2)
    starts = np.ascontiguousarray(starts, dtype=np.int64)
    weights = np.asarray(weights, dtype=np.float64).reshape(-1)
    if weights.size != starts.size - 1:
        raise ValueError(f"{starts.size - 1} polygons but {weights.size} weights")
    acc = np.zeros((rows, cols), dtype=np.float64)
    if weights.size == 0:
        return acc
    if not np.all(np.isfinite(xy)):
        raise ValueError("a polygon vertex is not finite")
    # the accumulation counts +1 inside a polygon whose shoelace area is negative: the others count with -weight
    nxt = np.arange(len(xy)) + 1
    nxt[starts[1:] - 1] = starts[:-1]
    cross = xy[:, 0] * xy[nxt, 1] - xy[nxt, 0] * xy[:, 1]
    sign = np.where(np.add.reduceat(cross, starts[:-1]) > 0, -1.0, 1.0)
    # cell c of the window spans [c, c + 1) after this shift (pixel centres at integers + 0.5)
    _accumulate(acc, xy[:, 0] - origin_px[0] + 0.5, xy[:, 1] - origin_px[1] + 0.5, starts, weights * sign)
    return np.cumsum(acc, axis=1)
