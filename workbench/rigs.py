"""Stereo rigs used as ground truth: the paper's Table 1 rig and its scaled versions.

Conventions: the left camera frame is the world frame; ``X_right = R_right_from_left @ X_left + T_right_from_left_mm``
(OpenCV's stereoCalibrate convention, checked against the paper's geometry in ``data/paper-values.json``).
"""
from __future__ import annotations

import json
import warnings
from dataclasses import dataclass, replace
from functools import lru_cache
from importlib import resources

import cv2
import numpy as np

from measurement.camera import ScheimpflugCamera
from measurement.stereo import closest_approach

#: Assumed pixel pitch: the paper gives none; 3.45 um is typical of 2456 x 2058 CCDs (DESIGN.md §4).
DEFAULT_PIXEL_PITCH_MM = 0.00345
#: Working distance of the paper's rig (where the two optical axes pass closest), mm.
PAPER_WORKING_DISTANCE_MM = 376.0

RIG_NAMES = ("paper", "scheimpflug")
#: Default f-number of the thin lens of the ``scheimpflug`` rig (a modest DIC aperture).
DEFAULT_F_NUMBER = 8.0
#: Below this many pixels on the shorter side a scaled rig's images warn: a checkerboard square or a DIC
#: subset no longer fits (0.01 of the paper's 2456 x 2058 px is 25 x 21 px).
MIN_IMAGE_SIDE_PX = 100


