"""MATLAB stereo calibrations: the struct of ``toStruct(stereoParams)``, as JSON (``jsonencode``) or in a MAT-file.

MATLAB's ``stereoParameters`` object (Computer Vision Toolbox, Stereo Camera Calibrator app) is an opaque class;
``toStruct`` turns it into a plain struct that other programs can read once it is written as JSON
(``jsonencode(toStruct(stereoParams))``) or saved in a version 5/7 MAT-file (``s = toStruct(stereoParams);
save('calib.mat', '-struct', 's', '-v7')``, or ``save('calib.mat', 's')``). Both are read here; a MAT-file holding
the object itself (an MCOS object, which only MATLAB can decode) is refused with these export instructions.

Conventions and the sources checked:

* **Layout** (MathWorks' ``toStruct``/``saveobj`` of ``stereoParameters`` and ``CameraParametersImpl``, Computer
  Vision Toolbox source, copyright MathWorks 2013-2024; https://www.mathworks.com/help/vision/ref/stereoparameters.
  tostruct.html): top level ``CameraParameters1``, ``CameraParameters2``, ``RotationOfCamera2``,
  ``TranslationOfCamera2``, ``Version``, ``RectificationParams`` (R2022b and later also ``PoseCamera2``). Each camera:
  ``RadialDistortion`` [k1 k2], [k1 k2 k3] or [k1 ... k6], ``TangentialDistortion`` [p1 p2], ``ImageSize``
  [rows cols], ``WorldUnits``, ``K`` (R2022b and later) or ``IntrinsicMatrix`` (before R2022b), and fields this
  reader ignores (``WorldPoints``, ``RotationVectors``, ``ReprojectionErrors``, ...). Camera 1 is the left camera.
* **Intrinsics**: ``K = [fx s cx; 0 fy cy; 0 0 1]``; ``IntrinsicMatrix = K'`` = ``[fx 0 0; s fy 0; cx cy 1]``, the
  post-multiply (row-vector) form (cameraParameters page, https://www.mathworks.com/help/vision/ref/
  cameraparameters.html; ``CameraParametersImpl``: ``get.IntrinsicMatrix`` returns ``this.K'``; ``loadobj``: "K
  introduced in 22b", ``K = that.IntrinsicMatrix'``). The skew ``s`` is ``K(1,2)``, as here.
* **Distortion**: ``x_d = x (1 + k1 r^2 + k2 r^4 + k3 r^6) + 2 p1 x y + p2 (r^2 + 2 x^2)`` and likewise for y, on the
  ideal normalised plane (the ``RadialDistortion`` and ``TangentialDistortion`` comments of ``CameraParametersImpl``):
  OpenCV's and this instrument's terms. The six-term rational model (k4-k6, newer releases) is not held here: a
  non-zero k4, k5 or k6 is refused. No tilt.
* **Pixels**: MATLAB puts the centre of the top-left pixel at (1, 1), OpenCV (and this instrument) at (0, 0); MATLAB's
  own converters ``cameraIntrinsicsToOpenCV`` and ``stereoParametersToOpenCV`` "compensate for this difference by
  subtracting 1" from the principal point (https://www.mathworks.com/help/vision/ref/stereoparameterstoopencv.html,
  https://www.mathworks.com/help/vision/ref/cameraintrinsicstoopencv.html; also https://www.mathworks.com/help/vision/
  gs/coordinate-systems.html and https://www.mathworks.com/help/images/image-coordinate-systems.html: "The center of
  the pixel in the top-left corner of the image has intrinsic coordinates (1.0, 1.0)"). So ``cx = cx_MATLAB - 1``
  (:data:`PIXEL_ORIGIN_SHIFT_PX`). ``ImageSize`` is [rows, cols] = [height, width].
* **Extrinsics**: row vectors, ``[x y z]_camera2 = [x y z]_camera1 * RotationOfCamera2 + TranslationOfCamera2``
  (MathWorks Support answer 502227, https://www.mathworks.com/matlabcentral/answers/502227), so OpenCV's and this
  instrument's ``R = RotationOfCamera2'`` and ``T = TranslationOfCamera2`` (as ``stereoParametersToOpenCV`` returns
  them), in ``WorldUnits`` (converted to mm here). R2022b's ``PoseCamera2`` is ``rigidtform3d(RotationOfCamera2',
  TranslationOfCamera2)`` (``stereoParameters.loadobj``), so its ``R`` and ``Translation`` are R and T directly;
  when both are present they must agree.
* **JSON** (https://www.mathworks.com/help/matlab/ref/jsonencode.html): vectors are flat arrays, matrices nested
  arrays of rows, NaN ``null``. Nested 1-by-N or N-by-1 lists are accepted for vectors too.

Writing: :func:`save_matlab` writes the same struct (a ``.json`` path: JSON as ``jsonencode`` lays it out; a ``.mat``
path: a version 5 MAT-file with the struct's fields as its variables, as ``save -struct`` does). Cameras are
converted with :func:`~.nearest.nearest_camera` into :data:`MATLAB_MODEL` (no tilt) and the report says what that
cost in pixels. The file holds the calibration only (no calibration views, no rectification): in MATLAB,
``stereoParameters(cameraParameters(s.CameraParameters1), cameraParameters(s.CameraParameters2),
rigidtform3d(s.RotationOfCamera2', s.TranslationOfCamera2))`` (R2022b and later) rebuilds the object; whether
``stereoParameters(s)`` accepts the struct without ``RectificationParams`` has not been checked in MATLAB.
"""
from __future__ import annotations

