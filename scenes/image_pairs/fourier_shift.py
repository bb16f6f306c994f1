"""Exact sub-pixel translations by Fourier shifting (the truth side, no rendering).

Reu 2011, "Experimental and numerical methods for exact subpixel shifting": the image is taken as one period of
a periodic, band-limited function; multiplying its FFT by a phase ramp translates that function by an exact
sub-pixel amount. :func:`fourier_shift` does it, :func:`band_limit` gives the matching reference,
:func:`fourier_shifted_pair` makes a ready pair (pattern: :mod:`scenes.image_pairs.gaussian_speckle`; pixel
conventions: :mod:`scenes.image_pairs.analytic_fields`).
"""
from __future__ import annotations

import numpy as np
import scipy.fft

from scenes.image_pairs.analytic_fields import check_xy
from scenes.image_pairs.gaussian_speckle import (check_image, check_image_shape, extent_for_shape, gaussian_speckle,
                                                 radius_for_speckle_size)

def fourier_shift(image: np.ndarray, shift_xy_px) -> np.ndarray:
    """Translate an image by an exact sub-pixel amount in the Fourier domain (Reu 2011).

    The image is treated as one period of a periodic, band-limited function; its FFT is multiplied by the
    phase ramp ``exp(-2 pi i (f_x s_x + f_y s_y))`` and the real part of the inverse FFT is returned, so that
    ``g(x, y) = f(x - s_x, y - s_y)`` (content moves by ``+s``; ``x`` is the column, ``y`` the row
    coordinate). Content leaving one side re-enters on the other. The Nyquist bins of even-sized axes are
    zeroed, because a shifted Nyquist cosine is not representable by real samples; the reference that the
    result is an exact shift of is therefore :func:`band_limit` ``(image)``, not ``image`` itself (they
    differ only for even sizes). For an integer shift the result is ``np.roll(band_limit(image), ...)``.

    Parameters
    ----------
    image : ndarray, shape (rows, cols)
        Real, finite image (any float or integer dtype), each side >= 2.
    shift_xy_px : sequence of 2 floats
        ``(s_x, s_y)`` in pixels: ``s_x`` along columns, ``s_y`` along rows; finite.

    Returns
    -------
    ndarray of float64, shape (rows, cols)
        The shifted, band-limited image.
    """
    image = check_image(image)
    shift_x, shift_y = check_xy(shift_xy_px, "shift_xy_px")
    return _shift_band_limited(image, shift_x, shift_y)


def band_limit(image: np.ndarray) -> np.ndarray:
    """The image with its Nyquist bins zeroed: the reference matching :func:`fourier_shift`.

    For a DIC test with Fourier-shifted images use ``band_limit(f)`` as the reference and
    ``fourier_shift(f, s)`` as the deformed image: both are then samples of the same periodic band-limited
    function, exactly ``s`` apart. For odd sizes there is no Nyquist bin and this returns ``image`` as float64
    (up to FFT round-off, ~1e-13 relative).

    Parameters
    ----------
    image : ndarray, shape (rows, cols)
        Real, finite image, each side >= 2.

    Returns
    -------
    ndarray of float64, shape (rows, cols)
    """
    return _shift_band_limited(check_image(image), 0.0, 0.0)


def fourier_shifted_pair(shape: tuple[int, int], speckle_size_px: float, shift_xy_px, seed: int = 0, *,
                         density: float = 0.5, mean_grey: float = 128.0,
                         std_grey: float = 30.0) -> tuple[np.ndarray, np.ndarray]:
    """A periodic speckle image and its exact sub-pixel translation.

    The pattern is a *periodic* :class:`GaussianSpeckle` (period = image size, so the FFT sees no seam)
    sampled at the pixel centres, with blob sizes from :func:`radius_for_speckle_size` so that
    :func:`scenes.surfaces.speckle.speckle_size_from_pattern` reads about ``speckle_size_px`` (within ~2 % on
    256 x 256 px). The Boolean-disk texture of :func:`scenes.surfaces.speckle.speckle_pattern` is not used: at pixel
    resolution it cannot be made finer than about 2.9 px by that measure.

    Parameters
    ----------
    shape : tuple of int
        ``(rows, cols)``, each >= 16.
    speckle_size_px : float
        Autocorrelation speckle size in px, >= :func:`speckle_size_for_radius` of the smallest allowed blob
        (about 1.6 px); about 2.75 px and more keep aliasing small (see the module notes). Aliasing does not
        affect this pair's exactness: both images are the same band-limited function.
    shift_xy_px : sequence of 2 floats
        ``(s_x, s_y)`` in px; the second image is ``g(x, y) = f(x - s_x, y - s_y)``.
    seed : int
        Seed of the pattern; the same seed gives the same pair.
    density, mean_grey, std_grey : float
        As in :func:`gaussian_speckle`.

    Returns
    -------
    reference, shifted : ndarray of float64, shape (rows, cols)
        ``band_limit(f)`` and ``fourier_shift(f, shift_xy_px)``.
    """
    rows, cols = check_image_shape(shape, minimum=16)
    shift_x, shift_y = check_xy(shift_xy_px, "shift_xy_px")
    radius_px = radius_for_speckle_size(speckle_size_px)
    pattern = gaussian_speckle(extent_for_shape((rows, cols)), radius_px, density, seed,
                               mean_grey=mean_grey, std_grey=std_grey, periodic=True)
    image = pattern.render_reference((rows, cols))
    return _shift_band_limited(image, 0.0, 0.0), _shift_band_limited(image, shift_x, shift_y)


def _shift_band_limited(image: np.ndarray, shift_x: float, shift_y: float) -> np.ndarray:
    """Fourier shift of a checked float64 image, Nyquist bins zeroed."""
    rows, cols = image.shape
    ramp_x = np.exp(-2j * np.pi * scipy.fft.fftfreq(cols) * shift_x)
    ramp_y = np.exp(-2j * np.pi * scipy.fft.fftfreq(rows) * shift_y)
    if cols % 2 == 0:
        ramp_x[cols // 2] = 0.0
    if rows % 2 == 0:
        ramp_y[rows // 2] = 0.0
    spectrum = scipy.fft.fft2(image, workers=-1)
    spectrum *= ramp_y[:, None]
    spectrum *= ramp_x[None, :]
    return np.ascontiguousarray(scipy.fft.ifft2(spectrum, workers=-1, overwrite_x=True).real)