def _warn_if_tiny(name: str, scale: float, camera: ScheimpflugCamera, full: ScheimpflugCamera) -> None:
    """Warn when ``camera`` (``full`` scaled by ``scale``) has fewer than MIN_IMAGE_SIDE_PX pixels on a side."""
    if min(camera.width, camera.height) < MIN_IMAGE_SIDE_PX:
        lowest = MIN_IMAGE_SIDE_PX / min(full.width, full.height)
        warnings.warn(f"the {name!r} rig at scale {scale:g} renders {camera.width} x {camera.height} px images, "
                      f"below {MIN_IMAGE_SIDE_PX} px on a side: too small for checkerboard detection or DIC "
                      f"subsets (a scale of {lowest:.3f} or more keeps {MIN_IMAGE_SIDE_PX} px)",
                      UserWarning, stacklevel=3)


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
    lens_focal_length_mm : ``(left, right)`` focal length F of each camera's thin lens, or None (the rig
        defines no lens: experiments choose one)
    f_number : f-number of those lenses (0 when the rig defines none)
    """

    name: str
    left: ScheimpflugCamera
    right: ScheimpflugCamera
    R_right_from_left: np.ndarray
    T_right_from_left_mm: np.ndarray
    pixel_pitch_mm: float = DEFAULT_PIXEL_PITCH_MM
    working_distance_mm: float = PAPER_WORKING_DISTANCE_MM
    lens_focal_length_mm: tuple[float, float] | None = None
    f_number: float = 0.0

    def thin_lens(self, which: str) -> dict:
        """``{"lens": "thin", "focal_length_mm": F, "f_number": N}`` of a rig that defines its lenses."""
        if self.lens_focal_length_mm is None:
            raise ValueError(f"the {self.name!r} rig defines no thin lens")
        F = self.lens_focal_length_mm[0 if which == "left" else 1]
        self.camera(which)          # validates the name
        return {"lens": "thin", "focal_length_mm": float(F), "f_number": float(self.f_number)}

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
    _warn_if_tiny("paper", scale, cams["left"], cam)
    return StereoRig("paper", cams["left"], cams["right"], R, T, pixel_pitch_mm=pixel_pitch_mm / scale)


def facing_plane_world(rig: StereoRig) -> tuple[np.ndarray, np.ndarray]:
    """The specimen plane the rig is built for: ``(centre_mm (3,), normal (3,))`` in the world frame.

    The plane passes through the point where the optical axes meet; its unit normal points from there
    to the midpoint of the two camera centres (the specimen faces the cameras' bisector).
    """
    centre = rig.optical_axes_meeting_point_mm()
    to_cameras = 0.5 * (rig.camera_centre_mm("left") + rig.camera_centre_mm("right")) - centre
    return centre, to_cameras / np.linalg.norm(to_cameras)


def scheimpflug_tilt_for_plane(camera: ScheimpflugCamera, R_cam_from_world, t_cam_from_world_mm, centre_world_mm,
                               normal_world, pixel_pitch_mm: float = DEFAULT_PIXEL_PITCH_MM,
                               f_number: float = DEFAULT_F_NUMBER) -> tuple[float, float, float, float]:
    """Sensor tilt and lens focal length that put a thin lens' plane of sharp focus on a given plane.

    The thin-lens rule of the renderer (:func:`scenes.optics.projection.in_focus_points_world_mm`: a sensor point at
    image distance ``v p_z`` is conjugate to depth ``1 / (1/F - 1/(v p_z))`` on its chief ray) is solved in
    least squares for ``(alpha, beta, F)``: the in-focus points of a 7 x 7 grid of pixels over the image must
    lie on the plane. Without distortion the in-focus points of a tilted sensor form one plane (Scheimpflug)
    and three unknowns fit its three degrees of freedom exactly; Brown distortion bends the surface slightly.

    Returns
    -------
    alpha_deg, beta_deg, focal_length_mm, rms_mm
        ``rms_mm``: RMS distance of the in-focus points from the plane (the residual focus error).
    """
    from scipy.optimize import least_squares

    from scenes.optics.camera import SensorSpec
    from scenes.optics.projection import in_focus_points_world_mm

    c = np.asarray(centre_world_mm, float)
    n = np.asarray(normal_world, float) / np.linalg.norm(normal_world)
    u = np.linspace(0, camera.width - 1, 7)
    v = np.linspace(0, camera.height - 1, 7)
    pixels = np.stack(np.meshgrid(u, v), -1).reshape(-1, 2)
    base = replace(camera, alpha_deg=0.0, beta_deg=0.0)
    image_distance = camera.fx * pixel_pitch_mm
    depth = float((np.asarray(R_cam_from_world) @ c + np.asarray(t_cam_from_world_mm))[2])

    def spec(p):
        return SensorSpec(**replace(base, alpha_deg=p[0], beta_deg=p[1]).intrinsics(), width=camera.width,
                          height=camera.height, lens="thin", focal_length_mm=p[2], f_number=f_number,
                          pixel_pitch_mm=pixel_pitch_mm)

    def residual(p):
        return (in_focus_points_world_mm(spec(p), R_cam_from_world, t_cam_from_world_mm, pixels) - c) @ n

    start = np.array([0.0, 0.0, 1.0 / (1.0 / image_distance + 1.0 / depth)])
    fit = least_squares(residual, start, x_scale=[1.0, 1.0, 1.0], xtol=1e-14, ftol=1e-14, gtol=1e-14)
    return float(fit.x[0]), float(fit.x[1]), float(fit.x[2]), float(np.sqrt(np.mean(fit.fun ** 2)))


@lru_cache(maxsize=8)
def _scheimpflug_design(f_number: float, pixel_pitch_mm: float) -> tuple:
    paper = paper_rig(1.0, pixel_pitch_mm)
    centre, normal = facing_plane_world(paper)
    return tuple(scheimpflug_tilt_for_plane(paper.camera(side), *paper.pose(side), centre, normal,
                                            pixel_pitch_mm, f_number) for side in ("left", "right"))


def scheimpflug_rig(scale: float = 1.0, f_number: float = DEFAULT_F_NUMBER,
                    pixel_pitch_mm: float = DEFAULT_PIXEL_PITCH_MM) -> StereoRig:
    """The paper's stereo geometry with sensor tilts chosen from the Scheimpflug condition.

    Table 1's focal lengths, principal points, distortion and stereo pose (R, T), but each sensor's tilt
    (alpha, beta) and thin-lens focal length F are solved so that the plane of sharp focus is the specimen
    face of :func:`facing_plane_world` (through the point where the optical axes meet, facing the cameras'
    bisector). Table 1's own tilts (beta ~ -/+4.5 deg) focus a plane ~50 deg away from that face; the
    Scheimpflug condition for it asks for tilts of about a degree (``tan(beta) ~ (v/u) tan(theta)`` with the
    image/object distance ratio v/u ~ 0.1 and the face ~11.5 deg off each optical axis).

    Lens: image distance ``v = fx * pitch`` (37.6 mm for the left camera at 3.45 um), F ~ 34 mm from the
    thin-lens equation at the ~376 mm working distance, ``f_number`` f/8 by default.
    """
    if not 0 < scale <= 4:
        raise ValueError(f"scale must be in (0, 4], got {scale}")
    if not (np.isfinite(f_number) and f_number > 0):
        raise ValueError(f"f_number must be positive, got {f_number}")
    paper = paper_rig(1.0, pixel_pitch_mm)
    design = _scheimpflug_design(float(f_number), float(pixel_pitch_mm))
    cams = {}
    for side, (alpha, beta, _, _) in zip(("left", "right"), design):
        cam = replace(paper.camera(side), alpha_deg=alpha, beta_deg=beta)
        cams[side] = cam.scaled(scale) if scale != 1.0 else cam
    _warn_if_tiny("scheimpflug", scale, cams["left"], paper.camera("left"))
    return StereoRig("scheimpflug", cams["left"], cams["right"], paper.R_right_from_left, paper.T_right_from_left_mm,
                     pixel_pitch_mm=pixel_pitch_mm / scale, lens_focal_length_mm=(design[0][2], design[1][2]),
                     f_number=float(f_number))


def scheimpflug_design_report(f_number: float = DEFAULT_F_NUMBER,
                              pixel_pitch_mm: float = DEFAULT_PIXEL_PITCH_MM) -> dict:
    """The ``scheimpflug`` rig's optics beside Table 1's tilts, for reports (full-resolution figures).

    Includes the principal-point offset read as a tilt, ``delta_beta ~ (cx - (w-1)/2) / fx`` (and alpha
    from cy): on planar targets a tilt and a principal-point shift are nearly interchangeable, so part of
    a calibrated tilt can be principal-point offset traded for tilt.
    """
    paper = paper_rig(1.0, pixel_pitch_mm)
    design = _scheimpflug_design(float(f_number), float(pixel_pitch_mm))
    out = {"f_number": f_number, "pixel_pitch_mm": pixel_pitch_mm}
    for side, (alpha, beta, F, rms) in zip(("left", "right"), design):
        cam = paper.camera(side)
        v = cam.fx * pixel_pitch_mm
        out[side] = {"alpha_deg": alpha, "beta_deg": beta, "focal_length_mm": F, "image_distance_mm": v,
                     "focus_distance_on_axis_mm": 1.0 / (1.0 / F - 1.0 / v), "focus_surface_rms_mm": rms,
                     "table1_alpha_deg": cam.alpha_deg, "table1_beta_deg": cam.beta_deg,
                     "principal_point_offset_px": [cam.cx - (cam.width - 1) / 2, cam.cy - (cam.height - 1) / 2],
                     # a shift of the principal point by d px turns the image like a tilt of d / f rad
                     "offset_as_tilt_deg": {"beta": float(np.degrees(np.arctan((cam.cx - (cam.width - 1) / 2) / cam.fx))),
                                            "alpha": float(np.degrees(np.arctan((cam.cy - (cam.height - 1) / 2) / cam.fy)))}}
    return out


def rig_from_calibration(path, scale: float = 1.0) -> StereoRig:
    """A user's own rig from their calibration file (any format the instrument reads: this project's JSON, OpenCV
    YAML/XML, DICe, VIC-3D, MATLAB; MatchID needs the image size and is refused here) as the true rig of a render;
    ``scale`` < 1 shrinks image size and K together. The working distance is where the optical axes meet. A
    calibration does not say how large the pixels are: they are taken as the paper camera's (3.45 um at scale 1),
    which only the lens' diffraction and defocus in pixels depend on -- unless the file is this project's JSON with
    an ``optics`` block (a rig from ``workbench design``, :func:`optics_block`): then its pixel pitch, its thin
    lenses' focal lengths and f-number are the rig's (the instrument ignores the block)."""
    from pathlib import Path

    from measurement.calibration.formats import load_any_calibration

    if not 0 < scale <= 4:
        raise ValueError(f"scale must be in (0, 4], got {scale}")
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"rig calibration {path}: no such file")
    cal = load_any_calibration(path)
    cams = {side: (c.scaled(scale) if scale != 1.0 else c) for side, c in (("left", cal.left), ("right", cal.right))}
    optics = _optics_of_file(path)
    rig = StereoRig(f"calibration:{path.name}", cams["left"], cams["right"], np.asarray(cal.R_right_from_left, float),
                    np.asarray(cal.T_right_from_left_mm, float),
                    pixel_pitch_mm=optics.get("pixel_pitch_mm", DEFAULT_PIXEL_PITCH_MM) / scale,
                    lens_focal_length_mm=optics.get("lens_focal_length_mm"), f_number=optics.get("f_number", 0.0))
    meeting = rig.optical_axes_meeting_point_mm()
    if not (np.all(np.isfinite(meeting)) and meeting[2] > 0):
        raise ValueError(f"rig calibration {path}: the optical axes do not meet in front of the cameras")
    return replace(rig, working_distance_mm=float(np.linalg.norm(meeting)))


def optics_block(pixel_pitch_mm: float, focal_length_mm: tuple[float, float], f_number: float) -> dict:
    """The ``optics`` entry a designed rig's calibration JSON carries (read back by :func:`rig_from_calibration`)."""
    return {"optics": {"about": "the true rig's optics (workbench design): pixel pitch at full resolution, each "
                                "camera's thin-lens focal length and the f-number; the instrument does not read it",
                       "pixel_pitch_mm": float(pixel_pitch_mm),
                       "lens_focal_length_mm": [float(focal_length_mm[0]), float(focal_length_mm[1])],
                       "f_number": float(f_number)}}


