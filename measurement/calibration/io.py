"""Calibration files: a JSON with every parameter and its convention, and an OpenCV-readable YAML export.

Both load back into :class:`CalibratedRig` with identical projections (the YAML stores every parameter as a
double at full precision). Both are written atomically (:mod:`labio.atomic`) and only after the content
has passed the same validation as on loading, so a file is whole and loadable or not written at all.

Loading validates every key the rig is built from (:mod:`labio.schema`): required keys (a missing one is
never filled with 0 or a default), types (a string where a number belongs is refused, never read as
1.8e308), finite values and physical ranges (:data:`RANGES`: ``0 < fx, fy < 1e6`` px, ``|tilt| <``
:data:`~measurement.camera.MAX_TILT_DEG`, ``|k1|, |k2|, |p1|, |p2| < 1e3``, image size positive integers,
R a proper rotation within 1e-6, ``0 < |T| < 1e6`` mm). Every defect raises
:class:`~labio.schema.FileFormatError` (a ``ValueError``) naming the file and the key.

Cameras may carry terms beyond Table 1 (:data:`EXTRA_RANGES`): the radial r^6 coefficient ``k3``, the skew
``K[0, 1]`` (px) and OpenCV's thin prism ``s1``-``s4``. They are written only when non-zero (so files and hashes of
calibrations without them are unchanged): in the JSON as ``<side>.extra_intrinsics = {"k3": ..., "skew": ...}``, in
the YAML as ``<side>_k3``/``<side>_skew``/``<side>_s1``... (and in K/D). Loading accepts them as optional keys,
range-checked like the rest.

A calibration fitted with more than the paper's four lens terms (:data:`~measurement.calibration.stepwise.LENSES`)
says so in the JSON (``"lens": "brown5"`` or ``"full"``; absent means ``brown4``, so files of the four-term fit are
unchanged) and stores the sigmas of its extra terms beside the others (``<side>.sigma.k3``, ``.s1``...).

A stereo calibration also stores the covariance of its shared parameters (:data:`COVARIANCE_CONVENTION`) as the
top-level key ``"covariance": {"names": [...], "matrix": [[...]], "convention": "..."}``, which
:mod:`measurement.uncertainty.calibration` propagates to points and displacements. It is optional (files written
before it, and other tools' files, load with ``CalibratedRig.covariance = None``); when present it is validated:
a finite, square, symmetric matrix (``|C_ij - C_ji| <= 1e-9 sqrt(C_ii C_jj)``) with a non-negative diagonal, one
row per name, names unique and each one of ``left.<intrinsic>``, ``right.<intrinsic>`` (the names of
:data:`~measurement.camera.INTRINSIC_NAMES` and :data:`~measurement.camera.EXTRA_NAMES`) or
:data:`~measurement.calibration.stepwise.STEREO_PARAMETER_NAMES`. A covariance that is not finite (a singular
normal matrix) or has a negative variance is not written. The entry's ``"estimator"`` says what made it:
``"linear"`` (the least squares' ``s^2 (J^T J)^-1``, :data:`COVARIANCE_CONVENTION`) or ``"bootstrap (K draws)"``
(:mod:`measurement.calibration.bootstrap`, :data:`BOOTSTRAP_COVARIANCE_CONVENTION`); files written before it have
none and are linear.
"""
from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from measurement.calibration.stepwise import (
    LENSES,
    MODELS,
    STEREO_PARAMETER_NAMES,
    TILT_MODEL,
    CameraCalibration,
    StereoCalibration,
)
from measurement.calibration.bootstrap import LINEAR, parse_estimator
from measurement.camera import EXTRA_NAMES, INTRINSIC_NAMES, MAX_TILT_DEG, TILT_MODELS, ScheimpflugCamera
from labio.atomic import atomic_write_text
from labio.schema import FileFormatError, Node, read_json_file, read_text_file

__all__ = ["FORMAT", "CONVENTION", "RANGES", "CalibratedRig", "FileFormatError", "calibration_to_dict",
           "save_calibration", "load_calibration", "export_opencv_yaml", "load_opencv_yaml", "rig_to_dict", "save_rig",
           "opencv_distortion_cost_px", "EXTRA_RANGES", "EXTRA_CONVENTION", "CAMERA_FORMAT",
           "camera_calibration_to_dict", "save_camera_calibration", "load_camera_calibration",
           "COVARIANCE_CONVENTION", "BOOTSTRAP_COVARIANCE_CONVENTION", "COVARIANCE_PARAMETER_NAMES"]

FORMAT = "scheimpflug-stereo-calibration/1"
CONVENTION = ("Camera frame as OpenCV (x right, y down, z forward), pixel centres at integer coordinates. "
              "Stereo: X_right = R_right_from_left @ X_left + T_right_from_left_mm (mm). Camera model 'rmm' is "
              "the paper's rotation-matrix Scheimpflug model: x_n = X/Z; Brown distortion (k1, k2, p1, p2) on the "
              "ideal plane; [x_t, y_t, 1] ~ A R_S^T [x_d, y_d, 1] with R_S = R_Y(beta) R_X(alpha); u = fx x_t + cx, "
              "v = fy y_t + cy. 'opencv-tilt' uses OpenCV's CALIB_TILTED_MODEL rotation order (tau_x = alpha, "
              "tau_y = beta). 'pinhole' has alpha = beta = 0.")

#: Accepted range of every Table 1 parameter in a calibration file, open intervals (lo, hi).
RANGES = {"fx": (0.0, 1e6), "fy": (0.0, 1e6), "cx": (-1e6, 1e6), "cy": (-1e6, 1e6),
          "alpha_deg": (-MAX_TILT_DEG, MAX_TILT_DEG), "beta_deg": (-MAX_TILT_DEG, MAX_TILT_DEG),
          "k1": (-1e3, 1e3), "k2": (-1e3, 1e3), "p1": (-1e3, 1e3), "p2": (-1e3, 1e3)}
#: Accepted range of the optional terms beyond Table 1: k3 multiplies r^6, so on the narrow fields of DIC lenses
#: (corners at r ~ 0.1-0.2) calibrations report |k3| of tens (the DIC Challenge cameras: ~30), hence a wider bound.
EXTRA_RANGES = {"k3": (-1e4, 1e4), "skew": (-1e4, 1e4),
                "s1": (-1e3, 1e3), "s2": (-1e3, 1e3), "s3": (-1e3, 1e3), "s4": (-1e3, 1e3)}
