"""Reliability-guided propagation of IC-GN over a POI grid (Pan 2009, "Reliability-guided digital image
correlation for image deformation measurement", Appl. Opt. 48, 1535-1542).

From each seed, points are processed in order of decreasing ZNCC of the converged point they are reached
from: a max-heap holds converged points, the best is popped and its four grid neighbours are computed by
IC-GN starting from its warp carried over to their position (:func:`.shape_functions.shift_parameters`).
Large and spatially varying displacements are followed as long as they vary smoothly on the grid scale,
and a bad point (low correlation, failure) never passes its guess on.

The grid is cut into ``regions`` vertical bands that propagate independently, each from its own seeds, so
the bands run on separate threads. The cut does not depend on the number of threads, so results are the
same on any machine. Points a band could not reach from its own seeds are then reached, in a last
single-region pass, from the converged points around them.
"""
from __future__ import annotations

import heapq

import numba
import numpy as np

from .icgn import solve_node
from .shape_functions import shift_parameters
from .status import CONVERGED, NOT_REACHED


#: ZNCC resolution of the propagation order. Points are taken best-correlated first, but ZNCC is rounded down to
#: this step so that points of equal quality go in grid (row-major) order: that keeps the subsets just used in
#: the cache, which makes propagation ~30 % faster than a strict ZNCC order for no loss of robustness.
PRIORITY_STEP = 0.01


@numba.njit(inline="always")
def _priority(zncc):
    return -np.floor(zncc / PRIORITY_STEP) * PRIORITY_STEP


@numba.njit(cache=True)
def _propagate_region(image, grad_x, grad_y, coef, degree, bad, check_bad, grid_x, grid_y, active, region,
                      region_id, seed_rc, seed_p, half, order, min_std, max_iterations, tolerance_px, min_zncc,
                      params, status, zncc, iterations, sssig, resume, use_cache, cache_info, cache_hinv, cache_a,
                      cache_s):
    n_rows, n_cols = grid_x.shape
    heap = [(0.0, 0)]
    heap.pop()
    guess = np.empty(12)
    for k in range(seed_rc.shape[0]):
        r, c = seed_rc[k, 0], seed_rc[k, 1]
        if region[r, c] != region_id or status[r, c] == CONVERGED:
            continue
        for j in range(12):
            guess[j] = seed_p[k, j]
        st, score, it, sx, sy = solve_node(image, grad_x, grad_y, coef, degree, bad, check_bad, grid_x[r, c],
                                            grid_y[r, c], half, order, min_std, guess, max_iterations,
                                            tolerance_px, min_zncc, use_cache, cache_info, cache_hinv, cache_a,
                                            cache_s, r, c)
        # A seed that fails leaves its point free for a neighbour to reach later.
        if st == CONVERGED:
            params[r, c, :] = guess
            status[r, c] = st
            zncc[r, c] = score
            iterations[r, c] = it
            sssig[r, c, 0] = sx
            sssig[r, c, 1] = sy
            heapq.heappush(heap, (_priority(score), r * n_cols + c))
    if resume:
        # Continue from points already converged (e.g. by another region) that border unreached ones.
        for r0 in range(n_rows):
            for c0 in range(n_cols):
                if status[r0, c0] != CONVERGED:
                    continue
                for neighbour in range(4):
                    r = r0 + (neighbour == 1) - (neighbour == 0)
                    c = c0 + (neighbour == 3) - (neighbour == 2)
                    if 0 <= r < n_rows and 0 <= c < n_cols and active[r, c] and status[r, c] == NOT_REACHED \
                            and region[r, c] == region_id:
                        heapq.heappush(heap, (_priority(zncc[r0, c0]), r0 * n_cols + c0))
                        break
    source = np.empty(12)
    while len(heap) > 0:
        _, index = heapq.heappop(heap)
        r0 = index // n_cols
        c0 = index % n_cols
        for source_k in range(12):
            source[source_k] = params[r0, c0, source_k]
        for neighbour in range(4):
            r = r0 + (neighbour == 1) - (neighbour == 0)
            c = c0 + (neighbour == 3) - (neighbour == 2)
            if r < 0 or c < 0 or r >= n_rows or c >= n_cols:
                continue
            if not active[r, c] or region[r, c] != region_id or status[r, c] != NOT_REACHED:
                continue
            shift_parameters(source, float(grid_x[r, c] - grid_x[r0, c0]), float(grid_y[r, c] - grid_y[r0, c0]),
                             guess)
            st, score, it, sx, sy = solve_node(image, grad_x, grad_y, coef, degree, bad, check_bad,
                                                grid_x[r, c], grid_y[r, c], half, order, min_std, guess,
                                                max_iterations, tolerance_px, min_zncc, use_cache, cache_info,
                                                cache_hinv, cache_a, cache_s, r, c)
            status[r, c] = st
            zncc[r, c] = score
            iterations[r, c] = it
            sssig[r, c, 0] = sx
            sssig[r, c, 1] = sy
            if st == CONVERGED:
                params[r, c, :] = guess
                heapq.heappush(heap, (_priority(score), r * n_cols + c))