def _optics_of_file(path) -> dict:
    """The ``optics`` block of a calibration JSON (empty for other files or without one); checked."""
    if path.suffix.lower() != ".json":
        return {}
    try:
        block = json.loads(path.read_text(encoding="utf-8")).get("optics")
    except (OSError, ValueError, AttributeError):
        return {}
    if block is None:
        return {}
    try:
        pitch = float(block["pixel_pitch_mm"])
        F = tuple(float(v) for v in block["lens_focal_length_mm"])
        N = float(block["f_number"])
    except (KeyError, TypeError, ValueError) as err:
        raise ValueError(f"rig calibration {path}: optics: needs pixel_pitch_mm, lens_focal_length_mm [left, right] "
                         f"and f_number ({err})") from None
    if not (np.isfinite(pitch) and pitch > 0 and len(F) == 2 and all(np.isfinite(F)) and min(F) > 0
            and np.isfinite(N) and N > 0):
        raise ValueError(f"rig calibration {path}: optics: pixel_pitch_mm, lens_focal_length_mm and f_number must be "
                         f"positive numbers, got {block!r}")
    return {"pixel_pitch_mm": pitch, "lens_focal_length_mm": F, "f_number": N}


def get_rig(name: str, scale: float = 1.0) -> StereoRig:
    """A rig by name; unknown names raise ``ValueError`` listing the known ones."""
    if name == "paper":
        return paper_rig(scale)
    if name == "scheimpflug":
        return scheimpflug_rig(scale)
    raise ValueError(f"unknown rig {name!r}; known rigs: {', '.join(RIG_NAMES)}")
