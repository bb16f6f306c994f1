"""DICe camera-system files (``cal.xml``, ``xml_file_format = DICe_xml_camera_system_file``).

Conventions, as read in DICe's source (github.com/dicengine/dice at 5ebcdfafad1d0ac4ed120ebc1a3fe04138216d5b):

* **Layout** (``src/core/DICe_CameraSystem.cpp``, ``read_camera_system_file`` / ``write_camera_system_file``): a
  Teuchos ``<ParameterList>`` of ``<Parameter name= type= value=/>``; top level ``xml_file_format``,
  ``system_type_3D`` (GENERIC_SYSTEM, OPENCV, VIC3D, DICE), ``extrinsics_relative_camera_to_camera`` (bool, default
  false); one sublist ``CAMERA n`` per camera (n = 0, 1, ...) with ``CX CY FX FY FS K1-K6 P1 P2 S1-S4 T1 T2`` (each
  optional, absent = 0: "zero valued parameters don't need to be specified"), ``LENS_DISTORTION_MODEL`` (default
  NO_LENS_DISTORTION), ``TX TY TZ`` (default 0), the rotation as a sublist ``rotation_3x3_matrix`` with
  ``ROW 0``-``ROW 2`` = ``"{ R11, R12, R13 }"`` or as ``ALPHA BETA GAMMA`` (not both; neither = identity),
  ``IMAGE_HEIGHT_WIDTH = "{ h, w }"`` (height first; required).
* **Projection** (``src/core/DICe_Camera.cpp``, ``sensor_to_image``): for ``OPENCV_LENS_DISTORTION``, OpenCV's model
  (radial k1-k3 over 1 + k4-k6, tangential, thin prism, then the Scheimpflug matrix built from T1, T2 exactly as
  OpenCV's ``computeTiltProjectionMatrix`` with ``tau_x = T1``, ``tau_y = T2`` in radians), then
  ``u = FX x + FS y + CX``, ``v = FY y + CY``: FS is a pixel-valued skew ``K[0, 1]`` (the writer's comment "FS-skew
  (deg)" does not match the code, which is followed here). ``K1R2_K2R4_K3R6`` is the same radial polynomial without
  the other terms; ``NO_LENS_DISTORTION`` ignores every K/P/S/T; ``K1R1_K2R2_K3R3``, ``K1R3_K2R5_K3R7`` and
  ``VIC3D_LENS_DISTORTION`` use odd powers of r, which this instrument's model has not, and are refused.
* **Pixels**: DICe indexes pixel (row i, column j) at image coordinates (x, y) = (j, i) (``prep_lens_distortion``
  inverts the distortion at ``x = i % width, y = i / width``; the csv reader sets ``CX = width / 2 - 0.5``) and
  calibrates with OpenCV: pixel centres at integers, as here. No shift.
* **Extrinsics** (``Camera_Info``: "rotation_matrix_ [R] matrix transforming from the world coordinates to the camera
  coordinates"; ``DICe_Triangulation.cpp``, ``load_calibration_parameters``): each camera's R, T map world to camera,
  ``X_cam = R X_world + T`` (mm). Camera 0 is the reference. With ``extrinsics_relative_camera_to_camera = false``
  camera 1's R, T are world -> camera 1, so camera 0 -> camera 1 is ``T1 T0^-1``; with ``true`` they are camera 0 ->
  camera 1 directly. ``ALPHA BETA GAMMA`` are degrees with ``R = Rz(GAMMA) Ry(BETA) Rx(ALPHA)``
  (``eulers_to_rotation_matrix``). The writer here makes the world this instrument's left camera frame and writes
  the flag false; without a frame rotation camera 0 is then the identity at the origin, where both readings of
  the flag agree (the trap of DICe issues #297 and #305).
* **Numbering**: camera 0 is the left camera (DICe's calibration input names the left images by
  ``stereo_left_suffix = "_0"``), camera 1 the right one.
"""
from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np

