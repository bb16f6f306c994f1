"""Two-image subset DIC: the public entry point that ties grid, seeds, propagation and IC-GN together.

``correlate(reference, deformed, settings)`` returns a :class:`DICResult` with, for every point of interest,
the displacement, the shape-function parameters, the ZNCC, the iteration count and a :class:`Status`.
A point that fails has NaN numbers and says why in its status.
"""
from __future__ import annotations

import csv
import time
import warnings
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

import numba
import numpy as np
from scipy import ndimage

from labio.atomic import atomic_writer

from . import bspline
from .grid import PoiGrid, check_subset_size, poi_grid
from .guide import band_regions, propagate_grid
from .icgn import INFO_SIZE, correlate_batch
from .initial import DEFAULT_SEED_ANGLES_DEG, Seed, zncc_search
from .reference_cache import ReferenceCache
from .shape_functions import N_PARAMETERS, PARAMETER_NAMES, SECOND_ORDER
from .status import CONVERGED, NOT_REACHED, Status
from .traversal import TRAVERSALS, choose_traversal, propagate_columns


@dataclass(frozen=True)
class DICSettings:
    """Settings of a 2-D DIC run.

    Attributes
    ----------
    subset_size : int
        Odd subset width 2M + 1, px.
    step : int
        POI grid spacing, px.
    order : int
        Shape function: 1 (affine, 6 parameters) or 2 (quadratic, 12).
    interpolation : str
        'biquintic' (the paper's) or 'bicubic' B-spline.
    max_iterations : int
        IC-GN iteration cap.
    tolerance_px : float
        Convergence threshold on the increment at the subset edge, px.
    min_zncc : float
        Converged points below this ZNCC get LOW_CORRELATION (NaN) and do not pass their guess on.
    min_subset_std : float or None
        Subsets whose grey-level standard deviation is below this are LOW_TEXTURE. None: 0.5 % of the
        reference image's grey range (0.5-99.5 percentiles).
    search_radius_px : int
        Half-width of the seed search window, px (the largest displacement a seed finds from its centre guess).
    seed_angles_deg : tuple of float
        Rotations tried by the seed search (deg).
    regions : int
        Vertical bands propagated independently (and in parallel), each from its own seed.
    lowpass_sigma_px : float
        Gaussian low-pass applied to both images before matching (Pan 2013, "Bias error reduction of digital
        image correlation using Gaussian pre-filtering"), px; 0 disables it. It cuts the interpolation bias on
        fine speckles (the spline errs most near the Nyquist frequency) at the price of a somewhat larger
        random error; a translation commutes with the filter, so the truth is unchanged.
    """

    subset_size: int = 33
    step: int = 8
    order: int = 1
    interpolation: str = "biquintic"
    max_iterations: int = 50
    tolerance_px: float = 1e-3
    min_zncc: float = 0.8
    min_subset_std: float | None = None
    search_radius_px: int = 32
    seed_angles_deg: tuple = DEFAULT_SEED_ANGLES_DEG
    regions: int = 4
    lowpass_sigma_px: float = 0.0

    def __post_init__(self):
        check_subset_size(self.subset_size)
        if self.order not in (1, 2):
            raise ValueError(f"order must be 1 or 2, got {self.order!r}")
        bspline.degree_of(self.interpolation)
        if int(self.max_iterations) < 1:
            raise ValueError(f"max_iterations must be >= 1, got {self.max_iterations}")
        if not (np.isfinite(self.tolerance_px) and self.tolerance_px > 0):
            raise ValueError(f"tolerance_px must be positive, got {self.tolerance_px}")
        if not -1.0 <= self.min_zncc <= 1.0:
            raise ValueError(f"min_zncc must be in [-1, 1], got {self.min_zncc}")
        if int(self.search_radius_px) < 1:
            raise ValueError(f"search_radius_px must be >= 1, got {self.search_radius_px}")
        if int(self.regions) < 1:
            raise ValueError(f"regions must be >= 1, got {self.regions}")
        if not (np.isfinite(self.lowpass_sigma_px) and self.lowpass_sigma_px >= 0):
            raise ValueError(f"lowpass_sigma_px must be >= 0, got {self.lowpass_sigma_px}")