#: What the optional terms mean, written beside them.
EXTRA_CONVENTION = ("k3: radial r^6 term, x_d = x_n (1 + k1 r^2 + k2 r^4 + k3 r^6) + tangential terms; skew (px): "
                    "u = fx x_t + skew y_t + cx (K[0][1]); s1-s4: OpenCV's thin prism, x_d += s1 r^2 + s2 r^4, "
                    "y_d += s3 r^2 + s4 r^4. Absent means 0.")
_UNITS = {"fx": "px", "fy": "px", "cx": "px", "cy": "px", "alpha_deg": "deg", "beta_deg": "deg", "skew": "px"}
#: What the stored covariance is, written beside it.
COVARIANCE_CONVENTION = ("s^2 (J^T J)^-1 of the final stereo least-squares problem (s^2 the residual variance), its "
                         "block of the parameters named in 'names' (the board poses marginalised out); "
                         "stereo.rvec_* is the rotation vector of R_right_from_left (rad), stereo.T_*_mm is "
                         "T_right_from_left_mm (mm), alpha_deg and beta_deg are in degrees, fx, fy, cx, cy and skew "
                         "in px, distortion terms dimensionless.")
#: What a bootstrap covariance is (estimator "bootstrap (K draws)"), written beside it.
BOOTSTRAP_COVARIANCE_CONVENTION = (
    "sample covariance of K stereo calibrations (K in 'estimator') of synthetic corners: the fitted model's "
    "projections of the board at the fitted poses plus Gaussian noise of the fit's residual standard deviation per "
    "camera, each calibrated with the same options; stereo.rvec_* is the difference of the rotation vectors of "
    "R_right_from_left (rad), stereo.T_*_mm of T_right_from_left_mm (mm), alpha_deg and beta_deg in degrees, fx, "
    "fy, cx, cy and skew in px, distortion terms dimensionless.")
#: Every name a covariance row may carry: each camera's intrinsics, then the stereo pose.
COVARIANCE_PARAMETER_NAMES = (tuple(f"{side}.{n}" for side in ("left", "right") for n in INTRINSIC_NAMES + EXTRA_NAMES)
                              + STEREO_PARAMETER_NAMES)
#: Relative asymmetry a stored covariance may have: |C_ij - C_ji| <= COVARIANCE_SYMMETRY_TOL sqrt(C_ii C_jj).
COVARIANCE_SYMMETRY_TOL = 1e-9
#: Image width and height: integers in [1, MAX_IMAGE_PX].
MAX_IMAGE_PX = 1_000_000
#: The stereo translation's length must be in (0, MAX_BASELINE_MM) mm.
MAX_BASELINE_MM = 1e6


@dataclass(frozen=True)
class CalibratedRig:
    """A calibrated stereo pair as loaded from a file.

    ``covariance`` (k, k) and ``covariance_names`` (k,): the calibration's parameter covariance as stored in the
    file (:data:`COVARIANCE_CONVENTION`), or None and ``()`` when the file has none. ``covariance_estimator``:
    ``"linear"`` or ``"bootstrap (K draws)"`` (:mod:`measurement.calibration.bootstrap`), what made it.
    """

    model: str
    left: ScheimpflugCamera
    right: ScheimpflugCamera
    R_right_from_left: np.ndarray
    T_right_from_left_mm: np.ndarray
    covariance: np.ndarray | None = None
    covariance_names: tuple = ()
    covariance_estimator: str = LINEAR


def _covariance_entry(covariance, names, estimator: str = LINEAR) -> dict:
    """``{"covariance": {...}}`` for a present covariance, else ``{}``. One that is not finite or has a negative
    variance (what inverting a singular normal matrix leaves) is not written either: the loader would refuse it,
    and with it the whole calibration."""
    if covariance is None:
        return {}
    cov = np.asarray(covariance, float)
    if not (np.all(np.isfinite(cov)) and np.all(np.diag(cov) >= 0)):
        return {}
    kind, _ = parse_estimator(estimator)             # an unknown estimator is a programming error: raise
    convention = COVARIANCE_CONVENTION if kind == LINEAR else BOOTSTRAP_COVARIANCE_CONVENTION
    return {"covariance": {"names": list(names), "matrix": cov.tolist(), "convention": convention,
                           "estimator": estimator}}


def _extra_terms(cam: ScheimpflugCamera) -> dict:
    """``{"extra_intrinsics": {...}}`` with the non-zero terms beyond Table 1, or ``{}`` (nothing written)."""
    extra = {n: float(getattr(cam, n)) for n in EXTRA_RANGES if getattr(cam, n) != 0.0}
    return {"extra_intrinsics": extra} if extra else {}


def _with_extra_convention(d: dict, cams) -> dict:
    if any(_extra_terms(c) for c in cams):
        d["extra_intrinsics_convention"] = EXTRA_CONVENTION
    return d


def _camera_entry(cam_cal) -> dict:
    cam = cam_cal.camera
    return {"intrinsics": cam.intrinsics(), **_extra_terms(cam),
            "sigma": {n: cam_cal.sigma[n] for n in INTRINSIC_NAMES + EXTRA_NAMES if n in cam_cal.sigma},
            "tilt_model": cam.tilt_model, "width": cam.width, "height": cam.height,
            "reprojection_rms_px": cam_cal.rms_px, "per_view_rms_px": np.asarray(cam_cal.per_view_rms_px).tolist(),
            "steps": [{"step": s[0], "free": list(s[1]), "rms_px": s[2]} for s in cam_cal.steps]}


def calibration_to_dict(cal: StereoCalibration, extra: dict | None = None) -> dict:
    """Everything a user needs to reuse or audit a calibration, as plain JSON types."""
    d = {"format": FORMAT, "convention": CONVENTION, "model": cal.model,
         **({"lens": cal.lens} if getattr(cal, "lens", "brown4") != "brown4" else {}),
         "image_size_px": [cal.left.camera.width, cal.left.camera.height],
         "left": _camera_entry(cal.left), "right": _camera_entry(cal.right),
         "stereo": {"R_right_from_left": np.asarray(cal.R_right_from_left).tolist(),
                    "rvec_right_from_left": cv2.Rodrigues(np.asarray(cal.R_right_from_left))[0].ravel().tolist(),
                    "T_right_from_left_mm": np.asarray(cal.T_right_from_left_mm).tolist(),
                    "sigma_rvec": cal.sigma_stereo["rvec"], "sigma_T_mm": cal.sigma_stereo["T_mm"]},
         "reprojection_rms_px": dict(cal.rms_px),
         "steps": [{"step": s[0], "free": list(s[1]), "rms_px": s[2]} for s in cal.steps],
         **_covariance_entry(getattr(cal, "covariance", None), getattr(cal, "covariance_names", ()),
                             getattr(cal, "covariance_estimator", LINEAR))}
    _with_extra_convention(d, (cal.left.camera, cal.right.camera))
    if extra:
        d.update(extra)
    return d