from measurement.calibration.io import MAX_IMAGE_PX, RANGES, CalibratedRig, EXTRA_RANGES
from measurement.camera import MAX_TILT_DEG, ScheimpflugCamera
from labio.schema import FileFormatError, Node

from . import _common as C
from .nearest import DICE_MODEL

__all__ = ["save_dice", "load_dice", "FORMAT_NAME", "looks_like_dice"]

FORMAT_NAME = "DICe camera-system XML (DICe_xml_camera_system_file)"
_FILE_FORMAT = "DICe_xml_camera_system_file"
_SYSTEM_TYPES = ("GENERIC_SYSTEM", "OPENCV", "VIC3D", "DICE")
_INTRINSICS = ("CX", "CY", "FX", "FY", "FS", "K1", "K2", "K3", "K4", "K5", "K6", "P1", "P2",
               "S1", "S2", "S3", "S4", "T1", "T2")
_MODELS = ("NO_LENS_DISTORTION", "OPENCV_LENS_DISTORTION", "VIC3D_LENS_DISTORTION", "K1R1_K2R2_K3R3",
           "K1R2_K2R4_K3R6", "K1R3_K2R5_K3R7")
#: The terms each accepted lens model uses (others must be 0 there: DICe ignores them).
_USES = {"NO_LENS_DISTORTION": (), "K1R2_K2R4_K3R6": ("K1", "K2", "K3"),
         "OPENCV_LENS_DISTORTION": ("K1", "K2", "K3", "K4", "K5", "K6", "P1", "P2", "S1", "S2", "S3", "S4", "T1", "T2")}
_CAMERA_KEYS = set(_INTRINSICS) | {"CAMERA_ID", "LENS_DISTORTION_MODEL", "TX", "TY", "TZ", "ALPHA", "BETA", "GAMMA",
                                   "IMAGE_HEIGHT_WIDTH", "PIXEL_DEPTH", "LENS", "COMMENTS", "rotation_3x3_matrix"}


# --------------------------------------------------------------------------------------------------------
# Reading
# --------------------------------------------------------------------------------------------------------
#: A camera-system file nests three deep (file, CAMERA n, rotation_3x3_matrix); deeper ones are refused.
_MAX_NESTING = 8


def _plist(element, path, key: str, depth: int = 0) -> dict:
    """A Teuchos ParameterList element as ``{name: (type, value) | dict}`` (sublists nested)."""
    if depth > _MAX_NESTING:
        raise FileFormatError(path, key, f"ParameterLists nest deeper than {_MAX_NESTING}: not a camera-system file")
    out = {}
    for child in element:
        name = child.get("name")
        if child.tag not in ("Parameter", "ParameterList"):
            raise FileFormatError(path, key, f"has an unexpected <{child.tag}> element (a Teuchos ParameterList "
                                             f"holds <Parameter> and <ParameterList>)")
        where = f"{key}.{name}" if key else str(name)
        if name is None:
            raise FileFormatError(path, key, f"has a <{child.tag}> without a name")
        if name in out:
            raise FileFormatError(path, where, "appears twice")
        if child.tag == "ParameterList":
            out[name] = _plist(child, path, where, depth + 1)
        else:
            if child.get("value") is None:
                raise FileFormatError(path, where, "has no value attribute")
            out[name] = (child.get("type", ""), child.get("value"))
    return out


def looks_like_dice(text: str) -> bool:
    return _FILE_FORMAT in text and "<ParameterList" in text


def _param(d: dict, name: str, path, key: str):
    v = d.get(name)
    if isinstance(v, dict):
        raise FileFormatError(path, f"{key}.{name}" if key else name, "must be a parameter, got a sublist")
    return v


def _number(d: dict, name: str, path, key: str, default: float | None = None, lo=None, hi=None,
            unit: str = "") -> float:
    v = _param(d, name, path, key)
    where = Node(None, path, f"{key}.{name}" if key else name)
    if v is None:
        if default is None:
            raise where.error("required key is missing")
        return default
    typ, text = v
    if typ not in ("double", "float", "int"):
        raise where.error(f"must be a number (type double), got type {typ!r}")
    return C.parse_number(text, where, lo, hi, unit)


