"""Illumination change between the states of an experiment (truth side).

Lamps drift in intensity as they warm up, ambient light changes, and a light source that moves relative to
the specimen brightens one side of the image more than the other. DIC with a zero-normalised criterion
(ZNCC / ZNSSD) is insensitive to a uniform gain and offset of the grey levels within a subset but not to a
gain that varies across it (Pan 2009, "Two-dimensional digital image correlation for in-plane displacement
and strain measurement: a review", Meas. Sci. Technol. 20 062001; iDICs, "A Good Practices Guide for
Digital Image Correlation", 2018). Realistic values: gain changes of a few % between images, offsets of a
few grey levels (8 bit), and gradients of a few % across the field of view.

Model, per state index ``k`` (linear in ``k``: a slow, monotonic drift), per pixel at OpenCV pixel-centre
coordinates ``(x, y)`` of the *full* sensor, ``W x H`` pixels:

``I_k = max(0, I_0 * (1 + k (gain_per_state + gradient_per_state * xi(x, y))) + k offset_grey_per_state)``

``xi = ((x - (W - 1) / 2) cos(phi) + (y - (H - 1) / 2) sin(phi)) / W``, ``phi = gradient_angle_deg``

For ``phi = 0`` the ramp runs from ``-1/2`` at the left edge of the sensor (x = -0.5) to ``+1/2`` at the right
edge (x = W - 0.5): the relative gain changes by ``k * gradient_per_state`` across the image width, centred
on the sensor centre. The ramp is normalised by the width for every ``phi``.

Order: this is a change of the *scene radiance*, so it acts on the noise-free, exposed grey image (the
exposure of :mod:`scenes.rendering.mitsuba` is linear, so a radiance gain is a grey-level gain); sensor noise and
quantisation (:mod:`scenes.sensor.noise`) come after it. Negative results are clipped to 0 (radiance cannot be
negative); with realistic parameters and a lit specimen nothing is clipped.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from scenes import _checks


@dataclass(frozen=True)
class IlluminationChange:
    """Gain, offset and gradient of the illumination, each linear in the state index; zero by default.

    Parameters
    ----------
    gain_per_state : float
        Relative (dimensionless) gain change per state index: the image is multiplied by
        ``1 + gain_per_state * k``. Realistic: a few % over an experiment (lamp warm-up, mains flicker
        averaged by the exposure).
    offset_grey_per_state : float
        Grey levels (of the final bit depth) added per state index, e.g. ambient light: a few grey levels
        over an experiment at 8 bit.
    gradient_per_state : float
        Relative gain change across the image width per state index (dimensionless): a linear ramp from
        ``-k g / 2`` to ``+k g / 2`` across the sensor. Realistic: a few % across the field of view.
    gradient_angle_deg : float
        Direction of the ramp in the image, degrees from +x towards +y (OpenCV: y down); 0 = along x.
    """

    gain_per_state: float = 0.0
    offset_grey_per_state: float = 0.0
    gradient_per_state: float = 0.0
    gradient_angle_deg: float = 0.0

    def __post_init__(self):
        for name in ("gain_per_state", "offset_grey_per_state", "gradient_per_state", "gradient_angle_deg"):
            object.__setattr__(self, name, _checks.finite_float(name, getattr(self, name)))

    @property
    def is_zero(self) -> bool:
        """True when the illumination does not change (the angle alone changes nothing)."""
        return self.gain_per_state == 0 and self.offset_grey_per_state == 0 and self.gradient_per_state == 0

    def gain_map(self, state_index: int, shape_hw: tuple[int, int], crop=None, sensor_size_px=None) -> np.ndarray:
        """Multiplicative factor ``1 + k (gain + gradient * xi)`` (H, W) of the image (or crop) of state ``k``.

        Arguments as for :meth:`apply`; ``shape_hw`` is the (height, width) of the image or crop.
        """
        k = _checks.state_index(state_index)
        x0, y0, W, H = _window(shape_hw, crop, sensor_size_px)
        h, w = shape_hw
        phi = np.radians(self.gradient_angle_deg)
        # Coordinates of the full sensor, so that a crop sees the same ramp as the full image there.
        x = (x0 + np.arange(w, dtype=float)) - (W - 1) / 2
        y = (y0 + np.arange(h, dtype=float)) - (H - 1) / 2
        xi = (np.cos(phi) * x[None, :] + np.sin(phi) * y[:, None]) / W
        return 1.0 + k * (self.gain_per_state + self.gradient_per_state * xi)

    def apply(self, image_grey, state_index: int, crop=None, sensor_size_px=None) -> np.ndarray:
        """The noise-free grey image of state ``k`` under the changed illumination.

        Parameters
        ----------
        image_grey : (H, W) float
            Noise-free, exposed grey image of the state as rendered under the state-0 illumination
            (before :mod:`scenes.sensor.noise`). Finite.
        state_index : int
            State index ``k >= 0``; state 0 is returned unchanged (as a float64 copy).
        crop : (x0, y0, width, height) or None
            Window of the full sensor the image covers (as in :func:`scenes.rendering.mitsuba.render_view`); None: the
            image is the full sensor.
        sensor_size_px : (W, H) or None
            Size of the full sensor in pixels; required with ``crop`` (the ramp is defined over the full
            sensor), optional without it (then it must equal the image size).

        Returns
        -------
        (H, W) float64, grey levels: ``max(0, I * gain_map + k * offset_grey_per_state)``.
        """
        image = _check_image(image_grey)
        k = _checks.state_index(state_index)
        factor = self.gain_map(k, image.shape, crop, sensor_size_px)   # also validates crop and sensor size
        if k == 0 or self.is_zero:
            return image.copy()
        return np.maximum(image * factor + k * self.offset_grey_per_state, 0.0)


# ------------------------------------------------------------------------------------------------------------
def _window(shape_hw, crop, sensor_size_px) -> tuple[int, int, int, int]:
    """``(x0, y0, W, H)``: offset of the image on the sensor and the sensor size, validated."""
    h, w = (int(n) for n in shape_hw)
    if sensor_size_px is not None:
        size = _int_tuple(sensor_size_px, 2, "sensor_size_px")
        if size[0] < 1 or size[1] < 1:
            raise ValueError(f"sensor_size_px must be positive (W, H), got {sensor_size_px!r}")
    if crop is None:
        if sensor_size_px is not None and size != (w, h):
            raise ValueError(f"sensor_size_px {size} differs from the image size (W, H) = {(w, h)}; "
                             "pass crop for a window of the sensor")
        return 0, 0, w, h
    x0, y0, cw, ch = _int_tuple(crop, 4, "crop")
    if sensor_size_px is None:
        raise ValueError("sensor_size_px (W, H) is required with crop: the ramp is defined over the full sensor")
    if (cw, ch) != (w, h):
        raise ValueError(f"crop size (width, height) = {(cw, ch)} differs from the image size {(w, h)}")
    W, H = size
    if x0 < 0 or y0 < 0 or x0 + cw > W or y0 + ch > H:
        raise ValueError(f"crop {tuple(crop)} is outside the {W} x {H} sensor (sensor_size_px)")
    return x0, y0, W, H


def _int_tuple(value, n: int, name: str) -> tuple[int, ...]:
    try:
        v = np.asarray(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be {n} integers, got {value!r}") from None
    if v.shape != (n,) or not (np.issubdtype(v.dtype, np.integer)
                               or (np.issubdtype(v.dtype, np.floating) and np.all(np.isfinite(v))
                                   and np.all(v == np.round(v)))):
        raise ValueError(f"{name} must be {n} integers, got {value!r}")
    return tuple(int(x) for x in v)


def _check_image(image_grey) -> np.ndarray:
    try:
        image = np.array(image_grey, dtype=float)
    except (TypeError, ValueError):
        raise ValueError("image_grey must be a real (H, W) array") from None
    if image.ndim != 2 or image.size == 0:
        raise ValueError(f"image_grey must be a non-empty (H, W) array, got shape {image.shape}")
    if not np.all(np.isfinite(image)):
        raise ValueError(f"image_grey has {np.count_nonzero(~np.isfinite(image))} non-finite pixels")
    return image
