"""Calibration files: a JSON with every parameter and its convention, and an OpenCV-readable YAML export.

Both load back into :class:`CalibratedRig` with identical projections (the YAML stores every parameter as a
double at full precision).
"""
from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from measurement.calibration.stepwise import StereoCalibration
from measurement.camera import INTRINSIC_NAMES, ScheimpflugCamera

FORMAT = "scheimpflug-stereo-calibration/1"
CONVENTION = ("Camera frame as OpenCV (x right, y down, z forward), pixel centres at integer coordinates. "
              "Stereo: X_right = R_right_from_left @ X_left + T_right_from_left_mm (mm). Camera model 'rmm' is "
              "the paper's rotation-matrix Scheimpflug model: x_n = X/Z; Brown distortion (k1, k2, p1, p2) on the "
              "ideal plane; [x_t, y_t, 1] ~ A R_S^T [x_d, y_d, 1] with R_S = R_Y(beta) R_X(alpha); u = fx x_t + cx, "
              "v = fy y_t + cy. 'opencv-tilt' uses OpenCV's CALIB_TILTED_MODEL rotation order (tau_x = alpha, "
              "tau_y = beta). 'pinhole' has alpha = beta = 0.")


@dataclass(frozen=True)
class CalibratedRig:
    """A calibrated stereo pair as loaded from a file."""

    model: str
    left: ScheimpflugCamera
    right: ScheimpflugCamera
    R_right_from_left: np.ndarray
    T_right_from_left_mm: np.ndarray


def _camera_entry(cam_cal) -> dict:
    cam = cam_cal.camera
    return {"intrinsics": cam.intrinsics(), "sigma": {n: cam_cal.sigma[n] for n in INTRINSIC_NAMES},
            "tilt_model": cam.tilt_model, "width": cam.width, "height": cam.height,
            "reprojection_rms_px": cam_cal.rms_px, "per_view_rms_px": np.asarray(cam_cal.per_view_rms_px).tolist(),
            "steps": [{"step": s[0], "free": list(s[1]), "rms_px": s[2]} for s in cam_cal.steps]}


def calibration_to_dict(cal: StereoCalibration, extra: dict | None = None) -> dict:
    """Everything a user needs to reuse or audit a calibration, as plain JSON types."""
    d = {"format": FORMAT, "convention": CONVENTION, "model": cal.model,
         "image_size_px": [cal.left.camera.width, cal.left.camera.height],
         "left": _camera_entry(cal.left), "right": _camera_entry(cal.right),
         "stereo": {"R_right_from_left": np.asarray(cal.R_right_from_left).tolist(),
                    "rvec_right_from_left": cv2.Rodrigues(np.asarray(cal.R_right_from_left))[0].ravel().tolist(),
                    "T_right_from_left_mm": np.asarray(cal.T_right_from_left_mm).tolist(),
                    "sigma_rvec": cal.sigma_stereo["rvec"], "sigma_T_mm": cal.sigma_stereo["T_mm"]},
         "reprojection_rms_px": dict(cal.rms_px),
         "steps": [{"step": s[0], "free": list(s[1]), "rms_px": s[2]} for s in cal.steps]}
    if extra:
        d.update(extra)
    return d


def save_calibration(cal: StereoCalibration, path: str | Path, extra: dict | None = None) -> None:
    Path(path).write_text(json.dumps(calibration_to_dict(cal, extra), indent=1))


def _camera_from(entry: dict, where: str) -> ScheimpflugCamera:
    try:
        return ScheimpflugCamera(**entry["intrinsics"], width=entry["width"], height=entry["height"],
                                 tilt_model=entry.get("tilt_model", "rmm"))
    except (KeyError, TypeError) as err:
        raise ValueError(f"{where}: malformed camera entry ({err})") from None


