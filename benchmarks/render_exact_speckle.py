"""The deterministic speckle renderer (exact coverage + Gauss-Legendre quadrature, scenes.rendering.exact) against
Mitsuba at full resolution (2456 x 2058 px, pinhole, the paper rig's tilted, distorted cameras): time and render
error.

Scenes: the rigid-motion beam (closed box, speckled front face) at 3 mm of stage travel; a speckled plate at 45°
to the left camera's axis; the beam of the bending test at 2000 N (FE-deformed front face) through pinholes, and
through the thin lenses the bending experiment uses (its ``scheimpflug`` rig): there the in-focus pixels are quadrature
(``render_view_in_focus``: blur circle <= 0.1 px) and Mitsuba's adaptive renderer traces only the rest (the end
face the lens blurs by up to a few px, and the silhouette), one window on the face, one on the blurred end face.
For each camera: the deterministic render (best of two, after a warm-up that compiles the kernels), the adaptive
Mitsuba render at the paper run's target (0.3 grey RMS MC noise), and a reference of 2 x ``--ref-spp`` stratified
Mitsuba samples per pixel over a window on the specimen. Render error = RMS over the window's lit pixels of
(render - reference), with the reference's own MC noise (half the difference of its halves) beside it and taken
out in quadrature.

    .venv/bin/python benchmarks/render_exact_speckle.py [--ref-spp 2048] [--window 300] [--order 6]
"""
from __future__ import annotations

import argparse
import platform
import time

import numpy as np

from scenes.rendering.adaptive import AdaptiveSettings, render_views_adaptive
from scenes.optics.backend import VARIANT
from scenes.rendering.exact import QUADRATURE_ORDER, render_view_exact, render_view_in_focus
from scenes.rendering.mitsuba import render_view
from scenes.specimens.plate import SpeckledPlate
from workbench.experiments.bending.scenes import bending_truth
from workbench.experiments.rigid_motion.scenes import rigid_motion_truth
from workbench.poses import common_view_centre_mm
from workbench.rigs import get_rig

from timing import best_of


def _rot_y(deg: float) -> np.ndarray:
    a = np.radians(deg)
    return np.array([[np.cos(a), 0.0, np.sin(a)], [0.0, 1.0, 0.0], [-np.sin(a), 0.0, np.cos(a)]])


def scenes_to_render(rig, thin_rig):
    """name -> (surfaces, {side: (spec, pose)})."""
    out = {}
    rm = rigid_motion_truth(rig, lens="pinhole", seed=0)
    cams = {side: (rm.specs[side], rm.camera_poses[side]) for side in ("left", "right")}
    out["rigid-motion beam, 3 mm"] = (rm.specimen.surfaces(*rm.poses[3], texture=rm.specimen.texture()), cams)
    footprint_mm = 376.0 / rig.left.fx
    plate = SpeckledPlate(width_mm=60.0, height_mm=45.0, texel_mm=footprint_mm / 3.0, speckle_mm=4 * footprint_mm,
                          seed=1)
    out["speckle plate at 45 deg"] = ([plate.surface(_rot_y(45.0), common_view_centre_mm(rig))], cams)
    bt = bending_truth(rig, lens="pinhole", seed=0)
    cams_b = {side: (bt.specs[side], bt.camera_poses[side]) for side in ("left", "right")}
    k = len(bt.loads_N) - 1
    out[f"bending beam, {bt.loads_N[k]:g} N"] = (
        bt.specimen.surfaces(*bt.pose, texture=bt.specimen.texture(), displacement_mm=bt.field(k)), cams_b)
    bt = bending_truth(thin_rig, lens="thin", seed=0)
    cams_t = {side: (bt.specs[side], bt.camera_poses[side]) for side in ("left", "right")}
    out[f"bending, {bt.loads_N[k]:g} N, {thin_rig.name} rig thin f/{bt.specs['left'].f_number:g}"] = (
        bt.specimen.surfaces(*bt.pose, texture=bt.specimen.texture(), displacement_mm=bt.field(k)), cams_t)
    return out