@dataclass
class DICResult:
    """Per-point output of :func:`correlate` (arrays over the N points of interest).

    Attributes
    ----------
    x, y : ndarray of int64, shape (N,)
        Reference POI, px (column, row).
    u, v : ndarray of float64, shape (N,)
        Displacement, px (NaN unless converged).
    parameters : ndarray of float64, shape (N, 12)
        Shape-function parameters, named by :data:`PARAMETER_NAMES` (second-order terms zero for order 1).
    zncc : ndarray of float64, shape (N,)
    iterations : ndarray of int64, shape (N,)
    status : ndarray of int8, shape (N,)
        :class:`Status` codes.
    sssig : ndarray of float64, shape (N, 2)
        Sum of squared subset intensity gradients along x and y, grey^2/px^2 (Pan 2008).
    grid_index : ndarray of int64, shape (N, 2)
        (row, col) of each point in the POI grid of shape ``grid_shape``.
    grid_shape : tuple of int
    settings : DICSettings
    timings_s : dict
        Wall time of the stages, s.
    uncertainty : MatchUncertainty or None
        Per-point uncertainty, when computed (:func:`measurement.uncertainty.match.dic_uncertainty`); its columns
        (``sigma_u_px``, ``sigma_v_px``, ``residual_ratio``, ``sigma_flag``) are then written by :meth:`to_csv`.
    traversal : str
        'rows' or 'columns': the order IC-GN sampled the subsets in (:mod:`.traversal`).
    """

    x: np.ndarray
    y: np.ndarray
    u: np.ndarray
    v: np.ndarray
    parameters: np.ndarray
    zncc: np.ndarray
    iterations: np.ndarray
    status: np.ndarray
    sssig: np.ndarray
    grid_index: np.ndarray
    grid_shape: tuple
    settings: DICSettings
    timings_s: dict = field(default_factory=dict)
    uncertainty: object = field(default=None, repr=False)
    traversal: str = "rows"

    @property
    def converged(self) -> np.ndarray:
        """Boolean mask of the points with numbers."""
        return self.status == CONVERGED

    def status_counts(self) -> dict[str, int]:
        """Number of points per status name."""
        codes, counts = np.unique(self.status, return_counts=True)
        return {Status(int(c)).name: int(n) for c, n in zip(codes, counts)}

    def predicted_std_px(self, noise_sigma_grey: float) -> tuple[np.ndarray, np.ndarray]:
        """Noise-limited standard deviation of u and v per point, px: sqrt(2) sigma / sqrt(SSSIG) (Pan 2008).

        Valid for Gaussian noise of ``noise_sigma_grey`` in both images and a translation-dominated match.
        """
        with np.errstate(divide="ignore"):
            return (np.sqrt(2.0) * noise_sigma_grey / np.sqrt(self.sssig[:, 0]),
                    np.sqrt(2.0) * noise_sigma_grey / np.sqrt(self.sssig[:, 1]))

    def to_grid(self, values: np.ndarray, fill: float = np.nan) -> np.ndarray:
        """Scatter per-point ``values`` (N, ...) onto the POI grid (n_rows, n_cols, ...)."""
        values = np.asarray(values)
        out = np.full(self.grid_shape + values.shape[1:], fill, dtype=np.result_type(values, type(fill)))
        out[self.grid_index[:, 0], self.grid_index[:, 1]] = values
        return out

    def to_csv(self, path: str | Path) -> Path:
        """Write ``x,y,u,v,zncc,iterations,status,status_name`` and the shape parameters, one row per point.

        The file is written atomically (:func:`labio.atomic.atomic_writer`): whole or not at all.
        """
        path = Path(path)
        names = [Status(int(s)).name.lower() for s in self.status]
        extra = self.uncertainty.columns() if self.uncertainty is not None else {}
        with atomic_writer(path, "w", newline="") as handle:
            writer = csv.writer(handle)
            writer.writerow(["x", "y", "u", "v", "zncc", "iterations", "status", "status_name",
                             *PARAMETER_NAMES[1:6], *PARAMETER_NAMES[7:], *extra])
            for k in range(self.x.size):
                p = self.parameters[k]
                writer.writerow([int(self.x[k]), int(self.y[k]), _fmt(self.u[k]), _fmt(self.v[k]),
                                 _fmt(self.zncc[k]), int(self.iterations[k]), int(self.status[k]), names[k],
                                 *(_fmt(val) for val in p[1:6]), *(_fmt(val) for val in p[7:]),
                                 *(str(int(values[k])) if values.dtype.kind == "i" else _fmt(values[k])
                                   for values in extra.values())])
        return path


