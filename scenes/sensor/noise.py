"""Sensor noise applied to rendered, already exposed images (the truth side).

The model, per pixel, in grey levels ``g`` of the final bit depth:

1. shot noise: the signal holds ``g * electrons_per_grey`` electrons, drawn Poisson, converted back, so its
   variance is ``g / electrons_per_grey`` grey^2;
2. read noise: additive Gaussian with standard deviation ``read_noise_grey``;
3. quantisation: round to the nearest integer and clip to ``[0, 2^bits - 1]``, which adds about 1/12 grey^2
   of variance when the other noise is at least ~0.5 grey.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Bit depths the quantiser supports.
SUPPORTED_BIT_DEPTHS = (8, 16)

#: Variance of rounding to integers, for a signal spread over several grey levels (grey^2).
QUANTISATION_VARIANCE_GREY2 = 1.0 / 12.0


def max_grey(bit_depth: int) -> int:
    """Largest grey level of an unsigned integer image with ``bit_depth`` bits (8 or 16)."""
    _check_bit_depth(bit_depth, allow_none=False)
    return 2**bit_depth - 1


def apply_sensor_noise(image_grey: np.ndarray, *, read_noise_grey: float = 0.0,
                       electrons_per_grey: float | None = None, bit_depth: int | None = 8,
                       seed: int = 0) -> np.ndarray:
    """Add shot and read noise to a noise-free image and quantise it.

    Parameters
    ----------
    image_grey : ndarray, any shape
        Noise-free exposed image in grey levels of the final bit depth (e.g. 0-255 for 8 bit).
        Must be finite, and non-negative when shot noise is on.
    read_noise_grey : float
        Standard deviation of the Gaussian read noise in grey levels (>= 0).
    electrons_per_grey : float or None
        Conversion gain in electrons per grey level (> 0); None turns shot noise off.
    bit_depth : {8, 16} or None
        Round and clip to ``[0, 2^bit_depth - 1]``; None keeps the noisy float values unclipped.
    seed : int
        Seed for ``np.random.default_rng``; the same seed gives the same noise.

    Returns
    -------
    ndarray of float32, same shape as ``image_grey``
        Noisy image in grey levels; integral values when quantised.
    """
    image = _check_image(image_grey)
    read_noise_grey = _check_read_noise(read_noise_grey)
    electrons_per_grey = _check_gain(electrons_per_grey)
    _check_bit_depth(bit_depth)

    rng = np.random.default_rng(seed)
    noisy = image.astype(np.float64, copy=True)
    if electrons_per_grey is not None:
        n_negative = np.count_nonzero(noisy < 0)
        if n_negative:
            raise ValueError(f"image_grey has {n_negative} negative pixels; shot noise needs a signal >= 0")
        noisy = rng.poisson(noisy * electrons_per_grey) / electrons_per_grey
    if read_noise_grey > 0:
        noisy += rng.normal(0.0, read_noise_grey, size=noisy.shape)
    if bit_depth is not None:
        noisy = np.clip(np.rint(noisy), 0, max_grey(bit_depth))
    return noisy.astype(np.float32)


def noise_sigma_grey(image_grey: np.ndarray, read_noise_grey: float = 0.0,
                     electrons_per_grey: float | None = None, bit_depth: int | None = 8) -> np.ndarray:
    """Predicted per-pixel standard deviation of :func:`apply_sensor_noise`.

    ``sigma^2 = read_noise_grey^2 + image_grey / electrons_per_grey + 1/12`` (each term only when that
    noise source is on). The 1/12 is exact on average only when the other noise is >= ~0.5 grey, and
    clipping at 0 and full scale is ignored.

    Parameters
    ----------
    image_grey : ndarray, any shape
        Noise-free image in grey levels (finite; >= 0 when ``electrons_per_grey`` is given).
    read_noise_grey, electrons_per_grey, bit_depth
        As for :func:`apply_sensor_noise`.

    Returns
    -------
    ndarray of float64, same shape as ``image_grey``
        Standard deviation in grey levels.
    """
    image = _check_image(image_grey).astype(np.float64)
    read_noise_grey = _check_read_noise(read_noise_grey)
    electrons_per_grey = _check_gain(electrons_per_grey)
    _check_bit_depth(bit_depth)
    variance = np.full(image.shape, read_noise_grey**2)
    if electrons_per_grey is not None:
        n_negative = np.count_nonzero(image < 0)
        if n_negative:
            raise ValueError(f"image_grey has {n_negative} negative pixels; shot noise needs a signal >= 0")
        variance += image / electrons_per_grey
    if bit_depth is not None:
        variance += QUANTISATION_VARIANCE_GREY2
    return np.sqrt(variance)


def to_image_dtype(image: np.ndarray, bit_depth: int) -> np.ndarray:
    """Round, clip and cast grey levels to ``uint8`` (8 bit) or ``uint16`` (16 bit) for writing files.

    Parameters
    ----------
    image : ndarray, any shape
        Grey levels (finite).
    bit_depth : {8, 16}
        Target bit depth.

    Returns
    -------
    ndarray of uint8 or uint16, same shape as ``image``
    """
    _check_bit_depth(bit_depth, allow_none=False)
    image = _check_image(image, name="image")
    dtype = np.uint8 if bit_depth == 8 else np.uint16
    return np.clip(np.rint(image), 0, max_grey(bit_depth)).astype(dtype)


@dataclass(frozen=True)
class SensorNoise:
    """Parameters of the sensor-noise model; see :func:`apply_sensor_noise`.

    Parameters
    ----------
    read_noise_grey : float
        Read-noise standard deviation in grey levels (>= 0).
    electrons_per_grey : float or None
        Conversion gain in electrons per grey level (> 0); None turns shot noise off.
    bit_depth : {8, 16} or None
        Output bit depth; None skips quantisation.
    """

    read_noise_grey: float = 0.0
    electrons_per_grey: float | None = None
    bit_depth: int | None = 8

    def __post_init__(self):
        _check_read_noise(self.read_noise_grey)
        _check_gain(self.electrons_per_grey)
        _check_bit_depth(self.bit_depth)

    def apply(self, image_grey: np.ndarray, seed: int = 0) -> np.ndarray:
        """Noisy float32 image in grey levels, as :func:`apply_sensor_noise`."""
        return apply_sensor_noise(image_grey, read_noise_grey=self.read_noise_grey,
                                  electrons_per_grey=self.electrons_per_grey, bit_depth=self.bit_depth,
                                  seed=seed)

    def sigma_grey(self, image_grey: np.ndarray) -> np.ndarray:
        """Predicted per-pixel standard deviation in grey levels, as :func:`noise_sigma_grey`."""
        return noise_sigma_grey(image_grey, self.read_noise_grey, self.electrons_per_grey, self.bit_depth)


# ------------------------------------------------------------------------------------------------------------
def _check_image(image, name: str = "image_grey") -> np.ndarray:
    image = np.asarray(image)
    if not (np.issubdtype(image.dtype, np.floating) or np.issubdtype(image.dtype, np.integer)):
        raise ValueError(f"{name} must be a real numeric array, got dtype {image.dtype}")
    if np.issubdtype(image.dtype, np.floating):
        n_nan = np.count_nonzero(np.isnan(image))
        if n_nan:
            raise ValueError(f"{name} has {n_nan} NaN pixels")
        n_inf = np.count_nonzero(np.isinf(image))
        if n_inf:
            raise ValueError(f"{name} has {n_inf} infinite pixels")
    return image


def _check_read_noise(read_noise_grey) -> float:
    value = float(read_noise_grey)
    if not np.isfinite(value) or value < 0:
        raise ValueError(f"read_noise_grey must be finite and >= 0, got {read_noise_grey}")
    return value


def _check_gain(electrons_per_grey) -> float | None:
    if electrons_per_grey is None:
        return None
    value = float(electrons_per_grey)
    if not np.isfinite(value) or value <= 0:
        raise ValueError(f"electrons_per_grey must be finite and > 0 (or None), got {electrons_per_grey}")
    return value


def _check_bit_depth(bit_depth, allow_none: bool = True) -> None:
    if bit_depth is None and allow_none:
        return
    if isinstance(bit_depth, bool) or bit_depth not in SUPPORTED_BIT_DEPTHS:
        allowed = ", ".join(map(str, SUPPORTED_BIT_DEPTHS)) + (" or None" if allow_none else "")
        raise ValueError(f"bit_depth must be {allowed}, got {bit_depth!r}")
