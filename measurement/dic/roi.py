"""Automatic region of interest for whole-image DIC: texture before correlation, consistency after.

On a real image a grid over the whole frame puts subsets on the background, on the dark void around a
specimen, on its edges and on fixtures. Many of them "converge", some with ZNCC >= 0.99, at displacements that
belong to no material point of the specimen. Two tests flag them (NaN with a :class:`.Status`, never a number):

1. :func:`texture_mask`, on the reference image, before correlation. A subset is measurable if

   - its sum of squared intensity gradients (SSSIG, Pan et al. 2008, "Study on subset size selection in digital
     image correlation for speckle patterns", Opt. Express 16(10)) less the part the noise itself contributes
     gives a predicted noise-limited precision ``sigma_u = sqrt(2) sigma / sqrt(SSSIG)`` at or below a target,
     in x and in y;
   - its texture is centred on its point: the centroid of its textured pixels (noise-corrected gradient energy
     above their share of the requirement) lies within a fraction of the half subset of the centre. A subset
     centred on the background next to a specimen has plenty of SSSIG from its specimen half and matches the
     specimen's motion perfectly; this test is what keeps that motion from being reported at a background point;
   - enough of its pixels are usable: finite, not on a clipped plateau (saturated or black), not exactly flat.

   ``sigma`` is the image noise, estimated when not given by :func:`estimate_noise_sigma` (Immerkær 1996's
   Laplacian-difference residual, read on the weakest-textured blocks).

2. :func:`consistency_flags`, on the correlated grid. The normalised median test of Westerweel & Scarano
   (2005, "Universal outlier detection for PIV data", Exp. Fluids 39) compares each point's displacement with the
   median of its eight grid neighbours, normalised by the neighbours' own scatter plus a noise level ``eps`` (the
   field's robust neighbour-difference scale, with a floor); a residual above 2 flags the point. It catches
   isolated wrong matches, not the band of subsets along a boundary between two motions: with a step smaller
   than the subset those blend smoothly from one motion to the other, which reads like a strain. The ZNCC test
   catches that band: a subset straddling two motions fits neither, and its deficit ``1 - ZNCC`` is many times
   the ``sigma^2 / var(f)`` the noise alone leaves (:func:`expected_zncc_deficit`; without an image, its
   neighbours' deficit). Both iterate until nothing new is flagged.

:func:`correlate_auto_roi` chains both around :func:`.correlate.correlate` and returns the result over the
whole grid, flagged points included.
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy import ndimage, stats

from .grid import PoiGrid, check_subset_size
from .status import CONVERGED, INCONSISTENT, LOW_TEXTURE

#: Default target of the noise-limited precision a subset must reach, px (one standard deviation).
DEFAULT_TARGET_PRECISION_PX = 0.02
#: Default largest distance of a subset's texture centroid from its centre, as a fraction of the half subset M.
DEFAULT_MAX_CENTROID_OFFSET = 1.0 / 3.0
#: Default least fraction of usable (finite, unclipped, non-flat) pixels in a subset.
DEFAULT_MIN_USABLE_FRACTION = 0.9
#: Window over which a pixel's gradient energy is averaged to call it textured, px.
TEXTURE_WINDOW_PX = 5
#: Westerweel & Scarano's threshold on the normalised median residual.
DEFAULT_MEDIAN_THRESHOLD = 2.0
#: Floor of the noise level ``eps`` of the normalised median test, px.
DEFAULT_MIN_EPSILON_PX = 0.01
#: A point whose ZNCC deficit 1 - ZNCC exceeds this many times its neighbours' median deficit is flagged.
DEFAULT_ZNCC_RATIO = 4.0
#: Deficits below this count as this (noise-free images: 1 - ZNCC ~ 1e-6 everywhere), so ZNCC >= 0.996 is never
#: flagged by the ratio alone.
DEFAULT_MIN_ZNCC_DEFICIT = 1e-3

# Immerkær's 3 x 3 operator: the outer product of [1, -2, 1] with itself; /6 gives unit gain on white noise.
_IMMERKAER = np.outer([1.0, -2.0, 1.0], [1.0, -2.0, 1.0]) / 6.0
# Sum of the squared autocorrelation of that operator's output on white noise: (1 + 2 (2/3)^2 + 2 (1/6)^2)^2.
_IMMERKAER_CORRELATION_SUM = (35.0 / 18.0) ** 2


# --- noise -----------------------------------------------------------------------------------------------

def estimate_noise_sigma(image: np.ndarray, *, block_px: int = 16, quantile: float = 0.1) -> float:
    """Standard deviation of additive white image noise, grey levels, from one image.

    Immerkær's operator (J. Immerkær, "Fast noise variance estimation", Comput. Vis. Image Underst. 64(2), 1996)
    ``N = [1 -2 1]^T [1 -2 1] / 6`` removes locally linear intensity and leaves white noise of standard deviation
    sigma. Texture leaks into it, so (in the spirit of Liu, Tanaka & Okutomi 2013, "Single-image noise level
    estimation for blind denoising", IEEE TIP 22(12)) the noise is read on the weakest-textured parts only: the
    RMS residual ``s_b`` of every ``block_px``-square block is computed, and the ``quantile`` of the block values
    is divided by that quantile of pure noise, ``sqrt(chi2.ppf(q, n) / n)``, with ``n`` the block's effective
    number of independent residuals (Satterthwaite: pixels / 3.78 for the operator's correlation).

    The estimate is unbiased when at least ``quantile`` of the blocks show no texture at the operator's scale
    (background, out-of-focus parts, smooth regions) and too high otherwise: on a frame filled with fine
    (~3 px) speckle it read 1.65 times a noise of 2 grey, 1.15 times 5 grey and 5 times 0.5 grey; with a third of
    the frame background it was within 5 % (tests/test_auto_roi.py).
    Blocks that touch a non-finite pixel or a clipped plateau (the image's minimum or maximum held by two
    neighbouring pixels) are left out, and so are exactly flat blocks (no camera pixel is noise-free: they are
    padding or synthetic background) unless fewer than 8 others remain (then a noise-free image reads 0). The
    quantisation noise (1/sqrt(12) grey for integer levels) is part of the estimate, as it is part of the noise
    DIC sees. Signal-dependent (shot) noise is estimated where the weak-texture blocks are, often the darker
    background, so it may be low for the specimen: pass the noise yourself when it is known.

    Parameters
    ----------
    image : ndarray, shape (H, W)
        Grey image, any real dtype; NaN pixels are ignored.
    block_px : int
        Side of the blocks, px (>= 4).
    quantile : float
        Fraction of blocks, the least textured, the estimate rests on; in (0, 0.5].

    Returns
    -------
    float
        Noise standard deviation, grey levels (0.0 for a constant image, or when the ``quantile`` of the blocks
        is exactly flat).

    Raises
    ------
    ValueError
        Bad arguments, or fewer than 8 usable blocks (image too small, or all NaN/clipped).
    """
    values = grey_float_image(image)
    if isinstance(block_px, bool) or int(block_px) != block_px or int(block_px) < 4:
        raise ValueError(f"block_px must be an integer >= 4, got {block_px!r}")
    block_px = int(block_px)
    if not 0.0 < float(quantile) <= 0.5:
        raise ValueError(f"quantile must be in (0, 0.5], got {quantile!r}")
    if np.nanmin(values) == np.nanmax(values):
        return 0.0
    usable = _finite_unclipped(values)
    filled = np.where(usable, values, 0.0)
    residual = ndimage.correlate(filled, _IMMERKAER, mode="nearest")
    # a residual is good where its whole 3 x 3 footprint is usable and inside the image
    good = ndimage.binary_erosion(usable, np.ones((3, 3), dtype=bool), border_value=0)
    rows, cols = (values.shape[0] - 2) // block_px, (values.shape[1] - 2) // block_px
    if rows * cols < 8:
        raise ValueError(f"the {values.shape[1]} x {values.shape[0]} px image holds {rows * cols} blocks of "
                         f"{block_px} px: at least 8 are needed to estimate the noise (smaller block_px?)")
    crop = (slice(1, 1 + rows * block_px), slice(1, 1 + cols * block_px))
    r2 = (residual[crop] ** 2).reshape(rows, block_px, cols, block_px)
    whole = good[crop].reshape(rows, block_px, cols, block_px).all(axis=(1, 3))
    s_block = np.sqrt(r2.mean(axis=(1, 3)))[whole]
    # Exactly flat blocks carry no noise: a camera pixel is never noise-free, so they are padding, masks or synthetic
    # background (Stereo-DIC Challenge Sample 3: 11 % of the frame at exactly grey 8, which read sigma = 0 and then
    # flagged every subset as inconsistent). They are left out unless nothing else is left.
    if np.count_nonzero(s_block > 0) >= 8:
        s_block = s_block[s_block > 0]
    elif s_block.size >= 8:
        return 0.0
    if s_block.size < 8:
        raise ValueError(f"only {s_block.size} blocks of {block_px} px are free of NaN and clipped pixels: "
                         "at least 8 are needed to estimate the noise")
    n_eff = block_px * block_px / _IMMERKAER_CORRELATION_SUM
    pure_noise_quantile = np.sqrt(stats.chi2.ppf(float(quantile), n_eff) / n_eff)
    return float(np.quantile(s_block, float(quantile)) / pure_noise_quantile)


def noise_floor_grey(image: np.ndarray) -> float:
    """The least noise an image is credited with, grey levels: 8-bit quantisation of its range, ``q / sqrt(12)``.

    ``q`` is 1 grey level for integer images, and the 0.5-99.5 percentile range / 255 for float images, so an
    estimate of zero on a noise-free synthetic image does not make every faint gradient "measurable".
    """
    values = np.asarray(image)
    if np.issubdtype(values.dtype, np.integer):
        return 1.0 / np.sqrt(12.0)
    finite = values[np.isfinite(values)]
    if finite.size == 0:
        return 0.0
    low, high = np.percentile(finite[:: max(1, finite.size // 250_000)], [0.5, 99.5])
    return float(max(high - low, 0.0)) / 255.0 / np.sqrt(12.0)


# --- texture ---------------------------------------------------------------------------------------------

def texture_mask(image: np.ndarray, subset_size: int, *, noise_sigma_grey: float | None = None,
                 target_precision_px: float = DEFAULT_TARGET_PRECISION_PX,
                 max_centroid_offset: float = DEFAULT_MAX_CENTROID_OFFSET,
                 min_usable_fraction: float = DEFAULT_MIN_USABLE_FRACTION) -> np.ndarray:
    """Pixels whose subset has enough texture, centred on them, to be measured (see the module notes).

    With central-difference gradients ``g`` (px^-1 grey) and ``n = subset_size^2`` pixels, a subset passes when

    - ``SSSIG_x - n sigma^2 / 2 >= 2 sigma^2 / p^2`` and the same in y (``sigma_u <= p``, Pan 2008; white noise
      of sigma gives each central difference a variance of ``sigma^2 / 2``, which is removed: noise "texture"
      differs between the two images and does not help the match);
    - the centroid of its textured pixels lies within ``max_centroid_offset * M`` of the centre
      (``M = subset_size // 2``). A pixel is textured when its noise-corrected gradient energy ``|g|^2 - sigma^2``
      (white noise adds ``sigma^2``), averaged over ``TEXTURE_WINDOW_PX`` square, is at least its share
      ``2 sigma^2 / (p^2 n)`` of what the subset needs: a subset whose texture lies to one side measures the
      motion of that side, not of its centre. (The area, not the energy, is used: a few dark speckles or a
      bright edge would pull an energy centroid about.);
    - at least ``min_usable_fraction`` of its pixels are finite, off clipped plateaus and not exactly flat;
    - it lies inside the image.

    Parameters
    ----------
    image : ndarray, shape (H, W)
        Reference grey image, any real dtype; NaN pixels are unusable.
    subset_size : int
        Odd subset width 2M + 1, px.
    noise_sigma_grey : float, optional
        Image noise, grey levels. None: :func:`estimate_noise_sigma`. Either way at least
        :func:`noise_floor_grey`.
    target_precision_px : float
        Largest acceptable noise-limited standard deviation of u and v, px (> 0).
    max_centroid_offset : float
        Largest texture-centroid distance from the centre, in units of M; in (0, 1].
    min_usable_fraction : float
        Least fraction of usable pixels; in [0, 1].

    Returns
    -------
    ndarray of bool, shape (H, W)
        True where a subset centred on the pixel may be measured.
    """
    values = grey_float_image(image)
    subset_size = check_subset_size(subset_size)
    sigma = _noise_for(image, values, noise_sigma_grey)
    if not (np.isfinite(target_precision_px) and target_precision_px > 0):
        raise ValueError(f"target_precision_px must be a finite number > 0, got {target_precision_px!r}")
    if not (np.isfinite(max_centroid_offset) and 0 < max_centroid_offset <= 1):
        raise ValueError(f"max_centroid_offset must be in (0, 1], got {max_centroid_offset!r}")
    if not (np.isfinite(min_usable_fraction) and 0 <= min_usable_fraction <= 1):
        raise ValueError(f"min_usable_fraction must be in [0, 1], got {min_usable_fraction!r}")
    rows, cols = values.shape
    half = subset_size // 2
    ok = np.zeros((rows, cols), dtype=bool)
    if rows < subset_size or cols < subset_size:
        return ok
    usable = _finite_unclipped(values)
    gy, gx = np.gradient(np.where(np.isfinite(values), values, 0.0))
    usable &= (gx != 0) | (gy != 0)
    gx = np.where(usable, gx, 0.0)
    gy = np.where(usable, gy, 0.0)
    n = float(subset_size * subset_size)
    sssig_x = _box_sum(gx * gx, subset_size) - n * sigma ** 2 / 2.0
    sssig_y = _box_sum(gy * gy, subset_size) - n * sigma ** 2 / 2.0
    needed = 2.0 * sigma ** 2 / target_precision_px ** 2
    ok = (sssig_x >= needed) & (sssig_y >= needed) & (sssig_x > 0) & (sssig_y > 0)
    ok &= _box_sum(usable.astype(np.float64), subset_size) >= min_usable_fraction * n - 1e-9
    energy = ndimage.uniform_filter(gx * gx + gy * gy - sigma ** 2, size=TEXTURE_WINDOW_PX, mode="nearest")
    textured = usable & (energy >= needed / n)
    ok &= _centroid_offset(textured.astype(np.float64), subset_size) <= max_centroid_offset * half
    border = np.zeros_like(ok)
    border[half:rows - half, half:cols - half] = True
    return ok & border


def _noise_for(image, values: np.ndarray, noise_sigma_grey) -> float:
    if noise_sigma_grey is None:
        sigma = estimate_noise_sigma(values)
    else:
        sigma = float(noise_sigma_grey)
        if not (np.isfinite(sigma) and sigma >= 0):
            raise ValueError(f"noise_sigma_grey must be a finite number >= 0, got {noise_sigma_grey!r}")
    return max(sigma, noise_floor_grey(image))


def _centroid_offset(weight: np.ndarray, subset_size: int) -> np.ndarray:
    """Distance of the ``weight`` centroid over the subset from its centre, px (inf where the weight sum <= 0)."""
    rows, cols = weight.shape
    y, x = np.mgrid[0:rows, 0:cols].astype(np.float64)
    total = _box_sum(weight, subset_size)
    with np.errstate(divide="ignore", invalid="ignore"):
        dx = (_box_sum(weight * x, subset_size) - x * total) / total
        dy = (_box_sum(weight * y, subset_size) - y * total) / total
    return np.where(total > 0, np.hypot(dx, dy), np.inf)


def _box_sum(values: np.ndarray, size: int) -> np.ndarray:
    """Sum over the ``size``-square window centred on each pixel (windows leaving the image are meaningless)."""
    return ndimage.uniform_filter(values, size=size, mode="constant") * float(size * size)


def _finite_unclipped(values: np.ndarray) -> np.ndarray:
    """Finite pixels that are not on a clipped plateau (the image's min or max shared with a 4-neighbour)."""
    finite = np.isfinite(values)
    if not finite.any():
        return finite
    usable = finite.copy()
    for level in (np.nanmin(values), np.nanmax(values)):
        at = finite & (values == level)
        pair = np.zeros_like(at)
        pair[:, 1:] |= at[:, 1:] & at[:, :-1]
        pair[:, :-1] |= at[:, :-1] & at[:, 1:]
        pair[1:, :] |= at[1:, :] & at[:-1, :]
        pair[:-1, :] |= at[:-1, :] & at[1:, :]
        usable &= ~pair
    return usable


def grey_float_image(image) -> np.ndarray:
    """A 2-D real image as float64 (NaN kept); refused with a ValueError if not 2-D, not real, or without a finite
    pixel."""
    values = np.asarray(image)
    if values.ndim != 2:
        raise ValueError(f"image must be 2-D grey (rows, cols), got shape {values.shape}")
    if not np.issubdtype(values.dtype, np.number) or np.iscomplexobj(values):
        raise ValueError(f"image must be real-valued, got dtype {values.dtype}")
    values = values.astype(np.float64)
    if not np.isfinite(values).any():
        raise ValueError("image has no finite pixel")
    return values


# --- consistency -----------------------------------------------------------------------------------------

@dataclass(frozen=True)
class ConsistencyFlags:
    """Outcome of :func:`consistency_flags` (arrays over the N points).

    Attributes
    ----------
    flagged : ndarray of bool, shape (N,)
        True for the points to flag INCONSISTENT.
    reason : ndarray of str, shape (N,)
        '' (kept or not tested), 'displacement' (normalised median test), 'zncc' (ZNCC deficit) or 'isolated'
        (fewer than ``min_neighbours`` measured neighbours, so it cannot be checked).
    residual : ndarray of float64, shape (N,)
        Largest normalised median residual of u and v, 1, at the last round that tested the point (for a flagged
        point the round that flagged it; NaN where never tested).
    epsilon_px : float
        Noise level ``eps`` of the normalised median test, px.
    """

    flagged: np.ndarray
    reason: np.ndarray
    residual: np.ndarray
    epsilon_px: float

    def counts(self) -> dict[str, int]:
        """Flagged points per reason."""
        names, counts = np.unique(self.reason[self.flagged], return_counts=True)
        return {str(k): int(v) for k, v in zip(names, counts)}


def consistency_flags(grid_index: np.ndarray, grid_shape: tuple[int, int], u: np.ndarray, v: np.ndarray,
                      zncc: np.ndarray | None = None, *, threshold: float = DEFAULT_MEDIAN_THRESHOLD,
                      epsilon_px: float | None = None, min_epsilon_px: float = DEFAULT_MIN_EPSILON_PX,
                      zncc_ratio: float | None = DEFAULT_ZNCC_RATIO,
                      min_zncc_deficit: float = DEFAULT_MIN_ZNCC_DEFICIT,
                      expected_zncc_deficit: np.ndarray | None = None, min_neighbours: int = 3,
                      max_iterations: int = 5) -> ConsistencyFlags:
    """Flag grid points whose displacement or ZNCC disagrees with their eight neighbours.

    For a point with measured 3 x 3 neighbours ``u_i`` (Westerweel & Scarano 2005): ``u_m = median(u_i)``,
    ``r_m = median(|u_i - u_m|)`` and the normalised residual ``r = |u_0 - u_m| / (r_m + eps)``; the point is
    flagged 'displacement' when ``r > threshold`` for u or for v. ``eps`` is the noise level: unless given,
    ``max(min_epsilon_px, 1.4826 median |u_0 - u_m|)`` over every tested point and both components (the field's
    robust neighbour-difference scale). With ``zncc`` and ``zncc_ratio`` a point is flagged 'zncc' when
    ``1 - ZNCC_0 > zncc_ratio * max(D, min_zncc_deficit)``, ``D`` being ``expected_zncc_deficit`` when given (the
    noise's share, :func:`expected_zncc_deficit`: a subset straddling two motions fits neither and its deficit
    is many times that; scaled by the median over the tested points of ``(1 - ZNCC) / D`` where that exceeds 1, so a
    noise estimate that is too low does not flag the whole specimen) and else its neighbours' median deficit
    ``median(1 - ZNCC_i)``. Flagged points leave the
    neighbourhoods and the tests repeat until no new point is flagged (at most ``max_iterations`` times). Points
    with fewer than ``min_neighbours`` measured neighbours at the start are flagged 'isolated'; a point that
    loses neighbours to later flags is left as it is.

    Parameters
    ----------
    grid_index : ndarray of int, shape (N, 2)
        (row, col) of each point in the grid (:attr:`.DICResult.grid_index`).
    grid_shape : (n_rows, n_cols)
        Grid shape, at least 3 x 3.
    u, v : ndarray, shape (N,)
        Displacements, px; NaN for points not measured (they are neither tested nor used).
    zncc : ndarray, shape (N,), optional
        ZNCC of each point.
    threshold : float
        Normalised-residual threshold (> 0; 2 in Westerweel & Scarano).
    epsilon_px : float, optional
        Noise level of the test, px (> 0). None: from the field, see above.
    min_epsilon_px : float
        Floor of the field's noise level, px (>= 0).
    zncc_ratio : float or None
        ZNCC-deficit ratio (> 1); None switches the ZNCC test off.
    min_zncc_deficit : float
        Floor of the reference deficit ``D`` (>= 0).
    expected_zncc_deficit : ndarray, shape (N,), optional
        Deficit ``1 - ZNCC`` each point would have from the image noise alone; NaN counts as 0 (the floor).
    min_neighbours : int
        Least number of measured neighbours (1-8).
    max_iterations : int
        Most rounds of testing (>= 1).

    Returns
    -------
    ConsistencyFlags
    """
    rows_cols, shape, u, v, zncc = _check_consistency_inputs(grid_index, grid_shape, u, v, zncc)
    _check_consistency_options(threshold, epsilon_px, min_epsilon_px, zncc_ratio, min_zncc_deficit,
                               min_neighbours, max_iterations)
    r, c = rows_cols[:, 0], rows_cols[:, 1]
    measured = np.isfinite(u) & np.isfinite(v)
    u_grid, v_grid = _scatter(u, r, c, shape, measured), _scatter(v, r, c, shape, measured)
    deficit = None if zncc is None or zncc_ratio is None else \
        _scatter(1.0 - zncc, r, c, shape, measured & np.isfinite(zncc))
    expected = None
    if expected_zncc_deficit is not None:
        expected = np.asarray(expected_zncc_deficit, dtype=np.float64)
        if expected.shape != u.shape:
            raise ValueError(f"expected_zncc_deficit must have shape {u.shape} like u, got {expected.shape}")
        expected = np.where(np.isfinite(expected), expected, 0.0)
    n_neighbours = np.sum(np.isfinite(_neighbours(u_grid)), axis=0)[r, c]
    reason = np.full(u.size, "", dtype=object)
    isolated = measured & (n_neighbours < int(min_neighbours))
    reason[isolated] = "isolated"
    alive = measured & ~isolated
    residual = np.full(u.size, np.nan)
    eps = epsilon_px
    for _ in range(int(max_iterations)):
        keep = _scatter(np.ones(u.size), r, c, shape, alive) == 1
        dev_u, spread_u, count = _median_stats(np.where(keep, u_grid, np.nan))
        dev_v, spread_v, _ = _median_stats(np.where(keep, v_grid, np.nan))
        tdev_u, tspread_u, _ = _median_stats(np.where(keep, u_grid, np.nan), detrend=True)
        tdev_v, tspread_v, _ = _median_stats(np.where(keep, v_grid, np.nan), detrend=True)
        tested = alive & (count[r, c] >= int(min_neighbours))
        if eps is None:
            deviations = np.concatenate([dev_u[r, c][tested], dev_v[r, c][tested]])
            eps = max(float(min_epsilon_px), 1.4826 * float(np.median(deviations)) if deviations.size else 0.0)
        # flagged only if the point disagrees with its neighbours' median both as they are and carried along the
        # local gradient (:func:`_median_stats`): the first alone peels the edges of a region with a gradient, the
        # second alone misjudges nodes next to a motion discontinuity, whose gradient estimate crosses it
        norm = np.fmin(np.fmax(dev_u / (spread_u + eps), dev_v / (spread_v + eps)),
                       np.fmax(tdev_u / (tspread_u + eps), tdev_v / (tspread_v + eps)))[r, c]
        residual = np.where(tested, norm, residual)
        new = tested & (norm > threshold)
        reason[new] = "displacement"
        if deficit is not None:
            if expected is not None:
                # The noise estimate may be low (a near-flat synthetic background, signal-dependent noise): the
                # median point, on the specimen, then shows a deficit of several times the expected one. Scaling by
                # that median (never below 1) keeps the test relative to how well the specimen itself matches.
                ratio = deficit[r, c] / np.where(expected > 0, expected, np.nan)
                usable = tested & np.isfinite(ratio)
                scale = max(1.0, float(np.median(ratio[usable]))) if usable.any() else 1.0
                reference = expected * scale
            else:
                reference = _nanmedian(_neighbours(np.where(keep, deficit, np.nan)))[r, c]
            bad_zncc = tested & ~new & (deficit[r, c] > zncc_ratio * np.fmax(reference, min_zncc_deficit))
            reason[bad_zncc] = "zncc"
            new |= bad_zncc
        if not new.any():
            break
        alive &= ~new
    flagged = reason != ""
    return ConsistencyFlags(flagged, reason.astype(str), residual, float(eps))


def _local_gradient(grid_values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per node, the field's change per grid step along rows and columns, from differences between its neighbours
    only (the node itself is left out, so an outlier does not bend its own prediction): the median of the three
    central differences across it and the four one-sided differences between neighbours beside it. 0 where none."""
    p = np.pad(grid_values, 2, constant_values=np.nan)
    n_rows, n_cols = grid_values.shape

    def at(dr, dc):
        return p[2 + dr:2 + dr + n_rows, 2 + dc:2 + dc + n_cols]

    along_cols = np.stack([(at(dr, 1) - at(dr, -1)) / 2.0 for dr in (-1, 0, 1)]
                          + [at(dr, 1) - at(dr, 0) for dr in (-1, 1)] + [at(dr, 0) - at(dr, -1) for dr in (-1, 1)])
    along_rows = np.stack([(at(1, dc) - at(-1, dc)) / 2.0 for dc in (-1, 0, 1)]
                          + [at(1, dc) - at(0, dc) for dc in (-1, 1)] + [at(0, dc) - at(-1, dc) for dc in (-1, 1)])
    return np.nan_to_num(_nanmedian(along_rows)), np.nan_to_num(_nanmedian(along_cols))


def _median_stats(grid_values: np.ndarray, detrend: bool = False):
    """Per node: ``|u_0 - u_m|``, ``r_m`` and the number of measured neighbours of its 3 x 3 neighbourhood.

    ``detrend``: the neighbours are first carried to the node along the local gradient (:func:`_local_gradient`).
    Without that,
    a node on the edge of the measured region, whose neighbours all lie on one side, differs from their median by
    one step of the field's gradient while their spread is nearly 0: on the Stereo-DIC Challenge's Sample 3
    (left-to-right disparity, step 50 px) the plain median test flagged the outer column, and iterating peeled five
    columns of good points on either side of the specimen."""
    neighbours = _neighbours(grid_values)
    if detrend:
        g_rows, g_cols = _local_gradient(grid_values)
        offsets = [(dr, dc) for dr in (-1, 0, 1) for dc in (-1, 0, 1) if (dr, dc) != (0, 0)]
        neighbours = neighbours - np.stack([dr * g_rows + dc * g_cols for dr, dc in offsets])
    count = np.sum(np.isfinite(neighbours), axis=0)
    median = _nanmedian(neighbours)
    spread = _nanmedian(np.abs(neighbours - median[None]))
    return np.abs(grid_values - median), spread, count


def _neighbours(grid_values: np.ndarray) -> np.ndarray:
    """The eight 3 x 3 neighbours of every node, shape (8, n_rows, n_cols), NaN off the grid."""
    padded = np.pad(grid_values, 1, constant_values=np.nan)
    n_rows, n_cols = grid_values.shape
    return np.stack([padded[1 + dr:1 + dr + n_rows, 1 + dc:1 + dc + n_cols]
                     for dr in (-1, 0, 1) for dc in (-1, 0, 1) if (dr, dc) != (0, 0)])


def _nanmedian(stack: np.ndarray) -> np.ndarray:
    """Median over axis 0 ignoring NaN; NaN where all are NaN (without numpy's warning)."""
    out = np.full(stack.shape[1:], np.nan)
    some = np.isfinite(stack).any(axis=0)
    out[some] = np.nanmedian(stack[:, some], axis=0)
    return out


def _scatter(values: np.ndarray, r: np.ndarray, c: np.ndarray, shape, where: np.ndarray) -> np.ndarray:
    grid = np.full(shape, np.nan)
    grid[r[where], c[where]] = values[where]
    return grid


def _check_consistency_inputs(grid_index, grid_shape, u, v, zncc):
    try:
        shape = (int(grid_shape[0]), int(grid_shape[1]))
    except (TypeError, ValueError, IndexError):
        raise ValueError(f"grid_shape must be (n_rows, n_cols), got {grid_shape!r}") from None
    if shape[0] < 3 or shape[1] < 3:
        raise ValueError(f"the consistency test needs a grid of at least 3 x 3 points, got {shape[0]} x {shape[1]}")
    rows_cols = np.asarray(grid_index)
    if rows_cols.ndim != 2 or rows_cols.shape[1] != 2 or not np.issubdtype(rows_cols.dtype, np.integer):
        raise ValueError(f"grid_index must be integer (N, 2) (row, col), got {rows_cols.dtype} {rows_cols.shape}")
    if rows_cols.size and (rows_cols.min(axis=0) < 0).any() or \
            rows_cols.size and (rows_cols.max(axis=0) >= np.array(shape)).any():
        raise ValueError(f"grid_index has nodes outside the {shape[0]} x {shape[1]} grid")
    arrays = []
    for name, array in (("u", u), ("v", v), ("zncc", zncc)):
        if array is None:
            arrays.append(None)
            continue
        array = np.asarray(array, dtype=np.float64)
        if array.shape != (rows_cols.shape[0],):
            raise ValueError(f"{name} must have shape ({rows_cols.shape[0]},) like grid_index, got {array.shape}")
        arrays.append(array)
    return rows_cols.astype(np.int64), shape, *arrays


def _check_consistency_options(threshold, epsilon_px, min_epsilon_px, zncc_ratio, min_zncc_deficit,
                               min_neighbours, max_iterations) -> None:
    if not (np.isfinite(threshold) and threshold > 0):
        raise ValueError(f"threshold must be a finite number > 0, got {threshold!r}")
    if epsilon_px is not None and not (np.isfinite(epsilon_px) and epsilon_px > 0):
        raise ValueError(f"epsilon_px must be a finite number > 0 (or None), got {epsilon_px!r}")
    if not (np.isfinite(min_epsilon_px) and min_epsilon_px >= 0):
        raise ValueError(f"min_epsilon_px must be a finite number >= 0, got {min_epsilon_px!r}")
    if zncc_ratio is not None and not (np.isfinite(zncc_ratio) and zncc_ratio > 1):
        raise ValueError(f"zncc_ratio must be a finite number > 1 (or None), got {zncc_ratio!r}")
    if not (np.isfinite(min_zncc_deficit) and min_zncc_deficit >= 0):
        raise ValueError(f"min_zncc_deficit must be a finite number >= 0, got {min_zncc_deficit!r}")
    if isinstance(min_neighbours, bool) or int(min_neighbours) != min_neighbours or not 1 <= min_neighbours <= 8:
        raise ValueError(f"min_neighbours must be an integer in 1..8, got {min_neighbours!r}")
    if isinstance(max_iterations, bool) or int(max_iterations) != max_iterations or max_iterations < 1:
        raise ValueError(f"max_iterations must be an integer >= 1, got {max_iterations!r}")


# --- the two tests around a DIC run ----------------------------------------------------------------------

@dataclass(frozen=True)
class AutoRoi:
    """Settings of the automatic ROI (the defaults are the module's ``DEFAULT_*`` constants).

    Attributes
    ----------
    noise_sigma_grey : float or None
        Image noise, grey levels; None estimates it from the reference image (:func:`estimate_noise_sigma`).
    target_precision_px, max_centroid_offset, min_usable_fraction : float
        :func:`texture_mask` options.
    threshold, min_epsilon_px : float
        :func:`consistency_flags` normalised median test options.
    zncc_ratio : float or None
        :func:`consistency_flags` ZNCC test option (None: off).
    """

    noise_sigma_grey: float | None = None
    target_precision_px: float = DEFAULT_TARGET_PRECISION_PX
    max_centroid_offset: float = DEFAULT_MAX_CENTROID_OFFSET
    min_usable_fraction: float = DEFAULT_MIN_USABLE_FRACTION
    threshold: float = DEFAULT_MEDIAN_THRESHOLD
    min_epsilon_px: float = DEFAULT_MIN_EPSILON_PX
    zncc_ratio: float | None = DEFAULT_ZNCC_RATIO

    def __post_init__(self):
        if self.noise_sigma_grey is not None and not (np.isfinite(self.noise_sigma_grey)
                                                      and self.noise_sigma_grey >= 0):
            raise ValueError(f"noise_sigma_grey must be a finite number >= 0 (or None), got {self.noise_sigma_grey!r}")
        if not (np.isfinite(self.target_precision_px) and self.target_precision_px > 0):
            raise ValueError(f"target_precision_px must be a finite number > 0, got {self.target_precision_px!r}")
        if not (np.isfinite(self.max_centroid_offset) and 0 < self.max_centroid_offset <= 1):
            raise ValueError(f"max_centroid_offset must be in (0, 1], got {self.max_centroid_offset!r}")
        if not (np.isfinite(self.min_usable_fraction) and 0 <= self.min_usable_fraction <= 1):
            raise ValueError(f"min_usable_fraction must be in [0, 1], got {self.min_usable_fraction!r}")
        _check_consistency_options(self.threshold, None, self.min_epsilon_px, self.zncc_ratio,
                                   DEFAULT_MIN_ZNCC_DEFICIT, 3, 1)


@dataclass(frozen=True)
class AutoRoiReport:
    """What the automatic ROI flagged.

    Attributes
    ----------
    points : int
        Points of interest of the whole grid.
    low_texture : int
        Points flagged LOW_TEXTURE by :func:`texture_mask` (not correlated).
    inconsistent : int
        Points flagged INCONSISTENT by :func:`consistency_flags` (in any of the matches, for a stereo state).
    noise_sigma_grey : float
        Noise the texture test used (given or estimated, at least the floor), grey levels.
    reasons : dict
        INCONSISTENT points per reason ('displacement', 'zncc', 'isolated'), summed over the matches checked (a
        stereo state's point flagged in both of its matches counts twice here).
    """

    points: int
    low_texture: int
    inconsistent: int
    noise_sigma_grey: float
    reasons: dict

    @property
    def flagged(self) -> int:
        return self.low_texture + self.inconsistent

    def summary(self) -> str:
        """One line: ``auto ROI: 1234 of 5000 points flagged: 1100 low texture, 134 inconsistent (...)``."""
        why = ", ".join(f"{k} {n}" for k, n in sorted(self.reasons.items()))
        return (f"auto ROI: {self.flagged} of {self.points} points flagged: {self.low_texture} low texture, "
                f"{self.inconsistent} inconsistent" + (f" ({why})" if why else "")
                + f"; noise {self.noise_sigma_grey:.3g} grey")


def texture_grid(reference: np.ndarray, grid: PoiGrid, auto_roi: AutoRoi | None = None) -> tuple[PoiGrid, float]:
    """The nodes of ``grid`` whose reference subset passes :func:`texture_mask`, and the noise it used.

    Returns
    -------
    PoiGrid
        Same layout as ``grid``, ``active`` reduced to the textured nodes.
    float
        Noise standard deviation used, grey levels.
    """
    auto_roi = auto_roi or AutoRoi()
    values = grey_float_image(reference)
    sigma = _noise_for(reference, values, auto_roi.noise_sigma_grey)
    mask = texture_mask(values, grid.subset_size, noise_sigma_grey=sigma,
                        target_precision_px=auto_roi.target_precision_px,
                        max_centroid_offset=auto_roi.max_centroid_offset,
                        min_usable_fraction=auto_roi.min_usable_fraction)
    return replace(grid, active=grid.active & mask[grid.y, grid.x]), sigma


def expand_result(result, grid: PoiGrid, status: int = LOW_TEXTURE):
    """A :class:`.DICResult` over a sub-grid of ``grid`` (same layout) spread over every active node of ``grid``.

    Nodes of ``grid`` the result lacks get ``status`` and NaN numbers. The points come in the row-major order of
    ``grid.active``, as :func:`.correlate.correlate` would return them for ``grid``.
    """
    from .correlate import DICResult

    if tuple(result.grid_shape) != tuple(grid.shape):
        raise ValueError(f"the result's grid {tuple(result.grid_shape)} is not the layout {grid.shape} to expand to")
    where = np.full(grid.shape, -1, dtype=np.int64)
    where[result.grid_index[:, 0], result.grid_index[:, 1]] = np.arange(result.x.size)
    if (where >= 0)[~grid.active].any():
        raise ValueError("the result has points that are not active nodes of the grid to expand to")
    rc = np.argwhere(grid.active)
    k = where[rc[:, 0], rc[:, 1]]
    have = k >= 0

    def spread(values, fill):
        out = np.full((rc.shape[0],) + values.shape[1:], fill, dtype=values.dtype)
        out[have] = values[k[have]]
        return out

    return DICResult(
        x=grid.x[rc[:, 0], rc[:, 1]].astype(np.int64), y=grid.y[rc[:, 0], rc[:, 1]].astype(np.int64),
        u=spread(result.u, np.nan), v=spread(result.v, np.nan), parameters=spread(result.parameters, np.nan),
        zncc=spread(result.zncc, np.nan), iterations=spread(result.iterations, 0),
        status=spread(result.status, status), sssig=spread(result.sssig, np.nan), grid_index=rc.astype(np.int64),
        grid_shape=grid.shape, settings=result.settings, timings_s=dict(result.timings_s))


def expected_zncc_deficit(reference: np.ndarray, x: np.ndarray, y: np.ndarray, subset_size: int,
                          noise_sigma_grey: float) -> np.ndarray:
    """``1 - ZNCC`` that white noise alone leaves at a perfect match: ``sigma^2 / var(f)`` over each subset.

    A reference subset ``f = s + n1`` and its perfectly matched deformed subset ``g = s + n2`` (independent noise
    of ``sigma`` each) have ``ZNCC = var(s) / (var(s) + sigma^2) = 1 - sigma^2 / var(f)``.

    Parameters
    ----------
    reference : ndarray, shape (H, W)
        Reference grey image.
    x, y : ndarray of int, shape (N,)
        Subset centres, px (column, row), whole subsets inside the image.
    subset_size : int
        Odd subset width, px.
    noise_sigma_grey : float
        Noise standard deviation of each image, grey levels.

    Returns
    -------
    ndarray of float64, shape (N,)
        Expected deficit, 1 (inf for a flat subset).
    """
    values = grey_float_image(reference)
    subset_size = check_subset_size(subset_size)
    x, y = np.asarray(x, dtype=np.int64), np.asarray(y, dtype=np.int64)
    finite = np.isfinite(values)
    filled = np.where(finite, values, 0.0)
    count = _box_sum(finite.astype(np.float64), subset_size)[y, x]
    with np.errstate(divide="ignore", invalid="ignore"):
        mean = _box_sum(filled, subset_size)[y, x] / count
        variance = _box_sum(filled * filled, subset_size)[y, x] / count - mean * mean
        return np.where(variance > 0, float(noise_sigma_grey) ** 2 / variance, np.inf)


def flag_inconsistent(result, auto_roi: AutoRoi | None = None, reference: np.ndarray | None = None,
                      noise_sigma_grey: float | None = None):
    """``result`` with its converged points that fail :func:`consistency_flags` set INCONSISTENT (NaN numbers).

    With the ``reference`` image and its ``noise_sigma_grey`` the ZNCC test compares each deficit with the
    noise's share (:func:`expected_zncc_deficit`), else with the neighbours' deficits.

    Returns
    -------
    DICResult
        A copy; ``result`` is left as it is.
    ConsistencyFlags
    """
    auto_roi = auto_roi or AutoRoi()
    converged = result.status == CONVERGED
    u = np.where(converged, result.u, np.nan)
    v = np.where(converged, result.v, np.nan)
    expected = None
    if reference is not None and noise_sigma_grey is not None:
        expected = np.full(result.x.size, np.nan)
        expected[converged] = expected_zncc_deficit(reference, result.x[converged], result.y[converged],
                                                    result.settings.subset_size, noise_sigma_grey)
    flags = consistency_flags(result.grid_index, result.grid_shape, u, v, result.zncc,
                              threshold=auto_roi.threshold, min_epsilon_px=auto_roi.min_epsilon_px,
                              zncc_ratio=auto_roi.zncc_ratio, expected_zncc_deficit=expected)
    bad = flags.flagged & converged
    status = result.status.copy()
    status[bad] = INCONSISTENT
    parameters = result.parameters.copy()
    parameters[bad] = np.nan
    return replace(result, u=np.where(bad, np.nan, result.u), v=np.where(bad, np.nan, result.v),
                   parameters=parameters, status=status), flags


def correlate_auto_roi(reference, deformed, settings=None, *, grid: PoiGrid | None = None, roi=None, mask=None,
                       auto_roi: AutoRoi | None = None, **correlate_options):
    """:func:`.correlate.correlate` over the textured nodes only, then the consistency test; every node reported.

    Parameters
    ----------
    reference, deformed : ndarray, shape (H, W)
        Grey images (``reference`` may be a :class:`.correlate.PreparedImage`).
    settings : DICSettings, optional
    grid : PoiGrid, optional
        The whole grid; None builds it from ``roi``, ``mask`` and the settings (:func:`.grid.poi_grid`).
    auto_roi : AutoRoi, optional
    **correlate_options
        Passed on (seed points, seed guess, seeds, a callable ``initial_parameters``).

    Returns
    -------
    DICResult
        Over every active node of ``grid``: LOW_TEXTURE where :func:`texture_mask` fails, INCONSISTENT where
        :func:`consistency_flags` does, the correlation's own status elsewhere.
    AutoRoiReport

    Raises
    ------
    ValueError
        When no node of the grid has enough texture (and the correlation's own errors).
    """
    from .correlate import DICSettings, PreparedImage, correlate
    from .grid import poi_grid

    settings = settings or DICSettings()
    auto_roi = auto_roi or AutoRoi()
    values = reference.values if isinstance(reference, PreparedImage) else np.asarray(reference)
    if grid is None:
        grid = poi_grid(values.shape, settings.subset_size, settings.step, roi=roi, mask=mask,
                        interpolation=settings.interpolation)
    textured, sigma = texture_grid(values, grid, auto_roi)
    if not textured.active.any():
        raise ValueError(f"auto ROI: none of the {grid.count} points of interest has enough texture (noise "
                         f"{sigma:.3g} grey, target precision {auto_roi.target_precision_px:g} px, subset "
                         f"{grid.subset_size} px): a larger subset or a finer speckle pattern is needed")
    result = expand_result(correlate(reference, deformed, settings, grid=textured, **correlate_options), grid)
    result, flags = flag_inconsistent(result, auto_roi, values, sigma)
    report = AutoRoiReport(grid.count, int(np.count_nonzero(grid.active & ~textured.active)),
                           int(np.count_nonzero(result.status == INCONSISTENT)), sigma, flags.counts())
    return result, report


__all__ = ["AutoRoi", "AutoRoiReport", "ConsistencyFlags", "consistency_flags", "correlate_auto_roi",
           "estimate_noise_sigma", "expand_result", "expected_zncc_deficit", "flag_inconsistent", "noise_floor_grey",
           "texture_grid", "texture_mask"]