def _rotation(cam: dict, path, key: str) -> np.ndarray:
    has_eulers = any(n in cam for n in ("ALPHA", "BETA", "GAMMA"))
    sub = cam.get("rotation_3x3_matrix")
    if sub is not None and not isinstance(sub, dict):
        raise FileFormatError(path, f"{key}.rotation_3x3_matrix", "must be a ParameterList of ROW 0-ROW 2")
    if sub is not None and has_eulers:
        raise FileFormatError(path, f"{key}.rotation_3x3_matrix", "cannot be given together with ALPHA/BETA/GAMMA "
                                                                  "(DICe refuses both)")
    if sub is not None:
        rows = []
        for i in range(3):
            v = _param(sub, f"ROW {i}", path, f"{key}.rotation_3x3_matrix")
            where = Node(None, path, f"{key}.rotation_3x3_matrix.ROW {i}")
            if v is None:
                raise where.error("required key is missing")
            rows.append(C.parse_numbers(v[1], where, 3))
        return Node(rows, path, f"{key}.rotation_3x3_matrix").rotation()
    if has_eulers:
        angles = [_number(cam, n, path, key, 0.0, -360.0, 360.0, "deg") for n in ("ALPHA", "BETA", "GAMMA")]
        return C.rotation_zyx_deg(*angles)
    return np.eye(3)


def _size(cam: dict, path, key: str) -> tuple[int, int]:
    v = _param(cam, "IMAGE_HEIGHT_WIDTH", path, key)
    where = Node(None, path, f"{key}.IMAGE_HEIGHT_WIDTH")
    if v is None:
        raise where.error("required key is missing (DICe needs the image size, \"{ height, width }\")")
    h, w = C.parse_numbers(v[1], where, 2)
    if not (h == int(h) and w == int(w) and 1 <= h <= MAX_IMAGE_PX and 1 <= w <= MAX_IMAGE_PX):
        raise where.error(f"must be two whole numbers in [1, {MAX_IMAGE_PX}] (height, width), got {v[1]!r}")
    return int(w), int(h)


def _distortion_cost_px(K: np.ndarray, d14: np.ndarray, kept: np.ndarray, size) -> float:
    """Largest corner displacement (px) of dropping ``d14 - kept`` (OpenCV's projection, as the YAML loader does)."""
    w, h = size
    corners = np.array([[0, 0], [w - 1, 0], [0, h - 1], [w - 1, h - 1]], dtype=np.float64)
    ideal = cv2.undistortPoints(corners.reshape(-1, 1, 2), K, d14).reshape(-1, 2)
    rays = np.column_stack([ideal, np.ones(len(ideal))])
    full = cv2.projectPoints(rays, np.zeros(3), np.zeros(3), K, d14)[0].reshape(-1, 2)
    short = cv2.projectPoints(rays, np.zeros(3), np.zeros(3), K, kept)[0].reshape(-1, 2)
    return float(np.max(np.linalg.norm(full - short, axis=1)))