import io
import json
import struct
import zlib
from pathlib import Path

import numpy as np

from measurement.calibration.io import EXTRA_RANGES, MAX_IMAGE_PX, RANGES, CalibratedRig
from measurement.camera import ScheimpflugCamera
from labio.atomic import atomic_write_bytes
from labio.schema import FileFormatError, Node, read_file_bytes

from . import _common as C
from .nearest import TargetModel

__all__ = ["load_matlab", "save_matlab", "looks_like_matlab", "is_mat_file", "FORMAT_NAME", "MATLAB_MODEL",
           "PIXEL_ORIGIN_SHIFT_PX", "MATLAB_EXPORT_HINT"]

FORMAT_NAME = "MATLAB stereoParameters struct (toStruct) as JSON or MAT-file"
#: What MATLAB's cameraParameters hold: k1 k2 k3 (r^2, r^4, r^6), p1 p2 and the skew K(1,2); no tilt.
MATLAB_MODEL = TargetModel("MATLAB cameraParameters: pinhole + radial k1 k2 k3 + tangential p1 p2 + skew (no tilt)")
#: This instrument's ``cx = MATLAB cx + PIXEL_ORIGIN_SHIFT_PX`` (same for cy): MATLAB's first pixel centre is (1, 1).
PIXEL_ORIGIN_SHIFT_PX = -1.0
#: How to get a readable file out of MATLAB (quoted in the errors for files that hold the object itself).
MATLAB_EXPORT_HINT = ("in MATLAB, export the struct instead: s = toStruct(stereoParams); save('calib.mat', '-struct', "
                      "'s', '-v7') or fid = fopen('calib.json', 'w'); fprintf(fid, '%s', jsonencode(s)); fclose(fid)")
#: A toStruct JSON holds the calibration views' points and errors too: allow more than the other formats' 4 MiB.
MAX_JSON_BYTES = 64 << 20
#: MAT-files: largest file, and largest total of its compressed variables once decompressed (bytes).
MAX_MAT_BYTES = 64 << 20
MAX_MAT_DECOMPRESSED_BYTES = 512 << 20
#: ``WorldUnits`` this reader converts to mm (lower-cased).
UNITS_MM = {"mm": 1.0, "millimeter": 1.0, "millimeters": 1.0, "millimetre": 1.0, "millimetres": 1.0,
            "cm": 10.0, "centimeter": 10.0, "centimeters": 10.0, "centimetre": 10.0, "centimetres": 10.0,
            "m": 1000.0, "meter": 1000.0, "meters": 1000.0, "metre": 1000.0, "metres": 1000.0,
            "in": 25.4, "inch": 25.4, "inches": 25.4}
_MAT_MAGIC = (b"MATLAB 5.0 MAT-file", b"MATLAB 7.3 MAT-file")
_CAMERAS = ("CameraParameters1", "CameraParameters2")


