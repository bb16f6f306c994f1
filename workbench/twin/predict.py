"""The twin's predictions: the instrument run on the twin's images, and the instrument's own sigma beside it.

* :func:`twin_static_noise` -- ``repeats`` static pairs of the twin (fresh noise draws of each camera's noise
  model), each measured by :mod:`workbench.twin.measure` exactly as the real pair is; pooled over repeats
  (root mean square of the per-repeat standard deviations) and per point (standard deviation over repeats).
  Each repeat's reference is measured with the cameras' noise models, so each also carries the instrument's
  predicted static sigma (:mod:`measurement.uncertainty`; one implementation, the instrument's: the twin only
  arranges the scene), pooled the same way (:attr:`PooledNoise.instrument_sigma`, :attr:`PooledNoise.sigma_map`).
* :func:`interpolation_bias_px` -- the instrument's bias on the user's pattern: sub-pixel translations of the
  band-limited pattern (Fourier shift of a mirrored crop, exact for a band-limited image), noise-free.
* :func:`spatial_resolution` -- l10 (DIC Challenge 2.0) of the user's settings on the user's pattern: the Star
  displacement imposed on their left image (:mod:`scenes.surfaces.image_texture`), measured with their subset and order
  (:func:`workbench.experiments.dic2d.star.run_star`).
"""
from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field, replace

import numpy as np

from measurement.dic import DICSettings, correlate
from scenes.surfaces.image_texture import ImageTexture, render_deformed_image
from scenes.image_pairs.star import StarImages, star_displacement_for_shape
from scenes.image_pairs.fourier_shift import fourier_shift

from ..experiments.dic2d.star import run_star
from .measure import StaticNoise, static_noise_2d, static_noise_stereo
from .scene import noisy


@dataclass
class PooledNoise:
    """Static noise of several twin repeats.

    Attributes
    ----------
    noise, strain_ue, detrended : dict
        RMS over repeats of each repeat's figure (µm / px / µε).
    per_point : ndarray, shape (N, 3) or (N, 2)
        Standard deviation over repeats at each point (NaN with fewer than 2 valid repeats).
    runs : list of StaticNoise
    instrument_sigma : dict
        RMS over repeats of each repeat's instrument sigma (its RMS over the measured points), keys of ``noise``;
        empty when the repeats were measured without noise models.
    sigma_map : ndarray, shape (N, 3) or (N, 2), or None
        The instrument's predicted sigma per point, RMS over repeats (µm or px).
    """

    noise: dict
    strain_ue: dict
    detrended: dict
    per_point: np.ndarray = field(repr=False)
    runs: list = field(repr=False, default_factory=list)
    instrument_sigma: dict = field(default_factory=dict)
    sigma_map: np.ndarray | None = field(default=None, repr=False)

    @property
    def x_px(self):
        return self.runs[0].x_px

    @property
    def y_px(self):
        return self.runs[0].y_px


def pool(runs: list[StaticNoise]) -> PooledNoise:
    """RMS over repeats of each figure, and the per-point spread."""
    def rms(key: str) -> dict:
        names = getattr(runs[0], key).keys()
        return {n: float(np.sqrt(np.nanmean([getattr(r, key).get(n, math.nan) ** 2 for r in runs]))) for n in names}

    stack = np.stack([r.values for r in runs])
    count = np.sum(np.isfinite(stack), axis=0)
    with np.errstate(invalid="ignore", divide="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)       # points no repeat measured: NaN, as they should be
        mean = np.nanmean(stack, axis=0) if len(runs) > 1 else stack[0]
        per_point = np.sqrt(np.nansum((stack - mean) ** 2, axis=0) / np.maximum(count - 1, 1))
    per_point = np.where(count >= 2, per_point, np.nan)
    sigma_map = None
    if all(r.sigma is not None for r in runs):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)   # points with no sigma in any repeat stay NaN
            sigma_map = np.sqrt(np.nanmean(np.stack([r.sigma for r in runs]) ** 2, axis=0))
    return PooledNoise(rms("noise"), rms("strain_ue"), rms("detrended"), per_point, runs,
                       rms("instrument_sigma") if sigma_map is not None else {}, sigma_map)


def draws(scene, noise_models: dict, bit_depth: int, seed: int, repeat: int) -> dict:
    """The four (or two) noisy images of twin static pair ``repeat``."""
    out = {}
    for camera, side in enumerate(("left", "right")):
        if side not in scene.clean:
            continue
        out[f"{side}"] = noisy(scene.clean[side], noise_models[side], bit_depth, seed, camera, 2 * repeat)
        out[f"static_{side}"] = noisy(scene.clean[side], noise_models[side], bit_depth, seed, camera, 2 * repeat + 1)
    return out


def twin_static_noise(scene, noise_models: dict, bit_depth: int, settings: DICSettings, *, roi=None, mask=None,
                      strain_window: int | None = 5, repeats: int = 2, seed: int = 0, progress=None) -> PooledNoise:
    """Measure ``repeats`` twin static pairs with the instrument and pool them (module notes); the instrument
    is given ``noise_models`` (the ones the twin's noise is drawn from) for its predicted sigma."""
    runs = []
    for r in range(int(repeats)):
        images = draws(scene, noise_models, bit_depth, seed, r)
        if "right" in images:
            runs.append(static_noise_stereo(scene.rig, images["left"], images["right"], images["static_left"],
                                            images["static_right"], settings, roi=roi, mask=mask,
                                            strain_window=strain_window, noise=noise_models))
        else:
            runs.append(static_noise_2d(images["left"], images["static_left"], settings, roi=roi, mask=mask,
                                        strain_window=strain_window, noise=noise_models["left"]))
        if progress is not None:
            progress(f"twin static pair {r + 1}/{repeats}")
    return pool(runs)


