"""Cropped, adaptively sampled renders: samples only where they change the image, with a measured MC noise.

A fixed 64 spp over the whole sensor spends most samples where they do nothing: on background pixels that no
surface can reach (they are exactly 0 radiance) and, on a checkerboard, inside squares whose pixels are
constant. This renderer uses the same Mitsuba scene, Embree intersection, sensor plugin (:mod:`scenes.optics.camera`)
and emitter textures as :func:`scenes.rendering.mitsuba.render_view`, but its own sample loop instead of Mitsuba's film:

1. **Crop** to the projected bounding box of the surfaces (truth side's own projection, widened by the
   thin lens' blur circle and a margin). Pixels outside are background, 0. A lit pixel on the crop's edge
   means the box was too small: the crop grows and the view is rendered again.
2. **Pilot**: one stratified batch of ``pilot_side**2`` samples per pixel. The spread of its single samples
   (their standard deviation sigma: how much the pixel's footprint varies; 0 inside a checkerboard square)
   predicts the error of a stratified mean of ``side**2`` samples as ``sigma * side**-1.5`` (a straight
   edge through the pixel; a smooth texture falls faster, as ``side**-2``). A pixel whose samples agree but
   whose neighbours vary (an edge clips its corner) takes its neighbours' largest spread.
3. **Refine**: each pixel whose pilot predicts more than ``target_mc_grey`` gets one fresh stratified batch
   of the smallest ``side**2`` in ``sides`` that meets it; its pilot samples are discarded, so the value
   does not depend on the decision made from them (no adaptive-sampling bias).
4. **Measure**: on a random ``check_fraction`` of the lit pixels, a second independent batch at the same
   stratification gives the realised MC variance: ``mc_rms_grey`` in the result is measured, not predicted.

Stratification: sample ``k`` of an ``s x s`` batch jitters inside film stratum ``(k mod s, k div s)``; the
thin lens' aperture sample is stratified too, through a per-pixel random permutation of the strata (a hash
permutation, :func:`_permute`), independent of the film strata. Random numbers
are TEA hashes of (pixel, sample, seed), so a pixel's value does not depend on which pixels are rendered
with it or how they are chunked: same seed, same image.

The seed and sizes enter the traced kernels as opaque values, so Dr.Jit compiles one kernel per camera and
stratification and reuses it for every view, state and seed.
"""
from __future__ import annotations

import time
import warnings
from dataclasses import asdict, dataclass, field

import numpy as np

from scenes.optics.backend import dr, mi
from scenes.optics.camera import SensorSpec, sensor_dict
from scenes.rendering.integrator import PLUGIN_NAME as INTEGRATOR
from scenes.surfaces.textured_surface import TexturedSurface

#: Largest number of samples traced in one kernel launch (memory: ~40 bytes per lane).
MAX_LANES = 1 << 25


@dataclass(frozen=True)
class AdaptiveSettings:
    """How :func:`render_views_adaptive` spends its samples.

    target_mc_grey : Monte-Carlo standard error a pixel should stay below, grey levels (of ``exposure_grey``)
    pilot_side : the pilot traces ``pilot_side**2`` samples per pixel
    sides : stratification grids a refined pixel can get (``side**2`` samples), ascending
    check_fraction : share of lit pixels given a second batch to measure the realised MC noise
    margin_px : margin around the projected bounding box of the surfaces, px
    crop : render only the projected bounding box (False: the whole sensor)
    """

    target_mc_grey: float = 0.3
    pilot_side: int = 3
    sides: tuple[int, ...] = (4, 5, 6, 8, 11, 16, 23)
    check_fraction: float = 0.03
    margin_px: int = 3
    crop: bool = True

    def __post_init__(self):
        if not (self.target_mc_grey > 0 and np.isfinite(self.target_mc_grey)):
            raise ValueError(f"target_mc_grey must be a positive number, got {self.target_mc_grey}")
        if self.pilot_side < 1 or not self.sides or any(s <= self.pilot_side for s in self.sides) \
                or list(self.sides) != sorted(set(self.sides)):
            raise ValueError(f"sides must ascend above pilot_side={self.pilot_side}, got {self.sides}")
        if not 0 < self.check_fraction <= 1:
            raise ValueError(f"check_fraction must be in (0, 1], got {self.check_fraction}")
        if self.margin_px < 0:
            raise ValueError(f"margin_px must be >= 0, got {self.margin_px}")

    def to_dict(self) -> dict:
        return {k: (list(v) if isinstance(v, tuple) else v) for k, v in asdict(self).items()}