def looks_like_matlab(text: str) -> bool:
    """Whether (the start of) JSON text holds a MATLAB stereoParameters struct: its ``CameraParameters1`` and a key
    that follows it (``jsonencode`` writes ``CameraParameters1`` first, starting with ``RadialDistortion``)."""
    return '"CameraParameters1"' in text and any(f'"{k}"' in text for k in ("RadialDistortion", "CameraParameters2",
                                                                         "RotationOfCamera2", "PoseCamera2"))


def is_mat_file(path: str | Path) -> bool:
    """Whether ``path`` starts like a MATLAB MAT-file (version 5/7 or 7.3 header); False if it cannot be read."""
    try:
        with open(path, "rb") as handle:
            head = handle.read(20)
    except OSError:
        return False
    return head.startswith(_MAT_MAGIC)


# --------------------------------------------------------------------------------------------------------
# Reading: file -> plain tree (dicts, lists, numbers, strings) -> rig
# --------------------------------------------------------------------------------------------------------
def _json_tree(text: str, path):
    try:
        return json.loads(text)
    except json.JSONDecodeError as err:
        raise FileFormatError(path, "", f"is neither a MAT-file nor valid JSON: {err}") from None
    except RecursionError:
        raise FileFormatError(path, "", "is not a usable JSON file: nested too deeply") from None
    except ValueError as err:
        raise FileFormatError(path, "", f"is not a usable JSON file: {err}") from None


def _check_mat_inflation(data: bytes, path) -> None:
    """Refuse a version 5 MAT-file whose compressed variables inflate beyond :data:`MAX_MAT_DECOMPRESSED_BYTES`
    (a few hundred bytes of zlib can claim gigabytes), before scipy allocates anything."""
    order = "<" if data[126:128] == b"IM" else ">"
    offset, total = 128, 0
    while offset + 8 <= len(data):
        dtype, nbytes = struct.unpack(order + "II", data[offset:offset + 8])
        if dtype == 15:                                                  # miCOMPRESSED
            inflater = zlib.decompressobj()
            chunk = data[offset + 8:offset + 8 + nbytes]
            try:
                while chunk:
                    total += len(inflater.decompress(chunk, 1 << 20))
                    chunk = inflater.unconsumed_tail
                    if total > MAX_MAT_DECOMPRESSED_BYTES:
                        raise FileFormatError(path, "", f"inflates to more than {MAX_MAT_DECOMPRESSED_BYTES:,} bytes: "
                                                        f"not a calibration")
            except zlib.error as err:
                raise FileFormatError(path, "", f"is not a readable MAT-file (corrupt compressed data: "
                                                f"{err})") from None
        offset += 8 + nbytes + ((-nbytes) % 8 if dtype != 15 else 0)


def _plain(value):
    """A value loaded by scipy (``simplify_cells=True``) as JSON-like Python data; MCOS objects stay as they are."""
    from scipy.io.matlab import MatlabOpaque

    if isinstance(value, MatlabOpaque):
        return value
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if isinstance(value, np.ndarray):
        if value.dtype.kind in "OV":
            return [_plain(v) for v in value.tolist()] if value.ndim else _plain(value.item())
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, bytes):
        return value.decode("latin-1")
    return value


def _mat_tree(data: bytes, path) -> dict:
    if data.startswith(b"MATLAB 7.3 MAT-file"):
        raise FileFormatError(path, "", "is a MATLAB 7.3 MAT-file (HDF5), which this reader does not read: save it "
                                        "with -v7 (save('calib.mat', '-struct', 's', '-v7') with s = "
                                        "toStruct(stereoParams)) or export JSON")
    _check_mat_inflation(data, path)
    from scipy.io import loadmat

    try:
        loaded = loadmat(io.BytesIO(data), simplify_cells=True)
    except MemoryError:
        raise
    except Exception as err:                     # scipy raises many kinds on corrupt input; all mean "unreadable"
        raise FileFormatError(path, "", f"is not a readable MAT-file: {type(err).__name__}: {err}") from None
    return {k: _plain(v) for k, v in loaded.items() if not k.startswith("__")}


def _opaque_class(value) -> str:
    try:
        item = value.ravel()[0] if value.shape else value[()]
        name = item["s2"]
        return name.decode("latin-1") if isinstance(name, bytes) else str(name)
    except Exception:                            # a malformed opaque record still is one
        return "?"


