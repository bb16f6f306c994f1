"""Defocus without Monte Carlo (scenes.rendering.defocus_quadrature) on the depth-of-field experiment's untilted camera at full
resolution (2456 x 2058 px, f/4, a speckled plate at 38°: blur circles from 0 to ~17 px): time and error against
converged Mitsuba thin-lens renders.

Time: the whole view (``render_view_in_focus`` then ``fill_defocused_faces``), cold (the per-blur rules measured
on the texture, numba kernels loaded) and warm (rules remembered: a second state of the same paint), on a quiet
machine. Error: on windows across the blur range, against two independent Mitsuba renders of ``--ref-spp``
samples each (stratified); the renderer's RMS error is ``sqrt(mean((q - a)(q - b)))`` (the two halves' noises
are independent, so the mean carries none of their variance, only a spread: its standard error
``std((q - a)(q - b)) / sqrt(N)`` is printed as the 95 % upper bound ``sqrt(mean + 2 se)``), per window and pooled
over all windows; beside it the reference's own noise (half the difference of its halves). The Monte-Carlo alternative this replaces is timed on the same view (adaptive Mitsuba at the
paper run's 0.3 grey target), with the noise it reached.

    .venv/bin/python benchmarks/render_defocus.py [--ref-spp 4096] [--window 256] [--scale 1.0] [--tolerance 0.03]
"""
from __future__ import annotations

import argparse
import platform
import time

import numpy as np

from scenes.rendering.adaptive import AdaptiveSettings, render_views_adaptive
from scenes.optics.backend import VARIANT
from scenes.rendering.defocus_rules import DEFAULT_TOLERANCE_GREY
from scenes.rendering.defocus_quadrature import fill_defocused_faces
from scenes.rendering.exact import render_view_in_focus
from scenes.rendering.mitsuba import render_view
from scenes.optics.projection import defocus_blur_px, pixel_rays
from workbench.experiments.depth_of_field.run import depth_of_field_scene


def deterministic(spec, pose, surfaces, tolerance_grey):
    image, known, _ = render_view_in_focus(spec, *pose, surfaces, exposure_grey=255.0)
    return fill_defocused_faces(spec, *pose, surfaces, image, known, exposure_grey=255.0,
                                tolerance_grey=tolerance_grey)


def _rms_and_bound(products: np.ndarray) -> tuple[float, float]:
    """RMS error from the products (q - a)(q - b) (signed: a negative mean is reference noise), and the 95 %
    upper bound from the mean's standard error."""
    mean = float(products.mean())
    se = float(products.std() / np.sqrt(products.size))
    return float(np.sign(mean) * np.sqrt(abs(mean))), float(np.sqrt(max(mean + 2 * se, 0.0)))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--ref-spp", type=int, default=4096, help="samples per half of the reference (2 halves)")
    ap.add_argument("--window", type=int, default=256, help="reference window side, px")
    ap.add_argument("--scale", type=float, default=1.0)
    ap.add_argument("--tolerance", type=float, default=DEFAULT_TOLERANCE_GREY, help="rule tolerance, grey RMS")
    ap.add_argument("--skip-adaptive", action="store_true", help="do not time the Monte-Carlo alternative")
    args = ap.parse_args()
    scene = depth_of_field_scene(scale=args.scale, object_tilt_deg=38.0, seed=0)
    surfaces = [scene.plate.surface(scene.R_world_from_plate, scene.t_world_from_plate_mm, scene.plate.texture())]
    spec, pose = scene.specs["conventional"], (np.eye(3), np.zeros(3))
    print(f"machine: {platform.platform()}, {platform.machine()}; variant {VARIANT}; image {spec.width} x "
          f"{spec.height} px, f/{spec.f_number:g}, plate at 38°; rule tolerance {args.tolerance} grey")
    t0 = time.perf_counter()
    deterministic(spec, pose, surfaces, args.tolerance)
    cold = time.perf_counter() - t0
    t0 = time.perf_counter()
    image, known, info = deterministic(spec, pose, surfaces, args.tolerance)
    warm = time.perf_counter() - t0
    print(f"deterministic view: cold {cold:.1f} s (rules measured, kernels loaded), warm {warm:.1f} s; "
          f"{info['defocus_pixels']} px by defocus quadrature ({100 * info['defocus_pixels'] / known.size:.2f} %), "
          f"{int((~known).sum())} px left; mean {info['defocus_nodes']:.0f} nodes per pixel; rules' largest error "
          f"against their dense rule {max(b['error_grey'] for b in info['defocus_bins']):.3f} grey")
    # the blur circle along the middle row: where the windows sit
    H, W = image.shape
    cols = np.arange(W)
    rays = pixel_rays(spec, *pose, np.column_stack([cols, np.full(W, H // 2)]))
    normal = scene.R_world_from_plate[:, 2]
    lam = (normal @ scene.t_world_from_plate_mm) / (rays[1] @ normal)
    blur = defocus_blur_px(spec, *pose, rays[1] * lam[:, None])
    win = min(args.window, W, H)
    print(f"\nerror against 2 x {args.ref_spp} spp Mitsuba, {win} x {win} px windows on the middle rows")
    print("| window x0 | blur circle (px) | RMS error (grey) | 95 % upper bound (grey) | reference noise (grey RMS) "
          "| Mitsuba s |")
    print("|---|---|---|---|---|---|")
    products = []
    for f in (0.0, 0.15, 0.3, 0.45, 0.6, 0.8, 1.0):
        x0 = int(f * (W - win))
        y0 = (H - win) // 2
        t0 = time.perf_counter()
        a, b = (render_view(spec, *pose, surfaces, spp=args.ref_spp, seed=s, exposure_grey=255.0,
                            crop=(x0, y0, win, win)).image_grey.astype(np.float64) for s in (101, 102))
        t_ref = time.perf_counter() - t0
        q = image[y0:y0 + win, x0:x0 + win].astype(np.float64)
        p = ((q - a) * (q - b)).ravel()
        products.append(p)
        rms, upper = _rms_and_bound(p)
        print(f"| {x0} | {blur[x0:x0 + win].min():.1f}-{blur[x0:x0 + win].max():.1f} | {rms:.3f} | {upper:.3f} | "
              f"{np.sqrt(np.mean((0.5 * (a - b)) ** 2)):.3f} | {t_ref:.1f} |", flush=True)
    rms, upper = _rms_and_bound(np.concatenate(products))
    print(f"\nall windows: {rms:.3f} grey RMS, 95 % upper bound {upper:.3f} (goal <= 0.1); view {warm:.1f} s warm, "
          f"{cold:.1f} s cold (goal <= 5 s)")
    if not args.skip_adaptive:
        t0 = time.perf_counter()
        ad = render_views_adaptive([(spec, pose)], surfaces, seed=1, exposure_grey=255.0,
                                   settings=AdaptiveSettings(target_mc_grey=0.3))[0]
        print(f"the Monte-Carlo alternative (adaptive Mitsuba, target 0.3 grey): {time.perf_counter() - t0:.1f} s, "
              f"measured {ad.mc['mc_rms_grey']:.2f} grey RMS, target met: {ad.mc['target_met']}")


if __name__ == "__main__":
    main()
