"""Speed of the digital twin on a 5 MP stereo rig, what-if table included (issue 24 goal: <= 10 min on 2 cores).

The "user's files" are made first (not timed): the paper's rig at full resolution (two 2456 x 2058 px Scheimpflug
cameras) looking at a plane with an analytic Gaussian speckle (4 px), two exposures per camera with read noise 1.5
grey and 30 e-/grey, 8 bit, and the rig's calibration as the project's JSON. Then ``workbench twin`` runs on them
exactly as a user would call it (subset 33, step 8, order 2, strain window 5, automatic ROI, two twin repeats, the
what-if table and the top recommendation applied to the pair), and its stages are timed.

    .venv/bin/python benchmarks/twin_speed.py [--scale 1.0] [--work reports/twin_speed/work] [--out reports/twin_speed]
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(HERE))

from labio.atomic import atomic_write_text  # noqa: E402


def make_user_files(work: Path, scale: float) -> dict:
    import cv2

    from measurement.calibration.formats import save_calibration_as
    from measurement.calibration.io import CalibratedRig
    from scenes.surfaces.image_texture import ImageTexture, TexturedPlane, render_plane_view
    from scenes.sensor.noise import apply_sensor_noise
    from scenes.image_pairs.gaussian_speckle import extent_for_shape, gaussian_speckle, radius_for_speckle_size
    from workbench.experiments.calibration.views import sensor_spec_for
    from workbench.rigs import get_rig
    from workbench.twin.scene import default_plane

    work.mkdir(parents=True, exist_ok=True)
    rig = get_rig("paper", scale)
    specs = {side: sensor_spec_for(rig, side) for side in ("left", "right")}
    shape = (specs["left"].height, specs["left"].width)
    pattern = gaussian_speckle(extent_for_shape(shape, 8.0), radius_for_speckle_size(4.0), 0.5, 11,
                               mean_grey=110.0, std_grey=35.0)
    left_clean = pattern.render_reference(shape)
    point, normal = default_plane(rig)
    plane = TexturedPlane(point, normal, ImageTexture.from_image(left_clean), specs["left"], rig.pose("left"))
    right_clean, _ = render_plane_view(specs["right"], rig.pose("right"), plane)
    files = {}
    for k, (side, clean) in enumerate((("left", left_clean), ("right", right_clean))):
        for draw in (0, 1):
            noisy = apply_sensor_noise(np.clip(clean, 0, None), read_noise_grey=1.5, electrons_per_grey=30.0,
                                       bit_depth=8, seed=100 + 10 * k + draw)
            path = work / f"{side}_{draw}.png"
            cv2.imwrite(str(path), noisy.astype(np.uint8))
            files[f"{side}_{draw}"] = path
    cal = work / "calibration.json"
    save_calibration_as(CalibratedRig("rmm", rig.left, rig.right, rig.R_right_from_left, rig.T_right_from_left_mm),
                        cal, "json")
    files["calibration"] = cal
    files["shape"] = shape
    return files


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--scale", type=float, default=1.0)
    p.add_argument("--work", type=Path, default=HERE / "reports" / "twin_speed" / "work")
    p.add_argument("--out", type=Path, default=HERE / "reports" / "twin_speed")
    args = p.parse_args(argv)
    t0 = time.perf_counter()
    files = make_user_files(args.work, args.scale)
    print(f"user files made in {time.perf_counter() - t0:.0f} s: {files['shape'][1]} x {files['shape'][0]} px",
          flush=True)
    from workbench.cli import main as cli

    start = time.perf_counter()
    code = cli(["twin", "--calib", str(files["calibration"]), "--left", str(files["left_0"]),
                "--right", str(files["right_0"]), "--static-left", str(files["left_1"]),
                "--static-right", str(files["right_1"]), "--auto-roi", "--subset", "33", "--step", "8",
                "--out", str(args.out / "twin")])
    wall = time.perf_counter() - start
    doc = json.loads((args.out / "twin" / "twin.json").read_text())
    megapixels = files["shape"][0] * files["shape"][1] / 1e6
    summary = {"exit_code": code, "wall_s": wall, "megapixels_per_camera": megapixels,
               "points": doc["prediction"]["points"], "stages_s": doc["timings_s"],
               "whatif_rows": sum(1 for r in doc["whatif"] if r.get("displacement_noise") is not None),
               "comparison": {k: v["ratio"] for k, v in (doc["comparison"] or {}).items()}}
    atomic_write_text(args.out / "summary.json", json.dumps(summary, indent=1))
    lines = ["# Twin speed: a 5 MP stereo rig", "",
             f"`workbench twin` on two {files['shape'][1]} x {files['shape'][0]} px cameras ({megapixels:.2f} MP "
             "each), "
             f"subset 33, step 8, order 2, automatic ROI, 2 twin repeats, what-if table "
             f"({summary['whatif_rows']} rows measured) and the top recommendation applied to the pair: "
             f"**{wall / 60:.1f} min** wall on this machine (goal <= 10 min on 2 cores), "
             f"{summary['points']} points.", "", "| stage | s |", "|---|---|"]
    lines += [f"| {k} | {v:.1f} |" for k, v in doc["timings_s"].items()]
    lines += ["", "Predicted / measured on the pair: " + ", ".join(f"{k} {v:.3f}" for k, v in
                                                                   summary["comparison"].items()), "",
              "Reproduce: `.venv/bin/python benchmarks/twin_speed.py` (nothing else running).", ""]
    atomic_write_text(args.out / "report.md", "\n".join(lines))
    print("\n".join(lines))
    return code


if __name__ == "__main__":
    sys.exit(main())
