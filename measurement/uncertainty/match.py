"""Random uncertainty of a subset match (u, v and the shape parameters) from the IC-GN Hessian and the image noise.

IC-GN (:mod:`measurement.dic.icgn`) converges where ``sum J^T r = 0`` with ``J = grad f . dW/dp`` from the reference
subset and ``r = (f - f_m) - (Df / Dg) (g(W) - g_m)``. Linearised at the truth, the image noise ``n_f`` (reference,
at its pixels) and ``n_g`` (target, *interpolated* at the warped positions) move the solution by

    dp = H0^-1 J^T (n_f - n_g'),        Cov(dp) = H0^-1 [J^T (S_f + S_g') J] H0^-1,

where ``H0 = E[J^T grad g . dW/dp]`` is the Hessian of the noise-free pattern. The computed Hessian ``H = J^T J``
is that of the *noisy* reference gradients: white noise adds ``c_grad sigma_f^2 sum m m^T`` to its diagonal
blocks (``c_grad`` = the squared norm of the interpolant's derivative filter: 1.89 px^-2 quintic, 1.39 cubic, see
:func:`gradient_noise_gain`), so ``H0 = H - c_grad sigma_f^2 M``; using ``H`` itself would under-state sigma by
the ratio of noise to texture in the gradients (10 % at 5 grey on a 4 px speckle).

* The **reference part** ``H0^-1 J^T S_f J H0^-1`` comes from the reference image's noise at its own pixels: every
  match of that reference subset (the stereo match and every temporal match) shares it, which is why it is kept
  apart (:attr:`MatchUncertainty.cov_reference_px2`).
* The **target part** is the same form with the target's noise, ``S_g = sigma_g^2(I)``, passed through the
  interpolant: at sub-pixel phase ``t`` the interpolated noise is white noise filtered by the cardinal spline
  shifted by ``t``, whose gain on the subset's gradient spectrum ``kappa(t) <= 1`` (1 at whole pixels; for
  biquintic on 3 px speckle 0.98 at half a pixel along the gradient's axis, while white noise -- what the residual
  sees -- drops to 0.84 per axis, 0.70 at (0.5, 0.5)) is read from a table of the reference image's gradient
  spectrum (:func:`interpolation_noise_gain`) and averaged over the warped subset.

Noise: a :class:`~measurement.speckle_quality.NoiseModel` per image (``sigma^2(I) = read^2 + I / gain``), from a
static pair (measured) when the user has one; otherwise :func:`noise_from_residuals` fits it to the matches' own
ZNSSD residuals (``source = "match residuals"``: shape-function misfit and interpolation error count as noise
there, so it errs high). Which was used is stated in :attr:`MatchUncertainty.noise_source`.

Residual check: the converged ZNSSD residual ``sum r^2 = Df^2 (2 - 2 ZNCC)`` is compared with what the noise
explains, ``(n - n_p - 2) (sigma_f^2 + kappa_0 sigma_g^2)`` (``kappa_0``: the white-noise gain of the
interpolant); a ratio above ``max_residual_ratio`` flags the point (shape-function mismatch, occlusion,
specularity, a wrong noise model). The sigma of a flagged point is still given; its ``flag`` says not to trust it.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numba
import numpy as np

from measurement.dic import bspline
from measurement.dic.correlate import DICResult, PreparedImage, prepare_image
from measurement.dic.icgn import prepare_reference
from measurement.dic.status import CONVERGED
from measurement.speckle_quality import NoiseModel

#: Default residual ratio (observed / explained by the noise) above which a point is flagged. With ~10^3 pixels
#: per subset the ratio of pure noise scatters by a few per cent; a subset whose shape function leaves as much
#: misfit as the noise itself reads 2.
DEFAULT_MAX_RESIDUAL_RATIO = 2.0
#: Sub-pixel phases of the interpolation-gain tables, px (by symmetry 0 .. 0.5 suffices).
_PHASES = np.linspace(0.0, 0.5, 11)

#: Flags of :attr:`MatchUncertainty.flag`.
FLAG_NONE, FLAG_RESIDUAL, FLAG_NO_MATCH, FLAG_SINGULAR, FLAG_SATURATED = 0, 1, 2, 3, 4
FLAG_NAMES = {FLAG_NONE: "", FLAG_RESIDUAL: "residual above noise", FLAG_NO_MATCH: "no match",
              FLAG_SINGULAR: "texture too weak for a sigma", FLAG_SATURATED: "saturated subset"}
#: A subset with more than this fraction of clipped pixels (at the image's ceiling or floor) gets no sigma: clipped
#: pixels carry neither noise nor gradient, so the noise model says nothing about them.
MAX_CLIPPED_FRACTION = 0.02


# ---------------------------------------------------------------------------------------------------------------
# The interpolant's effect on noise
# ---------------------------------------------------------------------------------------------------------------

def _weights(degree: int, t: float) -> np.ndarray:
    return np.array(bspline.cubic_weights(t) if degree == 3 else bspline.quintic_weights(t))


def interpolant_response(degree: int, omega: np.ndarray, shift_px: float) -> np.ndarray:
    """Transfer function of the cardinal B-spline interpolant of ``degree`` evaluated ``shift_px`` past a pixel.

    The interpolated value at ``k + t`` of samples ``s`` is ``sum_j s_j h_t(k - j)``; this returns
    ``H_t(omega) = sum_j h_t(j) exp(-i omega j)`` (``|H_0| = 1``; the ideal is ``exp(i omega t)``).

    Parameters
    ----------
    degree : 3 or 5
    omega : ndarray, rad/px
    shift_px : float in [0, 1)
    """
    lo, _ = bspline.support_margin(degree)
    w_t = _weights(degree, float(shift_px))              # nodes floor - lo ...
    w_0 = _weights(degree, 0.0)
    nodes = np.arange(-lo, -lo + w_t.size)
    omega = np.asarray(omega, dtype=np.float64)
    phase = np.exp(1j * np.multiply.outer(omega, nodes))
    return (phase @ w_t) / (phase @ w_0)


def gradient_noise_gain(degree: int) -> float:
    """Variance of the interpolant's pixel-centre gradient on unit white noise, px^-2 (``sum d_k^2``)."""
    omega = np.linspace(-np.pi, np.pi, 4097)[:-1]
    lo, _ = bspline.support_margin(degree)
    # d/dt of the interpolant at t = 0: derivative of the B-spline weights over the prefilter's response
    _, derivative = bspline.integer_kernels(degree)
    value, _ = bspline.integer_kernels(degree)
    half = value.size // 2
    nodes = np.arange(-half, half + 1)
    phase = np.exp(1j * np.multiply.outer(omega, nodes))
    response = (phase @ derivative) / (phase @ value)
    return float(np.mean(np.abs(response) ** 2))