@dataclass
class AdaptiveRender:
    """One adaptively rendered view.

    image_grey : (H, W) float32, full sensor, grey levels before sensor noise (0 outside ``crop``)
    spp_map : (H, W) uint16, samples that made each pixel's value (0 outside the crop)
    crop : (x0, y0, width, height) of the rendered window
    mc : the measured Monte-Carlo noise and the sample budget (see :func:`render_views_adaptive`)
    """

    image_grey: np.ndarray
    spp_map: np.ndarray
    crop: tuple[int, int, int, int]
    mc: dict = field(default_factory=dict)


def _stream(view_seed: int, purpose: int) -> int:
    """A 32-bit sampler key for one pass of one view (distinct passes and views never share a stream)."""
    return int(np.random.SeedSequence([int(view_seed) & 0xFFFFFFFFFFFF, purpose]).generate_state(1)[0])


def _uniform_pair(a, b):
    """Two uniform floats in [0, 1) from one TEA hash of two 32-bit words (its two output words)."""
    h0, h1 = mi.sample_tea_32(a, b, 5)
    scale = 1.0 / 4294967296.0
    return mi.Float(h0 >> 8) * (scale * 256.0), mi.Float(h1 >> 8) * (scale * 256.0)


#: Cycle-walking rounds of :func:`_permute` before a lane takes its hash modulo n (each round ends a lane
#: with probability > 1/2: 2^-16 or fewer lanes are left, and their value is still uniform, only not a stratum of
#: their own).
PERMUTE_ROUNDS = 16


def _permute(i, n: int, key, offset):
    """A random permutation of ``0 .. n - 1`` per ``key`` (Kensler 2013, "Correlated multi-jittered sampling",
    Pixar tech memo 13-01: a hash that is a bijection on the next power of two, walked until it lands below n),
    then turned by ``offset mod n`` so that every output is uniform whatever the walk did. ``i``, ``key``,
    ``offset``: UInt32 arrays; ``n``: a literal."""
    w = n - 1
    for b in (1, 2, 4, 8, 16):
        w |= w >> b
    x = mi.UInt32(i)
    done = x < 0                                              # all False
    for _ in range(PERMUTE_ROUNDS):
        y = x ^ key
        y *= 0xE170893D
        y ^= key >> 16
        y ^= (y & w) >> 4
        y ^= key >> 8
        y *= 0x0929EB3F
        y ^= key >> 23
        y ^= (y & w) >> 1
        y *= 1 | key >> 27
        y *= 0x6935FA69
        y ^= (y & w) >> 11
        y *= 0x74DCB303
        y ^= (y & w) >> 2
        y *= 0x9E501CC3
        y ^= (y & w) >> 2
        y *= 0xC860A3DF
        y &= w
        y ^= y >> 5
        x = dr.select(done, x, y)
        done = x < n
    return (x % n + offset % n) % n


