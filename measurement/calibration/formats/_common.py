"""What the format modules share: the conversion report, safe XML reading, Euler angles, write-after-check."""
from __future__ import annotations

import math
import re
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from measurement.calibration.io import MAX_BASELINE_MM, CalibratedRig
from measurement.camera import ScheimpflugCamera
from labio.atomic import atomic_write_text
from labio.schema import FileFormatError, Node

from .nearest import EXACT_PX, ConversionCost, TargetModel, nearest_rig, projection_cost_px

#: Calibration files of the other tools are a few kB (VIC-3D project files with long image lists: ~100 kB).
MAX_FILE_BYTES = 4 << 20
#: Converted rigs must reload to cameras projecting within this of what was written (px).
RELOAD_TOL_PX = 1e-6
SIDES = ("left", "right")


# --------------------------------------------------------------------------------------------------------
# Reports
# --------------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class CameraConversion:
    """What became of one camera in a written file.

    Attributes
    ----------
    side : ``"left"`` or ``"right"``
    file_camera : str
        The camera's name in the file (``"CAMERA 0"``, ``"camera id=1"``, ``"Cam0"`` ...).
    model : str
        The model written (the target's description).
    mean_px, max_px : float
        Mean and largest distance (px) over the image between the source camera and the written one.
    exact : bool
        ``max_px <= 1e-6``.
    notes : tuple of str
        What the format could not express and what it cost.
    """

    side: str
    file_camera: str
    model: str
    mean_px: float
    max_px: float
    exact: bool
    notes: tuple[str, ...] = ()


@dataclass(frozen=True)
class ConversionReport:
    """What :func:`save_calibration_as` and the ``save_<format>`` writers wrote, camera by camera."""

    format: str
    path: Path
    cameras: tuple[CameraConversion, ...]
    notes: tuple[str, ...] = ()

    @property
    def max_px(self) -> float:
        return max(c.max_px for c in self.cameras)

    @property
    def exact(self) -> bool:
        return all(c.exact for c in self.cameras)

    def lines(self) -> list[str]:
        """One line per camera and note, for printing."""
        out = [f"{self.path}: {self.format}"]
        for c in self.cameras:
            state = "exact" if c.exact else f"mean {c.mean_px:.3g} px, max {c.max_px:.3g} px"
            out.append(f"  {c.side} ({c.file_camera}): {c.model}: {state}")
            out += [f"    - {n}" for n in c.notes]
        out += [f"  - {n}" for n in self.notes]
        return out


def camera_notes(model: TargetModel, cost: ConversionCost, frame_rotation: bool) -> tuple[str, ...]:
    """Human-readable notes on one converted camera: what was lacking and the pixels it cost."""
    notes = []
    rotated = frame_rotation and cost.rotation_deg > 0.0
    if cost.lacks:
        lacking = ", ".join(cost.lacks)
        if cost.exact:
            notes.append(f"{lacking}: not held as such, but exactly after rotating the camera frame by "
                         f"{cost.rotation_deg:.4g} deg (max {cost.max_px:.2g} px)")
        else:
            notes.append(f"{lacking} -> nearest {model.name}: mean {cost.mean_px:.3g} px, max {cost.max_px:.3g} px "
                         f"over the image")
    if rotated:
        notes.append(f"camera frame rotated by {cost.rotation_deg:.4g} deg; the extrinsics carry the rotation")
    return tuple(notes)


# --------------------------------------------------------------------------------------------------------
# Conversion and the write-after-check
# --------------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Converted:
    """A rig in a target model, with each camera's rotation of its frame and conversion cost."""

    left: ScheimpflugCamera
    right: ScheimpflugCamera
    R_right_from_left: np.ndarray
    T_right_from_left_mm: np.ndarray
    R_left_new_from_old: np.ndarray
    R_right_new_from_old: np.ndarray
    costs: tuple[ConversionCost, ConversionCost]


def convert_rig(rig: CalibratedRig, model: TargetModel, frame_rotation: bool) -> Converted:
    left, right, R, T, cost_l, cost_r = nearest_rig(rig.left, rig.right, rig.R_right_from_left,
                                                    rig.T_right_from_left_mm, model, frame_rotation=frame_rotation)
    return Converted(left, right, R, T, cost_l.R_new_from_old, cost_r.R_new_from_old, (cost_l, cost_r))