@dataclass(frozen=True)
class NoiseGainTable:
    """Gain ``kappa`` of the interpolant on the noise seen by u and by v, over sub-pixel phases (tx, ty) in [0, 0.5].

    Attributes
    ----------
    phases_px : ndarray (P,)
    kappa_u, kappa_v : ndarray (P, P)
        Indexed [tx, ty]: the noise variance the target image adds to u (v), relative to whole-pixel phases,
        weighted by the reference's x (y) gradient spectrum.
    kappa_white : ndarray (P, P)
        The same for unweighted white noise (what the residual sees).
    interpolation_error : ndarray (P, P)
        Mean squared error of the interpolant on the image at each phase, relative to the image's variance:
        ``sum P |H_t - exp(i w t)|^2 / sum P`` (a residual the noise does not explain, largest for fine speckle).
        The image's noise is in ``P`` too: :meth:`signal_interpolation_error` takes it out.
    interpolation_error_white : ndarray (P, P)
        The same for white noise.
    power_total, power_per_noise_variance : float
        ``sum P`` and what a unit white-noise variance adds to it.
    """

    phases_px: np.ndarray
    kappa_u: np.ndarray
    kappa_v: np.ndarray
    kappa_white: np.ndarray
    interpolation_error: np.ndarray
    interpolation_error_white: np.ndarray
    power_total: float = 0.0
    power_per_noise_variance: float = 0.0

    def signal_interpolation_error(self, tx, ty, noise_variance: float) -> np.ndarray:
        """:attr:`interpolation_error` of the texture alone (the noise's share of the spectrum taken out), at
        fractional positions (tx, ty), relative to the texture's variance."""
        measured = self.lookup("interpolation", tx, ty)
        white = self.lookup("interpolation_white", tx, ty)
        noise = float(noise_variance) * self.power_per_noise_variance
        signal = self.power_total - noise
        if not signal > 0:
            return np.zeros_like(measured)
        return np.clip((measured * self.power_total - white * noise) / signal, 0.0, None)

    def lookup(self, which: str, tx, ty) -> np.ndarray:
        """Bilinear lookup at fractional positions (any real; folded to [0, 0.5])."""
        table = {"u": self.kappa_u, "v": self.kappa_v, "white": self.kappa_white,
                 "interpolation": self.interpolation_error,
                 "interpolation_white": self.interpolation_error_white}[which]
        fx = _fold(np.asarray(tx, float))
        fy = _fold(np.asarray(ty, float))
        step = self.phases_px[1] - self.phases_px[0]
        gx = np.clip(fx / step, 0, len(self.phases_px) - 1 - 1e-9)
        gy = np.clip(fy / step, 0, len(self.phases_px) - 1 - 1e-9)
        ix, iy = gx.astype(int), gy.astype(int)
        ax, ay = gx - ix, gy - iy
        return ((1 - ax) * (1 - ay) * table[ix, iy] + ax * (1 - ay) * table[ix + 1, iy]
                + (1 - ax) * ay * table[ix, iy + 1] + ax * ay * table[ix + 1, iy + 1])


def _fold(t: np.ndarray) -> np.ndarray:
    frac = t - np.floor(t)
    return np.minimum(frac, 1.0 - frac)


