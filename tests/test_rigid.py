"""Tests for measurement.rigid: least-squares rigid motion (Kabsch / Umeyama with the reflection guard)."""
import numpy as np
import pytest
from scipy.optimize import minimize
from scipy.spatial.transform import Rotation

from measurement.rigid import apply_rigid, fit_rigid, remove_rigid_motion


def _points(n: int, seed: int) -> np.ndarray:
    """A DIC-like cloud near the working distance: 40 x 30 x 10 mm around (0, 0, 350) mm, shape (n, 3)."""
    rng = np.random.default_rng(seed)
    return np.stack([rng.uniform(-20, 20, n), rng.uniform(-15, 15, n), rng.uniform(345, 355, n)], axis=-1)


def _motion(seed: int) -> tuple[np.ndarray, np.ndarray]:
    """A random proper rotation (any angle) and a translation of up to ~50 mm."""
    rng = np.random.default_rng(seed)
    return Rotation.random(random_state=seed).as_matrix(), rng.uniform(-50, 50, 3)


def _rotation_angle_rad(R_a: np.ndarray, R_b: np.ndarray) -> float:
    return float(Rotation.from_matrix(R_a.T @ R_b).magnitude())


def _cost(R, t, A, B) -> float:
    return float(np.sum((A @ R.T + t - B) ** 2))


def test_recovers_exact_motion():
    A = _points(50, seed=1)
    R_true, t_true = _motion(seed=2)
    R, t = fit_rigid(A, apply_rigid(R_true, t_true, A))
    np.testing.assert_allclose(R, R_true, atol=1e-10)
    np.testing.assert_allclose(t, t_true, atol=1e-10)
    assert np.linalg.det(R) == pytest.approx(1.0, abs=1e-12)


def test_recovers_exact_motion_of_coplanar_points():
    # Coplanar points: the cross-covariance has rank 2 and the sign of its null direction is arbitrary, so
    # without the reflection guard half of such fits would come back as reflections.
    for seed in range(10):
        A = _points(30, seed=seed)
        A[:, 2] = 350.0
        R_true, t_true = _motion(seed=100 + seed)
        R, t = fit_rigid(A, apply_rigid(R_true, t_true, A))
        np.testing.assert_allclose(R, R_true, atol=1e-10)
        np.testing.assert_allclose(t, t_true, atol=1e-10)


def test_noisy_fit_is_close_to_truth_and_least_squares():
    n, sigma_mm = 400, 0.01
    A = _points(n, seed=3)
    R_true, t_true = _motion(seed=4)
    rng = np.random.default_rng(5)
    B = apply_rigid(R_true, t_true, A) + rng.normal(0.0, sigma_mm, (n, 3))

    R, t = fit_rigid(A, B)

    angle_rad = _rotation_angle_rad(R, R_true)
    motion_error_mm = np.sqrt(np.mean(np.sum((apply_rigid(R, t, A) - apply_rigid(R_true, t_true, A)) ** 2, 1)))
    residual_rms_mm = np.sqrt(_cost(R, t, A, B) / (3 * n))
    print(f"\nnoisy rigid fit (sigma {sigma_mm} mm, {n} points): rotation error {angle_rad:.2e} rad, "
          f"RMS motion error {motion_error_mm:.2e} mm, residual RMS {residual_rms_mm:.4f} mm")
    # Expected rotation error ~ sigma / (extent ~12 mm * sqrt(n)) ~ 4e-5 rad; motion error ~ sigma sqrt(6/n)/sqrt(3).
    assert angle_rad < 2e-4
    assert motion_error_mm < 5 * sigma_mm * np.sqrt(6 / n) / np.sqrt(3)
    # The least-squares fit beats the true motion on the noisy data, and the residual is the noise
    # (6 fitted parameters out of 3 n coordinates).
    assert _cost(R, t, A, B) <= _cost(R_true, t_true, A, B)
    assert residual_rms_mm == pytest.approx(sigma_mm * np.sqrt((3 * n - 6) / (3 * n)), rel=0.05)
    assert np.linalg.det(R) == pytest.approx(1.0, abs=1e-12)