def _find_opaque(value, key: str):
    """(key, class name) of the first MATLAB object (MCOS) in a loaded tree, or None."""
    from scipy.io.matlab import MatlabOpaque

    if isinstance(value, MatlabOpaque):
        return key, _opaque_class(value)
    items = value.items() if isinstance(value, dict) else enumerate(value) if isinstance(value, list) else ()
    for k, v in items:
        found = _find_opaque(v, f"{key}[{k}]" if isinstance(k, int) else (f"{key}.{k}" if key else str(k)))
        if found:
            return found
    return None


def _select(tree, path) -> Node:
    """The stereoParameters struct in a loaded file: the top level itself (``save -struct``, JSON) or the one
    variable / member that holds ``CameraParameters1``."""
    if not isinstance(tree, dict):
        raise FileFormatError(path, "", "must hold a MATLAB struct (a JSON object) with CameraParameters1, "
                                        "CameraParameters2 and RotationOfCamera2, got " + type(tree).__name__)
    if "CameraParameters1" in tree or "CameraParameters2" in tree:
        return Node(tree, path)
    candidates = [k for k, v in tree.items() if isinstance(v, dict) and "CameraParameters1" in v]
    if len(candidates) == 1:
        return Node(tree[candidates[0]], path, candidates[0])
    if len(candidates) > 1:
        raise FileFormatError(path, candidates[0], f"holds several stereo calibrations ({', '.join(candidates)}): "
                                                   f"keep one per file")
    opaque = _find_opaque(tree, "")
    if opaque is not None:
        key, cls = opaque
        single = ("; a cameraParameters object is one camera, and a stereo calibration needs the pair's "
                  "stereoParameters (estimateCameraParameters with both cameras' points)" if cls != "stereoParameters"
                  else "")
        raise FileFormatError(path, key, f"is a MATLAB {cls} object (stored in MATLAB's undocumented MCOS object "
                                         f"format, which only MATLAB can read), not a struct: {MATLAB_EXPORT_HINT}"
                                         f"{single}")
    shown = ", ".join(sorted(tree)[:8]) or "nothing"
    raise FileFormatError(path, "CameraParameters1", f"required key is missing: no MATLAB stereoParameters struct in "
                                                     f"the file (it holds {shown}); {MATLAB_EXPORT_HINT}")


def _flat(node: Node):
    """A MATLAB vector as a flat list: a flat list, a 1-by-N ``[[...]]`` or an N-by-1 ``[[a], [b]]``; a scalar is a
    1-vector (how scipy loads a 1-by-1)."""
    v = node.value
    if isinstance(v, (int, float)) and not isinstance(v, bool):
        return [v]
    if isinstance(v, list) and len(v) == 1 and isinstance(v[0], list):
        return v[0]
    if isinstance(v, list) and v and all(isinstance(e, list) and len(e) == 1 for e in v):
        return [e[0] for e in v]
    return v


def _vector(node: Node, sizes: tuple[int, ...], bound: float = 1e12) -> np.ndarray:
    values = _flat(node)
    if not isinstance(values, list) or len(values) not in sizes:
        n = f"{len(values)} numbers" if isinstance(values, list) else f"{type(values).__name__}"
        want = " or ".join(map(str, sizes))
        raise node.error(f"must be a vector of {want} numbers, got {n}")
    return Node(values, node.file, node.key).array((len(values),), bound=bound)


def _matrix3(node: Node) -> np.ndarray:
    v = node.value
    if not (isinstance(v, list) and len(v) == 3 and all(isinstance(r, list) and len(r) == 3 for r in v)):
        shape = (f"{len(v)} x {len(v[0]) if v and isinstance(v[0], list) else '?'}" if isinstance(v, list)
                 else type(v).__name__)
        raise node.error(f"must be a 3 x 3 matrix (nested lists of rows), got {shape}")
    return node.array((3, 3), bound=1e9)


