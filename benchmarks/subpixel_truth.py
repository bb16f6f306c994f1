"""The truth below a pixel (issue 38): every render path's own sub-pixel error, before and after the paint is
looked up at 20 texels per speckle, and what it costs.

A speckled plate (5 px speckles) faces a 96 x 96 px camera square on and moves in its plane by k/8 px (k = 0..8)
along x and by seeded random fractions along both axes. For every path and phase (:mod:`workbench.experiments.subpixel`):

* render error: DIC from the converged reference (16 x 16 rays per pixel, the paint's band-limited interpolant) to
  the render of the same position -- RMS and mean over ~120 points, px;
* motion error: DIC from the render at rest to the render moved, minus the motion, beside the instrument alone on
  the two references (the exact images).

The twin's photographed texture (:mod:`scenes.surfaces.image_texture`) is checked on a periodic 5 px speckle
"photograph", whose exact motion is its Fourier shift: render error = DIC from that shift to the twin's image.

"before" looks the pattern itself up (5 texels per speckle, as every mesh-specimen path did before issue 38); the
paper's planar specimens look up their own pattern at 3.5 texels per pixel (17.5 per speckle). Time: the texture
of a plate filling a 1024 x 1024 px view, and the view, before and after, in this process.

    .venv/bin/python benchmarks/subpixel_truth.py [--random 6] [--paths quadrature,mitsuba]
"""
from __future__ import annotations

import argparse
import json
import platform
import time
from pathlib import Path

import numpy as np

from scenes.rendering.exact import render_view_exact
from workbench.experiments.subpixel import PATHS, PlateScene, phase_errors

from timing import best_of


def _variants(paths):
    """(label, scene, path) rows of the table."""
    out = []
    for path in paths:
        out.append((f"{path}, before", PlateScene(lookup_factor=1), path))
        out.append((f"{path}", PlateScene(), path))
    out.append(("quadrature, Scheimpflug tilt 4 deg + k1 -0.2, before", PlateScene(lookup_factor=1, alpha_deg=4.0,
                                                                                   k1=-0.2), "quadrature"))
    out.append(("quadrature, Scheimpflug tilt 4 deg + k1 -0.2", PlateScene(alpha_deg=4.0, k1=-0.2), "quadrature"))
    out.append(("paper planar texture (3.5 texels/px)", PlateScene(texel_px=1 / 3.5, lookup_factor=1), "quadrature"))
    return out


def _summary_line(label: str, rows: list[dict]) -> str:
    """One table row: the worst render error (and its phase), the largest |mean|, the worst motion error, the
    instrument alone."""
    worst = max(rows, key=lambda r: r["render_rms_px"])
    worst_motion = max(rows, key=lambda r: r["motion_rms_px"])
    mean = max(max(abs(v) for v in r["render_mean_px"]) for r in rows)
    alone = max(r["instrument_alone_rms_px"] for r in rows)
    return (f"{label:58s} | {worst['render_rms_px']:.5f} ({worst['phase_px'][0]:g}, {worst['phase_px'][1]:g}) / "
            f"{mean:.5f} | {worst_motion['motion_rms_px']:.5f} at ({worst_motion['phase_px'][0]:g}, "
            f"{worst_motion['phase_px'][1]:g}) | {alone:.5f}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--random", type=int, default=6, help="random (x, y) fractions besides k/8 along x")
    ap.add_argument("--paths", default=",".join(PATHS), help="comma-separated render paths")
    ap.add_argument("--json", type=Path, help="write the rows here")
    args = ap.parse_args()
    rng = np.random.default_rng(38)
    phases = [(k / 8, 0.0) for k in range(9)] + [tuple(p) for p in rng.random((args.random, 2)).round(3)]
    print(f"machine: {platform.platform()}, {platform.processor() or platform.machine()}; phases: k/8 px along x "
          f"(k = 0..8) and {args.random} random (x, y) fractions")
    print(f"{'path':58s} | render error px RMS: worst (at) / max |mean| | motion error px RMS: worst | alone")
    table = []
    for label, scene, path in _variants([p.strip() for p in args.paths.split(",") if p.strip()]):
        rows = phase_errors(scene, path, phases)
        print(_summary_line(label, rows))
        table.append({"label": label, "path": path, "rows": rows})
    from scenes.surfaces.speckle import speckle_pattern
    from workbench.experiments.subpixel import photo_phase_errors

    photo = 20.0 + 200.0 * speckle_pattern((192, 192), 5.0, contrast=0.8, seed=3).astype(float)
    for label, upsample in (("twin photo texture, before (cubic through pixels)", 1), ("twin photo texture", None)):
        import scenes.surfaces.image_texture as image_texture

        kept = image_texture.UPSAMPLE
        image_texture.UPSAMPLE = upsample or kept
        try:
            rows = photo_phase_errors(photo, phases)
        finally:
            image_texture.UPSAMPLE = kept
        print(_summary_line(label, rows))
        table.append({"label": label, "path": "photo", "rows": rows})
    print("\nper phase (render error RMS px), k/8 along x:")
    for t in table:
        print(f"  {t['label']:58s} " + " ".join(f"{r['render_rms_px']:.4f}" for r in t["rows"][:9]))
    print("\ntime of one 1024 x 1024 px view of a plate filling it (quadrature), best of 2 after a warm-up; the "
          "texture is made once per specimen, the view once per camera and state:")
    times = {}
    for label, factor in (("before (pattern looked up)", 1), ("after (4x band-limited texture)", None)):
        scene = PlateScene(size_px=1024, lookup_factor=factor)
        t_texture, surfaces = best_of(lambda: scene.surfaces(), 2)
        render_view_exact(scene.spec(), np.eye(3), np.zeros(3), surfaces)          # compile / warm caches
        t_view, _ = best_of(lambda: render_view_exact(scene.spec(), np.eye(3), np.zeros(3), surfaces), 2)
        times[label] = {"texture_s": t_texture, "view_s": t_view, "texels": int(surfaces[0].texture.size)}
        print(f"  {label:34s} texture {t_texture:5.2f} s ({surfaces[0].texture.size / 1e6:.1f} M texels), "
              f"view {t_view:5.2f} s")
    a, b = times["after (4x band-limited texture)"], times["before (pattern looked up)"]
    print(f"  per view: {a['view_s'] / b['view_s']:.2f} x; a specimen of 2 cameras x 5 states: "
          f"{(a['texture_s'] + 10 * a['view_s']) / (b['texture_s'] + 10 * b['view_s']):.2f} x (goal <= 1.5)")
    if args.json:
        args.json.write_text(json.dumps({"table": table, "times_s": times, "machine": platform.platform()}, indent=1))


if __name__ == "__main__":
    main()