def rig_to_dict(rig: CalibratedRig, extra: dict | None = None) -> dict:
    """A loaded rig in the calibration JSON format: no sigmas or calibration history, the parameter covariance
    when the rig has one."""
    d = {"format": FORMAT, "convention": CONVENTION, "model": rig.model,
         "image_size_px": [rig.left.width, rig.left.height],
         **{side: {"intrinsics": cam.intrinsics(), **_extra_terms(cam), "tilt_model": cam.tilt_model,
                   "width": cam.width, "height": cam.height}
            for side, cam in (("left", rig.left), ("right", rig.right))},
         "stereo": {"R_right_from_left": np.asarray(rig.R_right_from_left).tolist(),
                    "rvec_right_from_left": cv2.Rodrigues(np.asarray(rig.R_right_from_left))[0].ravel().tolist(),
                    "T_right_from_left_mm": np.asarray(rig.T_right_from_left_mm).ravel().tolist()},
         **_covariance_entry(rig.covariance, rig.covariance_names, rig.covariance_estimator)}
    _with_extra_convention(d, (rig.left, rig.right))
    if extra:
        d.update(extra)
    return d


def save_rig(rig: CalibratedRig, path: str | Path, extra: dict | None = None) -> None:
    """Write a loaded rig as calibration JSON (``.json``) or OpenCV YAML/XML (``.yaml``/``.yml``/``.xml``), after
    checking it loads back."""
    path = Path(path)
    if path.suffix.lower() in OPENCV_SUFFIXES:
        export_opencv_yaml(rig, path)
        return
    text = json.dumps(rig_to_dict(rig, extra), indent=1)
    _refuse_unloadable(lambda: _rig_from_json(Node(json.loads(text), path)))
    atomic_write_text(path, text)


def opencv_distortion_cost_px(cam: ScheimpflugCamera, n: int = 21) -> float:
    """Largest distance (px) over an ``n x n`` grid of the image between ``cam``'s projection and OpenCV's
    ``cv2.projectPoints`` with the ``K``/``D`` that :func:`export_opencv_yaml` writes for it: what a tool that
    reads only K and D loses (0 where OpenCV's tilted model expresses the camera exactly)."""
    u, v = np.meshgrid(np.linspace(0, cam.width - 1, n), np.linspace(0, cam.height - 1, n))
    pixels = np.column_stack([u.ravel(), v.ravel()])
    rays = cam.rays(pixels)
    rays = rays / rays[:, 2:3]
    ours = cam.project(rays)
    theirs = cv2.projectPoints(rays, np.zeros(3), np.zeros(3), cam.K, opencv_distortion(cam))[0].reshape(-1, 2)
    return float(np.max(np.linalg.norm(ours - theirs, axis=1)))


def save_calibration(cal: StereoCalibration, path: str | Path, extra: dict | None = None) -> None:
    """Write the calibration JSON atomically, after checking it loads back (FileFormatError otherwise)."""
    text = json.dumps(calibration_to_dict(cal, extra), indent=1)
    _refuse_unloadable(lambda: _rig_from_json(Node(json.loads(text), path)))
    atomic_write_text(path, text)


def _refuse_unloadable(load) -> None:
    try:
        load()
    except FileFormatError as err:
        raise FileFormatError(err.file, err.key, f"{err.problem} (refusing to write a file that would not load; "
                                                 f"nothing written)") from None


# --- validation ----------------------------------------------------------------------------------------------
def _camera(values: dict[str, float], width: int, height: int, tilt_model: str, model: str, where: Node,
            key_of) -> ScheimpflugCamera:
    """The camera of validated values, checked against the file's model; ``key_of(name)`` names a key."""
    if tilt_model != TILT_MODEL[model]:
        raise where.error(f"tilt model {tilt_model!r} contradicts the file's model {model!r} "
                          f"(which uses {TILT_MODEL[model]!r})", key=key_of("tilt_model"))
    if model == "pinhole":
        for n in ("alpha_deg", "beta_deg"):
            if values[n] != 0.0:
                raise where.error(f"must be 0 for the 'pinhole' model, got {values[n]!r}", key=key_of(n))
    try:
        return ScheimpflugCamera(**values, width=width, height=height, tilt_model=tilt_model)
    except ValueError as err:                                   # pragma: no cover - the ranges above are tighter
        raise where.error(f"invalid camera: {err}") from None


def _intrinsic(node: Node, name: str) -> float:
    lo, hi = RANGES[name] if name in RANGES else EXTRA_RANGES[name]
    return node.number(lo, hi, unit=_UNITS.get(name, ""))


def _json_camera(entry: Node, model: str) -> ScheimpflugCamera:
    entry.mapping()
    intr = entry["intrinsics"]
    intr.only_keys(INTRINSIC_NAMES)
    values = {n: _intrinsic(intr[n], n) for n in INTRINSIC_NAMES}
    extra = entry.get("extra_intrinsics")
    if extra is not None:                              # optional: written only for cameras with k3 or skew
        extra.only_keys(EXTRA_RANGES)
        values.update({n: _intrinsic(extra[n], n) for n in EXTRA_RANGES if extra.get(n) is not None})
    width, height = entry["width"].integer(1, MAX_IMAGE_PX), entry["height"].integer(1, MAX_IMAGE_PX)
    tilt_model = entry["tilt_model"].string(TILT_MODELS)
    key = entry.key
    return _camera(values, width, height, tilt_model, model, entry,
                   lambda n: f"{key}.{'intrinsics.' if n in INTRINSIC_NAMES else ''}{n}")


