"""Camera drift between the states of an experiment (truth side): the camera is not where it was calibrated.

A camera that warms up after switching on (self-heating of the sensor and electronics), or a rig that
settles, moves the image of a static specimen by a fraction of a pixel over tens of minutes. Ma, Pang & Ma
(2012), "The systematic error in digital image correlation induced by self-heating of a digital camera",
Meas. Sci. Technol. 23 025403, measured image drifts of ~0.1-0.5 px during warm-up and apparent strains of
tens to hundreds of µε; the drift is roughly monotonic (an exponential approach to thermal equilibrium).
Here it is **linear in the state index**: state ``k`` is rendered from a camera moved by ``k`` times a
per-state drift, which is the first-order (early warm-up) part of that monotonic curve; state 0 is the
calibrated pose.

Conventions (DESIGN §2): ``X_cam = R X_world + t``, OpenCV axes (x right, y down, z forward). The drift is
expressed in the *state-0 camera frame*: the camera centre moves by ``d`` (those axes, i.e.
``C_k = C_0 + R^T d``) and the camera turns about its own centre by the rotation vector ``w`` (right-handed,
those axes). A camera point then becomes ``X' = R_w^T (X - d) ~ X - d - w x X``: a static world point
*appears* to move by ``-d - w x X`` (:func:`apparent_displacement_mm`).

Scale of the parameters for the paper's rig (fx ~ 10 900 px, working distance ~ 376 mm): an image drift of
0.1-0.5 px is a rotation of ~9-46 µrad about x or y, or a translation of ~3-17 µm across the optical axis,
over the whole experiment; divide by the number of states for the per-state values.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from scenes import _checks

#: The cameras of a stereo rig a drift can apply to.
CAMERAS = ("left", "right")


@dataclass(frozen=True)
class CameraDrift:
    """Linear drift of one camera's pose with the state index; zero by default.

    Parameters
    ----------
    camera : {"left", "right"}
        The camera that drifts (the other keeps its calibrated pose).
    translation_um_per_state : (3,) float
        Motion of the camera centre per state index, µm, in the state-0 frame of that camera. Realistic:
        ~3-17 µm across the optical axis over a whole warm-up (see the module docstring), per state that
        divided by the number of states.
    rotation_urad_per_state : (3,) float
        Rotation vector of the camera about its own centre per state index, µrad, in the state-0 frame of
        that camera (right-handed). Realistic: ~9-46 µrad about x or y over a whole warm-up.
    """

    camera: str = "left"
    translation_um_per_state: tuple[float, float, float] = (0.0, 0.0, 0.0)
    rotation_urad_per_state: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def __post_init__(self):
        _check_camera(self.camera, "camera")
        for name in ("translation_um_per_state", "rotation_urad_per_state"):
            object.__setattr__(self, name, _finite_vector(name, getattr(self, name)))

    @property
    def is_zero(self) -> bool:
        """True when the camera does not drift."""
        return not (any(self.translation_um_per_state) or any(self.rotation_urad_per_state))

    def translation_mm(self, state_index: int) -> np.ndarray:
        """Camera-centre motion ``d`` (3,) at state ``k``, mm, state-0 camera frame: ``k * translation``."""
        k = _checks.state_index(state_index)
        return k * 1e-3 * np.asarray(self.translation_um_per_state)

    def rotation_vector_rad(self, state_index: int) -> np.ndarray:
        """Rotation vector ``w`` (3,) of the camera at state ``k``, rad, state-0 camera frame."""
        k = _checks.state_index(state_index)
        return k * 1e-6 * np.asarray(self.rotation_urad_per_state)


def rotation_matrix(rotation_vector_rad) -> np.ndarray:
    """Rotation matrix (3, 3) of a rotation vector (3,) in rad (Rodrigues' formula; exact, any angle)."""
    w = np.asarray(rotation_vector_rad, dtype=float).reshape(3)
    theta = float(np.linalg.norm(w))
    if theta == 0:
        return np.eye(3)
    k = w / theta
    K = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + np.sin(theta) * K + (1.0 - np.cos(theta)) * (K @ K)


def drifted_pose(R_cam_from_world, t_cam_from_world_mm, drift: CameraDrift | None, state_index: int,
                 camera: str | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The pose a camera really has when it takes the image of state ``k``.

    Parameters
    ----------
    R_cam_from_world : (3, 3), t_cam_from_world_mm : (3,)
        Calibrated (state-0) pose, ``X_cam = R X_world + t``, mm.
    drift : CameraDrift or None
        None, a zero drift, or state 0 return the calibrated pose unchanged.
    state_index : int
        State index ``k >= 0``.
    camera : {"left", "right"} or None
        Which camera this pose belongs to; when given and not ``drift.camera`` the pose is returned
        unchanged (so one drift can be passed for both cameras of a rig). None applies the drift.

    Returns
    -------
    R (3, 3), t (3,) mm: ``R' = R_w^T R`` and ``t' = R_w^T (t - d)`` with ``R_w`` the rotation of
    ``w = k * rotation`` and ``d = k * translation`` (state-0 camera frame). The camera centre moves to
    ``C_0 + R^T d``.
    """
    R = np.array(R_cam_from_world, dtype=float)
    t = np.array(t_cam_from_world_mm, dtype=float).reshape(-1)
    if R.shape != (3, 3) or not np.all(np.isfinite(R)):
        raise ValueError(f"R_cam_from_world must be a finite (3, 3) matrix, got shape {R.shape}")
    if t.shape != (3,) or not np.all(np.isfinite(t)):
        raise ValueError(f"t_cam_from_world_mm must be a finite 3-vector, got shape {t.shape}")
    k = _checks.state_index(state_index)
    if camera is not None:
        _check_camera(camera, "camera")
    if drift is None or drift.is_zero or k == 0 or (camera is not None and camera != drift.camera):
        return R, t
    R_w = rotation_matrix(drift.rotation_vector_rad(k))
    # New camera coordinates: shift the origin to the moved centre, then turn the axes with the camera.
    return R_w.T @ R, R_w.T @ (t - drift.translation_mm(k))


def apparent_displacement_mm(X_cam_mm, drift: CameraDrift, state_index: int) -> np.ndarray:
    """First-order apparent motion of static points caused by the drift, in the state-0 camera frame.

    Parameters
    ----------
    X_cam_mm : (N, 3) or (3,) float
        Points in the state-0 camera frame, mm.
    drift : CameraDrift
    state_index : int
        State index ``k >= 0``.

    Returns
    -------
    (N, 3) (or (3,)) float, mm: ``-d - w x X`` with ``d``, ``w`` of state ``k``. The exact change of the
    camera coordinates, ``R_w^T (X - d) - X``, differs from it by second-order terms,
    ``|error| <= |w|^2 |X| / 2 + |w| |d|`` up to higher orders.
    """
    X = np.asarray(X_cam_mm, dtype=float)
    if X.shape[-1:] != (3,) or X.ndim > 2 or not np.all(np.isfinite(X)):
        raise ValueError(f"X_cam_mm must be finite points of shape (N, 3) or (3,), got shape {X.shape}")
    d = drift.translation_mm(state_index)
    w = drift.rotation_vector_rad(state_index)
    return -d - np.cross(w, X)


# ------------------------------------------------------------------------------------------------------------
def _check_camera(camera, name: str) -> None:
    if not isinstance(camera, str) or camera not in CAMERAS:
        raise ValueError(f"{name} must be 'left' or 'right', got {camera!r}")


def _finite_vector(name: str, value) -> tuple[float, float, float]:
    try:
        v = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a finite 3-vector, got {value!r}") from None
    if v.shape != (3,) or not np.all(np.isfinite(v)):
        raise ValueError(f"{name} must be a finite 3-vector, got {value!r}")
    return tuple(float(x) for x in v)                # a tuple keeps the frozen dataclass hashable and JSON-able