def _intrinsic_matrix(cam: Node) -> np.ndarray:
    """K (pre-multiply) from ``K`` or from ``IntrinsicMatrix = K'``; both present must agree."""
    K = IM = None
    if cam.get("K") is not None:
        K = _matrix3(cam["K"])
        bad = [f"K({i + 1},{j + 1})" for i, j in ((1, 0), (2, 0), (2, 1)) if K[i, j] != 0.0]
        if bad or K[2, 2] != 1.0:
            raise cam["K"].error(f"must be MATLAB's [fx s cx; 0 fy cy; 0 0 1], but {', '.join(bad) or 'K(3,3)'} "
                                 f"{'are' if len(bad) > 1 else 'is'} {'not 0' if bad else 'not 1'}: {K.tolist()}")
    if cam.get("IntrinsicMatrix") is not None:
        IM = _matrix3(cam["IntrinsicMatrix"])
        bad = [f"IntrinsicMatrix({i + 1},{j + 1})" for i, j in ((0, 1), (0, 2), (1, 2)) if IM[i, j] != 0.0]
        if bad or IM[2, 2] != 1.0:
            raise cam["IntrinsicMatrix"].error(
                f"must be MATLAB's post-multiply [fx 0 0; s fy 0; cx cy 1] (K'), but "
                f"{', '.join(bad) or 'IntrinsicMatrix(3,3)'} {'are' if len(bad) > 1 else 'is'} "
                f"{'not 0' if bad else 'not 1'}: {IM.tolist()} (a matrix in the [fx s cx; 0 fy cy; 0 0 1] layout "
                f"belongs in K)")
    if K is None and IM is None:
        raise cam.error("required key is missing (a MATLAB camera holds K, or IntrinsicMatrix before R2022b)",
                        key=f"{cam.key}.K")
    if K is not None and IM is not None and not np.allclose(K, IM.T, rtol=1e-12, atol=1e-9):
        raise cam["IntrinsicMatrix"].error(f"disagrees with K (IntrinsicMatrix must be K'): K = {K.tolist()}, "
                                           f"IntrinsicMatrix' = {IM.T.tolist()}")
    return K if K is not None else IM.T


def _world_units_mm(cam: Node) -> float:
    from scipy.io.matlab import MatlabOpaque

    if isinstance(cam["WorldUnits"].value, MatlabOpaque):
        raise cam["WorldUnits"].error("is a MATLAB string object (MCOS), which only MATLAB can read: in MATLAB, make "
                                      "it a char vector before saving (s.CameraParameters1.WorldUnits = "
                                      "char(s.CameraParameters1.WorldUnits), likewise for camera 2), or export JSON")
    units = cam["WorldUnits"].string()
    if units.strip().lower() not in UNITS_MM:
        raise cam["WorldUnits"].error(f"must be a length unit ({', '.join(sorted(set(UNITS_MM)))}), got {units!r}")
    return UNITS_MM[units.strip().lower()]


def _image_size(cam: Node, image_size_px) -> tuple[int, int]:
    """(width, height) from ``ImageSize`` = [rows cols]; ``image_size_px`` when the camera holds none."""
    node = cam.get("ImageSize")
    if node is None or node.value in ([], None):
        if image_size_px is None:
            raise cam.error("required key is missing or empty (it holds the image size [rows cols]; or pass "
                            "image_size_px=(width, height))", key=f"{cam.key}.ImageSize")
        w, h = image_size_px
        if not (int(w) == w and int(h) == h and 1 <= w <= MAX_IMAGE_PX and 1 <= h <= MAX_IMAGE_PX):
            raise ValueError(f"image_size_px must be two whole numbers in [1, {MAX_IMAGE_PX}], got {image_size_px!r}")
        return int(w), int(h)
    rows, cols = _vector(node, (2,))
    if not all(v == int(v) and 1 <= v <= MAX_IMAGE_PX for v in (rows, cols)):
        raise node.error(f"must be [rows cols], whole numbers in [1, {MAX_IMAGE_PX}], got [{rows:g} {cols:g}]")
    return int(cols), int(rows)


