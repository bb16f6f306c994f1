"""Render one camera's view of a set of emissive surfaces: grey image plus per-pixel truth.

The image is radiance times ``exposure_grey`` (grey levels of the final bit depth), before any sensor
noise: apply :mod:`scenes.sensor.noise` afterwards. The truth channels are pixel-footprint averages (box filter)
of the world position and texture coordinates of the visible surface.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from scenes.optics.backend import mi
from scenes.optics.camera import SensorSpec, sensor_dict
from scenes.rendering.integrator import PLUGIN_NAME as INTEGRATOR
from scenes.surfaces.textured_surface import TexturedSurface


@dataclass
class RenderResult:
    """One rendered view.

    Attributes
    ----------
    image_grey : (H, W) float32, noise-free grey levels
    position_world_mm : (H, W, 3) float32 or None, footprint-averaged world position of the visible surface
    uv : (H, W, 2) float32 or None, footprint-averaged texture coordinates
    coverage : (H, W) float32 or None, fraction of the pixel footprint that hits a surface (1 inside)
    crop : (x0, y0, width, height) of the rendered window on the full sensor
    """

    image_grey: np.ndarray
    position_world_mm: np.ndarray | None
    uv: np.ndarray | None
    coverage: np.ndarray | None
    crop: tuple[int, int, int, int]


def render_view(spec: SensorSpec, R_cam_from_world: np.ndarray, t_cam_from_world_mm: np.ndarray,
                surfaces: list[TexturedSurface], *, spp: int = 64, seed: int = 0, exposure_grey: float = 255.0,
                crop: tuple[int, int, int, int] | None = None, truth: bool = False,
                sampler: str = "stratified") -> RenderResult:
    """Render ``surfaces`` as seen by the camera ``spec`` posed at ``X_cam = R X_world + t``.

    Parameters
    ----------
    spp : samples per pixel; ``seed`` seeds the sampler (use a new seed per frame: MC noise is pixel-locked).
    crop : ``(x0, y0, width, height)`` window of the sensor to render (default: all of it).
    truth : also return position/uv/coverage channels.
    """
    if spp < 1:
        raise ValueError(f"spp must be >= 1, got {spp}")
    if not surfaces:
        raise ValueError("nothing to render: no surfaces given")
    scene = {"type": "scene", "integrator": {"type": INTEGRATOR, "truth": bool(truth)},
             "sensor": sensor_dict(spec, R_cam_from_world, t_cam_from_world_mm, spp, seed, crop, sampler)}
    if mi.variant().startswith("llvm"):
        # Embree's default triangle test is not watertight: ~1 ray in 10^6 slips through an edge shared by two
        # triangles of a grid mesh and sees whatever lies behind (~5 % slower when robust; OptiX is watertight).
        scene["embree_use_robust_intersections"] = True
    for i, surface in enumerate(surfaces):
        scene[f"surface_{i}"] = surface.to_mitsuba(f"surface_{i}")
    out = np.array(mi.render(mi.load_dict(scene), spp=spp, seed=seed), dtype=np.float32)
    window = crop if crop is not None else (0, 0, spec.width, spec.height)
    image = out[..., 0] * np.float32(exposure_grey)
    if not truth:
        return RenderResult(image, None, None, None, tuple(int(c) for c in window))
    # Channels: radiance, then TRUTH_CHANNELS; footprint averages include misses as zeros, so divide by
    # coverage to get the mean over the part of the pixel that sees a surface.
    coverage = out[..., 6]
    with np.errstate(invalid="ignore", divide="ignore"):
        pos = np.where(coverage[..., None] > 0, out[..., 1:4] / coverage[..., None], np.nan).astype(np.float32)
        uv = np.where(coverage[..., None] > 0, out[..., 4:6] / coverage[..., None], np.nan).astype(np.float32)
    return RenderResult(image, pos, uv, coverage, tuple(int(c) for c in window))
