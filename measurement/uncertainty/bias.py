"""Interpolation bias of subset DIC on sub-pixel translations, predicted from the reference image.

IC-GN (:mod:`measurement.dic.icgn`) samples the deformed image through a B-spline interpolant. Between the
pixels the interpolant is not the band-limited image, so a noise-free, exactly translated pair is matched with a
systematic error that depends on the sub-pixel part ``t`` of the displacement and on the subset's intensity
spectrum (Schreier, Braasch & Sutton 2000, "Systematic errors in digital image correlation caused by intensity
interpolation", Opt. Eng. 39(11):2915). This module predicts that error, to first order in the interpolation
error, for the estimator the engine runs (ZNSSD, reference-side Jacobian, first- or second-order shapes).

Transfer function (sign convention)
-----------------------------------
For the samples ``s[n] = exp(i w n)`` (``w = 2 pi f``, ``f`` in cycles/px) the cardinal B-spline interpolant of
degree ``p`` evaluated at ``x = n - t`` is ``H(f, t) s[n]`` with

    H(f, t) = sum_k beta_p(t - k) exp(-i w k) / sum_k beta_p(k) exp(-i w k),

i.e. ``H`` is the frequency response, in the DFT convention ``X(w) = sum_n x[n] exp(-i w n)``, of resampling that
moves the content by ``+t``; the ideal (band-limited) response is ``exp(-i w t)``. ``H(f, 0) = 1``,
``H(f, -t) = conj H(f, t)``, ``H(f, t + 1) = exp(-i w) H(f, t)``.

Derivation (translation along x; v is the same along y)
-------------------------------------------------------
Let ``f`` be the reference (samples of a band-limited function), ``g(x) = f(x - t)`` the deformed image and
``g^`` its spline interpolant. IC-GN stops where the ZNSSD gradient vanishes,
``sum_W J [(f - f_m) - (Df / Dg)(g^(W(x; p)) - g_m)] = 0``, with ``J = [f^_x, f^_y] (x) [1, dx, dy, ...]`` built
from the reference *interpolant's* gradient at the pixel centres. Write the deformed samples at the true
position as ``g^(n + t) = f(n) + e_t(n)``, where ``e_t`` is the interpolation error: in the Fourier domain a
component ``a exp(i w n)`` of ``f`` becomes ``a exp(i w n) X(w, t)`` with ``X(w, t) = exp(-i w t) conj H(f, t)``,
so ``e_t = F^-1[(X - 1) F[f]]`` along x. Linearising in ``e_t`` and in the error ``dp`` of the parameters
(``Df / Dg = 1 - rho``, ``rho = <f~, e~> / <f~, f~>``, ``~`` = minus the subset mean) gives

    dp(t) = -(J^T J')^-1 J^T (e~_t - rho f~),                                              (1)

``J'`` being the Jacobian with the deformed interpolant's gradient at the true position. It is ``J`` up to
the interpolation error, so ``J^T J'`` is taken as the engine's Hessian ``J^T J`` with its (u, u) entry
rescaled by the spectral ratio ``sum P D Im dX/dt / sum P D^2`` (worth ~4 % on a 2.5 px speckle, bicubic;
< 1 % otherwise). For a periodic subset with power spectrum ``P`` the window terms (``rho``, means,
the shape-function moments) vanish and (1) reduces to Schreier's weighted phase error,

    du(t) = -sum P(w) D(w_x) Im X(w_x, t) / sum P(w) D(w_x) Im dX/dt(w_x, t),                  (2)

``i D(w)`` being the response of the interpolant's pixel-centre gradient (``D ~ w`` at low frequency) and
``dX/dt`` that of the deformed interpolant's gradient at ``n + t`` (``~ i w``). :func:`translation_bias_px`
evaluates (2) (the mean bias of a pattern); :func:`bias_curves_px` evaluates (1) per point from the
reference image and :func:`bias_bound_px` takes its largest magnitude over ``t``.

The window terms of (1) do not vanish on a real subset: they add a per-point error that is even in
``t - 1/2`` (it does not vanish at ``t = 1/2``), 10-25 % of the curve (rms) on 2.5-4 px speckles and ~75 % on
8 px speckles (33 px subsets). So only the mean curve is antisymmetric about 1/2; a point's largest bias over
``[0, 1/2]`` is up to 2x smaller than over the whole period, which :data:`DEFAULT_SHIFTS_PX` covers.

Accuracy (noise-free Fourier-shifted speckle against :func:`measurement.dic.correlate`, subsets at least
16 px from the image border): per point, rms(predicted - measured) / rms(measured) is 0.2-5 % for 33 px
subsets and <= 2 % for 65 px; for 21 px subsets <= 1.5 % on 2.5-4 px speckles but ~14 % on 8 px speckles (the
subset holds ~2.5 speckles; the exact fixed point of the ZNSSD equations, solved in double precision, agrees
with the engine to 5e-8 px there, so it is the first-order expansion itself that falls short). Order-2 runs
likewise: 1-5 %. Not modelled: within ~12 px of the image border the engine's spline has mirror boundaries
that the exact translate does not have (there the prediction can be off by as much as the bias itself on
smooth speckles).
"""
from __future__ import annotations

