"""Candidate rigs: where the two cameras stand, how each sensor is tilted, and the specimen's face they look at.

Frames. The *specimen frame* has the face the cameras see near ``z = 0``, facing ``-z`` (as every catalog specimen
and the beam), its centre at the origin. A candidate is symmetric: both camera centres at ``working distance D``
from the origin, in the specimen's x-z plane, each ``stereo angle / 2`` off the face normal, both optical axes
through the origin (left camera at -x); image rows run along the specimen's +y. The rig's world is the left
camera's frame (the project's convention, :class:`workbench.rigs.StereoRig`).

Optics (the renderer's thin lens, :mod:`scenes.optics.projection`): a lens of focal length F and a sensor at image distance
``v`` (so ``fx = fy = v / pitch``, principal point at the image centre, no distortion). Untilted, ``v`` focuses the
face centre on the axis: ``1/v = 1/F - 1/D``. Tilted (Scheimpflug), :func:`hinge_rule` solves the sensor tilts
(alpha about x, beta about y) and ``v`` so that the plane of sharp focus is the face's (best) plane: the in-focus
points of a 7 x 7 grid of pixels lie on it in least squares -- the renderer's own focus rule, so the rendered
design is sharp where the designer says. The classical form, ``tan(psi) = (v/u) tan(phi)`` for a face at ``phi`` to
the lens plane, is its first-order check (tests). A tilt beyond the adapter's range is clamped and ``v`` refocused on
the centre: the plane of focus then turns less than the face.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares

from measurement.camera import ScheimpflugCamera
from scenes.optics.camera import SensorSpec
from scenes.optics.projection import in_focus_points_world_mm, sensor_points
from workbench.rigs import StereoRig

SIDES = ("left", "right")


@dataclass(frozen=True)
class Placement:
    """Camera poses in the specimen frame: ``X_cam = R_cam_from_spec X_spec + t_cam_from_spec_mm``."""

    R_cam_from_spec: dict
    t_cam_from_spec_mm: dict
    distance_mm: float
    stereo_angle_deg: float

    def centre_mm(self, side: str) -> np.ndarray:
        return -self.R_cam_from_spec[side].T @ self.t_cam_from_spec_mm[side]


def placement(distance_mm: float, stereo_angle_deg: float) -> Placement:
    """The symmetric rig's camera poses (module notes)."""
    if not (math.isfinite(distance_mm) and distance_mm > 0):
        raise ValueError(f"working distance must be a positive number of mm, got {distance_mm!r}")
    if not 0 < stereo_angle_deg < 180:
        raise ValueError(f"stereo angle must be in (0, 180) deg, got {stereo_angle_deg!r}")
    h = math.radians(stereo_angle_deg) / 2
    R, t = {}, {}
    for side, sign in (("left", -1.0), ("right", 1.0)):
        centre = distance_mm * np.array([sign * math.sin(h), 0.0, -math.cos(h)])
        z = -centre / distance_mm
        y = np.array([0.0, 1.0, 0.0])
        x = np.cross(y, z)
        R[side] = np.stack([x, y, z])
        t[side] = -R[side] @ centre
    return Placement(R, t, float(distance_mm), float(stereo_angle_deg))


def _pixels(width: int, height: int, n: int = 7) -> np.ndarray:
    u = np.linspace(0, width - 1, n)
    v = np.linspace(0, height - 1, n)
    return np.stack(np.meshgrid(u, v), -1).reshape(-1, 2)


def thin_spec(width: int, height: int, pitch_mm: float, image_distance_mm: float, focal_length_mm: float,
              f_number: float, alpha_deg: float = 0.0, beta_deg: float = 0.0) -> SensorSpec:
    """The renderer's description of a designed camera (principal point at the image centre, no distortion)."""
    f_px = image_distance_mm / pitch_mm
    return SensorSpec(fx=f_px, fy=f_px, cx=(width - 1) / 2, cy=(height - 1) / 2, width=int(width), height=int(height),
                      alpha_deg=float(alpha_deg), beta_deg=float(beta_deg), lens="thin",
                      focal_length_mm=float(focal_length_mm), f_number=float(f_number), pixel_pitch_mm=float(pitch_mm))