def _optional_extras(doc: Node, prefix: str) -> dict[str, float]:
    """The optional ``<prefix>k3`` / ``<prefix>skew`` / ``<prefix>s1``... scalars of a YAML (absent = 0, not
    returned)."""
    return {n: _intrinsic(doc[f"{prefix}{n}"], n) for n in EXTRA_RANGES if doc.get(f"{prefix}{n}") is not None}


def _model(node: Node) -> str:
    return node.string(MODELS)


def _check_format(node: Node) -> None:
    fmt = node.string(nonempty=False)
    if fmt != FORMAT:
        raise node.error(f"unknown format {fmt!r}, expected {FORMAT!r}")


def _translation(node: Node, shape=(3,)) -> np.ndarray:
    T = node.array(shape).ravel()
    norm = float(np.linalg.norm(T))
    if not 0.0 < norm < MAX_BASELINE_MM:
        raise node.error(f"the stereo translation's length must be in (0, {MAX_BASELINE_MM:g}) mm, got {norm:.6g} mm")
    return T


#: Most rows a stored covariance may have (every name of COVARIANCE_PARAMETER_NAMES once).
_MAX_COVARIANCE_ROWS = len(COVARIANCE_PARAMETER_NAMES)


def _covariance_from_json(node: Node) -> tuple[np.ndarray, tuple[str, ...], str]:
    """The validated ``(matrix (k, k), names (k,), estimator)`` of a ``covariance`` entry (module docstring)."""
    node.mapping()
    node.only_keys(("names", "matrix", "convention", "estimator"))
    if node.get("convention") is not None:
        node["convention"].string(nonempty=False)
    estimator = LINEAR                              # files written before the key: the least squares' covariance
    if node.get("estimator") is not None:
        estimator = node["estimator"].string()
        try:
            parse_estimator(estimator)
        except ValueError as err:
            raise node["estimator"].error(str(err)) from None
    names_node = node["names"]
    names = tuple(n.string() for n in names_node.sequence(1, _MAX_COVARIANCE_ROWS))
    for i, name in enumerate(names):
        if name not in COVARIANCE_PARAMETER_NAMES:
            raise names_node.error(f"unknown parameter {name!r}; a name is left.<intrinsic>, right.<intrinsic> "
                                   f"({', '.join(INTRINSIC_NAMES + EXTRA_NAMES)}) or one of "
                                   f"{', '.join(STEREO_PARAMETER_NAMES)}", key=f"{names_node.key}[{i}]")
        if name in names[:i]:
            raise names_node.error(f"parameter {name!r} is listed twice", key=f"{names_node.key}[{i}]")
    k = len(names)
    matrix_node = node["matrix"]
    rows = matrix_node.sequence()
    if len(rows) != k:
        raise matrix_node.error(f"has {len(rows)} rows but {names_node.key} lists {k} names (one row and column "
                                f"per name)")
    cov = matrix_node.array((k, k))             # square, finite numbers (names the row and column otherwise)
    d = np.diag(cov)
    if np.any(d < 0):
        i = int(np.flatnonzero(d < 0)[0])
        raise matrix_node.error(f"a variance must not be negative, got {d[i]:.6g} for {names[i]!r}",
                                key=f"{matrix_node.key}[{i}][{i}]")
    limit = COVARIANCE_SYMMETRY_TOL * np.sqrt(np.outer(d, d))
    bad = np.abs(cov - cov.T) > limit
    if bad.any():
        i, j = (int(a) for a in np.argwhere(bad)[0])
        raise matrix_node.error(f"is not symmetric: [{i}][{j}] = {cov[i, j]:.17g} but [{j}][{i}] = {cov[j, i]:.17g} "
                                f"(allowed: {COVARIANCE_SYMMETRY_TOL:g} sqrt(C_ii C_jj))")
    return cov, names, estimator


def _rig_from_json(doc: Node) -> CalibratedRig:
    doc.mapping()
    _check_format(doc["format"])
    model = _model(doc["model"])
    if doc.get("lens") is not None:                    # optional: written for the five-term lens fit only
        doc["lens"].string(LENSES)
    left, right = _json_camera(doc["left"], model), _json_camera(doc["right"], model)
    size = doc.get("image_size_px")
    if size is not None:
        w, h = (n.integer(1, MAX_IMAGE_PX) for n in size.sequence(2, 2))
        if (w, h) != (left.width, left.height):
            raise size.error(f"{w} x {h} disagrees with the left camera's {left.width} x {left.height} px")
    st = doc["stereo"]
    R = st["R_right_from_left"].rotation()
    T = _translation(st["T_right_from_left_mm"])
    rvec = st.get("rvec_right_from_left")
    if rvec is not None:
        rv = rvec.array((3,), bound=10.0)
        if not np.max(np.abs(cv2.Rodrigues(rv)[0] - R)) <= 1e-6:
            raise rvec.error("disagrees with R_right_from_left (edit both, or remove the rotation vector)")
    cov, cov_names, estimator = None, (), LINEAR
    if doc.get("covariance") is not None:             # optional: calibrations of this instrument write it
        cov, cov_names, estimator = _covariance_from_json(doc["covariance"])
    return CalibratedRig(model, left, right, R, T, cov, cov_names, estimator)


def load_calibration(path: str | Path) -> CalibratedRig:
    """Read a calibration JSON written by :func:`save_calibration` (or an OpenCV YAML by :func:`export_opencv_yaml`).

    Raises
    ------
    FileFormatError (a ValueError)
        Naming the file and the key: missing/empty/non-UTF-8/non-JSON file, unknown format, a missing key, a
        wrong type, a non-finite value or one outside :data:`RANGES`, R not a rotation, T zero, a malformed
        ``covariance`` (module docstring).
    """
    path = Path(path)
    if path.suffix.lower() in OPENCV_SUFFIXES:
        return load_opencv_yaml(path)
    return _rig_from_json(read_json_file(path, "calibration file"))