def _trace(scene, sensor, pixels: np.ndarray, width: int, side: int, seed: int, thin: bool,
           spread: bool = False):
    """Mean radiance of one stratified batch of ``side**2`` samples in each of the flat ``pixels``; with
    ``spread`` also the variance of the single samples within each pixel (how much the pixel's footprint varies)."""
    spp = side * side
    out = np.empty(len(pixels), dtype=np.float64)
    var = np.empty(len(pixels), dtype=np.float64) if spread else None
    per_launch = max(1, MAX_LANES // spp)
    for start in range(0, len(pixels), per_launch):
        chunk = pixels[start:start + per_launch]
        n = len(chunk) * spp
        lane = dr.arange(mi.UInt32, n)
        # spp, side and width stay literals (integer division by an opaque value does not vectorise); the seed
        # is opaque: one compiled kernel per (camera, side, chunk size), reused for every seed and view
        seed_o = dr.opaque(mi.UInt32, seed)
        pix = dr.gather(mi.UInt32, mi.UInt32(chunk.astype(np.uint32)), lane // spp)
        k = lane % spp
        key = (k << 3) ^ (seed_o * 0x9E3779B1)
        inv = 1.0 / side
        ux, uy = _uniform_pair(pix, key)
        px = mi.Float(pix % width) + (mi.Float(k % side) + ux) * inv
        py = mi.Float(pix // width) + (mi.Float(k // side) + uy) * inv
        film = sensor.film().crop_size()     # the sensor's film is the full sensor (no crop window)
        position = mi.Point2f(px * (1.0 / film[0]), py * (1.0 / film[1]))
        if thin:
            # aperture strata in a per-pixel random permuted order: stratified marginals, uncorrelated with the
            # film's (a lattice q = a k + b mod n is not: it ties each film row to a few aperture rows, and a
            # blurred edge's pixel then scattered by +-20 grey at 4096 spp, tests/test_adaptive_render.py)
            key_p, key_o = mi.sample_tea_32(pix, seed_o ^ 0x5BD1E995, 4)
            q = _permute(k, spp, key_p, key_o)
            vx, vy = _uniform_pair(pix, key ^ 1)
            ax = (mi.Float(q % side) + vx) * inv
            ay = (mi.Float(q // side) + vy) * inv
            aperture = mi.Point2f(ax, ay)
        else:
            aperture = mi.Point2f(0.5, 0.5)
        ray, _ = sensor.sample_ray(0.0, 0.5, position, aperture)
        si = scene.ray_intersect(ray)
        hit = si.is_valid()
        radiance = dr.select(hit, si.emitter(scene).eval(si, hit)[0], 0.0)
        radiance = mi.Float(radiance)
        mean = np.array(dr.block_sum(radiance, spp), dtype=np.float64) / spp
        out[start:start + len(chunk)] = mean
        if spread:
            # deviations from the pixel's first sample: exactly 0 for a constant footprint (float32 sums of
            # squares would leave rounding noise that reads as texture)
            dr.eval(radiance)
            d = radiance - dr.gather(mi.Float, radiance, (lane // spp) * spp)
            m1 = np.array(dr.block_sum(d, spp), dtype=np.float64) / spp
            m2 = np.array(dr.block_sum(d * d, spp), dtype=np.float64) / spp
            var[start:start + len(chunk)] = np.maximum(m2 - m1 * m1, 0.0) * spp / max(spp - 1, 1)
    return (out, var) if spread else out


def _crop_box(spec: SensorSpec, pose, surfaces: list[TexturedSurface], margin_px: float) -> tuple[int, int, int, int]:
    """Projected bounding box of the surfaces' vertices, widened by the blur circle and the margin."""
    from scenes.optics.projection import defocus_blur_px, project_points

    vertices = np.concatenate([s.vertices_mm for s in surfaces])
    px = project_points(spec, *pose, vertices)
    ok = np.all(np.isfinite(px), axis=1)
    if not ok.all():            # a surface reaches behind the lens: no useful box
        return 0, 0, spec.width, spec.height
    grow = margin_px + 0.5 * float(np.max(defocus_blur_px(spec, *pose, vertices))) + 1.0
    x0 = int(np.clip(np.floor(px[:, 0].min() - grow), 0, spec.width))
    y0 = int(np.clip(np.floor(px[:, 1].min() - grow), 0, spec.height))
    x1 = int(np.clip(np.ceil(px[:, 0].max() + grow) + 1, 0, spec.width))
    y1 = int(np.clip(np.ceil(px[:, 1].max() + grow) + 1, 0, spec.height))
    return x0, y0, max(0, x1 - x0), max(0, y1 - y0)


def _window_pixels(box, width: int) -> np.ndarray:
    x0, y0, w, h = box
    yy, xx = np.mgrid[y0:y0 + h, x0:x0 + w]
    return (yy * width + xx).ravel().astype(np.int64)


def _lit_on_edge(values: np.ndarray, box, spec: SensorSpec) -> bool:
    """True when a crop edge that is not the sensor's own edge has a lit pixel (the box missed something)."""
    x0, y0, w, h = box
    img = values.reshape(h, w)
    edges = []
    if x0 > 0:
        edges.append(img[:, 0])
    if y0 > 0:
        edges.append(img[0, :])
    if x0 + w < spec.width:
        edges.append(img[:, -1])
    if y0 + h < spec.height:
        edges.append(img[-1, :])
    return any(np.any(e != 0) for e in edges)


def _max3(a: np.ndarray) -> np.ndarray:
    """3 x 3 maximum with edge replication."""
    p = np.pad(a, 1, mode="edge")
    h, w = a.shape
    return np.max([p[i:i + h, j:j + w] for i in range(3) for j in range(3)], axis=0)


def _min3(a: np.ndarray) -> np.ndarray:
    """3 x 3 minimum with edge replication."""
    return -_max3(-a)


def _mean3(a: np.ndarray) -> np.ndarray:
    """3 x 3 box mean with edge replication."""
    p = np.pad(a, 1, mode="edge")
    h, w = a.shape
    return sum(p[i:i + h, j:j + w] for i in range(3) for j in range(3)) / 9.0


def _allocate(sigma: np.ndarray, lit: np.ndarray, pilot_side: int, sides, target: float, kappa: float,
              p: float):
    """Stratification level per pixel (-1: the pilot; j: ``sides[j]``) that meets an RMS target at least cost.

    With a pixel's error ``kappa * sigma * side**-p`` (n = side^2 samples: ``kappa sigma n**(-p/2)``), the
    fewest samples for a given mean squared error over the lit pixels are ``n ∝ sigma**(2 / (1 + p))``
    (Lagrange); the scale is found by bisection on a histogram of sigma, and each pixel gets the smallest
    available side at or above its n. Returns ``(level, worst)``: worst marks pixels that would need more
    than the finest side.
    """
    grid = np.array([pilot_side] + list(sides), dtype=float)
    n_lit = max(int(lit.sum()), 1)
    varying = lit & (sigma > 0)
    if not varying.any():
        return np.full(len(sigma), -1), np.zeros(len(sigma), dtype=bool)
    # histogram of log sigma: 256 bins are plenty to set one scale factor
    log_s = np.log(sigma[varying])
    edges = np.linspace(log_s.min(), log_s.max() + 1e-9, 257)
    counts, _ = np.histogram(log_s, edges)
    centre = np.exp(np.maximum(edges[1:], edges[:-1]))           # upper edge: conservative

    def sides_for(lam, s):
        need = np.sqrt(lam * s ** (2.0 / (1.0 + p)))              # the side whose n = lam * sigma^(2/(1+p))
        k = np.searchsorted(grid, need - 1e-12)
        return grid[np.minimum(k, len(grid) - 1)], k >= len(grid)

    def rms(lam):
        side, _ = sides_for(lam, centre)
        return kappa * np.sqrt(np.sum(counts * centre ** 2 * side ** (-2.0 * p)) / n_lit)

    lo, hi = 1e-12, 1e12
    saturated = rms(hi) > target
    if saturated:                                                 # even the finest grid everywhere misses it
        lam = hi
    else:
        for _ in range(80):
            mid = np.sqrt(lo * hi)
            lo, hi = (lo, mid) if rms(mid) <= target else (mid, hi)
        lam = hi
    side, over = sides_for(lam, sigma)
    if saturated:
        # every pixel at the finest grid: the ones still above the target on their own are the misses
        over = kappa * sigma * grid[-1] ** -p > target
    level = np.searchsorted(grid, side) - 1                       # grid[0] is the pilot -> -1
    level[~lit | (sigma == 0)] = -1
    return level, over & varying


def render_views_adaptive(views: list[tuple[SensorSpec, tuple[np.ndarray, np.ndarray]]],
                          surfaces: list[TexturedSurface], *, seed: int = 0, exposure_grey: float = 255.0,
                          settings: AdaptiveSettings | None = None,
                          known: list[tuple[np.ndarray, np.ndarray]] | None = None) -> list[AdaptiveRender]:
    """Render ``surfaces`` in every view ``(spec, (R_cam_from_world, t_cam_from_world_mm))`` of one scene.

    The scene (and its textures and acceleration structure) is loaded once for all the views, e.g. the two
    cameras of a stereo state. View ``i`` uses sampler seed ``seed + i`` (Monte-Carlo noise is pixel-locked:
    give every image its own).

    ``known``: per view ``(image_grey (H, W), mask (H, W) bool)`` of pixels already made without Monte Carlo
    (:func:`scenes.rendering.exact.render_view_in_focus`): they are taken as given, with 0 samples, and serve as
    the neighbours of the sampled pixels; only the others are traced. Noise figures are of the traced pixels;
    ``mc["known_pixels"]`` counts the given ones inside the crop.

    Returns one :class:`AdaptiveRender` per view; its ``mc`` holds ``target_grey``, ``mc_rms_grey``
    (measured RMS Monte-Carlo error of the lit pixels, from ``check_pixels`` pixels rendered twice),
    ``predicted_rms_grey``, ``above_target_fraction`` (lit pixels predicted above the target even at the
    finest stratification), ``mean_spp`` (over the lit pixels) and ``sensor_spp`` (samples traced per sensor
    pixel, pilot and checks included: the cost), ``spp_histogram`` ({spp: pixels}), ``crop_fraction``,
    ``lit_pixels`` and ``seconds``.
    """
    settings = settings or AdaptiveSettings()
    if not surfaces:
        raise ValueError("nothing to render: no surfaces given")
    scene_dict = {"type": "scene", "integrator": {"type": INTEGRATOR, "truth": False}}
    if mi.variant().startswith("llvm"):
        scene_dict["embree_use_robust_intersections"] = True   # see scenes.rendering.mitsuba: Embree is not watertight
    for i, (spec, pose) in enumerate(views):
        # full-sensor film: pixel indices address the whole sensor; spp/seed of the sampler are unused here
        scene_dict[f"sensor_{i}"] = sensor_dict(spec, *pose, 1, 0, None, "independent")
    for i, surface in enumerate(surfaces):
        scene_dict[f"surface_{i}"] = surface.to_mitsuba(f"surface_{i}")
    scene = mi.load_dict(scene_dict)
    sensors = scene.sensors()
    target = settings.target_mc_grey / exposure_grey      # in radiance units
    results = []
    for i, (spec, pose) in enumerate(views):
        t0 = time.perf_counter()
        view_seed = seed + i
        thin = spec.lens == "thin"
        box = _crop_box(spec, pose, surfaces, settings.margin_px) if settings.crop else (0, 0, spec.width, spec.height)
        ps = settings.pilot_side
        given_image, given = (None, None) if known is None else known[i]
        if given is not None and (np.shape(given) != (spec.height, spec.width)
                                  or np.shape(given_image) != (spec.height, spec.width)):
            raise ValueError(f"known pixels of view {i}: image and mask must be {spec.height} x {spec.width}")
        while True:
            pixels = _window_pixels(box, spec.width)
            todo = np.ones(len(pixels), dtype=bool) if given is None else ~np.asarray(given, bool).ravel()[pixels]
            value, spread = np.zeros(len(pixels)), np.zeros(len(pixels))
            if given is not None:
                value[~todo] = np.asarray(given_image, np.float64).ravel()[pixels[~todo]] / exposure_grey
            value[todo], spread[todo] = _trace(scene, sensors[i], pixels[todo], spec.width, ps,
                                               _stream(view_seed, 0), thin, spread=True)
            if box == (0, 0, spec.width, spec.height) or not _lit_on_edge(value, box, spec):
                break
            x0, y0, w, h = box                     # the box missed part of a surface: grow it and start again
            grow = max(16, w // 4, h // 4)
            x1, y1 = min(spec.width, x0 + w + grow), min(spec.height, y0 + h + grow)
            x0, y0 = max(0, x0 - grow), max(0, y0 - grow)
            box = (x0, y0, x1 - x0, y1 - y0)
        x0, y0, w, h = box
        # The footprint's spread (std of single samples) sets a pixel's error at a finer stratification. A
        # pixel whose samples all agree is flat unless a neighbour differs from it: then an edge may clip it
        # (the pilot's samples can all miss a thin sliver), and it gets half the local contrast as its spread.
        own = np.sqrt(spread).reshape(h, w)
        img = value.reshape(h, w)
        contrast = _max3(img) - _min3(img)
        sigma = np.where(own > 0, np.maximum(own, _mean3(own)),
                         np.where(contrast > 0, np.maximum(_max3(own), 0.5 * contrast), 0.0)).ravel()
        lit = ((value != 0) | (contrast.ravel() > 0)) & todo    # a background pixel beside a lit one may be clipped
        traced = ps * ps * int(todo.sum())
        # How the error falls with the grid here (an edge: side^-1.5, a smooth texture: side^-2): measured on
        # a random share of the varying pixels, rendered twice at two grids.
        rng = np.random.default_rng([view_seed & 0xFFFFFFFF, 0xCA1B])
        cal = np.flatnonzero(lit & (sigma > 0) & (rng.random(len(pixels)) < settings.check_fraction))
        kappa, p = 1.0, 1.5
        if len(cal) >= 100:
            ratio = {}
            for side in (4, 8):
                b1 = _trace(scene, sensors[i], pixels[cal], spec.width, side, _stream(view_seed, 100 + 2 * side), thin)
                b2 = _trace(scene, sensors[i], pixels[cal], spec.width, side, _stream(view_seed, 101 + 2 * side), thin)
                ratio[side] = np.sqrt(np.sum((b1 - b2) ** 2 / 2.0) / np.sum(sigma[cal] ** 2))
                traced += 2 * side * side * len(cal)
            if ratio[4] > 0 and ratio[8] > 0:
                p = float(np.clip(np.log(ratio[4] / ratio[8]) / np.log(2.0), 1.0, 2.5))
                kappa = float(ratio[8] * 8.0 ** p)
        level, worst = _allocate(sigma, lit, ps, settings.sides, target, kappa, p)
        spp = np.where(todo, ps * ps, 0).astype(np.int64)
        # check pixels: a random share of the lit pixels, rendered a second time at their final stratification
        rng = np.random.default_rng([view_seed & 0xFFFFFFFF, 0xC0FFEE])
        check = lit & (rng.random(len(pixels)) < settings.check_fraction)
        check_var = np.zeros(len(pixels))

        for j, side in [(-1, ps)] + list(enumerate(settings.sides)):
            sel = np.flatnonzero(level == j)
            if len(sel) == 0:
                continue
            if j >= 0:
                value[sel] = _trace(scene, sensors[i], pixels[sel], spec.width, side, _stream(view_seed, 2 * side), thin)
                spp[sel] = side * side
                traced += side * side * len(sel)
            chk = sel[check[sel]]
            if len(chk):
                again = _trace(scene, sensors[i], pixels[chk], spec.width, side, _stream(view_seed, 2 * side + 1), thin)
                check_var[chk] = (again - value[chk]) ** 2 / 2.0          # variance of one batch's mean
                traced += side * side * len(chk)
        predicted = np.where(spp > 0, kappa * sigma * np.sqrt(np.maximum(spp, 1)) ** -p, 0.0)   # 0: a known pixel
        image = np.zeros((spec.height, spec.width), dtype=np.float32)
        image[y0:y0 + h, x0:x0 + w] = (value * exposure_grey).reshape(h, w).astype(np.float32)
        spp_map = np.zeros((spec.height, spec.width), dtype=np.uint16)
        spp_map[y0:y0 + h, x0:x0 + w] = np.minimum(spp, 65535).reshape(h, w)
        n_lit = int(lit.sum())
        n_check = int(check.sum())
        values, counts = np.unique(spp[lit], return_counts=True)
        mc = {"target_grey": settings.target_mc_grey, "error_model": {"kappa": kappa, "exponent": p},
              "mc_rms_grey": float(np.sqrt(check_var[check].mean()) * exposure_grey) if n_check else 0.0,
              "check_pixels": n_check,
              "predicted_rms_grey": float(np.sqrt(np.mean(predicted[lit] ** 2)) * exposure_grey) if n_lit else 0.0,
              "above_target_fraction": float(worst[lit].mean()) if n_lit else 0.0,
              "mean_spp": float(spp[lit].mean()) if n_lit else 0.0,
              "sensor_spp": traced / (spec.width * spec.height),
              "spp_histogram": {int(v): int(c) for v, c in zip(values, counts)},
              "crop": [int(c) for c in box], "crop_fraction": w * h / (spec.width * spec.height),
              "lit_pixels": n_lit, "seconds": time.perf_counter() - t0}
        if given is not None:
            mc["known_pixels"] = int((~todo).sum())
        missed = _target_missed(mc)
        mc["target_met"] = missed is None
        if missed is not None:
            warnings.warn(f"adaptive render, view {i}: the Monte-Carlo noise target {settings.target_mc_grey:g} grey "
                          f"RMS was not reached: {missed}", stacklevel=2)
        results.append(AdaptiveRender(image, spp_map, box, mc))
    return results


#: Lit pixels that may stay above the target (the allocator's largest stratification not enough) before it is said.
MISSED_FRACTION = 1e-3
#: Measured over target beyond which the target counts as missed (the check pixels' estimate scatters by a few %).
MISSED_RATIO = 1.25


#: Check pixels enough for their measured noise to overrule the error model's prediction.
MIN_CHECK_PIXELS = 200


def _target_missed(mc: dict) -> str | None:
    """Why a view's MC noise target was not reached (the budget of ``sides`` too small), or None."""
    why = []
    measured_ok = mc["check_pixels"] >= MIN_CHECK_PIXELS and mc["mc_rms_grey"] <= mc["target_grey"]
    if mc["above_target_fraction"] > MISSED_FRACTION and not measured_ok:     # a measured pass beats a prediction
        why.append(f"{100 * mc['above_target_fraction']:.2g} % of the lit pixels would need more samples than the "
                   f"largest stratification allows (AdaptiveSettings.sides)")
    if mc["check_pixels"] and mc["mc_rms_grey"] > MISSED_RATIO * mc["target_grey"]:
        why.append(f"measured {mc['mc_rms_grey']:.3g} grey RMS on {mc['check_pixels']} check pixels")
    return "; ".join(why) or None


@dataclass
class AutoRender:
    """One view of :func:`render_views_auto`: the image, which renderer made it, and how.

    Attributes
    ----------
    image_grey : ndarray (H, W) float32
        Grey levels before sensor noise.
    renderer : str
        :data:`scenes.rendering.exact.RENDERER` / ``RENDERER_QUADRATURE`` (no Monte Carlo at all),
        :data:`scenes.rendering.defocus_quadrature.RENDERER_THIN_LENS` (a thin lens, no Monte Carlo: in focus
        and blurred flat faces), :data:`scenes.rendering.defocus_quadrature.RENDERER_THIN_LENS_ADAPTIVE` (the
        same and Mitsuba's adaptive renders for the rest), :data:`scenes.rendering.exact.RENDERER_IN_FOCUS`
        (in-focus pixels without Monte Carlo, the rest adaptive Mitsuba) or ``"mitsuba-adaptive"``.
    mc : dict or None
        The adaptive render's noise figures (:func:`render_views_adaptive`), None where Mitsuba traced nothing.
    known_fraction : float
        Share of the view's lit pixels made without Monte Carlo.
    fallback : str or None
        Why the deterministic renderer could not be used at all.
    defocus_error_grey : float or None
        Where blurred flat faces were made by quadrature
        (:func:`scenes.rendering.defocus_quadrature.fill_defocused_faces`), the largest RMS error measured for its
        rules against the dense rule, grey.
    """

    image_grey: np.ndarray
    renderer: str
    mc: dict | None
    known_fraction: float
    fallback: str | None = None
    defocus_error_grey: float | None = None


def render_views_auto(views: list[tuple[SensorSpec, tuple[np.ndarray, np.ndarray]]],
                      surfaces: list[TexturedSurface], *, seed: int = 0, exposure_grey: float = 255.0,
                      settings: AdaptiveSettings | None = None) -> list[AutoRender]:
    """Every view of one scene with as little Monte Carlo as the optics allow.

    Each view's pixels that need no sampling (:func:`scenes.rendering.exact.render_view_in_focus`: all of a pinhole
    view, the in-focus ones of a thin lens) are made deterministically, and so are a thin-lens view's blurred
    flat faces, by quadrature over the pixel and the aperture
    (:func:`scenes.rendering.defocus_quadrature.fill_defocused_faces`); where any view has pixels left, the adaptive renderer (:func:`render_views_adaptive`, ``settings``) traces just those, all views from one
    Mitsuba scene. A scene the deterministic renderer refuses (occlusion, a surface behind a camera) is rendered
    by Mitsuba whole, with the reason in ``fallback``. Seeds as :func:`render_views_adaptive`.
    """
    from scenes.rendering.exact import (RENDERER_IN_FOCUS, RENDERER_OCCLUSION, NotExactError, render_view_in_focus,
                                        render_view_occluded)

    made_by = RENDERER_IN_FOCUS
    try:
        parts = [render_view_in_focus(spec, *pose, surfaces, exposure_grey=exposure_grey) for spec, pose in views]
    except NotExactError as err:
        try:           # surfaces hiding one another: exact but at the occluding edges
            parts = [render_view_occluded(spec, *pose, surfaces, exposure_grey=exposure_grey) for spec, pose in views]
            made_by = RENDERER_OCCLUSION
        except NotExactError as err2:
            rendered = render_views_adaptive(views, surfaces, seed=seed, exposure_grey=exposure_grey,
                                             settings=settings)
            return [AutoRender(r.image_grey, "mitsuba-adaptive", r.mc, 0.0, f"{err}; {err2}") for r in rendered]
    if made_by == RENDERER_IN_FOCUS:
        # blurred flat faces by quadrature over the pixel and the aperture, before any Monte Carlo
        from scenes.rendering.defocus_quadrature import RENDERER_THIN_LENS, fill_defocused_faces

        filled = []
        for (spec, pose), (image, known, info) in zip(views, parts):
            if not known.all() and spec.lens == "thin":
                image, known, extra = fill_defocused_faces(spec, *pose, surfaces, image, known,
                                                           exposure_grey=exposure_grey)
                if extra["defocus_pixels"]:
                    made_by = RENDERER_THIN_LENS
                    reached = max(int(info["reached_pixels"]), 1)
                    info = {**info, **extra, "renderer": made_by,
                            "known_fraction": 1.0 - float((~known).sum()) / reached}
            filled.append((image, known, info))
        parts = filled
    def quadrature_error(info):
        return max((b["error_grey"] for b in info.get("defocus_bins", [])), default=None)

    if all(known.all() for _, known, _ in parts):
        return [AutoRender(image, info["renderer"], None, 1.0, defocus_error_grey=quadrature_error(info))
                for image, _, info in parts]
    rendered = render_views_adaptive(views, surfaces, seed=seed, exposure_grey=exposure_grey, settings=settings,
                                     known=[(image, known) for image, known, _ in parts])
    if made_by not in (RENDERER_IN_FOCUS, RENDERER_OCCLUSION):
        from scenes.rendering.defocus_quadrature import RENDERER_THIN_LENS_ADAPTIVE as made_by
    return [AutoRender(r.image_grey, made_by, r.mc, float(info["known_fraction"]),
                       defocus_error_grey=quadrature_error(info))
            for r, (_, _, info) in zip(rendered, parts)]


def render_view_adaptive(spec: SensorSpec, R_cam_from_world, t_cam_from_world_mm, surfaces: list[TexturedSurface],
                         *, seed: int = 0, exposure_grey: float = 255.0,
                         settings: AdaptiveSettings | None = None) -> AdaptiveRender:
    """One view of :func:`render_views_adaptive`."""
    return render_views_adaptive([(spec, (R_cam_from_world, t_cam_from_world_mm))], surfaces, seed=seed,
                                 exposure_grey=exposure_grey, settings=settings)[0]


__all__ = ["AdaptiveRender", "AdaptiveSettings", "AutoRender", "render_view_adaptive", "render_views_adaptive",
           "render_views_auto"]
