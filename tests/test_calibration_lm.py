"""Tests for measurement.calibration.lm: the block-structured Levenberg-Marquardt (Schur complement).

A toy problem with the calibration's structure: V noisy ellipses sharing their semi-axes (a, b) (the "shared"
parameters, k = 2), each with its own centre (the per-view block, b = 2). Residual of point i of ellipse v:
``sqrt(((x - cx_v) / a)^2 + ((y - cy_v) / b)^2) - 1``. The rows of each ellipse are scattered through the
residual vector (as the left and right halves of a stereo view are) to exercise the row bookkeeping.
"""
import numpy as np
import pytest
from scipy.optimize import least_squares

from measurement.calibration.lm import BlockJacobian, _damped_step, block_fd_jacobian, levenberg_marquardt

N_ELLIPSES = 7
N_POINTS = 40
BLOCK = 2
TRUE_AXES = np.array([3.0, 1.7])


def _toy(noise, seed=0):
    """Residual function, (V, R) view rows, x_true (2 + 2 V,), and a perturbed start."""
    rng = np.random.default_rng(seed)
    centres = rng.uniform(-10, 10, (N_ELLIPSES, 2))
    t = rng.uniform(0, 2 * np.pi, (N_ELLIPSES, N_POINTS))
    pts = centres[:, None, :] + TRUE_AXES * np.stack([np.cos(t), np.sin(t)], axis=-1)
    pts = pts + rng.normal(0.0, noise, pts.shape)
    order = rng.permutation(N_ELLIPSES * N_POINTS)          # residual row of (ellipse v, point i)
    rows = order.reshape(N_ELLIPSES, N_POINTS)

    def residual(x):
        axes, c = x[:2], x[2:].reshape(N_ELLIPSES, BLOCK)
        d = np.sqrt(np.sum(((pts - c[:, None, :]) / axes) ** 2, axis=-1)) - 1.0     # (V, R)
        r = np.empty(N_ELLIPSES * N_POINTS)
        r[rows] = d
        return r

    x_true = np.concatenate([TRUE_AXES, centres.ravel()])
    x0 = x_true + np.concatenate([[0.4, -0.3], rng.normal(0.0, 0.5, 2 * N_ELLIPSES)])
    return residual, rows, x_true, x0


def _dense_central_jacobian(residual, x, steps):
    J = np.empty((len(residual(x)), len(x)))
    for j in range(len(x)):
        e = np.zeros_like(x)
        e[j] = steps[j]
        J[:, j] = (residual(x + e) - residual(x - e)) / (2 * steps[j])
    return J


def test_block_jacobian_matches_a_column_by_column_difference():
    residual, rows, _, x0 = _toy(0.01)
    jac = block_fd_jacobian(residual, x0, 2, rows, block_size=BLOCK)
    assert jac.shared.shape == (N_ELLIPSES, N_POINTS, 2) and jac.pose.shape == (N_ELLIPSES, N_POINTS, BLOCK)
    np.testing.assert_array_equal(jac.residual, residual(x0))
    # Same steps as block_fd_jacobian (1e-6 shared, 1e-7 per view, relative above 1): the same numbers, only
    # computed one column at a time.
    steps = np.concatenate([1e-6 * np.maximum(1, np.abs(x0[:2])), 1e-7 * np.maximum(1, np.abs(x0[2:]))])
    J = _dense_central_jacobian(residual, x0, steps)
    np.testing.assert_allclose(jac.dense(), J, rtol=0, atol=1e-7 * np.abs(J).max())
    # Off-block entries are exactly zero (a view's centre does not touch another view's rows).
    assert np.all(J[np.abs(jac.dense()) == 0] == 0)
    np.testing.assert_allclose(jac.normal_matrix(), jac.dense().T @ jac.dense(), rtol=1e-12, atol=1e-12)


def test_schur_step_solves_the_damped_normal_equations():
    """The Schur-complement step equals the dense solution of (J^T J + mu D^2) dx = -J^T r."""
    rng = np.random.default_rng(3)
    V, R, k, b = 5, 12, 3, 6
    jac = BlockJacobian(rng.normal(size=V * R), rng.normal(size=(V, R, k)) * [1e3, 1.0, 1e-2],
                        rng.normal(size=(V, R, b)), np.arange(V * R).reshape(V, R))
    U, W, Vb, g_shared, g_pose = jac.normal_equations()
    J = jac.dense()
    g = J.T @ jac.residual
    np.testing.assert_allclose(np.concatenate([g_shared, g_pose.ravel()]), g, rtol=1e-12)
    D = np.sqrt(np.diag(J.T @ J))
    for mu in (1e-12, 1e-3, 10.0):
        dx = _damped_step(U, W, Vb, g_shared, g_pose, D[:k], D[k:].reshape(V, b), mu)
        dense = np.linalg.solve(J.T @ J + mu * np.diag(D ** 2), -g)
        np.testing.assert_allclose(dx, dense, rtol=1e-9, atol=1e-12 * np.abs(dense).max())


def test_same_minimum_as_minpack():
    residual, rows, x_true, x0 = _toy(0.01)
    res = levenberg_marquardt(residual, lambda x: block_fd_jacobian(residual, x, 2, rows, block_size=BLOCK), x0)
    ref = least_squares(residual, x0, method="lm", xtol=1e-15, ftol=1e-15, gtol=1e-15)
    assert res.success, res.status
    assert res.cost == pytest.approx(ref.cost, rel=1e-12)
    # Parameter uncertainties from the reference Jacobian; the two solutions agree to ~1e-6 of them.
    J = ref.jac
    sigma = np.sqrt(np.diag(np.linalg.inv(J.T @ J)) * 2 * ref.cost / (len(ref.fun) - len(x0)))
    assert np.all(np.abs(res.x - ref.x) <= 1e-5 * sigma)
    assert np.all(np.abs(res.x - x_true) <= 5 * sigma)        # and it is the right answer


def test_exact_data_converges_to_zero_residual():
    residual, rows, x_true, x0 = _toy(0.0)
    res = levenberg_marquardt(residual, lambda x: block_fd_jacobian(residual, x, 2, rows, block_size=BLOCK), x0)
    assert res.success, res.status
    np.testing.assert_allclose(res.x, x_true, rtol=0, atol=1e-10)
    assert np.sqrt(2 * res.cost / len(residual(x0))) < 1e-12


def test_non_finite_residuals_reject_the_step():
    """A trial point where the residual is NaN (e.g. a point behind a camera) is rejected, not accepted."""
    residual, rows, x_true, x0 = _toy(0.01)
    calls = []

    def guarded(x):
        calls.append(x[0])
        r = residual(x)
        return r if x[0] > 2.6 else np.full_like(r, np.nan)     # a wall the first (overshooting) step hits

    def jacobian(x):
        return block_fd_jacobian(residual, x, 2, rows, block_size=BLOCK)

    res = levenberg_marquardt(guarded, jacobian, x0 + np.concatenate([[0.5, 0.0], np.zeros(2 * N_ELLIPSES)]))
    assert res.success and np.isfinite(res.cost)
    assert min(calls) <= 2.6                                     # the wall was hit and the solver recovered
    assert res.x[0] == pytest.approx(x_true[0], abs=0.05)
