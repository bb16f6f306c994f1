"""Inverse-compositional Gauss-Newton (IC-GN) subset matching with the ZNSSD criterion (numba).

For a square reference subset of ``(2M + 1)^2`` pixels centred on an integer point of interest, IC-GN
(Baker & Matthews 2004; Pan, Li & Tong 2013, "Fast, robust and accurate digital image correlation
calculation without redundant computations", Exp. Mech. 53, 1277-1289) minimises

    C(dp) = sum [ (f(W(xi; dp)) - f_m) / Df  -  (g(W(xi; p)) - g_m) / Dg ]^2         (ZNSSD)

over the increment ``dp`` applied to the *reference* subset, then updates ``W(p) <- W(p) o W(dp)^-1``.
Because the increment lives on the reference side, the Jacobian ``J = grad f . dW/dp`` and the Hessian
``H = sum J^T J`` are computed once per point; an iteration costs one interpolation of the deformed image per
subset pixel. The Gauss-Newton step is

    dp = -H^-1 sum J^T [ (f - f_m) - (Df / Dg) (g - g_m) ],

and since ``sum J^T (f - f_m)`` and ``sum J^T`` are also constants, one pass over the subset that accumulates
``sum g``, ``sum g^2``, ``sum f g`` and ``sum J^T g`` gives both the step and the ZNCC of the current warp.

Convergence: the increment, expressed as the largest displacement it causes anywhere on the subset edge
(``|du| + M |dux| + M |duy| + M^2/2 (|duxx| + 2|duxy| + |duyy|)``, same for v, combined in quadrature), falls
below ``tolerance_px``.

Reference gradients are those of the B-spline interpolant at the pixel centres (:mod:`.bspline`), so the
linearisation matches the interpolant the deformed image is sampled with.

Precision: the deformed image is sampled in single precision (float32 coefficients and weights, 8 AVX2 lanes;
~1e-5 grey, a few 1e-8 px on the bias curves); the reference subset, the Hessian and every sum of the step and
the ZNCC are double precision.
"""
from __future__ import annotations

import numba
import numpy as np

from .bspline import cubic_weights_f32, quintic_weights_f32
from .shape_functions import compose_inverse
from .status import (CONVERGED, DIVERGED, INVALID_IMAGE, LOW_CORRELATION, LOW_TEXTURE, MAX_ITERATIONS,
                     OUT_OF_IMAGE)

#: Largest |u| or |v| update (px) accepted in one iteration before the point is declared diverged.
MAX_STEP_PX = 50.0


# ---------------------------------------------------------------------------------------------------------
# Reference subset: zero-mean values, gradients, Hessian (inverted once), constant parts of the step.
# ---------------------------------------------------------------------------------------------------------

@numba.njit(cache=True)
def _cholesky_inverse(h, out):
    """Inverse of a symmetric positive-definite matrix via Jacobi-scaled Cholesky; False if not SPD."""
    n = h.shape[0]
    d = np.empty(n)
    for i in range(n):
        if not h[i, i] > 0.0:
            return False
        d[i] = 1.0 / np.sqrt(h[i, i])
    a = np.empty((n, n))
    for i in range(n):
        for j in range(n):
            a[i, j] = h[i, j] * d[i] * d[j]
    lower = np.zeros((n, n))
    for j in range(n):
        s = a[j, j]
        for k in range(j):
            s -= lower[j, k] * lower[j, k]
        # A relative pivot this small means the subset cannot constrain this parameter combination.
        if s <= 1e-10:
            return False
        lower[j, j] = np.sqrt(s)
        for i in range(j + 1, n):
            s = a[i, j]
            for k in range(j):
                s -= lower[i, k] * lower[j, k]
            lower[i, j] = s / lower[j, j]
    # inverse of lower, then A^-1 = L^-T L^-1
    linv = np.zeros((n, n))
    for i in range(n):
        linv[i, i] = 1.0 / lower[i, i]
        for j in range(i):
            s = 0.0
            for k in range(j, i):
                s -= lower[i, k] * linv[k, j]
            linv[i, j] = s / lower[i, i]
    for i in range(n):
        for j in range(n):
            s = 0.0
            for k in range(max(i, j), n):
                s += linv[k, i] * linv[k, j]
            out[i, j] = s * d[i] * d[j]
    return True


#: Monomials of the shape-function Jacobian, (power of dx, power of dy, factor), in parameter order
#: (u, ux, uy, uxx, uxy, uyy); the first three make the first-order shape function.
MONOMIALS = np.array([[0, 0, 1.0], [1, 0, 1.0], [0, 1, 1.0], [2, 0, 0.5], [1, 1, 1.0], [0, 2, 0.5]])


