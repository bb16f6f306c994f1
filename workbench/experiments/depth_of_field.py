"""Depth of field: a Scheimpflug-tilted sensor keeps an oblique specimen sharp; an untilted one does not.

The paper (§4.1, Fig 4) compares the MIG of speckle images from the Scheimpflug camera (16.88) and from the
same camera without tilt (8.78). Here both cameras share the lens (focal length F, f-number N) and the image
distance ``v = fx * pixel_pitch``; the plate is rotated about the camera Y axis by ``object_tilt_deg`` around
the on-axis point in focus. The tilted camera's sensor angle comes from the thin-lens focus condition
(:func:`scheimpflug_sensor_tilt_deg`), not from the renderer.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import brentq

from measurement.image_quality import mean_intensity_gradient
from scenes.camera import SensorSpec
from scenes.render import render_view
from scenes.specimens import SpeckledPlate


def _focus_slope(beta_rad: float, image_distance_mm: float, focal_length_mm: float, ds: float = 1e-3) -> float:
    """dZ/dX of the in-focus object line in the camera XZ plane for a sensor tilted by beta about Y."""
    pts = []
    for s in (-ds, ds):
        px, pz = s * np.cos(beta_rad), 1.0 - s * np.sin(beta_rad)   # tilted sensor point, units of v
        z_image = image_distance_mm * pz
        z_object = 1.0 / (1.0 / focal_length_mm - 1.0 / z_image)
        pts.append((px / pz * z_object, z_object))
    (x0, z0), (x1, z1) = pts
    return (z1 - z0) / (x1 - x0)


def scheimpflug_sensor_tilt_deg(object_tilt_deg: float, image_distance_mm: float, focal_length_mm: float) -> float:
    """Sensor tilt beta (about Y) that puts the plane of sharp focus on a plane rotated by ``object_tilt_deg``.

    A plane rotated about the camera Y axis by theta has dZ/dX = -tan(theta) in the camera frame.
    """
    target = -np.tan(np.deg2rad(object_tilt_deg))
    f = lambda b: _focus_slope(b, image_distance_mm, focal_length_mm) - target  # noqa: E731
    return float(np.rad2deg(brentq(f, -np.deg2rad(30), np.deg2rad(30), xtol=1e-12)))


@dataclass
class DepthOfFieldResult:
    sensor_tilt_deg: float
    mig_scheimpflug: float
    mig_conventional: float
    image_scheimpflug: np.ndarray
    image_conventional: np.ndarray

    @property
    def mig_ratio(self) -> float:
        return self.mig_scheimpflug / self.mig_conventional


def run_depth_of_field(fx: float = 10912.0, width: int = 2456, height: int = 2058, scale: float = 1.0,
                       pixel_pitch_mm: float = 0.00345, distance_mm: float = 376.0, object_tilt_deg: float = 35.0,
                       f_number: float = 4.0, speckle_px: float = 5.0, texels_per_px: float = 2.5, spp: int = 64,
                       seed: int = 0) -> DepthOfFieldResult:
    """Render an oblique speckled plate through a Scheimpflug and an untilted thin-lens camera; compare MIG.

    ``scale`` shrinks the image and fx together and grows the pixel pitch (same optics, coarser sensor).
    The MIG is taken over the central 80 % of each image (the plate fills the view).
    """
    fx_s, w, h, pitch = fx * scale, int(round(width * scale)), int(round(height * scale)), pixel_pitch_mm / scale
    v = fx_s * pitch
    F = 1.0 / (1.0 / v + 1.0 / distance_mm)         # on-axis focus at the plate's centre
    beta = scheimpflug_sensor_tilt_deg(object_tilt_deg, v, F)
    px_mm = distance_mm / fx_s                          # pixel footprint at the plate centre
    theta = np.deg2rad(object_tilt_deg)
    plate_w = 1.3 * w * px_mm / np.cos(theta)
    plate = SpeckledPlate(width_mm=plate_w, height_mm=1.3 * h * px_mm, texel_mm=px_mm / texels_per_px,
                          speckle_mm=speckle_px * px_mm, seed=seed)
    R_plate = np.array([[np.cos(theta), 0, np.sin(theta)], [0, 1, 0], [-np.sin(theta), 0, np.cos(theta)]])
    texture = plate.texture()
    surface = plate.surface(R_plate, [0.0, 0.0, distance_mm], texture)
    images = {}
    for name, tilt in (("scheimpflug", beta), ("conventional", 0.0)):
        spec = SensorSpec(fx=fx_s, fy=fx_s, cx=(w - 1) / 2, cy=(h - 1) / 2, width=w, height=h, beta_deg=tilt,
                          lens="thin", focal_length_mm=F, f_number=f_number, pixel_pitch_mm=pitch)
        images[name] = render_view(spec, np.eye(3), np.zeros(3), [surface], spp=spp, seed=seed + 1).image_grey
    mask = np.zeros((h, w), bool)
    mask[int(0.1 * h):int(0.9 * h), int(0.1 * w):int(0.9 * w)] = True
    return DepthOfFieldResult(beta, mean_intensity_gradient(images["scheimpflug"], mask),
                              mean_intensity_gradient(images["conventional"], mask),
                              images["scheimpflug"], images["conventional"])