def export_opencv_yaml(rig: CalibratedRig | StereoCalibration, path: str | Path) -> None:
    """Write an OpenCV ``FileStorage`` YAML (XML for a ``.xml`` path): K1, D1, K2, D2, R, T, image size, and every
    Table 1 parameter.

    ``D1``/``D2`` are OpenCV's 14 ``CALIB_TILTED_MODEL`` coefficients. They reproduce our projection exactly only
    for the ``opencv-tilt`` and ``pinhole`` models or a single-axis RMM tilt, and without a skew (``K[0][1]``, which
    ``cv2.projectPoints`` ignores); ``D_exact`` says which. The named scalars (``left_fx`` ..., ``left_k3`` and
    ``left_skew`` when non-zero) always hold the exact model. The file is written atomically, after the text has
    passed :func:`load_opencv_yaml`'s validation.
    """
    if isinstance(rig, StereoCalibration):
        rig = CalibratedRig(rig.model, rig.left.camera, rig.right.camera, rig.R_right_from_left, rig.T_right_from_left_mm)
    fmt = _storage_format(path)               # .xml: the same keys in OpenCV's XML
    fs = cv2.FileStorage(".xml" if fmt == cv2.FILE_STORAGE_FORMAT_XML else ".yaml",
                         cv2.FILE_STORAGE_WRITE | cv2.FILE_STORAGE_MEMORY | fmt)
    if not fs.isOpened():                                       # pragma: no cover
        raise OSError(f"cannot write {path}: OpenCV could not open a FileStorage")
    fs.write("format", FORMAT)
    fs.write("model", rig.model)
    fs.write("convention", CONVENTION)
    fs.write("image_width", int(rig.left.width))
    fs.write("image_height", int(rig.left.height))
    for side, cam in (("1", rig.left), ("2", rig.right)):
        fs.write(f"K{side}", cam.K)
        fs.write(f"D{side}", opencv_distortion(cam))
        # cv2.projectPoints reads fx, fy, cx, cy of K only, so a skew makes K/D inexact for OpenCV's projection
        exact = (cam.tilt_model == "opencv" or cam.alpha_deg == 0.0 or cam.beta_deg == 0.0) and cam.skew == 0.0
        fs.write(f"D{side}_exact", int(exact))
    for name, cam in (("left", rig.left), ("right", rig.right)):
        fs.write(f"{name}_tilt_model", cam.tilt_model)
        for n in INTRINSIC_NAMES:
            fs.write(f"{name}_{n}", float(getattr(cam, n)))
        for n, v in _extra_terms(cam).get("extra_intrinsics", {}).items():
            fs.write(f"{name}_{n}", v)
    fs.write("R", np.asarray(rig.R_right_from_left, float))
    fs.write("T", np.asarray(rig.T_right_from_left_mm, float).reshape(3, 1))
    text = fs.releaseAndGetString()
    _refuse_unloadable(lambda: _rig_from_yaml_text(text, path))
    atomic_write_text(path, text)


def opencv_distortion(cam: ScheimpflugCamera) -> np.ndarray:
    """OpenCV's 14 coefficients (k1, k2, p1, p2, k3, k4, k5, k6, s1..s4, tau_x, tau_y) of ``cam``, (1, 14)."""
    dist = np.zeros((1, 14))
    dist[0, :5] = cam.k1, cam.k2, cam.p1, cam.p2, cam.k3
    dist[0, 8:12] = cam.s1, cam.s2, cam.s3, cam.s4
    dist[0, 12:] = cam.alpha_rad, cam.beta_rad
    return dist


def _cv_message(err: BaseException) -> str:
    """The useful part of an OpenCV error ("... error: (-212:Parsing error) ... in function '...'")."""
    err = err.__cause__ or err
    text = str(err).strip().splitlines()[0] if str(err).strip() else type(err).__name__
    return text.split(" error: ", 1)[-1]


def _filenode_value(node, file, depth: int = 0):
    """A cv2.FileNode as plain Python values (maps -> dict, sequences -> list, int, float, str, None)."""
    if depth > 64:
        raise FileFormatError(file, "", "is not a usable OpenCV YAML file: nested too deeply")
    if node.isMap():
        return {k: _filenode_value(node.getNode(k), file, depth + 1) for k in node.keys()}
    if node.isSeq():
        return [_filenode_value(node.at(i), file, depth + 1) for i in range(node.size())]
    if node.isInt():
        return int(node.real())
    if node.isReal():
        return float(node.real())
    if node.isString():
        return node.string()
    return None


#: OpenCV's YAML parser recurses once per nesting level and overflows the stack (a segmentation fault, not an
#: exception) somewhere between 20 000 and 50 000 levels (``a: [[[[...``, ``- - - ...``). Texts that could nest
#: that deep are refused before parsing: at most this many bytes (block nesting by indentation then stays
#: below ~1 500 levels) and at most MAX_YAML_NESTING_TOKENS characters that can open a level. A calibration
#: YAML has ~2.5 kB and ~100 such characters.
MAX_YAML_BYTES = 1 << 20
MAX_YAML_NESTING_TOKENS = 10_000


#: OpenCV FileStorage formats by file suffix (the same keys in either).
_STORAGE_FORMAT = {".yaml": cv2.FILE_STORAGE_FORMAT_YAML, ".yml": cv2.FILE_STORAGE_FORMAT_YAML,
                   ".xml": cv2.FILE_STORAGE_FORMAT_XML}
OPENCV_SUFFIXES = tuple(_STORAGE_FORMAT)


def _storage_format(path) -> int:
    return _STORAGE_FORMAT.get(Path(str(path)).suffix.lower(), cv2.FILE_STORAGE_FORMAT_YAML)


def _read_opencv_yaml(text: str, path) -> Node:
    kind = "XML" if _storage_format(path) == cv2.FILE_STORAGE_FORMAT_XML else "YAML"
    if len(text.encode("utf-8", "surrogatepass")) > MAX_YAML_BYTES:
        raise FileFormatError(path, "", f"is larger than {MAX_YAML_BYTES} bytes: not a calibration YAML")
    tokens = sum(text.count(c) for c in "[{-:?")
    if tokens > MAX_YAML_NESTING_TOKENS:
        raise FileFormatError(path, "", f"has {tokens} of the characters '[{{-:?' (more than "
                                        f"{MAX_YAML_NESTING_TOKENS}): too deeply nested for a calibration YAML")
    try:
        fs = cv2.FileStorage(text, cv2.FILE_STORAGE_READ | cv2.FILE_STORAGE_MEMORY | _storage_format(path))
    except (cv2.error, SystemError) as err:
        raise FileFormatError(path, "", f"is not an OpenCV FileStorage {kind} file: {_cv_message(err)}") from None
    try:
        if not fs.isOpened():
            raise FileFormatError(path, "", f"is not an OpenCV FileStorage {kind} file")
        value = _filenode_value(fs.root(), path)
    except (cv2.error, SystemError, UnicodeError) as err:
        raise FileFormatError(path, "", f"is not a usable OpenCV FileStorage {kind} file: {_cv_message(err)}") from None
    finally:
        fs.release()
    return Node(value, path)


