"""Bending benchmark: stereo-DIC + strain per load state at full resolution, 2 cores.

Goal (bending issue): stereo + strain <= 10 s per load state. Reuses the renders of
``workbench reproduce bending --out reports/bending`` (run that first, or pass --images), measures the
reference shape once, then times every load state: the two second-order 65 x 65 matches (feature seeds,
reliability-guided IC-GN), triangulation, rigid-motion removal and the strain window. Prints the time of
each state, best and median; a numba warm-up state is run first and not counted.

    .venv/bin/python benchmarks/bending_speed.py [--images reports/bending/images] [--calib true|FILE] [--window 15]
"""
from __future__ import annotations

import argparse
import resource
import time
from pathlib import Path

import numpy as np

from measurement.calibration.io import CalibratedRig, load_calibration
from measurement.dic import DICSettings
from measurement.image_io import read_grey
from measurement.rigid import remove_rigid_motion
from measurement.stereo_dic import measure_state, reference_shape
from measurement.strain import surface_strain
from workbench.experiments.bending.run import _FacePoses, _overlap_roi, grid_values
from workbench.experiments.bending.scenes import load_bending_truth
from workbench.experiments.rigid_motion.run import face_roi
from workbench.rigs import get_rig


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--images", type=Path, default=Path("reports/bending/images"))
    ap.add_argument("--calib", default="true")
    ap.add_argument("--window", type=int, default=15)
    ap.add_argument("--states", type=int, default=5, help="load states to time (after the warm-up one)")
    args = ap.parse_args()
    truth = load_bending_truth(args.images)
    if args.calib == "true":
        rig = get_rig(truth.info["rig"]["name"], truth.info["rig"]["scale"])
        rig = CalibratedRig("rmm", rig.left, rig.right, rig.R_right_from_left, rig.T_right_from_left_mm)
    else:
        rig = load_calibration(args.calib)
    settings = DICSettings(subset_size=65, step=5, order=2)
    roi = _overlap_roi(truth, face_roi(_FacePoses(truth), 32), 32, 5)
    left_ref = read_grey(args.images / truth.files[0]["left"])
    right_ref = read_grey(args.images / truth.files[0]["right"])
    start = time.perf_counter()
    shape = reference_shape(rig.left, rig.right, rig.R_right_from_left, rig.T_right_from_left_mm, left_ref, right_ref,
                            settings, roi=roi)
    print(f"reference shape: {shape.x.size} points, {time.perf_counter() - start:.2f} s (once per sequence)")
    times = []
    for k in range(1, min(len(truth.files), args.states + 2)):
        left_def = read_grey(args.images / truth.files[k]["left"])
        right_def = read_grey(args.images / truth.files[k]["right"])
        start = time.perf_counter()
        state = measure_state(rig.left, rig.right, rig.R_right_from_left, rig.T_right_from_left_mm, shape, left_ref,
                              left_def, right_def, settings)
        stereo = time.perf_counter() - start
        removal = remove_rigid_motion(shape.X_mm, state.X_mm)
        surface_strain(grid_values(shape.X_mm, shape.grid), grid_values(removal.X1_aligned_mm, shape.grid), window=args.window)
        total = time.perf_counter() - start
        label = "warm-up (not counted)" if k == 1 else ""
        print(f"state {k} ({truth.loads_N[k]:.0f} N): stereo {stereo:.2f} s + strain {total - stereo:.2f} s = "
              f"{total:.2f} s {label}")
        if k > 1:
            times.append(total)
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(f"stereo + strain per load state: best {min(times):.2f} s, median {np.median(times):.2f} s "
          f"(goal <= 10 s); peak memory {peak:.0f} MiB")


if __name__ == "__main__":
    main()