def interpolation_noise_gain(reference: np.ndarray, degree: int, *, crop_px: int = 256,
                             box: tuple[int, int, int, int] | None = None) -> NoiseGainTable:
    """Noise-gain tables of the interpolant on this reference image's texture (module notes).

    The power spectra of the x and y gradients are estimated from up to four ``crop_px`` tiles (Hann-tapered)
    inside ``box`` = (x0, y0, x1, y1) (default: the whole image), NaN pixels replaced by the tile mean.
    """
    values = np.asarray(reference, dtype=np.float64)
    x0, y0, x1, y1 = box if box is not None else (0, 0, values.shape[1], values.shape[0])
    size = int(max(16, min(crop_px, x1 - x0, y1 - y0)))
    xs = np.unique(np.clip(np.linspace(x0, x1 - size, 2).astype(int), 0, max(0, values.shape[1] - size)))
    ys = np.unique(np.clip(np.linspace(y0, y1 - size, 2).astype(int), 0, max(0, values.shape[0] - size)))
    taper = np.outer(np.hanning(size), np.hanning(size))
    power = np.zeros((size, size))
    tiles = 0
    for ty in ys:
        for tx in xs:
            tile = values[ty:ty + size, tx:tx + size]
            tile = np.where(np.isfinite(tile), tile, np.nanmean(tile) if np.isfinite(tile).any() else 0.0)
            if tile.shape != (size, size):
                continue
            spectrum = np.fft.fft2((tile - tile.mean()) * taper)
            power += np.abs(spectrum) ** 2
            tiles += 1
    w = 2 * np.pi * np.fft.fftfreq(size)
    wx, wy = np.meshgrid(w, w)                               # [row = y freq, col = x freq]
    weight_u = power * wx ** 2
    weight_v = power * wy ** 2
    # Every table entry is a sum over (y, x) frequencies of a separable gain: matrix products (P, S) x (S, S) x (S, P).
    C = np.array([interpolant_response(degree, w, t) for t in _PHASES])           # (P, S)
    A = np.abs(C) ** 2
    D = C * np.conj(np.exp(1j * np.multiply.outer(_PHASES, w)))                    # response x conj(ideal)
    total_u, total_v, total_p = (max(float(np.sum(m)), 1e-300) for m in (weight_u, weight_v, power))
    ku = A @ weight_u.T @ A.T / total_u          # [i = tx, j = ty]: W[y, x] A_i[x] A_j[y]
    kv = A @ weight_v.T @ A.T / total_v
    kw = np.outer(A.mean(axis=1), A.mean(axis=1))
    # |C_j(y) C_i(x) - E_j(y) E_i(x)|^2 = A_j A_i + 1 - 2 Re(D_j D_i)
    ke = (A @ power.T @ A.T + total_p - 2.0 * (D.real @ power.T @ D.real.T - D.imag @ power.T @ D.imag.T)) / total_p
    flat = np.ones((size, size))
    ke_white = (A @ flat @ A.T + flat.sum() - 2.0 * (D.real @ flat @ D.real.T - D.imag @ flat @ D.imag.T)) / flat.sum()
    # white noise of unit variance adds sum(taper^2) to every frequency bin of every tile
    per_variance = float(tiles * np.sum(taper ** 2) * size * size)
    return NoiseGainTable(_PHASES.copy(), ku, kv, kw, ke, ke_white, float(np.sum(power)), per_variance)


# ---------------------------------------------------------------------------------------------------------------
# Reference subsets: Hessians
# ---------------------------------------------------------------------------------------------------------------

@numba.njit(cache=True, parallel=True)
def _hessians(image, grad_x, grad_y, weighted_gx, weighted_gy, xs, ys, half, order, hinv_out, hinvw_out,
              delta_f_out, ok_out):
    n = 2 * half + 1
    npar = 6 if order == 1 else 12
    for k in numba.prange(xs.size):
        f = np.empty(n * n)
        fx = np.empty(n * n)
        fy = np.empty(n * n)
        a = np.empty(npar)
        s = np.empty(npar)
        hinv = np.empty((npar, npar))
        status, delta_f, _, _ = prepare_reference(image, grad_x, grad_y, xs[k], ys[k], half, order, 0.0, f, fx, fy,
                                                  hinv, a, s)
        if status != CONVERGED:
            ok_out[k] = False
            continue
        hinv_out[k] = hinv
        delta_f_out[k] = delta_f
        status, _, _, _ = prepare_reference(image, weighted_gx, weighted_gy, xs[k], ys[k], half, order, 0.0, f, fx,
                                            fy, hinv, a, s)
        if status != CONVERGED:
            ok_out[k] = False
            continue
        hinvw_out[k] = hinv
        ok_out[k] = True


#: Least fraction of a subset's gradient information (along its worst shape-parameter direction) that must be
#: texture rather than noise for its sigma to be given (below it: FLAG_SINGULAR, NaN).
MIN_SIGNAL_FRACTION = 0.2


def _signal_fraction(h: np.ndarray, h0: np.ndarray) -> np.ndarray:
    """Smallest eigenvalue of ``H^-1/2 H0 H^-1/2`` per subset (N,): the signal's share of the worst direction."""
    d = 1.0 / np.sqrt(np.abs(np.einsum("kii->ki", h)))
    hs = h * d[:, :, None] * d[:, None, :]
    h0s = h0 * d[:, :, None] * d[:, None, :]
    out = np.zeros(h.shape[0])
    idx = np.flatnonzero(np.all(np.isfinite(hs), axis=(1, 2)) & np.all(np.isfinite(h0s), axis=(1, 2)))
    try:
        L = np.linalg.cholesky(hs[idx])
    except np.linalg.LinAlgError:           # one not positive definite: one by one, that one scores 0
        for k in idx:
            try:
                Li = np.linalg.inv(np.linalg.cholesky(hs[k]))
            except np.linalg.LinAlgError:
                continue
            out[k] = np.linalg.eigvalsh(Li @ h0s[k] @ Li.T)[0]
        return out
    Li = np.linalg.inv(L)
    out[idx] = np.linalg.eigvalsh(Li @ h0s[idx] @ np.swapaxes(Li, 1, 2))[:, 0]
    return out


