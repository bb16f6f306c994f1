"""Bicubic and biquintic B-spline interpolation of grey images (numba).

A B-spline interpolant of degree ``n`` writes the continuous image as

    f(x, y) = sum_{i, j} c[i, j] * beta_n(y - i) * beta_n(x - j),

where ``c`` are the B-spline coefficients. They come from the image by the recursive prefilter of Unser
(1991); :func:`prefilter` runs it with mirror boundaries, multi-threaded (numba; the same coefficients as
``scipy.ndimage.spline_filter(mode='mirror')``, which holds the GIL and runs on one core), so that the
interpolant passes exactly through every pixel. Evaluating ``f`` at a real point needs the ``n + 1``
coefficients around it in each direction and ``n + 1`` weights per axis: ``4 x 4`` for the bicubic, ``6 x 6``
for the biquintic interpolant. The weights are the formulas of Thevenaz, Blu & Unser (2000), "Interpolation
revisited", IEEE TMI 19(7).

Coordinates: ``x`` is the column, ``y`` the row; pixel ``(row i, col j)`` has its centre at ``(x, y) = (j, i)``.

A point can be evaluated when its whole support lies inside the coefficient array; :func:`support_margin`
gives how far from the border that is, and the evaluation functions return False otherwise.
"""
from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np

#: Degrees implemented, by name.
DEGREES = {"bicubic": 3, "biquintic": 5}


@dataclass(frozen=True)
class BSplineImage:
    """B-spline coefficients of one image, with the exact gradient of the interpolant at the pixel centres.

    Attributes
    ----------
    coefficients : ndarray of float64 or float32, shape (rows, cols)
        B-spline coefficients ``c``.
    degree : int
        3 (bicubic) or 5 (biquintic).
    grad_x : ndarray of float64, shape (rows, cols) or None
        d f / d x of the interpolant at each pixel centre, grey levels per pixel (None if not requested).
    grad_y : ndarray of float64, shape (rows, cols) or None
        d f / d y at each pixel centre.
    """

    coefficients: np.ndarray
    degree: int
    grad_x: np.ndarray | None = None
    grad_y: np.ndarray | None = None

    @property
    def shape(self) -> tuple[int, int]:
        return self.coefficients.shape


def degree_of(interpolation: str | int) -> int:
    """Return the spline degree for ``'bicubic'``, ``'biquintic'``, 3 or 5; raise ValueError otherwise."""
    if isinstance(interpolation, str):
        if interpolation not in DEGREES:
            raise ValueError(f"interpolation must be one of {sorted(DEGREES)}, got {interpolation!r}")
        return DEGREES[interpolation]
    if interpolation in (3, 5):
        return int(interpolation)
    raise ValueError(f"spline degree must be 3 or 5, got {interpolation!r}")


def support_margin(degree: int) -> tuple[int, int]:
    """Coefficients needed below and above ``floor(x)``: (1, 2) for cubic, (2, 3) for quintic."""
    return (1, 2) if degree == 3 else (2, 3)


def prefilter(image: np.ndarray, interpolation: str | int = "biquintic", gradients: bool = True,
              coefficient_dtype=np.float64) -> BSplineImage:
    """B-spline coefficients (and, optionally, pixel-centre gradients) of a grey image.

    Parameters
    ----------
    image : ndarray, shape (rows, cols)
        Grey-level image, any real dtype; must be finite.
    interpolation : {'biquintic', 'bicubic'} or {5, 3}
        Spline degree.
    gradients : bool
        Also compute the exact gradient of the interpolant at every pixel centre (what IC-GN needs of the
        reference image).
    coefficient_dtype : {np.float64, np.float32}
        Storage of the coefficients. The prefilter and the gradients are always computed in double precision;
        float32 halves the memory and lets IC-GN sample 8 pixels per AVX2 instruction (rounding the
        coefficients changes interpolated values by ~1e-5 grey).

    Returns
    -------
    BSplineImage
    """
    degree = degree_of(interpolation)
    image = np.asarray(image)
    if image.ndim != 2:
        raise ValueError(f"image must be 2-D (rows, cols), got shape {image.shape}")
    if min(image.shape) < degree + 1:
        raise ValueError(f"image {image.shape} is too small for a degree-{degree} spline")
    if not np.isfinite(image).all():
        raise ValueError("image contains NaN or infinite values")
    coefficients = _spline_coefficients(image, degree)
    grad_x = grad_y = None
    if gradients:
        grad_x, grad_y = pixel_gradients(coefficients, degree)
    if np.dtype(coefficient_dtype) not in (np.dtype(np.float64), np.dtype(np.float32)):
        raise ValueError(f"coefficient_dtype must be float64 or float32, got {coefficient_dtype!r}")
    return BSplineImage(coefficients.astype(coefficient_dtype, copy=False), degree, grad_x, grad_y)


