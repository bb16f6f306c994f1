"""Quality metrics for speckle images (the instrument side; works on real or rendered images).

Mean intensity gradient (MIG), Pan et al. (2010), "Mean intensity gradient: an effective global parameter
for quality assessment of the speckle patterns used in digital image correlation", Optics and Lasers in
Engineering 48, 469-477:

    MIG = (1 / N) sum_{i,j} |grad f(i, j)|,    |grad f| = sqrt(f_x^2 + f_y^2),

with ``f_x``, ``f_y`` from the Sobel operator and the sum over the ``N`` pixels considered. Larger MIG means
sharper, higher-contrast speckles and, for a given noise level, smaller DIC displacement errors.
"""
from __future__ import annotations

import numpy as np
from scipy import ndimage

#: A Sobel kernel applied to the unit ramp f = x returns this; dividing by it gives grey levels per pixel.
SOBEL_SCALE = 8.0


def gradient_magnitude(image: np.ndarray) -> np.ndarray:
    """Sobel gradient magnitude ``sqrt(f_x^2 + f_y^2)`` in grey levels per pixel.

    The Sobel responses are divided by 8 so a unit ramp gives 1. Border pixels are computed with the image
    edge replicated (``mode='nearest'``), which underestimates the gradient across the border;
    :func:`mean_intensity_gradient` leaves them out.

    Parameters
    ----------
    image : ndarray, shape (rows, cols)
        Grey-level image (any real dtype), finite, at least 3 x 3.

    Returns
    -------
    ndarray of float64, shape (rows, cols)
        Gradient magnitude in grey levels per pixel.
    """
    image = _check_image(image)
    grad_rows = ndimage.sobel(image, axis=0, mode="nearest") / SOBEL_SCALE
    grad_cols = ndimage.sobel(image, axis=1, mode="nearest") / SOBEL_SCALE
    return np.hypot(grad_rows, grad_cols)


def mean_intensity_gradient(image: np.ndarray, mask: np.ndarray | None = None) -> float:
    """Mean intensity gradient (MIG) of Pan et al. (2010), in grey levels per pixel.

    ``MIG = mean(|grad f|)`` over the interior pixels (the one-pixel border is excluded, because the Sobel
    stencil there would reach outside the image) that are also selected by ``mask``. See
    :func:`gradient_magnitude` for the gradient.

    Parameters
    ----------
    image : ndarray, shape (rows, cols)
        Grey-level image (any real dtype), finite, at least 3 x 3.
    mask : ndarray of bool, shape (rows, cols), optional
        True for pixels to include (e.g. the specimen region). None includes every interior pixel.

    Returns
    -------
    float
        MIG in grey levels per pixel.
    """
    magnitude = gradient_magnitude(image)
    include = np.zeros(magnitude.shape, dtype=bool)
    include[1:-1, 1:-1] = True
    if mask is not None:
        mask = np.asarray(mask)
        if mask.dtype != bool:
            raise ValueError(f"mask must be a boolean array, got dtype {mask.dtype}")
        if mask.shape != magnitude.shape:
            raise ValueError(f"mask shape {mask.shape} does not match image shape {magnitude.shape}")
        include &= mask
    if not include.any():
        raise ValueError("mask selects no interior pixels (the one-pixel image border is always excluded)")
    return float(magnitude[include].mean())


def _check_image(image) -> np.ndarray:
    image = np.asarray(image)
    if image.ndim != 2:
        raise ValueError(f"image must be 2-D (one grey channel), got shape {image.shape}")
    if min(image.shape) < 3:
        raise ValueError(f"image must be at least 3 x 3 for the Sobel operator, got shape {image.shape}")
    if not (np.issubdtype(image.dtype, np.floating) or np.issubdtype(image.dtype, np.integer)
            or image.dtype == bool):
        raise ValueError(f"image must be a real numeric array, got dtype {image.dtype}")
    image = image.astype(np.float64)
    n_bad = np.count_nonzero(~np.isfinite(image))
    if n_bad:
        raise ValueError(f"image has {n_bad} non-finite pixels")
    return image
