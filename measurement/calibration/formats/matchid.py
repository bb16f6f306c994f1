"""MatchID stereo calibrations (``.caldat``): one ``key;value`` pair per line.

Conventions and the sources checked (no MatchID documentation was available; these are the public programs that
read or write the format, and a cross-check with DICe):

* **Keys**: per camera ``Cam<n>_Fx [pixels]``, ``_Fy [pixels]``, ``_Fs [pixels]``, ``_Kappa 1``, ``_Kappa 2``,
  ``_Kappa 3``, ``_P1``, ``_P2``, ``_Cx [pixels]``, ``_Cy [pixels]``, then ``Tx [mm]``, ``Ty [mm]``, ``Tz [mm]``,
  ``Theta [deg]``, ``Phi [deg]``, ``Psi [deg]`` (pyvale, Computer-Aided-Validation-Laboratory/pyvale,
  ``CameraStereo.save_calibration_mid``). Camera numbering differs between writers: ``Cam0``/``Cam1`` (pyvale's
  stereo module, an OpenCorr example) and ``Cam1``/``Cam2`` (pyvale's Blender exporter); some writers omit the
  ``[unit]`` suffixes or lower-case the prefix. The loader accepts all of these (the lower number is the left,
  reference camera); unit suffixes, when present, must be the ones above. The writer uses ``Cam0``/``Cam1``. The
  file holds no image size: :func:`load_matchid` takes it as an argument.
* **Lens**: ``K = [[Fx, Fs, Cx], [0, Fy, Cy], [0, 0, 1]]``, Kappa 1-3 = OpenCV's k1 k2 k3 (r^2, r^4, r^6 on the
  ideal normalised plane), P1 P2 = OpenCV's p1 p2 (pyvale's ``opencv_distort`` passes them to OpenCV as
  ``[k1, k2, p1, p2, k3]`` with ``K[0][1] = Fs``). No tilt.
* **Extrinsics**: ``X_cam1 = R X_cam0 + T`` (mm) with ``R = Rz(Psi) Ry(Phi) Rx(Theta)``, degrees. Evidence: the
  DIC Challenge calibration that appears with MatchID keys in an OpenCorr example (``Tx 122.2488624``, ``Theta
  0.130689541``, ``Phi -19.06769369``, ``Psi 0.281404039``) is DICe's ``sim_checkerboard_cal_gold.xml`` camera 1
  (TX 122.2488, ALPHA 0.13068954, BETA -19.0676936, GAMMA 0.281404038, camera 0 = world), which DICe's test
  compares with its own OpenCV stereo calibration (``X_1 = R X_0 + T``); pyvale reads the angles as scipy's
  extrinsic ``"xyz"`` Euler sequence, which is ``Rz Ry Rx``.
* **Pixels (not confirmed from a MatchID source)**: integer pixel centres (OpenCV's), :data:`PIXEL_ORIGIN_SHIFT_PX`.
"""
from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from measurement.calibration.io import EXTRA_RANGES, MAX_IMAGE_PX, RANGES, CalibratedRig
from measurement.camera import ScheimpflugCamera
from labio.schema import FileFormatError, Node

from . import _common as C
from .nearest import MATCHID_MODEL

__all__ = ["save_matchid", "load_matchid", "FORMAT_NAME", "looks_like_matchid", "PIXEL_ORIGIN_SHIFT_PX"]

FORMAT_NAME = "MatchID calibration (.caldat)"
#: This instrument's ``cx = MatchID Cx + PIXEL_ORIGIN_SHIFT_PX`` (same for cy).
PIXEL_ORIGIN_SHIFT_PX = 0.0

#: Per-camera keys (without the ``Cam<n>_`` prefix): (name in the file, unit suffix, our name, range).
_CAMERA_KEYS = (("Fx", "pixels", "fx", (0.0, 1e6)), ("Fy", "pixels", "fy", (0.0, 1e6)),
                ("Fs", "pixels", "skew", EXTRA_RANGES["skew"]), ("Kappa 1", "", "k1", RANGES["k1"]),
                ("Kappa 2", "", "k2", RANGES["k2"]), ("Kappa 3", "", "k3", EXTRA_RANGES["k3"]),
                ("P1", "", "p1", RANGES["p1"]), ("P2", "", "p2", RANGES["p2"]),
                ("Cx", "pixels", "cx", (-1e6, 1e6)), ("Cy", "pixels", "cy", (-1e6, 1e6)))