def test_mirrored_configuration_gives_best_proper_rotation():
    A = _points(20, seed=6)
    A -= A.mean(axis=0)
    B = A * np.array([1.0, 1.0, -1.0]) + np.array([3.0, -2.0, 1.0])  # a reflection: no rotation fits exactly

    # Precondition: plain Kabsch (without the guard) would return a reflection here.
    U, _, Vt = np.linalg.svd((A - A.mean(0)).T @ (B - B.mean(0)))
    assert np.linalg.det(Vt.T @ U.T) < 0

    R, t = fit_rigid(A, B)

    np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-12)
    assert np.linalg.det(R) == pytest.approx(1.0, abs=1e-12)
    # It is the optimum over proper rotations: no local optimiser started anywhere does better.
    def cost(params):
        return _cost(Rotation.from_rotvec(params[:3]).as_matrix(), params[3:], A, B)

    best_other = min(minimize(cost, np.concatenate([Rotation.random(random_state=s).as_rotvec(), np.zeros(3)]),
                              method="BFGS").fun for s in range(8))
    assert _cost(R, t, A, B) <= best_other + 1e-8


def test_nan_rows_and_zero_weights_are_ignored():
    A = _points(30, seed=7)
    R_true, t_true = _motion(seed=8)
    rng = np.random.default_rng(9)
    B = apply_rigid(R_true, t_true, A) + rng.normal(0.0, 0.01, A.shape)
    R_ref, t_ref = fit_rigid(A, B)

    A_bad = np.vstack([A, [[np.nan, 1.0, 2.0], [0.0, 0.0, 0.0], [5.0, 5.0, 5.0]]])
    B_bad = np.vstack([B, [[1e6, 1e6, 1e6], [np.nan, np.nan, np.nan], [np.inf, 0.0, 0.0]]])
    R, t = fit_rigid(A_bad, B_bad)
    np.testing.assert_allclose(R, R_ref, atol=1e-12)
    np.testing.assert_allclose(t, t_ref, atol=1e-10)

    # A zero-weighted outlier has no influence either.
    A_out, B_out = np.vstack([A, [[0.0, 0.0, 350.0]]]), np.vstack([B, [[100.0, 100.0, 100.0]]])
    R_w, t_w = fit_rigid(A_out, B_out, weights=np.r_[np.ones(len(A)), 0.0])
    np.testing.assert_allclose(R_w, R_ref, atol=1e-12)
    np.testing.assert_allclose(t_w, t_ref, atol=1e-10)


def test_integer_weights_equal_duplicated_rows():
    A = _points(15, seed=10)
    R_true, t_true = _motion(seed=11)
    B = apply_rigid(R_true, t_true, A) + np.random.default_rng(12).normal(0.0, 0.05, A.shape)
    counts = np.random.default_rng(13).integers(1, 4, len(A))
    R_w, t_w = fit_rigid(A, B, weights=counts.astype(float))
    R_dup, t_dup = fit_rigid(np.repeat(A, counts, axis=0), np.repeat(B, counts, axis=0))
    np.testing.assert_allclose(R_w, R_dup, atol=1e-12)
    np.testing.assert_allclose(t_w, t_dup, atol=1e-10)
    # ... and differ from the unweighted fit (the weights do something).
    assert not np.allclose(fit_rigid(A, B)[0], R_w, atol=1e-8, rtol=0)


def test_too_few_points_raise():
    A = _points(5, seed=14)
    B = A + 1.0
    A[[0, 2, 4]] = np.nan
    with pytest.raises(ValueError, match="at least 3 rows.*got 2 of 5"):
        fit_rigid(A, B)
    with pytest.raises(ValueError, match="at least 3 rows"):
        fit_rigid(B[:2], B[:2])


def test_collinear_or_coincident_points_raise():
    line = np.outer(np.linspace(-10, 10, 12), [1.0, 0.5, 0.2]) + [0.0, 0.0, 350.0]
    with pytest.raises(ValueError, match="A: .*collinear"):
        fit_rigid(line, line + 1.0)
    with pytest.raises(ValueError, match="B: .*collinear"):
        fit_rigid(_points(12, seed=15), line)
    same = np.tile([1.0, 2.0, 3.0], (5, 1))
    with pytest.raises(ValueError, match="coincident"):
        fit_rigid(same, same)


