"""The twin's scene: the user's photographed speckle on a plane in front of their rig, rendered with their noise.

This module writes truth (images of a known, unmoved or known-moved surface) and does not import the
instrument; the rig comes in as the workbench's :class:`workbench.rigs.StereoRig` (built from the user's
calibration file) and the plane as a point and a normal.

* The plane: through the measured reference points when the user gave a right image (total least squares; the
  instrument's triangulation of their own pair, done by the caller), else through the point where the two
  optical axes meet (or at the working distance on the left optical axis), facing the cameras.
* The texture: the left reference image (the mean of the left static pair when there is one: half the noise),
  painted onto the plane through the left camera (:mod:`scenes.surfaces.image_texture`). The left twin view of the plane
  at rest is therefore the photograph itself; the right view is that pattern as the right camera sees the plane,
  scaled to the right image's own mean and contrast over the ROI (lighting differs between cameras; their optics
  are taken equal, which is stated in the report).
* Noise: each camera's :class:`measurement.speckle_quality.NoiseModel` (read + shot noise, grey) drawn with
  ``SeedSequence([seed, camera, draw])``, rounded and clipped to the image's bit depth.
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from scenes.rendering.render import render_views
from scenes.surfaces.image_texture import ImageTexture, TexturedPlane
from scenes.sensor.noise import apply_sensor_noise

from ..experiments.calibration.views import camera_to_sensor_spec


def twin_rig(rig):
    """The rig the twin renders and measures with: the user's, with any skew set to 0 (the renderer has none).

    Returns
    -------
    rig : StereoRig
    skews : dict
        ``{"left": skew_px, "right": skew_px}`` that were dropped (0.0 where there was none).
    """
    skews = {side: float(rig.camera(side).skew) for side in ("left", "right")}
    return replace(rig, left=replace(rig.left, skew=0.0), right=replace(rig.right, skew=0.0)), skews


def plane_through_points(X_mm: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Total-least-squares plane ``(point_mm, normal)`` through finite points (normal towards the cameras)."""
    X = np.asarray(X_mm, dtype=np.float64)
    X = X[np.all(np.isfinite(X), axis=1)]
    if X.shape[0] < 3:
        raise ValueError(f"only {X.shape[0]} measured reference points: a plane needs at least 3")
    c = X.mean(axis=0)
    normal = np.linalg.svd(X - c, full_matrices=False)[2][-1]
    if normal @ c > 0:          # face the left camera at the origin
        normal = -normal
    return c, normal


def default_plane(rig) -> tuple[np.ndarray, np.ndarray]:
    """The plane where the optical axes meet, its normal bisecting the two viewing directions."""
    point = np.asarray(rig.optical_axes_meeting_point_mm(), dtype=np.float64)
    if not (np.all(np.isfinite(point)) and point[2] > 0):
        point = np.array([0.0, 0.0, float(rig.working_distance_mm)])
    to_left = rig.camera_centre_mm("left") - point
    to_right = rig.camera_centre_mm("right") - point
    normal = to_left / np.linalg.norm(to_left) + to_right / np.linalg.norm(to_right)
    return point, normal / np.linalg.norm(normal)


@dataclass(frozen=True, eq=False)
class TwinScene:
    """Noise-free twin views of the plane at rest, and what made them.

    Attributes
    ----------
    plane : TexturedPlane
    clean : dict
        ``{"left": image, "right": image}`` float64 grey (right absent for a one-camera twin).
    valid : dict
        Where each view shows the texture.
    specs : dict
        The renderer's description of each camera.
    rig : StereoRig or None
        The rig rendered (skew dropped).
    """

    plane: TexturedPlane | None
    clean: dict
    valid: dict
    specs: dict
    rig: object = None


def contrast_matched(image: np.ndarray, valid: np.ndarray, target: np.ndarray, region: np.ndarray) -> np.ndarray:
    """``image`` scaled so that its mean and standard deviation over ``region & valid`` equal ``target``'s over
    ``region`` (the right camera's own lighting)."""
    sel = region & valid
    if sel.sum() < 100 or region.sum() < 100:
        return image
    a, b = image[sel], target[region]
    scale = b.std() / a.std() if a.std() > 0 else 1.0
    return (image - a.mean()) * scale + b.mean()


def build_stereo_scene(rig, texture_image: np.ndarray, plane_point_mm, plane_normal, *,
                       right_target: np.ndarray | None = None, right_region: np.ndarray | None = None,
                       displacement_mm=None) -> TwinScene:
    """Render both cameras' noise-free views of the user's pattern on a plane (module notes).

    Parameters
    ----------
    rig : StereoRig
        The twin rig (:func:`twin_rig`).
    texture_image : ndarray, shape (height, width) of the left camera
    plane_point_mm, plane_normal : array, shape (3,)
        Left camera frame.
    right_target, right_region : ndarray, optional
        The user's right image and the region over which the right view takes its mean and contrast.
    displacement_mm : callable, optional
        A displacement of the plane's material points (``X (N, 3) -> u (N, 3)`` mm), e.g. a rigid shift.
    """
    specs = {side: camera_to_sensor_spec(rig.camera(side), rig.pixel_pitch_mm) for side in ("left", "right")}
    plane = TexturedPlane(np.asarray(plane_point_mm, float), np.asarray(plane_normal, float),
                          ImageTexture.from_image(texture_image), specs["left"], rig.pose("left"))
    sides = ("left", "right")
    made = render_views([(specs[side], rig.pose(side)) for side in sides], plane, displacement_mm=displacement_mm)
    clean = {side: view.image_grey for side, view in zip(sides, made)}
    valid = {side: view.valid for side, view in zip(sides, made)}
    if right_target is not None:
        region = right_region if right_region is not None else np.ones(right_target.shape, bool)
        clean["right"] = contrast_matched(clean["right"], valid["right"], np.asarray(right_target, float), region)
    return TwinScene(plane, clean, valid, specs, rig)


def noisy(image: np.ndarray, noise, bit_depth: int, seed: int, camera: int, draw: int) -> np.ndarray:
    """One noisy exposure of a noise-free twin view: the camera's noise model, rounded and clipped to
    ``[0, 2**bit_depth - 1]`` (float32 grey levels)."""
    rng_seed = int(np.random.SeedSequence([int(seed), int(camera), int(draw)]).generate_state(1)[0])
    ceiling = 2 ** int(bit_depth) - 1
    clean = np.clip(np.asarray(image, dtype=np.float64), 0.0, ceiling)
    gain = noise.electrons_per_grey if noise.electrons_per_grey else None
    # The model's read noise holds the quantisation of the images it was measured on; rounding adds it again.
    read = float(np.sqrt(max(noise.read_noise_grey ** 2 - 1.0 / 12.0, 0.0)))
    out = apply_sensor_noise(clean, read_noise_grey=read, electrons_per_grey=gain, bit_depth=None, seed=rng_seed)
    return np.clip(np.rint(out), 0, ceiling).astype(np.float32)