def _camera(cam: dict, path, key: str) -> tuple[ScheimpflugCamera, np.ndarray, np.ndarray]:
    unknown = sorted(set(cam) - _CAMERA_KEYS)
    if unknown:
        raise FileFormatError(path, key, f"unknown key(s) {', '.join(map(repr, unknown))}")
    v = _param(cam, "LENS_DISTORTION_MODEL", path, key)
    model = "NO_LENS_DISTORTION" if v is None else v[1].strip().upper()
    if model not in _MODELS:
        raise FileFormatError(path, f"{key}.LENS_DISTORTION_MODEL",
                              f"must be one of {', '.join(_MODELS)}, got {v[1]!r}")
    if model not in _USES:
        raise FileFormatError(path, f"{key}.LENS_DISTORTION_MODEL",
                              f"{model} uses odd powers of r (K1 r + K2 r^2 ... for VIC3D_LENS_DISTORTION too), which "
                              f"this instrument's lens model (even powers, OpenCV's) cannot hold: refused")
    values = {}
    for n in _INTRINSICS:
        lo, hi, unit = {"FX": (0.0, 1e6, "px"), "FY": (0.0, 1e6, "px"), "CX": (-1e6, 1e6, "px"),
                        "CY": (-1e6, 1e6, "px"), "FS": (*EXTRA_RANGES["skew"], "px"),
                        "T1": (-np.deg2rad(MAX_TILT_DEG), np.deg2rad(MAX_TILT_DEG), "rad"),
                        "T2": (-np.deg2rad(MAX_TILT_DEG), np.deg2rad(MAX_TILT_DEG), "rad")}.get(n, (-1e4, 1e4, ""))
        required = n in ("CX", "CY", "FX", "FY")
        values[n] = _number(cam, n, path, key, None if required else 0.0, lo, hi, unit)
    ignored = [n for n in _INTRINSICS[5:] if values[n] != 0.0 and n not in _USES[model]]
    if ignored:
        raise FileFormatError(path, f"{key}.{ignored[0]}",
                              f"is {values[ignored[0]]:g} but LENS_DISTORTION_MODEL {model} ignores it (DICe would not "
                              f"apply {', '.join(ignored)}): set OPENCV_LENS_DISTORTION or remove them")
    K = np.array([[values["FX"], values["FS"], values["CX"]], [0.0, values["FY"], values["CY"]], [0.0, 0.0, 1.0]])
    d14 = np.array([values[n] for n in ("K1", "K2", "P1", "P2", "K3", "K4", "K5", "K6", "S1", "S2", "S3", "S4",
                                        "T1", "T2")])
    size = _size(cam, path, key)
    lacking = {n: values[n] for n in ("K4", "K5", "K6", "S1", "S2", "S3", "S4") if values[n] != 0.0}
    if lacking:
        kept = d14.copy()
        kept[5:12] = 0.0
        cost = _distortion_cost_px(K, d14, kept, size)
        terms = ", ".join(f"{k} = {v:g}" for k, v in lacking.items())
        raise FileFormatError(path, f"{key}.{next(iter(lacking))}",
                              f"has {terms}: this instrument's lens model has k1, k2, p1, p2, k3 (and OpenCV's tilt) "
                              f"only; dropping the rest would move the image corners by up to {cost:.3g} px, so the "
                              f"file is refused")
    for n, name in (("K1", "k1"), ("K2", "k2"), ("P1", "p1"), ("P2", "p2")):
        lo, hi = RANGES[name]
        if not lo < values[n] < hi:
            raise FileFormatError(path, f"{key}.{n}", f"must be in ({lo:g}, {hi:g}), got {values[n]:.17g}")
    tilted = values["T1"] != 0.0 or values["T2"] != 0.0
    try:
        camera = ScheimpflugCamera(fx=values["FX"], fy=values["FY"], cx=values["CX"], cy=values["CY"],
                                   alpha_deg=float(np.rad2deg(values["T1"])), beta_deg=float(np.rad2deg(values["T2"])),
                                   k1=values["K1"], k2=values["K2"], p1=values["P1"], p2=values["P2"], k3=values["K3"],
                                   skew=values["FS"], width=size[0], height=size[1],
                                   tilt_model="opencv" if tilted else "rmm")
    except ValueError as err:                                    # pragma: no cover - the ranges above are tighter
        raise FileFormatError(path, key, f"invalid camera: {err}") from None
    R = _rotation(cam, path, key)
    T = np.array([_number(cam, n, path, key, 0.0, -1e6, 1e6, "mm") for n in ("TX", "TY", "TZ")])
    return camera, R, T