def check_reload(written: CalibratedRig, expected: Converted, path) -> None:
    """Refuse to write when what was serialised does not load back to the converted rig (FileFormatError)."""
    for side in SIDES:
        _, worst = projection_cost_px(getattr(expected, side), getattr(written, side))
        if not worst <= RELOAD_TOL_PX:
            raise FileFormatError(path, side, f"the written {side} camera reloads {worst:.3g} px away from what was "
                                              f"meant (refusing to write it; nothing written)")
    dR = np.max(np.abs(np.asarray(written.R_right_from_left) - expected.R_right_from_left))
    dT = np.max(np.abs(np.asarray(written.T_right_from_left_mm).ravel() - expected.T_right_from_left_mm))
    if not (dR <= 1e-12 and dT <= 1e-9 * max(1.0, float(np.linalg.norm(expected.T_right_from_left_mm)))):
        raise FileFormatError(path, "extrinsics", f"the written extrinsics reload off by {dR:.3g} (R), {dT:.3g} mm "
                                                  f"(T) (refusing to write them; nothing written)")


def write_checked(path, text: str, reload, expected: Converted) -> None:
    """Parse ``text`` with ``reload(text)`` (the format's own loader), compare with ``expected`` and only then
    write ``text`` atomically."""
    try:
        written = reload(text)
    except FileFormatError as err:
        raise FileFormatError(err.file, err.key, f"{err.problem} (refusing to write a file that would not load; "
                                                 f"nothing written)") from None
    check_reload(written, expected, path)
    atomic_write_text(path, text)


def reload_costs(rig: CalibratedRig, converted: Converted) -> tuple[tuple[float, float], tuple[float, float]]:
    """(mean, max) px of each source camera against its converted one (frame rotations included)."""
    return tuple(projection_cost_px(getattr(rig, s), getattr(converted, s),
                                    getattr(converted, f"R_{s}_new_from_old")) for s in SIDES)


def report(fmt: str, path, model: TargetModel, converted: Converted, names: tuple[str, str],
           frame_rotation: bool, notes=()) -> ConversionReport:
    cams = tuple(CameraConversion(side, name, model.name, cost.mean_px, cost.max_px, cost.max_px <= EXACT_PX,
                                  camera_notes(model, cost, frame_rotation))
                 for side, name, cost in zip(SIDES, names, converted.costs))
    return ConversionReport(fmt, Path(path), cams, tuple(notes))


# --------------------------------------------------------------------------------------------------------
# Euler angles: R = Rz(gamma) Ry(beta) Rx(alpha) (DICe's eulers_to_rotation_matrix, VIC-3D, MatchID)
# --------------------------------------------------------------------------------------------------------
def rotation_zyx_deg(alpha_deg: float, beta_deg: float, gamma_deg: float) -> np.ndarray:
    """``Rz(gamma) Ry(beta) Rx(alpha)``, angles in degrees, shape (3, 3) (DICe_Camera.cpp eulers_to_rotation_matrix)."""
    a, b, g = np.deg2rad([alpha_deg, beta_deg, gamma_deg])
    ca, sa, cb, sb, cg, sg = np.cos(a), np.sin(a), np.cos(b), np.sin(b), np.cos(g), np.sin(g)
    return np.array([[cb * cg, sa * sb * cg - ca * sg, ca * sb * cg + sa * sg],
                     [cb * sg, sa * sb * sg + ca * cg, ca * sb * sg - sa * cg],
                     [-sb, sa * cb, ca * cb]])


def euler_zyx_deg(R: np.ndarray) -> tuple[float, float, float]:
    """``(alpha, beta, gamma)`` in degrees with ``R = Rz(gamma) Ry(beta) Rx(alpha)``, ``|beta| < 90``."""
    R = np.asarray(R, float)
    sy = math.hypot(R[0, 0], R[1, 0])
    if sy < 1e-9:
        raise ValueError("the rotation is at the Euler-angle singularity (|beta| = 90 deg)")
    return (math.degrees(math.atan2(R[2, 1], R[2, 2])), math.degrees(math.atan2(-R[2, 0], sy)),
            math.degrees(math.atan2(R[1, 0], R[0, 0])))


def relative_pose(R0, T0, R1, T1) -> tuple[np.ndarray, np.ndarray]:
    """Camera 0 -> camera 1 from two world -> camera poses ``X_i = R_i X_w + T_i``: ``(R1 R0^T, T1 - R1 R0^T T0)``."""
    R = np.asarray(R1) @ np.asarray(R0).T
    return R, np.asarray(T1, float) - R @ np.asarray(T0, float)