def deterministic(spec, pose, surfaces, order):
    """The pinhole quadrature render, or through a thin lens quadrature where in focus + adaptive Mitsuba
    for the rest (as ``render_stereo_states`` does); returns the image, its info and the unknown-pixel mask."""
    if spec.lens == "pinhole":
        image, info = render_view_exact(spec, *pose, surfaces, exposure_grey=255.0, quadrature_order=order)
        return image, info, np.zeros(image.shape, dtype=bool)
    image, known, info = render_view_in_focus(spec, *pose, surfaces, exposure_grey=255.0, quadrature_order=order)
    filled = render_views_adaptive([(spec, pose)], surfaces, seed=1, exposure_grey=255.0,
                                   settings=AdaptiveSettings(target_mc_grey=0.3), known=[(image, known)])[0]
    info = {**info, "mitsuba_pixels": int((~known).sum()), "mc_rms_grey": filled.mc["mc_rms_grey"]}
    return filled.image_grey, info, ~known


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--ref-spp", type=int, default=2048, help="samples per half of the reference (2 halves)")
    ap.add_argument("--window", type=int, default=300, help="reference window side, px")
    ap.add_argument("--order", type=int, default=QUADRATURE_ORDER, help="Gauss-Legendre nodes per pixel side")
    ap.add_argument("--scale", type=float, default=1.0)
    ap.add_argument("--only", default="", help="render only the scenes whose name contains this text")
    args = ap.parse_args()
    rig = get_rig("paper", args.scale)
    print(f"machine: {platform.platform()}, {platform.machine()}; variant {VARIANT}; image "
          f"{rig.left.width} x {rig.left.height} px; quadrature {args.order} x {args.order} nodes per pixel")
    for name, (surfaces, cams) in scenes_to_render(rig, get_rig("scheimpflug", args.scale)).items():
        if args.only not in name:
            continue
        spec0, pose0 = cams["left"]
        deterministic(spec0, pose0, surfaces, args.order)     # numba compile / cache load
        for side, (spec, pose) in cams.items():
            t_q, (image, info, traced) = best_of(lambda: deterministic(spec, pose, surfaces, args.order))
            t_ad, ad = best_of(lambda: render_views_adaptive([(spec, pose)], surfaces, seed=1, exposure_grey=255.0,
                                                           settings=AdaptiveSettings(target_mc_grey=0.3))[0], 1)
            extra = (f"; {info['mitsuba_pixels']} px left to Mitsuba (its MC noise {info['mc_rms_grey']:.3f} grey)"
                     if "mitsuba_pixels" in info else "")
            print(f"{name:26s} {side:5s}: crop {info['crop'][2]} x {info['crop'][3]} px, {info['polygons']} polygons"
                  + extra)
            lit_rows, lit_cols = np.nonzero(image > 0)
            centres = {"face": (int(np.median(lit_rows)), int(np.median(lit_cols)))}
            if traced.any():
                from scipy.ndimage import uniform_filter
                density = uniform_filter((traced & (ad.image_grey > 0)).astype(np.float32), args.window)
                centres["blurred part"] = tuple(int(v) for v in np.unravel_index(np.argmax(density), density.shape))
            for where, (cy, cx) in centres.items():
                h = args.window // 2
                y0 = int(np.clip(cy - h, 0, spec.height - args.window))
                x0 = int(np.clip(cx - h, 0, spec.width - args.window))
                t0 = time.perf_counter()
                a, b = (render_view(spec, *pose, surfaces, spp=args.ref_spp, seed=s, exposure_grey=255.0,
                                    crop=(x0, y0, args.window, args.window)).image_grey for s in (11, 12))
                t_ref = time.perf_counter() - t0
                ref, ref_noise = 0.5 * (a + b), 0.5 * (a - b)
                win = (slice(y0, y0 + args.window), slice(x0, x0 + args.window))
                lit = (ref > 0) | (image[win] > 0)
                rn = float(np.sqrt(np.mean(ref_noise[lit] ** 2)))
                label_q = "quadrature" if spec.lens == "pinhole" else "in focus + Mitsuba"
                if len(centres) > 1:
                    print(f"  window on the {where} ({int(traced[win].sum())} px of it traced by Mitsuba):")
                for label, img, seconds in ((label_q, image[win], t_q),
                                            ("Mitsuba adaptive 0.3", ad.image_grey[win], t_ad)):
                    e = float(np.sqrt(np.mean((img - ref)[lit] ** 2)))
                    bias = float(np.mean((img - ref)[lit]))
                    print(f"    {label:22s}: {seconds:6.2f} s, RMS vs reference {e:.4f} grey, mean {bias:+.4f} "
                          f"(reference MC noise {rn:.4f}; error net of it {np.sqrt(max(e * e - rn * rn, 0.0)):.4f} grey)")
                print(f"    reference: 2 x {args.ref_spp} spp over {args.window} x {args.window} px at ({x0}, {y0}) in "
                      f"{t_ref:.0f} s")


if __name__ == "__main__":
    main()
