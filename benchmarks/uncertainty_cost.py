"""What the per-point uncertainty costs a stereo state at the paper's settings (issue 36: <= 10 %).

A speckled plate is rendered through the paper rig (``--scale 1``: 2456 x 2058 px) in a reference and a translated
state (deterministic exact renderer, 1 grey read noise, 8 bit); the instrument measures them with the paper's
settings (subset 65 px, step 5 px, second order) with and without the uncertainty, in one process, each the best
of ``--repeats`` runs. Printed: the reference shape's and the state's seconds both ways, the strain-window sigma's
seconds (pair covariances once per reference, then per state), and the overheads.

    .venv/bin/python benchmarks/uncertainty_cost.py [--scale 1.0] [--repeats 2] [--out reports/uncertainty_cost]

Run it alone: the machine's 2 cores are the benchmark's.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from timing import best_of  # noqa: E402


def render(scale: float):
    from scenes.rendering.exact import NotExactError, render_view_exact
    from scenes.sensor.noise import SensorNoise
    from scenes.rendering.mitsuba import render_view
    from scenes.specimens.plate import SpeckledPlate
    from workbench.experiments.calibration.views import sensor_spec_for
    from workbench.rigs import paper_rig

    rig = paper_rig(scale)
    mm_per_px = 85.0 / rig.left.width
    plate = SpeckledPlate(width_mm=70.0, height_mm=55.0, texel_mm=mm_per_px / 4, speckle_mm=4 * mm_per_px, seed=3)
    texture = plate.texture()
    axis_right = rig.R_right_from_left.T @ np.array([0.0, 0.0, 1.0])
    z = np.array([0.0, 0.0, 1.0]) + axis_right
    z /= np.linalg.norm(z)
    x = np.array([1.0, 0.0, 0.0]) - z[0] * z
    x /= np.linalg.norm(x)
    R_plate = np.column_stack([x, np.cross(z, x), z])
    centre = rig.optical_axes_meeting_point_mm()
    noise = SensorNoise(read_noise_grey=1.0, bit_depth=8)
    images = {}
    for state, offset in (("ref", np.zeros(3)), ("def", np.array([0.0, -1.0, 0.0]))):
        surface = plate.surface(R_plate, centre + offset, texture)
        for k, side in enumerate(("left", "right")):
            spec, (R, t) = sensor_spec_for(rig, side), rig.pose(side)
            try:
                image = render_view_exact(spec, R, t, [surface], exposure_grey=200.0)[0]
            except NotExactError:
                image = render_view(spec, R, t, [surface], spp=64, seed=k).image_grey
            images[f"{side}_{state}"] = noise.apply(image, seed=10 * k + (state == "def"))
    return rig, images


def scene(scale: float):
    """The rendered plate pair (:func:`render`, timed), the rig's four camera arguments and the central 40 % ROI."""
    t0 = time.perf_counter()
    rig, im = render(scale)
    print(f"rendered 4 images at scale {scale} in {time.perf_counter() - t0:.0f} s")
    cams = (rig.left, rig.right, rig.R_right_from_left, rig.T_right_from_left_mm)
    w, h = rig.left.width, rig.left.height
    return rig, im, cams, (int(0.3 * w), int(0.3 * h), int(0.7 * w), int(0.7 * h))


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scale", type=float, default=1.0)
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args(argv)

    from measurement.stereo_dic import STEREO_DIC_SETTINGS, measure_state, reference_shape
    from measurement.strain import surface_strain
    from measurement.uncertainty.strain import pair_covariances, state_strain_sigma
    from measurement.uncertainty.stereo import triangulation_sensitivity

    rig, im, cams, roi = scene(args.scale)
    s = STEREO_DIC_SETTINGS
    figures = {}
    for unc in (False, True, False, True):           # interleaved: a slow spell of the machine hits both
        shape_s, shape = best_of(lambda: reference_shape(*cams, im["left_ref"], im["right_ref"], s, roi=roi,
                                                         uncertainty=unc), args.repeats)
        state_s, state = best_of(lambda: measure_state(*cams, shape, im["left_ref"], im["left_def"], im["right_def"],
                                                       s), args.repeats)
        key = "with" if unc else "without"
        figures[f"shape_s_{key}"] = min(figures.get(f"shape_s_{key}", np.inf), shape_s)
        figures[f"state_s_{key}"] = min(figures.get(f"state_s_{key}", np.inf), state_s)
        figures["points"] = int(shape.x.size)
    # the same state warm-started from a state of the same sequence (measure_state's previous=): no feature matching
    warm_s, warm = best_of(lambda: measure_state(*cams, shape, im["left_ref"], im["left_def"], im["right_def"], s,
                                                 previous=state), args.repeats)
    figures["state_s_warm"] = warm_s
    figures["warm_seeded_by"] = warm.seeded_by
    grid = shape.grid

    def on_grid(v):
        out = np.full(grid.shape + (3,), np.nan)
        out[grid.active] = v
        return out

    strain_s, strain = best_of(lambda: surface_strain(on_grid(shape.X_mm), on_grid(state.X_mm), window=9),
                               args.repeats)
    pairs_s, pairs = best_of(lambda: pair_covariances(shape.reference, shape.subsets, shape.right_match.grid_index,
                                                      grid.shape, grid.step, window=9), args.repeats)
    G_ref = triangulation_sensitivity(*cams, shape.X_mm)
    G_def = triangulation_sensitivity(*cams, state.X_mm)
    sigma_s, _ = best_of(lambda: state_strain_sigma(shape, state, strain, G_ref, G_def, pairs), args.repeats)
    figures.update(strain_s=strain_s, strain_pairs_s=pairs_s, strain_sigma_s=sigma_s, scale=args.scale,
                   subset_px=s.subset_size, step_px=s.step, order=s.order)
    figures["state_overhead_percent"] = 100 * (figures["state_s_with"] / figures["state_s_without"] - 1)
    figures["shape_overhead_percent"] = 100 * (figures["shape_s_with"] / figures["shape_s_without"] - 1)
    lines = [f"points: {figures['points']} (subset {s.subset_size} px, step {s.step} px, order {s.order}, scale "
             f"{args.scale})",
             f"reference shape: {figures['shape_s_without']:.2f} s without, {figures['shape_s_with']:.2f} s with the "
             f"uncertainty ({figures['shape_overhead_percent']:+.1f} %)",
             f"state: {figures['state_s_without']:.2f} s without, {figures['state_s_with']:.2f} s with "
             f"({figures['state_overhead_percent']:+.1f} %; goal <= +10 %)",
             f"state warm-started from the state before it (seeds {figures['warm_seeded_by']}): "
             f"{figures['state_s_warm']:.2f} s with the uncertainty",
             f"strain window 9: {strain_s:.2f} s; its sigma: pair covariances {pairs_s:.2f} s once per reference, "
             f"{sigma_s:.2f} s per state"]
    print("\n".join(lines))
    if args.out is not None:
        args.out.mkdir(parents=True, exist_ok=True)
        (args.out / "uncertainty_cost.json").write_text(json.dumps(figures, indent=1))
        (args.out / "README.md").write_text("# What the per-point uncertainty costs\n\n" + "\n".join(
            f"- {line}" for line in lines) + "\n\nReproduce: `.venv/bin/python benchmarks/uncertainty_cost.py "
            f"--scale {args.scale} --out DIR` (alone on the machine).\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