@numba.njit(cache=True, fastmath=True)
def _copy_row(image_flat, gx_flat, gy_flat, start, n, mean, f, fx, fy, k0):
    """Copy one subset row (``n`` pixels from flat index ``start``) into the buffers (values minus ``mean``,
    gradients); return its sum of squares. Flat arrays and unsigned offsets: no per-row views of the shared
    images (each view is an atomic reference count that the threads would fight over), no wrap-around code."""
    base = np.uint64(start)
    k = np.uint64(k0)
    sum_sq = 0.0
    for c in range(np.uint64(n)):
        value = image_flat[base + c] - mean
        f[k + c] = value
        fx[k + c] = gx_flat[base + c]
        fy[k + c] = gy_flat[base + c]
        sum_sq += value * value
    return sum_sq


@numba.njit(cache=True, fastmath=True)
def _moments3(p, q, k0, dxs):
    """sum p q dx^j, j = 0..2, over one row (``p[k0:k0 + len(dxs)]``)."""
    k = np.uint64(k0)
    m0 = m1 = m2 = 0.0
    for c in range(np.uint64(dxs.shape[0])):
        pq = p[k + c] * q[k + c]
        d = dxs[c]
        m0 += pq
        m1 += pq * d
        m2 += pq * d * d
    return m0, m1, m2


@numba.njit(cache=True, fastmath=True)
def _moments5(p, q, k0, dxs):
    """sum p q dx^j, j = 0..4, over one row."""
    k = np.uint64(k0)
    m0 = m1 = m2 = m3 = m4 = 0.0
    for c in range(np.uint64(dxs.shape[0])):
        pq = p[k + c] * q[k + c]
        d = dxs[c]
        d2 = d * d
        m0 += pq
        m1 += pq * d
        m2 += pq * d2
        m3 += pq * d2 * d
        m4 += pq * d2 * d2
    return m0, m1, m2, m3, m4


@numba.njit(cache=True, fastmath=True)
def _sums3(p, k0, dxs):
    """sum p dx^j, j = 0..2, over one row."""
    k = np.uint64(k0)
    m0 = m1 = m2 = 0.0
    for c in range(np.uint64(dxs.shape[0])):
        value = p[k + c]
        d = dxs[c]
        m0 += value
        m1 += value * d
        m2 += value * d * d
    return m0, m1, m2


@numba.njit(cache=True, fastmath=True)
def _subset_mean(image_flat, corner, cols, n):
    """Mean grey level of the ``n`` x ``n`` subset whose first pixel is flat index ``corner`` (one function, so
    the cached and the fresh reference paths subtract the very same number)."""
    total = 0.0
    for r in range(n):
        base = np.uint64(corner + r * cols)
        for c in range(np.uint64(n)):
            total += image_flat[base + c]
    return total / (n * n)


@numba.njit(cache=True, fastmath=True)
def copy_subset(image, grad_x, grad_y, x0, y0, half, mean, f, fx, fy):
    """The subset's values minus ``mean`` and its gradients into ``f``, ``fx``, ``fy`` (row-major), as
    :func:`prepare_reference` leaves them: what IC-GN reads when the rest of the reference side is cached."""
    cols = image.shape[1]
    n = 2 * half + 1
    corner = (y0 - half) * cols + x0 - half
    image_flat = image.reshape(-1)
    gx_flat = grad_x.reshape(-1)
    gy_flat = grad_y.reshape(-1)
    k = 0
    for r in range(n):
        _copy_row(image_flat, gx_flat, gy_flat, corner + r * cols, n, mean, f, fx, fy, k)
        k += n