def _fmt(value: float) -> str:
    return "nan" if not np.isfinite(value) else f"{value:.9g}"


# ---------------------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class PreparedImage:
    """An image ready for DIC: finite values, B-spline coefficients, invalid-pixel mask."""

    values: np.ndarray          # float64, NaN where invalid (dilated)
    spline: bspline.BSplineImage
    invalid: np.ndarray | None  # bool (rows, cols), dilated by the interpolation support; None if all valid
    lowpass_sigma_px: float = 0.0


def prepare_image(image: np.ndarray, interpolation: str, gradients: bool, name: str,
                  lowpass_sigma_px: float = 0.0) -> PreparedImage:
    """Check an image and compute its B-spline coefficients.

    NaN/inf pixels are allowed: they are filled with the nearest valid value before the prefilter, and every
    pixel within reach of them (interpolation support plus the prefilter's decay) is marked invalid, so
    subsets touching them get the INVALID_IMAGE status. ``lowpass_sigma_px`` > 0 applies a Gaussian low-pass
    first (see :class:`DICSettings`).
    """
    array = np.asarray(image)
    if array.ndim != 2:
        raise ValueError(f"{name} image must be 2-D grey (rows, cols), got shape {array.shape}")
    if not np.issubdtype(array.dtype, np.number) or np.iscomplexobj(array):
        raise ValueError(f"{name} image must be real-valued, got dtype {array.dtype}")
    degree = bspline.degree_of(interpolation)
    if min(array.shape) < 2 * (degree + 1):
        raise ValueError(f"{name} image {array.shape} is too small")
    values = array.astype(np.float64, copy=True)
    finite = np.isfinite(values)
    if lowpass_sigma_px > 0:
        values = ndimage.gaussian_filter(np.where(finite, values, 0.0), lowpass_sigma_px, mode="nearest")
        # A NaN spreads over the filter's reach.
        finite = ~ndimage.binary_dilation(~finite, iterations=int(np.ceil(4 * lowpass_sigma_px))) \
            if not finite.all() else finite
        values[~finite] = np.nan
    # A deformed image (no gradients) is only sampled by IC-GN, which does so in single precision.
    coefficient_dtype = np.float64 if gradients else np.float32
    invalid = None
    if not finite.all():
        if not finite.any():
            raise ValueError(f"{name} image has no finite pixel")
        _, (rows, cols) = ndimage.distance_transform_edt(~finite, return_indices=True)
        filled = values[rows, cols]
        # Prefilter poles decay as 0.43^k (quintic): 8 px more brings a unit jump below 1e-3 grey.
        invalid = ndimage.binary_dilation(~finite, iterations=degree + 8)
        spline = bspline.prefilter(filled, degree, gradients=gradients, coefficient_dtype=coefficient_dtype)
        values[invalid] = np.nan
    else:
        spline = bspline.prefilter(values, degree, gradients=gradients, coefficient_dtype=coefficient_dtype)
    return PreparedImage(values, spline, invalid, float(lowpass_sigma_px))


