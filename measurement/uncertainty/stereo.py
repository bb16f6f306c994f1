"""Random uncertainty of triangulated positions and displacements: the matches carried through both cameras.

Every image is matched from the LEFT REFERENCE subset (:mod:`measurement.stereo_dic`): the stereo match
(left-ref -> right-ref) and, per state, left-ref -> left-def and left-ref -> right-def. To first order each match
error is a sum of independent parts (:mod:`measurement.uncertainty.match`):

    e_s = d_L + n_R,   e_l = d_L + n_Ld,   e_r = d_L + n_Rd,

with ``d_L`` the left reference's noise -- *the same* in all three matches, since they correlate the same reference
subset -- and ``n_*`` the noise of the right reference, left deformed and right deformed images. Strictly, the
left reference's noise moves each match by its own ``F_m xi`` (:attr:`~measurement.uncertainty.match.
MatchUncertainty.reference_factor`: the stereo match's cross-Hessian sees the right camera's blur and scale, the
left temporal match the left camera's); with the factors given, the shared part below is
``(G_L F_l + G_R F_r - G_R^ref F_s) (...)^T`` instead of ``(G_L + G_R - G_R^ref) C_L (...)^T``. Optimal
triangulation moves a point by ``G = (J^T J)^-1 J^T`` per pixel error (J: the (4, 3) stacked projection Jacobian
of both cameras, tilt and distortion included; G's columns 0-1 for the left pixel, 2-3 for the right one). So

    X_ref error = G_R^ref e_s                                   (the left reference pixel is the point itself)
    X_def error = G_L e_l + G_R e_r
    U error     = (G_L + G_R - G_R^ref) d_L + G_L n_Ld + G_R n_Rd - G_R^ref n_R,

and the covariances follow with the 2 x 2 covariances of the parts. The reference state's noise is thus counted in
every displacement, and the shared left-reference part is neither dropped nor double counted.
"""
from __future__ import annotations

import numpy as np

from measurement.stereo import check_stereo_pose, stacked_jacobian


def triangulation_sensitivity(left, right, R_right_from_left, T_right_from_left_mm, X_left_mm) -> np.ndarray:
    """``dX / d(pixels)`` of optimal triangulation at each point, shape (N, 3, 4), mm/px.

    Columns: left u, left v, right u, right v. NaN rows for non-finite points.
    """
    R, T = check_stereo_pose(R_right_from_left, T_right_from_left_mm)
    X = np.asarray(X_left_mm, dtype=np.float64).reshape(-1, 3)
    out = np.full((X.shape[0], 3, 4), np.nan)
    ok = np.all(np.isfinite(X), axis=1)
    if not ok.any():
        return out
    J = stacked_jacobian(left, right, R, T, X[ok])
    normal = np.swapaxes(J, 1, 2) @ J
    good = np.all(np.isfinite(normal), axis=(1, 2)) & (np.abs(np.linalg.det(normal)) > 0)
    G = np.full((J.shape[0], 3, 4), np.nan)
    G[good] = np.linalg.solve(normal[good], np.swapaxes(J[good], 1, 2))
    out[ok] = G
    return out


def _sandwich(A: np.ndarray, C: np.ndarray) -> np.ndarray:
    """A C A^T for stacks (N, 3, 2) and (N, 2, 2)."""
    return A @ C @ np.swapaxes(A, 1, 2)


def shape_covariance_mm2(G_ref: np.ndarray, cov_left_reference_px2: np.ndarray,
                         cov_right_reference_px2: np.ndarray) -> np.ndarray:
    """Covariance of the reference shape's points, (N, 3, 3) mm^2.

    Parameters
    ----------
    G_ref : (N, 3, 4) triangulation sensitivity at the reference points
    cov_left_reference_px2 : (N, 2, 2)
        The stereo match's part from the left reference image's noise.
    cov_right_reference_px2 : (N, 2, 2)
        Its part from the right reference image's noise.
    """
    Gr = G_ref[:, :, 2:]
    return _sandwich(Gr, cov_left_reference_px2 + cov_right_reference_px2)


def state_covariances_mm2(G_ref: np.ndarray, G_def: np.ndarray, cov_left_reference_px2: np.ndarray,
                          cov_right_reference_px2: np.ndarray, cov_left_deformed_px2: np.ndarray,
                          cov_right_deformed_px2: np.ndarray, *, factors=None) -> tuple[np.ndarray, np.ndarray]:
    """Covariance of the deformed positions and of the displacements (module notes), each (N, 3, 3) mm^2.

    Parameters
    ----------
    G_ref, G_def : (N, 3, 4)
        Triangulation sensitivity at the reference and at the deformed points.
    cov_left_reference_px2 : (N, 2, 2)
        The left reference image's part of every match (shared).
    cov_right_reference_px2, cov_left_deformed_px2, cov_right_deformed_px2 : (N, 2, 2)
        The target parts of the stereo match, the left temporal match and the right temporal match.
    factors : tuple of three (N, 2, np) arrays, optional
        The reference factors ``F`` of the stereo, left temporal and right temporal matches (module notes); the
        shared part then follows each match's own sensitivity to the left reference's noise and
        ``cov_left_reference_px2`` is not used.

    Returns
    -------
    cov_X_def, cov_U : ndarray (N, 3, 3)
    """
    GL, GR, GRref = G_def[:, :, :2], G_def[:, :, 2:], G_ref[:, :, 2:]
    if factors is None:
        shared_U = _sandwich(GL + GR - GRref, cov_left_reference_px2)
        shared_X = _sandwich(GL + GR, cov_left_reference_px2)
    else:
        F_s, F_l, F_r = (np.asarray(f, dtype=np.float64) for f in factors)
        deformed = GL @ F_l + GR @ F_r
        shared_X = deformed @ np.swapaxes(deformed, 1, 2)
        moved = deformed - GRref @ F_s
        shared_U = moved @ np.swapaxes(moved, 1, 2)
    cov_U = (shared_U + _sandwich(GL, cov_left_deformed_px2)
             + _sandwich(GR, cov_right_deformed_px2) + _sandwich(GRref, cov_right_reference_px2))
    cov_X = shared_X + _sandwich(GL, cov_left_deformed_px2) + _sandwich(GR, cov_right_deformed_px2)
    return cov_X, cov_U


