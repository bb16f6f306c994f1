"""Random uncertainty of window strain: the windowed fit's weights over displacements whose errors correlate.

A strain-window value (:func:`measurement.strain.surface_strain`, ``window=k``) is, to first order, a weighted sum
of the window's displacements: with ``(xi, eta)`` the in-plane coordinates of the window points about the node and
``w1, w2`` the least-squares weights of ``d/dxi``, ``d/deta`` at the node (design ``1, xi, eta`` or also
``xi^2, xi eta, eta^2``),

    E11 = sum_p w1_p e1 . U_p,   E22 = sum_p w2_p e2 . U_p,   E12 = 1/2 sum_p (w2_p e1 + w1_p e2) . U_p.

Neighbouring points' displacement errors are *not* independent: their subsets overlap (step < subset) and share
the noise of the same pixels. Each image's noise moves a point's match by ``A_p(x) = uv_rows_p J_p(x)`` per grey
level at pixel ``x`` of its subset (:class:`measurement.uncertainty.match.ReferenceSubsets`), so two points share

    C_pq = sum over their common pixels of A_p(x) A_q(x)^T sigma^2(x)          (2 x 2, px^2)

(:func:`pair_covariances`, once per reference). Computing it for every pair costs ~10^2 s at the paper's subset and
step, so it is computed exactly for a sample of points spread over the grid and kept as a correlation per grid
offset, ``C_pq = D_p rho(q - p) D_q`` with ``D`` each point's own standard deviations (exact) and ``rho`` the
sample's median correlation at that offset (the texture's statistics do not change across a speckle pattern).
Each image enters a displacement through its own 3 x 2 block of
the triangulation sensitivities (:mod:`measurement.uncertainty.stereo`: the left reference image through
``G_L + G_R - G_R^ref``, the right reference through ``-G_R^ref``, the deformed images through ``G_L``, ``G_R``);
the target images' noise is counted in the reference's pixel layout, scaled by each point's target-to-reference
variance ratio (which holds the interpolant's noise gain). Then ``var E = sum_images sum_p sum_q b_p^T C_pq b_q``.

The triangle (Cosserat) method has no such fit: its sigma is not computed here (NaN).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numba
import numpy as np

from measurement.dic.correlate import PreparedImage

from .match import ReferenceSubsets


@dataclass(frozen=True)
class PairCovariances:
    """Covariances of the (u, v) match errors of neighbouring grid points from one image's noise.

    Attributes
    ----------
    reach : int
        R: neighbours up to R grid steps away in each direction share pixels.
    rho : ndarray (2R + 1, 2R + 1, 2, 2)
        ``rho[R + di, R + dj]``: correlation of a point's (u, v) error with that of the point (di, dj) grid steps
        away (module notes).
    D : ndarray (N, 2)
        Each point's standard deviation of u and v from the reference image's noise, px (NaN where none).
    index : ndarray of int64 (rows, cols)
        Point index of every grid node, -1 where none.
    sampled : int
        Points the correlations were computed on.
    overlap_reach : int
        The farthest offset (grid steps) at which subsets still share pixels; ``reach`` may be less when the
        covariances were computed for a smaller strain window.
    """

    reach: int
    rho: np.ndarray = field(repr=False)
    D: np.ndarray = field(repr=False)
    index: np.ndarray = field(repr=False)
    sampled: int = 0
    overlap_reach: int = 0

    def covariance(self, p: int, q: int, di: int, dj: int) -> np.ndarray:
        """C_pq (2, 2) px^2 for points p and q = p + (di, dj) grid steps."""
        return self.D[p][:, None] * self.rho[self.reach + di, self.reach + dj] * self.D[q][None, :]


@numba.njit(cache=True, inline="always")
def _monomials(dx, dy, order, out):
    out[0] = 1.0
    out[1] = dx
    out[2] = dy
    if order == 2:
        out[3] = 0.5 * dx * dx
        out[4] = dx * dy
        out[5] = 0.5 * dy * dy


@numba.njit(cache=True, parallel=True)
def _pairs(gx, gy, variance, xs, ys, rows_uv, half, order, index, gi, gj, reach, sample, out):
    nm = 3 if order == 1 else 6
    n_rows, n_cols = index.shape
    for s in numba.prange(sample.size):
        p = sample[s]
        mp = np.empty(6)
        mq = np.empty(6)
        if not np.isfinite(rows_uv[p, 0, 0]):
            continue
        for a in range(2 * reach + 1):
            for b in range(2 * reach + 1):
                i, j = gi[p] + a - reach, gj[p] + b - reach
                if i < 0 or j < 0 or i >= n_rows or j >= n_cols:
                    continue
                q = index[i, j]
                if q < 0 or not np.isfinite(rows_uv[q, 0, 0]):
                    continue
                ox, oy = xs[q] - xs[p], ys[q] - ys[p]
                x0, x1 = max(-half, ox - half), min(half, ox + half)
                y0, y1 = max(-half, oy - half), min(half, oy + half)
                c00 = c01 = c10 = c11 = 0.0
                for dy in range(y0, y1 + 1):
                    for dx in range(x0, x1 + 1):
                        X, Y = xs[p] + dx, ys[p] + dy
                        fx, fy, w = gx[Y, X], gy[Y, X], variance[Y, X]
                        _monomials(float(dx), float(dy), order, mp)
                        _monomials(float(dx - ox), float(dy - oy), order, mq)
                        pu = pv = qu = qv = 0.0
                        for k in range(nm):
                            pu += (rows_uv[p, 0, k] * fx + rows_uv[p, 0, nm + k] * fy) * mp[k]
                            pv += (rows_uv[p, 1, k] * fx + rows_uv[p, 1, nm + k] * fy) * mp[k]
                            qu += (rows_uv[q, 0, k] * fx + rows_uv[q, 0, nm + k] * fy) * mq[k]
                            qv += (rows_uv[q, 1, k] * fx + rows_uv[q, 1, nm + k] * fy) * mq[k]
                        c00 += w * pu * qu
                        c01 += w * pu * qv
                        c10 += w * pv * qu
                        c11 += w * pv * qv
                out[s, a, b, 0, 0] = c00
                out[s, a, b, 0, 1] = c01
                out[s, a, b, 1, 0] = c10
                out[s, a, b, 1, 1] = c11


def pair_covariances(reference: PreparedImage, subsets: ReferenceSubsets, grid_index: np.ndarray,
                     grid_shape: tuple[int, int], step_px: int, *, window: int | None = None,
                     sample: int = 64, seed: int = 0) -> PairCovariances:
    """:class:`PairCovariances` of a reference's subsets on their grid (module notes).

    Parameters
    ----------
    reference : PreparedImage (with gradients)
    subsets : ReferenceSubsets of the same points
    grid_index : ndarray (N, 2)
        (row, col) of each point in the grid; grid_shape : (rows, cols); step_px : the grid step.
    window : int, optional
        The strain window the covariances are for: offsets beyond ``window - 1`` steps are not needed.
    sample : int
        Points the correlations are computed on (drawn with ``seed`` among those with a sigma).
    """
    half = subsets.subset_size // 2
    reach = overlap = min((2 * half) // int(step_px), max(grid_shape) - 1)
    if window is not None:
        reach = min(reach, int(window) - 1)
    index = np.full(grid_shape, -1, dtype=np.int64)
    gi = np.asarray(grid_index[:, 0], dtype=np.int64)
    gj = np.asarray(grid_index[:, 1], dtype=np.int64)
    index[gi, gj] = np.arange(gi.size)
    values = reference.values
    variance = subsets.noise_reference.sigma_at(np.where(np.isfinite(values), values, 0.0)) ** 2
    rows = np.ascontiguousarray(np.where(subsets.ok[:, None, None], subsets.uv_rows, np.nan))
    D = np.sqrt(np.einsum("kii->ki", subsets.cov_uv_reference))
    candidates = np.flatnonzero(subsets.ok & np.all(np.isfinite(D), axis=1))
    if candidates.size == 0:
        raise ValueError("no point has a sigma: the strain's sigma cannot be computed")
    chosen = np.sort(np.random.default_rng(seed).choice(candidates, min(int(sample), candidates.size), replace=False))
    C = np.full((chosen.size, 2 * reach + 1, 2 * reach + 1, 2, 2), np.nan)
    _pairs(reference.spline.grad_x, reference.spline.grad_y, variance, subsets.x, subsets.y, rows, half,
           subsets.order, index, gi, gj, reach, chosen.astype(np.int64), C)
    # normalise by both points' own standard deviations; the median over the sample per offset
    rho = np.full((2 * reach + 1, 2 * reach + 1, 2, 2), np.nan)
    Dp = D[chosen]
    for a in range(2 * reach + 1):
        for b in range(2 * reach + 1):
            i, j = gi[chosen] + a - reach, gj[chosen] + b - reach
            inside = (i >= 0) & (j >= 0) & (i < grid_shape[0]) & (j < grid_shape[1])
            q = np.full(chosen.size, -1)
            q[inside] = index[i[inside], j[inside]]
            ok = (q >= 0) & np.all(np.isfinite(C[:, a, b].reshape(-1, 4)), axis=1)
            if ok.sum() == 0:
                continue
            Dq = D[q[ok]]
            r = C[ok, a, b] / (Dp[ok][:, :, None] * Dq[:, None, :])
            rho[a, b] = np.median(r, axis=0)
    return PairCovariances(reach, rho, D, index, int(chosen.size), overlap)


@numba.njit(cache=True)
def _symmetric_kernel(rho):
    """``S(d) = rho(d) + rho(-d)^T`` over the offsets (rows, cols, 2, 2): a pair's two terms of the double sum in one
    (``b_p^T C_pq b_q + b_q^T C_qp b_p`` with ``C_pq = D_p rho(q - p) D_q``); an unknown correlation counts 0, NaN
    where both are unknown."""
    n0, n1 = rho.shape[0], rho.shape[1]
    S = np.full(rho.shape, np.nan)
    for a in range(n0):
        for b in range(n1):
            f = rho[a, b]
            g = rho[n0 - 1 - a, n1 - 1 - b]
            if np.isfinite(f[0, 0]) or np.isfinite(g[0, 0]):
                for u in range(2):
                    for v in range(2):
                        S[a, b, u, v] = ((f[u, v] if np.isfinite(f[0, 0]) else 0.0)
                                         + (g[v, u] if np.isfinite(g[0, 0]) else 0.0))
    return S


# reassociation (vectorised sums), not 'nnan'/'ninf': the kernel tests finiteness
@numba.njit(cache=True, parallel=True, fastmath={"reassoc", "contract", "nsz", "arcp"})
def _strain_variance(index, X, e1g, e2g, node_ok, r, quadratic, rho, D, reach, M, scale, out):
    # var E = sum_images sum_p sum_q g_p^T rho(q - p) g_q with g = D * b (each point's weights times its own
    # standard deviations); the double sum runs over unordered pairs with the symmetrised kernel, so every pair's
    # kernel is looked up once for all images and components
    n_rows, n_cols = index.shape
    n_img = M.shape[0]
    nb = 6 if quadratic else 3
    S = _symmetric_kernel(rho)
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
        g = np.empty((n, n_img, 3, 2))                 # per point, image, component: D * b
        for k in range(n):
            p = pts[k]
            for img in range(n_img):
                t1x = e1[0] * M[img, p, 0, 0] + e1[1] * M[img, p, 1, 0] + e1[2] * M[img, p, 2, 0]
                t1y = e1[0] * M[img, p, 0, 1] + e1[1] * M[img, p, 1, 1] + e1[2] * M[img, p, 2, 1]
                t2x = e2[0] * M[img, p, 0, 0] + e2[1] * M[img, p, 1, 0] + e2[2] * M[img, p, 2, 0]
                t2y = e2[0] * M[img, p, 0, 1] + e2[1] * M[img, p, 1, 1] + e2[2] * M[img, p, 2, 1]
                sx = np.sqrt(scale[img, p]) * D[p, 0]
                sy = np.sqrt(scale[img, p]) * D[p, 1]
                g[k, img, 0, 0], g[k, img, 0, 1] = sx * w1[k] * t1x, sy * w1[k] * t1y
                g[k, img, 1, 0], g[k, img, 1, 1] = sx * w2[k] * t2x, sy * w2[k] * t2y
                g[k, img, 2, 0] = 0.5 * sx * (w2[k] * t1x + w1[k] * t2x)
                g[k, img, 2, 1] = 0.5 * sy * (w2[k] * t1y + w1[k] * t2y)
        # the (image, component) terms of a pair as one contiguous innermost loop (x and y parts apart): it
        # vectorises; indexed in place (a row view per pair costs an atomic reference count)
        lanes = 3 * n_img
        gx = np.empty((n, lanes))
        gy = np.empty((n, lanes))
        for k in range(n):
            for img in range(n_img):
                for comp in range(3):
                    gx[k, 3 * img + comp] = g[k, img, comp, 0]
                    gy[k, 3 * img + comp] = g[k, img, comp, 1]
        acc = np.zeros(lanes)
        r0 = rho[reach, reach]
        if np.isfinite(r0[0, 0]):
            q00, q01, q10, q11 = r0[0, 0], r0[0, 1], r0[1, 0], r0[1, 1]
            for k in range(n):
                for q in range(lanes):
                    x = gx[k, q]
                    y = gy[k, q]
                    acc[q] += x * (q00 * x + q01 * y) + y * (q10 * x + q11 * y)
        for k in range(n):
            for l in range(k + 1, n):
                a = di_[l] - di_[k]
                b = dj_[l] - dj_[k]
                if a < -reach or a > reach or b < -reach or b > reach:
                    continue
                ia, ib = a + reach, b + reach
                s00 = S[ia, ib, 0, 0]
                if not np.isfinite(s00):
                    continue
                s01, s10, s11 = S[ia, ib, 0, 1], S[ia, ib, 1, 0], S[ia, ib, 1, 1]
                for q in range(lanes):
                    u = gx[l, q]
                    v = gy[l, q]
                    acc[q] += gx[k, q] * (s00 * u + s01 * v) + gy[k, q] * (s10 * u + s11 * v)
        for comp in range(3):
            var = 0.0
            for img in range(n_img):
                var += acc[3 * img + comp]
            out[i0, j0, comp] = np.sqrt(max(var, 0.0))


def strain_sigma(pairs: PairCovariances, strain, X_ref_mm: np.ndarray, blocks: list[tuple[np.ndarray, np.ndarray]],
                 rotation=None) -> np.ndarray:
    """Standard uncertainty of E11, E22, E12 at every node of a window strain, (rows, cols, 3).

    Parameters
    ----------
    pairs : PairCovariances of the reference's grid
    strain : measurement.strain.SurfaceStrain with ``method == "window"`` (its frames and window are used)
    X_ref_mm : ndarray (N, 3)
        Reference positions of the grid's points (the frame the strain was computed in).
    blocks : list of (M (N, 3, 2), scale (N,))
        Per image: how a pixel error of each point moves its displacement (mm/px), and the image's noise
        variance relative to the reference's in the pairs (1 for the reference itself).
    rotation : ndarray (3, 3), optional
        The rotation that took the measured positions (the blocks' frame, the left camera's) to the frame the
        strain was computed in (e.g. after a rigid alignment); ``X_ref_mm`` is in the strain's frame.

    Raises
    ------
    ValueError
        A strain of the triangle method (no windowed fit).
    """
    if strain.method != "window":
        raise ValueError("strain sigma needs the strain-window method (window=k); the triangle method has no "
                         "windowed fit")
    if pairs.reach < min(strain.window - 1, pairs.overlap_reach):
        raise ValueError(f"the pair covariances reach {pairs.reach} grid steps, but this {strain.window}-point strain "
                         f"window holds points up to {min(strain.window - 1, pairs.overlap_reach)} steps apart whose "
                         "subsets overlap: compute them for this window")
    M = np.stack([b[0] for b in blocks])
    if rotation is not None:
        M = np.einsum("ij,knjb->knib", np.asarray(rotation, dtype=np.float64), M)
    M = np.ascontiguousarray(M, dtype=np.float64)
    scale = np.ascontiguousarray(np.stack([np.where(np.isfinite(b[1]), b[1], 0.0) for b in blocks]), dtype=np.float64)
    node_ok = np.isfinite(strain.E11) & (pairs.index >= 0)
    out = np.full(pairs.index.shape + (3,), np.nan)
    _strain_variance(pairs.index, np.ascontiguousarray(X_ref_mm, dtype=np.float64),
                     np.ascontiguousarray(np.nan_to_num(strain.e1)), np.ascontiguousarray(np.nan_to_num(strain.e2)),
                     node_ok, strain.window // 2, strain.fit == "quadratic", np.ascontiguousarray(pairs.rho),
                     np.ascontiguousarray(pairs.D), pairs.reach, M, scale, out)
    return out


def _ratio(target: np.ndarray, reference: np.ndarray) -> np.ndarray:
    with np.errstate(invalid="ignore", divide="ignore"):
        return 0.5 * (target[:, 0, 0] / reference[:, 0, 0] + target[:, 1, 1] / reference[:, 1, 1])


def state_strain_sigma(shape, state, strain, G_ref: np.ndarray, G_def: np.ndarray, pairs: PairCovariances, *,
                       X_ref_mm: np.ndarray | None = None, rotation=None) -> np.ndarray:
    """:func:`strain_sigma` of a stereo state (:mod:`measurement.stereo_dic`): the four images' blocks.

    ``G_ref``, ``G_def``: (N, 3, 4) triangulation sensitivities at the reference and deformed points
    (:func:`measurement.uncertainty.stereo.triangulation_sensitivity`). ``X_ref_mm``/``rotation``: the reference
    positions in the strain's frame and the rotation to it, when the strain was computed after an alignment.
    """
    GL, GR, GRref = G_def[:, :, :2], G_def[:, :, 2:], G_ref[:, :, 2:]
    # the pairs' own standard deviations are the left reference's part of a repeat of its view (H0): every block is
    # scaled relative to it (the stereo match's cross-Hessian enters through its target part's ratio)
    ref = shape.subsets.cov_uv_reference
    blocks = [(GL + GR - GRref, np.ones(ref.shape[0])),
              (-GRref, _ratio(shape.match_uncertainty.cov_target_px2, ref)),
              (GL, _ratio(state.left_uncertainty.cov_target_px2, ref)),
              (GR, _ratio(state.right_uncertainty.cov_target_px2, ref))]
    blocks = [(np.nan_to_num(m), s) for m, s in blocks]
    return strain_sigma(pairs, strain, shape.X_mm if X_ref_mm is None else X_ref_mm, blocks, rotation)