def _opencv_matrix(node: Node, shape: tuple[int, int], *, bound: float = 1e12) -> np.ndarray:
    """An ``!!opencv-matrix`` map (rows, cols, dt, data) of exactly ``shape``, as float64."""
    node.mapping()
    rows, cols = node["rows"].integer(0, 10 ** 6), node["cols"].integer(0, 10 ** 6)
    if (rows, cols) != shape:
        raise node.error(f"must be a {shape[0]} x {shape[1]} matrix, got {rows} x {cols}")
    node["dt"].string(("d", "f"))
    return node["data"].array((rows * cols,), bound=bound).reshape(shape)


def _close(a, b) -> bool:
    a, b = np.asarray(a, float), np.asarray(b, float)
    return bool(np.all(np.abs(a - b) <= 1e-9 * np.maximum(1.0, np.abs(b))))


#: Names of the camera matrices and distortion vectors in OpenCV stereo files written by other programs
#: (``cv2.stereoCalibrate`` scripts, OpenCV's stereo_calib sample, ROS-style exports), camera n = 1 or 2.
_PLAIN_K = ("K{n}", "M{n}", "cameraMatrix{n}", "camera_matrix_{n}")
_PLAIN_D = ("D{n}", "distCoeffs{n}", "dist_coeffs_{n}")
#: OpenCV's distortion vector: the terms after p2 (k3, k4-k6, s1-s4, tau_x, tau_y) by position.
_OPENCV_EXTRA_TERMS = ("k3", "k4", "k5", "k6", "s1", "s2", "s3", "s4", "tau_x", "tau_y")


def _first_key(doc: Node, names, n: int, what: str) -> Node:
    for name in names:
        node = doc.get(name.format(n=n))
        if node is not None:
            return node
    raise doc.error(f"has no {what} of camera {n} (looked for {', '.join(x.format(n=n) for x in names)})")


def _plain_size(doc: Node) -> tuple[int, int]:
    for wk, hk in (("image_width", "image_height"), ("width", "height")):
        if doc.get(wk) is not None and doc.get(hk) is not None:
            return doc[wk].integer(1, MAX_IMAGE_PX), doc[hk].integer(1, MAX_IMAGE_PX)
    for key in ("imageSize", "image_size"):
        node = doc.get(key)
        if node is not None:
            value = node.value
            if isinstance(value, dict):                      # an !!opencv-matrix of 2 values (any dtype)
                value = node["data"].value
            w, h = Node(value, node.file, key).array((2,), bound=MAX_IMAGE_PX)
            if w != int(w) or h != int(h) or min(w, h) < 1:
                raise node.error(f"must be two positive whole numbers (width, height), got {value!r}")
            return int(w), int(h)
    raise doc.error("has no image size: add image_width and image_height (px), or imageSize: [width, height]")


#: The OpenCV distortion terms this instrument's lens model holds, by position: k1 k2 p1 p2 k3, s1-s4 (8-11) and
#: tau_x tau_y (positions 12, 13: CALIB_TILTED_MODEL, this instrument's "opencv" tilt model).
_PLAIN_KEPT = (0, 1, 2, 3, 4, 8, 9, 10, 11, 12, 13)