@numba.njit(cache=True, fastmath=True)
def prepare_reference(image, grad_x, grad_y, x0, y0, half, order, min_std, f, fx, fy, hinv, a, s):
    """Precompute everything IC-GN needs from one reference subset.

    The Hessian ``H = sum J^T J`` has entries ``sum g_i g_j m_i m_j`` with ``g`` in {f_x, f_y} and ``m`` the
    monomials of the shape function, so it is assembled from the moments ``sum g_i g_j dx^a dy^b``
    (a + b <= 4), accumulated row by row; likewise ``sum J^T (f - f_m)`` and ``sum J^T``.

    Parameters
    ----------
    image, grad_x, grad_y : ndarray of float64, shape (rows, cols)
        Reference image and its interpolant's gradients at pixel centres.
    x0, y0 : int
        Point of interest (column, row), px.
    half : int
        M; the subset is (2M + 1) x (2M + 1).
    order : int
        1 or 2.
    min_std : float
        Smallest accepted standard deviation of the subset's grey levels.
    f, fx, fy : ndarray of float64, shape ((2M+1)^2,)
        Out: zero-mean subset values and gradients, row-major.
    hinv : ndarray, shape (np, np)
        Out: inverse Hessian (np = 6 or 12: the parameters of :data:`MONOMIALS` for x, then for y).
    a, s : ndarray, shape (np,)
        Out: sum J^T (f - f_m) and sum J^T.

    Returns
    -------
    status : int
    delta_f : float
        sqrt(sum (f - f_m)^2).
    sssig_x, sssig_y : float
        Sum of squared subset intensity gradients (Pan 2008), grey^2 / px^2.
    """
    rows, cols = image.shape
    if x0 - half < 0 or y0 - half < 0 or x0 + half >= cols or y0 + half >= rows:
        return OUT_OF_IMAGE, 0.0, 0.0, 0.0
    n = 2 * half + 1
    image_flat = image.reshape(-1)
    gx_flat = grad_x.reshape(-1)
    gy_flat = grad_y.reshape(-1)
    corner = (y0 - half) * cols + x0 - half
    mean = _subset_mean(image_flat, corner, cols, n)
    if not np.isfinite(mean):
        return INVALID_IMAGE, 0.0, 0.0, 0.0
    # moments[k, a, b]: k = 0 fx fx, 1 fx fy, 2 fy fy, 3 fx f, 4 fy f, 5 fx, 6 fy
    moments = np.zeros((7, 5, 5))
    dy_powers = np.empty(5)
    sum_sq = 0.0
    k = 0
    dxs = np.arange(-half, half + 1).astype(np.float64)
    for r in range(n):
        dy = float(r - half)
        row_sq = _copy_row(image_flat, gx_flat, gy_flat, corner + r * cols, n, mean, f, fx, fy, k)
        # Separate short reductions (3-5 accumulators each) vectorise; one fused loop spills its ~20.
        if order == 1:
            xx0, xx1, xx2 = _moments3(fx, fx, k, dxs)
            xy0, xy1, xy2 = _moments3(fx, fy, k, dxs)
            yy0, yy1, yy2 = _moments3(fy, fy, k, dxs)
            xx3 = xx4 = xy3 = xy4 = yy3 = yy4 = 0.0
        else:
            xx0, xx1, xx2, xx3, xx4 = _moments5(fx, fx, k, dxs)
            xy0, xy1, xy2, xy3, xy4 = _moments5(fx, fy, k, dxs)
            yy0, yy1, yy2, yy3, yy4 = _moments5(fy, fy, k, dxs)
        xf0, xf1, xf2 = _moments3(fx, f, k, dxs)
        yf0, yf1, yf2 = _moments3(fy, f, k, dxs)
        x0_, x1_, x2_ = _sums3(fx, k, dxs)
        y0_, y1_, y2_ = _sums3(fy, k, dxs)
        k += n
        sum_sq += row_sq
        dy_powers[0] = 1.0
        for b in range(1, 5):
            dy_powers[b] = dy_powers[b - 1] * dy
        for b in range(3 if order == 1 else 5):   # the first order needs moments up to degree 2 only
            w = dy_powers[b]
            if b <= 4:
                moments[0, 0, b] += xx0 * w
                moments[1, 0, b] += xy0 * w
                moments[2, 0, b] += yy0 * w
            if b <= 3:
                moments[0, 1, b] += xx1 * w
                moments[1, 1, b] += xy1 * w
                moments[2, 1, b] += yy1 * w
            if b <= 2:
                moments[0, 2, b] += xx2 * w
                moments[1, 2, b] += xy2 * w
                moments[2, 2, b] += yy2 * w
                moments[3, 0, b] += xf0 * w
                moments[4, 0, b] += yf0 * w
                moments[5, 0, b] += x0_ * w
                moments[6, 0, b] += y0_ * w
            if b <= 1:
                moments[0, 3, b] += xx3 * w
                moments[1, 3, b] += xy3 * w
                moments[2, 3, b] += yy3 * w
                moments[3, 1, b] += xf1 * w
                moments[4, 1, b] += yf1 * w
                moments[5, 1, b] += x1_ * w
                moments[6, 1, b] += y1_ * w
            if b == 0:
                moments[0, 4, b] += xx4 * w
                moments[1, 4, b] += xy4 * w
                moments[2, 4, b] += yy4 * w
                moments[3, 2, b] += xf2 * w
                moments[4, 2, b] += yf2 * w
                moments[5, 2, b] += x2_ * w
                moments[6, 2, b] += y2_ * w
    sssig_x = moments[0, 0, 0]
    sssig_y = moments[2, 0, 0]
    nm = 3 if order == 1 else 6
    npar = 2 * nm
    h = np.empty((npar, npar))
    for ci in range(2):
        for i in range(nm):
            ai = int(MONOMIALS[i, 0])
            bi = int(MONOMIALS[i, 1])
            wi = MONOMIALS[i, 2]
            a[ci * nm + i] = wi * moments[3 + ci, ai, bi]
            s[ci * nm + i] = wi * moments[5 + ci, ai, bi]
            for cj in range(2):
                kind = ci + cj   # 0 xx, 1 xy, 2 yy
                for j in range(nm):
                    h[ci * nm + i, cj * nm + j] = wi * MONOMIALS[j, 2] * moments[
                        kind, ai + int(MONOMIALS[j, 0]), bi + int(MONOMIALS[j, 1])]
    std = np.sqrt(sum_sq / (n * n))
    if not std >= min_std:
        return LOW_TEXTURE, 0.0, sssig_x, sssig_y
    if not _cholesky_inverse(h, hinv):
        return LOW_TEXTURE, 0.0, sssig_x, sssig_y
    return CONVERGED, np.sqrt(sum_sq), sssig_x, sssig_y