def reference_subset_status(values: np.ndarray, xs: np.ndarray, ys: np.ndarray, half: int,
                            min_std: float) -> np.ndarray:
    """OUT_OF_IMAGE, INVALID_IMAGE, LOW_TEXTURE (grey-level std below ``min_std``) or CONVERGED (= usable) for the
    reference subsets at (xs, ys), from integral images (cheap for many points).

    The subset Hessian is not formed, so a textured subset with a singular Hessian reads usable here.
    """
    rows, cols = values.shape
    xs = np.asarray(xs, dtype=np.int64)
    ys = np.asarray(ys, dtype=np.int64)
    status = np.full(xs.size, CONVERGED, dtype=np.int64)
    outside = (xs - half < 0) | (ys - half < 0) | (xs + half >= cols) | (ys + half >= rows)
    status[outside] = int(Status.OUT_OF_IMAGE)
    inside = ~outside
    if not inside.any():
        return status
    # integral images over the bounding box of the subsets only
    bx0, by0 = int(xs[inside].min()) - half, int(ys[inside].min()) - half
    bx1, by1 = int(xs[inside].max()) + half + 1, int(ys[inside].max()) + half + 1
    window = values[by0:by1, bx0:bx1]
    finite = np.isfinite(window)
    filled = np.where(finite, window, 0.0)

    def box_sums(image):
        integral = np.zeros((image.shape[0] + 1, image.shape[1] + 1))
        integral[1:, 1:] = image.cumsum(axis=0).cumsum(axis=1)
        x0, y0 = xs[inside] - half - bx0, ys[inside] - half - by0
        x1, y1 = x0 + 2 * half + 1, y0 + 2 * half + 1
        return integral[y1, x1] - integral[y0, x1] - integral[y1, x0] + integral[y0, x0]

    n = float((2 * half + 1) ** 2)
    mean = box_sums(filled) / n
    variance = np.maximum(box_sums(filled * filled) / n - mean * mean, 0.0)
    own = np.where(np.sqrt(variance) < min_std, int(Status.LOW_TEXTURE), CONVERGED)
    own[box_sums((~finite).astype(np.float64)) > 0.5] = int(Status.INVALID_IMAGE)
    status[inside] = own
    return status


def subset_min_std(settings: DICSettings, reference_values: np.ndarray) -> float:
    """The texture threshold a match applies to its reference subsets: ``settings.min_subset_std`` or, when None,
    0.5 % of the reference's grey range (grey)."""
    if settings.min_subset_std is not None:
        return float(settings.min_subset_std)
    return _default_min_std(reference_values)


def _default_min_std(values: np.ndarray) -> float:
    # a strided subsample estimates the grey range just as well, at 1/16 of the cost
    low, high = np.nanpercentile(values[::4, ::4], [0.5, 99.5])
    return max(0.005 * float(high - low), 1e-12)


def check_seed_points(seed_points_xy, image_shape: tuple[int, int]) -> list[tuple[float, float]]:
    """The user's seed points as (x, y) floats, each finite and inside the image; ValueError naming the point."""
    if seed_points_xy is None:
        return []
    rows, cols = int(image_shape[0]), int(image_shape[1])
    points = []
    for point in seed_points_xy:
        try:
            x, y = (float(v) for v in point)
        except (TypeError, ValueError):
            raise ValueError(f"a seed point must be two numbers (x, y), got {point!r}") from None
        if not (np.isfinite(x) and np.isfinite(y)):
            raise ValueError(f"seed point ({x:g}, {y:g}) is not finite")
        if not (0 <= x <= cols - 1 and 0 <= y <= rows - 1):
            raise ValueError(f"seed point ({x:g}, {y:g}) px is outside the {cols} x {rows} px image "
                             f"(0 <= x <= {cols - 1}, 0 <= y <= {rows - 1})")
        points.append((x, y))
    return points


