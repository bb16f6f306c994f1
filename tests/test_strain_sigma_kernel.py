"""The strain-window sigma's kernel against a dense evaluation of the same double sum (a different implementation)."""
from __future__ import annotations

import numpy as np
import pytest


def _dense(index, X, e1g, e2g, node_ok, r, quadratic, rho, D, reach, M, scale):
    """var E per node from the full covariance matrix of the window's displacements (numpy, no pair tricks)."""
    rows, cols = index.shape
    out = np.full((rows, cols, 3), np.nan)
    for i0 in range(rows):
        for j0 in range(cols):
            if not node_ok[i0, j0]:
                continue
            c = index[i0, j0]
            pts, off = [], []
            for a in range(-r, r + 1):
                for b in range(-r, r + 1):
                    i, j = i0 + a, j0 + b
                    if 0 <= i < rows and 0 <= j < cols and index[i, j] >= 0 and np.isfinite(X[index[i, j], 0]) \
                            and np.isfinite(D[index[i, j], 0]):
                        pts.append(index[i, j])
                        off.append((a, b))
            nb = 6 if quadratic else 3
            if len(pts) < nb:
                continue
            pts, off = np.array(pts), np.array(off)
            d = X[pts] - X[c]
            xi, eta = d @ e1g[i0, j0], d @ e2g[i0, j0]
            phi = np.column_stack([np.ones_like(xi), xi, eta] + ([xi * xi, xi * eta, eta * eta] if quadratic else []))
            w = np.linalg.pinv(phi)                       # least-squares weights, (nb, n)
            n = len(pts)
            C = np.zeros((2 * n, 2 * n))
            for k in range(n):
                for m in range(n):
                    a, b = off[m] - off[k]
                    if abs(a) > reach or abs(b) > reach or not np.isfinite(rho[a + reach, b + reach, 0, 0]):
                        continue
                    C[2 * k:2 * k + 2, 2 * m:2 * m + 2] = np.diag(D[pts[k]]) @ rho[a + reach, b + reach] @ np.diag(D[pts[m]])
            var = np.zeros(3)
            e1, e2 = e1g[i0, j0], e2g[i0, j0]
            for img in range(M.shape[0]):
                T1 = np.einsum("i,kij->kj", e1, M[img, pts]) * np.sqrt(scale[img, pts])[:, None]
                T2 = np.einsum("i,kij->kj", e2, M[img, pts]) * np.sqrt(scale[img, pts])[:, None]
                for comp, beta in enumerate((w[1][:, None] * T1, w[2][:, None] * T2,
                                             0.5 * (w[2][:, None] * T1 + w[1][:, None] * T2))):
                    bvec = beta.ravel()
                    var[comp] += bvec @ C @ bvec
            out[i0, j0] = np.sqrt(np.maximum(var, 0.0))
    return out


@pytest.mark.parametrize("quadratic", [False, True])
def test_strain_variance_kernel_equals_the_dense_double_sum(quadratic):
    """A 10 x 11 grid with holes, a curved surface, random per-point sigmas, an asymmetric correlation kernel with
    unknown offsets and two images: every node's sigma equal to the dense evaluation to 1e-10 (relative)."""
    from measurement.uncertainty.strain import _strain_variance

    rng = np.random.default_rng(3)
    rows, cols, reach, r = 10, 11, 4, 3
    index = np.arange(rows * cols).reshape(rows, cols)
    index[2, 3] = index[7, 8] = -1                                  # holes in the grid
    gx, gy = np.meshgrid(np.arange(cols) * 0.5, np.arange(rows) * 0.5)
    X = np.column_stack([gx.ravel(), gy.ravel(), 0.02 * (gx.ravel() - 2) ** 2])
    X[5] = np.nan                                                   # a point with no position
    e1g = np.zeros((rows, cols, 3))
    e1g[..., 0] = 1.0
    e2g = np.zeros((rows, cols, 3))
    e2g[..., 1] = 1.0
    node_ok = (index >= 0) & np.isfinite(X[np.maximum(index, 0), 0])   # as strain_sigma: a node with a strain
    D = rng.uniform(0.01, 0.03, (rows * cols, 2))
    D[17] = np.nan
    rho = rng.normal(0, 0.3, (2 * reach + 1, 2 * reach + 1, 2, 2))
    rho[reach, reach] = [[1.0, 0.2], [0.2, 1.0]]
    rho[0, 1] = np.nan                                              # an offset whose correlation is unknown ...
    rho[1, 3] = rho[-2, -4] = np.nan                                # ... and one unknown both ways
    M = rng.normal(0, 0.05, (2, rows * cols, 3, 2))
    scale = rng.uniform(0.5, 1.5, (2, rows * cols))
    out = np.full((rows, cols, 3), np.nan)
    _strain_variance(index, X, e1g, e2g, node_ok, r, quadratic, rho, D, reach, M, scale, out)
    ref = _dense(index, X, e1g, e2g, node_ok, r, quadratic, rho, D, reach, M, scale)
    assert np.isfinite(ref).sum() > 250
    np.testing.assert_array_equal(np.isfinite(out), np.isfinite(ref))
    np.testing.assert_allclose(out[np.isfinite(ref)], ref[np.isfinite(ref)], rtol=1e-10)