_STEREO_KEYS = (("Tx", "mm"), ("Ty", "mm"), ("Tz", "mm"), ("Theta", "deg"), ("Phi", "deg"), ("Psi", "deg"))
_KEY = re.compile(r"^\s*(?:(cam)(\d+)_)?([A-Za-z][A-Za-z0-9 ]*?)\s*(?:\[([^\]]*)\])?\s*$", re.IGNORECASE)


def looks_like_matchid(text: str) -> bool:
    return bool(re.search(r"^\s*cam\d+_fx\b[^;\n]*;", text, re.IGNORECASE | re.MULTILINE))


# --------------------------------------------------------------------------------------------------------
# Reading
# --------------------------------------------------------------------------------------------------------
def _entries(text: str, path) -> dict:
    """``{(camera number or None, name lower-cased): (key as written, unit or None, value text)}``."""
    out = {}
    for lineno, line in enumerate(text.splitlines(), start=1):
        if not line.strip():
            continue
        if line.count(";") != 1:
            raise FileFormatError(path, f"line {lineno}", f"must be 'key;value', got {line.strip()[:60]!r}")
        key, value = line.split(";")
        m = _KEY.match(key)
        if not m:
            raise FileFormatError(path, key.strip() or f"line {lineno}", "is not a MatchID calibration key")
        cam = int(m.group(2)) if m.group(2) is not None else None
        ident = (cam, " ".join(m.group(3).split()).lower())
        if ident in out:
            raise FileFormatError(path, key.strip(), "appears twice")
        out[ident] = (key.strip(), m.group(4), value)
    return out


def _value(entries: dict, cam, name: str, unit: str, lo, hi, path, shown: str) -> float:
    entry = entries.pop((cam, name.lower()), None)
    if entry is None:
        raise FileFormatError(path, shown, "required key is missing")
    key, found_unit, text = entry
    if found_unit is not None and found_unit.strip().lower() != unit:
        raise FileFormatError(path, key, f"has the unit [{found_unit}], expected [{unit}]" if unit else
                              f"has a unit [{found_unit}] where none belongs")
    return C.parse_number(text, Node(None, path, key), lo, hi)


def _rig_from_text(text: str, path, image_size_px) -> CalibratedRig:
    entries = _entries(text, path)
    numbers = sorted({c for c, _ in entries if c is not None})
    if len(numbers) != 2 or numbers[1] != numbers[0] + 1 or numbers[0] not in (0, 1):
        raise FileFormatError(path, "Cam0_Fx [pixels]", f"a stereo calibration numbers its two cameras Cam0, Cam1 (or "
                                                        f"Cam1, Cam2), got {['Cam%d' % n for n in numbers] or 'none'}")
    if image_size_px is None:
        raise FileFormatError(path, "", "a MatchID .caldat holds no image size: pass image_size_px=(width, height)")
    w, h = image_size_px
    if not (int(w) == w and int(h) == h and 1 <= w <= MAX_IMAGE_PX and 1 <= h <= MAX_IMAGE_PX):
        raise ValueError(f"image_size_px must be two whole numbers in [1, {MAX_IMAGE_PX}], got {image_size_px!r}")
    cams = []
    for n in numbers:
        values = {ours: _value(entries, n, name, unit, lo, hi, path, f"Cam{n}_{name}" + (f" [{unit}]" if unit else ""))
                  for name, unit, ours, (lo, hi) in _CAMERA_KEYS}
        values["cx"] += PIXEL_ORIGIN_SHIFT_PX
        values["cy"] += PIXEL_ORIGIN_SHIFT_PX
        cams.append(ScheimpflugCamera(**values, width=int(w), height=int(h)))
    stereo = {name: _value(entries, None, name, unit, -1e6 if unit == "mm" else -360.0,
                           1e6 if unit == "mm" else 360.0, path, f"{name} [{unit}]") for name, unit in _STEREO_KEYS}
    if entries:
        keys = sorted(e[0] for e in entries.values())
        raise FileFormatError(path, keys[0], f"unknown key(s) {', '.join(map(repr, keys))}")
    R = C.rotation_zyx_deg(stereo["Theta"], stereo["Phi"], stereo["Psi"])
    T = C.check_baseline(np.array([stereo["Tx"], stereo["Ty"], stereo["Tz"]]), Node(None, path, "Tx [mm]"))
    return CalibratedRig("pinhole", cams[0], cams[1], R, T)


