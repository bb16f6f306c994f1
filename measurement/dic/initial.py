"""Initial guesses for IC-GN: a ZNCC search for seed points, and the seed type other guessers produce.

IC-GN converges only from a guess within a fraction of a speckle of the answer. Reliability-guided
propagation (:mod:`.guide`) gives every point its converged neighbour's warp, so only a few *seeds* need a
guess from scratch. Here that guess is an exhaustive ZNCC search (``cv2.matchTemplate`` with
``TM_CCOEFF_NORMED``, i.e. zero-normalised cross-correlation over every integer displacement in a window),
repeated for the reference subset rotated by a set of angles so that large rotations are found too; the
best peak is refined to sub-pixel by a parabola through its neighbours.

Other sources of guesses (feature matches, epipolar geometry for stereo, a user's displacement field) only
need to produce :class:`Seed` objects (or per-point parameters, see :func:`measurement.dic.correlate`).
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from .shape_functions import N_PARAMETERS

#: Rotation angles (deg) tried by default for a seed: the search handles any rotation within +-45 deg.
DEFAULT_SEED_ANGLES_DEG = tuple(float(a) for a in range(-45, 46, 5))


@dataclass(frozen=True)
class Seed:
    """An initial guess at one point of interest.

    Attributes
    ----------
    x, y : int
        Reference POI (column, row), px.
    parameters : ndarray of float64, shape (12,)
        Shape-function parameters (see :mod:`.shape_functions`); a translation guess has only u, v.
    zncc : float
        Score of the guess (NaN if unknown).
    """

    x: int
    y: int
    parameters: np.ndarray
    zncc: float = float("nan")


def translation_parameters(u_px: float, v_px: float) -> np.ndarray:
    """12-vector of a pure translation."""
    p = np.zeros(N_PARAMETERS)
    p[0] = u_px
    p[6] = v_px
    return p


def rotation_parameters(u_px: float, v_px: float, angle_deg: float) -> np.ndarray:
    """12-vector of a rigid rotation by ``angle_deg`` (+x towards +y) plus a translation, about the POI."""
    p = translation_parameters(u_px, v_px)
    a = np.deg2rad(angle_deg)
    p[1] = np.cos(a) - 1.0
    p[2] = -np.sin(a)
    p[7] = np.sin(a)
    p[8] = np.cos(a) - 1.0
    return p


def _subpixel_peak(score: np.ndarray, row: int, col: int) -> tuple[float, float]:
    """Parabolic sub-pixel offset of a correlation peak (0 at the border of the score map)."""
    def offset(minus, centre, plus):
        denominator = minus - 2.0 * centre + plus
        return 0.0 if denominator >= 0 else float(np.clip(0.5 * (minus - plus) / denominator, -0.5, 0.5))

    dx = dy = 0.0
    if 0 < col < score.shape[1] - 1:
        dx = offset(score[row, col - 1], score[row, col], score[row, col + 1])
    if 0 < row < score.shape[0] - 1:
        dy = offset(score[row - 1, col], score[row, col], score[row + 1, col])
    return dx, dy


def zncc_search(reference: np.ndarray, deformed: np.ndarray, x: int, y: int, half: int, search_radius_px: int,
                centre_guess_px: tuple[float, float] = (0.0, 0.0),
                angles_deg: tuple[float, ...] = (0.0,), accept_zncc: float = 0.9) -> Seed | None:
    """Exhaustive ZNCC search for the subset at ``(x, y)`` within a window of the deformed image.

    Parameters
    ----------
    reference, deformed : ndarray, shape (rows, cols)
        Grey images (float32-convertible).
    x, y : int
        Reference POI (column, row), px.
    half : int
        M; the subset is (2M + 1) px square.
    search_radius_px : int
        Displacements within ``centre_guess +- search_radius_px`` in x and y are searched.
    centre_guess_px : (u, v)
        Centre of the search window, px.
    angles_deg : tuple of float
        Rotations of the reference subset to try (deg, +x towards +y).
    accept_zncc : float
        The unrotated subset is tried first; if its best match reaches this ZNCC the other angles are skipped
        (a subset that matches that well unrotated is turned by a few degrees at most, which IC-GN takes from
        a translation). Set above 1 to always try every angle.

    Returns
    -------
    Seed or None
        Best match (translation and rotation in its parameters, ZNCC as score), or None when the subset or the
        whole search window leaves the image.
    """
    rows, cols = reference.shape
    # Template: the reference subset, or for a rotation the subset resampled on the rotated grid. The
    # rotated template needs pixels out to M * sqrt(2) around the POI.
    reach = int(np.ceil(half * np.sqrt(2.0))) + 2 if any(a != 0.0 for a in angles_deg) else half
    if x - reach < 0 or y - reach < 0 or x + reach >= cols or y + reach >= rows:
        return None
    cu, cv = int(round(centre_guess_px[0])), int(round(centre_guess_px[1]))
    wx0 = max(x + cu - search_radius_px - half, 0)
    wy0 = max(y + cv - search_radius_px - half, 0)
    wx1 = min(x + cu + search_radius_px + half + 1, cols)
    wy1 = min(y + cv + search_radius_px + half + 1, rows)
    size = 2 * half + 1
    if wx1 - wx0 < size or wy1 - wy0 < size:
        return None
    window = np.ascontiguousarray(deformed[wy0:wy1, wx0:wx1], dtype=np.float32)
    patch = np.ascontiguousarray(reference[y - reach:y + reach + 1, x - reach:x + reach + 1], dtype=np.float32)
    best = None
    # 0 deg first (if asked for), so that a good unrotated match can end the search.
    ordered = sorted(angles_deg, key=lambda a: a != 0.0)
    for angle in ordered:
        if angle == 0.0:
            template = patch[reach - half:reach + half + 1, reach - half:reach + half + 1]
        else:
            # The deformed image shows the subset turned by +angle, g(R d) = f(d): the template samples the
            # reference at R(-angle) d. OpenCV's matrix for angle a is R(-a) in our x-right, y-down convention
            # and warpAffine samples src at M^-1 d, hence -angle.
            rotation = cv2.getRotationMatrix2D((float(reach), float(reach)), -float(angle), 1.0)
            turned = cv2.warpAffine(patch, rotation, (patch.shape[1], patch.shape[0]), flags=cv2.INTER_CUBIC)
            template = turned[reach - half:reach + half + 1, reach - half:reach + half + 1]
        # flat template (interpolation of a constant patch leaves only rounding noise): nothing to match
        if float(template.std()) <= 1e-6 * (abs(float(template.mean())) + 1.0):
            continue
        score = cv2.matchTemplate(window, np.ascontiguousarray(template), cv2.TM_CCOEFF_NORMED)
        _, peak, _, (col, row) = cv2.minMaxLoc(score)
        if best is None or peak > best[0]:
            best = (peak, row, col, angle, score)
        if angle == 0.0 and peak >= accept_zncc:
            break
    if best is None or not np.isfinite(best[0]):
        return None
    peak, row, col, angle, score = best
    dx, dy = _subpixel_peak(score, row, col)
    u = wx0 + col + dx + half - x
    v = wy0 + row + dy + half - y
    return Seed(int(x), int(y), rotation_parameters(u, v, angle), float(peak))
