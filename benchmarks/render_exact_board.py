"""The exact board renderer (scenes.rendering.exact) against Mitsuba at full resolution: time and render error.

For one board view of the paper rig (both cameras, 2456 x 2058 px): the exact box-filtered render, the adaptive
Mitsuba render at the paper run's target (0.3 grey RMS MC noise) and a reference of 2 x ``--ref-spp`` stratified
Mitsuba samples per pixel over a window around the board's corner region. Render error = RMS over the window's
lit pixels of (render - reference), with the reference's own MC noise (half the difference of its two halves)
reported beside it and taken out in quadrature. Also the time of a ChArUco and a dot-grid view.

    .venv/bin/python benchmarks/render_exact_board.py [--ref-spp 2048] [--window 400] [--seed 0]
"""
from __future__ import annotations

import argparse
import platform
import time

import numpy as np

from scenes.rendering.adaptive import AdaptiveSettings, render_views_adaptive
from scenes.optics.backend import VARIANT
from scenes.rendering.exact import render_view_exact
from scenes.rendering.mitsuba import render_view
from scenes.surfaces.charuco import CharucoBoard
from scenes.surfaces.checkerboard import Checkerboard
from scenes.surfaces.dot_grid import DotGrid
from workbench.experiments.calibration.views import board_outline_mm, sensor_spec_for
from workbench.poses import random_board_poses
from workbench.rigs import get_rig

from timing import best_of


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--ref-spp", type=int, default=2048, help="samples per half of the reference (2 halves)")
    ap.add_argument("--window", type=int, default=400, help="reference window side, px")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    rig = get_rig("paper", 1.0)
    print(f"machine: {platform.platform()}, {platform.machine()}; variant {VARIANT}; image "
          f"{rig.left.width} x {rig.left.height} px")
    boards = {"checkerboard 12 x 9": Checkerboard(), "ChArUco 10 x 7": CharucoBoard(squares=(10, 7), square_mm=6.0,
                                                                                      marker_mm=4.5,
                                                                                      dictionary="DICT_4X4_50"),
              "dot grid 11 x 8": DotGrid()}
    for name, board in boards.items():
        R_wb, t_wb = random_board_poses(rig, board_outline_mm(board), 1, args.seed)[0]
        surface = board.surface(R_wb, t_wb)
        render_view_exact(sensor_spec_for(rig, "left"), *rig.pose("left"), [surface])     # numba compile / load
        for side in ("left", "right"):
            spec, pose = sensor_spec_for(rig, side), rig.pose(side)
            t_ex, (exact, info) = best_of(lambda: render_view_exact(spec, *pose, [surface]))
            print(f"{name:20s} {side:5s}: exact {t_ex:6.3f} s ({info['polygons']} polygons, crop "
                  f"{info['crop'][2]} x {info['crop'][3]} px)")
            if name != "checkerboard 12 x 9":
                continue
            t_ad, ad = best_of(lambda: render_views_adaptive([(spec, pose)], [surface], seed=1,
                                                           settings=AdaptiveSettings(target_mc_grey=0.3))[0], 1)
            # reference window: centred on the projected board centre (edges of many squares)
            centre = np.nanmean(np.argwhere(exact > 0), axis=0).astype(int)
            h = args.window // 2
            y0, x0 = max(0, centre[0] - h), max(0, centre[1] - h)
            crop = (int(x0), int(y0), args.window, args.window)
            t0 = time.perf_counter()
            a, b = (render_view(spec, *pose, [surface], spp=args.ref_spp, seed=s, crop=crop).image_grey
                    for s in (11, 12))
            t_ref = time.perf_counter() - t0
            ref, ref_noise = 0.5 * (a + b), 0.5 * (a - b)
            win = (slice(y0, y0 + args.window), slice(x0, x0 + args.window))
            lit = (ref > 0) | (exact[win] > 0)
            rn = float(np.sqrt(np.mean(ref_noise[lit] ** 2)))
            for label, img, seconds in (("exact", exact[win], t_ex), ("Mitsuba adaptive 0.3", ad.image_grey[win],
                                                                      t_ad)):
                e = float(np.sqrt(np.mean((img - ref)[lit] ** 2)))
                print(f"    {label:22s}: {seconds:6.2f} s, RMS vs reference {e:.4f} grey (reference MC noise "
                      f"{rn:.4f}; error net of it {np.sqrt(max(e * e - rn * rn, 0.0)):.4f} grey)")
            print(f"    reference: 2 x {args.ref_spp} spp over {args.window} x {args.window} px in {t_ref:.0f} s")


if __name__ == "__main__":
    main()
