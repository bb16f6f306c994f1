"""Rigid stage motions of a specimen (truth side): the paper's vertical translation test.

The paper (§4.2) moves the specimen with a vertical linear stage 0 -> 10 -> 0 mm in 1 mm steps. Here the
stage moves the specimen *up in the left image*, i.e. along **-y of the left camera frame** (OpenCV axes:
y points down in the image). The left camera frame is the world frame, so the default direction is
``STAGE_UP_WORLD = (0, -1, 0)``. A pose is ``X_world = R_world_from_specimen X_specimen + t``; a stage
position ``s`` mm moves it to ``(R, t + s * direction)``.

A real stage does not move exactly where it reports. :class:`StageErrors` (off by default) describes the
scale error, straightness and axis tilt of the stage; :func:`true_stage_displacements_mm` gives where the
specimen really goes. The *nominal* displacement (:func:`stage_displacements_mm`) is what the stage reports
and what the experiment compares the measurement with, as the paper does; the *true* one moves the specimen
in the rendered scene and is the truth the measurement is scored against.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from scenes import _checks

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


#: Sine modes ``sin(n pi s / L)``, n = 2 ... 6, of the seeded random straightness component (mode 1 is the bow).
STRAIGHTNESS_RANDOM_MODES = tuple(range(2, 7))


@dataclass(frozen=True)
class StageErrors:
    """Errors of a linear stage: where the specimen really goes for a reported position ``s`` (mm).

    All zero by default (the stage moves exactly as reported). The true displacement is

    ``d_true(s) = (1 + scale_error) s a_true + 1e-3 (bow(s) + random(s)) p``

    with ``a_true`` the nominal axis ``a`` tilted by ``axis_tilt_deg`` and ``p`` the lateral direction
    (perpendicular to ``a_true``); see :meth:`true_axis`, :meth:`lateral_direction`,
    :meth:`lateral_deviation_um`. The deviation depends on the position only, not on the direction of
    travel (no backlash or hysteresis).

    Parameters
    ----------
    scale_error : float
        Relative scale (positioning) error, dimensionless, > -1: the stage moves ``(1 + scale_error) s``
        along its true axis when it reports ``s``. Precision linear stages (data sheets of PI, Thorlabs,
        Newport: positioning accuracy over the travel) are typically 1e-4 to 1e-3 (0.01-0.1 %).
    straightness_um : float
        Peak lateral deviation of a smooth bow, µm (either sign), at mid-travel:
        ``bow(s) = straightness_um * 4 s (L - s) / L^2`` over the travel ``0 <= s <= L = travel_mm``; zero
        at both ends. Data sheets give straightness of 1-10 µm over 25-100 mm of travel.
    straightness_random_um : float
        RMS over the travel (µm, >= 0) of a seeded, smooth random deviation added to the bow:
        ``random(s) = sum_n c_n sin(n pi s / L)`` over :data:`STRAIGHTNESS_RANDOM_MODES`, with
        ``c_n ~ N(0, 1) / n`` drawn from ``seed`` and scaled so that ``sqrt(sum c_n^2 / 2)`` (the RMS of the
        continuous curve over ``[0, L]``) equals this value. Also zero at both ends. Same range as above.
    travel_mm : float
        Travel ``L`` over which the straightness is defined, mm (> 0); default 10 mm, the paper's travel.
        Positions outside ``[0, L]`` are refused when a straightness term is on.
    straightness_direction_world : (3,) float
        Direction of the lateral deviation, world frame; only its component perpendicular to the true axis
        is used (normalised). Default world x: to the right in the left image, perpendicular to the default
        "up" axis :data:`STAGE_UP_WORLD`.
    axis_tilt_deg : float
        Angle between the true and the nominal stage axis, degrees (``|angle| < 90``): a right-handed rotation
        of the nominal axis by this angle about ``tilt_axis_world``. Mounting misalignment of a stage aligned
        by eye or against a square is of order 0.1-1 deg, with a dial gauge < 0.05 deg (an estimate, not a
        data-sheet value).
    tilt_axis_world : (3,) float
        Axis of the tilt, world frame; only its component perpendicular to the nominal axis is used, so the
        angle between true and nominal axis is exactly ``axis_tilt_deg``. Default world z (the left optical
        axis): the tilt stays in the left image plane; for the default "up" axis a positive tilt leans the
        motion towards +x (right in the left image).
    seed : int
        Seed (>= 0) of the random straightness component.
    """

    scale_error: float = 0.0
    straightness_um: float = 0.0
    straightness_random_um: float = 0.0
    travel_mm: float = 10.0
    straightness_direction_world: tuple[float, float, float] = (1.0, 0.0, 0.0)
    axis_tilt_deg: float = 0.0
    tilt_axis_world: tuple[float, float, float] = (0.0, 0.0, 1.0)
    seed: int = 0
    rotation_urad_per_mm: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def __post_init__(self):
        rot = np.asarray(self.rotation_urad_per_mm, dtype=float).reshape(-1)
        if rot.shape != (3,) or not np.all(np.isfinite(rot)):
            raise ValueError(f"rotation_urad_per_mm must be a finite 3-vector, got {self.rotation_urad_per_mm!r}")
        object.__setattr__(self, "rotation_urad_per_mm", tuple(float(x) for x in rot))
        scalars = {"scale_error": self.scale_error, "straightness_um": self.straightness_um,
                   "straightness_random_um": self.straightness_random_um, "travel_mm": self.travel_mm,
                   "axis_tilt_deg": self.axis_tilt_deg}
        for name, value in scalars.items():
            object.__setattr__(self, name, _checks.finite_float(name, value))
        if not self.scale_error > -1:
            raise ValueError(f"scale_error must be > -1 (the stage must move forwards), got {self.scale_error}")
        if self.straightness_random_um < 0:
            raise ValueError(f"straightness_random_um must be >= 0 (an RMS), got {self.straightness_random_um}")
        if self.travel_mm <= 0:
            raise ValueError(f"travel_mm must be > 0, got {self.travel_mm}")
        if not abs(self.axis_tilt_deg) < 90:
            raise ValueError(f"axis_tilt_deg must be within (-90, 90) deg, got {self.axis_tilt_deg}")
        for name in ("straightness_direction_world", "tilt_axis_world"):
            object.__setattr__(self, name, _nonzero_vector(name, getattr(self, name)))
        if isinstance(self.seed, bool) or not isinstance(self.seed, (int, np.integer)) or self.seed < 0:
            raise ValueError(f"seed must be an integer >= 0, got {self.seed!r}")
        object.__setattr__(self, "seed", int(self.seed))

    @property
    def is_zero(self) -> bool:
        """True when every error is zero: the stage moves exactly as reported."""
        return (self.scale_error == 0 and self.straightness_um == 0 and self.straightness_random_um == 0
                and self.axis_tilt_deg == 0 and not any(self.rotation_urad_per_mm))

    def rotation(self, s_mm: float) -> np.ndarray:
        """(3, 3) rotation of the carriage at reported position ``s_mm`` (world frame)."""
        from scipy.spatial.transform import Rotation

        return Rotation.from_rotvec(1e-6 * float(s_mm) * np.asarray(self.rotation_urad_per_mm)).as_matrix()

    def true_axis(self, direction_world=STAGE_UP_WORLD) -> np.ndarray:
        """Unit vector (3,) of the true stage axis, world frame: the nominal axis tilted by ``axis_tilt_deg``.

        Rodrigues with the tilt axis ``n`` made perpendicular to the nominal axis ``a``:
        ``a_true = cos(theta) a + sin(theta) n x a``.
        """
        a = stage_direction(direction_world)
        if self.axis_tilt_deg == 0:
            return a
        n = _perpendicular_unit(np.asarray(self.tilt_axis_world), a, "tilt_axis_world")
        theta = np.radians(self.axis_tilt_deg)
        return np.cos(theta) * a + np.sin(theta) * np.cross(n, a)

    def lateral_direction(self, direction_world=STAGE_UP_WORLD) -> np.ndarray:
        """Unit vector (3,) of the straightness deviation: ``straightness_direction_world`` made perpendicular
        to the true axis."""
        return _perpendicular_unit(np.asarray(self.straightness_direction_world), self.true_axis(direction_world),
                                   "straightness_direction_world")

    def random_mode_amplitudes_um(self) -> np.ndarray:
        """Amplitudes ``c_n`` (µm) of the random straightness modes :data:`STRAIGHTNESS_RANDOM_MODES`."""
        n = np.asarray(STRAIGHTNESS_RANDOM_MODES, dtype=float)
        c = np.random.default_rng(self.seed).normal(size=n.size) / n     # 1/n: smooth, long waves dominate
        rms = np.sqrt(np.sum(c**2) / 2)                                  # the sine modes are orthogonal on [0, L]
        return c * (self.straightness_random_um / rms)

    def lateral_deviation_um(self, states_mm) -> np.ndarray:
        """Lateral deviation ``bow(s) + random(s)`` (µm) at stage positions ``states_mm`` (K,), shape (K,)."""
        s = np.asarray(states_mm, dtype=float).reshape(-1)
        if not np.all(np.isfinite(s)):
            raise ValueError("stage states must be finite")
        if self.straightness_um == 0 and self.straightness_random_um == 0:
            return np.zeros_like(s)
        L = self.travel_mm
        slack = 1e-9 * L                            # states built from steps land on 0 and L up to rounding
        if np.any(s < -slack) or np.any(s > L + slack):
            raise ValueError(f"stage states must lie within the travel [0, {L:g}] mm (travel_mm) when a "
                             f"straightness error is on, got {s.min():g} to {s.max():g} mm")
        deviation = self.straightness_um * 4 * s * (L - s) / L**2
        if self.straightness_random_um > 0:
            n = np.asarray(STRAIGHTNESS_RANDOM_MODES, dtype=float)
            deviation = deviation + np.sin(np.pi * np.outer(s / L, n)) @ self.random_mode_amplitudes_um()
        return deviation


def true_stage_displacements_mm(states_mm, direction_world=STAGE_UP_WORLD,
                                errors: StageErrors | None = None) -> np.ndarray:
    """Where the specimen really goes for every reported stage position, (K, 3) mm, world frame.

    Parameters
    ----------
    states_mm : (K,) reported (nominal) stage positions, mm
    direction_world : (3,) nominal stage axis, world frame (normalised here)
    errors : StageErrors or None
        None, or all-zero errors, give :func:`stage_displacements_mm` exactly (the same array values).

    Returns
    -------
    (K, 3) float, mm: ``(1 + scale_error) s a_true + 1e-3 lateral_deviation_um(s) p`` (see
    :class:`StageErrors`).
    """
    nominal = stage_displacements_mm(states_mm, direction_world)
    if errors is None or errors.is_zero:
        return nominal                               # bit-identical to the error-free stage
    s = np.asarray(states_mm, dtype=float).reshape(-1)
    along = ((1.0 + errors.scale_error) * s)[:, None] * errors.true_axis(direction_world)
    lateral_mm = 1e-3 * errors.lateral_deviation_um(s)
    if not np.any(lateral_mm):
        return along
    return along + lateral_mm[:, None] * errors.lateral_direction(direction_world)


def stage_poses(R_world_from_specimen, t_world_from_specimen_mm, states_mm,
                direction_world=STAGE_UP_WORLD, errors: StageErrors | None = None
                ) -> list[tuple[np.ndarray, np.ndarray]]:
    """Specimen pose in every stage state: a pure translation of the state-0 pose along the stage axis.

    Parameters
    ----------
    R_world_from_specimen : (3, 3), t_world_from_specimen_mm : (3,)
        The pose at stage position 0.
    states_mm : (K,) stage positions (e.g. :func:`stage_states_mm`)
    direction_world : (3,) stage axis, world frame (normalised here); default "up" in the left image.
    errors : StageErrors or None
        Stage errors; the pose moves by the *true* displacement (:func:`true_stage_displacements_mm`).
        None (or all-zero errors) gives the nominal translation exactly.

    Returns
    -------
    list of K ``(R_world_from_specimen (3, 3), t_world_from_specimen_mm (3,))``
    """
    R = np.asarray(R_world_from_specimen, dtype=float)
    t = np.asarray(t_world_from_specimen_mm, dtype=float).reshape(3)
    shifts = true_stage_displacements_mm(states_mm, direction_world, errors)
    if errors is None or not any(errors.rotation_urad_per_mm):
        return [(R.copy(), t + d) for d in shifts]
    # the carriage turns the specimen about its own state-0 origin, which the translation carries along
    s = np.asarray(states_mm, dtype=float).reshape(-1)
    return [(errors.rotation(sk) @ R, t + d) for sk, d in zip(s, shifts)]


def stage_fields(R_world_from_specimen, states_mm, direction_world=STAGE_UP_WORLD,
                 errors: StageErrors | None = None) -> list:
    """The stage motion of every state as a displacement field of the specimen (:mod:`scenes.deformation.beam_bending`).

    A stage translation ``d`` (world frame) moves every material point by ``R^T d`` in the specimen frame:
    a :class:`scenes.deformation.displacement_field.RigidMotionField` with ``R = I``. ``specimen.surfaces(R, t0, displacement_mm=field)``
    and :func:`scenes.optics.projection.material_point_positions` with these fields give the same positions as the
    translated poses of :func:`stage_poses` (with the same ``errors``: the true displacement).
    """
    from scenes.deformation.displacement_field import RigidMotionField

    R = np.asarray(R_world_from_specimen, dtype=float)
    shifts = true_stage_displacements_mm(states_mm, direction_world, errors)
    if errors is None or not any(errors.rotation_urad_per_mm):
        return [RigidMotionField(np.eye(3), R.T @ d) for d in shifts]
    # world X' = Rc (R X + t0 - t0) + t0 + d  =>  specimen frame: X' = (R^T Rc R) X + R^T d
    s = np.asarray(states_mm, dtype=float).reshape(-1)
    return [RigidMotionField(R.T @ errors.rotation(sk) @ R, R.T @ d) for sk, d in zip(s, shifts)]


# ------------------------------------------------------------------------------------------------------------
def _nonzero_vector(name: str, value) -> tuple[float, float, float]:
    try:
        v = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a finite, non-zero 3-vector, got {value!r}") from None
    if v.shape != (3,) or not np.all(np.isfinite(v)) or not np.any(v):
        raise ValueError(f"{name} must be a finite, non-zero 3-vector, got {value!r}")
    return tuple(float(x) for x in v)                # a tuple keeps the frozen dataclass hashable and JSON-able


def _perpendicular_unit(v: np.ndarray, axis: np.ndarray, name: str) -> np.ndarray:
    """``v`` without its component along the unit vector ``axis``, normalised."""
    v = np.asarray(v, dtype=float) / np.linalg.norm(v)
    w = v - (v @ axis) * axis
    norm = np.linalg.norm(w)
    if norm < 1e-9:
        raise ValueError(f"{name} {tuple(v)} is parallel to the stage axis {tuple(axis)}; it needs a "
                         "perpendicular component")
    return w / norm
