"""The quadrature rule of a thin-lens pixel, measured on the view's own texture (truth side, no Monte Carlo).

A defocused pixel is a 4-D integral over its square on the sensor and the aperture disc
(:mod:`scenes.rendering.defocus_quadrature`). Its product rule -- ``n_p x n_p`` Gauss-Legendre nodes on the pixel,
``n_r`` rings Gauss-Legendre in ``r^2`` on the disc (the uniform measure Mitsuba samples), ``n_t`` angles on the
outer ring and fewer inwards -- grows with the blur radius, so it is **measured, not assumed**: per blur bin,
candidate rules (:func:`thin_lens_rule`) are run on the texture at its finest scale on the sensor against a rule a
few times denser, and the cheapest within ``tolerance_grey`` RMS is chosen (:func:`choose_rule`); the choice is
cached per texture (:func:`texture_fingerprint`) and Jacobian.
"""
from __future__ import annotations

import functools
import math
import zlib

import numba
import numpy as np

from scenes.rendering.thin_lens_rays import bilinear_lookup

#: Default largest RMS error of a bin's rule against the dense rule, grey levels. The whole view's error
#: against converged Mitsuba follows it (full resolution, benchmarks/render_defocus.py: 0.023 grey RMS at
#: 0.03 and 5.8 s, 0.035 at 0.05 and 5.3 s, 0.050 at 0.08 and 4.8 s): 0.08 keeps it within the 0.1 grey
#: bound of a deterministic render with a factor of 2 to spare.
DEFAULT_TOLERANCE_GREY = 0.08
#: Texture points and dense-rule density (nodes per texture detail length) of a bin's calibration.
CALIBRATION_POINTS = 160
DENSE_NODES_PER_DETAIL = 4.0


# --- the rule ---------------------------------------------------------------------------------------------
@functools.lru_cache(maxsize=64)
def _gauss_legendre_unit(n: int) -> tuple[np.ndarray, np.ndarray]:
    x, w = np.polynomial.legendre.leggauss(int(n))
    return 0.5 * (x + 1.0), 0.5 * w


def _ring_angles(n_rings: int, n_angles: int) -> list[int]:
    """Angles on each ring: ``n_angles`` on the outermost, fewer inwards in proportion to the radius (the
    texture a ring crosses is as long as its circumference)."""
    s, _ = _gauss_legendre_unit(n_rings)
    r = np.sqrt(s)
    return [max(1, math.ceil(n_angles * rk / r[-1] - 1e-9)) for rk in r]


def rule_size(n_pixel: int, n_rings: int, n_angles: int) -> int:
    """Nodes of :func:`thin_lens_rule`."""
    return n_pixel * n_pixel * sum(_ring_angles(n_rings, n_angles))


@functools.lru_cache(maxsize=1024)
def thin_lens_rule(n_pixel: int, n_rings: int, n_angles: int) -> np.ndarray:
    """Nodes of the product rule over the unit pixel square and the unit disc (module notes).

    ``n_angles`` is the count on the outermost ring; ring k has ``ceil(n_angles r_k / r_outer)``.

    Returns
    -------
    (:func:`rule_size`, 5) float, read-only: pixel position (px, py) in [0, 1]^2 from the pixel's top-left
    corner, aperture position (ax, ay) on the unit disc, weight (the weights sum to 1).
    """
    if min(n_pixel, n_rings, n_angles) < 1:
        raise ValueError(f"rule sizes must be >= 1, got {n_pixel}, {n_rings}, {n_angles}")
    xs, ws = _gauss_legendre_unit(n_pixel)
    s, wr = _gauss_legendre_unit(n_rings)
    per_ring = _ring_angles(n_rings, n_angles)
    m = n_pixel * n_pixel
    j = np.arange(m)
    jx, jy = j % n_pixel, j // n_pixel
    rings = []                                   # per ring (m, na, 5): pixel node j, then the ring's angles
    for k in range(n_rings):
        na = per_ring[k]
        theta = 2 * np.pi * (np.arange(na)[None, :] + 0.5 * (k % 2) + (j / m)[:, None]) / na
        r = math.sqrt(s[k])
        block = np.empty((m, na, 5))
        block[:, :, 0] = xs[jx][:, None]
        block[:, :, 1] = xs[jy][:, None]
        block[:, :, 2], block[:, :, 3] = r * np.cos(theta), r * np.sin(theta)
        block[:, :, 4] = (ws[jx] * ws[jy] * wr[k] / na)[:, None]
        rings.append(block)
    out = np.concatenate(rings, axis=1).reshape(-1, 5)
    out.setflags(write=False)
    return out