def _scaled_inverse(m: np.ndarray) -> np.ndarray:
    """Inverse of a batch (N, n, n) of SPD matrices with Jacobi scaling (their entries span ~10^6)."""
    d = 1.0 / np.sqrt(np.abs(np.einsum("kii->ki", m)))
    scaled = m * d[:, :, None] * d[:, None, :]
    return np.linalg.inv(scaled) * d[:, :, None] * d[:, None, :]


def _monomial_moments(half: int, order: int) -> np.ndarray:
    """``sum m m^T`` over the square subset for the shape function's monomials (nm, nm)."""
    d = np.arange(-half, half + 1, dtype=np.float64)
    dx, dy = np.meshgrid(d, d)
    monomials = [np.ones_like(dx), dx, dy] + ([0.5 * dx * dx, dx * dy, 0.5 * dy * dy] if order == 2 else [])
    m = np.stack([v.ravel() for v in monomials])
    return m @ m.T


@dataclass(frozen=True)
class ReferenceSubsets:
    """The reference-side terms of :func:`match_uncertainty`, computed once per reference image and grid.

    Attributes
    ----------
    x, y : ndarray of int64 (N,)
    cov_uv_reference : ndarray (N, 2, 2)
        The (u, v) block of ``H0^-1 J^T S_f J H0^-1``, px^2: the reference noise's part of every match.
    var_parameters_reference : ndarray (N, np)
        Its diagonal over all shape parameters (px^2, px^2/px^2 for the gradients, ...).
    uv_rows : ndarray (N, 2, np)
        The u and v rows of ``H0^-1``: a point's (u, v) error is ``uv_rows J^T n`` for image noise ``n`` on its
        subset (what correlates neighbouring points, :mod:`measurement.uncertainty.strain`).
    mean_grey, variance_reference : ndarray (N,)
        Subset mean grey level and mean reference noise variance (grey^2).
    delta_f : ndarray (N,)
        ``sqrt(sum (f - f_m)^2)``, grey.
    ok : ndarray of bool (N,)
    clipped : ndarray of bool (N,)
        More than :data:`MAX_CLIPPED_FRACTION` of the subset is clipped (saturated or black): no sigma.
    subset_size, order : int
    gains : NoiseGainTable
    noise_reference : NoiseModel
    """

    x: np.ndarray
    y: np.ndarray
    cov_uv_reference: np.ndarray = field(repr=False)
    var_parameters_reference: np.ndarray = field(repr=False)
    uv_rows: np.ndarray = field(repr=False)
    mean_grey: np.ndarray = field(repr=False)
    variance_reference: np.ndarray = field(repr=False)
    delta_f: np.ndarray = field(repr=False)
    ok: np.ndarray = field(repr=False)
    clipped: np.ndarray = field(repr=False)
    subset_size: int = 0
    order: int = 1
    gains: NoiseGainTable | None = field(default=None, repr=False)
    noise_reference: NoiseModel | None = None

    @property
    def n_parameters(self) -> int:
        return 6 if self.order == 1 else 12

    @property
    def uv_index(self) -> tuple[int, int]:
        return 0, self.n_parameters // 2


