"""The catalog specimens' scenarios: what ``workbench catalog`` writes beside each FE result."""
from __future__ import annotations

#: Per specimen: the [specimen] table of its scenario beyond the file (paint, placement).
SCENARIO_EXTRAS = {
    "plate_with_hole": {},
    "notched_coupon": {},
    # a printed sheet wrapped on the tube (its axis: the specimen frame's y axis through z = R)
    "pressurised_cylinder": {"paint_method": "wrapped", "axis_point_mm": [0.0, 0.0, 57.0],
                             "axis_direction": [0.0, 1.0, 0.0]},
    "beam": {},
}


def scenario_text(name: str, file_name: str, scale: float, extras: dict | None = None) -> str:
    """The scenario TOML of a catalog specimen."""
    from workbench.config import dumps_toml

    specimen = {"mesh": file_name, **SCENARIO_EXTRAS[name], **(extras or {})}
    doc = {"experiment": "specimen", "seed": 0, "rig": {"name": "paper", "scale": scale}, "specimen": specimen}
    return f"# {name}: rendered by `workbench render specimen scenario.toml --out DIR`\n" + dumps_toml(doc)
