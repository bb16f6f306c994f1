"""``workbench catalog``: a catalog specimen's FE result and a scenario that renders it (issue 23).

    workbench catalog plate_with_hole --out my_plate        # my_plate/plate_with_hole.pvd (+ VTU), scenario.toml
    workbench render specimen my_plate/scenario.toml --out my_plate/images
"""
from __future__ import annotations

from pathlib import Path

from workbench.commands.options import output_folder, scale_arg


def add_parser(sub) -> None:
    from scenes.specimens.catalog import CATALOG

    ca = sub.add_parser("catalog", help="a catalog specimen (FE solved with scikit-fem) as a .pvd/VTU result and a "
                                        "scenario.toml that renders it with `workbench render specimen`")
    ca.add_argument("name", choices=sorted(CATALOG))
    ca.add_argument("--scale", type=scale_arg, default=0.25, help="the scenario's rig scale (1: the paper's 5 MP)")
    ca.add_argument("--out", type=Path, required=True, help="a new folder")


def catalog_command(args) -> int:
    import json

    from labio.atomic import atomic_write_text
    from scenes.specimens.catalog import CATALOG, write_pvd
    from workbench.experiments.specimen.catalog import scenario_text

    output_folder(args.out)
    result = CATALOG[args.name]()
    pvd = write_pvd(result, args.out)
    atomic_write_text(args.out / "scenario.toml", scenario_text(args.name, pvd.name, args.scale))
    readme = [f"# {result.name}", "", result.info.get("about", ""), "",
              f"- FE: {result.info['elements']} curved 27-node hexahedra (scikit-fem), solved in "
              f"{result.info['solve_s']} s; steps: " + ", ".join(f"{t:g}" for t in result.times) +
              f" ({result.load_unit})",
              f"- model: {json.dumps({k: v for k, v in result.info.items() if k not in ('about', 'elements', 'solve_s')})}",
              f"- files: `{pvd.name}` (ParaView collection), one VTU per step, point data `displacement` (mm)", "",
              "Render it in stereo with its per-pixel truth, then measure and score:", "", "```bash",
              "workbench render specimen scenario.toml --out images",
              "workbench export images --format native --out export      # calibration + images for any DIC tool",
              "workbench score images RESULTS... --out score", "```", ""]
    atomic_write_text(args.out / "README.md", "\n".join(readme))
    print(f"wrote {pvd} ({len(result.times)} steps, {result.info['elements']} elements), scenario.toml and README.md "
          f"to {args.out}")
    return 0


#: The handler of each (command, subcommand) this module adds.
HANDLERS = {("catalog", None): catalog_command}