def reference_subsets(reference, x_px, y_px, subset_size: int, order: int, noise_reference: NoiseModel,
                      interpolation: str = "biquintic", gains: NoiseGainTable | None = None) -> ReferenceSubsets:
    """Hessians and the reference noise's covariance of every subset centred at (x_px, y_px).

    Parameters
    ----------
    reference : ndarray (rows, cols) or PreparedImage (with gradients)
    x_px, y_px : array of int (N,)
        Subset centres (the points of interest), px.
    subset_size : int (odd); order : 1 or 2
    noise_reference : NoiseModel
        The reference image's noise.
    interpolation : 'biquintic' or 'bicubic'
    gains : NoiseGainTable, optional
        :func:`interpolation_noise_gain` of this reference, if already computed.
    """
    if isinstance(reference, PreparedImage):
        prepared = reference
    else:
        prepared = prepare_image(np.asarray(reference), interpolation, True, "reference")
    values = prepared.values
    gx, gy = prepared.spline.grad_x, prepared.spline.grad_y
    if gx is None:
        raise ValueError("the prepared reference has no gradients (prepare_image(..., gradients=True))")
    degree = prepared.spline.degree
    xs = np.asarray(x_px, dtype=np.int64).ravel()
    ys = np.asarray(y_px, dtype=np.int64).ravel()
    half = int(subset_size) // 2
    npar = 6 if order == 1 else 12
    nm = npar // 2
    variance = noise_reference.sigma_at(np.where(np.isfinite(values), values, 0.0)) ** 2
    root = np.sqrt(variance)
    hinv = np.full((xs.size, npar, npar), np.nan)
    hinvw = np.full((xs.size, npar, npar), np.nan)
    delta_f = np.full(xs.size, np.nan)
    ok = np.zeros(xs.size, dtype=np.bool_)
    _hessians(values, gx, gy, np.ascontiguousarray(gx * root), np.ascontiguousarray(gy * root), xs, ys, half,
              int(order), hinv, hinvw, delta_f, ok)
    # subset means of the grey level and of the noise variance (box filters on integral images)
    mean_grey = _box_mean(values, xs, ys, half)
    mean_var = _box_mean(variance, xs, ys, half)
    ok &= np.isfinite(mean_grey)
    clipped = _box_mean(_clipped_pixels(values).astype(np.float64), xs, ys, half) > MAX_CLIPPED_FRACTION
    ok &= ~clipped
    cov_uv = np.full((xs.size, 2, 2), np.nan)
    var_all = np.full((xs.size, npar), np.nan)
    uv_rows = np.full((xs.size, 2, npar), np.nan)
    if ok.any():
        idx = np.flatnonzero(ok)
        h = _scaled_inverse(hinv[idx])
        hw = _scaled_inverse(hinvw[idx])
        moments = _monomial_moments(half, order)
        correction = np.zeros((npar, npar))
        correction[:nm, :nm] = moments
        correction[nm:, nm:] = moments
        h0 = h - gradient_noise_gain(degree) * mean_var[idx, None, None] * correction
        # Where the noise makes up much of the gradient energy along some shape parameter (texture buried in noise,
        # an edge subset), H0 = H - noise is a small difference of large numbers and its inverse, hence the sigma,
        # is not reliable: the fraction of each direction's information that is signal -- the eigenvalues of
        # H^-1/2 H0 H^-1/2, in (0, 1] -- must be at least MIN_SIGNAL_FRACTION, else the point has no sigma.
        eig_ok = _signal_fraction(h, h0) >= MIN_SIGNAL_FRACTION
        good = idx[eig_ok]
        inv0 = _scaled_inverse(h0[eig_ok])
        cov = inv0 @ hw[eig_ok] @ inv0
        cov_uv[good] = cov[:, [0, nm]][:, :, [0, nm]]
        var_all[good] = np.einsum("kii->ki", cov)
        uv_rows[good] = inv0[:, [0, nm], :]
        ok[idx[~eig_ok]] = False
    if gains is None:
        box = (int(xs.min()) - half, int(ys.min()) - half, int(xs.max()) + half + 1, int(ys.max()) + half + 1) \
            if xs.size else None
        gains = interpolation_noise_gain(values, degree, box=box)
    return ReferenceSubsets(xs, ys, cov_uv, var_all, uv_rows, mean_grey, mean_var, delta_f, ok, clipped,
                            int(subset_size), int(order),
                            gains, noise_reference)


def _clipped_pixels(values: np.ndarray) -> np.ndarray:
    """Pixels at the image's maximum or minimum where that value is a plateau (held by more than 0.1 % of the
    pixels): a sensor's saturation or black level, not texture."""
    finite = values[np.isfinite(values)]
    out = np.zeros(values.shape, dtype=bool)
    if finite.size == 0:
        return out
    for level in (finite.max(), finite.min()):
        at = values == level
        if np.count_nonzero(at) > 1e-3 * finite.size:
            out |= at
    return out


def _box_mean(values: np.ndarray, xs: np.ndarray, ys: np.ndarray, half: int) -> np.ndarray:
    """Mean of ``values`` over each (2 half + 1)^2 box centred at (xs, ys); NaN if the box leaves the image or
    holds a NaN."""
    out = np.full(xs.size, np.nan)
    rows, cols = values.shape
    inside = (xs - half >= 0) & (ys - half >= 0) & (xs + half < cols) & (ys + half < rows)
    if not inside.any():
        return out
    finite = np.isfinite(values)
    x0, y0 = xs[inside] - half, ys[inside] - half
    x1, y1 = x0 + 2 * half + 1, y0 + 2 * half + 1

    def box_sum(image):
        integral = np.zeros((rows + 1, cols + 1))
        integral[1:, 1:] = image.cumsum(0).cumsum(1)
        return integral[y1, x1] - integral[y0, x1] - integral[y1, x0] + integral[y0, x0]

    total = box_sum(np.where(finite, values, 0.0))
    holes = box_sum((~finite).astype(np.float64))
    out[inside] = np.where(holes > 0.5, np.nan, total / float((2 * half + 1) ** 2))
    return out