def _camera(cam: Node, image_size_px) -> ScheimpflugCamera:
    cam.mapping()
    K = _intrinsic_matrix(cam)
    key = cam["K"].key if cam.get("K") is not None else cam["IntrinsicMatrix"].key
    fx, skew, cx, fy, cy = K[0, 0], K[0, 1], K[0, 2], K[1, 1], K[1, 2]
    for name, v, (lo, hi), (i, j) in (("fx", fx, RANGES["fx"], (1, 1)), ("fy", fy, RANGES["fy"], (2, 2)),
                                      ("cx", cx, RANGES["cx"], (1, 3)), ("cy", cy, RANGES["cy"], (2, 3)),
                                      ("skew", skew, EXTRA_RANGES["skew"], (1, 2))):
        if not lo < v < hi:
            at = f"K({i},{j})" if cam.get("K") is not None else f"IntrinsicMatrix({j},{i})"
            raise FileFormatError(cam.file, key, f"{name} = {at} must be in ({lo:g}, {hi:g}) px, got {v:.17g}")
    radial_node = cam["RadialDistortion"]
    radial = _vector(radial_node, (2, 3, 6))
    if len(radial) == 6 and np.any(radial[3:] != 0.0):
        raise radial_node.error(f"has the rational terms k4, k5, k6 = {radial[3:].tolist()}, which this instrument's "
                                f"model does not hold: refused (calibrate with NumRadialDistortionCoefficients 2 or 3)")
    k1, k2 = radial[:2]
    k3 = radial[2] if len(radial) >= 3 else 0.0
    for name, v, (lo, hi) in (("k1", k1, RANGES["k1"]), ("k2", k2, RANGES["k2"]), ("k3", k3, EXTRA_RANGES["k3"])):
        if not lo < v < hi:
            raise radial_node.error(f"{name} must be in ({lo:g}, {hi:g}), got {v:.17g}")
    tangential_node = cam["TangentialDistortion"]
    p1, p2 = _vector(tangential_node, (2,))
    for name, v in (("p1", p1), ("p2", p2)):
        lo, hi = RANGES[name]
        if not lo < v < hi:
            raise tangential_node.error(f"{name} must be in ({lo:g}, {hi:g}), got {v:.17g}")
    width, height = _image_size(cam, image_size_px)
    return ScheimpflugCamera(fx=float(fx), fy=float(fy), cx=float(cx) + PIXEL_ORIGIN_SHIFT_PX,
                             cy=float(cy) + PIXEL_ORIGIN_SHIFT_PX, k1=float(k1), k2=float(k2), k3=float(k3),
                             p1=float(p1), p2=float(p2), skew=float(skew), width=width, height=height)


def _pose(root: Node, scale_mm: float) -> tuple[np.ndarray | None, np.ndarray | None]:
    """R, T (mm) of R2022b's ``PoseCamera2`` (``rigidtform3d``: ``R`` and ``Translation``, or the 4 x 4 ``A``)."""
    pose = root.get("PoseCamera2")
    if pose is None or pose.value in ([], None):
        return None, None
    pose.mapping()
    if pose.get("R") is not None and pose.get("Translation") is not None:
        return pose["R"].rotation(), _vector(pose["Translation"], (3,)) * scale_mm
    if pose.get("A") is not None:
        A = pose["A"].array((4, 4), bound=1e9)
        if not np.array_equal(A[3], [0.0, 0.0, 0.0, 1.0]):
            raise pose["A"].error(f"must be a rigid transform [R t; 0 0 0 1], its last row is {A[3].tolist()}")
        return Node(A[:3, :3].tolist(), pose.file, pose["A"].key).rotation(), A[:3, 3] * scale_mm
    raise pose.error("must hold R and Translation (or A), as a rigidtform3d does")


def _extrinsics(root: Node, scale_mm: float) -> tuple[np.ndarray, np.ndarray]:
    R_pose, T_pose = _pose(root, scale_mm)
    if root.get("RotationOfCamera2") is None and R_pose is not None:
        R, T = R_pose, T_pose
        where = Node(None, root.file, root["PoseCamera2"].key)
    else:
        R = root["RotationOfCamera2"].rotation().T           # row-vector convention: R_opencv = R_matlab'
        T = _vector(root["TranslationOfCamera2"], (3,)) * scale_mm
        where = Node(None, root.file, root["TranslationOfCamera2"].key)
        if R_pose is not None and not (np.allclose(R_pose, R, rtol=0, atol=1e-9)
                                       and np.allclose(T_pose, T, rtol=1e-9, atol=1e-9)):
            raise root["PoseCamera2"].error(f"disagrees with RotationOfCamera2 / TranslationOfCamera2 (PoseCamera2 "
                                            f"must be rigidtform3d(RotationOfCamera2', TranslationOfCamera2)): R = "
                                            f"{R_pose.tolist()} vs {R.tolist()}, T = {T_pose.tolist()} vs "
                                            f"{T.tolist()} mm")
    return R, C.check_baseline(T, where)


