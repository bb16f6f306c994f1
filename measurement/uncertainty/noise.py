"""Each camera's noise from a static pair, measured the way the instrument measures everything else.

A static pair is a second exposure of the unmoved reference scene. Its difference with the reference holds twice
the sensor noise (:func:`measurement.speckle_quality.noise_from_static_pair`), once any common motion of the
image between the exposures (a few thousandths of a pixel on real rigs) is undone; the motion is what the
instrument's own matches say. A pair whose images moved by more than ``max_motion_px`` is refused: it is not a
static pair, and its difference would read motion as noise.
"""
from __future__ import annotations

import numpy as np
from scipy import ndimage

from measurement.speckle_quality import NoiseModel, noise_from_static_pair

#: Largest common motion (px) between the exposures of a "static" pair that is undone rather than refused.
MAX_STATIC_MOTION_PX = 0.5


class StaticPairError(ValueError):
    """The "static" pair moved (or cannot be measured): its noise figure would not be the camera's."""


def _subset_region(shape: tuple[int, int], x, y, subset_px: int) -> np.ndarray:
    """The pixels the subsets centred at (x, y) cover (where the noise matters)."""
    points = np.zeros(shape, dtype=bool)
    x, y = np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64)
    ok = np.isfinite(x) & np.isfinite(y)
    xi, yi = np.rint(x[ok]).astype(np.int64), np.rint(y[ok]).astype(np.int64)
    inside = (xi >= 0) & (yi >= 0) & (xi < shape[1]) & (yi < shape[0])
    points[yi[inside], xi[inside]] = True
    return ndimage.maximum_filter(points, size=int(subset_px)) if points.any() else np.ones(shape, dtype=bool)


def _mean_motion(u: np.ndarray, v: np.ndarray, what: str, max_motion_px: float) -> tuple[float, float]:
    ok = np.isfinite(u) & np.isfinite(v)
    if ok.sum() < 10:
        raise StaticPairError(f"{what}: only {int(ok.sum())} points matched between the static pair's exposures")
    motion = (float(np.median(u[ok])), float(np.median(v[ok])))
    if np.hypot(*motion) > max_motion_px:
        raise StaticPairError(f"{what} moved by ({motion[0]:.3f}, {motion[1]:.3f}) px between the exposures (more "
                              f"than {max_motion_px:g} px): not a static pair; give two exposures of the unmoved "
                              "specimen")
    return motion


def static_pair_noise_2d(reference: np.ndarray, static: np.ndarray, result, *,
                         max_motion_px: float = MAX_STATIC_MOTION_PX, what: str = "the static image") -> NoiseModel:
    """The camera's noise from a static pair, given the instrument's match ``result`` of reference -> static.

    Raises
    ------
    StaticPairError
        The pair moved by more than ``max_motion_px`` or too few points matched.
    """
    motion = _mean_motion(result.u, result.v, what, max_motion_px)
    region = _subset_region(np.asarray(reference).shape, result.x, result.y, result.settings.subset_size)
    return noise_from_static_pair(reference, static, region, motion_xy_px=motion)


def static_pair_noise_stereo(shape, static_state, left_ref: np.ndarray, right_ref: np.ndarray,
                             left_static: np.ndarray, right_static: np.ndarray, *,
                             max_motion_px: float = MAX_STATIC_MOTION_PX) -> dict[str, NoiseModel]:
    """Both cameras' noise from a stereo static pair: ``{"left": NoiseModel, "right": NoiseModel}``.

    ``static_state`` is the instrument's :func:`measurement.stereo_dic.measure_state` of the static pair against
    ``shape``: its left temporal match gives the left image's motion, its right match less the shape's stereo match
    the right image's.
    """
    lm = static_state.left_match
    left_motion = _mean_motion(lm.u, lm.v, "the left static image", max_motion_px)
    rm, sm = shape.right_match, static_state.right_match
    right_motion = _mean_motion(sm.u - rm.u, sm.v - rm.v, "the right static image", max_motion_px)
    subset = rm.settings.subset_size
    left_region = _subset_region(np.asarray(left_ref).shape, lm.x, lm.y, subset)
    right_region = _subset_region(np.asarray(right_ref).shape, rm.x + rm.u, rm.y + rm.v, subset)
    return {"left": noise_from_static_pair(left_ref, left_static, left_region, motion_xy_px=left_motion),
            "right": noise_from_static_pair(right_ref, right_static, right_region, motion_xy_px=right_motion)}
