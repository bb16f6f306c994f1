"""What a real camera's optics add to a rendered image: the diffraction of its aperture (the truth side).

A renderer draws the scene box-filtered over each pixel (a sensor whose pixels collect all the light that falls on
them, as microlenses make them do) through a pinhole or a thin lens. A real lens at f-number ``N`` also diffracts:
the image of a point is an Airy pattern of radius ``1.22 lambda N`` (first dark ring: 1.56 px at f/8, 550 nm,
3.45 um pixels), and the image of the scene is the geometric one convolved with it. Left out, a rendered speckle
keeps edges sharper than any camera records, and a paint finer than the pixel aliases where a real camera's lens
would have low-passed it.

The incoherent optical transfer function of a circular aperture without aberrations is

    OTF(nu) = 2 / pi * (arccos(r) - r sqrt(1 - r^2)),   r = nu / nu_c <= 1,  0 beyond,

with the cut-off ``nu_c = 1 / (lambda N)`` cycles per mm on the sensor, ``pitch / (lambda N)`` cycles per pixel
(0.78 at f/8: the OTF is 0.25 at the Nyquist frequency). :func:`apply_diffraction` multiplies the image's
cosine-series (DCT-II) coefficients by it: the convolution of the image's mirrored copy with the (symmetric) point
spread function, exact for an image whose content lies below the Nyquist frequency. For a paint that has content
above it, render ``supersample`` times finer and let :func:`apply_diffraction` bin the result: the optics then act
before the pixels sample.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Default wavelength: the middle of the visible band (a white-light or green-LED DIC rig), nm.
DEFAULT_WAVELENGTH_NM = 550.0


def cutoff_cycles_per_px(f_number: float, wavelength_nm: float, pixel_pitch_mm: float) -> float:
    """The diffraction OTF's cut-off ``pitch / (lambda N)``, cycles per pixel."""
    _positive(f_number, "f_number")
    _positive(wavelength_nm, "wavelength_nm")
    _positive(pixel_pitch_mm, "pixel_pitch_mm")
    return float(pixel_pitch_mm / (wavelength_nm * 1e-6 * f_number))


def airy_radius_px(f_number: float, wavelength_nm: float, pixel_pitch_mm: float) -> float:
    """Radius of the Airy pattern's first dark ring, ``1.22 lambda N``, in pixels."""
    return 1.22 / cutoff_cycles_per_px(f_number, wavelength_nm, pixel_pitch_mm)


def diffraction_otf(frequency_cycles_per_px, f_number: float, wavelength_nm: float,
                    pixel_pitch_mm: float) -> np.ndarray:
    """The incoherent OTF of a circular aperture (module docstring) at radial frequencies (cycles per pixel, any
    shape); 1 at 0, 0 beyond the cut-off."""
    r = np.abs(np.asarray(frequency_cycles_per_px, float)) / cutoff_cycles_per_px(f_number, wavelength_nm,
                                                                                    pixel_pitch_mm)
    r = np.minimum(r, 1.0)
    return 2.0 / np.pi * (np.arccos(r) - r * np.sqrt(1.0 - r * r))


def apply_diffraction(image: np.ndarray, f_number: float, wavelength_nm: float = DEFAULT_WAVELENGTH_NM,
                      pixel_pitch_mm: float = 0.00345, supersample: int = 1) -> np.ndarray:
    """The image a lens at ``f_number`` records of a box-filtered render (module docstring).

    Parameters
    ----------
    image : ndarray, shape (rows * supersample, cols * supersample)
        Render, grey levels; with ``supersample > 1`` drawn on pixels ``supersample`` times finer than the sensor's.
    f_number, wavelength_nm, pixel_pitch_mm : the lens' aperture, the light, the sensor's pixel (mm)
    supersample : int >= 1
        Fine pixels per sensor pixel along each axis; the result is binned (mean) to the sensor's pixels.

    Returns
    -------
    ndarray of float64, shape (rows, cols)
    """
    import scipy.fft

    image = np.asarray(image, np.float64)
    if image.ndim != 2 or not np.all(np.isfinite(image)):
        raise ValueError(f"apply_diffraction: the image must be a finite 2-D array, got shape {image.shape}")
    s = int(supersample)
    if s != supersample or s < 1:
        raise ValueError(f"apply_diffraction: supersample must be an integer >= 1, got {supersample!r}")
    rows, cols = image.shape
    if rows % s or cols % s:
        raise ValueError(f"apply_diffraction: a {cols} x {rows} image is not a whole number of {s} x {s} blocks")
    coefficients = scipy.fft.dctn(image, type=2, workers=-1)
    fy = np.arange(rows) / (2.0 * rows) * s          # cycles per sensor pixel of each cosine
    fx = np.arange(cols) / (2.0 * cols) * s
    coefficients *= diffraction_otf(np.hypot(fy[:, None], fx[None, :]), f_number, wavelength_nm, pixel_pitch_mm)
    out = scipy.fft.idctn(coefficients, type=2, workers=-1)
    if s > 1:
        out = out.reshape(rows // s, s, cols // s, s).mean(axis=(1, 3))
    return out


@dataclass(frozen=True)
class Optics:
    """A camera's diffraction (:func:`apply_diffraction`) at ``f_number`` (None: ideal optics, the image as
    rendered), ``wavelength_nm``, on pixels of ``pixel_pitch_mm``."""

    f_number: float | None = None
    wavelength_nm: float = DEFAULT_WAVELENGTH_NM
    pixel_pitch_mm: float = 0.00345

    def __post_init__(self):
        if self.f_number is not None:
            _positive(self.f_number, "f_number")
        _positive(self.wavelength_nm, "wavelength_nm")
        _positive(self.pixel_pitch_mm, "pixel_pitch_mm")

    @property
    def airy_radius_px(self) -> float | None:
        return None if self.f_number is None else airy_radius_px(self.f_number, self.wavelength_nm,
                                                                 self.pixel_pitch_mm)

    def apply(self, image: np.ndarray, supersample: int = 1) -> np.ndarray:
        """The recorded image of a render (float64); unchanged but binned without a diffraction."""
        if self.f_number is None:
            image = np.asarray(image, np.float64)
            if supersample == 1:
                return image
            r, c = image.shape
            return image.reshape(r // supersample, supersample, c // supersample, supersample).mean(axis=(1, 3))
        return apply_diffraction(image, self.f_number, self.wavelength_nm, self.pixel_pitch_mm, supersample)

    def to_dict(self) -> dict:
        return {"f_number": self.f_number, "wavelength_nm": self.wavelength_nm, "pixel_pitch_mm": self.pixel_pitch_mm,
                "airy_radius_px": self.airy_radius_px}


def _positive(value, name: str) -> float:
    if not (np.isfinite(value) and value > 0):
        raise ValueError(f"{name} must be a positive number, got {value!r}")
    return float(value)


__all__ = ["DEFAULT_WAVELENGTH_NM", "Optics", "airy_radius_px", "apply_diffraction", "cutoff_cycles_per_px",
           "diffraction_otf"]