def _rig_from_tree(tree, path, image_size_px=None) -> CalibratedRig:
    root = _select(tree, path)
    left, right = (_camera(root[name], image_size_px) for name in _CAMERAS)
    units = [_world_units_mm(root[name]) for name in _CAMERAS]
    if units[0] != units[1]:
        raise root["CameraParameters2"]["WorldUnits"].error(
            f"differs from CameraParameters1.WorldUnits ({root['CameraParameters1']['WorldUnits'].value!r}): the "
            f"stereo translation's unit is ambiguous")
    R, T = _extrinsics(root, units[0])
    return CalibratedRig("pinhole", left, right, R, T)


def load_matlab(path: str | Path, *, image_size_px: tuple[int, int] | None = None) -> CalibratedRig:
    """Read a MATLAB ``toStruct(stereoParams)`` struct, as JSON or in a version 5/7 MAT-file, into a rig.

    The content decides (a MAT-file header, else JSON text); camera 1 is the left camera, camera 2 the right one.

    Parameters
    ----------
    path : the file
    image_size_px : (width, height), optional
        Used only for a camera whose ``ImageSize`` is empty (cameraParameters built by hand).

    Returns
    -------
    CalibratedRig
        Principal points shifted to OpenCV's pixel origin (``cx = cx_MATLAB - 1``), ``R = RotationOfCamera2'``,
        ``T = TranslationOfCamera2`` converted from ``WorldUnits`` to mm.

    Raises
    ------
    FileFormatError (a ValueError)
        Naming the file and the key (``CameraParameters2``, ``CameraParameters1.K``, ``RotationOfCamera2`` ...); a
        MAT-file holding the stereoParameters object itself (which only MATLAB can decode) says how to export it.
    """
    p = Path(path)
    if p.is_file() and is_mat_file(p):
        size = p.stat().st_size
        if size > MAX_MAT_BYTES:
            raise FileFormatError(p, "", f"MATLAB MAT-file is {size} bytes, more than the {MAX_MAT_BYTES} a "
                                         f"calibration can sensibly hold")
        return _rig_from_tree(_mat_tree(p.read_bytes(), p), p, image_size_px)
    data = read_file_bytes(p, "MATLAB calibration file", max_bytes=MAX_JSON_BYTES)
    try:
        text = data.decode("utf-8-sig")
    except UnicodeDecodeError as err:
        raise FileFormatError(p, "", f"is neither a MAT-file nor UTF-8 JSON text (byte {err.start})") from None
    return _rig_from_tree(_json_tree(text, p), p, image_size_px)


# --------------------------------------------------------------------------------------------------------
# Writing
# --------------------------------------------------------------------------------------------------------
def _camera_struct(cam: ScheimpflugCamera, intrinsics_key: str) -> dict:
    """One camera as the fields of MATLAB's cameraParameters toStruct (numpy arrays in MATLAB's shapes)."""
    K = np.array([[cam.fx, cam.skew, cam.cx - PIXEL_ORIGIN_SHIFT_PX], [0.0, cam.fy, cam.cy - PIXEL_ORIGIN_SHIFT_PX],
                  [0.0, 0.0, 1.0]])
    radial = [cam.k1, cam.k2, cam.k3] if cam.k3 != 0.0 else [cam.k1, cam.k2]
    return {"RadialDistortion": np.array([radial]), "TangentialDistortion": np.array([[cam.p1, cam.p2]]),
            "ImageSize": np.array([[float(cam.height), float(cam.width)]]), "WorldPoints": np.zeros((0, 2)),
            "WorldUnits": "mm", "EstimateSkew": bool(cam.skew != 0.0),
            "NumRadialDistortionCoefficients": float(len(radial)),
            "EstimateTangentialDistortion": bool(cam.p1 != 0.0 or cam.p2 != 0.0),
            "RotationVectors": np.zeros((0, 3)), "TranslationVectors": np.zeros((0, 3)),
            "ReprojectionErrors": np.zeros((0, 2)), intrinsics_key: K if intrinsics_key == "K" else K.T,
            "DetectedKeypoints": np.zeros((0, 2))}


def _struct(conv: C.Converted, intrinsics_key: str) -> dict:
    return {"CameraParameters1": _camera_struct(conv.left, intrinsics_key),
            "CameraParameters2": _camera_struct(conv.right, intrinsics_key),
            "RotationOfCamera2": np.asarray(conv.R_right_from_left, float).T,
            "TranslationOfCamera2": np.asarray(conv.T_right_from_left_mm, float).reshape(1, 3)}