def focus_image_distance_mm(width: int, height: int, pitch_mm: float, focal_length_mm: float, alpha_deg: float,
                            beta_deg: float, R, t, point_mm) -> float:
    """Image distance v that focuses ``point_mm`` (specimen frame) with the given tilts.

    The pixel where the point is imaged depends on v only through the scale of the image, so two fixed-point
    passes of ``v p_z = 1 / (1/F - 1/Z)`` converge (p_z: the pixel's relative image distance on the tilted sensor).
    """
    X = np.asarray(point_mm, float).reshape(1, 3)
    Z = float((X @ np.asarray(R).T + np.asarray(t))[0, 2])
    if Z <= focal_length_mm:
        raise ValueError(f"the point is {Z:.1f} mm from the lens, inside its focal length {focal_length_mm:g} mm: "
                         "no sharp image")
    v = 1.0 / (1.0 / focal_length_mm - 1.0 / Z)
    from scenes.optics.projection import project_points
    for _ in range(4):
        spec = thin_spec(width, height, pitch_mm, v, focal_length_mm, 8.0, alpha_deg, beta_deg)
        p_z = float(sensor_points(spec, project_points(spec, R, t, X))[0, 2])
        v = 1.0 / ((1.0 / focal_length_mm - 1.0 / Z) * p_z)
    return float(v)


def hinge_rule(width: int, height: int, pitch_mm: float, focal_length_mm: float, R, t, centre_mm, normal,
               ) -> tuple[float, float, float, float]:
    """Sensor tilts and image distance that put the plane of sharp focus on a plane (module notes).

    Parameters
    ----------
    width, height : int, px
    pitch_mm : float
    focal_length_mm : float
        The lens' F (fixed: one focuses by moving the sensor).
    R, t : (3, 3), (3,)
        The camera's pose, ``X_cam = R X + t``, in the frame of ``centre_mm`` and ``normal``.
    centre_mm, normal : (3,)
        A point of the plane and its normal.

    Returns
    -------
    alpha_deg, beta_deg, image_distance_mm, rms_mm
        ``rms_mm``: RMS distance of the in-focus points of a 7 x 7 pixel grid from the plane.
    """
    c = np.asarray(centre_mm, float)
    n = np.asarray(normal, float) / np.linalg.norm(normal)
    pixels = _pixels(width, height)
    v0 = focus_image_distance_mm(width, height, pitch_mm, focal_length_mm, 0.0, 0.0, R, t, c)

    def residual(p):
        spec = thin_spec(width, height, pitch_mm, v0 * p[2], focal_length_mm, 8.0, p[0], p[1])
        return (in_focus_points_world_mm(spec, R, t, pixels) - c) @ n

    fit = least_squares(residual, np.array([0.0, 0.0, 1.0]), xtol=1e-14, ftol=1e-14, gtol=1e-14)
    return float(fit.x[0]), float(fit.x[1]), float(v0 * fit.x[2]), float(np.sqrt(np.mean(fit.fun ** 2)))


@dataclass(frozen=True)
class CandidateRig:
    """A designed rig: the true stereo rig (world = left camera), its thin lenses, and its specimen placement.

    Attributes
    ----------
    rig : StereoRig
        With ``lens_focal_length_mm`` and ``f_number`` set (the renderer's thin lenses).
    specs : dict of SensorSpec
        The renderer's cameras (thin lens).
    R_world_from_spec, t_world_from_spec_mm : (3, 3), (3,)
        The specimen frame in the rig's world.
    placement : Placement
    tilted : bool
        Whether the sensors were tilted (hinge rule) or not.
    tilt_clamped : bool
        A tilt reached the adapter's limit.
    focus_rms_mm : dict
        Per camera, the plane of focus' RMS distance from the face plane over the image (hinge rule only).
    camera_name, lens_name : str
    """

    rig: StereoRig
    specs: dict
    R_world_from_spec: np.ndarray
    t_world_from_spec_mm: np.ndarray
    placement: Placement
    tilted: bool
    tilt_clamped: bool = False
    focus_rms_mm: dict = field(default_factory=dict)
    camera_name: str = ""
    lens_name: str = ""

    @property
    def f_number(self) -> float:
        return self.rig.f_number

    def tilts_deg(self, side: str) -> tuple[float, float]:
        cam = self.rig.camera(side)
        return cam.alpha_deg, cam.beta_deg


