"""Stereo rigs used as ground truth: the paper's Table 1 rig and its scaled versions.

Conventions: the left camera frame is the world frame; ``X_right = R_right_from_left @ X_left + T_right_from_left_mm``
(OpenCV's stereoCalibrate convention, checked against the paper's geometry in ``data/paper-values.json``).
"""
from __future__ import annotations

import json
from dataclasses import dataclass
from importlib import resources

import cv2
import numpy as np

from measurement.camera import ScheimpflugCamera
from measurement.stereo import closest_approach

#: Assumed pixel pitch: the paper gives none; 3.45 um is typical of 2456 x 2058 CCDs (DESIGN.md §4).
DEFAULT_PIXEL_PITCH_MM = 0.00345
#: Working distance of the paper's rig (where the two optical axes pass closest), mm.
PAPER_WORKING_DISTANCE_MM = 376.0

RIG_NAMES = ("paper",)


def paper_values() -> dict:
    """The paper's reported figures (Table 1, protocols), shipped with the package."""
    return json.loads(resources.files("workbench").joinpath("data/paper-values.json").read_text())


@dataclass(frozen=True)
class StereoRig:
    """Two cameras and their relative pose.

    Attributes
    ----------
    left, right : ScheimpflugCamera
    R_right_from_left : (3, 3)
    T_right_from_left_mm : (3,)
    pixel_pitch_mm : physical pixel size at ``scale = 1`` divided by ``scale`` (thin-lens renders need it)
    working_distance_mm : distance from the left camera to the point the optical axes meet
    """

    name: str
    left: ScheimpflugCamera
    right: ScheimpflugCamera
    R_right_from_left: np.ndarray
    T_right_from_left_mm: np.ndarray
    pixel_pitch_mm: float = DEFAULT_PIXEL_PITCH_MM
    working_distance_mm: float = PAPER_WORKING_DISTANCE_MM

    def camera(self, which: str) -> ScheimpflugCamera:
        if which not in ("left", "right"):
            raise ValueError(f"camera must be 'left' or 'right', got {which!r}")
        return self.left if which == "left" else self.right

    def pose(self, which: str) -> tuple[np.ndarray, np.ndarray]:
        """``(R_cam_from_world, t_cam_from_world_mm)`` of a camera; the world is the left camera frame."""
        if which == "left":
            return np.eye(3), np.zeros(3)
        if which == "right":
            return np.array(self.R_right_from_left, float), np.array(self.T_right_from_left_mm, float)
        raise ValueError(f"camera must be 'left' or 'right', got {which!r}")

    def camera_centre_mm(self, which: str) -> np.ndarray:
        R, t = self.pose(which)
        return -R.T @ t

    def optical_axes_meeting_point_mm(self) -> np.ndarray:
        """Midpoint of the shortest segment between the two optical axes (left frame, mm)."""
        axis = np.array([[0.0, 0.0, 1.0]])
        return closest_approach(self.camera_centre_mm("left"), axis, self.camera_centre_mm("right"),
                                axis @ self.pose("right")[0])[0][0]


def paper_rig(scale: float = 1.0, pixel_pitch_mm: float = DEFAULT_PIXEL_PITCH_MM) -> StereoRig:
    """Table 1 of the paper as the true rig; ``scale`` < 1 shrinks image size and K together (fast tests)."""
    if not 0 < scale <= 4:
        raise ValueError(f"scale must be in (0, 4], got {scale}")
    v = paper_values()
    w, h = v["cameras"]["image_size_px"]
    cams = {}
    for side in ("left", "right"):
        t = v["table1_calibration"][side]
        cam = ScheimpflugCamera(fx=t["fx_px"], fy=t["fy_px"], cx=t["cx_px"], cy=t["cy_px"],
                                alpha_deg=t["alpha_deg"], beta_deg=t["beta_deg"], k1=t["k1"], k2=t["k2"],
                                p1=t["p1"], p2=t["p2"], width=w, height=h)
        cams[side] = cam.scaled(scale) if scale != 1.0 else cam
    R = cv2.Rodrigues(np.array(v["table1_calibration"]["stereo_R_rodrigues"], dtype=float))[0]
    T = np.array(v["table1_calibration"]["stereo_T_mm"], dtype=float)
    return StereoRig("paper", cams["left"], cams["right"], R, T, pixel_pitch_mm=pixel_pitch_mm / scale)


def get_rig(name: str, scale: float = 1.0) -> StereoRig:
    """A rig by name; unknown names raise ``ValueError`` listing the known ones."""
    if name == "paper":
        return paper_rig(scale)
    raise ValueError(f"unknown rig {name!r}; known rigs: {', '.join(RIG_NAMES)}")