def _number(x: float) -> float | int:
    """As jsonencode writes numbers: whole values without a fraction (exactly: |x| < 2^53), others as shortest
    round-trip text."""
    x = float(x)
    return int(x) if x.is_integer() and abs(x) < 2.0 ** 53 else x


def _jsonable(value):
    """MATLAB jsonencode's layout: a vector (1-by-N or N-by-1) a flat array, a matrix nested rows, empty ``[]``."""
    if isinstance(value, dict):
        return {k: _jsonable(v) for k, v in value.items()}
    if isinstance(value, np.ndarray):
        if value.size == 0:
            return []
        if value.ndim == 2 and 1 in value.shape:
            return [_number(v) for v in value.ravel()]
        return [_jsonable(row) for row in value] if value.ndim > 1 else [_number(v) for v in value]
    if isinstance(value, float):
        return _number(value)
    return value


def _json_text(struct_: dict) -> str:
    return json.dumps(_jsonable(struct_), indent=2) + "\n"


def _mat_bytes(struct_: dict) -> bytes:
    from scipy.io import savemat

    buffer = io.BytesIO()
    savemat(buffer, struct_, do_compression=False, oned_as="row")
    return buffer.getvalue()


def save_matlab(rig: CalibratedRig, path: str | Path, *, frame_rotation: bool = False,
                intrinsics_key: str = "IntrinsicMatrix") -> C.ConversionReport:
    """Write ``rig`` as a MATLAB stereoParameters struct: JSON for a ``.json`` path, a MAT-file for ``.mat``.

    Parameters
    ----------
    rig : CalibratedRig
    path : the file; its suffix chooses the encoding
    frame_rotation : bool
        Let each camera frame rotate to absorb a Scheimpflug tilt, which MATLAB's model lacks; MATLAB keeps only
        the relative pose, so its world is then the left camera's rotated frame (the report says by how much).
    intrinsics_key : ``"IntrinsicMatrix"`` (default) or ``"K"``
        ``IntrinsicMatrix = K'`` is what ``cameraParameters`` accepts in every release (``K`` only from R2022b,
        and giving both is an error there); both read back here.

    Returns
    -------
    ConversionReport
        Per camera the model written and its cost in px over the image (:func:`~.nearest.nearest_camera` into
        :data:`MATLAB_MODEL`: a tilted camera is fitted, never silently dropped).

    Raises
    ------
    ValueError
        For a suffix other than ``.json`` / ``.mat`` or an unknown ``intrinsics_key``; FileFormatError (nothing
        written) if the encoded file would not reload within 1e-6 px.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in (".json", ".mat"):
        raise ValueError(f"{path}: a MATLAB calibration needs a .json (jsonencode) or .mat (MAT-file) suffix")
    if intrinsics_key not in ("IntrinsicMatrix", "K"):
        raise ValueError(f"intrinsics_key must be 'IntrinsicMatrix' or 'K', got {intrinsics_key!r}")
    conv = C.convert_rig(rig, MATLAB_MODEL, frame_rotation)
    struct_ = _struct(conv, intrinsics_key)
    if suffix == ".json":
        text = _json_text(struct_)
        C.write_checked(path, text, lambda t: _rig_from_tree(_json_tree(t, path), path), conv)
    else:
        data = _mat_bytes(struct_)
        try:
            written = _rig_from_tree(_mat_tree(data, path), path)
        except FileFormatError as err:
            raise FileFormatError(err.file, err.key, f"{err.problem} (refusing to write a file that would not "
                                                     f"load; nothing written)") from None
        C.check_reload(written, conv, path)
        atomic_write_bytes(path, data)
    notes = ["pixel origin: MATLAB's first pixel centre is (1, 1), so the principal points are written 1 px larger "
             "than this instrument's"]
    if conv.costs[0].rotation_deg > 0.0:
        notes.append(f"MATLAB's world is camera 1's frame, here the left camera frame rotated by "
                     f"{conv.costs[0].rotation_deg:.4g} deg: 3-D coordinates are rotated by that against this "
                     f"instrument's")
    return C.report(FORMAT_NAME, path, MATLAB_MODEL, conv, _CAMERAS, frame_rotation, notes)
