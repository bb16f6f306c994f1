"""VIC-3D (Correlated Solutions) calibrations in the project XML layout: ``<calibration>`` with one ``<camera id>``
per camera.

Conventions and the sources checked:

* **Layout**: ``<camera id="n">cx cy fx fy fs k1 k2 k3<orientation>alpha beta gamma tx ty tz</orientation></camera>``
  inside ``<calibration>``, the image size in ``<polygonmask width= height=>`` (DICe's VIC-3D reader,
  ``src/core/DICe_CameraSystem.cpp`` at dicengine/dice 5ebcdfafad1d0ac4ed120ebc1a3fe04138216d5b: parameter order
  ``CX, CY, FX, FY, FS, K1, K2, K3``; samples ``tests/component/cal/cal_a.xml``, ``tests/regression/stereo_d_spec/
  cal.xml``). Newer VIC-3D projects split the numbers into ``<intrinsics>cx cy fx fy s</intrinsics>`` and
  ``<distortion>`` (SDynPy, ``sdynpy/fileio/sdynpy_vic.py``); the intrinsics are read, a non-zero ``<distortion>``
  is refused (its layout is in no source checked).
* **Extrinsics**: each ``<orientation>`` is the world -> camera transform, ``X_cam = R X_world + t`` (mm), with
  Cardan-Bryant angles in degrees, ``R = Rz(gamma) Ry(beta) Rx(alpha)``. Two independent readers agree: DICe
  (``eulers_to_rotation_matrix``; ``DICe_Triangulation.cpp``: "With VIC3D the first transform is from world to
  camera 0 and the second is from world to camera 1") and SDynPy (``camera_matrix_from_vic_parameters``:
  ``R = (Rx^T Ry^T Rz^T)^T``, ``K [R | t]`` mapping world to image). DICe's own ``cal_a.txt`` holds the camera 0 ->
  camera 1 transform of ``cal_a.xml`` and matches ``T1 T0^-1`` computed this way to its 5 printed digits (tested).
  Camera 0 is the left camera, camera 1 the right one (DICe's reader and its "camera on the left" comment for
  camera 0 of the same calibration).
* **Intrinsics**: ``K = [[fx, fs, cx], [0, fy, cy], [0, 0, 1]]``, fs a pixel-valued skew (SDynPy:
  ``K[0, 1] = s``; DICe: ``image_x = x fx + y fs + cx``).
* **Distortion (inferred, not confirmed from a Correlated Solutions source)**: k1, k2, k3 are taken as radial
  coefficients of r^2, r^4, r^6 on the ideal normalised image plane, applied as OpenCV applies its radial terms
  (ideal -> distorted), with no tangential terms. DICe's reader assumes odd powers (``VIC3D_LENS_DISTORTION``: "I
  believe it is K1R1_K2R2_K3R3 but need to confirm") and drops k3 because "it's usually a high number"; the sample
  values (DICe's ``stereo_d_spec``: k2 = 0.87, k3 = -26.9 at corner radius 0.17) move the corners by a fraction of
  a pixel with even powers but by ~150 px with odd ones, so even powers are used (tested on that sample).
* **Pixels (not confirmed from a Correlated Solutions source)**: pixel centres at integer coordinates, as here and
  as DICe uses VIC-3D's cx, cy unchanged; :data:`PIXEL_ORIGIN_SHIFT_PX` is the one place to change that.
* Writing: the file mirrors the samples' layout line by line (one ``<camera>`` line each, a ``<!DOCTYPE vpml>``,
  which is how DICe tells a VIC-3D file from its own), so DICe reads it; whether VIC-3D itself imports such a
  calibration-only project has not been verified. The world is this instrument's left camera frame.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from measurement.calibration.io import EXTRA_RANGES, MAX_IMAGE_PX, RANGES, CalibratedRig
from measurement.camera import ScheimpflugCamera
from labio.schema import FileFormatError, Node

from . import _common as C
from .nearest import VIC3D_MODEL

__all__ = ["save_vic3d", "load_vic3d", "FORMAT_NAME", "looks_like_vic3d", "PIXEL_ORIGIN_SHIFT_PX"]

FORMAT_NAME = "VIC-3D calibration (project XML <calibration>)"
#: This instrument's ``cx = VIC-3D cx + PIXEL_ORIGIN_SHIFT_PX`` (same for cy): 0 for integer pixel centres in both.
PIXEL_ORIGIN_SHIFT_PX = 0.0


def looks_like_vic3d(text: str) -> bool:
    return "<calibration" in text and "<camera" in text and "<orientation" in text


# --------------------------------------------------------------------------------------------------------
# Reading
# --------------------------------------------------------------------------------------------------------
def _numbers(element, path, key: str, count: int) -> list[float]:
    if element is None:
        raise FileFormatError(path, key, "required element is missing")
    return C.parse_numbers(element.text or "", Node(None, path, key), count)


def _intrinsics(camera, path, key: str) -> list[float]:
    """cx cy fx fy fs k1 k2 k3 of one ``<camera>`` (old layout: its own text; newer: ``<intrinsics>``)."""
    own = (camera.text or "").strip()
    if own:
        return C.parse_numbers(own, Node(None, path, key), 8)
    values = _numbers(camera.find("intrinsics"), path, f"{key}.intrinsics", 5)
    dist = camera.find("distortion")
    if dist is not None:
        numbers = C.parse_numbers(dist.text or "0", Node(None, path, f"{key}.distortion"))
        if any(v != 0.0 for v in numbers):
            raise FileFormatError(path, f"{key}.distortion", "the newer VIC-3D <distortion> element is not supported "
                                                             "(its layout is documented in no source checked): refused")
    return values + [0.0, 0.0, 0.0]


def _image_size(root, path, image_size_px) -> tuple[int, int]:
    mask = next(root.iter("polygonmask"), None)
    if mask is None:
        if image_size_px is None:
            raise FileFormatError(path, "polygonmask", "required element is missing (it holds the image size; or "
                                                       "pass image_size_px=(width, height))")
        w, h = image_size_px
    else:
        w = C.parse_number(mask.get("width", ""), Node(None, path, "polygonmask.width"), 0, MAX_IMAGE_PX + 1)
        h = C.parse_number(mask.get("height", ""), Node(None, path, "polygonmask.height"), 0, MAX_IMAGE_PX + 1)
    if not (w == int(w) and h == int(h) and w >= 1 and h >= 1):
        raise FileFormatError(path, "polygonmask", f"the image size must be whole numbers >= 1, got {w} x {h}")
    return int(w), int(h)


def _camera(element, path, key: str, size) -> tuple[ScheimpflugCamera, np.ndarray, np.ndarray]:
    cx, cy, fx, fy, fs, k1, k2, k3 = _intrinsics(element, path, key)
    checks = {"fx": (fx, 0.0, 1e6), "fy": (fy, 0.0, 1e6), "cx": (cx, -1e6, 1e6), "cy": (cy, -1e6, 1e6),
              "fs": (fs, *EXTRA_RANGES["skew"]), "k1": (k1, *RANGES["k1"]), "k2": (k2, *RANGES["k2"]),
              "k3": (k3, *EXTRA_RANGES["k3"])}
    for name, (v, lo, hi) in checks.items():
        if not lo < v < hi:
            raise FileFormatError(path, f"{key}.{name}", f"must be in ({lo:g}, {hi:g}), got {v:.17g}")
    camera = ScheimpflugCamera(fx=fx, fy=fy, cx=cx + PIXEL_ORIGIN_SHIFT_PX, cy=cy + PIXEL_ORIGIN_SHIFT_PX,
                               k1=k1, k2=k2, k3=k3, skew=fs, width=size[0], height=size[1])
    a, b, g, tx, ty, tz = _numbers(element.find("orientation"), path, f"{key}.orientation", 6)
    for name, v in (("alpha", a), ("beta", b), ("gamma", g)):
        if not -360.0 <= v <= 360.0:
            raise FileFormatError(path, f"{key}.orientation.{name}", f"must be an angle in [-360, 360] deg, got {v:g}")
    for name, v in (("tx", tx), ("ty", ty), ("tz", tz)):
        if not abs(v) < 1e6:
            raise FileFormatError(path, f"{key}.orientation.{name}", f"must be in (-1e6, 1e6) mm, got {v:g}")
    return camera, C.rotation_zyx_deg(a, b, g), np.array([tx, ty, tz])


def _rig_from_text(text: str, path, image_size_px=None) -> CalibratedRig:
    root = C.parse_xml(text, path, wrap=True)
    calibrations = [c for c in root.iter("calibration") if c.find("camera") is not None]
    if len(calibrations) != 1:
        raise FileFormatError(path, "calibration", f"a VIC-3D calibration holds one <calibration> with <camera> "
                                                   f"elements, found {len(calibrations)}")
    cams = {}
    for element in calibrations[0].findall("camera"):
        cid = element.get("id")
        if cid in cams:
            raise FileFormatError(path, f"camera[{cid}]", "appears twice")
        cams[cid] = element
    if sorted(cams, key=str) != ["0", "1"]:
        raise FileFormatError(path, "calibration.camera", f"a stereo calibration needs cameras id=0 and id=1, got "
                                                          f"ids {sorted(map(str, cams))}")
    size = _image_size(root, path, image_size_px)
    (left, R0, T0), (right, R1, T1) = (_camera(cams[i], path, f"camera[{i}]", size) for i in ("0", "1"))
    R, T = C.relative_pose(R0, T0, R1, T1)                     # both orientations are world -> camera
    T = C.check_baseline(T, Node(None, path, "camera[1].orientation"))
    return CalibratedRig("pinhole", left, right, R, T)


def load_vic3d(path: str | Path, *, image_size_px: tuple[int, int] | None = None) -> CalibratedRig:
    """Read a VIC-3D calibration (a project XML or an excerpt holding its ``<calibration>``) into a rig.

    Parameters
    ----------
    path : the file
    image_size_px : (width, height), optional
        Used only when the file has no ``<polygonmask>`` (VIC-3D keeps the image size there).

    Raises
    ------
    FileFormatError (a ValueError)
        Naming the file and the key (``camera[1].orientation``, ``polygonmask.width`` ...).
    """
    return _rig_from_text(C.decode_xml(C.read_bytes(path, "VIC-3D calibration file"), path), path, image_size_px)


# --------------------------------------------------------------------------------------------------------
# Writing
# --------------------------------------------------------------------------------------------------------
def _camera_line(index: int, cam: ScheimpflugCamera, R: np.ndarray, T: np.ndarray) -> str:
    intr = (cam.cx - PIXEL_ORIGIN_SHIFT_PX, cam.cy - PIXEL_ORIGIN_SHIFT_PX, cam.fx, cam.fy, cam.skew,
            cam.k1, cam.k2, cam.k3)
    orient = (*C.euler_zyx_deg(R), *np.asarray(T, float))
    return (f'  <camera id="{index}">{" ".join(C.fmt_float(v) for v in intr)}'
            f'<orientation>{" ".join(C.fmt_float(v) for v in orient)}</orientation>\n  </camera>')


def _text(conv: C.Converted) -> str:
    if (conv.left.width, conv.left.height) != (conv.right.width, conv.right.height):
        raise ValueError(f"VIC-3D keeps one image size for both cameras; the left is {conv.left.width} x "
                         f"{conv.left.height} px, the right {conv.right.width} x {conv.right.height} px")
    R_L = conv.R_left_new_from_old            # world = this instrument's left camera frame
    lines = ['<?xml version="1.0" encoding="UTF-8"?>', "<!DOCTYPE vpml>",
             "<!-- VIC-3D calibration written by measurement.calibration.formats.vic3d: <camera id>: cx cy fx fy fs "
             "k1 k2 k3; <orientation>: world -> camera, R = Rz(gamma) Ry(beta) Rx(alpha) in deg, t in mm -->",
             "<project>", ' <calibration lri="calibration">',
             _camera_line(0, conv.left, R_L, np.zeros(3)),
             _camera_line(1, conv.right, conv.R_right_from_left @ R_L, conv.T_right_from_left_mm),
             " </calibration>",
             f' <polygonmask width="{conv.left.width}" height="{conv.left.height}" lri="polygonmask">',
             " </polygonmask>", "</project>"]
    return "\n".join(lines) + "\n"


def save_vic3d(rig: CalibratedRig, path: str | Path, *, frame_rotation: bool = False) -> C.ConversionReport:
    """Write ``rig`` as a VIC-3D calibration (camera 0 = left, world = the left camera frame).

    VIC-3D's model has no tilt and no tangential terms (:data:`~.nearest.VIC3D_MODEL`): cameras are converted by
    :func:`~.nearest.nearest_camera` and the report says what that cost. ``frame_rotation=True`` lets each camera
    frame rotate to absorb a Scheimpflug tilt (much cheaper, see the report); the orientations carry the rotation,
    so the world stays this instrument's left camera frame. Written atomically after reloading within 1e-6 px.
    """
    conv = C.convert_rig(rig, VIC3D_MODEL, frame_rotation)
    text = _text(conv)

    C.write_checked(path, text, lambda t: _rig_from_text(t, path), conv)
    return C.report(FORMAT_NAME, path, VIC3D_MODEL, conv, ("camera id=0", "camera id=1"), frame_rotation)
