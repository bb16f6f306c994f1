"""``workbench catalog``: a catalog specimen's FE result and a scenario that renders it (issue 23).

    workbench catalog plate_with_hole --out my_plate        # my_plate/plate_with_hole.pvd (+ VTU), scenario.toml
    workbench render specimen my_plate/scenario.toml --out my_plate/images
"""
from __future__ import annotations

from pathlib import Path

from workbench.commands.options import output_folder, scale_arg

#: Per specimen: the [specimen] table of its scenario beyond the file (paint, placement).
SCENARIO_EXTRAS = {
    "plate_with_hole": {},
    "notched_coupon": {},
    # a printed sheet wrapped on the tube (its axis: the specimen frame's y axis through z = R)
    "pressurised_cylinder": {"paint_method": "wrapped", "axis_point_mm": [0.0, 0.0, 57.0],
                             "axis_direction": [0.0, 1.0, 0.0]},
    "beam": {},
}


def add_parser(sub) -> None:
    from scenes.fe_catalog import CATALOG

    ca = sub.add_parser("catalog", help="a catalog specimen (FE solved with scikit-fem) as a .pvd/VTU result and a "
                                        "scenario.toml that renders it with `workbench render specimen`")
    ca.add_argument("name", choices=sorted(CATALOG))
    ca.add_argument("--scale", type=scale_arg, default=0.25, help="the scenario's rig scale (1: the paper's 5 MP)")
    ca.add_argument("--out", type=Path, required=True, help="a new folder")


def scenario_text(name: str, file_name: str, scale: float, extras: dict | None = None) -> str:
    """The scenario TOML of a catalog specimen."""
    from workbench.config import dumps_toml

    specimen = {"mesh": file_name, **SCENARIO_EXTRAS[name], **(extras or {})}
    doc = {"experiment": "specimen", "seed": 0, "rig": {"name": "paper", "scale": scale}, "specimen": specimen}
    return f"# {name}: rendered by `workbench render specimen scenario.toml --out DIR`\n" + dumps_toml(doc)


def catalog_command(args) -> int:
    import json

    from labio.atomic import atomic_write_text
    from scenes.fe_catalog import CATALOG, write_pvd

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