@functools.lru_cache(maxsize=256)
def _ring_ratios(n_rings: int) -> np.ndarray:
    s, _ = _gauss_legendre_unit(n_rings)
    return np.sqrt(s) / math.sqrt(s[-1])


def _candidates(rho_px: float, detail_px: float, at_least: int = 0) -> list[tuple[int, int, int]]:
    """Rules to try for a blur radius, cheapest first, from ``0.8 * at_least`` nodes (the previous, smaller
    blur's rule: the next needs about as many or more): pixel orders 2-8, up to 3 rings and 3 rim angles
    per detail length (at least 16 angles per pixel node)."""
    most = 3.0 / detail_px
    out = []
    for n_p in (2, 3, 4, 6, 8):
        m = n_p * n_p
        n_t = np.arange(1, max(math.ceil(2 * math.pi * rho_px * most / 2), 16) + 2)
        for n_r in range(1, math.ceil(rho_px * most) + 3):
            sizes = m * np.ceil(np.outer(n_t, _ring_ratios(n_r)) - 1e-9).sum(axis=1).astype(int)
            for t, size in zip(n_t, sizes):
                if size >= 0.8 * at_least:
                    out.append((int(size), n_p, n_r, int(t)))
    out.sort()
    return [c[1:] for c in out]


def _dense(rho_px: float, detail_px: float) -> tuple[int, int, int]:
    """The reference rule: every pixel node with its own full ring of angles (no reliance on interleaving);
    against a rule 4-5x denser still it differs by ~0.001-0.005 grey on the paper's 5 px speckle."""
    density = max(3.0, DENSE_NODES_PER_DETAIL / detail_px)
    return (12 if rho_px < 0.5 else 6 if rho_px < 2 else 4), math.ceil(rho_px * density) + 2, \
        math.ceil(2 * math.pi * rho_px * density) + 6


@numba.njit(cache=True, parallel=True)
def _model_values(texture, centres, J, rho, rule):
    """The rule on the affine model of a view: texel = centre + J (p - 1/2 - rho a), per centre."""
    rows, cols = texture.shape
    out = np.empty(len(centres))
    for i in numba.prange(len(centres)):
        acc = 0.0
        for j in range(rule.shape[0]):
            dx = rule[j, 0] - 0.5 - rho * rule[j, 2]
            dy = rule[j, 1] - 0.5 - rho * rule[j, 3]
            acc += rule[j, 4] * bilinear_lookup(texture, rows, cols, centres[i, 0] + J[0, 0] * dx + J[0, 1] * dy,
                                          centres[i, 1] + J[1, 0] * dx + J[1, 1] * dy)
        out[i] = acc
    return out