def test_bad_shapes_and_weights_raise():
    A = _points(6, seed=16)
    with pytest.raises(ValueError, match="same number of points, got 6 and 5"):
        fit_rigid(A, A[:5])
    with pytest.raises(ValueError, match=r"B must have shape \(N, 3\), got \(6, 2\)"):
        fit_rigid(A, A[:, :2])
    with pytest.raises(ValueError, match=r"weights must have shape \(6,\)"):
        fit_rigid(A, A, weights=np.ones(5))
    with pytest.raises(ValueError, match="weight 3 is -1.0"):
        fit_rigid(A, A, weights=np.array([1.0, 1.0, 1.0, -1.0, 1.0, 1.0]))
    with pytest.raises(ValueError, match="weight 1 is nan"):
        fit_rigid(A, A, weights=np.array([1.0, np.nan, 1.0, 1.0, 1.0, 1.0]))
    with pytest.raises(ValueError, match=r"R must have shape \(3, 3\)"):
        apply_rigid(np.eye(2), np.zeros(3), A)


def test_remove_rigid_motion_returns_deformation():
    # A symmetric 9 x 7 x 3 grid and a deformation with no rigid part on it: a diagonal strain about the
    # centre plus an out-of-plane bending w = kappa x^2. By the grid's symmetry the cross-covariance stays
    # diagonal, so the least-squares rotation is exactly the applied one and the translation absorbs only
    # the mean bending; the residual must be the deformation minus its mean.
    gx, gy, gz = np.meshgrid(np.linspace(-20, 20, 9), np.linspace(-15, 15, 7), np.linspace(-2, 2, 3))
    centred = np.stack([gx.ravel(), gy.ravel(), gz.ravel()], axis=-1)
    X0 = centred + [1.0, -2.0, 350.0]
    deformation_mm = centred * [1e-3, -5e-4, 3e-4]
    deformation_mm[:, 2] += 2e-4 * centred[:, 0] ** 2
    R_true, t_true = _motion(seed=18)
    X1 = apply_rigid(R_true, t_true, X0 + deformation_mm)

    removal = remove_rigid_motion(X0, X1)

    expected_residual_mm = deformation_mm - deformation_mm.mean(axis=0)
    np.testing.assert_allclose(removal.R_0_from_1, R_true.T, atol=1e-10)
    np.testing.assert_allclose(removal.t_0_from_1_mm, -R_true.T @ t_true - deformation_mm.mean(axis=0),
                               atol=1e-9)
    np.testing.assert_allclose(removal.residual_mm, expected_residual_mm, atol=1e-9)
    np.testing.assert_allclose(removal.X1_aligned_mm, X0 + expected_residual_mm, atol=1e-9)
    # Rigid motion alone leaves nothing.
    assert np.abs(remove_rigid_motion(X0, apply_rigid(R_true, t_true, X0)).residual_mm).max() < 1e-10


def test_remove_rigid_motion_with_missing_points():
    X0 = _points(100, seed=21)
    R_true, t_true = _motion(seed=22)
    X1 = apply_rigid(R_true, t_true, X0) + np.random.default_rng(23).normal(0.0, 0.01, X0.shape)
    X1_missing = X1.copy()
    X1_missing[[5, 40]] = np.nan

    removal = remove_rigid_motion(X0, X1_missing)
    reference = remove_rigid_motion(np.delete(X0, [5, 40], axis=0), np.delete(X1, [5, 40], axis=0))

    assert np.isnan(removal.residual_mm[[5, 40]]).all() and np.isnan(removal.X1_aligned_mm[[5, 40]]).all()
    np.testing.assert_allclose(np.delete(removal.residual_mm, [5, 40], axis=0), reference.residual_mm,
                               atol=1e-10)
    np.testing.assert_allclose(removal.R_0_from_1, reference.R_0_from_1, atol=1e-12)


def test_remove_rigid_motion_names_its_arguments():
    with pytest.raises(ValueError, match="X1_mm and X0_mm must have the same number of points"):
        remove_rigid_motion(_points(5, seed=19), _points(4, seed=20))