from math import comb, factorial

import numba
import numpy as np
import scipy.fft

from measurement.dic import bspline

#: Sub-pixel shifts of :func:`bias_bound_px`, px: every 0.05 px over a whole period (a point's bias is not
#: antisymmetric about 0.5 px, see the module notes), 0 and 1 excluded (no bias there).
DEFAULT_SHIFTS_PX = np.round(np.arange(1, 20) * 0.05, 10)

#: Largest relative error, per frequency, of the low-rank expansion of the error filters over the shifts.
_BASIS_TOLERANCE = 1e-3

#: Pixels of image kept around the subsets for the spline prefilter and the Fourier filters (64 px changes a
#: prediction by < 1 % against 250 px).
_CONTEXT_PX = 64


# ---------------------------------------------------------------------------------------------------------
# Transfer functions
# ---------------------------------------------------------------------------------------------------------

def _bspline(degree: int, x: np.ndarray) -> np.ndarray:
    """Centred B-spline of ``degree`` at ``x`` (truncated-power form, exact for the small degrees used)."""
    x = np.asarray(x, dtype=np.float64)
    half = (degree + 1) / 2.0
    out = np.zeros_like(x)
    for j in range(degree + 2):
        out += (-1) ** j * comb(degree + 1, j) * np.maximum(x + half - j, 0.0) ** degree
    out /= factorial(degree)
    out[np.abs(x) >= half] = 0.0   # the truncated powers cancel there only up to round-off
    return out


def _bspline_derivative(degree: int, x: np.ndarray) -> np.ndarray:
    """d beta_p / dx = beta_{p-1}(x + 1/2) - beta_{p-1}(x - 1/2)."""
    return _bspline(degree - 1, np.asarray(x) + 0.5) - _bspline(degree - 1, np.asarray(x) - 0.5)


def interpolant_transfer(degree, frequency_cycles_per_px, shift_px, *, derivative: bool = False) -> np.ndarray:
    """Transfer function of the cardinal B-spline interpolant at a fractional shift.

    ``H(f, t) = sum_k beta(t - k) exp(-i w k) / sum_k beta(k) exp(-i w k)``, ``w = 2 pi f``: the interpolant of
    the samples ``exp(i w n)`` evaluated at ``n - t`` is ``H exp(i w n)`` (content moved by ``+t``); the ideal,
    band-limited response is ``exp(-i w t)`` (module notes).

    Parameters
    ----------
    degree : {3, 5, 'bicubic', 'biquintic'}
        Spline degree.
    frequency_cycles_per_px : array_like
        Frequency ``f``, cycles/px (any real; the useful range is ``|f| <= 0.5``).
    shift_px : array_like
        Shift ``t``, px (any real), broadcast against ``frequency_cycles_per_px``.
    derivative : bool
        Return ``dH/dt`` (per px) instead of ``H``: the response of minus the interpolant's gradient at
        ``n - t``.

    Returns
    -------
    ndarray of complex128, broadcast shape of the inputs
    """
    degree = bspline.degree_of(degree)
    f, t = np.broadcast_arrays(np.asarray(frequency_cycles_per_px, dtype=np.float64),
                               np.asarray(shift_px, dtype=np.float64))
    if not (np.isfinite(f).all() and np.isfinite(t).all()):
        raise ValueError("frequency_cycles_per_px and shift_px must be finite")
    w = 2.0 * np.pi * f
    # beta(t - k) is non-zero for |t - k| < (p + 1) / 2: k = floor(t) - p//2 - 1 ... floor(t) + p//2 + 1.
    base = np.floor(t)
    reach = degree // 2 + 1
    kernel = _bspline_derivative if derivative else _bspline
    numerator = np.zeros(f.shape, dtype=np.complex128)
    for offset in range(-reach, reach + 1):
        k = base + offset
        numerator += kernel(degree, t - k) * np.exp(-1j * w * k)
    k = np.arange(-reach, reach + 1)
    denominator = (_bspline(degree, k.astype(float)) * np.cos(np.multiply.outer(w, k))).sum(axis=-1)
    return numerator / denominator