# ---------------------------------------------------------------------------------------------------------
# Iterations
# ---------------------------------------------------------------------------------------------------------

@numba.njit(inline="always")
def _quadratic_range(a, b, c, half):
    """Min and max of ``a + b t + c t^2`` over t in [-half, half]."""
    m = float(half)
    lo_value = a - b * m + c * m * m
    hi_value = a + b * m + c * m * m
    low = min(lo_value, hi_value)
    high = max(lo_value, hi_value)
    if c != 0.0:
        t = -b / (2.0 * c)
        if -m < t < m:
            vertex = a + b * t + c * t * t
            low = min(low, vertex)
            high = max(high, vertex)
    return low, high


@numba.njit(inline="always")
def _warp_row(ax, bx, cx, ay, by, cy, dxs, tx, ty, ix_minus_c, iy):
    """Warped positions of one subset row (offsets ``dxs`` from the centre column) as integer cells (x cell
    minus the pixel index) and fractions."""
    for c in range(dxs.shape[0]):
        dx = dxs[c]   # a float array: AVX2 has no packed int64 -> double conversion
        x = ax + dx * (bx + cx * dx)
        y = ay + dx * (by + cy * dx)
        # int32 conversions vectorise (vcvttpd2dq); AVX2 has no packed double -> int64.
        ix = np.int32(x)
        jy = np.int32(y)
        tx[c] = np.float32(x - ix)
        ty[c] = np.float32(y - jy)
        ix_minus_c[c] = ix - np.int32(c)
        iy[c] = jy


#: Pixels per vector in the sampling loops (float32 on AVX2). Runs are sampled in whole vectors where that is
#: safe: the few extra samples past a run's end land where the next run (or the padding) overwrites them, and
#: the vector loop never falls into its scalar remainder, which costs ~10x per pixel. Rows cut into short runs
#: (strain, rotation, a stereo pair's foreshortening) profit most.
LANES = 8