def integer_kernels(degree: int) -> tuple[np.ndarray, np.ndarray]:
    """beta_n(k) and beta_n'(k) at k = -h..h, as correlation kernels over the coefficients."""
    if degree == 3:
        value = np.array([1.0, 4.0, 1.0]) / 6.0
        # f'(j) = (c[j+1] - c[j-1]) / 2
        derivative = np.array([-0.5, 0.0, 0.5])
    else:
        value = np.array([1.0, 26.0, 66.0, 26.0, 1.0]) / 120.0
        # f'(j) = 5/12 (c[j+1] - c[j-1]) + 1/24 (c[j+2] - c[j-2])
        derivative = np.array([-1.0 / 24.0, -5.0 / 12.0, 0.0, 5.0 / 12.0, 1.0 / 24.0])
    return value, derivative


def pixel_gradients(coefficients: np.ndarray, degree: int) -> tuple[np.ndarray, np.ndarray]:
    """Exact gradient of the spline interpolant at every pixel centre.

    Returns
    -------
    grad_x, grad_y : ndarray of float64, shape (rows, cols)
        Grey levels per pixel along x (columns) and y (rows).
    """
    value, derivative = integer_kernels(degree)
    c = np.ascontiguousarray(coefficients, dtype=np.float64)
    smooth = np.empty_like(c)
    grad_x = np.empty_like(c)
    grad_y = np.empty_like(c)
    _correlate_columns(c, value, smooth)
    _correlate_rows(smooth, derivative, grad_x)
    _correlate_rows(c, value, smooth)
    _correlate_columns(smooth, derivative, grad_y)
    return grad_x, grad_y


# ---------------------------------------------------------------------------------------------------------
# Prefilter and pixel gradients, multi-threaded (scipy's spline_filter holds the GIL and runs on one core).
# ---------------------------------------------------------------------------------------------------------

def _poles(degree: int) -> np.ndarray:
    """Poles of the B-spline interpolation prefilter (Unser 1991; the values scipy.ndimage uses)."""
    if degree == 3:
        return np.array([np.sqrt(3.0) - 2.0])
    return np.array([np.sqrt(67.5 - np.sqrt(4436.25)) + np.sqrt(26.25) - 6.5,
                     np.sqrt(67.5 + np.sqrt(4436.25)) - np.sqrt(26.25) - 6.5])


@numba.njit(inline="always")
def _mirror(i, n):
    """Index ``i`` reflected about the edge pixels (ndimage's 'mirror': d c b | a b c d | c b a)."""
    if i < 0:
        return -i
    if i >= n:
        return 2 * (n - 1) - i
    return i


@numba.njit(cache=True)
def _causal_start(line_at, n, z, horizon):
    """Mirror-boundary start of the causal recursion, c+[0] = sum_k z^|k| s[mirror(k)] (exact when n is short,
    truncated after ``horizon`` terms, where z^k is below double precision, otherwise)."""
    if n <= horizon:
        z_n_1 = z ** (n - 1)
        total = line_at[0] + z_n_1 * line_at[n - 1]
        z_i = z
        for i in range(1, n - 1):
            total += z_i * (line_at[i] + z_n_1 * line_at[n - 1 - i])
            z_i *= z
        return total / (1.0 - z_n_1 * z_n_1)
    total = 0.0
    z_i = 1.0
    for i in range(horizon):
        total += z_i * line_at[i]
        z_i *= z
    return total


