"""Speed of a specimen of one's own at full resolution (issue 23): a 100 000-element FE result to its first rendered
stereo pair, and the truth (ray-surface intersection) of a 5 MP image.

    .venv/bin/python benchmarks/specimen_speed.py [--elements 100000] [--out reports/specimen_speed]

The FE result is a 120 x 60 x 3 mm plate of linear tetrahedra with a smooth displacement over 2 steps, written as
Exodus (what MOOSE writes); the scenario is the paper's rig at full resolution (2456 x 2058 px). Timed stages:
reading the file (outer surface included), the specimen (tessellation, paint layout), the speckle texture, the
per-pixel truth of one reference image (ray cast + Newton onto the surface), both cameras' first image. Run it alone:
the machine's 2 cores are the benchmark's.
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np


def plate_mesh(elements: int):
    """A tetrahedral plate of about ``elements`` cells (6 per hexahedron of a tensor grid)."""
    import skfem
    from skfem.io.meshio import to_meshio

    hexes = elements / 6
    nz = 4
    # 120 x 60 mm in-plane, nx = 2 ny
    ny = int(round(np.sqrt(hexes / (2 * nz))))
    nx = 2 * ny
    m = to_meshio(skfem.MeshTet.init_tensor(np.linspace(-60, 60, nx + 1), np.linspace(-30, 30, ny + 1),
                                            np.linspace(0, 3, nz + 1)))
    return m.points, m.cells[0].data


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--elements", type=int, default=100_000)
    ap.add_argument("--out", type=Path, default=Path("reports/specimen_speed"))
    args = ap.parse_args(argv)

    from scenes.specimens.fe_files import write_exodus
    from scenes.sensor.noise import SensorNoise
    from workbench.config import from_dict
    from workbench.scenario import Scenario

    work = args.out / "work"
    work.mkdir(parents=True, exist_ok=True)
    P, T = plate_mesh(args.elements)
    x, y = P[:, 0], P[:, 1]
    U1 = np.column_stack([1e-3 * x + 2e-5 * y * y, -3e-4 * y + 1e-5 * x * y, 1e-4 * (x * x + y * y) / 60])
    write_exodus(work / "plate.e", P, {"tetra": T}, np.stack([0 * U1, U1]), times=[0.0, 1.0])
    scenario = from_dict(Scenario, {"experiment": "specimen", "rig": {"name": "paper", "scale": 1.0},
                                    "specimen": {"mesh": str(work / "plate.e"), "static_pair": False}})
    figures = {"elements": int(len(T)), "nodes": int(len(P)), "image_px": [2456, 2058]}
    import warnings
    warnings.simplefilter("ignore")
    t0 = time.perf_counter()
    from workbench.experiments.specimen.scenes import build_specimen
    from workbench.experiments.bending.scenes import bending_specs
    from workbench.rigs import get_rig

    start = time.perf_counter()
    built = build_specimen(scenario)
    figures["read_place_paint_s"] = time.perf_counter() - start
    spec = built.specimen
    figures["surface_triangles"] = int(len(spec.tessellation.triangles))
    start = time.perf_counter()
    spec.texture()
    figures["texture_s"] = time.perf_counter() - start
    rig = get_rig("paper", 1.0)
    specs = bending_specs(rig, "pinhole", built.pose[1])
    cams = {side: (specs[side], *rig.pose(side)) for side in ("left", "right")}
    start = time.perf_counter()
    pt = spec.material_points(*cams["left"], *built.pose)
    figures["truth_5mp_s"] = time.perf_counter() - start
    figures["truth_pixels_on_specimen"] = int(np.sum(pt.face >= 0))
    start = time.perf_counter()
    pt = spec.material_points(*cams["left"], *built.pose)
    figures["truth_5mp_again_s"] = time.perf_counter() - start
    from scenes.rendering.adaptive import AdaptiveSettings, render_views_auto
    start = time.perf_counter()
    views = [(specs[side], rig.pose(side)) for side in ("left", "right")]
    auto = render_views_auto(views, spec.surfaces(0, *built.pose), seed=0, exposure_grey=255.0,
                             settings=AdaptiveSettings(target_mc_grey=0.3))
    noise = SensorNoise(read_noise_grey=1.0, bit_depth=8)
    images = [noise.apply(a.image_grey, seed=c) for c, a in enumerate(auto)]
    figures["first_stereo_pair_render_s"] = time.perf_counter() - start
    figures["renderers"] = [a.renderer for a in auto]
    figures["file_to_first_pair_s"] = time.perf_counter() - t0
    figures["image_mean_grey"] = [float(np.mean(im)) for im in images]
    lines = [f"specimen speed benchmark ({time.strftime('%Y-%m-%d')}, 2-core machine, nothing else running)",
             f"FE: {figures['elements']} linear tetrahedra, {figures['nodes']} nodes, Exodus, 2 steps; surface "
             f"{figures['surface_triangles']} triangles",
             f"read + outer surface + placement + paint layout: {figures['read_place_paint_s']:.2f} s",
             f"speckle texture: {figures['texture_s']:.2f} s",
             f"truth of the 5 MP left reference image (ray cast + Newton): {figures['truth_5mp_s']:.2f} s (first: "
             f"undistorted pixel rays computed and cached), {figures['truth_5mp_again_s']:.2f} s again; "
             f"{figures['truth_pixels_on_specimen']} pixels on the specimen",
             f"first stereo pair (both 5 MP cameras, {', '.join(figures['renderers'])}): "
             f"{figures['first_stereo_pair_render_s']:.2f} s",
             f"file -> first stereo pair (everything above, from import): {figures['file_to_first_pair_s']:.1f} s "
             f"(goal <= 60 s); truth of a 5 MP image goal <= 10 s"]
    print("\n".join(lines))
    (args.out / "benchmark.txt").write_text("\n".join(lines) + "\n")
    (args.out / "benchmark.json").write_text(json.dumps(figures, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
