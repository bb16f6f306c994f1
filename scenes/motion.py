"""Rigid stage motions of a specimen (truth side): the paper's vertical translation test.

The paper (§4.2) moves the specimen with a vertical linear stage 0 -> 10 -> 0 mm in 1 mm steps. Here the
stage moves the specimen *up in the left image*, i.e. along **-y of the left camera frame** (OpenCV axes:
y points down in the image). The left camera frame is the world frame, so the default direction is
``STAGE_UP_WORLD = (0, -1, 0)``. A pose is ``X_world = R_world_from_specimen X_specimen + t``; a stage
position ``s`` mm moves it to ``(R, t + s * direction)``.
"""
from __future__ import annotations

import numpy as np

#: "Up" in the left image: -y of the left camera (= world) frame.
STAGE_UP_WORLD = np.array([0.0, -1.0, 0.0])


def stage_states_mm(max_mm: float = 10.0, step_mm: float = 1.0) -> np.ndarray:
    """Stage positions out and back: ``0, step, ..., max, max - step, ..., 0`` (mm).

    Parameters
    ----------
    max_mm : float
        Largest travel (> 0), a whole number of steps.
    step_mm : float
        Step (> 0).

    Returns
    -------
    (2 n + 1,) float, mm, with ``n = max_mm / step_mm`` (21 states for the paper's 10 mm in 1 mm steps).
    """
    if not (np.isfinite(max_mm) and max_mm > 0 and np.isfinite(step_mm) and step_mm > 0):
        raise ValueError(f"max_mm and step_mm must be positive and finite, got {max_mm} and {step_mm}")
    n = round(max_mm / step_mm)
    if n < 1 or abs(n * step_mm - max_mm) > 1e-9 * max_mm:
        raise ValueError(f"max_mm = {max_mm} must be a whole number of steps of {step_mm} mm")
    up = np.arange(n + 1) * float(step_mm)      # multiples of the step, not cumulative sums: no drift
    return np.concatenate([up, up[-2::-1]])


def stage_direction(direction_world=STAGE_UP_WORLD) -> np.ndarray:
    """Validated unit vector of a stage axis (world frame)."""
    d = np.asarray(direction_world, dtype=float).reshape(-1)
    norm = np.linalg.norm(d)
    if d.shape != (3,) or not np.isfinite(norm) or norm == 0:
        raise ValueError(f"stage direction must be a non-zero 3-vector, got {direction_world!r}")
    return d / norm


def stage_displacements_mm(states_mm, direction_world=STAGE_UP_WORLD) -> np.ndarray:
    """Stage displacement of every state in the world (= left camera) frame, (K, 3) mm."""
    s = np.asarray(states_mm, dtype=float).reshape(-1)
    if not np.all(np.isfinite(s)):
        raise ValueError("stage states must be finite")
    return s[:, None] * stage_direction(direction_world)


def stage_poses(R_world_from_specimen, t_world_from_specimen_mm, states_mm,
                direction_world=STAGE_UP_WORLD) -> list[tuple[np.ndarray, np.ndarray]]:
    """Specimen pose in every stage state: a pure translation of the state-0 pose along the stage axis.

    Parameters
    ----------
    R_world_from_specimen : (3, 3), t_world_from_specimen_mm : (3,)
        The pose at stage position 0.
    states_mm : (K,) stage positions (e.g. :func:`stage_states_mm`)
    direction_world : (3,) stage axis, world frame (normalised here); default "up" in the left image.

    Returns
    -------
    list of K ``(R_world_from_specimen (3, 3), t_world_from_specimen_mm (3,))``
    """
    R = np.asarray(R_world_from_specimen, dtype=float)
    t = np.asarray(t_world_from_specimen_mm, dtype=float).reshape(3)
    return [(R.copy(), t + d) for d in stage_displacements_mm(states_mm, direction_world)]


def stage_fields(R_world_from_specimen, states_mm, direction_world=STAGE_UP_WORLD) -> list:
    """The stage motion of every state as a displacement field of the specimen (:mod:`scenes.fields`).

    A stage translation ``d`` (world frame) moves every material point by ``R^T d`` in the specimen frame:
    a :class:`scenes.fields.RigidMotionField` with ``R = I``. ``specimen.surfaces(R, t0, displacement_mm=field)``
    and :func:`scenes.truth.material_point_positions` with these fields give the same positions as the
    translated poses of :func:`stage_poses`.
    """
    from scenes.fields import RigidMotionField

    R = np.asarray(R_world_from_specimen, dtype=float)
    return [RigidMotionField(np.eye(3), R.T @ d) for d in stage_displacements_mm(states_mm, direction_world)]
