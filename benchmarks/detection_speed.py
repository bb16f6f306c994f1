"""Checkerboard corner detection + saddle refinement on 5 MP boards: seconds per image and accuracy.

Renders ``--views`` random stereo views of the paper's board at full resolution (exact renderer, 1 grey read
noise, 8 bit), then times :func:`measurement.calibration.detection.detect_checkerboard` per image with the search
pyramid (640 px copy first) and with the 1280 px copy alone (the previous default), both refined at full size
(OpenCV sub-pixel), and the pyramid followed by the saddle-model fit the calibration runs
(:func:`~measurement.calibration.detection.refine_corners_saddle`), and scores every corner against the truth
side's projection. All run in this one process.

    .venv/bin/python benchmarks/detection_speed.py [--views 6] [--seed 0]
"""
from __future__ import annotations

import argparse
import platform
import time

import numpy as np

import measurement.calibration.detection as detection
from scenes.rendering.exact import render_view_exact
from scenes.sensor.noise import SensorNoise, to_image_dtype
from scenes.surfaces.checkerboard import Checkerboard
from scenes.optics.projection import project_points
from workbench.experiments.calibration.views import board_outline_mm, sensor_spec_for
from workbench.poses import random_board_poses
from workbench.rigs import get_rig


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--views", type=int, default=6)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    rig, board = get_rig("paper", 1.0), Checkerboard()
    noise = SensorNoise(read_noise_grey=1.0, bit_depth=8)
    images, truths = [], []
    for v, (R_wb, t_wb) in enumerate(random_board_poses(rig, board_outline_mm(board), args.views, args.seed)):
        for side in ("left", "right"):
            spec, pose = sensor_spec_for(rig, side), rig.pose(side)
            image, _ = render_view_exact(spec, *pose, [board.surface(R_wb, t_wb)])
            images.append(to_image_dtype(noise.apply(image, seed=2 * v + (side == "right")), 8))
            truths.append(project_points(spec, *pose, board.true_corners_board_mm() @ np.asarray(R_wb).T + t_wb))
    print(f"machine: {platform.platform()}; {len(images)} images of {images[0].shape[1]} x {images[0].shape[0]} px")
    detection.detect_checkerboard(images[0], (11, 8))                     # warm-up
    pyramid = detection.DETECT_SEARCH_SIDES_PX
    for label, sides, saddle in (("pyramid 640 -> 1280", pyramid, False), ("1280 px copy only", (), False),
                                 ("pyramid + saddle fit", pyramid, True)):
        detection.DETECT_SEARCH_SIDES_PX = sides
        seconds, errors, missed = [], [], 0
        for image, truth in zip(images, truths):
            t0 = time.perf_counter()
            found = detection.detect_checkerboard(image, (11, 8))
            if saddle and found is not None:       # what the calibration runs (refine_corners=True)
                found = detection.refine_corners_saddle(image, found, (11, 8))
            seconds.append(time.perf_counter() - t0)
            if found is None:
                missed += 1
                continue
            errors.append(np.linalg.norm(found - truth, axis=1))
        e = np.concatenate(errors)
        print(f"{label:20s}: {np.median(seconds):.3f} s per image (median; max {max(seconds):.3f}), corner error "
              f"RMS {np.sqrt(np.mean(e ** 2)):.4f} px, mean {e.mean():.4f}, max {e.max():.4f}; missed {missed}")


if __name__ == "__main__":
    main()
