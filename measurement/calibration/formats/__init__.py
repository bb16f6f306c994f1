"""Calibration files of the field's DIC tools: DICe ``cal.xml``, VIC-3D calibration XML, MatchID ``.caldat``, MATLAB
``stereoParameters`` structs (JSON or MAT-file).

Each format module documents the conventions it follows and the sources they were checked against (extrinsics
direction, Euler angles, units, camera numbering, pixel origin). Writers convert cameras into the format's model
with :func:`~measurement.calibration.formats.nearest.nearest_camera` and return a :class:`ConversionReport` saying
per camera what the format could not hold and what that costs in pixels; they write atomically, and only text that
loads back to the converted rig. Loaders never execute content (``xml.etree`` without entities) and turn every
defect into a :class:`~labio.schema.FileFormatError` naming the file and the key.

Public API::

    load_any_calibration(path, *, image_size_px=None) -> CalibratedRig
    save_calibration_as(rig, path, format, *, frame_rotation=False) -> ConversionReport
    load_dice(path), save_dice(rig, path, *, frame_rotation=False)
    load_vic3d(path, *, image_size_px=None), save_vic3d(rig, path, *, frame_rotation=False)
    load_matchid(path, image_size_px), save_matchid(rig, path, *, frame_rotation=False)
    load_matlab(path, *, image_size_px=None), save_matlab(rig, path, *, frame_rotation=False, intrinsics_key=...)
    nearest_camera(camera, model, *, frame_rotation=False) -> (camera_in_model, ConversionCost)
"""
from __future__ import annotations

from pathlib import Path

from measurement.calibration.io import CalibratedRig, load_calibration, save_rig
from labio.schema import FileFormatError

from . import _common
from ._common import CameraConversion, ConversionReport
from .dice import load_dice, looks_like_dice, save_dice
from .matchid import load_matchid, looks_like_matchid, save_matchid
from .matlab import MATLAB_MODEL, is_mat_file, load_matlab, looks_like_matlab, save_matlab
from .nearest import (DICE_MODEL, MATCHID_MODEL, VIC3D_MODEL, ConversionCost, TargetModel, nearest_camera,
                      nearest_rig, projection_cost_px)
from .vic3d import load_vic3d, looks_like_vic3d, save_vic3d

__all__ = ["load_any_calibration", "save_calibration_as", "FORMATS", "detect_format",
           "load_dice", "save_dice", "load_vic3d", "save_vic3d", "load_matchid", "save_matchid",
           "load_matlab", "save_matlab", "looks_like_matlab",
           "nearest_camera", "nearest_rig", "projection_cost_px", "TargetModel", "ConversionCost",
           "ConversionReport", "CameraConversion", "DICE_MODEL", "VIC3D_MODEL", "MATCHID_MODEL", "MATLAB_MODEL"]

#: Names accepted by :func:`save_calibration_as` (``"json"`` and ``"opencv"`` are this instrument's own files).
FORMATS = ("dice", "vic3d", "matchid", "matlab", "json", "opencv")
_WRITERS = {"dice": save_dice, "vic3d": save_vic3d, "matchid": save_matchid, "matlab": save_matlab}


def detect_format(path: str | Path) -> str:
    """``"dice"``, ``"vic3d"``, ``"matchid"``, ``"matlab"`` or ``"native"`` (this instrument's JSON / OpenCV YAML or
    XML), by content first and suffix second (a ``.json`` is MATLAB's when it holds a stereoParameters struct)."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix == ".caldat":
        return "matchid"
    if suffix == ".mat" or is_mat_file(path):
        return "matlab"
    if suffix in (".yaml", ".yml"):
        return "native"
    if suffix == ".json":                     # a MATLAB toStruct JSON can exceed the other formats' size limit
        try:
            with open(path, "rb") as handle:
                start = handle.read(1 << 16).decode("utf-8", "replace")
        except OSError:
            return "native"                   # let the native loader name the problem
        return "matlab" if looks_like_matlab(start) else "native"
    try:
        head = _common.read_bytes(path, "calibration file")[:1 << 20].decode("utf-8", "replace")
    except FileFormatError:
        return "native"                       # let the native loader name the problem
    if looks_like_matlab(head):
        return "matlab"
    if looks_like_dice(head):
        return "dice"
    if looks_like_vic3d(head):
        return "vic3d"
    if looks_like_matchid(head):
        return "matchid"
    return "native"


def load_any_calibration(path: str | Path, *, image_size_px: tuple[int, int] | None = None) -> CalibratedRig:
    """Read a calibration of any supported kind: DICe, VIC-3D, MatchID or MATLAB by content (``.caldat`` and
    ``.mat`` by suffix), else this instrument's JSON / OpenCV YAML or XML
    (:func:`~measurement.calibration.io.load_calibration`).

    ``image_size_px`` (width, height) is required for MatchID files (they hold none) and used by VIC-3D files
    without a ``<polygonmask>`` and MATLAB cameras with an empty ``ImageSize``. Raises FileFormatError naming the
    file and the key.
    """
    kind = detect_format(path)
    if kind == "dice":
        return load_dice(path)
    if kind == "vic3d":
        return load_vic3d(path, image_size_px=image_size_px)
    if kind == "matchid":
        return load_matchid(path, image_size_px)
    if kind == "matlab":
        return load_matlab(path, image_size_px=image_size_px)
    return load_calibration(path)


def save_calibration_as(rig: CalibratedRig, path: str | Path, format: str, *,
                        frame_rotation: bool = False) -> ConversionReport:
    """Write ``rig`` to ``path`` in ``format`` (one of :data:`FORMATS`) and report what the conversion cost.

    ``"json"`` and ``"opencv"`` (YAML, or XML for a ``.xml`` path) are this instrument's own files, which hold every
    parameter: their report is exact. ``frame_rotation`` lets the other formats absorb a Scheimpflug tilt in a
    rotation of the camera frames (see the writers).
    """
    if format not in FORMATS:
        raise ValueError(f"format must be one of {', '.join(FORMATS)}, got {format!r}")
    if format in _WRITERS:
        return _WRITERS[format](rig, path, frame_rotation=frame_rotation)
    path = Path(path)
    if format == "opencv" and path.suffix.lower() not in (".yaml", ".yml", ".xml"):
        raise ValueError(f"{path}: an OpenCV calibration needs a .yaml, .yml or .xml suffix")
    if format == "json" and path.suffix.lower() != ".json":
        raise ValueError(f"{path}: a calibration JSON needs a .json suffix")
    save_rig(rig, path)
    cams = tuple(CameraConversion(side, side, "this instrument's model (every parameter)", 0.0, 0.0, True)
                 for side in ("left", "right"))
    return ConversionReport(format, path, cams)
