"""What a real camera's optics and pixels add to a rendered image: its aperture's diffraction, the pixels'
aperture, a sensor MTF (the truth side).

A renderer draws the scene box-filtered over each pixel (a sensor whose pixels collect all the light that falls on
them, as microlenses make them do) through a pinhole or a thin lens. A real lens at f-number ``N`` also diffracts:
the image of a point is an Airy pattern of radius ``1.22 lambda N`` (first dark ring: 1.56 px at f/8, 550 nm,
3.45 um pixels), and the image of the scene is the geometric one convolved with it. Left out, a rendered speckle
keeps edges sharper than any camera records, and a paint finer than the pixel aliases where a real camera's lens
would have low-passed it.

The incoherent optical transfer function of a circular aperture without aberrations is

    OTF(nu) = 2 / pi * (arccos(r) - r sqrt(1 - r^2)),   r = nu / nu_c <= 1,  0 beyond,

with the cut-off ``nu_c = 1 / (lambda N)`` cycles per mm on the sensor, ``pitch / (lambda N)`` cycles per pixel
(0.78 at f/8: the OTF is 0.25 at the Nyquist frequency). :func:`apply_optics` multiplies the image's
cosine-series (DCT-II) coefficients by it: the convolution of the image's mirrored copy with the (symmetric) point
spread function, exact for an image whose content lies below the Nyquist frequency. For a paint that has content
above it, render ``supersample`` times finer and let :func:`apply_optics` bin the result: the optics then act
before the pixels sample. A pixel that collects light over less than its whole area (``fill_factor``; no
microlenses) and a measured sensor MTF (crosstalk) multiply the sensor image's coefficients too.
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
    return aperture_otf(r)


def aperture_otf(r) -> np.ndarray:
    """The incoherent OTF of a circular aperture at ``r`` = frequency / cut-off (any shape): 1 at 0, 0 from 1 on."""
    r = np.minimum(np.abs(np.asarray(r, float)), 1.0)
    return 2.0 / np.pi * (np.arccos(r) - r * np.sqrt(1.0 - r * r))


def pixel_aperture_gain(fx_cycles_per_px, fy_cycles_per_px, fill_factor: float) -> np.ndarray:
    """Transfer of a square pixel aperture of side ``fill_factor`` (a fraction of the pitch) *relative to* the
    whole pixel a render integrates: ``sinc(a fx) sinc(a fy) / (sinc(fx) sinc(fy))`` (``np.sinc``), 1 at a = 1."""
    fx = np.asarray(fx_cycles_per_px, float)
    fy = np.asarray(fy_cycles_per_px, float)
    a = float(fill_factor)
    return (np.sinc(a * fx) * np.sinc(a * fy)) / (np.sinc(fx) * np.sinc(fy))


def mtf_from_table(frequency_cycles_per_px, table) -> np.ndarray:
    """A measured sensor MTF given as ``(cycles per px, MTF)`` pairs: linear between them, 1 at 0, the last value
    beyond the last frequency."""
    t = np.asarray(table, float)
    nu = np.concatenate([[0.0], t[:, 0]])
    m = np.concatenate([[1.0], t[:, 1]])
    return np.interp(np.abs(np.asarray(frequency_cycles_per_px, float)), nu, m)


def apply_optics(image: np.ndarray, f_number: float | None, wavelength_nm: float = DEFAULT_WAVELENGTH_NM,
                 pixel_pitch_mm: float = 0.00345, supersample: int = 1, fill_factor: float = 1.0,
                 sensor_mtf=None) -> np.ndarray:
    """The image a camera records of a box-filtered render (module docstring).

    Parameters
    ----------
    image : ndarray, shape (rows * supersample, cols * supersample)
        Render, grey levels; with ``supersample > 1`` drawn on pixels ``supersample`` times finer than the sensor's.
    f_number, wavelength_nm, pixel_pitch_mm : the lens' aperture (None: no diffraction), the light, the sensor's
        pixel (mm)
    supersample : int >= 1
        Fine pixels per sensor pixel along each axis; the diffracted image is binned (mean) to the sensor's pixels.
    fill_factor : the pixel's light-collecting aperture, a square of this fraction of the pitch (1: the whole
        pixel, as microlenses make it; a smaller aperture low-passes less and aliases more)
    sensor_mtf : ``(cycles per px, MTF)`` pairs of a measured sensor MTF beyond the pixel aperture (crosstalk), or
        None

    Returns
    -------
    ndarray of float64, shape (rows, cols)
    """
    import scipy.fft

    image = np.asarray(image, np.float64)
    if image.ndim != 2 or not np.all(np.isfinite(image)):
        raise ValueError(f"apply_optics: the image must be a finite 2-D array, got shape {image.shape}")
    s = int(supersample)
    if s != supersample or s < 1:
        raise ValueError(f"apply_optics: supersample must be an integer >= 1, got {supersample!r}")
    rows, cols = image.shape
    if rows % s or cols % s:
        raise ValueError(f"apply_optics: a {cols} x {rows} image is not a whole number of {s} x {s} blocks")
    if not 0 < fill_factor <= 1:
        raise ValueError(f"apply_optics: fill_factor must be in (0, 1], got {fill_factor!r}")
    if sensor_mtf is not None:
        t = np.asarray(sensor_mtf, float)
        if t.ndim != 2 or t.shape[1] != 2 or len(t) < 1 or np.any(np.diff(t[:, 0]) <= 0) or t[0, 0] <= 0 \
                or np.any(t[:, 1] < 0) or not np.all(np.isfinite(t)):
            raise ValueError("apply_optics: sensor_mtf must be (cycles per px, MTF >= 0) pairs at ascending positive "
                             "frequencies")
    out = image
    if f_number is not None:
        coefficients = scipy.fft.dctn(image, type=2, workers=-1)
        fy = np.arange(rows) / (2.0 * rows) * s          # cycles per sensor pixel of each cosine
        fx = np.arange(cols) / (2.0 * cols) * s
        coefficients *= diffraction_otf(np.hypot(fy[:, None], fx[None, :]), f_number, wavelength_nm,
                                        pixel_pitch_mm)
        out = scipy.fft.idctn(coefficients, type=2, workers=-1)
    if s > 1:
        out = out.reshape(rows // s, s, cols // s, s).mean(axis=(1, 3))
    if fill_factor != 1.0 or sensor_mtf is not None:
        # On the sensor's pixels: both act on what the pixel grid holds (below its Nyquist frequency).
        r, c = out.shape
        coefficients = scipy.fft.dctn(out, type=2, workers=-1)
        fy = (np.arange(r) / (2.0 * r))[:, None]
        fx = (np.arange(c) / (2.0 * c))[None, :]
        coefficients *= pixel_aperture_gain(fx, fy, fill_factor)
        if sensor_mtf is not None:
            coefficients *= mtf_from_table(np.hypot(fx, fy), sensor_mtf)
        out = scipy.fft.idctn(coefficients, type=2, workers=-1)
    return out


@dataclass(frozen=True)
class Optics:
    """What a camera adds to a render (:func:`apply_optics`): the lens' diffraction at ``f_number`` (None: none),
    ``wavelength_nm``, on pixels of ``pixel_pitch_mm`` whose aperture is ``fill_factor`` of the pitch, and a
    measured ``sensor_mtf`` (``(cycles per px, MTF)`` pairs, or None)."""

    f_number: float | None = None
    wavelength_nm: float = DEFAULT_WAVELENGTH_NM
    pixel_pitch_mm: float = 0.00345
    fill_factor: float = 1.0
    sensor_mtf: tuple | None = None

    def __post_init__(self):
        if self.f_number is not None:
            _positive(self.f_number, "f_number")
        _positive(self.wavelength_nm, "wavelength_nm")
        _positive(self.pixel_pitch_mm, "pixel_pitch_mm")
        if not 0 < self.fill_factor <= 1:
            raise ValueError(f"fill_factor must be in (0, 1], got {self.fill_factor!r}")

    @property
    def ideal(self) -> bool:
        return self.f_number is None and self.fill_factor == 1.0 and self.sensor_mtf is None

    @property
    def airy_radius_px(self) -> float | None:
        return None if self.f_number is None else airy_radius_px(self.f_number, self.wavelength_nm,
                                                                 self.pixel_pitch_mm)

    def apply(self, image: np.ndarray, supersample: int = 1) -> np.ndarray:
        """The recorded image of a render (float64); ideal optics only bin a supersampled one."""
        return apply_optics(image, self.f_number, self.wavelength_nm, self.pixel_pitch_mm, supersample,
                            self.fill_factor, self.sensor_mtf)

    def to_dict(self) -> dict:
        out = {"f_number": self.f_number, "wavelength_nm": self.wavelength_nm, "pixel_pitch_mm": self.pixel_pitch_mm,
               "airy_radius_px": self.airy_radius_px}
        # the pixels' terms only when they act: a dataset's hash of its optics stays what it was without them
        if self.fill_factor != 1.0:
            out["fill_factor"] = self.fill_factor
        if self.sensor_mtf is not None:
            out["sensor_mtf"] = [list(map(float, p)) for p in self.sensor_mtf]
        return out


def _positive(value, name: str) -> float:
    if not (np.isfinite(value) and value > 0):
        raise ValueError(f"{name} must be a positive number, got {value!r}")
    return float(value)


__all__ = ["DEFAULT_WAVELENGTH_NM", "Optics", "airy_radius_px", "apply_optics", "cutoff_cycles_per_px",
           "diffraction_otf", "mtf_from_table", "pixel_aperture_gain"]