def _check_seed_points_reach(grid: PoiGrid, points) -> None:
    """Every seed point must lie within reach (as :func:`_seed_candidates` takes it) of a point of interest."""
    xs, ys = grid.x[grid.active], grid.y[grid.active]
    for x, y in points:
        distance = (xs - x) ** 2 + (ys - y) ** 2
        k = int(np.argmin(distance))
        if distance[k] > (grid.step ** 2) * 2:
            raise ValueError(f"seed point ({x:g}, {y:g}) px is not near any point of interest (the nearest is at "
                             f"({int(xs[k])}, {int(ys[k])}) px): put it inside the region of interest and mask")


def _seed_candidates(grid: PoiGrid, region: np.ndarray, region_id: int, seed_points_xy) -> list[tuple[int, int]]:
    """Grid nodes of a region to try as seeds: the user's points first, then outward from the region centre."""
    rows, cols = np.nonzero(grid.active & (region == region_id))
    if rows.size == 0:
        return []
    candidates = []
    for x, y in seed_points_xy or ():
        distance = (grid.x[rows, cols] - x) ** 2 + (grid.y[rows, cols] - y) ** 2
        k = int(np.argmin(distance))
        if distance[k] <= (grid.step ** 2) * 2:
            candidates.append((int(rows[k]), int(cols[k])))
    centre_r, centre_c = rows.mean(), cols.mean()
    order = np.argsort((rows - centre_r) ** 2 + (cols - centre_c) ** 2, kind="stable")
    candidates.extend((int(rows[k]), int(cols[k])) for k in order)
    return candidates


def find_seeds(reference: np.ndarray, deformed: np.ndarray, grid: PoiGrid, region: np.ndarray, n_regions: int,
               settings: DICSettings, seed_points_xy=None, seed_guess_px=(0.0, 0.0),
               tries_per_region: int = 8) -> list[tuple[int, int, Seed]]:
    """ZNCC-searched seeds: up to ``tries_per_region`` candidates per region, best-scoring first.

    Regions are searched on as many threads as numba uses (OpenCV releases the GIL); the result does not
    depend on the thread count.
    """
    half = grid.half

    def search_region(region_id: int) -> list[tuple[int, int, Seed]]:
        found = []
        for r, c in _seed_candidates(grid, region, region_id, seed_points_xy)[:tries_per_region]:
            seed = zncc_search(reference, deformed, int(grid.x[r, c]), int(grid.y[r, c]), half,
                               int(settings.search_radius_px), seed_guess_px, tuple(settings.seed_angles_deg))
            if seed is not None and np.isfinite(seed.zncc):
                found.append((r, c, seed))
        found.sort(key=lambda item: -item[2].zncc)
        return found

    workers = max(1, min(numba.get_num_threads(), n_regions))
    if workers == 1:
        per_region = [search_region(k) for k in range(n_regions)]
    else:
        with ThreadPoolExecutor(workers) as pool:
            per_region = list(pool.map(search_region, range(n_regions)))
    return [seed for found in per_region for seed in found]