def _plain_distortion(node: Node, K: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """The 14 OpenCV coefficients of a distortion vector of 4, 5, 8, 12 or 14 values (zero-padded), shape (14,).

    The model holds k1 k2 p1 p2 k3, the thin prism s1-s4 and tau_x tau_y; a non-zero rational term (k4-k6) is
    refused with the pixels dropping it would move the image corners by."""
    value = node.value
    if isinstance(value, dict):
        rows, cols = int(value.get("rows", 0)), int(value.get("cols", 0))
        if min(rows, cols) != 1 or rows * cols not in (4, 5, 8, 12, 14):
            raise node.error(f"must be a 1 x N or N x 1 OpenCV distortion vector with N = 4, 5, 8, 12 or 14, got "
                             f"{rows} x {cols}")
        d = _opencv_matrix(node, (rows, cols)).ravel()
    else:
        d = np.asarray(Node(value, node.file, node.key).array((len(value),) if isinstance(value, list) else (4,)))
        if d.size not in (4, 5, 8, 12, 14):
            raise node.error(f"must hold 4, 5, 8, 12 or 14 distortion terms, got {d.size}")
    extra = {name: float(v) for i, (name, v) in enumerate(zip(_OPENCV_EXTRA_TERMS, d[4:]), start=4)
             if v != 0.0 and i not in _PLAIN_KEPT}
    full14 = np.zeros(14)
    full14[:d.size] = d
    if extra:
        w, h = size
        corners = np.array([[0, 0], [w - 1, 0], [0, h - 1], [w - 1, h - 1]], dtype=np.float64)
        ideal = cv2.undistortPoints(corners.reshape(-1, 1, 2), K, d).reshape(-1, 2)
        rays = np.column_stack([ideal, np.ones(len(ideal))])
        kept = np.zeros(14)
        kept[list(_PLAIN_KEPT)] = full14[list(_PLAIN_KEPT)]
        full = cv2.projectPoints(rays, np.zeros(3), np.zeros(3), K, full14)[0].reshape(-1, 2)
        short = cv2.projectPoints(rays, np.zeros(3), np.zeros(3), K, kept)[0].reshape(-1, 2)
        cost = float(np.max(np.linalg.norm(full - short, axis=1)))
        terms = ", ".join(f"{k} = {v:g}" for k, v in extra.items())
        raise node.error(f"has {terms}: this instrument's lens model has k1, k2, p1, p2, k3, s1-s4 (and tau_x, tau_y) "
                         "only; "
                         f"dropping the rest would move the image corners by up to {cost:.3g} px, so the file is "
                         f"refused")
    return full14


def _plain_camera_values(k_node: Node, d_node: Node, size: tuple[int, int]) -> dict[str, float]:
    """The camera parameters of an OpenCV camera matrix and distortion vector, range-checked (the error names the
    node that gives a bad value)."""
    K = _opencv_matrix(k_node, (3, 3))
    if not (np.allclose(K[1, 0], 0) and np.allclose(K[2], [0, 0, 1])):
        raise k_node.error(f"is not a camera matrix [[fx, s, cx], [0, fy, cy], [0, 0, 1]]: {K.tolist()}")
    d = _plain_distortion(d_node, K, size)
    values = {"fx": K[0, 0], "fy": K[1, 1], "cx": K[0, 2], "cy": K[1, 2],
              "alpha_deg": float(np.rad2deg(d[12])), "beta_deg": float(np.rad2deg(d[13])),
              "k1": d[0], "k2": d[1], "p1": d[2], "p2": d[3], "k3": d[4], "skew": K[0, 1],
              "s1": d[8], "s2": d[9], "s3": d[10], "s4": d[11]}
    for key, v in values.items():
        lo, hi = RANGES[key] if key in RANGES else EXTRA_RANGES[key]
        if not (lo < v < hi) or (key in ("fx", "fy") and not v > 0):
            node = k_node if key in ("fx", "fy", "cx", "cy", "skew") else d_node
            raise node.error(f"gives {key} = {v:g}, outside ({lo:g}, {hi:g})")
    return {k: float(v) for k, v in values.items()}


def _rig_from_plain_opencv(doc: Node, path) -> CalibratedRig:
    """A stereo calibration as OpenCV programs write it: K1 D1 K2 D2 R T and the image size; a pinhole rig, or an
    ``opencv-tilt`` one when a distortion vector has tau_x/tau_y. K[0][1] is the skew. T is taken in mm (the unit of
    the square size given to the calibration)."""
    size = _plain_size(doc)
    found = {}
    for n, name in ((1, "left"), (2, "right")):
        found[name] = _plain_camera_values(_first_key(doc, _PLAIN_K, n, "camera matrix"),
                                           _first_key(doc, _PLAIN_D, n, "distortion vector"), size)
    # one model for the rig: OpenCV's tilted model if either camera has a tilt (tau = 0 is the pinhole then)
    tilted = any(v["alpha_deg"] != 0.0 or v["beta_deg"] != 0.0 for v in found.values())
    model, tilt_model = ("opencv-tilt", "opencv") if tilted else ("pinhole", "rmm")
    cams = {name: _camera(v, size[0], size[1], tilt_model, model, doc, lambda k: k) for name, v in found.items()}
    r_node = doc["R"]
    r_val = r_node.value
    if isinstance(r_val, dict) and (int(r_val.get("rows", 0)), int(r_val.get("cols", 0))) in ((3, 1), (1, 3)):
        R = cv2.Rodrigues(_opencv_matrix(r_node, (int(r_val["rows"]), int(r_val["cols"]))).reshape(3, 1))[0]
    else:
        R = _opencv_matrix(r_node, (3, 3))
    R = Node(R.tolist(), path, "R").rotation()
    t_node = doc["T"]
    t_val = t_node.value
    shape = (int(t_val.get("rows", 3)), int(t_val.get("cols", 1))) if isinstance(t_val, dict) else (3, 1)
    if shape not in ((3, 1), (1, 3)):
        raise t_node.error(f"must be a 3-vector, got {shape[0]} x {shape[1]}")
    T = _translation(Node(_opencv_matrix(t_node, shape).reshape(3, 1).tolist(), path, "T"), (3, 1))
    return CalibratedRig(model, cams["left"], cams["right"], R, T)


def _rig_from_yaml_text(text: str, path) -> CalibratedRig:
    doc = _read_opencv_yaml(text, path)
    doc.mapping()
    ours = any(doc.get(k) is not None for k in ("format", "model", "left_fx", "right_fx"))
    if not ours:                                   # not the project's own export: an OpenCV program's file
        return _rig_from_plain_opencv(doc, path)
    _check_format(doc["format"])
    model = _model(doc["model"])
    width, height = doc["image_width"].integer(1, MAX_IMAGE_PX), doc["image_height"].integer(1, MAX_IMAGE_PX)
    cams = {}
    for side, name in (("1", "left"), ("2", "right")):
        values = {n: _intrinsic(doc[f"{name}_{n}"], n) for n in INTRINSIC_NAMES}
        values.update(_optional_extras(doc, f"{name}_"))
        tilt_model = doc[f"{name}_tilt_model"].string(TILT_MODELS)
        cam = _camera(values, width, height, tilt_model, model, doc, lambda n: f"{name}_{n}")
        # K and D are OpenCV's view of the same camera: if present they must agree with the named scalars,
        # which are what is loaded (an edit of K1 alone would otherwise be ignored silently).
        for key, shape, expected in ((f"K{side}", (3, 3), cam.K), (f"D{side}", (1, 14), opencv_distortion(cam))):
            node = doc.get(key)
            if node is not None and not _close(_opencv_matrix(node, shape), expected):
                raise node.error(f"disagrees with the {name}_* parameters, which are what is loaded "
                                 f"(edit both, or remove {key})")
        cams[name] = cam
    R = Node(_opencv_matrix(doc["R"], (3, 3)).tolist(), path, "R").rotation()
    T = _translation(Node(_opencv_matrix(doc["T"], (3, 1)).tolist(), path, "T"), (3, 1))
    return CalibratedRig(model, cams["left"], cams["right"], R, T)


def load_opencv_yaml(path: str | Path) -> CalibratedRig:
    """Read back a YAML (or, by its ``.xml`` suffix, an XML) written by :func:`export_opencv_yaml` (OpenCV
    ``FileStorage``), validated.

    Every key the rig is built from is required (``format``, ``model``, ``image_width``, ``image_height``,
    ``{left,right}_{tilt_model, fx, ..., p2}``, ``R``, ``T``); ``K1``/``D1``/``K2``/``D2`` are optional but must
    agree with the named parameters. A file with none of ``format``, ``model``, ``left_fx``, ``right_fx`` is read
    as other OpenCV programs write a stereo
    calibration (``cv2.stereoCalibrate``): ``K1``/``M1``/``cameraMatrix1``, ``D1``/``distCoeffs1``, the same
    for camera 2, ``R`` (3 x 3 or a rotation vector), ``T`` (mm) and the image size (``image_width`` and
    ``image_height``, or ``imageSize``); a pinhole rig (``opencv-tilt`` when a D has tau_x/tau_y; k3 and the skew
    K[0][1] are kept; non-zero k4-k6 or s1-s4 are refused with their pixel cost).
    Raises FileFormatError (a ValueError) naming the file
    and the key.
    """
    return _rig_from_yaml_text(read_text_file(path, "calibration file", max_bytes=MAX_YAML_BYTES), path)


# --- single-camera calibrations ------------------------------------------------------------------------------
#: Format tag of a single-camera calibration JSON (``workbench calibrate --camera``).
CAMERA_FORMAT = "scheimpflug-camera-calibration/1"


def camera_calibration_to_dict(cal: CameraCalibration, model: str, extra: dict | None = None) -> dict:
    """One camera's calibration (intrinsics, sigmas, residuals, steps, board poses) as plain JSON types."""
    if model not in MODELS:
        raise ValueError(f"unknown camera model {model!r}; choose one of {', '.join(MODELS)}")
    d = {"format": CAMERA_FORMAT, "convention": CONVENTION, "model": model,
         **({"lens": cal.lens} if cal.lens != "brown4" else {}),
         "image_size_px": [cal.camera.width, cal.camera.height],
         "camera": _camera_entry(cal),
         "board_poses": {"rvec": np.asarray(cal.rvecs).tolist(), "t_mm": np.asarray(cal.tvecs_mm).tolist(),
                         "convention": "X_cam = R(rvec) X_board + t_mm"}}
    _with_extra_convention(d, (cal.camera,))
    if extra:
        d.update(extra)
    return d


def _camera_from_json(doc: Node) -> ScheimpflugCamera:
    doc.mapping()
    fmt = doc["format"].string(nonempty=False)
    if fmt != CAMERA_FORMAT:
        hint = " (a stereo calibration: load it with load_calibration)" if fmt == FORMAT else ""
        raise doc["format"].error(f"unknown format {fmt!r}, expected {CAMERA_FORMAT!r}{hint}")
    model = _model(doc["model"])
    if doc.get("lens") is not None:
        doc["lens"].string(LENSES)
    return _json_camera(doc["camera"], model)


def opencv_camera_yaml_text(cal: CameraCalibration | ScheimpflugCamera, path: str | Path) -> str:
    """OpenCV's single-camera calibration file (the keys of OpenCV's ``calibration`` sample: ``camera_matrix``,
    ``distortion_coefficients`` (14 terms), ``image_width``, ``image_height``, ``avg_reprojection_error``), YAML or
    XML by the suffix of ``path``, plus the named parameters (``fx``, ...) that hold the exact model."""
    cam = cal.camera if isinstance(cal, CameraCalibration) else cal
    fmt = _storage_format(path)
    fs = cv2.FileStorage(".xml" if fmt == cv2.FILE_STORAGE_FORMAT_XML else ".yaml",
                         cv2.FILE_STORAGE_WRITE | cv2.FILE_STORAGE_MEMORY | fmt)
    fs.write("format", CAMERA_FORMAT)
    fs.write("image_width", int(cam.width))
    fs.write("image_height", int(cam.height))
    fs.write("camera_matrix", cam.K)
    fs.write("distortion_coefficients", opencv_distortion(cam))
    if isinstance(cal, CameraCalibration):
        fs.write("avg_reprojection_error", float(cal.rms_px))
    fs.write("tilt_model", cam.tilt_model)
    for n in INTRINSIC_NAMES:
        fs.write(n, float(getattr(cam, n)))
    for n, v in _extra_terms(cam).get("extra_intrinsics", {}).items():
        fs.write(n, v)
    return fs.releaseAndGetString()


def save_camera_calibration(cal: CameraCalibration, path: str | Path, *, model: str,
                            extra: dict | None = None) -> None:
    """Write a single-camera calibration: JSON (``.json``) or OpenCV YAML/XML by suffix; atomically, after checking
    that the text loads back."""
    path = Path(path)
    if path.suffix.lower() in OPENCV_SUFFIXES:
        text = opencv_camera_yaml_text(cal, path)
        _refuse_unloadable(lambda: _camera_from_opencv_text(text, path))
    else:
        text = json.dumps(camera_calibration_to_dict(cal, model, extra), indent=1)
        _refuse_unloadable(lambda: _camera_from_json(Node(json.loads(text), path)))
    atomic_write_text(path, text)


def _one_of(doc: Node, names, what: str) -> Node:
    for name in names:
        if doc.get(name) is not None:
            return doc[name]
    raise doc.error(f"has no {what} (looked for {', '.join(names)})")


def _camera_from_opencv_text(text: str, path) -> ScheimpflugCamera:
    """A camera from OpenCV's calibration-sample keys; the named parameters (this instrument's export) win."""
    doc = _read_opencv_yaml(text, path)
    doc.mapping()
    size = _plain_size(doc)
    if doc.get("fx") is not None and doc.get("tilt_model") is not None:
        values = {n: _intrinsic(doc[n], n) for n in INTRINSIC_NAMES}
        values.update(_optional_extras(doc, ""))
        tilt_model = doc["tilt_model"].string(TILT_MODELS)
        model = "pinhole" if values["alpha_deg"] == values["beta_deg"] == 0.0 else \
            ("opencv-tilt" if tilt_model == "opencv" else "rmm")
        return _camera(values, size[0], size[1], tilt_model, model, doc, lambda n: n)
    values = _plain_camera_values(_one_of(doc, ("camera_matrix", "cameraMatrix", "K"), "camera matrix"),
                                  _one_of(doc, ("distortion_coefficients", "distCoeffs", "D"), "distortion vector"),
                                  size)
    tilted = values["alpha_deg"] != 0.0 or values["beta_deg"] != 0.0
    return ScheimpflugCamera(**values, width=size[0], height=size[1],
                             tilt_model="opencv" if tilted else "rmm")


def load_camera_calibration(path: str | Path) -> ScheimpflugCamera:
    """Read one camera: this instrument's camera JSON (``workbench calibrate --camera``), or an OpenCV YAML/XML
    with ``camera_matrix``, ``distortion_coefficients`` (4-14 terms), ``image_width``, ``image_height`` (OpenCV's
    calibration sample). Raises FileFormatError naming the file and the key."""
    path = Path(path)
    if path.suffix.lower() in OPENCV_SUFFIXES:
        return _camera_from_opencv_text(read_text_file(path, "camera calibration file"), path)
    return _camera_from_json(read_json_file(path, "camera calibration file"))