def load_matchid(path: str | Path, image_size_px: tuple[int, int] | None = None) -> CalibratedRig:
    """Read a MatchID ``.caldat`` (the lower-numbered camera is the left one) into a :class:`CalibratedRig`.

    Parameters
    ----------
    path : the file
    image_size_px : (width, height)
        The images' size; required (the format has none).

    Raises
    ------
    FileFormatError (a ValueError)
        Naming the file and the key: missing/duplicate/unknown keys, a wrong unit, a non-number, a value out of
        range, no image size.
    """
    data = C.read_bytes(path, "MatchID calibration file")
    try:
        text = data.decode("utf-8-sig")
    except UnicodeDecodeError as err:
        raise FileFormatError(path, "", f"is not UTF-8 text (byte {err.start})") from None
    return _rig_from_text(text, path, image_size_px)


# --------------------------------------------------------------------------------------------------------
# Writing
# --------------------------------------------------------------------------------------------------------
def _text(conv: C.Converted) -> str:
    lines = []
    for n, cam in enumerate((conv.left, conv.right)):
        values = {"fx": cam.fx, "fy": cam.fy, "skew": cam.skew, "k1": cam.k1, "k2": cam.k2, "k3": cam.k3,
                  "p1": cam.p1, "p2": cam.p2, "cx": cam.cx - PIXEL_ORIGIN_SHIFT_PX,
                  "cy": cam.cy - PIXEL_ORIGIN_SHIFT_PX}
        for name, unit, ours, _ in _CAMERA_KEYS:
            lines.append(f"Cam{n}_{name}{f' [{unit}]' if unit else ''};{C.fmt_float(values[ours])}")
    theta, phi, psi = C.euler_zyx_deg(conv.R_right_from_left)
    stereo = dict(zip(("Tx", "Ty", "Tz"), conv.T_right_from_left_mm), Theta=theta, Phi=phi, Psi=psi)
    lines += [f"{name} [{unit}];{C.fmt_float(stereo[name])}" for name, unit in _STEREO_KEYS]
    return "\n".join(lines) + "\n"


def save_matchid(rig: CalibratedRig, path: str | Path, *, frame_rotation: bool = False) -> C.ConversionReport:
    """Write ``rig`` as a MatchID ``.caldat`` (Cam0 = left, Cam1 = right; camera 0 -> camera 1 extrinsics).

    MatchID's model has no tilt (:data:`~.nearest.MATCHID_MODEL`): tilted cameras are converted by
    :func:`~.nearest.nearest_camera` and the report says what that cost. ``frame_rotation=True`` lets each camera
    frame rotate to absorb the tilt; MatchID keeps only the relative pose, so its world is then the left camera's
    rotated frame (the report says by how much). Written atomically after reloading within 1e-6 px.
    """
    conv = C.convert_rig(rig, MATCHID_MODEL, frame_rotation)
    text = _text(conv)
    size = (conv.left.width, conv.left.height)
    if size != (conv.right.width, conv.right.height):
        raise ValueError("this writer's reader takes one image size for both cameras; the left and right differ")
    C.write_checked(path, text, lambda t: _rig_from_text(t, path, size), conv)
    notes = ["the .caldat holds no image size: load it with image_size_px=" + f"({size[0]}, {size[1]})"]
    if conv.costs[0].rotation_deg > 0.0:
        notes.append(f"MatchID's world is camera 0's frame, here the left camera frame rotated by "
                     f"{conv.costs[0].rotation_deg:.4g} deg: 3-D coordinates are rotated by that against this "
                     f"instrument's")
    return C.report(FORMAT_NAME, path, MATCHID_MODEL, conv, ("Cam0", "Cam1"), frame_rotation, notes)