def build_candidate(camera, lens, f_number: float, distance_mm: float, stereo_angle_deg: float, *, tilt: bool,
                    tilt_max_deg: float, plane_centre_mm=(0.0, 0.0, 0.0), plane_normal=(0.0, 0.0, -1.0),
                    name: str = "") -> CandidateRig:
    """One candidate rig (module notes): ``camera`` and ``lens`` as in :mod:`workbench.design.inputs`; ``tilt``: the
    hinge rule for the plane (``plane_centre_mm``, ``plane_normal``, specimen frame), else untilted sensors focused
    on ``plane_centre_mm`` (the face's best plane's centre: the face centre for a flat face)."""
    P = placement(distance_mm, stereo_angle_deg)
    pitch = camera.pixel_pitch_mm
    F = lens.focal_length_mm
    w, h = camera.width_px, camera.height_px
    cams, specs, rms = {}, {}, {}
    clamped = False
    for side in SIDES:
        R, t = P.R_cam_from_spec[side], P.t_cam_from_spec_mm[side]
        if tilt and tilt_max_deg > 0:
            alpha, beta, v, r = hinge_rule(w, h, pitch, F, R, t, plane_centre_mm, plane_normal)
            if abs(alpha) > tilt_max_deg or abs(beta) > tilt_max_deg:
                clamped = True
                alpha = float(np.clip(alpha, -tilt_max_deg, tilt_max_deg))
                beta = float(np.clip(beta, -tilt_max_deg, tilt_max_deg))
                v = focus_image_distance_mm(w, h, pitch, F, alpha, beta, R, t, plane_centre_mm)
            rms[side] = r
        else:
            alpha = beta = 0.0
            v = focus_image_distance_mm(w, h, pitch, F, 0.0, 0.0, R, t, plane_centre_mm)
        specs[side] = thin_spec(w, h, pitch, v, F, f_number, alpha, beta)
        s = specs[side]
        cams[side] = ScheimpflugCamera(fx=s.fx, fy=s.fy, cx=s.cx, cy=s.cy, alpha_deg=alpha, beta_deg=beta,
                                       width=w, height=h)
    RL, tL = P.R_cam_from_spec["left"], P.t_cam_from_spec_mm["left"]
    RR, tR = P.R_cam_from_spec["right"], P.t_cam_from_spec_mm["right"]
    R_rl = RR @ RL.T
    T_rl = tR - R_rl @ tL
    label = name or f"{'tilted' if tilt else 'untilted'} D{distance_mm:.0f} {stereo_angle_deg:.0f}deg f/{f_number:g}"
    rig = StereoRig(label, cams["left"], cams["right"], R_rl, T_rl, pixel_pitch_mm=pitch,
                    working_distance_mm=float(distance_mm), lens_focal_length_mm=(F, F), f_number=float(f_number))
    return CandidateRig(rig, specs, RL, tL, P, bool(tilt and tilt_max_deg > 0), clamped, rms,
                        getattr(camera, "name", ""), getattr(lens, "name", ""))


def classical_scheimpflug_tilt_deg(object_angle_deg: float, image_distance_mm: float, object_distance_mm: float
                                   ) -> float:
    """The textbook Scheimpflug rule: a face at ``phi`` to the lens plane is sharp on a sensor at ``psi`` with
    ``tan(psi) = (v / u) tan(phi)`` (u, v: object and image distances on the axis). Magnitude only."""
    return math.degrees(math.atan(image_distance_mm / object_distance_mm * math.tan(math.radians(object_angle_deg))))