def texture_detail_texels(texture: np.ndarray) -> float:
    """The texture's detail length, texels: its standard deviation over the RMS of its gradient (~0.3 x the
    speckle diameter of :func:`scenes.surfaces.speckle.speckle_pattern`), on a central window of at most 1024^2."""
    t = np.asarray(texture)
    r0, c0 = max(0, t.shape[0] // 2 - 512), max(0, t.shape[1] // 2 - 512)
    t = t[r0:r0 + 1024, c0:c0 + 1024].astype(np.float64)
    if min(t.shape) < 3:
        return 1.0
    gy, gx = np.gradient(t)
    g = math.sqrt(float(np.mean(gx ** 2 + gy ** 2)))
    return float(t.std() / g) if g > 0 else float("inf")


#: Rules chosen so far, by texture fingerprint, Jacobian, blur radius, exposure, tolerance and seed.
_RULES: dict = {}


def texture_fingerprint(texture: np.ndarray) -> tuple:
    """What :func:`choose_rule` remembers a texture by: its shape, sum and CRC-32 of its float32 bytes (a
    content hash at memory speed: ~0.1 s for a 270 MB texture)."""
    t = np.ascontiguousarray(texture, dtype=np.float32)
    return t.shape, float(t.sum(dtype=np.float64)), zlib.crc32(memoryview(t).cast("B"))


#: The last rule chosen per texture, blur radius, exposure, tolerance and seed, whatever the Jacobian.
_NEAR_RULES: dict = {}


def _calibration_points(tex: np.ndarray, J: np.ndarray, rho_px: float, seed: int) -> np.ndarray:
    """:data:`CALIBRATION_POINTS` random texel positions (x, y) far enough from the texture's edge for the rule's
    reach through ``J`` at blur ``rho_px``."""
    stretch = float(np.linalg.svd(J, compute_uv=False)[0])
    rng = np.random.default_rng(seed)
    reach = stretch * (rho_px + 1.0) + 2.0
    lo = np.minimum(reach, 0.5 * np.array(tex.shape[::-1]))
    return rng.uniform(lo, np.array(tex.shape[::-1]) - lo, size=(CALIBRATION_POINTS, 2))


def choose_rule(texture: np.ndarray, jacobian_texels_per_px: np.ndarray, rho_px: float, exposure_grey: float,
                tolerance_grey: float = DEFAULT_TOLERANCE_GREY, seed: int = 0, *,
                detail_texels: float | None = None, fingerprint: tuple | None = None, at_least: int = 0) -> dict:
    """The cheapest candidate rule whose RMS error against the dense rule is within ``tolerance_grey``.

    Measured on :data:`CALIBRATION_POINTS` random points of ``texture`` seen through the affine map
    ``jacobian_texels_per_px`` (2 x 2, d texel / d pixel) with a blur radius ``rho_px``. Returns ``{"rule":
    (n_p, n_r, n_t), "nodes", "error_grey", "dense": (n_p, n_r, n_t)}``; the dense rule itself where no
    candidate meets the tolerance. Candidates start from ``0.8 * at_least`` nodes (the rule of the next smaller
    blur). Remembered per ``fingerprint`` (:func:`texture_fingerprint`) when given; then a rule chosen for the same
    texture and blur at another Jacobian is tried first and kept where it measures within the tolerance here.
    """
    J = np.asarray(jacobian_texels_per_px, dtype=np.float64).reshape(2, 2)
    key = None
    if fingerprint is not None:
        key = (fingerprint, tuple(np.round(J.ravel(), 4)), round(float(rho_px), 6), float(exposure_grey),
               float(tolerance_grey), int(seed), int(at_least))
        if key in _RULES:
            return _RULES[key]
    tex = np.ascontiguousarray(texture, dtype=np.float32)
    near = None if key is None else (key[0],) + key[2:6]
    if near in _NEAR_RULES:
        # the rule chosen for this texture and blur at another Jacobian (the next state or view): kept if it is
        # measured within the tolerance here too (not necessarily the cheapest then)
        rule, dense = _NEAR_RULES[near]
        centres = _calibration_points(tex, J, rho_px, seed)
        ref = _model_values(tex, centres, J, rho_px, thin_lens_rule(*dense))
        got = _model_values(tex, centres, J, rho_px, thin_lens_rule(*rule))
        err = float(exposure_grey * np.sqrt(np.mean((got - ref) ** 2)))
        if err <= tolerance_grey:
            result = {"rule": rule, "nodes": rule_size(*rule), "error_grey": err, "dense": dense}
            _RULES[key] = result
            return result
    if detail_texels is None:
        detail_texels = texture_detail_texels(tex)
    stretch = float(np.linalg.svd(J, compute_uv=False)[0])
    detail_px = max(detail_texels / stretch, 0.25)
    centres = _calibration_points(tex, J, rho_px, seed)
    dense = _dense(rho_px, detail_px)
    ref = _model_values(tex, centres, J, rho_px, thin_lens_rule(*dense))
    dense_nodes = rule_size(*dense)
    result = {"rule": dense, "nodes": dense_nodes, "error_grey": 0.0, "dense": dense}
    # a candidate is first tried on a quarter of the points: one erring by more than twice the tolerance there is
    # passed over without the full measurement (the rule chosen is always measured on every point)
    few = CALIBRATION_POINTS // 4
    for cand in _candidates(rho_px, detail_px, at_least):
        nodes = rule_size(*cand)
        if nodes >= dense_nodes:
            break
        rule = thin_lens_rule(*cand)
        got = _model_values(tex, centres[:few], J, rho_px, rule)
        if exposure_grey * np.sqrt(np.mean((got - ref[:few]) ** 2)) > 2.0 * tolerance_grey:
            continue
        got = _model_values(tex, centres, J, rho_px, rule)
        err = float(exposure_grey * np.sqrt(np.mean((got - ref) ** 2)))
        if err <= tolerance_grey:
            result = {"rule": cand, "nodes": nodes, "error_grey": err, "dense": dense}
            break
    if key is not None:
        if len(_RULES) > 4096:
            _RULES.clear()
            _NEAR_RULES.clear()
        _RULES[key] = result
        _NEAR_RULES[near] = (tuple(result["rule"]), tuple(result["dense"]))
    return result


__all__ = ["DEFAULT_TOLERANCE_GREY", "choose_rule", "rule_size", "texture_detail_texels", "texture_fingerprint",
           "thin_lens_rule"]