@numba.njit(cache=True, parallel=True)
def propagate(image, grad_x, grad_y, coef, degree, bad, check_bad, grid_x, grid_y, active, region, n_regions,
              seed_rc, seed_p, half, order, min_std, max_iterations, tolerance_px, min_zncc,
              params, status, zncc, iterations, sssig, resume, use_cache, cache_info, cache_hinv, cache_a, cache_s):
    """Reliability-guided IC-GN over every region in parallel.

    Parameters
    ----------
    image, grad_x, grad_y : ndarray of float64, shape (rows, cols)
        Reference image and its spline gradients at pixel centres.
    coef : ndarray of float32, shape (rows, cols)
        B-spline coefficients of the deformed image.
    degree : int
        3 or 5.
    bad : ndarray of bool, shape (rows, cols); check_bad : bool
        Invalid deformed pixels (dilated by the spline support), checked when ``check_bad``.
    grid_x, grid_y : ndarray of int64, shape (n_rows, n_cols)
        POI positions, px.
    active : ndarray of bool, shape (n_rows, n_cols)
    region : ndarray of int64, shape (n_rows, n_cols)
        Region index of each node, 0 .. n_regions - 1.
    seed_rc : ndarray of int64, shape (n_seeds, 2)
        Grid (row, col) of the seeds, in order of preference.
    seed_p : ndarray of float64, shape (n_seeds, 12)
        Initial parameters of the seeds.
    params : ndarray of float64, shape (n_rows, n_cols, 12)
        Out: converged parameters (untouched elsewhere).
    status : ndarray of int64, shape (n_rows, n_cols)
        In: NOT_REACHED on every node to compute. Out: status per node.
    zncc, iterations, sssig
        Out, per node.
    resume : bool
        Also start from the converged nodes that border unreached ones in their region (no seed needed):
        used for a last pass with a single region, so bands whose own seeds failed are reached from their
        neighbours.
    use_cache : bool; cache_info, cache_hinv, cache_a, cache_s : ndarray
        The reference side of every node (:class:`.reference_cache.ReferenceCache`'s arrays, shaped as the
        grid): read where a node's record is filled, computed and written where not. Ignored (any shape) when
        ``use_cache`` is False.
    """
    for region_id in numba.prange(n_regions):
        _propagate_region(image, grad_x, grad_y, coef, degree, bad, check_bad, grid_x, grid_y, active, region,
                          region_id, seed_rc, seed_p, half, order, min_std, max_iterations, tolerance_px,
                          min_zncc, params, status, zncc, iterations, sssig, resume, use_cache, cache_info,
                          cache_hinv, cache_a, cache_s)


def propagate_grid(image, grad_x, grad_y, coef, degree, bad, check_bad, grid_x, grid_y, active, region, n_regions,
                   seed_rc, seed_p, half, settings, min_std, params, status, zncc, iterations, sssig, cache_arrays):
    """:func:`propagate` over every band from the seeds, then one single-region pass that reaches, from their
    converged neighbours, the points a band could not reach from its own seeds. Arguments as :func:`propagate`
    (``settings`` a :class:`.correlate.DICSettings`; ``cache_arrays`` = (use_cache, info, hinv, a, s))."""
    grid_x = np.asarray(grid_x, dtype=np.int64)
    grid_y = np.asarray(grid_y, dtype=np.int64)
    # Bands can hold very different amounts of work (part of the ROI out of view): hand them out one at a time
    # instead of in fixed chunks per thread.
    with numba.parallel_chunksize(1):
        propagate(image, grad_x, grad_y, coef, degree, bad, check_bad, grid_x, grid_y, active, region, n_regions,
                  seed_rc, seed_p, half, settings.order, min_std, int(settings.max_iterations),
                  float(settings.tolerance_px), float(settings.min_zncc), params, status, zncc, iterations, sssig,
                  False, *cache_arrays)
    unreached = active & (status == NOT_REACHED)
    if n_regions > 1 and unreached.any() and (status == CONVERGED).any():
        propagate(image, grad_x, grad_y, coef, degree, bad, check_bad, grid_x, grid_y, active,
                  np.zeros(active.shape, dtype=np.int64), 1, seed_rc[:0], seed_p[:0], half, settings.order, min_std,
                  int(settings.max_iterations), float(settings.tolerance_px), float(settings.min_zncc), params,
                  status, zncc, iterations, sssig, True, *cache_arrays)


def band_regions(shape: tuple[int, int], n_regions: int) -> np.ndarray:
    """Cut a grid of ``shape`` (n_rows, n_cols) into ``n_regions`` vertical bands; returns region ids."""
    n_rows, n_cols = shape
    n_regions = max(1, min(int(n_regions), n_cols))
    column_region = (np.arange(n_cols) * n_regions) // n_cols
    return np.broadcast_to(column_region[None, :], (n_rows, n_cols)).astype(np.int64).copy()