def sigmas(cov: np.ndarray) -> np.ndarray:
    """Square roots of the diagonals of a stack of covariances, (N, k, k) -> (N, k)."""
    return np.sqrt(np.clip(np.einsum("kii->ki", cov), 0.0, None)) * np.where(
        np.all(np.isfinite(np.einsum("kii->ki", cov)), axis=1), 1.0, np.nan)[:, None]


def static_repeat_covariance_mm2(G_ref: np.ndarray, cov_left_reference_px2: np.ndarray,
                                 cov_right_reference_px2: np.ndarray) -> np.ndarray:
    """Covariance of U for a *static repeat* of the reference pair (the noise floor), from the shape alone, mm^2.

    A static repeat samples both new images at the reference's own sub-pixel phases: the left one at whole pixels
    (its noise counts as the left reference's, ``C_L``), the right one where the stereo match sampled the right
    reference (``C_R``); the deformed points are the reference points, so ``G_def = G_ref``, the right repeat's
    match moves with the left reference's noise as the stereo match does (their shares cancel) and (module notes)
    ``Cov U = 2 G_L C_L G_L^T + 2 G_R C_R G_R^T``. This is what a digital twin predicts for a rig before any
    static pair is recorded.

    ``cov_left_reference_px2`` is the left reference's part of a left-to-left match
    (:attr:`~measurement.uncertainty.match.ReferenceSubsets.cov_uv_reference`), ``cov_right_reference_px2`` the
    right image's part of the stereo match (its ``cov_target_px2``).
    """
    GL, GR = G_ref[:, :, :2], G_ref[:, :, 2:]
    return 2.0 * _sandwich(GL, cov_left_reference_px2) + 2.0 * _sandwich(GR, cov_right_reference_px2)


def shape_bias_bound_mm(G_ref: np.ndarray, bias_bound_px: np.ndarray) -> np.ndarray:
    """Bound on the interpolation bias of the reference points, (N, 3) mm: ``|G_R^ref| b`` (element-wise absolute
    values), ``b`` (N, 2) the stereo match's bias bound on (u, v), px."""
    return np.einsum("kij,kj->ki", np.abs(G_ref[:, :, 2:]), bias_bound_px)


def state_bias_bound_mm(G_ref: np.ndarray, G_def: np.ndarray, bias_bound_px: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Bounds on the interpolation bias of the deformed points and of the displacements, each (N, 3) mm.

    Every match of a point correlates the same left reference subset, so one bound ``b`` (N, 2) px holds for each
    (:func:`measurement.uncertainty.bias.bias_bound_px`); their phases differ, so the bounds add (triangle
    inequality): ``|G_L| b + |G_R| b`` for X and ``+ |G_R^ref| b`` for U.
    """
    a = np.abs(G_def[:, :, :2]) + np.abs(G_def[:, :, 2:])
    X = np.einsum("kij,kj->ki", a, bias_bound_px)
    return X, X + shape_bias_bound_mm(G_ref, bias_bound_px)


def static_repeat_sigma_um(calibration, shape) -> np.ndarray:
    """The predicted 1-sigma of U, V, W for a static repeat of a measured reference shape, (N, 3) µm.

    :func:`static_repeat_covariance_mm2` with the shape's own match uncertainty (the noise models it was measured
    with): the left camera's part from its reference subsets, the right one's from the stereo match; NaN where the
    shape has none. ``calibration``: the stereo calibration the shape was triangulated with (``left``, ``right``,
    ``R_right_from_left``, ``T_right_from_left_mm``); ``shape``: a :class:`measurement.stereo_dic.ReferenceShape`
    measured with its uncertainty. What a digital twin predicts for a rig before any static pair is recorded.
    """
    unc = shape.match_uncertainty
    if unc is None or shape.subsets is None:
        return np.full((shape.x.size, 3), np.nan)
    G = triangulation_sensitivity(calibration.left, calibration.right, calibration.R_right_from_left,
                                  calibration.T_right_from_left_mm, shape.X_mm)
    left = np.where(np.isfinite(unc.sigma_u_px)[:, None, None], shape.subsets.cov_uv_reference, np.nan)
    return sigmas(static_repeat_covariance_mm2(G, left, unc.cov_target_px2)) * 1e3
