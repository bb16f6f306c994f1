"""Random, realistic calibration poses of a planar target inside both cameras' views."""
from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from measurement.camera import ScheimpflugCamera
from measurement.stereo import closest_approach
from workbench.rigs import StereoRig


class BoardOutOfViewError(ValueError):
    """A target pose puts part of the target outside an image."""


def common_view_centre_mm(rig: StereoRig) -> np.ndarray:
    """A point both image centres look at: midpoint of the two centre rays' closest approach (left frame, mm)."""
    centres, dirs = [], []
    for side in ("left", "right"):
        cam = rig.camera(side)
        R, _ = rig.pose(side)
        centres.append(rig.camera_centre_mm(side))
        dirs.append(R.T @ cam.rays(np.array([[(cam.width - 1) / 2, (cam.height - 1) / 2]]))[0])
    return closest_approach(centres[0], dirs[0][None], centres[1], dirs[1][None])[0][0]


def check_in_view(points_world_mm: np.ndarray, rig: StereoRig, margin_px: float = 2.0, what: str = "board") -> None:
    """Raise :class:`BoardOutOfViewError` naming the camera if any point projects outside its image."""
    for side in ("left", "right"):
        cam: ScheimpflugCamera = rig.camera(side)
        R, t = rig.pose(side)
        X = points_world_mm @ R.T + t
        if np.any(X[:, 2] <= 0):
            raise BoardOutOfViewError(f"{what} is (partly) behind the {side} camera")
        uv = cam.project(X)
        bad = ~np.all(np.isfinite(uv), axis=1) | (uv[:, 0] < margin_px - 0.5) | (uv[:, 1] < margin_px - 0.5) \
            | (uv[:, 0] > cam.width - 0.5 - margin_px) | (uv[:, 1] > cam.height - 0.5 - margin_px)
        if np.any(bad):
            worst = uv[bad][0]
            raise BoardOutOfViewError(
                f"{what} leaves the {side} image ({cam.width} x {cam.height} px): {int(bad.sum())} of "
                f"{len(uv)} points outside, e.g. at ({worst[0]:.1f}, {worst[1]:.1f}) px")


def random_board_poses(rig: StereoRig, outline_board_mm: np.ndarray, n_views: int, seed: int, *,
                       max_tilt_deg: float = 40.0, max_spin_deg: float = 20.0, depth_range_mm: float = 40.0,
                       lateral_range_mm: float = 12.0, margin_px: float = 2.0, max_tries: int = 20000
                       ) -> list[tuple[np.ndarray, np.ndarray]]:
    """Draw ``n_views`` poses ``X_world = R X_board + t`` of a planar target seen whole by both cameras.

    The target's centre is placed around the point both image centres look at (depth +- depth_range_mm/2,
    lateral +- lateral_range_mm), its normal faces the cameras' bisector and is tilted by up to
    ``max_tilt_deg`` about two axes plus a spin about the normal. Poses whose ``outline_board_mm`` (N, 3)
    leaves either image (with ``margin_px``) are redrawn.
    """
    if n_views < 1:
        raise ValueError(f"n_views must be >= 1, got {n_views}")
    rng = np.random.default_rng(seed)
    centre = common_view_centre_mm(rig)
    c_left, c_right = rig.camera_centre_mm("left"), rig.camera_centre_mm("right")
    to_cams = 0.5 * (c_left + c_right) - centre
    z_board = -to_cams / np.linalg.norm(to_cams)  # board z points away from the cameras
    x_board = np.cross([0.0, 1.0, 0.0], z_board)
    x_board /= np.linalg.norm(x_board)
    y_board = np.cross(z_board, x_board)
    R_facing = np.stack([x_board, y_board, z_board], axis=1)
    outline_centre = outline_board_mm.mean(axis=0)
    poses = []
    for _ in range(max_tries):
        tilt = rng.uniform(-max_tilt_deg, max_tilt_deg, size=2)
        spin = rng.uniform(-max_spin_deg, max_spin_deg)
        R = R_facing @ Rotation.from_euler("xyz", [tilt[0], tilt[1], spin], degrees=True).as_matrix()
        offset = np.array([*rng.uniform(-lateral_range_mm, lateral_range_mm, 2),
                           rng.uniform(-depth_range_mm / 2, depth_range_mm / 2)])
        t = centre + offset - R @ outline_centre
        try:
            check_in_view(outline_board_mm @ R.T + t, rig, margin_px)
        except BoardOutOfViewError:
            continue
        poses.append((R, t))
        if len(poses) == n_views:
            return poses
    raise BoardOutOfViewError(
        f"found only {len(poses)} of {n_views} board poses inside both images after {max_tries} tries: "
        "the target is too large for this rig's common field of view")
