"""Column-major traversal: IC-GN on the transposed images where a warp cuts subset rows into many runs.

IC-GN samples a warped subset row by row (:func:`.icgn.iterate`); a row is vectorised in *runs* of pixels whose
B-spline windows move by exactly one column per pixel, and a run ends wherever the warped position skips or
repeats a coefficient column or row: about ``2M (|u_x| + |v_x|)`` times per row of a subset of width 2M + 1. A
stereo match's foreshortening is mostly such a compression along x (the paper rig's right view: ``u_x`` ~ -0.07,
~5 runs per row of 65 px) while the subset's columns stay almost whole (``u_y``, ``v_y`` ~ 0.01). Every run costs
a loop start and a scan (benchmarks/dic_speed.py): sampled column by column, the same subset costs less.

Column order is row order of the transposed images, so the match is made there: the reference's values and
gradients, the deformed image's B-spline coefficients, the invalid-pixel mask, the grid and its bands are
transposed, each seed's shape parameters are re-expressed for x <-> y (:data:`TRANSPOSED_PARAMETERS`), and the
converged parameters and SSSIG are turned back. The ZNSSD criterion, its sums and IC-GN's steps are the same
(only their summation order differs), so the matches agree with the row-major ones to IC-GN's tolerance; the
propagation's tie order (row-major) becomes column-major. A reference cache keeps the transposed reference and its
own records for every later match (:meth:`.reference_cache.ReferenceCache.transposed`).
"""
from __future__ import annotations

import numpy as np

from .grid import PoiGrid
from .guide import propagate_grid
from .icgn import INFO_SIZE
from .status import NOT_REACHED

#: What :func:`.correlate.correlate` accepts as ``traversal``.
TRAVERSALS = ("auto", "rows", "columns")

#: Index of each parameter of the transposed warp in the original one (:data:`.shape_functions.PARAMETER_NAMES`):
#: x' = y, y' = x make u' = v, u'_x' = v_y, u'_y' = v_x, u'_x'x' = v_yy, u'_x'y' = v_xy, u'_y'y' = v_xx, and the
#: same for v'. The permutation is its own inverse.
TRANSPOSED_PARAMETERS = np.array([6, 8, 7, 11, 10, 9, 0, 2, 1, 5, 4, 3])


def expected_runs(parameters: np.ndarray, half: int) -> tuple[float, float]:
    """Median run breaks per subset row and per subset column over warps ``parameters`` (N, 12):
    ``2M (|u_x| + |v_x|)`` and ``2M (|u_y| + |v_y|)`` (M = ``half``)."""
    p = np.abs(np.asarray(parameters, dtype=np.float64).reshape(-1, 12))
    return (float(2 * half * np.median(p[:, 1] + p[:, 7])), float(2 * half * np.median(p[:, 2] + p[:, 8])))


def choose_traversal(traversal: str, seed_parameters: np.ndarray, half: int) -> str:
    """'rows' or 'columns' for ``traversal`` ('auto' decides): columns where the seeds' warps break a row at least
    once and a column at most half as often."""
    if traversal != "auto":
        return traversal
    along_rows, along_columns = expected_runs(seed_parameters, half)
    return "columns" if along_rows >= 1.0 and along_columns <= 0.5 * along_rows else "rows"


def transposed_grid(grid: PoiGrid) -> PoiGrid:
    """The POI grid seen in the transposed images: node (r, c) becomes (c, r), x and y swap."""
    return PoiGrid(np.ascontiguousarray(grid.y.T), np.ascontiguousarray(grid.x.T),
                   np.ascontiguousarray(grid.active.T), grid.subset_size, grid.step)


def transposed_reference(reference) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Values and gradients (along x', y') of a prepared reference's transpose, contiguous."""
    return (np.ascontiguousarray(reference.values.T), np.ascontiguousarray(reference.spline.grad_y.T),
            np.ascontiguousarray(reference.spline.grad_x.T))


def propagate_columns(reference, coefficients, degree, bad, check_bad, grid: PoiGrid, region, n_regions, seed_rc,
                      seed_p, settings, min_std, outputs, reference_cache=None) -> None:
    """Reliability-guided IC-GN (:func:`.guide.propagate_grid`) in column-major order, written into ``outputs``
    (params, status, zncc, iterations, sssig: the grid-shaped arrays of :func:`.correlate.correlate`).

    ``reference`` is the prepared reference (:class:`.correlate.PreparedImage`), ``coefficients`` the deformed
    image's B-spline coefficients; ``reference_cache`` (optional) lends its transposed reference and records.
    """
    params, status, zncc, iterations, sssig = outputs
    grid_t = transposed_grid(grid)
    if reference_cache is not None:
        values_t, grad_x_t, grad_y_t, cache_t = reference_cache.transposed(
            lambda: transposed_reference(reference), grid_t, settings, min_std)
        cache_arrays = (True, cache_t.info, cache_t.hinv, cache_t.a, cache_t.s)
    else:
        values_t, grad_x_t, grad_y_t = transposed_reference(reference)
        cache_arrays = (False, np.zeros((1, 1, INFO_SIZE)), np.zeros((1, 1, 1, 1)), np.zeros((1, 1, 1)),
                        np.zeros((1, 1, 1)))
    coefficients_t = np.ascontiguousarray(coefficients.T)
    bad_t = np.ascontiguousarray(bad.T) if check_bad else bad
    rows, cols = grid.shape
    params_t = np.full((cols, rows, params.shape[2]), np.nan)
    status_t = np.full((cols, rows), NOT_REACHED, dtype=status.dtype)
    zncc_t = np.full((cols, rows), np.nan)
    iterations_t = np.zeros((cols, rows), dtype=iterations.dtype)
    sssig_t = np.full((cols, rows, 2), np.nan)
    seeds_t = np.ascontiguousarray(np.asarray(seed_p)[:, TRANSPOSED_PARAMETERS])
    propagate_grid(values_t, grad_x_t, grad_y_t, coefficients_t, degree, bad_t, check_bad, grid_t.x, grid_t.y,
                   grid_t.active, np.ascontiguousarray(region.T), n_regions,
                   np.ascontiguousarray(np.asarray(seed_rc)[:, ::-1]), seeds_t, grid.half, settings, min_std,
                   params_t, status_t, zncc_t, iterations_t, sssig_t, cache_arrays)
    params[...] = params_t.transpose(1, 0, 2)[..., TRANSPOSED_PARAMETERS]
    status[...] = status_t.T
    zncc[...] = zncc_t.T
    iterations[...] = iterations_t.T
    sssig[...] = sssig_t.transpose(1, 0, 2)[..., ::-1]


__all__ = ["TRANSPOSED_PARAMETERS", "TRAVERSALS", "choose_traversal", "expected_runs", "propagate_columns",
           "transposed_grid", "transposed_reference"]