def correlate(reference: np.ndarray, deformed: np.ndarray, settings: DICSettings | None = None, *,
              roi: tuple[int, int, int, int] | None = None, mask: np.ndarray | None = None,
              seed_points_xy: list[tuple[float, float]] | None = None,
              seed_guess_px: tuple[float, float] = (0.0, 0.0),
              seeds: list[Seed] | None = None,
              initial_parameters: np.ndarray | None = None,
              grid: PoiGrid | None = None,
              reference_cache: ReferenceCache | None = None,
              traversal: str = "auto") -> DICResult:
    """Subset DIC between two grey images.

    Parameters
    ----------
    reference, deformed : ndarray, shape (rows, cols)
        Grey images of the same shape (any real dtype; NaN pixels are allowed and flag the subsets touching
        them). ``reference`` may also be a :class:`PreparedImage` (``prepare_image(..., gradients=True)``) to
        correlate one reference to many images without preparing it again.
    settings : DICSettings, optional
    roi : (x0, y0, x1, y1), optional
        Rectangle of POI centres, px.
    mask : ndarray of bool, optional
        POI centres must fall where it is True.
    seed_points_xy : list of (x, y), optional
        Preferred seed positions, px (the nearest grid node is used); a ZNCC search gives their guess. A point
        that is not finite, lies outside the image or near no point of interest raises ValueError naming it.
    seed_guess_px : (u, v)
        Centre of the seed search window, px (for displacements larger than ``search_radius_px``); finite.
    seeds : list of Seed, optional
        Seeds with their own initial guesses (feature matches, epipolar search, ...); they replace the ZNCC
        search. Each must sit on a grid node.
    initial_parameters : ndarray, shape (N, 12) or (N, 2), or callable, optional
        An initial guess for *every* active POI (row-major order of the grid); no propagation then: each point
        runs IC-GN from its own guess. (N, 2) gives (u, v) only; a callable ``(x_px, y_px) -> (u_px, v_px)``
        is evaluated at the POIs.
    grid : PoiGrid, optional
        Use this grid instead of building one from ``roi``/``mask``/settings.
    reference_cache : ReferenceCache, optional
        The reference side of every node, kept between matches of the same reference
        (:class:`.reference_cache.ReferenceCache`, made with ``ReferenceCache.for_grid`` for this reference, grid
        and settings): filled where a node is first matched, read afterwards. Same results, less work per match.
        A cache made for another reference, grid or settings raises ValueError naming the difference.
    traversal : {'auto', 'rows', 'columns'}
        The order IC-GN samples a warped subset in (:mod:`.traversal`): 'columns' correlates the transposed images
        (same sums, same results to IC-GN's tolerance) and pays where the warp compresses or stretches rows (a
        stereo view's foreshortening) more than columns; 'auto' picks it from the seeds' shape parameters. The
        result's ``traversal`` says which ran. Not used with ``initial_parameters``.

    Returns
    -------
    DICResult
    """
    settings = settings or DICSettings()
    if traversal not in TRAVERSALS:
        raise ValueError(f"traversal must be one of {', '.join(TRAVERSALS)}, got {traversal!r}")
    timings = {}
    start = time.perf_counter()
    if isinstance(reference, PreparedImage):
        # A sequence correlates one reference to many images: its spline and gradients are made once.
        ref = reference
        if ref.spline.degree != bspline.degree_of(settings.interpolation) or ref.spline.grad_x is None or \
                ref.lowpass_sigma_px != settings.lowpass_sigma_px:
            raise ValueError("the prepared reference does not match the settings (interpolation, gradients, low-pass)")
        reference = ref.values
    else:
        reference = np.asarray(reference)
        ref = None
    deformed = np.asarray(deformed)
    if reference.ndim == 2 and deformed.ndim == 2 and reference.shape != deformed.shape:
        raise ValueError(f"reference image {reference.shape} and deformed image {deformed.shape} differ in size")
    if reference.ndim == 2:
        seed_points_xy = check_seed_points(seed_points_xy, reference.shape) or None
    try:
        seed_guess_px = tuple(float(v) for v in seed_guess_px)
    except (TypeError, ValueError):
        raise ValueError(f"seed_guess_px must be two numbers (u, v), got {seed_guess_px!r}") from None
    if len(seed_guess_px) != 2 or not np.all(np.isfinite(seed_guess_px)):
        raise ValueError(f"seed_guess_px must be two finite numbers (u, v) px, got {seed_guess_px!r}")
    if reference.ndim == 2 and (abs(seed_guess_px[0]) >= reference.shape[1]
                                or abs(seed_guess_px[1]) >= reference.shape[0]):
        raise ValueError(f"seed_guess_px ({seed_guess_px[0]:g}, {seed_guess_px[1]:g}) px moves the seed search outside "
                         f"the {reference.shape[1]} x {reference.shape[0]} px image")
    if ref is None:
        ref = prepare_image(reference, settings.interpolation, True, "reference", settings.lowpass_sigma_px)
    dfm = prepare_image(deformed, settings.interpolation, False, "deformed", settings.lowpass_sigma_px)
    timings["prefilter"] = time.perf_counter() - start

    if grid is None:
        grid = poi_grid(reference.shape, settings.subset_size, settings.step, roi=roi, mask=mask,
                        interpolation=settings.interpolation)
    elif grid.subset_size != settings.subset_size:
        raise ValueError(f"grid subset size {grid.subset_size} differs from settings.subset_size "
                         f"{settings.subset_size}")
    half = grid.half
    degree = ref.spline.degree
    min_std = subset_min_std(settings, ref.values)
    if reference_cache is not None:
        reference_cache.check(ref.values, grid, settings, min_std)
        cache_arrays = (True, reference_cache.info, reference_cache.hinv, reference_cache.a, reference_cache.s)
    else:
        cache_arrays = (False, np.zeros((1, 1, INFO_SIZE)), np.zeros((1, 1, 1, 1)), np.zeros((1, 1, 1)),
                        np.zeros((1, 1, 1)))
    bad = dfm.invalid if dfm.invalid is not None else np.zeros((1, 1), dtype=bool)
    check_bad = dfm.invalid is not None
    n_rows, n_cols = grid.shape
    params = np.full((n_rows, n_cols, N_PARAMETERS), np.nan)
    status = np.full((n_rows, n_cols), NOT_REACHED, dtype=np.int64)
    zncc = np.full((n_rows, n_cols), np.nan)
    iterations = np.zeros((n_rows, n_cols), dtype=np.int64)
    sssig = np.full((n_rows, n_cols, 2), np.nan)
    active_rc = np.argwhere(grid.active)

    t = time.perf_counter()
    if initial_parameters is not None:
        if callable(initial_parameters):
            u0, v0 = initial_parameters(grid.x[grid.active].astype(float), grid.y[grid.active].astype(float))
            initial_parameters = np.stack(np.broadcast_arrays(u0, v0), axis=1)
        guesses = _check_initial_parameters(initial_parameters, active_rc.shape[0])
        if settings.order == 1:
            guesses[:, SECOND_ORDER] = 0.0
        xs = grid.x[grid.active].astype(np.int64)
        ys = grid.y[grid.active].astype(np.int64)
        st = np.empty(xs.size, dtype=np.int64)
        zn = np.empty(xs.size)
        it = np.empty(xs.size, dtype=np.int64)
        ss = np.empty((xs.size, 2))
        correlate_batch(ref.values, ref.spline.grad_x, ref.spline.grad_y, dfm.spline.coefficients, degree, bad,
                        check_bad, xs, ys, half, settings.order, min_std, guesses, int(settings.max_iterations),
                        float(settings.tolerance_px), float(settings.min_zncc), st, zn, it, ss, *cache_arrays,
                        active_rc.astype(np.int64))
        r, c = active_rc[:, 0], active_rc[:, 1]
        params[r, c] = guesses
        status[r, c] = st
        zncc[r, c] = zn
        iterations[r, c] = it
        sssig[r, c] = ss
        timings["icgn"] = time.perf_counter() - t
    else:
        region = band_regions(grid.shape, settings.regions)
        n_regions = int(region.max()) + 1
        if seeds is None:
            if seed_points_xy:
                _check_seed_points_reach(grid, seed_points_xy)
            found = find_seeds(ref.values, dfm.values, grid, region, n_regions, settings, seed_points_xy,
                               seed_guess_px)
        else:
            found = [(*_node_of(grid, s), s) for s in seeds]
        timings["seeds"] = time.perf_counter() - t
        if not found:
            warnings.warn("DIC: no seed found (every candidate subset is out of the image or untextured)",
                          stacklevel=2)
            status[grid.active] = int(Status.NO_INITIAL_GUESS)
        t = time.perf_counter()
        if found:
            seed_rc = np.array([(r, c) for r, c, _ in found], dtype=np.int64)
            seed_p = np.array([s.parameters for _, _, s in found], dtype=np.float64)
            if settings.order == 1:
                seed_p[:, SECOND_ORDER] = 0.0
            traversal = choose_traversal(traversal, seed_p, half)
            outputs = (params, status, zncc, iterations, sssig)
            if traversal == "columns":
                propagate_columns(ref, dfm.spline.coefficients, degree, bad, check_bad, grid, region, n_regions,
                                  seed_rc, seed_p, settings, min_std, outputs, reference_cache)
            else:
                propagate_grid(ref.values, ref.spline.grad_x, ref.spline.grad_y, dfm.spline.coefficients, degree,
                               bad, check_bad, grid.x, grid.y, grid.active, region, n_regions, seed_rc, seed_p, half,
                               settings, min_std, *outputs, cache_arrays)
        timings["propagation"] = time.perf_counter() - t
        if found and not (status == CONVERGED).any():
            # Every seed failed in IC-GN: their guesses were not acceptable matches.
            warnings.warn(f"DIC: none of the {len(found)} seed(s) converged (images unrelated, displacement beyond "
                          f"the search radius of {settings.search_radius_px} px, or no texture in the deformed image)",
                          stacklevel=2)
            status[grid.active & (status == NOT_REACHED)] = int(Status.NO_INITIAL_GUESS)
        # Unreached nodes whose reference subset is unusable anyway (outside, flat, NaN) say why.
        unreached = np.argwhere(grid.active & ((status == NOT_REACHED) | (status == int(Status.NO_INITIAL_GUESS))))
        if unreached.size:
            r_u, c_u = unreached[:, 0], unreached[:, 1]
            if reference_cache is not None:
                own = reference_cache.subset_status(
                    lambda xs, ys: reference_subset_status(ref.values, xs, ys, half, min_std))[r_u, c_u]
            else:
                own = reference_subset_status(ref.values, grid.x[r_u, c_u], grid.y[r_u, c_u], half, min_std)
            status[r_u, c_u] = np.where(own == CONVERGED, status[r_u, c_u], own)

    r, c = active_rc[:, 0], active_rc[:, 1]
    out_status = status[r, c]
    out_params = params[r, c]
    out_params[out_status != CONVERGED] = np.nan
    out_zncc = zncc[r, c]
    timings["total"] = time.perf_counter() - start
    return DICResult(
        x=grid.x[r, c].astype(np.int64), y=grid.y[r, c].astype(np.int64),
        u=out_params[:, 0].copy(), v=out_params[:, 6].copy(), parameters=out_params, zncc=out_zncc,
        iterations=iterations[r, c], status=out_status.astype(np.int8), sssig=sssig[r, c],
        grid_index=active_rc.astype(np.int64), grid_shape=grid.shape, settings=settings, timings_s=timings,
        traversal=traversal if traversal != "auto" else "rows")


def _node_of(grid: PoiGrid, seed: Seed) -> tuple[int, int]:
    hits = np.argwhere((grid.x == seed.x) & (grid.y == seed.y) & grid.active)
    if hits.size == 0:
        raise ValueError(f"seed at ({seed.x}, {seed.y}) px is not an active node of the POI grid")
    return int(hits[0, 0]), int(hits[0, 1])


def _check_initial_parameters(initial, count: int) -> np.ndarray:
    initial = np.asarray(initial, dtype=np.float64)
    if initial.ndim != 2 or initial.shape[0] != count or initial.shape[1] not in (2, N_PARAMETERS):
        raise ValueError(f"initial_parameters must have shape ({count}, 2) or ({count}, {N_PARAMETERS}) for the "
                         f"{count} points of interest, got {initial.shape}")
    if not np.isfinite(initial).all():
        raise ValueError("initial_parameters contains NaN or infinite values")
    if initial.shape[1] == 2:
        full = np.zeros((count, N_PARAMETERS))
        full[:, 0] = initial[:, 0]
        full[:, 6] = initial[:, 1]
        return full
    return initial.copy()


__all__ = ["DICSettings", "DICResult", "correlate", "find_seeds", "prepare_image"]