def _rig_from_text(text: str, path) -> CalibratedRig:
    root = C.parse_xml(text, path)
    if root.tag != "ParameterList":
        raise FileFormatError(path, "", f"the top-level element must be <ParameterList>, got <{root.tag}>")
    doc = _plist(root, path, "")
    fmt = _param(doc, "xml_file_format", path, "")
    if fmt is None or fmt[1] != _FILE_FORMAT:
        raise FileFormatError(path, "xml_file_format", f"must be {_FILE_FORMAT!r} (a DICe camera-system file), got "
                                                       f"{None if fmt is None else fmt[1]!r}")
    system = _param(doc, "system_type_3D", path, "")
    if system is None or system[1].strip().upper() not in _SYSTEM_TYPES:
        raise FileFormatError(path, "system_type_3D", f"must be one of {', '.join(_SYSTEM_TYPES)} (required), got "
                                                      f"{None if system is None else system[1]!r}")
    flag = _param(doc, "extrinsics_relative_camera_to_camera", path, "")
    if flag is not None and flag[1].strip().lower() not in ("true", "false"):
        raise FileFormatError(path, "extrinsics_relative_camera_to_camera", f"must be true or false, got {flag[1]!r}")
    relative = flag is not None and flag[1].strip().lower() == "true"
    cams = sorted(k for k in doc if k.startswith("CAMERA "))
    if cams != ["CAMERA 0", "CAMERA 1"]:
        raise FileFormatError(path, "CAMERA 0" if "CAMERA 0" not in cams else "CAMERA 1" if "CAMERA 1" not in cams
                              else cams[-1], f"a stereo file needs exactly the sublists CAMERA 0 and CAMERA 1, got "
                                             f"{cams or 'none'}")
    for k in cams:
        if not isinstance(doc[k], dict):
            raise FileFormatError(path, k, "must be a ParameterList")
    (left, R0, T0), (right, R1, T1) = (_camera(doc[k], path, k) for k in cams)
    if relative:                     # camera 1's pose is camera 0 -> camera 1 (DICe_Triangulation.cpp)
        R, T = R1, T1
    else:                            # both are world -> camera: camera 0 -> camera 1 = T1 T0^-1
        R, T = C.relative_pose(R0, T0, R1, T1)
    T = C.check_baseline(T, Node(None, path, "CAMERA 1.TX"))
    tilted = left.is_tilted or right.is_tilted
    if tilted:
        left, right = (c if c.tilt_model == "opencv" else _as_opencv(c) for c in (left, right))
    return CalibratedRig("opencv-tilt" if tilted else "pinhole", left, right, R, T)


def _as_opencv(camera: ScheimpflugCamera) -> ScheimpflugCamera:
    """An untilted camera under the rig's OpenCV-tilt model (one tilt model per rig)."""
    return replace(camera, tilt_model="opencv")


def load_dice(path: str | Path) -> CalibratedRig:
    """Read a DICe camera-system XML (``CAMERA 0`` = left, ``CAMERA 1`` = right) into a :class:`CalibratedRig`.

    Raises
    ------
    FileFormatError (a ValueError)
        Naming the file and the key: not a DICe camera-system file, missing or malformed keys, non-numbers, a
        rotation that is not one, terms this instrument's model cannot hold (with their pixel cost), entities.
    """
    return _rig_from_text(C.decode_xml(C.read_bytes(path, "DICe calibration file"), path), path)


# --------------------------------------------------------------------------------------------------------
# Writing
# --------------------------------------------------------------------------------------------------------
def _p(name: str, typ: str, value: str) -> str:
    return f'<Parameter name="{name}" type="{typ}" value="{value}" />'


