"""Issue 38's table on a catalog specimen: 2-D DIC error against the rendered truth, binned by the sub-pixel
fraction of the true motion.

The catalog's plate with a hole (``workbench reproduce catalog``'s scenario, rendered through the store: its
load steps, then the rigid tour of 4 moves through up to 10 px, then the static state moved by (0.5, 0.5) px), the
instrument's 2-D DIC (subset 33, step 8, second order, biquintic) on the left images, state 0 -> k, on the
measurable part of the reference. Each point's error (measured minus true ``uv_left_px``) is binned by the distance
of its true motion from the nearest whole pixel, per component; the static state's error is the floor.

    .venv/bin/python benchmarks/subpixel_specimen.py [--name plate_with_hole] [--scale 0.25] [--lens thin]
"""
from __future__ import annotations

import argparse
import platform
import tempfile
from pathlib import Path

import numpy as np

#: Distance of the true motion from the nearest whole pixel, px: the issue's bins.
BINS = ((0.0, 0.1), (0.2, 0.3), (0.4, 0.5))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--name", default="plate_with_hole")
    ap.add_argument("--scale", type=float, default=0.25)
    ap.add_argument("--subset", type=int, default=33)
    ap.add_argument("--step", type=int, default=8)
    ap.add_argument("--lens", choices=("pinhole", "thin"), default="pinhole",
                    help="the rig's lens model (thin: f/8, focused on the specimen)")
    args = ap.parse_args()

    from measurement.dic import DICSettings, correlate
    from measurement.image_io import read_grey
    from scenes.specimens.catalog import CATALOG, write_pvd
    from workbench.config import load_config
    from workbench.experiments.specimen.case import measurable_mask
    from workbench.experiments.specimen.catalog import scenario_text
    from workbench.experiments.specimen.run import rigid_tour_extras
    from workbench.experiments.specimen.scenes import load_specimen_truth, render_specimen
    from workbench.scenario import Scenario, dataset_parts, with_specimen_paths
    from workbench.scoring.datasets import open_dataset, point_truth
    from workbench.store import DatasetStore

    with tempfile.TemporaryDirectory() as tmp:
        fe_dir = Path(tmp) / "fe"
        pvd = write_pvd(CATALOG[args.name](), fe_dir)
        text = scenario_text(args.name, pvd.name, args.scale, rigid_tour_extras(args.scale))
        (fe_dir / "scenario.toml").write_text(text.replace("[rig]\n", f'[rig]\nlens = "{args.lens}"\n', 1))
        scenario = with_specimen_paths(load_config(Scenario, fe_dir / "scenario.toml"), fe_dir)
        key, content = dataset_parts(scenario)["states"]
        images, reused = DatasetStore().ensure("specimen", key, content,
                                               lambda f: render_specimen(scenario, f, progress=True, overwrite=True))
    truth = load_specimen_truth(images)
    dataset = open_dataset(images)
    print(f"machine: {platform.platform()}; {args.name}, scale {args.scale:g}, {args.lens} lens, f/8 diffraction, "
          f"dataset {images} "
          f"({'reused' if reused else 'rendered'}); 2-D DIC subset {args.subset}, step {args.step}, order 2")
    settings = DICSettings(subset_size=args.subset, step=args.step, order=2)
    reference = read_grey(dataset.images[0]["left"])
    mask = measurable_mask(truth, args.subset)
    errors, fractions, static = [], [], None
    for k in range(1, dataset.n_states):
        result = correlate(reference, read_grey(dataset.images[k]["left"]), settings, mask=mask)
        pt = point_truth(dataset, result.x, result.y)
        true_uv = pt.uv_left_px[k]
        err = np.column_stack([result.u, result.v]) - true_uv
        ok = np.all(np.isfinite(err), axis=1) & pt.valid
        label = truth.labels[k]
        rms = np.sqrt(np.mean(err[ok] ** 2, axis=0))
        span = np.nanmax(np.abs(true_uv[ok]), axis=0)
        print(f"  state {k} ({label}): {ok.sum()} points, |motion| up to ({span[0]:.2f}, {span[1]:.2f}) px, "
              f"error RMS u {rms[0]:.4f} v {rms[1]:.4f} px, mean ({np.mean(err[ok, 0]):+.4f}, "
              f"{np.mean(err[ok, 1]):+.4f})")
        if label.startswith("static"):
            static = rms
            continue
        errors.append(err[ok])
        fractions.append(np.abs(true_uv[ok] - np.round(true_uv[ok])))
    errors, fractions = np.concatenate(errors), np.concatenate(fractions)
    print("\nerror RMS (u / v) px by the distance of the true motion from a whole pixel, all moving states:")
    cells = []
    for lo, hi in BINS:
        row = []
        for c in range(2):
            sel = (fractions[:, c] >= lo) & (fractions[:, c] < hi + (1e-9 if hi == 0.5 else 0))
            row.append(f"{np.sqrt(np.mean(errors[sel, c] ** 2)):.4f} ({sel.sum()})" if sel.sum() >= 20 else "—")
        cells.append(" / ".join(row))
    print("| | within 0.1 px of a whole pixel | 0.2-0.3 px | 0.4-0.5 px | static (moved (0.5, 0.5) px) |")
    print("|---|---|---|---|---|")
    floor = "—" if static is None else f"{static[0]:.4f} / {static[1]:.4f}"
    print(f"| {args.name}, scale {args.scale:g}, {args.lens} (u / v, points) | " + " | ".join(cells)
          + f" | {floor} |")

    # What is measurable: the instrument alone on the reference moved by an exact (band-limited) shift, with fresh
    # sensor noise of the scenario's model, on the same points.
    from scenes.sensor.noise import SensorNoise
    from workbench.experiments.subpixel import fourier_shift

    r = scenario.render
    noise = SensorNoise(read_noise_grey=r.read_noise_grey, electrons_per_grey=r.electrons_per_grey, bit_depth=8)
    pad = 64
    padded = np.pad(reference.astype(float), pad, mode="symmetric")
    print("\ninstrument alone (the left reference Fourier-shifted, fresh noise), error RMS u / v px:")
    for i, shift in enumerate(((0.0, 0.0), (0.25, 0.25), (0.5, 0.5), (1.0, 1.0))):
        moved = fourier_shift(padded, shift)[pad:-pad, pad:-pad]
        moved = noise.apply(np.maximum(moved, 0.0), seed=1000 + i)
        result = correlate(reference, moved, settings, mask=mask)
        err = np.column_stack([result.u, result.v]) - np.array(shift)
        ok = np.all(np.isfinite(err), axis=1)
        rms = np.sqrt(np.mean(err[ok] ** 2, axis=0))
        print(f"  shift ({shift[0]:g}, {shift[1]:g}) px: {rms[0]:.4f} / {rms[1]:.4f} ({ok.sum()} points)")


if __name__ == "__main__":
    main()
