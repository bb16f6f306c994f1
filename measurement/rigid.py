"""Rigid-body motion: least-squares fit (Kabsch / Umeyama without scale), application and removal.

In stereo-DIC the specimen usually moves as a whole as well as deforming; the deformation is what is left
after the best rigid motion between the reference and the deformed point clouds is taken out.

Conventions: a rigid motion ``(R, t)`` maps points as ``X -> R X + t`` with ``R`` a proper rotation
(``det R = +1``), ``R`` (3, 3) and ``t`` (3,) in the points' length unit (mm in this project). Points are
rows of (N, 3) arrays, all in one frame (e.g. ``X_left_mm``).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Point sets whose second singular value (of the centred, weighted coordinates) is below this fraction of the
#: first are treated as collinear: the rotation about their line is then undetermined.
COLLINEARITY_TOL = 1e-9


@dataclass(frozen=True)
class RigidMotionRemoval:
    """Output of :func:`remove_rigid_motion`.

    Attributes
    ----------
    X1_aligned_mm : ndarray, shape (N, 3), mm
        The deformed points mapped back onto the reference: ``R_0_from_1 X1 + t_0_from_1_mm``.
    residual_mm : ndarray, shape (N, 3), mm
        ``X1_aligned_mm - X0``: the displacement that is not rigid-body motion (NaN where either input is).
    R_0_from_1 : ndarray, shape (3, 3)
        Rotation of the fitted motion from the deformed to the reference state.
    t_0_from_1_mm : ndarray, shape (3,), mm
        Translation of that motion.
    """

    X1_aligned_mm: np.ndarray
    residual_mm: np.ndarray
    R_0_from_1: np.ndarray
    t_0_from_1_mm: np.ndarray


def _check_points(name: str, points) -> np.ndarray:
    """``points`` as a float (N, 3) array; ValueError naming ``name`` otherwise."""
    points = np.asarray(points, dtype=float)
    if points.ndim != 2 or points.shape[1] != 3:
        raise ValueError(f"{name} must have shape (N, 3), got {points.shape}")
    return points


def _check_weights(weights, n_points: int) -> np.ndarray:
    """Validated non-negative finite weights of shape (n_points,); all ones for None."""
    if weights is None:
        return np.ones(n_points)
    weights = np.asarray(weights, dtype=float)
    if weights.shape != (n_points,):
        raise ValueError(f"weights must have shape ({n_points},) to match the points, got {weights.shape}")
    bad = np.flatnonzero(~np.isfinite(weights) | (weights < 0))
    if bad.size:
        raise ValueError(
            f"weights must be finite and non-negative; weight {bad[0]} is {float(weights[bad[0]])}")
    return weights


def _check_not_collinear(name: str, centred: np.ndarray, sqrt_weights: np.ndarray) -> None:
    """ValueError if the centred points (M, 3) are coincident or (nearly) collinear."""
    singular_values = np.linalg.svd(centred * sqrt_weights[:, None], compute_uv=False)
    if not singular_values[1] > COLLINEARITY_TOL * singular_values[0]:
        raise ValueError(
            f"{name}: the valid points are coincident or (nearly) collinear, so the rotation is undetermined "
            f"(singular values of the centred points {singular_values})")


def fit_rigid(A, B, weights=None) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares rigid motion taking ``A`` onto ``B`` (Kabsch / Umeyama with the reflection guard).

    Minimises ``sum_i w_i |R A_i + t - B_i|^2`` over proper rotations ``R`` and translations ``t``.

    Parameters
    ----------
    A, B : array, shape (N, 3)
        Corresponding points (same length unit, e.g. mm). Rows where either has a non-finite coordinate are
        ignored.
    weights : array, shape (N,), optional
        Non-negative finite weights; rows with zero weight are ignored. None weights all rows equally.

    Returns
    -------
    R : ndarray, shape (3, 3)
        Proper rotation, ``det R = +1`` (even when the best orthogonal map would be a reflection).
    t : ndarray, shape (3,)
        Translation, in the points' unit.

    Raises
    ------
    ValueError
        On wrong shapes, bad weights, fewer than 3 usable rows, or usable points of ``A`` or ``B`` that are
        coincident or collinear (the rotation about their line is then undetermined).
    """
    return _fit_rigid(A, B, weights, "A", "B")