# ---------------------------------------------------------------------------------------------------------------
# A match
# ---------------------------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class MatchUncertainty:
    """Random uncertainty of every point of one match (arrays over its N points).

    Attributes
    ----------
    sigma_u_px, sigma_v_px : ndarray (N,)
        Standard uncertainty of u and v (both images' noise), px; NaN where the point has no match or its
        subset's Hessian is singular (``flag`` says which).
    cov_reference_px2, cov_target_px2 : ndarray (N, 2, 2)
        Covariance of (u, v) from the reference image's noise (shared by every match of the same reference
        subset) and from the target image's noise, px^2.
    sigma_parameters : ndarray (N, 12)
        Standard uncertainty of every shape parameter (PARAMETER_NAMES order; NaN for terms the order lacks).
    residual_ratio : ndarray (N,)
        Converged ZNSSD residual over what the noise explains (1 for a perfect fit).
    flag : ndarray of int8 (N,)
        0 trusted; :data:`FLAG_NAMES` otherwise.
    noise_source : str
        Where the noise came from: "static pair", "match residuals", "single image", "given".
    noise_reference, noise_target : NoiseModel
    bias_bound_px : ndarray (N, 2) or None
        Bound on the interpolation bias of u and v over sub-pixel shifts (:mod:`measurement.uncertainty.bias`):
        systematic, kept apart from the random sigma; None when not computed.
    misfit_bias_px : ndarray (N, 2) or None
        Estimated (signed) error of u and v from the shape function's misfit, px
        (:mod:`measurement.uncertainty.misfit`): systematic, like the bias bound; None when not computed.
    """

    sigma_u_px: np.ndarray
    sigma_v_px: np.ndarray
    cov_reference_px2: np.ndarray = field(repr=False)
    cov_target_px2: np.ndarray = field(repr=False)
    sigma_parameters: np.ndarray = field(repr=False)
    residual_ratio: np.ndarray = field(repr=False)
    flag: np.ndarray = field(repr=False)
    noise_source: str = ""
    noise_reference: NoiseModel | None = None
    noise_target: NoiseModel | None = None
    bias_bound_px: np.ndarray | None = field(default=None, repr=False)
    misfit_bias_px: np.ndarray | None = field(default=None, repr=False)

    @property
    def trusted(self) -> np.ndarray:
        return (self.flag == FLAG_NONE) & np.isfinite(self.sigma_u_px)

    def columns(self) -> dict[str, np.ndarray]:
        """Per-point columns for result files: sigma_u_px, sigma_v_px, residual_ratio, sigma_flag (and
        bias_bound_u_px, bias_bound_v_px, misfit_bias_u_px, misfit_bias_v_px when the systematic terms were
        computed)."""
        out = {"sigma_u_px": self.sigma_u_px, "sigma_v_px": self.sigma_v_px,
               "residual_ratio": self.residual_ratio, "sigma_flag": self.flag.astype(np.int64)}
        if self.bias_bound_px is not None:
            out |= {"bias_bound_u_px": self.bias_bound_px[:, 0], "bias_bound_v_px": self.bias_bound_px[:, 1]}
        if self.misfit_bias_px is not None:
            out |= {"misfit_bias_u_px": self.misfit_bias_px[:, 0], "misfit_bias_v_px": self.misfit_bias_px[:, 1]}
        return out

    def summary(self) -> dict:
        """Median sigma of u and v over the trusted points, the flagged fraction, the noise source."""
        t = self.trusted
        measured = np.isfinite(self.sigma_u_px) | (self.flag == FLAG_RESIDUAL)
        return {"median_sigma_u_px": float(np.median(self.sigma_u_px[t])) if t.any() else math.nan,
                "median_sigma_v_px": float(np.median(self.sigma_v_px[t])) if t.any() else math.nan,
                "flagged_fraction": float(np.count_nonzero(self.flag == FLAG_RESIDUAL) / max(1, measured.sum())),
                "noise_source": self.noise_source}