@numba.njit(inline="always")
def _vector_stop(start, end, overrun_ok):
    """Loop end for the run ``[start, end)``: rounded up to whole vectors when reading past it is safe."""
    if overrun_ok:
        return start + ((end - start + LANES - 1) // LANES) * LANES
    return end


@numba.njit(inline="always")
def _row_breaks(ix_minus_c, iy, n, brk):
    """Flag in ``brk`` (uint8, zero past ``n``) each pixel whose coefficient window does not follow its left
    neighbour's by one column (a new run starts there); returns how many (a vectorised pass)."""
    breaks = 0
    for c in range(1, n):
        flag = np.uint8((ix_minus_c[c] != ix_minus_c[c - 1]) | (iy[c] != iy[c - 1]))
        brk[c] = flag
        breaks += flag
    return breaks


@numba.njit(inline="always")
def _run_end(brk, brk_words, start, n):
    """End of the run of pixels from ``start`` (the next flagged pixel, or ``n``): eight flags are read at a time
    through ``brk_words`` (``brk`` viewed as uint64), so a long run costs a few loads, not a compare per pixel."""
    c = start + 1
    while c < n and (c & 7) != 0:
        if brk[c]:
            return c
        c += 1
    while c < n:
        if brk_words[c >> 3] != 0:
            for j in range(8):
                if brk[c + j]:
                    return min(c + j, n)
        c += 8
    return n


# Sampling a warped subset row: the row is split into runs of pixels whose 6 x 6 (or 4 x 4) coefficient
# windows move by exactly one column per pixel. Within a run the coefficient loads are unit-stride, so LLVM
# vectorises the loop (AVX2, float32: 8 pixels at a time) without gathers. A run ends where the x or y cell changes
# other than by the step, i.e. about 1 + |ux| 2M + |vx| 2M times per row: long runs for small rotations and
# strains. Unsigned indices keep numba from emitting negative-index wrap-around code that would block the
# vectoriser. The sampling loop only writes the samples; the sums are a second loop over the row, because
# fused into one loop the ~20 live vectors (weights, accumulators) spill out of the 16 AVX2 registers.

# Two sampling kernels, one per spline degree, on purpose: a single kernel with the degree as a
# (loop-invariant) branch measured 5-10 % slower in benchmarks/dic_speed.py.
@numba.njit(cache=True, fastmath=True)
def _sample_row_quintic(cf, rows, cols, half, tx, ty, ix_minus_c, iy, g, brk, brk_words):
    """Biquintic samples ``g`` of one warped row (positions from :func:`_warp_row`, support inside).

    ``tx``, ``ty`` and ``g`` hold 2M + 1 + LANES entries (the padding takes the overrun of the last run);
    ``brk`` (uint8, zero-filled, a multiple of 8 entries >= 2M + 9) is scratch for the run breaks and ``brk_words``
    its uint64 view.
    """
    n = 2 * half + 1
    stride = np.uint64(cols)
    one, two, three, four, five = np.uint64(1), np.uint64(2), np.uint64(3), np.uint64(4), np.uint64(5)
    single_run = _row_breaks(ix_minus_c, iy, n, brk) == 0
    start = 0
    while start < n:
        end = n if single_run else _run_end(brk, brk_words, start, n)
        # Reading up to LANES - 1 columns past the run stays inside the array unless its last coefficient row
        # is the array's last row.
        stop = _vector_stop(start, end, iy[start] + 3 < rows - 1)
        base = np.uint64((iy[start] - 2) * cols + ix_minus_c[start] - 2)
        for cu in range(np.uint64(start), np.uint64(stop)):
            b = base + cu
            x0, x1, x2, x3, x4, x5 = quintic_weights_f32(tx[cu])
            y0, y1, y2, y3, y4, y5 = quintic_weights_f32(ty[cu])
            acc = y0 * (cf[b] * x0 + cf[b + one] * x1 + cf[b + two] * x2 + cf[b + three] * x3
                        + cf[b + four] * x4 + cf[b + five] * x5)
            b += stride
            acc += y1 * (cf[b] * x0 + cf[b + one] * x1 + cf[b + two] * x2 + cf[b + three] * x3
                         + cf[b + four] * x4 + cf[b + five] * x5)
            b += stride
            acc += y2 * (cf[b] * x0 + cf[b + one] * x1 + cf[b + two] * x2 + cf[b + three] * x3
                         + cf[b + four] * x4 + cf[b + five] * x5)
            b += stride
            acc += y3 * (cf[b] * x0 + cf[b + one] * x1 + cf[b + two] * x2 + cf[b + three] * x3
                         + cf[b + four] * x4 + cf[b + five] * x5)
            b += stride
            acc += y4 * (cf[b] * x0 + cf[b + one] * x1 + cf[b + two] * x2 + cf[b + three] * x3
                         + cf[b + four] * x4 + cf[b + five] * x5)
            b += stride
            acc += y5 * (cf[b] * x0 + cf[b + one] * x1 + cf[b + two] * x2 + cf[b + three] * x3
                         + cf[b + four] * x4 + cf[b + five] * x5)
            g[cu] = acc
        start = end


@numba.njit(cache=True, fastmath=True)
def _sample_row_cubic(cf, rows, cols, half, tx, ty, ix_minus_c, iy, g, brk, brk_words):
    """As :func:`_sample_row_quintic`, bicubic."""
    n = 2 * half + 1
    stride = np.uint64(cols)
    one, two, three = np.uint64(1), np.uint64(2), np.uint64(3)
    single_run = _row_breaks(ix_minus_c, iy, n, brk) == 0
    start = 0
    while start < n:
        end = n if single_run else _run_end(brk, brk_words, start, n)
        stop = _vector_stop(start, end, iy[start] + 2 < rows - 1)
        base = np.uint64((iy[start] - 1) * cols + ix_minus_c[start] - 1)
        for cu in range(np.uint64(start), np.uint64(stop)):
            b = base + cu
            x0, x1, x2, x3 = cubic_weights_f32(tx[cu])
            y0, y1, y2, y3 = cubic_weights_f32(ty[cu])
            acc = y0 * (cf[b] * x0 + cf[b + one] * x1 + cf[b + two] * x2 + cf[b + three] * x3)
            b += stride
            acc += y1 * (cf[b] * x0 + cf[b + one] * x1 + cf[b + two] * x2 + cf[b + three] * x3)
            b += stride
            acc += y2 * (cf[b] * x0 + cf[b + one] * x1 + cf[b + two] * x2 + cf[b + three] * x3)
            b += stride
            acc += y3 * (cf[b] * x0 + cf[b + one] * x1 + cf[b + two] * x2 + cf[b + three] * x3)
            g[cu] = acc
        start = end


@numba.njit(cache=True, fastmath=True)
def _row_sums(g, f, fx, fy, k0, dxs):
    """Sums over one row of samples ``g``: g, g^2, f g, and f_x g, f_y g times 1, dx, dx^2 (the dx^2 sums serve
    the second order only; sharing the loop cost the first order nothing measurable)."""
    sum_g = 0.0
    sum_gg = 0.0
    sum_fg = 0.0
    rx0 = 0.0
    rx1 = 0.0
    rx2 = 0.0
    ry0 = 0.0
    ry1 = 0.0
    ry2 = 0.0
    n = dxs.shape[0]   # g is padded (see LANES)
    k = np.uint64(k0)
    for c in range(np.uint64(n)):
        value = np.float64(g[c])
        d = dxs[c]
        sum_g += value
        sum_gg += value * value
        sum_fg += f[k + c] * value
        gxg = fx[k + c] * value
        gyg = fy[k + c] * value
        rx0 += gxg
        rx1 += gxg * d
        rx2 += gxg * d * d
        ry0 += gyg
        ry1 += gyg * d
        ry2 += gyg * d * d
    return sum_g, sum_gg, sum_fg, rx0, rx1, rx2, ry0, ry1, ry2


@numba.njit(cache=True)
def _row_touches_bad(bad, ax, bx, cx, ay, by, cy, half):
    for c in range(2 * half + 1):
        dx = float(c - half)
        if bad[int(ay + dx * (by + cy * dx)), int(ax + dx * (bx + cx * dx))]:
            return True
    return False


@numba.njit(cache=True, fastmath=True)
def iterate(coef, degree, bad, check_bad, x0, y0, half, order, f, fx, fy, delta_f, hinv, a, s, p,
            max_iterations, tolerance_px):
    """Run IC-GN on one point from the initial parameters ``p``.

    Parameters
    ----------
    coef : ndarray of float32, shape (rows, cols)
        B-spline coefficients of the deformed image. It is sampled in single precision (8 AVX2 lanes); the
        sums that make the step and the ZNCC are accumulated in double precision.
    degree : int
        3 or 5.
    bad : ndarray of bool/uint8, shape (rows, cols)
        True where the deformed image is invalid (dilated by the interpolation support); read only when
        ``check_bad``.
    x0, y0, half, order, f, fx, fy, delta_f, hinv, a, s
        As produced by :func:`prepare_reference`.
    p : ndarray of float64, shape (12,)
        Initial shape parameters (see :mod:`.shape_functions`), updated in place.
    max_iterations : int
    tolerance_px : float
        Convergence threshold on the increment at the subset edge, px.

    Returns
    -------
    status : int
    zncc : float
        ZNCC of the last evaluated warp (the one before the final, below-tolerance increment).
    iterations : int
    """
    rows, cols = coef.shape
    cf = coef.reshape(-1)
    if degree == 5:
        lo, hi = 2.0, 3.0
    else:
        lo, hi = 1.0, 2.0
    xmax = cols - hi
    ymax = rows - hi
    n = 2 * half + 1
    count = float(n * n)
    nm = 3 if order == 1 else 6
    npar = 2 * nm
    g_j = np.empty(npar)
    b = np.empty(npar)
    step = np.empty(npar)
    dp = np.zeros(12)
    tx = np.zeros(n + LANES, dtype=np.float32)   # padded: see LANES
    ty = np.zeros(n + LANES, dtype=np.float32)
    ix_minus_c = np.empty(n, dtype=np.int32)
    iy = np.empty(n, dtype=np.int32)
    g_row = np.empty(n + LANES, dtype=np.float32)
    brk = np.zeros(((n + LANES + 7) // 8) * 8, dtype=np.uint8)     # entries past n stay 0
    brk_words = brk.view(np.uint64)
    dxs = np.arange(-half, half + 1).astype(np.float64)
    zncc = np.nan
    for iteration in range(1, max_iterations + 1):
        u, ux, uy, uxx, uxy, uyy = p[0], p[1], p[2], p[3], p[4], p[5]
        v, vx, vy, vxx, vxy, vyy = p[6], p[7], p[8], p[9], p[10], p[11]
        sum_g = 0.0
        sum_gg = 0.0
        sum_fg = 0.0
        for i in range(npar):
            g_j[i] = 0.0
        for r in range(n):
            dy = float(r - half)
            ax = x0 + u + uy * dy + 0.5 * uyy * dy * dy
            bx = 1.0 + ux + uxy * dy
            cx = 0.5 * uxx
            ay = y0 + dy + v + vy * dy + 0.5 * vyy * dy * dy
            by = vx + vxy * dy
            cy = 0.5 * vxx
            x_low, x_high = _quadratic_range(ax, bx, cx, half)
            y_low, y_high = _quadratic_range(ay, by, cy, half)
            if not (x_low >= lo and y_low >= lo and x_high < xmax and y_high < ymax):
                return OUT_OF_IMAGE, zncc, iteration
            if check_bad and _row_touches_bad(bad, ax, bx, cx, ay, by, cy, half):
                return INVALID_IMAGE, zncc, iteration
            _warp_row(ax, bx, cx, ay, by, cy, dxs, tx, ty, ix_minus_c, iy)
            if degree == 5:
                _sample_row_quintic(cf, rows, cols, half, tx, ty, ix_minus_c, iy, g_row, brk, brk_words)
            else:
                _sample_row_cubic(cf, rows, cols, half, tx, ty, ix_minus_c, iy, g_row, brk, brk_words)
            sg, sgg, sfg, rx0, rx1, rx2, ry0, ry1, ry2 = _row_sums(g_row, f, fx, fy, r * n, dxs)
            sum_g += sg
            sum_gg += sgg
            sum_fg += sfg
            g_j[0] += rx0
            g_j[1] += rx1
            g_j[2] += rx0 * dy
            g_j[nm] += ry0
            g_j[nm + 1] += ry1
            g_j[nm + 2] += ry0 * dy
            if order == 2:
                g_j[3] += 0.5 * rx2
                g_j[4] += rx1 * dy
                g_j[5] += 0.5 * rx0 * dy * dy
                g_j[9] += 0.5 * ry2
                g_j[10] += ry1 * dy
                g_j[11] += 0.5 * ry0 * dy * dy
        mean_g = sum_g / count
        var_g = sum_gg - count * mean_g * mean_g
        if not var_g > 1e-12 * (sum_gg + 1e-300):
            return DIVERGED, zncc, iteration
        delta_g = np.sqrt(var_g)
        # f is zero-mean, so sum f g = sum (f - f_m)(g - g_m).
        zncc = sum_fg / (delta_f * delta_g)
        ratio = delta_f / delta_g
        for i in range(npar):
            b[i] = a[i] - ratio * (g_j[i] - mean_g * s[i])
        for i in range(npar):
            acc = 0.0
            for j in range(npar):
                acc -= hinv[i, j] * b[j]
            step[i] = acc
        if order == 1:
            dp[0], dp[1], dp[2] = step[0], step[1], step[2]
            dp[6], dp[7], dp[8] = step[3], step[4], step[5]
        else:
            for i in range(12):
                dp[i] = step[i]
        m = float(half)
        edge_u = abs(dp[0]) + m * (abs(dp[1]) + abs(dp[2])) + 0.5 * m * m * (
            abs(dp[3]) + 2.0 * abs(dp[4]) + abs(dp[5]))
        edge_v = abs(dp[6]) + m * (abs(dp[7]) + abs(dp[8])) + 0.5 * m * m * (
            abs(dp[9]) + 2.0 * abs(dp[10]) + abs(dp[11]))
        if not (abs(dp[0]) < MAX_STEP_PX and abs(dp[6]) < MAX_STEP_PX):
            return DIVERGED, zncc, iteration
        if not compose_inverse(p, dp, order):
            return DIVERGED, zncc, iteration
        if np.sqrt(edge_u * edge_u + edge_v * edge_v) < tolerance_px:
            return CONVERGED, zncc, iteration
    return MAX_ITERATIONS, zncc, max_iterations


#: A node's record in a reference cache (:mod:`.reference_cache`), float64: filled (0 or 1), the subset's status,
#: sqrt(sum (f - f_m)^2), its mean grey level f_m, and the two SSSIG sums.
INFO_FILLED, INFO_STATUS, INFO_DELTA_F, INFO_MEAN, INFO_SSSIG_X, INFO_SSSIG_Y = 0, 1, 2, 3, 4, 5
INFO_SIZE = 6


@numba.njit(cache=True)
def solve_point_cached(image, grad_x, grad_y, coef, degree, bad, check_bad, x, y, half, order, min_std, p,
                       max_iterations, tolerance_px, min_zncc, info, hinv, a, s):
    """Reference side and IC-GN for one point; ``p`` (12,) is updated in place.

    ``info`` (:data:`INFO_SIZE`,), ``hinv`` (np, np), ``a``, ``s`` (np,) are the point's record of the reference
    side: when ``info[INFO_FILLED]`` is 0 they are computed (:func:`prepare_reference`) and written there; when 1
    they are read, and only the subset's values and gradients are copied again (every match of a sequence
    correlates the same reference subsets: their Hessian is made once).

    Returns (status, zncc, iterations, sssig_x, sssig_y); a converged point below ``min_zncc`` gets
    LOW_CORRELATION.
    """
    n = 2 * half + 1
    f = np.empty(n * n)
    fx = np.empty(n * n)
    fy = np.empty(n * n)
    if info[INFO_FILLED] == 0.0:
        status, delta_f, sx, sy = prepare_reference(image, grad_x, grad_y, x, y, half, order, min_std, f, fx, fy,
                                                    hinv, a, s)
        mean = 0.0
        if status == CONVERGED:
            mean = _subset_mean(image.reshape(-1), (y - half) * image.shape[1] + x - half, image.shape[1], n)
        info[INFO_STATUS] = status
        info[INFO_DELTA_F] = delta_f
        info[INFO_MEAN] = mean
        info[INFO_SSSIG_X] = sx
        info[INFO_SSSIG_Y] = sy
        info[INFO_FILLED] = 1.0
    else:
        status = int(info[INFO_STATUS])
        delta_f = info[INFO_DELTA_F]
        sx = info[INFO_SSSIG_X]
        sy = info[INFO_SSSIG_Y]
        if status == CONVERGED:
            copy_subset(image, grad_x, grad_y, x, y, half, info[INFO_MEAN], f, fx, fy)
    if status != CONVERGED:
        return status, np.nan, 0, sx, sy
    status, zncc, iterations = iterate(coef, degree, bad, check_bad, x, y, half, order, f, fx, fy, delta_f, hinv,
                                       a, s, p, max_iterations, tolerance_px)
    if status == CONVERGED and not zncc >= min_zncc:
        status = LOW_CORRELATION
    return status, zncc, iterations, sx, sy


@numba.njit(cache=True)
def solve_point(image, grad_x, grad_y, coef, degree, bad, check_bad, x, y, half, order, min_std, p,
                max_iterations, tolerance_px, min_zncc):
    """Reference precomputation and IC-GN for one point, nothing kept (:func:`solve_point_cached` with a fresh
    record); ``p`` (12,) is updated in place. Returns (status, zncc, iterations, sssig_x, sssig_y)."""
    npar = 6 if order == 1 else 12
    return solve_point_cached(image, grad_x, grad_y, coef, degree, bad, check_bad, x, y, half, order, min_std, p,
                              max_iterations, tolerance_px, min_zncc, np.zeros(INFO_SIZE), np.empty((npar, npar)),
                              np.empty(npar), np.empty(npar))


@numba.njit(cache=True)
def solve_node(image, grad_x, grad_y, coef, degree, bad, check_bad, x, y, half, order, min_std, p,
               max_iterations, tolerance_px, min_zncc, use_cache, cache_info, cache_hinv, cache_a, cache_s, r, c):
    """:func:`solve_point` for grid node (r, c), through the node's record in the cache arrays
    (``cache_info`` (R, C, INFO_SIZE), ``cache_hinv`` (R, C, np, np), ``cache_a``, ``cache_s`` (R, C, np)) when
    ``use_cache``."""
    if use_cache:
        return solve_point_cached(image, grad_x, grad_y, coef, degree, bad, check_bad, x, y, half, order, min_std,
                                  p, max_iterations, tolerance_px, min_zncc, cache_info[r, c], cache_hinv[r, c],
                                  cache_a[r, c], cache_s[r, c])
    return solve_point(image, grad_x, grad_y, coef, degree, bad, check_bad, x, y, half, order, min_std, p,
                       max_iterations, tolerance_px, min_zncc)


@numba.njit(cache=True, parallel=True)
def correlate_batch(image, grad_x, grad_y, coef, degree, bad, check_bad, xs, ys, half, order, min_std, p,
                    max_iterations, tolerance_px, min_zncc, status, zncc, iterations, sssig,
                    use_cache, cache_info, cache_hinv, cache_a, cache_s, rc):
    """IC-GN on many points in parallel, each from its own initial guess ``p[k]`` (updated in place).

    Outputs ``status``, ``zncc``, ``iterations`` (n,) and ``sssig`` (n, 2) are filled per point. With
    ``use_cache``, point k's reference side lives in the cache arrays at grid node ``rc[k]`` (see
    :func:`solve_node`).
    """
    for k in numba.prange(xs.shape[0]):
        st, c, it, sx, sy = solve_node(image, grad_x, grad_y, coef, degree, bad, check_bad, xs[k], ys[k], half,
                                       order, min_std, p[k], max_iterations, tolerance_px, min_zncc, use_cache,
                                       cache_info, cache_hinv, cache_a, cache_s, rc[k, 0], rc[k, 1])
        status[k] = st
        zncc[k] = c
        iterations[k] = it
        sssig[k, 0] = sx
        sssig[k, 1] = sy
