"""The twin's lens: what a change of f-number or focus does to the user's images (thin-lens rig only).

A calibration file describes a pinhole camera; the user states the lens's f-number and the pixel pitch
(``--f-number``, ``--pixel-pitch-um``) and the twin takes the lens focused on the specimen plane's centre (its focal
length follows from the calibrated image distance, :func:`scenes.optics.projection.focal_length_for_focus_mm`). Per camera:

* blur: the defocus circle of each pixel's plane point (:func:`scenes.optics.projection.defocus_blur_px`, diameter ``c``; a
  uniform disc has ``sigma = c / 4``) and diffraction (Airy pattern ~ Gaussian ``sigma = 0.42 lambda N``, in pixels
  of the given pitch), added in quadrature;
* light: at the same exposure time the image scales by ``(N0 / N)^2`` (clipped at the sensor's ceiling); the noise
  model (read + shot, grey) is the camera's, so the relative noise grows as the light falls.

A change is applied to the twin's noise-free views: the extra blur ``sqrt(sigma^2 - sigma_0^2)`` (RMS over the
ROI: one Gaussian per image) and the scale. Where the change would make the image *sharper* than the photograph the
twin cannot sharpen it: it applies no blur and says so (the prediction is then conservative).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from scenes.optics.projection import defocus_blur_px, focal_length_for_focus_mm

from .scene import TwinScene

#: Default wavelength of the light, nm (green, the middle of a monochrome sensor's response).
DEFAULT_WAVELENGTH_NM = 550.0
#: Airy pattern's best-fitting Gaussian: sigma = AIRY_SIGMA lambda N (image plane).
AIRY_SIGMA = 0.42


@dataclass(frozen=True)
class Lens:
    """The user's statement of their lenses.

    Attributes
    ----------
    f_number : float
        The f-number the images were taken at.
    pixel_pitch_um : float
        The sensor's pixel pitch, µm.
    wavelength_nm : float
    """

    f_number: float
    pixel_pitch_um: float
    wavelength_nm: float = DEFAULT_WAVELENGTH_NM

    def __post_init__(self):
        for name in ("f_number", "pixel_pitch_um", "wavelength_nm"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a finite number > 0, got {value!r}")


def thin_spec(spec, lens: Lens, pose, focus_point_mm, f_number: float | None = None):
    """The renderer's thin-lens description of a camera focused on ``focus_point_mm`` at ``f_number``."""
    pitch_mm = lens.pixel_pitch_um * 1e-3
    pin = spec.with_(pixel_pitch_mm=pitch_mm)
    F = focal_length_for_focus_mm(pin, pose[0], pose[1], np.asarray(focus_point_mm, float).reshape(1, 3))
    return pin.with_(lens="thin", focal_length_mm=F, f_number=float(f_number or lens.f_number))


def blur_sigma_px(spec, pose, plane_points_mm: np.ndarray, lens: Lens, f_number: float) -> np.ndarray:
    """Gaussian sigma (px) of defocus and diffraction at plane points seen by a thin-lens camera."""
    defocus = defocus_blur_px(spec.with_(f_number=float(f_number)), pose[0], pose[1], plane_points_mm) / 4.0
    diffraction = AIRY_SIGMA * lens.wavelength_nm * 1e-3 * f_number / lens.pixel_pitch_um
    return np.sqrt(defocus ** 2 + diffraction ** 2)


def sample_plane_points(scene: TwinScene, side: str, region: np.ndarray | None, count: int = 4000) -> np.ndarray:
    """Plane points (mm) seen by up to ``count`` pixels of a camera's ROI (the whole image without one)."""
    from scenes.surfaces.image_texture import plane_points

    spec = scene.specs[side]
    valid = scene.valid[side] if region is None else (scene.valid[side] & region)
    rows, cols = np.nonzero(valid)
    if rows.size == 0:
        raise ValueError(f"the {side} twin view shows no texture in the ROI")
    pick = np.linspace(0, rows.size - 1, min(count, rows.size)).astype(np.int64)
    pixels = np.column_stack([cols[pick], rows[pick]]).astype(np.float64)
    return plane_points(spec, scene.rig.pose(side), scene.plane, pixels)


def changed_scene(scene: TwinScene, lens: Lens, regions: dict, *, f_number: float | None = None,
                  focus_shift_mm: float = 0.0, ceiling: float = 255.0) -> tuple[TwinScene, dict]:
    """The twin's views with another f-number and/or the focus moved along each camera's axis (module notes).

    Returns the changed scene and, per camera, ``{"sigma_now_px", "sigma_new_px", "extra_blur_px", "light_factor",
    "sharper"}`` (RMS over the ROI).
    """
    N0 = lens.f_number
    N = float(f_number or N0)
    clean, info = {}, {}
    for side in scene.clean:
        pose = scene.rig.pose(side)
        X = sample_plane_points(scene, side, regions.get(side))
        X = X[np.all(np.isfinite(X), axis=1)]
        centre = np.median(X, axis=0)
        spec_now = thin_spec(scene.specs[side], lens, pose, centre)
        R, t = (np.asarray(a, float) for a in pose)
        camera_centre = -R.T @ t
        axis = (centre - camera_centre) / np.linalg.norm(centre - camera_centre)
        spec_new = thin_spec(scene.specs[side], lens, pose, centre + focus_shift_mm * axis)
        # RMS over the ROI: the parts the change blurs most weigh most
        s0 = float(np.sqrt(np.mean(blur_sigma_px(spec_now, pose, X, lens, N0) ** 2)))
        s1 = float(np.sqrt(np.mean(blur_sigma_px(spec_new, pose, X, lens, N) ** 2)))
        extra = math.sqrt(max(s1 ** 2 - s0 ** 2, 0.0))
        light = (N0 / N) ** 2
        image = scene.clean[side] * light
        if extra > 0.05:
            image = ndimage.gaussian_filter(image, extra, mode="nearest")
        clean[side] = np.minimum(image, ceiling)
        info[side] = {"sigma_now_px": s0, "sigma_new_px": s1, "extra_blur_px": extra, "light_factor": light,
                      "sharper": s1 < 0.99 * s0}
    return TwinScene(scene.plane, clean, scene.valid, scene.specs, scene.rig), info