def check_baseline(T: np.ndarray, where: Node) -> np.ndarray:
    norm = float(np.linalg.norm(T))
    if not 0.0 < norm < MAX_BASELINE_MM:
        raise where.error(f"the stereo translation's length must be in (0, {MAX_BASELINE_MM:g}) mm, got {norm:.6g} mm")
    return T


def fmt_float(x: float) -> str:
    """Shortest text that reads back to exactly ``x`` (17 significant digits at most)."""
    return repr(float(x))


# --------------------------------------------------------------------------------------------------------
# Text and XML input
# --------------------------------------------------------------------------------------------------------
_DECLARED = re.compile(rb"""^\s*<\?xml[^>]*encoding\s*=\s*["']([A-Za-z0-9._-]+)["']""")
_ENCODINGS = {"utf-8": "utf-8", "utf8": "utf-8", "iso-8859-1": "latin-1", "latin-1": "latin-1", "latin1": "latin-1",
              "us-ascii": "ascii", "ascii": "ascii", "windows-1252": "cp1252", "cp1252": "cp1252"}


def read_bytes(path, what: str) -> bytes:
    """The bytes of ``path``; FileFormatError if missing, not a file, empty, too large or binary."""
    from labio.schema import read_file_bytes

    return read_file_bytes(path, what, max_bytes=MAX_FILE_BYTES)


def decode_xml(data: bytes, path) -> str:
    """XML bytes as text, in the encoding their declaration names (VIC-3D writes ISO-8859-1), else UTF-8."""
    m = _DECLARED.match(data)
    name = m.group(1).decode("ascii").lower() if m else "utf-8"
    if name not in _ENCODINGS:
        raise FileFormatError(path, "", f"declares the unsupported encoding {name!r}")
    try:
        return data.decode(_ENCODINGS[name])
    except UnicodeDecodeError as err:
        raise FileFormatError(path, "", f"is not valid {name} text (byte {err.start})") from None


_DOCTYPE = re.compile(r"<!DOCTYPE\b([^>]*)>", re.IGNORECASE)


def parse_xml(text: str, path, *, wrap: bool = False) -> ET.Element:
    """Parse untrusted XML text without expanding anything: entity declarations and DOCTYPEs with an internal
    subset or an external identifier are refused; a bare ``<!DOCTYPE name>`` (VIC-3D writes ``<!DOCTYPE vpml>``)
    is removed before parsing. ``wrap`` parses a sequence of top-level elements under a synthetic root (DICe's
    VIC-3D samples have no single root element). FileFormatError on any defect."""
    if re.search(r"<!ENTITY", text, re.IGNORECASE):
        raise FileFormatError(path, "", "declares XML entities: refused (a calibration file has no use for them, "
                                        "and expanding them is how XML bombs work)")
    doctypes = _DOCTYPE.findall(text)
    if len(doctypes) > 1 or any(("[" in d) or re.search(r"\b(SYSTEM|PUBLIC)\b", d, re.IGNORECASE) for d in doctypes):
        raise FileFormatError(path, "", "has a DOCTYPE with an internal subset or an external identifier: refused "
                                        "(only a bare <!DOCTYPE name> is accepted)")
    body = _DOCTYPE.sub("", text)
    if wrap:
        body = "<_calibration_file>" + re.sub(r"^\s*<\?xml[^>]*\?>", "", body) + "</_calibration_file>"
    try:
        return ET.fromstring(body)
    except ET.ParseError as err:
        raise FileFormatError(path, "", f"is not well-formed XML: {err}") from None


def parse_number(text: str, where: Node, lo: float | None = None, hi: float | None = None, unit: str = "") -> float:
    """A finite decimal number written as text (``"1.2e-3"``), optionally in an open range, or FileFormatError."""
    s = text.strip() if isinstance(text, str) else text
    try:
        x = float(s)
    except (TypeError, ValueError):
        raise where.error(f"must be a number, got {s!r}") from None
    return Node(x, where.file, where.key).number(lo, hi, unit=unit)


def parse_numbers(text: str, where: Node, count: int | None = None) -> list[float]:
    """Whitespace- or comma-separated numbers (braces allowed: DICe's ``"{ 1, 2 }"``), checked like one number."""
    parts = [p for p in re.split(r"[\s,]+", text.strip().strip("{}").strip()) if p] if isinstance(text, str) else None
    if parts is None or (count is not None and len(parts) != count):
        n = "no" if parts is None else len(parts)
        raise where.error(f"must hold {count} numbers, got {n}: {text!r}")
    return [parse_number(p, Node(p, where.file, f"{where.key}[{i}]")) for i, p in enumerate(parts)]
