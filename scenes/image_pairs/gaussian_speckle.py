"""Analytic Gaussian speckle: exact image pairs for testing a 2-D DIC engine (the truth side, no rendering).

A sum of random Gaussian blobs (:class:`GaussianSpeckle`, built by :func:`gaussian_speckle`) that can be
evaluated exactly at any real point. A deformed image is the pattern sampled at the reference positions of the
deformed pixel grid (:meth:`GaussianSpeckle.render_deformed`), for any smooth displacement field of
:mod:`scenes.image_pairs.analytic_fields` (:class:`~scenes.image_pairs.analytic_fields.Translation`,
``HomogeneousStrain``, ``Rotation``, ``QuadraticField``), whose conventions (pixel coordinates, point sampling)
hold here. The other exact pairs, by Fourier shifting, are :mod:`scenes.image_pairs.fourier_shift`.

Sizes, density and aliasing
---------------------------
The pattern is ``I(X) = background - amplitude * sum_k exp(-|X - X_k|^2 / (2 s_k^2))`` (dark blobs on a
bright background). Centres ``X_k`` are a Poisson process; the blob *radius* follows Zhou & Goodson (2001),
``R_k = sqrt(2) s_k``, so each blob is ``exp(-r^2 / R_k^2)``. With ``density`` ``d`` the centre rate is
``lambda = -ln(1 - d) / (pi E[R^2])``: ``d`` is the fraction of the plane within ``R`` of some centre (as in
:mod:`scenes.surfaces.speckle`), and the blob sum ``S`` has mean ``L = -ln(1 - d)`` and variance ``L / 2``, so the
grey mean and standard deviation are exactly ``background - amplitude L`` and ``amplitude sqrt(L / 2)``.

Because the blobs add up (shot noise), the autocorrelation is the blob autocorrelation,
``exp(-h^2 / (4 s^2))``, independent of the density. The autocorrelation speckle size that
:func:`scenes.surfaces.speckle.speckle_size_from_pattern` measures is therefore predictable
(:func:`speckle_size_for_radius`, inverted by :func:`radius_for_speckle_size`; measured sizes on 256 x 256 px
agree within ~2 %): about ``3.35 s`` (``2.37 R``) for ``s >= 1`` px, a little more for finer blobs because of
the 1 px lag grid: ``s = 0.72`` px gives 2.5 px, ``s = 0.8`` px gives 2.75 px.

Sampling at 1 px aliases the part of the blob spectrum above 0.5 cycles/px, a fraction ``~2 erfc(pi s)`` of
the pattern's variance: 2.8e-3 at ``s = 0.72`` px (2.5 px speckles), 7.6e-4 at 0.8 px, 1.8e-5 at 1 px and
1.9e-7 at 1.2 px. Aliasing does not change the truth (the samples are exact), but it limits how well any
interpolant can reconstruct the pattern between pixels, i.e. it sets a DIC engine's interpolation bias. Even
the ideal (band-limited, Fourier) interpolant of the samples misses the pattern between pixels by an rms
of about 10 % of the grey standard deviation at ``s = 0.72`` px, 5 % at 0.8 px, 0.7 % at 1 px, 0.08 % at
1.2 px and 1e-5 at 1.5 px (measured on a periodic pattern, 128 x 96 px). Use ``s >= 1`` px (speckle size
>= 3.4 px) where that bias must be negligible, ``s >= 0.8`` px for small bias; blobs with ``s < 0.5`` px are
refused.

Blobs are binned in a uniform grid of cells at least as wide as the largest truncation radius, and each
evaluation visits only the 3 x 3 cells around the point. A blob is truncated where
``exp(-r^2 / (2 s^2)) < 1e-12``, i.e. at ``r = 7.43 s``; the neglected tails sum to about
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numba
import numpy as np
import scipy.optimize

from scenes.image_pairs.analytic_fields import (DEFAULT_TOLERANCE_PX, DisplacementField, check_n_floats,
                                                solve_reference_positions)
from scenes.surfaces.speckle import require_finite, require_positive_finite

#: Blob tails below this fraction of the blob depth are dropped.
TRUNCATION_LEVEL = 1e-12

#: Truncation radius in blob standard deviations: exp(-r^2 / (2 s^2)) = TRUNCATION_LEVEL.
TRUNCATION_SIGMAS = float(np.sqrt(-2.0 * np.log(TRUNCATION_LEVEL)))

#: Blobs narrower than this (standard deviation, px) are refused: sampled at 1 px they alias badly.
MIN_BLOB_SIGMA_PX = 0.5

#: Blob standard deviation (px) from which aliasing is small (< 1e-3 of the variance).
RECOMMENDED_MIN_BLOB_SIGMA_PX = 0.8




# ------------------------------------------------------------------------------------------------------------
# 2. Analytic Gaussian speckle
# ------------------------------------------------------------------------------------------------------------
def extent_for_shape(shape: tuple[int, int], margin_px: float = 0.0) -> tuple[float, float, float, float]:
    """Pattern extent covering an image of ``shape`` (pixel edges) plus a margin on every side.

    Parameters
    ----------
    shape : tuple of int
        ``(rows, cols)`` of the image, each >= 1.
    margin_px : float
        Extra width on each side in px (>= 0), e.g. the largest displacement the deformed image will show.

    Returns
    -------
    tuple of 4 floats
        ``(x_min, x_max, y_min, y_max)`` = ``(-0.5 - m, cols - 0.5 + m, -0.5 - m, rows - 0.5 + m)`` in px. With
        ``m = 0`` and ``periodic=True`` the pattern's period is exactly ``(cols, rows)`` px.
    """
    rows, cols = check_image_shape(shape)
    margin = require_finite(margin_px, "margin_px")
    if margin < 0:
        raise ValueError(f"margin_px must be >= 0, got {margin}")
    return (-0.5 - margin, cols - 0.5 + margin, -0.5 - margin, rows - 0.5 + margin)


def speckle_size_for_radius(mean_radius_px: float, radius_spread: float = 0.0) -> float:
    """Expected autocorrelation speckle size of a :class:`GaussianSpeckle` sampled at 1 px.

    The pattern's normalised autocovariance is ``rho(h) = E[s^2 exp(-h^2 / (4 s^2))] / E[s^2]`` over the blob
    standard deviations ``s = R / sqrt(2)`` (exact for a shot-noise process, at any density). This applies
    the estimator of :func:`scenes.surfaces.speckle.speckle_size_from_pattern` to ``rho`` at integer lags: first lag
    ``k`` with ``rho(k) <= 1/2``, linear interpolation from ``k - 1``, size ``2 h_half``. Measured sizes
    scatter around it by a few percent on 256 x 256 px.

    Parameters
    ----------
    mean_radius_px : float
        Mean blob radius ``R = sqrt(2) s`` in px (> 0).
    radius_spread : float
        Radii are uniform in ``mean_radius_px * [1 - radius_spread, 1 + radius_spread]``, ``0 <= spread < 1``.

    Returns
    -------
    float
        Speckle size in px.
    """
    sigmas, weights = _sigma_quadrature(mean_radius_px, radius_spread)
    lags = np.arange(0, int(np.ceil(2.0 * TRUNCATION_SIGMAS * sigmas.max())) + 2)
    # Each blob's autocorrelation integral is pi s^2 exp(-h^2 / (4 s^2)) (times amplitude^2).
    rho = ((weights * sigmas**2)[:, None] * np.exp(-lags[None, :] ** 2 / (4.0 * sigmas[:, None] ** 2))).sum(axis=0)
    rho /= rho[0]
    k = int(np.nonzero(rho <= 0.5)[0][0])
    return float(2.0 * (k - 1 + (rho[k - 1] - 0.5) / (rho[k - 1] - rho[k])))


def radius_for_speckle_size(speckle_size_px: float, radius_spread: float = 0.0) -> float:
    """Mean blob radius ``R`` (px) whose expected autocorrelation speckle size is ``speckle_size_px``.

    The inverse of :func:`speckle_size_for_radius`. For fixed radii: 2.5 px -> R = 1.02 px (s = 0.72 px),
    3 px -> R = 1.25 px, 4 px -> R = 1.70 px.

    Parameters
    ----------
    speckle_size_px : float
        Wanted speckle size in px; at least the size of blobs with ``s = MIN_BLOB_SIGMA_PX`` (about 1.6 px
        for fixed radii).
    radius_spread : float
        As in :func:`speckle_size_for_radius`.

    Returns
    -------
    float
        ``mean_radius_px`` for :func:`gaussian_speckle`.
    """
    size = require_positive_finite(speckle_size_px, "speckle_size_px")
    spread = _check_spread(radius_spread)
    r_min = np.sqrt(2.0) * MIN_BLOB_SIGMA_PX / (1.0 - spread)
    size_min = speckle_size_for_radius(r_min, spread)
    if size < size_min:
        raise ValueError(
            f"speckle_size_px={size} is below {size_min:.3f} px, the size of the narrowest allowed blobs "
            f"(sigma >= {MIN_BLOB_SIGMA_PX} px): finer speckles alias too much at 1 px sampling")
    r_max = r_min
    while speckle_size_for_radius(r_max, spread) < size:
        r_max *= 2.0
    return float(scipy.optimize.brentq(lambda r: speckle_size_for_radius(r, spread) - size, r_min, r_max,
                                       xtol=1e-12))


@dataclass(frozen=True, eq=False)
class GaussianSpeckle:
    """A sum of Gaussian blobs, evaluated exactly at any point.

    ``I(X) = background_grey - amplitude_grey * sum_k exp(-|X - X_k|^2 / (2 s_k^2))``, with ``X`` and the
    centres ``X_k`` as ``(x, y)`` in px (x = column, y = row). Usually built by :func:`gaussian_speckle`;
    constructing it directly (e.g. a single blob) is allowed.

    Attributes
    ----------
    centres_xy_px : ndarray, shape (n, 2)
        Blob centres ``(x, y)`` in px.
    sigmas_px : ndarray, shape (n,)
        Blob standard deviations ``s_k`` in px (> 0); the Zhou-Goodson radius is ``sqrt(2) s_k``.
    background_grey : float
        Grey level far from any blob.
    amplitude_grey : float
        Depth of an isolated blob in grey levels (negative values give bright blobs).
    extent_xy_px : tuple of 4 floats
        ``(x_min, x_max, y_min, y_max)``: the region where the pattern has uniform statistics.
        :meth:`render_reference` and :meth:`render_deformed` refuse to sample outside it (the pattern fades to
        the background there); :meth:`evaluate` evaluates anywhere.
    periodic : bool
        If True the pattern repeats with period ``(x_max - x_min, y_max - y_min)`` in x and y: coordinates
        are wrapped into the extent and blobs near its edges act across them. The centres must then lie in
        the extent.
    """

    centres_xy_px: np.ndarray
    sigmas_px: np.ndarray
    background_grey: float
    amplitude_grey: float
    extent_xy_px: tuple[float, float, float, float]
    periodic: bool = False
    _grid: tuple = field(init=False, repr=False)

    def __post_init__(self):
        centres = np.array(self.centres_xy_px, dtype=np.float64)
        if centres.ndim != 2 or centres.shape[1] != 2:
            raise ValueError(f"centres_xy_px must have shape (n, 2), got {centres.shape}")
        sigmas = np.array(self.sigmas_px, dtype=np.float64)
        if sigmas.shape != (centres.shape[0],):
            raise ValueError(f"sigmas_px must have shape ({centres.shape[0]},) to match centres_xy_px, "
                             f"got {sigmas.shape}")
        if not np.all(np.isfinite(centres)):
            raise ValueError("centres_xy_px must be finite")
        if not (np.all(np.isfinite(sigmas)) and np.all(sigmas > 0)):
            raise ValueError("sigmas_px must be finite and > 0")
        extent = _check_extent(self.extent_xy_px)
        periodic = bool(self.periodic)
        if periodic and centres.size and not (
                np.all((centres[:, 0] >= extent[0]) & (centres[:, 0] < extent[1]))
                and np.all((centres[:, 1] >= extent[2]) & (centres[:, 1] < extent[3]))):
            raise ValueError("a periodic pattern needs every centre in [x_min, x_max) x [y_min, y_max)")
        centres.setflags(write=False)
        sigmas.setflags(write=False)
        object.__setattr__(self, "centres_xy_px", centres)
        object.__setattr__(self, "sigmas_px", sigmas)
        object.__setattr__(self, "background_grey", require_finite(self.background_grey, "background_grey"))
        object.__setattr__(self, "amplitude_grey", require_finite(self.amplitude_grey, "amplitude_grey"))
        object.__setattr__(self, "extent_xy_px", extent)
        object.__setattr__(self, "periodic", periodic)
        object.__setattr__(self, "_grid", _build_grid(centres, sigmas, extent, periodic))

    @property
    def n_blobs(self) -> int:
        """Number of blobs (periodic copies not counted)."""
        return int(self.sigmas_px.size)

    @property
    def period_xy_px(self) -> tuple[float, float] | None:
        """``(x_max - x_min, y_max - y_min)`` if periodic, else None."""
        if not self.periodic:
            return None
        x_min, x_max, y_min, y_max = self.extent_xy_px
        return (x_max - x_min, y_max - y_min)

    def evaluate(self, points_xy: np.ndarray) -> np.ndarray:
        """Exact grey values at arbitrary points.

        Parameters
        ----------
        points_xy : ndarray, shape (..., 2)
            Points ``(x, y)`` in px, finite; typically (N, 2).

        Returns
        -------
        ndarray of float64, shape (...)
            ``I`` at the points, within ~1e-9 grey of the untruncated sum.
        """
        points = np.asarray(points_xy, dtype=np.float64)
        if points.ndim < 1 or points.shape[-1] != 2:
            raise ValueError(f"points_xy must have shape (..., 2), got {points.shape}")
        if not np.all(np.isfinite(points)):
            raise ValueError("points_xy must be finite")
        return self._evaluate_xy(points[..., 0], points[..., 1])

    def render_reference(self, shape: tuple[int, int]) -> np.ndarray:
        """The reference image: the pattern sampled at the pixel centres ``(x, y) = (column, row)``.

        Parameters
        ----------
        shape : tuple of int
            ``(rows, cols)``; the pixel centres must lie in the extent (always true for
            ``extent_for_shape(shape, margin)``).

        Returns
        -------
        ndarray of float64, shape (rows, cols)
        """
        rows, cols = check_image_shape(shape)
        y, x = np.mgrid[0:rows, 0:cols].astype(np.float64)
        self._require_inside(x, y, "the reference image")
        return self._evaluate_xy(x, y)

    def render_deformed(self, shape: tuple[int, int], displacement: DisplacementField, *,
                        tol_px: float = DEFAULT_TOLERANCE_PX, max_iter: int = 100) -> np.ndarray:
        """The deformed image ``g(x) = f(X)``, ``x = X + u(X)``, sampled at the pixel centres ``x``.

        For each pixel centre ``x`` the material point ``X`` is solved from ``X + u(X) = x`` by
        :func:`solve_reference_positions` (to ``tol_px``), and the pattern is evaluated there.

        Parameters
        ----------
        shape : tuple of int
            ``(rows, cols)`` of the deformed image.
        displacement : callable
            ``(X, Y) -> (U, V)``, arrays in px (e.g. :class:`Rotation`); with a ``gradient`` method it is
            inverted by Newton's method, otherwise by fixed-point iteration.
        tol_px, max_iter
            As in :func:`solve_reference_positions`.

        Returns
        -------
        ndarray of float64, shape (rows, cols)

        Raises
        ------
        ValueError
            If the inversion does not converge, or a solved ``X`` lies outside the extent of a non-periodic
            pattern (build it with a larger ``margin_px``).
        """
        rows, cols = check_image_shape(shape)
        y, x = np.mgrid[0:rows, 0:cols].astype(np.float64)
        X, Y = solve_reference_positions(x, y, displacement, tol_px=tol_px, max_iter=max_iter)
        self._require_inside(X, Y, "the deformed image's material points")
        return self._evaluate_xy(X, Y)

    # --------------------------------------------------------------------------------------------------------
    def _evaluate_xy(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        shape = np.shape(x)
        x = np.ascontiguousarray(x, dtype=np.float64).ravel()
        y = np.ascontiguousarray(y, dtype=np.float64).ravel()
        if self.periodic:
            x_min, x_max, y_min, y_max = self.extent_xy_px
            x = x_min + np.mod(x - x_min, x_max - x_min)
            y = y_min + np.mod(y - y_min, y_max - y_min)
        total = np.empty(x.size)
        _sum_blobs(x, y, *self._grid, total)
        return (self.background_grey - self.amplitude_grey * total).reshape(shape)

    def _require_inside(self, x: np.ndarray, y: np.ndarray, what: str) -> None:
        if self.periodic or x.size == 0:
            return
        x_min, x_max, y_min, y_max = self.extent_xy_px
        lo_x, hi_x, lo_y, hi_y = x.min(), x.max(), y.min(), y.max()
        if lo_x < x_min or hi_x > x_max or lo_y < y_min or hi_y > y_max:
            raise ValueError(
                f"{what} reach x in [{lo_x:.2f}, {hi_x:.2f}], y in [{lo_y:.2f}, {hi_y:.2f}] px, outside the "
                f"pattern extent x in [{x_min}, {x_max}], y in [{y_min}, {y_max}] px, where the speckle "
                f"fades to the background; build the pattern with a larger extent "
                f"(extent_for_shape(shape, margin_px=...))")


def gaussian_speckle(extent_xy_px, mean_radius_px: float, density: float = 0.5, seed: int = 0, *,
                     radius_spread: float = 0.0, mean_grey: float = 128.0, std_grey: float = 30.0,
                     periodic: bool = False) -> GaussianSpeckle:
    """Random Gaussian-blob speckle with uniform statistics over an extent.

    Blob centres are a Poisson process of rate ``lambda = -ln(1 - density) / (pi E[R^2])``; radii are uniform
    in ``mean_radius_px * [1 - radius_spread, 1 + radius_spread]``. Non-periodic patterns also get blobs in a
    border of one truncation radius around the extent, so the statistics are the same at the edge of the
    extent as in its middle. See the module notes for the speckle size (:func:`radius_for_speckle_size`) and
    aliasing (``sigma = R / sqrt(2) >= 0.8`` px keeps it small, >= 1 px negligible).

    Parameters
    ----------
    extent_xy_px : sequence of 4 floats
        ``(x_min, x_max, y_min, y_max)`` in px with ``x_min < x_max``, ``y_min < y_max``; see
        :func:`extent_for_shape`. It must contain every point an image will sample, including the material
        points of a deformed image.
    mean_radius_px : float
        Mean Zhou-Goodson blob radius ``R = sqrt(2) sigma`` in px; the smallest blob must have
        ``sigma >= MIN_BLOB_SIGMA_PX`` (0.5 px). 2.5 px speckles need ``R = 1.02`` px.
    density : float
        Fraction of the plane within ``R`` of a blob centre, ``0 < density < 1``.
    seed : int
        Seed for ``np.random.default_rng``; the same seed gives the same pattern.
    radius_spread : float
        Relative half-width of the radius distribution, ``0 <= radius_spread < 1``.
    mean_grey, std_grey : float
        Expected grey mean and standard deviation (``std_grey > 0``). The grey distribution is skewed: bright
        background ``mean + std sqrt(2 L)``, ``L = -ln(1 - density)``, with a dark tail. With the defaults
        (128, 30, density 0.5) the background is 163, ~0.7 % of pixels are below 30 and ~0.15 % below 0
        (down to about -110); values are not clipped. Clipping or any other pointwise grey-level map applied
        to both images keeps the displacement truth exact.
    periodic : bool
        Make the pattern periodic with the extent as its period (see :class:`GaussianSpeckle`).

    Returns
    -------
    GaussianSpeckle
    """
    extent = _check_extent(extent_xy_px)
    density = require_finite(density, "density")
    if not 0.0 < density < 1.0:
        raise ValueError(f"density must be in (0, 1), got {density}")
    mean_grey = require_finite(mean_grey, "mean_grey")
    std_grey = require_positive_finite(std_grey, "std_grey")
    sigmas_q, weights_q = _sigma_quadrature(mean_radius_px, radius_spread)
    mean_sigma = np.sqrt(0.5) * float(mean_radius_px)
    spread = float(radius_spread)

    mean_sigma2 = float(np.sum(weights_q * sigmas_q**2))
    coverage = -np.log1p(-density)  # L: mean of the blob sum
    rate = coverage / (2.0 * np.pi * mean_sigma2)  # = L / (pi E[R^2])
    amplitude = std_grey / np.sqrt(0.5 * coverage)
    background = mean_grey + amplitude * coverage

    x_min, x_max, y_min, y_max = extent
    if not periodic:
        border = TRUNCATION_SIGMAS * mean_sigma * (1.0 + spread)
        x_min, x_max, y_min, y_max = x_min - border, x_max + border, y_min - border, y_max + border
    width, height = x_max - x_min, y_max - y_min
    rng = np.random.default_rng(seed)
    count = rng.poisson(rate * width * height)
    centres = np.column_stack([x_min + width * rng.random(count), y_min + height * rng.random(count)])
    if periodic:
        # x_min + width * u can round up to x_max; keep centres in the half-open period box.
        centres[:, 0] = np.where(centres[:, 0] >= x_max, x_min, centres[:, 0])
        centres[:, 1] = np.where(centres[:, 1] >= y_max, y_min, centres[:, 1])
    sigmas = mean_sigma * (1.0 + spread * (2.0 * rng.random(count) - 1.0))
    return GaussianSpeckle(centres, sigmas, background, amplitude, extent, periodic)



# ------------------------------------------------------------------------------------------------------------
# Blob grid and the numba kernel
# ------------------------------------------------------------------------------------------------------------
def _build_grid(centres: np.ndarray, sigmas: np.ndarray, extent, periodic: bool) -> tuple:
    """Blobs sorted into square cells >= the largest truncation radius; periodic copies added near edges.

    Returns the kernel's arguments after ``x, y``: ``(bx, by, inv_two_var, cutoff2, cell_start, origin_x,
    origin_y, cell_px, n_cells_x, n_cells_y)``.
    """
    cutoff = TRUNCATION_SIGMAS * sigmas
    if periodic and centres.size:
        x_min, x_max, y_min, y_max = extent
        width, height = x_max - x_min, y_max - y_min
        if cutoff.max() > min(width, height):
            raise ValueError(
                f"a periodic pattern needs periods >= the blob truncation radius ({cutoff.max():.2f} px), got "
                f"{width} x {height} px: enlarge the extent or use smaller blobs")
        parts_c, parts_s = [centres], [sigmas]
        for ox in (-width, 0.0, width):
            for oy in (-height, 0.0, height):
                if ox == 0.0 and oy == 0.0:
                    continue
                moved = centres + (ox, oy)
                # Keep the copies that reach into the period box.
                near = ((moved[:, 0] > x_min - cutoff) & (moved[:, 0] < x_max + cutoff)
                        & (moved[:, 1] > y_min - cutoff) & (moved[:, 1] < y_max + cutoff))
                parts_c.append(moved[near])
                parts_s.append(sigmas[near])
        centres, sigmas = np.concatenate(parts_c), np.concatenate(parts_s)
        cutoff = TRUNCATION_SIGMAS * sigmas
    if centres.size == 0:
        empty = np.empty(0)
        return (empty, empty, empty, empty, np.zeros(2, dtype=np.int64), 0.0, 0.0, 1.0, 1, 1)
    cell_px = float(cutoff.max())
    origin_x, origin_y = float(centres[:, 0].min()), float(centres[:, 1].min())
    ix = np.floor((centres[:, 0] - origin_x) / cell_px).astype(np.int64)
    iy = np.floor((centres[:, 1] - origin_y) / cell_px).astype(np.int64)
    n_cells_x, n_cells_y = int(ix.max()) + 1, int(iy.max()) + 1
    cell = iy * n_cells_x + ix
    order = np.argsort(cell, kind="stable")
    counts = np.bincount(cell, minlength=n_cells_x * n_cells_y)
    cell_start = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
    return (np.ascontiguousarray(centres[order, 0]), np.ascontiguousarray(centres[order, 1]),
            0.5 / sigmas[order] ** 2, cutoff[order] ** 2, cell_start,
            origin_x, origin_y, cell_px, n_cells_x, n_cells_y)


@numba.njit(cache=True)
def _sum_blobs(x, y, bx, by, inv_two_var, cutoff2, cell_start, origin_x, origin_y, cell_px, n_cells_x,
               n_cells_y, out):
    """``out[i] = sum_k exp(-|p_i - b_k|^2 inv_two_var[k])`` over blobs within their cutoff of point i.

    Every blob within its cutoff of a point lies in one of the 3 x 3 cells around the point's cell, because
    cells are at least as wide as the largest cutoff.
    """
    for i in range(x.size):
        px = x[i]
        py = y[i]
        fx = (px - origin_x) / cell_px
        fy = (py - origin_y) / cell_px
        total = 0.0
        if fx > -2.0 and fx < n_cells_x + 1.0 and fy > -2.0 and fy < n_cells_y + 1.0:
            cx = int(np.floor(fx))
            cy = int(np.floor(fy))
            for gy in range(max(cy - 1, 0), min(cy + 2, n_cells_y)):
                for gx in range(max(cx - 1, 0), min(cx + 2, n_cells_x)):
                    c = gy * n_cells_x + gx
                    for k in range(cell_start[c], cell_start[c + 1]):
                        dx = px - bx[k]
                        dy = py - by[k]
                        d2 = dx * dx + dy * dy
                        if d2 < cutoff2[k]:
                            total += np.exp(-d2 * inv_two_var[k])
        out[i] = total


# ------------------------------------------------------------------------------------------------------------
# Checks
# ------------------------------------------------------------------------------------------------------------
def _sigma_quadrature(mean_radius_px, radius_spread) -> tuple[np.ndarray, np.ndarray]:
    """Blob sigmas and probability weights (Gauss-Legendre) for the uniform radius distribution; checked."""
    radius = require_positive_finite(mean_radius_px, "mean_radius_px")
    spread = _check_spread(radius_spread)
    smallest_sigma = np.sqrt(0.5) * radius * (1.0 - spread)
    if smallest_sigma < MIN_BLOB_SIGMA_PX:
        raise ValueError(
            f"mean_radius_px={radius} with radius_spread={spread} makes blobs with sigma = "
            f"{smallest_sigma:.3f} px < {MIN_BLOB_SIGMA_PX} px, which alias badly at 1 px sampling; "
            f"use mean_radius_px >= {np.sqrt(2.0) * MIN_BLOB_SIGMA_PX / (1.0 - spread):.3f}")
    if spread == 0.0:
        return np.array([np.sqrt(0.5) * radius]), np.array([1.0])
    nodes, weights = np.polynomial.legendre.leggauss(32)
    return np.sqrt(0.5) * radius * (1.0 + spread * nodes), 0.5 * weights


def _check_spread(radius_spread) -> float:
    spread = require_finite(radius_spread, "radius_spread")
    if not 0.0 <= spread < 1.0:
        raise ValueError(f"radius_spread must be in [0, 1), got {spread}")
    return spread


def check_image(image) -> np.ndarray:
    image = np.asarray(image)
    if image.ndim != 2 or min(image.shape) < 2:
        raise ValueError(f"image must be 2-D with each side >= 2, got shape {image.shape}")
    if np.iscomplexobj(image) or not (np.issubdtype(image.dtype, np.number) or image.dtype == bool):
        raise ValueError(f"image must be real-valued, got dtype {image.dtype}")
    image = image.astype(np.float64)
    n_bad = np.count_nonzero(~np.isfinite(image))
    if n_bad:
        raise ValueError(f"image has {n_bad} non-finite values")
    return image


def check_image_shape(shape, minimum: int = 1) -> tuple[int, int]:
    try:
        rows, cols = (int(n) for n in shape)
        exact = all(int(n) == n for n in shape)
    except (TypeError, ValueError):
        raise ValueError(f"shape must be two integers (rows, cols), got {shape!r}") from None
    if not exact or rows < minimum or cols < minimum:
        raise ValueError(f"shape must be two integers (rows, cols) >= {minimum}, got {shape!r}")
    return rows, cols


def _check_extent(extent) -> tuple[float, float, float, float]:
    x_min, x_max, y_min, y_max = check_n_floats(extent, 4, "extent_xy_px")
    if not (x_min < x_max and y_min < y_max):
        raise ValueError(f"extent_xy_px must be (x_min, x_max, y_min, y_max) with x_min < x_max and "
                         f"y_min < y_max, got {extent!r}")
    return (x_min, x_max, y_min, y_max)