def _fit_rigid(A, B, weights, name_A: str, name_B: str) -> tuple[np.ndarray, np.ndarray]:
    """:func:`fit_rigid` with the caller's names for ``A`` and ``B`` in error messages."""
    A = _check_points(name_A, A)
    B = _check_points(name_B, B)
    if len(A) != len(B):
        raise ValueError(
            f"{name_A} and {name_B} must have the same number of points, got {len(A)} and {len(B)}")
    weights = _check_weights(weights, len(A))
    usable = np.all(np.isfinite(A), axis=1) & np.all(np.isfinite(B), axis=1) & (weights > 0)
    n_usable = int(usable.sum())
    if n_usable < 3:
        raise ValueError(
            f"a rigid fit needs at least 3 rows that are finite in both {name_A} and {name_B} with positive "
            f"weight, got {n_usable} of {len(A)}")
    A, B, w = A[usable], B[usable], weights[usable] / weights[usable].sum()
    centroid_A, centroid_B = w @ A, w @ B
    A_c, B_c = A - centroid_A, B - centroid_B
    sqrt_w = np.sqrt(w)
    _check_not_collinear(name_A, A_c, sqrt_w)
    _check_not_collinear(name_B, B_c, sqrt_w)
    cross_covariance = (A_c * w[:, None]).T @ B_c  # sum_i w_i a_i b_i^T, (3, 3)
    U, _, Vt = np.linalg.svd(cross_covariance)
    # Reflection guard: flip the least significant axis if U V^T would be a reflection.
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T)) or 1.0])
    R = Vt.T @ D @ U.T
    t = centroid_B - R @ centroid_A
    return R, t


def apply_rigid(R, t, X) -> np.ndarray:
    """Apply the rigid motion ``X -> R X + t`` to rows of ``X``.

    Parameters
    ----------
    R : array, shape (3, 3)
    t : array, shape (3,)
    X : array, shape (N, 3)

    Returns
    -------
    ndarray, shape (N, 3)
        Moved points; NaN rows stay NaN.
    """
    R = np.asarray(R, dtype=float)
    t = np.asarray(t, dtype=float)
    if R.shape != (3, 3):
        raise ValueError(f"R must have shape (3, 3), got {R.shape}")
    if t.shape != (3,):
        raise ValueError(f"t must have shape (3,), got {t.shape}")
    return _check_points("X", X) @ R.T + t


def remove_rigid_motion(X0_mm, X1_mm, weights=None) -> RigidMotionRemoval:
    """Take the best-fit rigid motion out of a displacement ``X0 -> X1``.

    Fits ``(R, t)`` with ``R X1 + t ~ X0`` (:func:`fit_rigid`) and maps ``X1`` back onto the reference.

    Parameters
    ----------
    X0_mm : array, shape (N, 3), mm
        Reference points.
    X1_mm : array, shape (N, 3), mm
        The same material points after motion and deformation. Non-finite rows (in either) are ignored in
        the fit and come back as NaN.
    weights : array, shape (N,), optional
        Passed to :func:`fit_rigid`.

    Returns
    -------
    RigidMotionRemoval
        ``X1_aligned_mm`` (N, 3), ``residual_mm = X1_aligned_mm - X0_mm`` (N, 3), ``R_0_from_1`` (3, 3),
        ``t_0_from_1_mm`` (3,).
    """
    R, t = _fit_rigid(X1_mm, X0_mm, weights, "X1_mm", "X0_mm")
    X0_mm = _check_points("X0_mm", X0_mm)
    X1_aligned_mm = apply_rigid(R, t, X1_mm)
    return RigidMotionRemoval(X1_aligned_mm=X1_aligned_mm, residual_mm=X1_aligned_mm - X0_mm, R_0_from_1=R,
                              t_0_from_1_mm=t)