@numba.njit(cache=True, parallel=True)
def _filter_rows(c, poles, gain, horizons):
    """In-place recursive prefilter along axis 1 (each row on its own)."""
    rows, cols = c.shape
    for i in numba.prange(rows):
        line = c[i]
        for j in range(cols):
            line[j] *= gain
        for p in range(poles.shape[0]):
            z = poles[p]
            line[0] = _causal_start(line, cols, z, horizons[p])
            for j in range(1, cols):
                line[j] += z * line[j - 1]
            line[cols - 1] = (z * line[cols - 2] + line[cols - 1]) * z / (z * z - 1.0)
            for j in range(cols - 2, -1, -1):
                line[j] = z * (line[j + 1] - line[j])


@numba.njit(cache=True, parallel=True)
def _filter_columns(c, poles, gain, horizons):
    """In-place recursive prefilter along axis 0, a block of columns at a time (unit-stride, vectorised)."""
    rows, cols = c.shape
    block = 64
    for b in numba.prange((cols + block - 1) // block):
        j0 = b * block
        j1 = min(cols, j0 + block)
        for i in range(rows):
            for j in range(j0, j1):
                c[i, j] *= gain
        for p in range(poles.shape[0]):
            z = poles[p]
            for j in range(j0, j1):
                c[0, j] = _causal_start(c[:, j], rows, z, horizons[p])
            for i in range(1, rows):
                for j in range(j0, j1):
                    c[i, j] += z * c[i - 1, j]
            for j in range(j0, j1):
                c[rows - 1, j] = (z * c[rows - 2, j] + c[rows - 1, j]) * z / (z * z - 1.0)
            for i in range(rows - 2, -1, -1):
                for j in range(j0, j1):
                    c[i, j] = z * (c[i + 1, j] - c[i, j])


def _spline_coefficients(image: np.ndarray, degree: int) -> np.ndarray:
    """B-spline coefficients with mirror boundaries (same as ``scipy.ndimage.spline_filter(mode='mirror')``)."""
    poles = _poles(degree)
    gain = float(np.prod((1.0 - poles) * (1.0 - 1.0 / poles)))
    horizons = np.ceil(np.log(np.finfo(np.float64).eps / 4) / np.log(np.abs(poles))).astype(np.int64) + 1
    c = np.array(image, dtype=np.float64, order="C", copy=True)
    _filter_columns(c, poles, gain, horizons)
    _filter_rows(c, poles, gain, horizons)
    return c


@numba.njit(cache=True, parallel=True)
def _correlate_rows(c, kernel, out):
    """out[i, j] = sum_k kernel[k] c[i, mirror(j + k - h)]."""
    rows, cols = c.shape
    h = kernel.shape[0] // 2
    for i in numba.prange(rows):
        for j in range(cols):
            out[i, j] = 0.0
        for k in range(kernel.shape[0]):
            w = kernel[k]
            if w == 0.0:
                continue
            d = k - h
            for j in range(max(0, -d), min(cols, cols - d)):
                out[i, j] += w * c[i, j + d]
            for j in range(0, max(0, -d)):
                out[i, j] += w * c[i, _mirror(j + d, cols)]
            for j in range(min(cols, cols - d), cols):
                out[i, j] += w * c[i, _mirror(j + d, cols)]


@numba.njit(cache=True, parallel=True)
def _correlate_columns(c, kernel, out):
    """out[i, j] = sum_k kernel[k] c[mirror(i + k - h), j]."""
    rows, cols = c.shape
    h = kernel.shape[0] // 2
    for i in numba.prange(rows):
        for j in range(cols):
            out[i, j] = 0.0
        for k in range(kernel.shape[0]):
            w = kernel[k]
            if w == 0.0:
                continue
            source = c[_mirror(i + k - h, rows)]
            for j in range(cols):
                out[i, j] += w * source[j]


@numba.njit(inline="always", fastmath=True)
def cubic_weights(t):
    """Cubic B-spline weights for fraction ``t`` in [0, 1), nodes floor-1 .. floor+2 (a 4-tuple)."""
    w3 = (1.0 / 6.0) * t * t * t
    w0 = (1.0 / 6.0) + 0.5 * t * (t - 1.0) - w3
    w2 = t + w0 - 2.0 * w3
    return w0, 1.0 - w0 - w2 - w3, w2, w3


@numba.njit(inline="always", fastmath=True)
def quintic_weights(t):
    """Quintic B-spline weights for fraction ``t`` in [0, 1), nodes floor-2 .. floor+3 (a 6-tuple)."""
    t2 = t * t
    w5 = (1.0 / 120.0) * t * t2 * t2
    s2 = t2 - t
    s4 = s2 * s2
    h = t - 0.5
    q = s2 * (s2 - 3.0)
    w0 = (1.0 / 24.0) * (1.0 / 5.0 + s2 + s4) - w5
    a0 = (1.0 / 24.0) * (s2 * (s2 - 5.0) + 46.0 / 5.0)
    a1 = (-1.0 / 12.0) * h * (q + 4.0)
    b0 = (1.0 / 16.0) * (9.0 / 5.0 - q)
    b1 = (1.0 / 24.0) * h * (s4 - s2 - 5.0)
    return w0, b0 + b1, a0 + a1, a0 - a1, b0 - b1, w5


# Single-precision twins of the weights, for IC-GN's sampling of the deformed image: 8 AVX2 lanes instead of 4.
# Numba types a Python float literal as float64, which would promote the whole expression, hence the constants.
_F32 = np.float32
_C6, _C24, _C120, _C16, _Cm12 = _F32(1 / 6), _F32(1 / 24), _F32(1 / 120), _F32(1 / 16), _F32(-1 / 12)
_F0_2, _F0_5, _F1, _F2, _F3, _F4, _F5 = _F32(0.2), _F32(0.5), _F32(1), _F32(2), _F32(3), _F32(4), _F32(5)
_F1_8, _F9_2 = _F32(9 / 5), _F32(46 / 5)


@numba.njit(inline="always", fastmath=True)
def cubic_weights_f32(t):
    """:func:`cubic_weights` in float32 (``t`` float32)."""
    w3 = _C6 * t * t * t
    w0 = _C6 + _F0_5 * t * (t - _F1) - w3
    w2 = t + w0 - _F2 * w3
    return w0, _F1 - w0 - w2 - w3, w2, w3


@numba.njit(inline="always", fastmath=True)
def quintic_weights_f32(t):
    """:func:`quintic_weights` in float32 (``t`` float32)."""
    t2 = t * t
    w5 = _C120 * t * t2 * t2
    s2 = t2 - t
    s4 = s2 * s2
    h = t - _F0_5
    q = s2 * (s2 - _F3)
    w0 = _C24 * (_F0_2 + s2 + s4) - w5
    a0 = _C24 * (s2 * (s2 - _F5) + _F9_2)
    a1 = _Cm12 * h * (q + _F4)
    b0 = _C16 * (_F1_8 - q)
    b1 = _C24 * h * (s4 - s2 - _F5)
    return w0, b0 + b1, a0 + a1, a0 - a1, b0 - b1, w5


@numba.njit(inline="always", fastmath=True)
def cubic_weight_derivatives(t, w):
    """d/dt of :func:`cubic_weights`."""
    w[0] = -0.5 * (1.0 - t) * (1.0 - t)
    w[1] = 1.5 * t * t - 2.0 * t
    w[2] = -1.5 * t * t + t + 0.5
    w[3] = 0.5 * t * t


@numba.njit(inline="always", fastmath=True)
def quintic_weight_derivatives(t, w):
    """d/dt of :func:`quintic_weights` (nodes floor-2 .. floor+3)."""
    u = 1.0 - t
    t2 = t * t
    t3 = t2 * t
    t4 = t3 * t
    w[0] = -(1.0 / 24.0) * u * u * u * u
    # beta5'(x) on [1, 2) is 5/8 - 7/2 x + 15/4 x^2 - 3/2 x^3 + 5/24 x^4; node floor-1 sits at distance 1 + t.
    x = 1.0 + t
    w[1] = 5.0 / 8.0 - 3.5 * x + 3.75 * x * x - 1.5 * x * x * x + (5.0 / 24.0) * x * x * x * x
    # beta5'(x) on [0, 1) is -x + x^3 - 5/12 x^4; node floor sits at distance t.
    w[2] = -t + t3 - (5.0 / 12.0) * t4
    # node floor+1 at distance 1 - t: d/dt beta5(1 - t) = -beta5'(1 - t)
    x = u
    w[3] = x - x * x * x + (5.0 / 12.0) * x * x * x * x
    x = 2.0 - t
    w[4] = -(5.0 / 8.0 - 3.5 * x + 3.75 * x * x - 1.5 * x * x * x + (5.0 / 24.0) * x * x * x * x)
    w[5] = (1.0 / 24.0) * t4


@numba.njit(inline="always", fastmath=True)
def value_gradient(coefficients, degree, x, y, wx, wy, dwx, dwy):
    """(inside, f, df/dx, df/dy) of the interpolant at one real point, with caller-owned weight buffers ``wx``,
    ``wy``, ``dwx``, ``dwy`` (float64, length >= 6): no allocation, for loops over many points. ``inside`` is False
    (and the values 0) when the support leaves the coefficient array."""
    rows, cols = coefficients.shape
    if degree == 3:
        lo, hi = 1, 2
    else:
        lo, hi = 2, 3
    if not (x >= lo and y >= lo and x < cols - hi and y < rows - hi):
        return False, 0.0, 0.0, 0.0
    ix = int(x)
    iy = int(y)
    tx = x - ix
    ty = y - iy
    if degree == 3:
        wx[0], wx[1], wx[2], wx[3] = cubic_weights(tx)
        wy[0], wy[1], wy[2], wy[3] = cubic_weights(ty)
        cubic_weight_derivatives(tx, dwx)
        cubic_weight_derivatives(ty, dwy)
    else:
        wx[0], wx[1], wx[2], wx[3], wx[4], wx[5] = quintic_weights(tx)
        wy[0], wy[1], wy[2], wy[3], wy[4], wy[5] = quintic_weights(ty)
        quintic_weight_derivatives(tx, dwx)
        quintic_weight_derivatives(ty, dwy)
    value = 0.0
    gx = 0.0
    gy = 0.0
    for i in range(degree + 1):
        row_value = 0.0
        row_dx = 0.0
        for j in range(degree + 1):
            c = coefficients[iy - lo + i, ix - lo + j]
            row_value += c * wx[j]
            row_dx += c * dwx[j]
        value += wy[i] * row_value
        gx += wy[i] * row_dx
        gy += dwy[i] * row_value
    return True, value, gx, gy


@numba.njit(fastmath=True)
def evaluate_point(coefficients, degree, x, y, out):
    """Value and gradient of the interpolant at one real point.

    Parameters
    ----------
    coefficients : ndarray of float64, shape (rows, cols)
    degree : int
        3 or 5.
    x, y : float
        Column and row coordinate, px.
    out : ndarray of float64, shape (3,)
        Receives (f, df/dx, df/dy).

    Returns
    -------
    bool
        False (and ``out`` untouched) when the support leaves the coefficient array.
    """
    buffers = np.empty((4, 6))
    inside, value, gx, gy = value_gradient(coefficients, degree, x, y, buffers[0], buffers[1], buffers[2],
                                           buffers[3])
    if not inside:
        return False
    out[0] = value
    out[1] = gx
    out[2] = gy
    return True


@numba.njit(fastmath=True)
def _evaluate_many(coefficients, degree, x, y, out):
    buffer = np.empty(3)
    for k in range(x.shape[0]):
        if evaluate_point(coefficients, degree, x[k], y[k], buffer):
            out[k, 0] = buffer[0]
            out[k, 1] = buffer[1]
            out[k, 2] = buffer[2]
        else:
            out[k, :] = np.nan


def interpolate(spline: BSplineImage, x_px: np.ndarray, y_px: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Value and gradient of the interpolant at arbitrary points.

    Parameters
    ----------
    spline : BSplineImage
    x_px, y_px : array_like, same shape
        Column and row coordinates, px.

    Returns
    -------
    value, grad_x, grad_y : ndarray of float64, same shape as ``x_px``
        NaN where the interpolation support leaves the image (see :func:`support_margin`).
    """
    x = np.asarray(x_px, dtype=np.float64)
    y = np.asarray(y_px, dtype=np.float64)
    if x.shape != y.shape:
        raise ValueError(f"x_px and y_px must have the same shape, got {x.shape} and {y.shape}")
    out = np.empty((x.size, 3))
    _evaluate_many(spline.coefficients, spline.degree, x.ravel(), y.ravel(), out)
    return tuple(out[:, k].reshape(x.shape) for k in range(3))