def load_calibration(path: str | Path) -> CalibratedRig:
    """Read a calibration JSON written by :func:`save_calibration` (or an OpenCV YAML by :func:`export_opencv_yaml`)."""
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"calibration file {path} does not exist")
    if path.suffix.lower() in (".yml", ".yaml"):
        return load_opencv_yaml(path)
    try:
        d = json.loads(path.read_text())
    except json.JSONDecodeError as err:
        raise ValueError(f"{path} is not valid JSON: {err}") from None
    if d.get("format") != FORMAT:
        raise ValueError(f"{path}: unknown format {d.get('format')!r}, expected {FORMAT!r}")
    st = d["stereo"]
    return CalibratedRig(d["model"], _camera_from(d["left"], f"{path} left"), _camera_from(d["right"], f"{path} right"),
                         np.array(st["R_right_from_left"], float), np.array(st["T_right_from_left_mm"], float))


def export_opencv_yaml(rig: CalibratedRig | StereoCalibration, path: str | Path) -> None:
    """Write an OpenCV ``FileStorage`` YAML: K1, D1, K2, D2, R, T, image size, and every Table 1 parameter.

    ``D1``/``D2`` are OpenCV's 14 ``CALIB_TILTED_MODEL`` coefficients. They reproduce our projection exactly only
    for the ``opencv-tilt`` and ``pinhole`` models or a single-axis RMM tilt; ``D_exact`` says which. The named
    scalars (``left_fx`` ...) always hold the exact model.
    """
    if isinstance(rig, StereoCalibration):
        rig = CalibratedRig(rig.model, rig.left.camera, rig.right.camera, rig.R_right_from_left, rig.T_right_from_left_mm)
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    if not fs.isOpened():
        raise OSError(f"cannot write {path}")
    fs.write("format", FORMAT)
    fs.write("model", rig.model)
    fs.write("convention", CONVENTION)
    fs.write("image_width", int(rig.left.width))
    fs.write("image_height", int(rig.left.height))
    for side, cam in (("1", rig.left), ("2", rig.right)):
        fs.write(f"K{side}", cam.K)
        dist = np.zeros((1, 14))
        dist[0, :4] = cam.k1, cam.k2, cam.p1, cam.p2
        dist[0, 12:] = cam.alpha_rad, cam.beta_rad
        fs.write(f"D{side}", dist)
        exact = cam.tilt_model == "opencv" or cam.alpha_deg == 0.0 or cam.beta_deg == 0.0
        fs.write(f"D{side}_exact", int(exact))
    for name, cam in (("left", rig.left), ("right", rig.right)):
        fs.write(f"{name}_tilt_model", cam.tilt_model)
        for n in INTRINSIC_NAMES:
            fs.write(f"{name}_{n}", float(getattr(cam, n)))
    fs.write("R", np.asarray(rig.R_right_from_left, float))
    fs.write("T", np.asarray(rig.T_right_from_left_mm, float).reshape(3, 1))
    fs.release()


def load_opencv_yaml(path: str | Path) -> CalibratedRig:
    """Read back a YAML written by :func:`export_opencv_yaml`."""
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    if not fs.isOpened():
        raise ValueError(f"cannot read {path} as an OpenCV FileStorage file")
    try:
        w, h = int(fs.getNode("image_width").real()), int(fs.getNode("image_height").real())
        cams = {}
        for name in ("left", "right"):
            values = {n: fs.getNode(f"{name}_{n}").real() for n in INTRINSIC_NAMES}
            cams[name] = ScheimpflugCamera(**values, width=w, height=h,
                                           tilt_model=fs.getNode(f"{name}_tilt_model").string() or "rmm")
        R, T = fs.getNode("R").mat(), fs.getNode("T").mat()
        model = fs.getNode("model").string()
    finally:
        fs.release()
    if R is None or T is None:
        raise ValueError(f"{path}: missing R or T")
    return CalibratedRig(model, cams["left"], cams["right"], np.asarray(R, float), np.asarray(T, float).ravel())