def _sampled_response(degree: int, frequency: np.ndarray, shift: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """What IC-GN's sampling of the exact translate does to a component ``exp(i w n)`` of the reference.

    Returns ``X(f, t)``, the deformed interpolant at ``n + t`` (1 if it were exact), and ``dX/dt`` (its gradient
    there, ``~ i w``), shape ``broadcast(frequency, shift)``.
    """
    w = 2.0 * np.pi * frequency
    delay = np.exp(-1j * w * shift)
    value = delay * np.conj(interpolant_transfer(degree, frequency, shift))
    slope = delay * np.conj(interpolant_transfer(degree, frequency, shift, derivative=True))
    return value, slope


def _gradient_response(degree: int, frequency: np.ndarray) -> np.ndarray:
    """``D(f)``: the interpolant's gradient at the pixel centres responds ``i D(f)`` to ``exp(i w n)``."""
    return np.imag(np.conj(interpolant_transfer(degree, frequency, 0.0, derivative=True)))


def _check_shifts(shifts_px) -> np.ndarray:
    shifts = np.atleast_1d(np.asarray(shifts_px, dtype=np.float64))
    if shifts.ndim != 1 or shifts.size == 0 or not np.isfinite(shifts).all():
        raise ValueError(f"shifts_px must be a non-empty 1-D sequence of finite numbers, got {shifts_px!r}")
    return shifts


# ---------------------------------------------------------------------------------------------------------
# Spectral (periodic-subset) prediction: equation (2)
# ---------------------------------------------------------------------------------------------------------

def translation_bias_px(grey_or_spectrum, shifts_px, interpolation="biquintic", *,
                        spectrum: bool = False) -> np.ndarray:
    """Mean interpolation bias of u and v of a translation, from a power spectrum (equation 2).

    Given grey levels, the spectrum is the periodogram of the Hann-tapered region (the edges of an untapered
    one leak power ~1/f^2 into the high frequencies, where the interpolation error is largest). This is the
    bias that subsets of that spectrum have *on average*; a single subset's window terms (equation 1) are not
    in it (:func:`bias_curves_px` has them).

    The spectrum estimate limits the accuracy: the taper's main lobe (~2 / n cycles/px for an n px region)
    smooths the spectrum towards higher frequencies, where the phase error grows steeply (~f^(p+2)), so a small
    region over-predicts the bias of a smooth speckle. Measured against IC-GN (33 px subsets, noise-free
    Fourier-shifted speckle): the spectrum of the ~220 px region the subsets cover predicts the mean curve
    within 2-6 % of its peak for 2.5-8 px speckles; the 33 px subsets' own, averaged, within 2-14 % for
    2.5-4 px, but 31 % (bicubic) and 58 % (biquintic) too high for 8 px. Give a large region (or its
    spectrum) for the mean curve; :func:`bias_curves_px` for a point's own.

    Parameters
    ----------
    grey_or_spectrum : array_like, shape (..., rows, cols)
        Grey levels of a subset or region (or a stack of them), rows, cols >= 4; or, with ``spectrum=True``,
        power spectra ``|F|^2`` in ``numpy.fft.fft2`` layout (any normalisation). Finite.
    shifts_px : array_like, shape (T,)
        Sub-pixel translations ``t``, px.
    interpolation : {'biquintic', 'bicubic'} or {5, 3}
    spectrum : bool
        The input is a power spectrum, not grey levels.

    Returns
    -------
    ndarray of float64, shape (..., T, 2)
        Bias of u for a translation ``(t, 0)`` (``[..., 0]``) and of v for ``(0, t)`` (``[..., 1]``), px: the
        estimate minus ``t``. NaN where the input has no texture.
    """
    degree = bspline.degree_of(interpolation)
    shifts = _check_shifts(shifts_px)
    data = np.asarray(grey_or_spectrum, dtype=np.float64)
    if data.ndim < 2 or min(data.shape[-2:]) < 4:
        raise ValueError(f"grey_or_spectrum must be (..., rows, cols) with rows, cols >= 4, got shape {data.shape}")
    if not np.isfinite(data).all():
        raise ValueError("grey_or_spectrum contains NaN or infinite values")
    rows, cols = data.shape[-2:]
    if spectrum:
        if (data < 0).any():
            raise ValueError("a power spectrum cannot be negative")
        power = data
    else:
        taper = np.outer(np.hanning(rows + 2)[1:-1], np.hanning(cols + 2)[1:-1])
        # The tapered mean would leak into the lowest bins; they carry no bias weight, but remove it anyway.
        mean = (data * taper).sum(axis=(-2, -1), keepdims=True) / taper.sum()
        power = np.abs(scipy.fft.fft2((data - mean) * taper, workers=-1)) ** 2
    out = np.empty(data.shape[:-2] + (shifts.size, 2))
    for component, summed_axis, n in ((0, -2, cols), (1, -1, rows)):
        marginal = power.sum(axis=summed_axis)             # (..., n): power per frequency along the shift
        frequency = scipy.fft.fftfreq(n)
        value, slope = _sampled_response(degree, frequency[:, None], shifts[None, :])      # (n, T)
        weight = _gradient_response(degree, frequency)[:, None]
        with np.errstate(invalid="ignore", divide="ignore"):
            out[..., component] = -(marginal @ (weight * value.imag)) / (marginal @ (weight * slope.imag))
    return out


# ---------------------------------------------------------------------------------------------------------
# Per-point prediction: equation (1)
# ---------------------------------------------------------------------------------------------------------

def _powers(degree: int) -> np.ndarray:
    """Exponents (a, b) of the monomials dx^a dy^b of total degree <= ``degree``, by degree: (K, 2) int64.
    The first 3 (degree 1) or 6 (degree 2) are the shape function's, in IC-GN's parameter order."""
    return np.array([(d - b, b) for d in range(degree + 1) for b in range(d + 1)], dtype=np.int64)


@numba.njit(cache=True, parallel=True)
def _row_prefix(first, second, degree, prefix):
    """prefix[i, j, a] = sum_{j' < j} first[i, j'] second[i, j'] u^a (``second`` None: 1), u = j' - (cols - 1) / 2
    (about the centre: smaller raw moments, less cancellation when they are re-centred on a point)."""
    rows, cols = first.shape
    centre = (cols - 1) / 2.0
    for i in numba.prange(rows):
        acc = np.zeros(degree + 1)
        for a in range(degree + 1):
            prefix[i, 0, a] = 0.0
        for j in range(cols):
            u = j - centre
            term = first[i, j]
            if second is not None:
                term *= second[i, j]
            for a in range(degree + 1):
                acc[a] += term
                prefix[i, j + 1, a] = acc[a]
                term *= u


@numba.njit(cache=True, parallel=True)
def _gather_moments(prefix, xs, ys, half, powers, out):
    """out[k, q] = sum over point k's subset of product dx^a dy^b, (a, b) = powers[q], from :func:`_row_prefix`.

    Per subset row the raw sums about the image centre are re-centred on the point (binomial expansion), then
    weighted by dy^b: ~(2M + 1) D^2 operations per point instead of (2M + 1)^2.
    """
    degree = prefix.shape[2] - 1
    cols = prefix.shape[1] - 1
    centre = (cols - 1) / 2.0
    n_powers = powers.shape[0]
    binomial = np.zeros((degree + 1, degree + 1))
    for a in range(degree + 1):
        binomial[a, 0] = 1.0
        for i in range(1, a + 1):
            binomial[a, i] = binomial[a - 1, i - 1] + (binomial[a - 1, i] if i < a else 0.0)
    for k in numba.prange(xs.shape[0]):
        lo = xs[k] - half
        hi = xs[k] + half + 1
        shift = centre - xs[k]          # dx = u + shift
        centred = np.empty(degree + 1)
        shift_powers = np.empty(degree + 1)
        dy_powers = np.empty(degree + 1)
        acc = np.zeros(n_powers)
        shift_powers[0] = 1.0
        dy_powers[0] = 1.0
        for a in range(1, degree + 1):
            shift_powers[a] = shift_powers[a - 1] * shift
        for r in range(-half, half + 1):
            i = ys[k] + r
            # sum P dx^a = sum_b C(a, b) shift^(a - b) sum P u^b
            for a in range(degree + 1):
                total = 0.0
                for b in range(a + 1):
                    total += binomial[a, b] * shift_powers[a - b] * (prefix[i, hi, b] - prefix[i, lo, b])
                centred[a] = total
            for a in range(1, degree + 1):
                dy_powers[a] = dy_powers[a - 1] * r
            for q in range(n_powers):
                acc[q] += centred[powers[q, 0]] * dy_powers[powers[q, 1]]
        for q in range(n_powers):
            out[k, q] = acc[q]


class _Windows:
    """Subset sums of images times ``dx^a dy^b`` at a fixed set of points (prefix buffers reused)."""

    def __init__(self, shape, xs, ys, half):
        self.shape, self.xs, self.ys, self.half = shape, xs, ys, half
        self.buffer = np.empty(0)

    def __call__(self, powers, first, second=None):
        """(N, K) sums of ``first * second`` times the monomials ``powers`` (K, 2) over each subset."""
        degree = int(powers.sum(axis=1).max())
        shape = (self.shape[0], self.shape[1] + 1, degree + 1)
        if self.buffer.size < np.prod(shape):
            self.buffer = np.empty(int(np.prod(shape)))
        prefix = self.buffer[:np.prod(shape)].reshape(shape)      # contiguous, whatever the degree
        _row_prefix(first, second, degree, prefix)
        out = np.empty((self.xs.size, powers.shape[0]))
        _gather_moments(prefix, self.xs, self.ys, self.half, powers, out)
        return out


def _low_rank(response: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Expansion ``response[:, t] = basis @ coefficients[:, t]`` of a family of real filters over the shifts.

    Each shift would need its own filtered image; the family is smooth in ``t``, so a few filters (SVD, relative
    error per frequency below :data:`_BASIS_TOLERANCE`) serve any number of shifts.

    Parameters
    ----------
    response : ndarray of complex128, shape (K, T)
        Frequency responses (rfft bins) for T shifts.

    Returns
    -------
    basis : ndarray of complex128, shape (K, r)
    coefficients : ndarray of float64, shape (r, T)
    """
    # Relative accuracy per frequency (the low frequencies, where a smooth speckle's power is, have tiny
    # errors), but not below 1e-9 of the largest: there the response is round-off (~1e-14) and weighs nothing.
    scale = np.abs(response).max(axis=1)
    scale = np.maximum(scale, 1e-9 * scale.max() + 1e-300)
    stacked = np.vstack([response.real / scale[:, None], response.imag / scale[:, None]])
    # Right singular vectors from the T x T Gram matrix (T is small; LAPACK's SVD of the tall matrix was
    # ~50x slower beside numba's spinning threads). Projecting onto the leading ones is the truncated SVD.
    _, vectors = np.linalg.eigh(stacked.T @ stacked)
    right = vectors[:, ::-1].T                                   # (T, T), leading first
    rank = right.shape[0]
    for r in range(1, right.shape[0]):
        if np.abs((stacked @ right[:r].T) @ right[:r] - stacked).max() < _BASIS_TOLERANCE:
            rank = r
            break
    left = stacked @ right[:rank].T                              # (2K, r): basis times singular values
    k = response.shape[0]
    basis = (left[:k] + 1j * left[k:]) * scale[:, None]
    return basis, right[:rank]


def _odd_rfft(image: np.ndarray) -> np.ndarray:
    """rfft along axis 1 of a smooth periodic extension of the rows, less the line through each row's ends.

    Each row minus the line through its end samples is extended oddly (period ``2 (cols - 1)``), which keeps
    the value and the slope continuous: a plain mirror has a kink at each end whose near-Nyquist content the
    error filters (``1/k`` tails) carry tens of pixels inwards, 1e-5 px of false bias on an 8 px speckle. The
    line needs no filtering: the spline and the exact translate agree on it.

    Single precision: twice as fast, and its round-off (~1e-7 of the grey levels, at random from pixel to
    pixel) averages out over a subset: 3e-4 of the smallest bias tested (8 px speckle, biquintic).

    Returns
    -------
    ndarray of complex64, shape (rows, cols)
        Spectrum over the period ``2 (cols - 1)``.
    """
    cols = image.shape[1]
    slope = (image[:, -1:] - image[:, :1]) / (cols - 1)
    detrended = image - image[:, :1] - slope * np.arange(cols)[None, :]
    extended = np.concatenate([detrended, -detrended[:, -2:0:-1]], axis=1).astype(np.float32)
    return scipy.fft.rfft(extended, axis=1, workers=-1, overwrite_x=True)


def _solve_first_row(hessian: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """First row of the inverse of each (N, n, n) matrix, and which were invertible (Jacobi-scaled 1-norm
    condition number below 1e10; the entries span many decades), NaN rows elsewhere."""
    diagonal = np.abs(np.einsum("nii->ni", hessian))
    good = np.isfinite(hessian).all(axis=(1, 2)) & (diagonal > 0).all(axis=1)
    rows = np.full(hessian.shape[:2], np.nan)
    index = np.flatnonzero(good)
    scale = np.sqrt(diagonal[index])
    scaled = hessian[index] / (scale[:, :, None] * scale[:, None, :])
    inverse = np.full_like(scaled, np.nan)
    for k in range(0, index.size, 4096):
        try:
            inverse[k:k + 4096] = np.linalg.inv(scaled[k:k + 4096])
        except np.linalg.LinAlgError:          # one exactly singular matrix fails the batch: go one by one
            for j in range(k, min(k + 4096, index.size)):
                try:
                    inverse[j] = np.linalg.inv(scaled[j])
                except np.linalg.LinAlgError:
                    pass
    with np.errstate(invalid="ignore"):
        condition = np.abs(scaled).sum(axis=1).max(axis=1) * np.abs(inverse).sum(axis=1).max(axis=1)
    well = condition < 1e10
    # H = S A S  =>  H^-1 = S^-1 A^-1 S^-1
    rows[index[well]] = inverse[well, 0, :] / (scale[well, :1] * scale[well])
    good[:] = False
    good[index[well]] = True
    return rows, good


def _curves_along_x(f, grad_x, grad_y, xs, ys, half, degree, order, shifts):
    """Equation (1) for translations along x (columns): du(t) per point, shape (N, T); NaN where singular."""
    cols = f.shape[1]
    nm = 3 if order == 1 else 6
    count = float((2 * half + 1) ** 2)
    spectrum = _odd_rfft(f)
    length = 2 * (cols - 1)
    frequency = scipy.fft.rfftfreq(length)

    def filtered(response):
        product = spectrum * response.astype(np.complex64)
        return np.ascontiguousarray(scipy.fft.irfft(product, length, axis=1, workers=-1, overwrite_x=True)[:, :cols])

    powers = _powers(2 * order)
    shape_powers = powers[:nm]
    windows = _Windows(f.shape, xs, ys, half)
    # H = sum J J^T, J = [grad_x m, grad_y m]: the engine's Hessian, and J^T J' of equation (1) to zeroth order.
    where = {tuple(p): q for q, p in enumerate(powers)}
    pair = np.array([[where[(powers[a, 0] + powers[b, 0], powers[a, 1] + powers[b, 1])] for b in range(nm)]
                     for a in range(nm)])
    hessian = np.empty((xs.size, 2 * nm, 2 * nm))
    for ci, gi in enumerate((grad_x, grad_y)):
        for cj, gj in enumerate((grad_x, grad_y)):
            if cj >= ci:           # symmetric
                block = windows(powers, gi, gj)[:, pair]
                hessian[:, ci * nm:(ci + 1) * nm, cj * nm:(cj + 1) * nm] = block
                hessian[:, cj * nm:(cj + 1) * nm, ci * nm:(ci + 1) * nm] = np.swapaxes(block, 1, 2)
    sum_j = np.hstack([windows(shape_powers, grad_x), windows(shape_powers, grad_y)])
    sum_jf = np.hstack([windows(shape_powers, grad_x, f), windows(shape_powers, grad_y, f)])
    constant = powers[:1]
    mean_f = windows(constant, f)[:, 0] / count
    energy = windows(constant, f, f)[:, 0] - count * mean_f ** 2             # sum f~^2
    sum_jf_tilde = sum_jf - mean_f[:, None] * sum_j                         # sum J f~
    weights, good = _solve_first_row(hessian)                              # row 0 of H^-1
    good &= energy > 0
    out = np.full((xs.size, shifts.size), np.nan)
    if not good.any():
        return out
    energy = np.where(good, energy, 1.0)

    gradient = _gradient_response(degree, frequency)
    value, value_slope = _sampled_response(degree, frequency[:, None], shifts[None, :])
    error, error_slope = value - 1.0, value_slope - 1j * gradient[:, None]
    error[-1] = error[-1].real
    error_basis, error_coefficients = _low_rank(error)
    # du = -w . J^T (e~ - rho f~): per error filter, the subset sums of grad e m, e and f e.
    numerator = np.zeros((xs.size, shifts.size))
    for m in range(error_basis.shape[1]):
        e = filtered(error_basis[:, m])               # a row's line has no interpolation error
        sum_je = np.hstack([windows(shape_powers, grad_x, e), windows(shape_powers, grad_y, e)])
        mean_e = windows(constant, e)[:, 0] / count
        rho = (windows(constant, f, e)[:, 0] - count * mean_f * mean_e) / energy
        rhs = sum_je - mean_e[:, None] * sum_j - rho[:, None] * sum_jf_tilde   # J^T (e~ - rho f~)
        numerator += np.einsum("ni,ni->n", weights, rhs)[:, None] * error_coefficients[m]
    # First order in J' - J, kept because it is cheap and worth ~4 % on a 2.5 px speckle (bicubic): the
    # deformed interpolant's gradient at n + t is not the reference's at n; that changes the (u, u) entry of
    # J^T J' by a factor that hardly varies from point to point, so it comes from the whole crop's spectrum.
    power = (np.abs(spectrum.astype(np.complex128)) ** 2).sum(axis=0)
    uu_change = (power * gradient) @ error_slope.imag / ((power * gradient) @ gradient)             # (T,)
    out[good] = -numerator[good] / (1.0 + uu_change)
    return out


def _fast_window(lo: int, hi: int, size: int) -> tuple[int, int]:
    """Widen ``[lo, hi)`` within ``[0, size)`` so that ``2 (width - 1)`` is a fast FFT length (the odd
    extension's period); unchanged when the image is too narrow for that."""
    width = hi - lo
    target = scipy.fft.next_fast_len(width - 1, real=True) + 1
    if target <= size:
        grow = target - width
        hi = min(size, hi + grow)
        lo = hi - target
        return lo, hi
    return lo, hi   # the whole image is narrower than the fast length: take it as it is


def _check_points(reference_image, x_px, y_px, subset_size):
    image = np.asarray(reference_image)
    if image.ndim != 2:
        raise ValueError(f"reference_image must be 2-D (rows, cols), got shape {image.shape}")
    if not np.isfinite(image).all():
        raise ValueError("reference_image contains NaN or infinite values")
    if isinstance(subset_size, bool) or int(subset_size) != subset_size or subset_size < 5 or subset_size % 2 == 0:
        raise ValueError(f"subset_size must be an odd integer >= 5, got {subset_size!r}")
    x = np.atleast_1d(np.asarray(x_px, dtype=np.float64))
    y = np.atleast_1d(np.asarray(y_px, dtype=np.float64))
    if x.shape != y.shape or x.ndim != 1:
        raise ValueError(f"x_px and y_px must be 1-D of the same length, got shapes {x.shape} and {y.shape}")
    if not (np.isfinite(x).all() and np.isfinite(y).all()) or (x != np.round(x)).any() or (y != np.round(y)).any():
        raise ValueError("x_px and y_px must be finite integers (subset centres on pixel centres)")
    return image, x.astype(np.int64), y.astype(np.int64), int(subset_size)


def bias_curves_px(reference_image, x_px, y_px, subset_size, shifts_px=DEFAULT_SHIFTS_PX,
                   interpolation="biquintic", *, order: int = 1) -> np.ndarray:
    """Interpolation bias of u and v at each point of interest vs the sub-pixel translation (equation 1).

    For each point, the first-order error of IC-GN (ZNSSD, the engine's reference-side Jacobian and shape
    function) on its own reference subset when the deformed image is the exact band-limited translate by
    ``(t, 0)`` (bias of u) or ``(0, t)`` (bias of v). The interpolation error ``e_t`` is a Fourier filter of the
    reference along the shift (each row extended smoothly past the crop, so nothing is assumed periodic);
    the subset sums come from running sums along the rows, shared by all points, and the filters for all
    shifts from a few basis filters: the cost grows with the area covered and, mildly, with the number of
    points, hardly with the number of shifts (10^4 points of 65 px subsets at a 10 px step: ~2-3 s on 2 cores).
    Accuracy and limits: module notes.

    Parameters
    ----------
    reference_image : ndarray, shape (rows, cols)
        Reference grey image (finite).
    x_px, y_px : array_like of int, shape (N,)
        Points of interest (subset centres), column and row, px.
    subset_size : int
        Odd subset width 2M + 1, px.
    shifts_px : array_like, shape (T,)
        Sub-pixel translations, px.
    interpolation : {'biquintic', 'bicubic'} or {5, 3}
    order : {1, 2}
        Shape function of the DIC run.

    Returns
    -------
    ndarray of float64, shape (N, T, 2)
        Estimate minus truth, px: u for ``(t, 0)`` in ``[..., 0]``, v for ``(0, t)`` in ``[..., 1]``. NaN
        where the subset leaves the image or cannot constrain the shape function (flat).
    """
    image, xs, ys, subset_size = _check_points(reference_image, x_px, y_px, subset_size)
    degree = bspline.degree_of(interpolation)
    if order not in (1, 2):
        raise ValueError(f"order must be 1 or 2, got {order!r}")
    shifts = _check_shifts(shifts_px)
    half = subset_size // 2
    rows, cols = image.shape
    out = np.full((xs.size, shifts.size, 2), np.nan)
    inside = (xs - half >= 0) & (ys - half >= 0) & (xs + half < cols) & (ys + half < rows)
    if not inside.any():
        return out
    # Crop to the subsets and some context: the cost is the area covered.
    c0 = max(0, int(xs[inside].min()) - half - _CONTEXT_PX)
    c1 = min(cols, int(xs[inside].max()) + half + 1 + _CONTEXT_PX)
    r0 = max(0, int(ys[inside].min()) - half - _CONTEXT_PX)
    r1 = min(rows, int(ys[inside].max()) + half + 1 + _CONTEXT_PX)
    c0, c1 = _fast_window(c0, c1, cols)
    r0, r1 = _fast_window(r0, r1, rows)
    crop = np.ascontiguousarray(image[r0:r1, c0:c1], dtype=np.float64)
    if min(crop.shape) < degree + 1:
        return out
    spline = bspline.prefilter(crop, degree, gradients=True)
    px, py = xs[inside] - c0, ys[inside] - r0
    out[inside, :, 0] = _curves_along_x(crop, spline.grad_x, spline.grad_y, px, py, half, degree, order, shifts)
    # Along y: the same on the transposed image (the spline and its gradients are separable and symmetric).
    out[inside, :, 1] = _curves_along_x(np.ascontiguousarray(crop.T), np.ascontiguousarray(spline.grad_y.T),
                                        np.ascontiguousarray(spline.grad_x.T), py, px, half, degree, order, shifts)
    return out


def bias_bound_px(reference_image, x_px, y_px, subset_size, interpolation="biquintic", *, order: int = 1,
                  shifts_px=DEFAULT_SHIFTS_PX, relative_margin: float = 0.1) -> np.ndarray:
    """Bound on the interpolation bias of u and of v over sub-pixel translations, per point of interest.

    ``(1 + relative_margin) max_t |bias_curves_px(...)|`` over ``shifts_px`` (every 0.05 px of a whole period by
    default; a point's curve is not antisymmetric about 0.5 px, so half a period does not suffice). The margin
    stands for what the first-order prediction leaves out: with 10 % the bound covers the measured
    ``max_t |bias|`` at >= 98 % of the points for 33-65 px subsets on 2.5-8 px speckles (module notes; ~80 % for
    21 px subsets on 8 px speckles, where 20 % would be needed for ~94 %).

    Parameters
    ----------
    reference_image : ndarray, shape (rows, cols)
        Reference grey image (finite).
    x_px, y_px : array_like of int, shape (N,)
        Points of interest, px.
    subset_size : int
        Odd subset width, px.
    interpolation : {'biquintic', 'bicubic'} or {5, 3}
    order : {1, 2}
        Shape function.
    shifts_px : array_like, shape (T,)
        Sub-pixel translations searched, px.
    relative_margin : float
        Relative allowance added to the largest predicted bias, >= 0.

    Returns
    -------
    ndarray of float64, shape (N, 2)
        Bound on the absolute bias of u and of v, px; NaN where :func:`bias_curves_px` is NaN.
    """
    if not (np.isfinite(relative_margin) and relative_margin >= 0):
        raise ValueError(f"relative_margin must be a finite number >= 0, got {relative_margin!r}")
    curves = bias_curves_px(reference_image, x_px, y_px, subset_size, shifts_px, interpolation, order=order)
    return (1.0 + relative_margin) * np.abs(curves).max(axis=1)


__all__ = ["DEFAULT_SHIFTS_PX", "bias_bound_px", "bias_curves_px", "interpolant_transfer", "translation_bias_px"]
