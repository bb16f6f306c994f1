"""The strain-window sigma's kernel before and after (issue 39): the same sums at the paper's full-resolution grid.

A bending state at full resolution has ~67 000 points on a grid 5 px apart, 65 px subsets and a 15-point strain
window: every node sums the window's 225 points pairwise over four images. Before: every ordered pair, the
correlation looked up per image. After (:func:`measurement.uncertainty.strain._strain_variance`): unordered pairs
with the symmetrised kernel, each point's sigma folded into its weights once, and (issue 39, second step) a
pair's twelve (image, component) terms as one contiguous vectorised loop. Synthetic inputs of that size (the
sums do not depend on where the numbers came from); both kernels run in this process on the same inputs and their
results are compared.

    .venv/bin/python benchmarks/strain_sigma_speed.py [--rows 260 --cols 260]

Run it alone: the machine's 2 cores are the benchmark's.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numba
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))


# the kernel as it was at commit 4ef70b6 (measurement/uncertainty/strain.py), kept here as the "before"
@numba.njit(cache=True, parallel=True)
def _strain_variance_before(index, X, e1g, e2g, node_ok, r, quadratic, rho, D, reach, M, scale, out):
    n_rows, n_cols = index.shape
    n_img = M.shape[0]
    nb = 6 if quadratic else 3
    for node in numba.prange(n_rows * n_cols):
        i0, j0 = node // n_cols, node % n_cols
        out[i0, j0, 0] = out[i0, j0, 1] = out[i0, j0, 2] = np.nan
        if not node_ok[i0, j0]:
            continue
        c = index[i0, j0]
        pts = np.empty(((2 * r + 1) ** 2), dtype=np.int64)
        di_ = np.empty(((2 * r + 1) ** 2), dtype=np.int64)
        dj_ = np.empty(((2 * r + 1) ** 2), dtype=np.int64)
        n = 0
        for a in range(-r, r + 1):
            for b in range(-r, r + 1):
                i, j = i0 + a, j0 + b
                if i < 0 or j < 0 or i >= n_rows or j >= n_cols:
                    continue
                p = index[i, j]
                if p < 0 or not np.isfinite(X[p, 0]) or not np.isfinite(D[p, 0]):
                    continue
                pts[n] = p
                di_[n] = a
                dj_[n] = b
                n += 1
        if n < nb:
            continue
        e1 = e1g[i0, j0]
        e2 = e2g[i0, j0]
        phi = np.empty((n, nb))
        for k in range(n):
            d0 = X[pts[k], 0] - X[c, 0]
            d1 = X[pts[k], 1] - X[c, 1]
            d2 = X[pts[k], 2] - X[c, 2]
            xi = e1[0] * d0 + e1[1] * d1 + e1[2] * d2
            eta = e2[0] * d0 + e2[1] * d1 + e2[2] * d2
            phi[k, 0] = 1.0
            phi[k, 1] = xi
            phi[k, 2] = eta
            if quadratic:
                phi[k, 3] = xi * xi
                phi[k, 4] = xi * eta
                phi[k, 5] = eta * eta
        normal = phi.T @ phi
        weights = np.linalg.solve(normal, phi.T)     # (nb, n): rows 1 and 2 are d/dxi, d/deta at the node
        w1 = weights[1]
        w2 = weights[2]
        var = np.zeros(3)
        beta = np.empty((3, n, 2))
        for img in range(n_img):
            for k in range(n):
                p = pts[k]
                t1x = e1[0] * M[img, p, 0, 0] + e1[1] * M[img, p, 1, 0] + e1[2] * M[img, p, 2, 0]
                t1y = e1[0] * M[img, p, 0, 1] + e1[1] * M[img, p, 1, 1] + e1[2] * M[img, p, 2, 1]
                t2x = e2[0] * M[img, p, 0, 0] + e2[1] * M[img, p, 1, 0] + e2[2] * M[img, p, 2, 0]
                t2y = e2[0] * M[img, p, 0, 1] + e2[1] * M[img, p, 1, 1] + e2[2] * M[img, p, 2, 1]
                s = np.sqrt(scale[img, p])
                beta[0, k, 0], beta[0, k, 1] = s * w1[k] * t1x, s * w1[k] * t1y
                beta[1, k, 0], beta[1, k, 1] = s * w2[k] * t2x, s * w2[k] * t2y
                beta[2, k, 0] = 0.5 * s * (w2[k] * t1x + w1[k] * t2x)
                beta[2, k, 1] = 0.5 * s * (w2[k] * t1y + w1[k] * t2y)
            for k in range(n):
                p = pts[k]
                for l in range(n):
                    a = di_[l] - di_[k]
                    b = dj_[l] - dj_[k]
                    if a < -reach or a > reach or b < -reach or b > reach:
                        continue
                    rr = rho[a + reach, b + reach]
                    if not np.isfinite(rr[0, 0]):
                        continue
                    q = pts[l]
                    c00 = D[p, 0] * rr[0, 0] * D[q, 0]
                    c01 = D[p, 0] * rr[0, 1] * D[q, 1]
                    c10 = D[p, 1] * rr[1, 0] * D[q, 0]
                    c11 = D[p, 1] * rr[1, 1] * D[q, 1]
                    for comp in range(3):
                        var[comp] += (beta[comp, k, 0] * (c00 * beta[comp, l, 0] + c01 * beta[comp, l, 1])
                                      + beta[comp, k, 1] * (c10 * beta[comp, l, 0] + c11 * beta[comp, l, 1]))
        for comp in range(3):
            out[i0, j0, comp] = np.sqrt(max(var[comp], 0.0))


def main(argv=None) -> int:
    from measurement.uncertainty.strain import _strain_variance

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rows", type=int, default=260)
    ap.add_argument("--cols", type=int, default=260)
    ap.add_argument("--window", type=int, default=15)
    ap.add_argument("--reach", type=int, default=12, help="grid steps at which subsets still overlap (64 px / 5 px)")
    args = ap.parse_args(argv)
    rng = np.random.default_rng(0)
    rows, cols, reach, r = args.rows, args.cols, args.reach, args.window // 2
    index = np.arange(rows * cols).reshape(rows, cols)
    gx, gy = np.meshgrid(np.arange(cols) * 0.1, np.arange(rows) * 0.1)
    X = np.column_stack([gx.ravel(), gy.ravel(), 0.001 * gx.ravel() ** 2])
    e1g = np.zeros((rows, cols, 3))
    e1g[..., 0] = 1.0
    e2g = np.zeros((rows, cols, 3))
    e2g[..., 1] = 1.0
    node_ok = np.ones((rows, cols), bool)
    D = rng.uniform(0.01, 0.03, (rows * cols, 2))
    # overlapping subsets' correlation: falling with the offset to ~0 where they stop sharing pixels
    k = np.arange(-reach, reach + 1)
    fall = np.clip(1 - np.abs(k) / (reach + 1), 0, None)
    rho = (fall[:, None] * fall[None, :])[:, :, None, None] * np.array([[1.0, 0.05], [0.05, 1.0]])
    rho = rho + rng.normal(0, 0.01, rho.shape)
    M = rng.normal(0, 0.05, (4, rows * cols, 3, 2))
    scale = rng.uniform(0.5, 1.5, (4, rows * cols))
    small = (index[:20, :20].copy(), X, e1g[:20, :20], e2g[:20, :20], node_ok[:20, :20], r, False, rho, D, reach, M,
             scale)
    for kernel in (_strain_variance_before, _strain_variance):      # compile outside the timing
        kernel(*small, np.empty((20, 20, 3)))
    outs, secs = [], []
    for kernel in (_strain_variance_before, _strain_variance):
        out = np.empty((rows, cols, 3))
        t = time.perf_counter()
        kernel(index, X, e1g, e2g, node_ok, r, False, rho, D, reach, M, scale, out)
        secs.append(time.perf_counter() - t)
        outs.append(out)
    ok = np.isfinite(outs[0]) & (outs[0] > 0)
    rel = float(np.max(np.abs(outs[1][ok] - outs[0][ok]) / np.abs(outs[0][ok])))
    print(f"{rows * cols} nodes, window {args.window}, reach {reach}, 4 images, {numba.get_num_threads()} threads")
    print(f"before: {secs[0]:.2f} s   after: {secs[1]:.2f} s   ({secs[0] / secs[1]:.2f}x); "
          f"largest relative difference {rel:.1e}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
