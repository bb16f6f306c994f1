"""Calibration-speed benchmark: the stepwise stereo calibration of 30 views (rendering and detection excluded).

Goal (calibration issue): <= 10 s on 2 cores. Corners are the exact projections of 30 random board poses of
the paper rig plus 0.03 px Gaussian noise (about what the detector gives on rendered images).

    .venv/bin/python benchmarks/calibration_speed.py [--views 30] [--model rmm] [--repeat 2]
"""
from __future__ import annotations

import argparse
import time

import numpy as np

from measurement.calibration.detection import board_points_mm
from measurement.calibration.stepwise import calibrate_stereo
from scenes.surfaces.checkerboard import Checkerboard
from workbench.experiments.calibration.views import board_outline_mm
from workbench.poses import random_board_poses
from workbench.rigs import paper_rig


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--views", type=int, default=30)
    ap.add_argument("--model", default="rmm")
    ap.add_argument("--repeat", type=int, default=2)
    args = ap.parse_args()
    rig = paper_rig(1.0)
    obj = board_points_mm((11, 8), 5.0)
    poses = random_board_poses(rig, board_outline_mm(Checkerboard()), args.views, seed=0)
    R, T = rig.pose("right")
    rng = np.random.default_rng(0)
    noise = lambda: rng.normal(0.0, 0.03, (args.views, len(obj), 2))  # noqa: E731
    pl = np.array([rig.left.project(obj @ Rw.T + tw) for Rw, tw in poses]) + noise()
    pr = np.array([rig.right.project((obj @ Rw.T + tw) @ R.T + T) for Rw, tw in poses]) + noise()
    times = []
    for _ in range(args.repeat):
        t0 = time.perf_counter()
        cal = calibrate_stereo(pl, pr, obj, (rig.left.width, rig.left.height), model=args.model,
                               tilt_guess_left_deg=(0, -4), tilt_guess_right_deg=(0, 4))
        times.append(time.perf_counter() - t0)
    print(f"{args.views} stereo views, model {args.model}: {min(times):.2f} s (best of {args.repeat}) "
          f"[goal <= 10 s]; reprojection RMS {cal.rms_px['left']:.4f} / {cal.rms_px['right']:.4f} px")
    for name, step, rms in cal.steps:
        print(f"  {name:14s} rms {rms:.4f} px")


if __name__ == "__main__":
    main()