def _mirrored(crop: np.ndarray) -> np.ndarray:
    top = np.concatenate([crop, crop[:, ::-1]], axis=1)
    return np.concatenate([top, top[::-1]], axis=0)


def interpolation_bias_px(image: np.ndarray, region: np.ndarray, settings: DICSettings, *, crop_px: int = 256,
                          shifts_px=(0.1, 0.2, 0.3, 0.4, 0.5)) -> dict:
    """Systematic error of the instrument on sub-pixel translations of the user's pattern (noise-free).

    A ``crop_px`` square from the middle of the region is mirrored into a periodic tile (no edge jumps) and
    Fourier-shifted by each of ``shifts_px`` along x and along y; the mean error of u (resp. v) over the crop's
    points at each shift is the bias curve. Returns ``{"max_abs_px", "shifts_px", "bias_x_px", "bias_y_px"}``.
    """
    rows, cols = np.nonzero(region)
    cy, cx = int(np.median(rows)), int(np.median(cols))
    size = int(min(crop_px, image.shape[0], image.shape[1]))
    y0 = int(np.clip(cy - size // 2, 0, image.shape[0] - size))
    x0 = int(np.clip(cx - size // 2, 0, image.shape[1] - size))
    crop = np.asarray(image[y0:y0 + size, x0:x0 + size], dtype=np.float64)
    tile = _mirrored(crop)
    base = fourier_shift(tile, (0.0, 0.0))[:size, :size]
    margin = settings.subset_size // 2 + 4
    roi = (margin, margin, size - margin, size - margin)
    if roi[2] <= roi[0] or roi[3] <= roi[1]:
        return {"max_abs_px": math.nan, "shifts_px": [], "bias_x_px": [], "bias_y_px": []}
    bx, by = [], []
    for s in shifts_px:
        for axis, store in ((0, bx), (1, by)):
            shift = (s, 0.0) if axis == 0 else (0.0, s)
            moved = fourier_shift(tile, shift)[:size, :size]
            res = correlate(base, moved, replace(settings, step=max(settings.step, 8)),
                            roi=roi, initial_parameters=lambda x, y: (0.0 * x + shift[0], 0.0 * y + shift[1]))
            comp = res.u if axis == 0 else res.v
            ok = res.converged & np.isfinite(comp)
            store.append(float(np.mean(comp[ok]) - s) if ok.any() else math.nan)
    values = np.abs(np.array(bx + by, dtype=np.float64))
    return {"max_abs_px": float(np.nanmax(values)) if np.isfinite(values).any() else math.nan,
            "shifts_px": list(map(float, shifts_px)), "bias_x_px": bx, "bias_y_px": by}


def spatial_resolution(image: np.ndarray, region: np.ndarray, settings: DICSettings, noise_model, bit_depth: int,
                       *, seed: int = 0, max_shape=(301, 1200)) -> dict:
    """l10 of the user's settings on the user's pattern (module notes), px; with the Star curve."""
    rows, cols = np.nonzero(region)
    r0, r1, c0, c1 = rows.min(), rows.max() + 1, cols.min(), cols.max() + 1
    h = min(r1 - r0, max_shape[0])
    w = min(c1 - c0, max_shape[1])
    h -= 1 - h % 2                                           # odd rows: a middle crest row
    cy, cx = (r0 + r1) // 2, (c0 + c1) // 2
    y0 = int(np.clip(cy - h // 2, 0, image.shape[0] - h))
    x0 = int(np.clip(cx - w // 2, 0, image.shape[1] - w))
    crop = np.asarray(image[y0:y0 + h, x0:x0 + w], dtype=np.float64)
    if min(crop.shape) < settings.subset_size + 16:
        return {"l10_px": math.nan, "reason": f"the ROI ({w} x {h} px) is too small for a Star field"}
    truth = star_displacement_for_shape(crop.shape)
    texture = ImageTexture.from_image(crop)
    deformed, _ = render_deformed_image(texture, truth)

    # The photographed pattern carries its own noise; each Star image gets one more draw of the camera's.
    ref = noisy(crop, noise_model, bit_depth, seed, 7, 0)
    de = noisy(deformed, noise_model, bit_depth, seed, 7, 1)
    st = noisy(crop, noise_model, bit_depth, seed, 7, 2)
    metrics = run_star(settings.subset_size, settings.order, images=StarImages(ref, de, st, truth),
                       step_px=min(settings.step, 4))
    return {"l10_px": float(metrics["l10_px"]), "l10_theory_px": float(metrics.get("l10_theory_px", math.nan)),
            "noise_floor_px": float(metrics["noise_floor_px"]), "curve_period_px": metrics["curve_period_px"],
            "curve_ratio": metrics["curve_ratio"], "crop": [int(x0), int(y0), int(w), int(h)]}
