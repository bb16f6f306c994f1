"""The schema of ``truth.json`` (rigid-motion and bending datasets): the parts both share, validated.

Both loaders (:func:`workbench.experiments.rigid_motion.scenes.load_truth`,
:func:`workbench.experiments.bending.scenes.load_bending_truth`) walk the file with
:class:`labio.schema.Node`, so every defect (missing key, wrong type, non-finite or out-of-range value,
a matrix that is not a rotation, a dataclass field missing or unknown) is a
:class:`~labio.schema.FileFormatError` (a ``ValueError``) naming the file and the key, never a
``KeyError``/``TypeError`` or a silently substituted default.
"""
from __future__ import annotations

from pathlib import Path, PurePath

import numpy as np

from labio.schema import FileFormatError, Node, read_json_file
from scenes.optics.camera import EXTRA_LENS_TERMS, SensorSpec
from scenes.specimens.beam import BendingSpecimen

SIDES = ("left", "right")
#: Positions and translations in truth files: |x| below this (mm).
MAX_MM = 1e6

#: Physical ranges (open intervals, or (lo, hi, lo_open, hi_open)) of the dataclass fields in truth files.
SPECIMEN_RANGES = {"length_mm": (0.0, 1e4), "height_mm": (0.0, 1e4), "thickness_mm": (0.0, 1e4),
                   "texel_mm": (1e-6, 1e4), "speckle_mm": (0.0, 1e4), "grid_mm": (1e-3, 1e4)}
SENSOR_RANGES = {"fx": (0.0, 1e6), "fy": (0.0, 1e6), "cx": (-1e6, 1e6), "cy": (-1e6, 1e6),
                 "width": (1, 1_000_000), "height": (1, 1_000_000),
                 "alpha_deg": (-45.0, 45.0), "beta_deg": (-45.0, 45.0),
                 "k1": (-1e3, 1e3), "k2": (-1e3, 1e3), "p1": (-1e3, 1e3), "p2": (-1e3, 1e3),
                 "focal_length_mm": (0.0, 1e4, False, True), "f_number": (0.0, 1e4, False, True),
                 "pixel_pitch_mm": (0.0, 1.0)}
BEAM_RANGES = {"length_mm": (0.0, 1e4), "height_mm": (0.0, 1e4), "thickness_mm": (0.0, 1e4),
               "span_mm": (0.0, 1e4), "youngs_modulus_mpa": (0.0, 1e7), "poisson_ratio": (-1.0, 0.5),
               "nose_width_mm": (0.0, 1e4), "support_width_mm": (0.0, 1e4), "element_mm": (1e-3, 1e4)}


def read_truth(out_dir) -> Node:
    """``out_dir/truth.json`` as a Node (FileNotFoundError if absent; FileFormatError if not a JSON object)."""
    path = Path(out_dir) / "truth.json"
    if not path.is_file():
        raise FileNotFoundError(f"no truth.json in {out_dir}")
    doc = read_json_file(path, "truth file")
    doc.mapping()
    return doc


def typed(node: Node, cls, type_name: str, ranges: dict):
    """A dataclass from a mapping tagged ``"type": type_name`` (tag optional), every field required."""
    tag = node.get("type")
    if tag is not None:
        tag.string((type_name,))
    return node.dataclass(cls, ranges=ranges, ignore=("type",))


def specimen(node: Node) -> BendingSpecimen:
    return typed(node, BendingSpecimen, "BendingSpecimen", SPECIMEN_RANGES)


def position(node: Node) -> np.ndarray:
    return node.array((3,), bound=MAX_MM)


def cameras(doc: Node) -> tuple[dict[str, SensorSpec], dict[str, tuple[np.ndarray, np.ndarray]]]:
    """The ``cameras`` block: per side a SensorSpec and the pose (R_cam_from_world, t_cam_from_world_mm)."""
    cams = doc["cameras"]
    specs, poses = {}, {}
    for side in SIDES:
        cam = cams[side]
        # lens terms added later (k3, thin prism) may be absent from older files: absent = 0
        specs[side] = cam["sensor_spec"].dataclass(SensorSpec, ranges=SENSOR_RANGES, optional=EXTRA_LENS_TERMS)
        poses[side] = (cam["R_cam_from_world"].rotation(), position(cam["t_cam_from_world_mm"]))
    return specs, poses


def states(doc: Node) -> list[Node]:
    """The ``states`` list (at least one), each a mapping whose ``index`` (if given) is its position."""
    out = doc["states"].sequence(min_len=1)
    for k, state in enumerate(out):
        state.mapping()
        index = state.get("index")
        if index is not None and index.integer() != k:
            raise index.error(f"must be {k} (the state's position in the list), got {index.value!r}")
    return out


def files(state: Node) -> dict[str, str]:
    """A state's image names ``{"left": name, "right": name}``, relative to the dataset folder."""
    node = state["files"]
    node.only_keys(SIDES)
    names = {}
    for side in SIDES:
        child = node[side]
        name = child.string()
        if "\x00" in name or PurePath(name).is_absolute() or ".." in PurePath(name).parts:
            raise child.error(f"must be a file name inside the dataset folder, got {name!r}")
        names[side] = name
    return names


def info(doc: Node, known: tuple[str, ...], lenses: tuple[str, ...]) -> dict:
    """The rest of the file (render settings, rig, lens ...): ``lens`` required; ``rig``/``render`` mappings."""
    doc["lens"].string(lenses)
    for key in ("rig", "render"):
        node = doc.get(key)
        if node is not None:
            node.mapping()
    return {k: v for k, v in doc.mapping().items() if k not in known}


__all__ = ["FileFormatError", "read_truth", "typed", "specimen", "position", "cameras", "states", "files", "info"]