def _camera_xml(index: int, side: str, cam: ScheimpflugCamera, R: np.ndarray, T: np.ndarray) -> list[str]:
    tau = (np.deg2rad(cam.alpha_deg), np.deg2rad(cam.beta_deg)) if cam.is_tilted else (0.0, 0.0)
    if cam.is_tilted and cam.tilt_model != "opencv":             # pragma: no cover - nearest_camera guarantees it
        raise ValueError("only OpenCV-tilt cameras can be written to DICe")
    values = {"CX": cam.cx, "CY": cam.cy, "FX": cam.fx, "FY": cam.fy, "FS": cam.skew, "K1": cam.k1, "K2": cam.k2,
              "K3": cam.k3, "P1": cam.p1, "P2": cam.p2, "T1": tau[0], "T2": tau[1]}
    lines = [f'<ParameterList name="CAMERA {index}">', _p("CAMERA_ID", "string", side)]
    lines += [_p(n, "double", C.fmt_float(v)) for n, v in values.items() if v != 0.0 or n in ("CX", "CY", "FX", "FY")]
    lines.append(_p("LENS_DISTORTION_MODEL", "string", "OPENCV_LENS_DISTORTION"))
    lines += [_p(n, "double", C.fmt_float(v)) for n, v in zip(("TX", "TY", "TZ"), T)]
    lines.append("<!-- 3x3 camera rotation matrix (world to cam transformation) -->")
    lines.append('<ParameterList name="rotation_3x3_matrix">')
    lines += [_p(f"ROW {i}", "string", "{ " + ", ".join(C.fmt_float(x) for x in R[i]) + " }") for i in range(3)]
    lines.append("</ParameterList>")
    lines.append(_p("IMAGE_HEIGHT_WIDTH", "string", f"{{ {cam.height}, {cam.width} }}"))
    lines.append("</ParameterList>")
    return lines


def _text(conv: C.Converted) -> str:
    lines = ['<?xml version="1.0" encoding="UTF-8"?>', "<ParameterList>",
             "<!-- DICe formatted camera system file, written by measurement.calibration.formats.dice -->",
             "<!-- world = camera 0 (left); each camera's rotation_3x3_matrix, TX TY TZ map world to camera (mm); "
             "FS is the skew K[0][1] in px; T1 T2 are OpenCV's tau_x, tau_y in radians -->",
             _p("xml_file_format", "string", _FILE_FORMAT), _p("system_type_3D", "string", "OPENCV"),
             # both poses are world -> camera; without a frame rotation camera 0 is the world (identity, zero
             # translation), where world -> camera 1 and camera 0 -> camera 1 coincide: either reading of the flag works
             _p("extrinsics_relative_camera_to_camera", "bool", "false")]
    R_L = conv.R_left_new_from_old            # world = this instrument's left camera frame
    lines += _camera_xml(0, "left", conv.left, R_L, np.zeros(3))
    lines += _camera_xml(1, "right", conv.right, conv.R_right_from_left @ R_L, conv.T_right_from_left_mm)
    lines.append("</ParameterList>")
    return "\n".join(lines) + "\n"


def save_dice(rig: CalibratedRig, path: str | Path, *, frame_rotation: bool = False) -> C.ConversionReport:
    """Write ``rig`` as a DICe camera-system XML (camera 0 = left at the world origin, camera 1 = right).

    Each camera is converted to DICe's OpenCV model (:data:`~.nearest.DICE_MODEL`) by :func:`~.nearest.nearest_camera`:
    exact for OpenCV-tilt, pinhole and single-axis RMM cameras; the paper's two-axis RMM tilt is fitted (or, with
    ``frame_rotation=True``, expressed exactly after a small rotation of each camera frame about its optical axis,
    which the camera poses absorb: DICe's world stays this instrument's left camera frame). The file is written
    atomically and only after it has loaded back to cameras projecting within 1e-6 px of the converted ones.

    Returns
    -------
    ConversionReport
        Per camera: the model written, mean/max pixel cost over the image, notes.
    """
    conv = C.convert_rig(rig, DICE_MODEL, frame_rotation)
    text = _text(conv)
    C.write_checked(path, text, lambda t: _rig_from_text(t, path), conv)
    return C.report(FORMAT_NAME, path, DICE_MODEL, conv, ("CAMERA 0", "CAMERA 1"), frame_rotation,
                    _rotation_notes(conv))


def _rotation_notes(conv: C.Converted) -> tuple[str, ...]:
    if conv.costs[0].rotation_deg == 0.0:
        return ()
    return (f"camera 0's pose holds its {conv.costs[0].rotation_deg:.4g} deg frame rotation, so DICe's world stays "
            f"this instrument's left camera frame; loading the file back gives the rig in the rotated camera frames",)
