"""Render-speed benchmark: one 2456 x 2058 speckle render at 64 spp, pinhole and thin lens.

Goal (foundation issue): <= 5 s per render on 2 cores. Prints seconds (best of --repeat, after one warm-up
render that includes JIT compilation) and the process's peak resident memory.

    .venv/bin/python benchmarks/render_speed.py [--scale 1.0] [--spp 64] [--repeat 2]
"""
from __future__ import annotations

import argparse
import resource
import time

import numpy as np

from scenes.optics.backend import VARIANT
from scenes.rendering.mitsuba import render_view
from scenes.specimens.plate import SpeckledPlate
from workbench.experiments.calibration.views import camera_to_sensor_spec
from workbench.rigs import paper_rig


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scale", type=float, default=1.0)
    ap.add_argument("--spp", type=int, default=64)
    ap.add_argument("--repeat", type=int, default=2)
    args = ap.parse_args()
    rig = paper_rig(args.scale)
    cam = rig.left
    z_mm = 376.0
    px_mm = z_mm / cam.fx
    t0 = time.perf_counter()
    plate = SpeckledPlate(width_mm=1.3 * cam.width * px_mm, height_mm=1.3 * cam.height * px_mm,
                          texel_mm=px_mm / 2.5, speckle_mm=5 * px_mm, seed=0)
    texture = plate.texture()
    t_texture = time.perf_counter() - t0
    # Centre the plate on the image centre's line of sight so it fills the view.
    surface = plate.surface(np.eye(3), [(cam.width / 2 - cam.cx) * px_mm, (cam.height / 2 - cam.cy) * px_mm, z_mm],
                            texture)
    v = cam.fx * rig.pixel_pitch_mm
    lenses = {"pinhole": {}, "thin lens f/8": dict(lens="thin", focal_length_mm=1 / (1 / v + 1 / z_mm), f_number=8.0)}
    print(f"variant {VARIANT}; image {cam.width} x {cam.height} px, {args.spp} spp; speckle texture "
          f"{texture.shape[1]} x {texture.shape[0]} texels generated in {t_texture:.2f} s")
    for name, lens in lenses.items():
        spec = camera_to_sensor_spec(cam, rig.pixel_pitch_mm, **lens)
        t0 = time.perf_counter()
        render_view(spec, np.eye(3), np.zeros(3), [surface], spp=args.spp, seed=0)
        first = time.perf_counter() - t0
        times = []
        for k in range(args.repeat):
            t0 = time.perf_counter()
            render_view(spec, np.eye(3), np.zeros(3), [surface], spp=args.spp, seed=k + 1)
            times.append(time.perf_counter() - t0)
        peak_gb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024 ** 2
        print(f"{name:14s}: {min(times):6.2f} s per render (first call incl. JIT {first:.2f} s), "
              f"peak RSS so far {peak_gb:.2f} GB  [goal <= 5 s]")


if __name__ == "__main__":
    main()