def _warp_phases(parameters: np.ndarray, half: int, samples: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """Fractional target positions of a ``samples`` x ``samples`` lattice over each warped subset, (N, S)."""
    d = np.linspace(-half, half, samples)
    dx, dy = (v.ravel() for v in np.meshgrid(d, d))
    p = np.nan_to_num(parameters)
    u = (p[:, [0]] + p[:, [1]] * dx + p[:, [2]] * dy + 0.5 * p[:, [3]] * dx * dx + p[:, [4]] * dx * dy
         + 0.5 * p[:, [5]] * dy * dy)
    v = (p[:, [6]] + p[:, [7]] * dx + p[:, [8]] * dy + 0.5 * p[:, [9]] * dx * dx + p[:, [10]] * dx * dy
         + 0.5 * p[:, [11]] * dy * dy)
    return u, v


def match_uncertainty(subsets: ReferenceSubsets, result: DICResult, noise_target: NoiseModel | None = None, *,
                      noise_source: str | None = None,
                      max_residual_ratio: float = DEFAULT_MAX_RESIDUAL_RATIO) -> MatchUncertainty:
    """Per-point uncertainty of ``result`` (a match of the reference of ``subsets`` to a target image).

    ``noise_target`` defaults to the reference's noise model (same camera, temporal match). The points of
    ``result`` must be those of ``subsets`` (same order).
    """
    if not (np.array_equal(result.x, subsets.x) and np.array_equal(result.y, subsets.y)):
        raise ValueError("the match's points of interest differ from the reference subsets' (same grid needed)")
    if result.settings.order != subsets.order or result.settings.subset_size != subsets.subset_size:
        raise ValueError(f"the match used subset {result.settings.subset_size} px order {result.settings.order}, the "
                         f"reference subsets {subsets.subset_size} px order {subsets.order}")
    if not (np.isfinite(max_residual_ratio) and max_residual_ratio > 1):
        raise ValueError(f"max_residual_ratio must be a number > 1, got {max_residual_ratio!r}")
    noise_reference = subsets.noise_reference
    noise_target = noise_target or noise_reference
    source = noise_source or _source_of(noise_reference, noise_target)
    n = subsets.x.size
    npar = subsets.n_parameters
    matched = (result.status == CONVERGED) & subsets.ok
    flag = np.where(matched, FLAG_NONE, np.where(result.status == CONVERGED, FLAG_SINGULAR, FLAG_NO_MATCH))
    flag = np.where((result.status == CONVERGED) & subsets.clipped, FLAG_SATURATED, flag).astype(np.int8)
    cov_ref = np.full((n, 2, 2), np.nan)
    cov_tgt = np.full((n, 2, 2), np.nan)
    sigma_parameters = np.full((n, 12), np.nan)
    ratio = np.full(n, np.nan)
    if matched.any():
        idx = np.flatnonzero(matched)
        cov_ref[idx] = subsets.cov_uv_reference[idx]
        var_t = noise_target.sigma_at(subsets.mean_grey[idx]) ** 2
        var_f = subsets.variance_reference[idx]
        scale = var_t / np.maximum(var_f, 1e-300)
        pu, pv = _warp_phases(result.parameters[idx], subsets.subset_size // 2)
        ku = subsets.gains.lookup("u", pu, pv).mean(axis=1)
        kv = subsets.gains.lookup("v", pu, pv).mean(axis=1)
        kw = subsets.gains.lookup("white", pu, pv).mean(axis=1)
        gain = np.stack([np.sqrt(ku), np.sqrt(kv)], axis=1)
        cov_tgt[idx] = cov_ref[idx] * (scale[:, None, None] * gain[:, :, None] * gain[:, None, :])
        # every shape parameter: the u-like ones take kappa_u, the v-like kappa_v
        diag = subsets.var_parameters_reference[idx]
        gains_all = np.concatenate([np.repeat(ku[:, None], npar // 2, 1), np.repeat(kv[:, None], npar // 2, 1)], 1)
        var_all = diag * (1.0 + scale[:, None] * gains_all)
        cols = list(range(npar // 2)) + list(range(6, 6 + npar // 2))
        sigma_parameters[np.ix_(idx, cols)] = np.sqrt(var_all)
        # residual check: sum r^2 = Df^2 (2 - 2 ZNCC) against the noise
        pixels = subsets.subset_size ** 2
        observed = subsets.delta_f[idx] ** 2 * (2.0 - 2.0 * result.zncc[idx])
        ke = subsets.gains.signal_interpolation_error(pu, pv, float(np.median(var_f))).mean(axis=1)
        # the interpolant's own error on this texture is a residual too (fine speckle), not a misfit
        explained = (pixels - npar - 2) * (var_f + kw * var_t) + ke * np.maximum(
            subsets.delta_f[idx] ** 2 - pixels * var_f, 0.0)
        ratio[idx] = observed / explained
        high = ratio[idx] > max_residual_ratio
        flag[idx[high]] = FLAG_RESIDUAL
    total = cov_ref + cov_tgt
    sigma_u = np.sqrt(total[:, 0, 0])
    sigma_v = np.sqrt(total[:, 1, 1])
    return MatchUncertainty(sigma_u, sigma_v, cov_ref, cov_tgt, sigma_parameters, ratio, flag, source,
                            noise_reference, noise_target)


def _source_of(reference: NoiseModel, target: NoiseModel) -> str:
    sources = {reference.source, target.source}
    return " + ".join(sorted(sources))


# ---------------------------------------------------------------------------------------------------------------
# Noise from the matches themselves
# ---------------------------------------------------------------------------------------------------------------

def noise_from_residuals(subsets_values: np.ndarray, x_px, y_px, result: DICResult, *, bins: int = 12,
                         interpolation: str = "biquintic", gains: NoiseGainTable | None = None) -> NoiseModel:
    """A noise model fitted to the converged matches' ZNSSD residuals (both images assumed alike).

    Each converged subset's residual variance ``Df^2 (2 - 2 ZNCC) / (n - n_p - 2)`` estimates
    ``sigma^2(I) (1 + kappa_0)`` at its mean grey level ``I`` once the interpolant's own error on the texture
    (:attr:`NoiseGainTable.interpolation_error`) is taken off; the medians in ``bins`` grey-level bins (robust to
    the subsets a shape function cannot follow) are fitted by ``read^2 + I / gain`` (non-negative least squares).
    Misfit and interpolation error count as noise here: the model errs high, never low.

    Raises
    ------
    ValueError
        Fewer than 20 converged points: the residuals cannot support a noise estimate.
    """
    from scipy.optimize import nnls

    values = np.asarray(subsets_values, dtype=np.float64)
    xs = np.asarray(x_px, dtype=np.int64)
    ys = np.asarray(y_px, dtype=np.int64)
    half = result.settings.subset_size // 2
    ok = result.converged & np.isfinite(result.zncc)
    if np.count_nonzero(ok) < 20:
        raise ValueError(f"only {np.count_nonzero(ok)} converged points: too few to estimate the noise from the "
                         "match residuals (give a noise model from a static pair)")
    mean = _box_mean(values, xs[ok], ys[ok], half)
    sq = _box_mean(values * values, xs[ok], ys[ok], half)
    pixels = (2 * half + 1) ** 2
    npar = 6 if result.settings.order == 1 else 12
    delta_f2 = np.maximum(sq - mean * mean, 0.0) * pixels
    residual_var = delta_f2 * (2.0 - 2.0 * result.zncc[ok]) / (pixels - npar - 2)
    if gains is None:
        gains = interpolation_noise_gain(values, bspline.degree_of(interpolation))
    pu, pv = _warp_phases(result.parameters[ok], half)
    kw = gains.lookup("white", pu, pv).mean(axis=1)
    # the interpolation error's estimate needs the noise (its share of the spectrum): a few fixed-point steps
    var = residual_var / (1.0 + kw)
    for _ in range(3):
        ke = gains.signal_interpolation_error(pu, pv, float(np.nanmedian(var))).mean(axis=1)
        var = np.maximum(residual_var - ke * delta_f2 / (pixels - npar - 2), 0.0) / (1.0 + kw)
    good = np.isfinite(var) & np.isfinite(mean)
    mean, var = mean[good], var[good]
    edges = np.unique(np.quantile(mean, np.linspace(0, 1, bins + 1)))
    which = np.clip(np.searchsorted(edges, mean, side="right") - 1, 0, len(edges) - 2)
    grey, med = [], []
    for b in range(len(edges) - 1):
        sel = which == b
        if np.count_nonzero(sel) >= 5:
            grey.append(float(np.median(mean[sel])))
            med.append(float(np.median(var[sel])))
    grey, med = np.array(grey), np.array(med)
    if grey.size >= 3 and np.ptp(grey) > 1e-6:
        coef, _ = nnls(np.column_stack([np.ones_like(grey), np.clip(grey, 0, None)]), med)
        read2, slope = float(coef[0]), float(coef[1])
    else:
        read2, slope = float(np.median(var)), 0.0
    model = NoiseModel(float(np.sqrt(np.median(var))), float(np.sqrt(read2)), (1.0 / slope) if slope > 0 else None,
                       "match residuals", grey, med)
    return model


def dic_uncertainty(reference, result: DICResult, noise_reference: NoiseModel | None = None,
                    noise_target: NoiseModel | None = None, *,
                    max_residual_ratio: float = DEFAULT_MAX_RESIDUAL_RATIO, bias: bool = False) -> MatchUncertainty:
    """Uncertainty of a 2-D match in one call: :func:`reference_subsets` + :func:`match_uncertainty` (and, with
    ``bias``, the systematic terms of every point: the interpolation bias bound,
    :func:`measurement.uncertainty.bias.bias_bound_px`, and the shape function's misfit estimated from the measured
    field, :func:`measurement.uncertainty.misfit.misfit_bias_px`).

    Without ``noise_reference`` the noise is fitted to the match's residuals (:func:`noise_from_residuals`, both
    images alike); ``noise_target`` defaults to ``noise_reference``.

    Raises
    ------
    ValueError
        Too few converged points to fit the noise from the residuals (and no model given).
    """
    settings = result.settings
    prepared = reference if isinstance(reference, PreparedImage) else prepare_image(
        np.asarray(reference), settings.interpolation, True, "reference", settings.lowpass_sigma_px)
    half = settings.subset_size // 2
    box = (int(result.x.min()) - half, int(result.y.min()) - half, int(result.x.max()) + half + 1,
           int(result.y.max()) + half + 1) if result.x.size else None
    gains = interpolation_noise_gain(prepared.values, prepared.spline.degree, box=box)
    if noise_reference is None:
        noise_reference = noise_from_residuals(prepared.values, result.x, result.y, result,
                                               interpolation=settings.interpolation, gains=gains)
    subsets = reference_subsets(prepared, result.x, result.y, settings.subset_size, settings.order, noise_reference,
                                settings.interpolation, gains=gains)
    unc = match_uncertainty(subsets, result, noise_target, max_residual_ratio=max_residual_ratio)
    if bias:
        from dataclasses import replace

        from .bias import bias_bound_px
        from .misfit import misfit_bias_px

        unc = replace(unc, bias_bound_px=bias_bound_px(prepared.values, result.x, result.y, settings.subset_size,
                                                       settings.interpolation, order=settings.order),
                      misfit_bias_px=misfit_bias_px(prepared, result, subsets.uv_rows))
    return unc


def static_repeat_covariance_px2(cov_reference_px2: np.ndarray) -> np.ndarray:
    """Covariance of (u, v) for a *static repeat* of a reference image (the 2-D noise floor), px^2, (N, 2, 2).

    A second exposure of the unmoved pattern is sampled at the reference's own whole pixels, where the interpolant's
    noise gain is 1 and, for the same camera, its noise equals the reference's: the target part equals the
    reference part, so ``Cov (u, v) = 2 C_ref``. What a digital twin predicts from the reference image alone
    (the stereo counterpart is :func:`measurement.uncertainty.stereo.static_repeat_covariance_mm2`).

    Parameters
    ----------
    cov_reference_px2 : ndarray (N, 2, 2)
        The reference noise's part of the match, px^2 (:attr:`ReferenceSubsets.cov_uv_reference` or
        :attr:`MatchUncertainty.cov_reference_px2`).
    """
    cov = np.asarray(cov_reference_px2, dtype=np.float64)
    if cov.ndim != 3 or cov.shape[1:] != (2, 2):
        raise ValueError(f"cov_reference_px2 must have shape (N, 2, 2), got {cov.shape}")
    return 2.0 * cov
