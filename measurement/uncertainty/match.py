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
  apart (:attr:`MatchUncertainty.cov_reference_px2`, and the factor ``F`` with ``F F^T`` = it,
  :attr:`MatchUncertainty.reference_factor`, from which two matches' shared part follows).
* The **target part** is the same form with the target's noise, ``S_g = sigma_g^2(I)``, passed through the
  interpolant: at sub-pixel phase ``t`` the interpolated noise is white noise filtered by the cardinal spline
  shifted by ``t``, whose gain on the subset's gradient spectrum ``kappa(t) <= 1`` (1 at whole pixels; for
  biquintic on 3 px speckle 0.98 at half a pixel along the gradient's axis, while white noise -- what the residual
  sees -- drops to 0.84 per axis, 0.70 at (0.5, 0.5)) is read from a table of the reference image's gradient
  spectrum (:func:`interpolation_noise_gain`) and averaged over the warped subset.

**When the target is not a repeat of the reference's view** -- the other camera of a stereo rig, which sees the
speckle blurred, foreshortened or magnified differently, or a strongly strained state -- ``H0`` is the wrong
sensitivity. Linearising the converged condition in the match's own terms (:func:`cross_hessians`, with the target
image):

* the Hessian is the **cross-Hessian** ``M = (Df / Dg) sum J (G - G_m)^T``, ``G = grad g(W(x)) . dW/dp`` the
  target's gradients at the warped positions: a target blurred more than the reference has less gradient energy,
  so the match moves more (its expectation over the noise needs no noise correction: J and G hold independent
  noises);
* the reference's noise enters through ``J n_f + (grad n_f) r``: where the target's texture differs from the
  reference's the residual ``r`` is not noise, and summation by parts turns the two into
  ``(Df / Dg) K n_f``, ``K = grad(g o W)`` pulled back to the reference frame (its weight
  ``W = (Df / Dg)^2 sum S_f K K^T``; for a repeat ``K = J``);
* the target's noise enters through ``J``, scaled by ``Df / Dg``, at the target's own pixel density: a subset the
  warp ``A = dW/dx`` spreads over ``|det A|`` target pixels sees ``1 / |det A|`` of the noise power per reference
  pixel (sigma of u goes as the target's scale).

So ``Cov = M^-1 [W + (Df / Dg)^2 kappa / |det A| J^T S_g J] M^-T``. Measured on exact speckle pairs (36 noise
draws; ``tests/test_match_uncertainty.py``): a target blurred by a 1 px Gaussian on 4 px speckle moves u 1.6 times
what ``H0`` says, a 1.5 px one 2.7 times; the target scaled by 0.8 (1.25) 0.85 (1.23) times; with ``M`` every
case's std(error / sigma) is 0.96-1.03. The sums run over every ``stride``-th row and column of a large subset
(:func:`cross_stride`); a later match of the same camera reuses the known terms where its warp strains by less
than :data:`CROSS_REUSE_TOLERANCE` (``like=`` of :func:`match_uncertainty`). Without a target image ``M = H0``.

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
from measurement.dic.icgn import MONOMIALS, prepare_reference
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


@numba.njit(cache=True, parallel=True, fastmath=True)
def _cross_moments(ref_gx, ref_gy, variance, coefficients, degree, xs, ys, parameters, half, order, stride, out,
                   ok_out):
    """Per subset, the sums :func:`cross_hessians` needs, from the reference gradients and noise variance at its
    pixels (every ``stride``-th row and column) and the target interpolant's value and gradient at their warped
    positions.

    out (N, 4 + 7 P2 + 4 P1): [sum g, sum g^2, count, 0]; per moment ``dx^a dy^b`` (a + b <= 2 order, P2 of them)
    the sums of f_x g_x, f_x g_y, f_y g_x, f_y g_y times it; per such moment the sums of var k_x k_x, var k_x k_y,
    var k_y k_y (``k = grad (g o W)`` in the reference frame, ``var`` the reference noise variance) times it; per
    moment a + b <= order (P1) the sums of f_x, f_y, g_x, g_y times it. Each row accumulates its sums by powers of
    dx alone; the powers of dy enter once per row."""
    deg2 = 2 * order
    k_base = 4 + 4 * ((deg2 + 1) * (deg2 + 2) // 2)
    first_base = k_base + 3 * ((deg2 + 1) * (deg2 + 2) // 2)
    for k in numba.prange(xs.size):
        wx = np.empty(6)
        wy = np.empty(6)
        dwx = np.empty(6)
        dwy = np.empty(6)
        row2 = np.empty((7, deg2 + 1))
        row1 = np.empty((4, order + 1))
        acc = np.zeros(out.shape[1])
        p = parameters[k]
        good = True
        for r in range(-half, half + 1, stride):
            dy = float(r)
            row2[:] = 0.0
            row1[:] = 0.0
            s0 = 0.0
            s1 = 0.0
            cnt = 0.0
            # the warp along this row: u, v and the pull-back's entries are polynomials in dx
            u0 = p[0] + p[2] * dy + 0.5 * p[5] * dy * dy
            u1 = p[1] + p[4] * dy
            v0 = p[6] + p[8] * dy + 0.5 * p[11] * dy * dy
            v1 = p[7] + p[10] * dy
            for c in range(-half, half + 1, stride):
                dx = float(c)
                u = u0 + u1 * dx + 0.5 * p[3] * dx * dx
                v = v0 + v1 * dx + 0.5 * p[9] * dx * dx
                ok, g, gx, gy = bspline.value_gradient(coefficients, degree, xs[k] + dx + u, ys[k] + dy + v,
                                                       wx, wy, dwx, dwy)
                if not ok:
                    good = False
                    break
                fx = ref_gx[ys[k] + r, xs[k] + c]
                fy = ref_gy[ys[k] + r, xs[k] + c]
                var = variance[ys[k] + r, xs[k] + c]
                kx = gx * (1.0 + p[1] + p[3] * dx + p[4] * dy) + gy * (p[7] + p[9] * dx + p[10] * dy)
                ky = gx * (p[2] + p[4] * dx + p[5] * dy) + gy * (1.0 + p[8] + p[10] * dx + p[11] * dy)
                s0 += g
                s1 += g * g
                cnt += 1.0
                q0 = fx * gx
                q1 = fx * gy
                q2 = fy * gx
                q3 = fy * gy
                w0 = var * kx * kx
                w1 = var * kx * ky
                w2 = var * ky * ky
                pa = 1.0
                for a in range(deg2 + 1):
                    row2[0, a] += q0 * pa
                    row2[1, a] += q1 * pa
                    row2[2, a] += q2 * pa
                    row2[3, a] += q3 * pa
                    row2[4, a] += w0 * pa
                    row2[5, a] += w1 * pa
                    row2[6, a] += w2 * pa
                    if a <= order:
                        row1[0, a] += fx * pa
                        row1[1, a] += fy * pa
                        row1[2, a] += gx * pa
                        row1[3, a] += gy * pa
                    pa *= dx
            if not good:
                break
            acc[0] += s0
            acc[1] += s1
            acc[2] += cnt
            slot = 0
            for a in range(deg2 + 1):
                pb = 1.0
                for b in range(deg2 + 1 - a):
                    for q in range(4):
                        acc[4 + 4 * slot + q] += row2[q, a] * pb
                    for q in range(3):
                        acc[k_base + 3 * slot + q] += row2[4 + q, a] * pb
                    slot += 1
                    pb *= dy
            m = 0
            for a in range(order + 1):
                pb = 1.0
                for b in range(order + 1 - a):
                    for q in range(4):
                        acc[first_base + 4 * m + q] += row1[q, a] * pb
                    m += 1
                    pb *= dy
        ok_out[k] = good
        if good:
            area = float(stride * stride)
            for q in range(out.shape[1]):
                out[k, q] = acc[q] * area


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


def _sqrtm(m: np.ndarray) -> np.ndarray:
    """Symmetric square roots of a batch (N, n, n) of symmetric positive semi-definite matrices."""
    d = np.sqrt(np.abs(np.einsum("kii->ki", m)))
    d = np.where(d > 0, d, 1.0)
    scaled = m / d[:, :, None] / d[:, None, :]
    w, v = np.linalg.eigh(scaled)
    root = (v * np.sqrt(np.clip(w, 0.0, None))[:, None, :]) @ np.swapaxes(v, 1, 2)
    # (D S D)^1/2 is not D S^1/2 D; a congruence keeps the factor property: (D R)(D R)^T = D S D
    return d[:, :, None] * root


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
    weighted_hessian : ndarray (N, np, np)
        ``J^T S_f J``: the reference noise's covariance of the normal equations' right side, grey^2 x Hessian.
    reference : PreparedImage or None
        The reference image with its gradients (the cross-Hessian of a match needs them).
    inverse : ndarray (N, np, np)
        ``H0^-1``.
    reference_factor : ndarray (N, 2, np)
        ``uv_rows (J^T S_f J)^1/2``: the reference noise's effect on (u, v) of a match that repeats the reference's
        view (:attr:`MatchUncertainty.reference_factor`).
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
    weighted_hessian: np.ndarray | None = field(default=None, repr=False)
    reference: PreparedImage | None = field(default=None, repr=False)
    inverse: np.ndarray | None = field(default=None, repr=False)
    reference_factor: np.ndarray | None = field(default=None, repr=False)

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
    weighted = np.full((xs.size, npar, npar), np.nan)
    inverse = np.full((xs.size, npar, npar), np.nan)
    factor = np.full((xs.size, 2, npar), np.nan)
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
        weighted[good] = hw[eig_ok]
        inverse[good] = inv0
        factor[good] = inv0[:, [0, nm], :] @ _sqrtm(hw[eig_ok])
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
                            gains, noise_reference, weighted, prepared, inverse, factor)


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
    reference_factor : ndarray (N, 2, np) or None
        ``F`` with ``F F^T`` = the reference noise's part of (u, v), ``F = (M^-1)_uv W^1/2``: two matches of one
        reference subset share ``F_1 F_2^T`` of it (exact when their weights ``W`` are proportional: the
        stereo covariances, :mod:`measurement.uncertainty.stereo`).
    cross : CrossTerms or None
        This match's cross-Hessian terms, kept (``keep_cross``) for later matches to reuse
        (``like=`` of :func:`match_uncertainty`).
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
    reference_factor: np.ndarray | None = field(default=None, repr=False)
    cross: "CrossTerms | None" = field(default=None, repr=False)

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



#: Fewest subset pixels the cross-Hessian's sums sample: a larger subset is sampled every ``stride``-th row and
#: column (:func:`cross_stride`), its sums scaled by ``stride^2``.
CROSS_MIN_SAMPLES = 900


def cross_stride(subset_size: int) -> int:
    """Row and column step of the cross-Hessian's sums over a subset of ``subset_size`` px: the largest that keeps
    at least :data:`CROSS_MIN_SAMPLES` pixels (1 up to 59 px, 2 for the paper's 65 px)."""
    stride = 1
    while ((subset_size + stride) // (stride + 1)) ** 2 >= CROSS_MIN_SAMPLES:
        stride += 1
    return stride


def _moment_slots(order: int) -> tuple[dict, dict]:
    """Slots of :func:`_cross_moments`' table: ``(a, b) -> k`` for ``dx^a dy^b``, a + b <= 2 order (products of
    two monomials) and a + b <= order (the monomials), in the kernel's loop order."""
    second, first = {}, {}
    for a in range(2 * order + 1):
        for b in range(2 * order + 1 - a):
            second[(a, b)] = len(second)
    for a in range(order + 1):
        for b in range(order + 1 - a):
            first[(a, b)] = len(first)
    return second, first


def cross_hessians(subsets: ReferenceSubsets, target: PreparedImage, parameters: np.ndarray, *,
                   points: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray,
                                                               np.ndarray]:
    """The match's cross-Hessian ``M = (Df / Dg) sum J (G - G_m)^T`` per subset, from the reference gradients ``J``
    at its pixels and the target interpolant's gradients ``G = grad g(W(x)) . dW/dp`` at their converged warped
    positions (the module notes say why ``M`` and not ``H``).

    Parameters
    ----------
    subsets : ReferenceSubsets (with its ``reference``)
    target : PreparedImage
        The target image of the match.
    parameters : ndarray (N, 12)
        The match's converged shape parameters.
    points : array of int, optional
        Only these of the N points (the outputs are then over them).

    Returns
    -------
    M : ndarray (N, np, np)
    reference_weight : ndarray (N, np, np)
        ``(Df / Dg)^2 sum var_f K K^T``, ``K = grad (g o W) . dm`` in the reference frame: how the reference's noise
        reaches the normal equations once the match has converged on a target that differs from it (module notes).
    contrast_ratio : ndarray (N,)
        ``Df / Dg``: the reference subset's grey-level spread over the target's.
    mean_target : ndarray (N,)
        The warped target subset's mean grey level.
    ok : ndarray of bool (N,)
        False where the warped subset leaves the target (or the parameters are not finite).
    """
    if subsets.reference is None:
        raise ValueError("these reference subsets keep no reference image: the cross-Hessian needs its gradients")
    order = subsets.order
    half = subsets.subset_size // 2
    nm = 3 if order == 1 else 6
    second, first = _moment_slots(order)
    points = np.arange(subsets.x.size) if points is None else np.asarray(points, dtype=np.int64)
    n = points.size
    table = np.full((n, 4 + 7 * len(second) + 4 * len(first)), np.nan)
    ok = np.zeros(n, dtype=np.bool_)
    p = np.ascontiguousarray(np.asarray(parameters, dtype=np.float64)[points])
    xs, ys = subsets.x[points], subsets.y[points]
    finite = np.all(np.isfinite(p), axis=1)
    idx = np.flatnonzero(finite)
    sub_table = np.full((idx.size, table.shape[1]), np.nan)
    sub_ok = np.zeros(idx.size, dtype=np.bool_)
    reference = subsets.reference.spline
    values = subsets.reference.values
    variance = subsets.noise_reference.sigma_at(np.where(np.isfinite(values), values, 0.0)) ** 2
    _cross_moments(reference.grad_x, reference.grad_y, np.ascontiguousarray(variance), target.spline.coefficients,
                   int(target.spline.degree), xs[idx], ys[idx], p[idx], half, order,
                   cross_stride(subsets.subset_size), sub_table, sub_ok)
    table[idx], ok[idx] = sub_table, sub_ok
    monomials = MONOMIALS[:nm]
    S = np.zeros((n, 2 * nm, 2 * nm))
    K = np.zeros((n, 2 * nm, 2 * nm))
    k_base = 4 + 4 * len(second)
    for i, (ai, bi, ci) in enumerate(monomials):
        for j, (aj, bj, cj) in enumerate(monomials):
            slot = second[(int(ai + aj), int(bi + bj))]
            col = 4 + 4 * slot
            c = ci * cj
            S[:, i, j] = c * table[:, col]                 # J's u-rows take f_x, G's u-columns g_x
            S[:, i, nm + j] = c * table[:, col + 1]
            S[:, nm + i, j] = c * table[:, col + 2]
            S[:, nm + i, nm + j] = c * table[:, col + 3]
            col = k_base + 3 * slot
            K[:, i, j] = c * table[:, col]
            K[:, i, nm + j] = K[:, nm + j, i] = c * table[:, col + 1]
            K[:, nm + i, nm + j] = c * table[:, col + 2]
    base = k_base + 3 * len(second)
    sum_J = np.zeros((n, 2 * nm))
    sum_G = np.zeros((n, 2 * nm))
    for i, (a, b, c) in enumerate(monomials):
        col = base + 4 * first[(int(a), int(b))]
        sum_J[:, i], sum_J[:, nm + i] = c * table[:, col], c * table[:, col + 1]
        sum_G[:, i], sum_G[:, nm + i] = c * table[:, col + 2], c * table[:, col + 3]
    count = table[:, 2]
    mean_target = table[:, 0] / count
    delta_g = np.sqrt(np.maximum(table[:, 1] - count * mean_target ** 2, 0.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = subsets.delta_f[points] / delta_g
        M = ratio[:, None, None] * (S - sum_J[:, :, None] * sum_G[:, None, :] / count[:, None, None])
        K = ratio[:, None, None] ** 2 * K
    ok &= np.isfinite(ratio) & np.all(np.isfinite(M), axis=(1, 2)) & np.all(np.isfinite(K), axis=(1, 2))
    return M, K, ratio, mean_target, ok


def _general_inverse(m: np.ndarray, scale_from: np.ndarray) -> np.ndarray:
    """Inverse of a batch (N, n, n) of square matrices, Jacobi-scaled by the diagonal of ``scale_from`` (their
    entries span ~10^6); NaN for a singular one."""
    d = 1.0 / np.sqrt(np.abs(np.einsum("kii->ki", scale_from)))
    scaled = m * d[:, :, None] * d[:, None, :]
    out = np.full(m.shape, np.nan)
    good = np.all(np.isfinite(scaled), axis=(1, 2))
    good[good] = np.abs(np.linalg.det(scaled[good])) > 1e-12
    out[good] = np.linalg.inv(scaled[good]) * d[good][:, :, None] * d[good][:, None, :]
    return out


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


@dataclass(frozen=True)
class CrossTerms:
    """A match's per-point cross-Hessian results (:func:`cross_hessians` through ``M^-1``), for a later match to
    reuse (``like=`` of :func:`match_uncertainty`).

    cov_reference_uv, unit_target_uv : ndarray (N, 2, 2)
        The reference noise's part of (u, v) and ``M^-1 J^T J M^-T`` (the target noise's part per unit variance,
        before the contrast ratio, the pixel density and the interpolant's gain), px^2.
    var_reference, var_unit_target : ndarray (N, np)
        Their diagonals over all shape parameters.
    factor : ndarray (N, 2, np)
        ``(M^-1)_uv W^1/2``.
    contrast_ratio, mean_target : ndarray (N,)
    warp_gradient : ndarray (N, 4)
        The match's (du/dx, du/dy, dv/dx, dv/dy) where they were computed.
    """

    cov_reference_uv: np.ndarray = field(repr=False)
    unit_target_uv: np.ndarray = field(repr=False)
    var_reference: np.ndarray = field(repr=False)
    var_unit_target: np.ndarray = field(repr=False)
    factor: np.ndarray = field(repr=False)
    contrast_ratio: np.ndarray = field(repr=False)
    mean_target: np.ndarray = field(repr=False)
    warp_gradient: np.ndarray = field(repr=False)


#: A later match reuses its ``like``'s cross terms where its warp gradient is within this of ``like``'s (1 %
#: strain changes the target's pixel density, hence sigma, by ~1 %; that part is recomputed anyway).
CROSS_REUSE_TOLERANCE = 0.01


def _warp_gradient(parameters: np.ndarray) -> np.ndarray:
    return np.asarray(parameters)[:, [1, 2, 7, 8]]


def match_uncertainty(subsets: ReferenceSubsets, result: DICResult, noise_target: NoiseModel | None = None, *,
                      target=None, like=None, keep_cross: bool = False, noise_source: str | None = None,
                      max_residual_ratio: float = DEFAULT_MAX_RESIDUAL_RATIO) -> MatchUncertainty:
    """Per-point uncertainty of ``result`` (a match of the reference of ``subsets`` to a target image).

    ``noise_target`` defaults to the reference's noise model (same camera, temporal match). The points of
    ``result`` must be those of ``subsets`` (same order).

    ``target`` (the target image, array or :class:`PreparedImage`) gives each point its cross-Hessian ``M``
    (:func:`cross_hessians`): the sensitivity of the match to both images' noise through what the target really
    shows there -- a target more blurred, compressed or magnified than the reference (another camera's view, a
    strained state) moves the match more than the reference's own Hessian says (a 1 px blur on a 4 px speckle:
    x1.6 in sigma). Without it ``M = H0``, exact for a target that repeats the reference's view.

    ``like`` saves the cross terms' cost where they are known: ``subsets`` itself (a target of the reference's own
    camera: ``M = H0`` where the warp's gradient is within :data:`CROSS_REUSE_TOLERANCE` of zero) or an earlier
    :class:`MatchUncertainty` kept with ``keep_cross`` (the stereo match for the right camera's states: its terms
    where the warp's gradient is within the tolerance of its own). The other points get their own.
    """
    if not (np.array_equal(result.x, subsets.x) and np.array_equal(result.y, subsets.y)):
        raise ValueError("the match's points of interest differ from the reference subsets' (same grid needed)")
    if result.settings.order != subsets.order or result.settings.subset_size != subsets.subset_size:
        raise ValueError(f"the match used subset {result.settings.subset_size} px order {result.settings.order}, the "
                         f"reference subsets {subsets.subset_size} px order {subsets.order}")
    if not (np.isfinite(max_residual_ratio) and max_residual_ratio > 1):
        raise ValueError(f"max_residual_ratio must be a number > 1, got {max_residual_ratio!r}")
    if like is not None and not isinstance(like, (ReferenceSubsets, MatchUncertainty)):
        raise ValueError(f"like must be the ReferenceSubsets or a MatchUncertainty kept with keep_cross, got "
                         f"{type(like).__name__}")
    if isinstance(like, MatchUncertainty) and like.cross is None:
        raise ValueError("like: this MatchUncertainty kept no cross terms (make it with keep_cross=True)")
    if subsets.inverse is None:
        raise ValueError("these reference subsets were not made by reference_subsets() (no H0^-1 kept)")
    noise_reference = subsets.noise_reference
    noise_target = noise_target or noise_reference
    source = noise_source or _source_of(noise_reference, noise_target)
    n = subsets.x.size
    npar = subsets.n_parameters
    nm = npar // 2
    matched = (result.status == CONVERGED) & subsets.ok
    flag = np.where(matched, FLAG_NONE, np.where(result.status == CONVERGED, FLAG_SINGULAR, FLAG_NO_MATCH))
    flag = np.where((result.status == CONVERGED) & subsets.clipped, FLAG_SATURATED, flag).astype(np.int8)
    # every point's terms: those of a repeat of the reference's view (the subsets' own) unless the target says
    # otherwise
    var_f_all = np.maximum(subsets.variance_reference, 1e-300)
    cov_ref_uv = subsets.cov_uv_reference
    unit_uv = cov_ref_uv / var_f_all[:, None, None]
    var_ref = subsets.var_parameters_reference
    var_unit = var_ref / var_f_all[:, None]
    factor = subsets.reference_factor
    contrast = np.ones(n)
    mean_target = subsets.mean_grey
    density = np.ones(n)
    cross = None
    if target is not None:
        gradient = _warp_gradient(result.parameters)
        cov_ref_uv, unit_uv, var_ref, var_unit, factor = (a.copy() for a in (cov_ref_uv, unit_uv, var_ref, var_unit,
                                                                              factor))
        contrast, mean_target = contrast.copy(), mean_target.copy()
        need = matched.copy()
        if like is not None:
            base = np.zeros((n, 4)) if isinstance(like, ReferenceSubsets) else like.cross.warp_gradient
            reuse = matched & (np.max(np.abs(gradient - base), axis=1) <= CROSS_REUSE_TOLERANCE)
            if isinstance(like, MatchUncertainty):
                c = like.cross
                reuse &= np.all(np.isfinite(c.factor), axis=(1, 2))
                for mine, theirs in ((cov_ref_uv, c.cov_reference_uv), (unit_uv, c.unit_target_uv),
                                     (var_ref, c.var_reference), (var_unit, c.var_unit_target), (factor, c.factor),
                                     (contrast, c.contrast_ratio), (mean_target, c.mean_target)):
                    mine[reuse] = theirs[reuse]
            need &= ~reuse
        if need.any():
            prepared = target if isinstance(target, PreparedImage) else prepare_image(
                np.asarray(target), result.settings.interpolation, False, "target", result.settings.lowpass_sigma_px)
            idx = np.flatnonzero(need)
            M, w, c, m, ok = cross_hessians(subsets, prepared, result.parameters, points=idx)
            inv = np.full(M.shape, np.nan)
            inv[ok] = _general_inverse(M[ok], M[ok])
            ok &= np.all(np.isfinite(inv), axis=(1, 2))
            good = idx[ok]
            inv, w = inv[ok], w[ok]
            t_inv = np.swapaxes(inv, 1, 2)
            full = inv @ w @ t_inv
            # J^T J from the reference's noise-weighted Hessian over its mean noise variance
            unit = inv @ (subsets.weighted_hessian[good] / var_f_all[good][:, None, None]) @ t_inv
            cov_ref_uv[good] = full[:, [0, nm]][:, :, [0, nm]]
            unit_uv[good] = unit[:, [0, nm]][:, :, [0, nm]]
            var_ref[good] = np.einsum("kii->ki", full)
            var_unit[good] = np.einsum("kii->ki", unit)
            factor[good] = inv[:, [0, nm], :] @ _sqrtm(w)
            contrast[idx], mean_target[idx] = c, m
            flag[idx[~ok]] = FLAG_SINGULAR
            matched[idx[~ok]] = False
        p = result.parameters
        with np.errstate(divide="ignore", invalid="ignore"):
            density = 1.0 / np.abs((1.0 + p[:, 1]) * (1.0 + p[:, 8]) - p[:, 2] * p[:, 7])
        if keep_cross:
            cross = CrossTerms(cov_ref_uv, unit_uv, var_ref, var_unit, factor, contrast, mean_target, gradient)
    cov_ref = np.full((n, 2, 2), np.nan)
    cov_tgt = np.full((n, 2, 2), np.nan)
    sigma_parameters = np.full((n, 12), np.nan)
    ratio = np.full(n, np.nan)
    if matched.any():
        idx = np.flatnonzero(matched)
        c2 = contrast[idx] ** 2
        var_t = noise_target.sigma_at(mean_target[idx]) ** 2
        var_f = subsets.variance_reference[idx]
        pu, pv = _warp_phases(result.parameters[idx], subsets.subset_size // 2)
        ku = subsets.gains.lookup("u", pu, pv).mean(axis=1)
        kv = subsets.gains.lookup("v", pu, pv).mean(axis=1)
        kw = subsets.gains.lookup("white", pu, pv).mean(axis=1)
        gain = np.stack([np.sqrt(ku), np.sqrt(kv)], axis=1)
        gains_all = np.concatenate([np.repeat(ku[:, None], nm, 1), np.repeat(kv[:, None], nm, 1)], 1)
        cov_ref[idx] = cov_ref_uv[idx]
        # the target's noise reaches the normal equations through J (the reference's gradients), scaled by Df / Dg,
        # through the interpolant (kappa_u for the u-like parameters, kappa_v for the v-like), at the target's own
        # pixel density: a subset the warp spreads over |det A| target pixels holds 1 / |det A| of the noise power
        # per reference pixel (module notes)
        scale = c2 * var_t * density[idx]
        cov_tgt[idx] = unit_uv[idx] * (scale[:, None, None] * gain[:, :, None] * gain[:, None, :])
        var_all = var_ref[idx] + var_unit[idx] * scale[:, None] * gains_all
        cols = list(range(nm)) + list(range(6, 6 + nm))
        sigma_parameters[np.ix_(idx, cols)] = np.sqrt(var_all)
        # residual check: sum r^2 = Df^2 (2 - 2 ZNCC) against the noise
        pixels = subsets.subset_size ** 2
        observed = subsets.delta_f[idx] ** 2 * (2.0 - 2.0 * result.zncc[idx])
        ke = subsets.gains.signal_interpolation_error(pu, pv, float(np.median(var_f))).mean(axis=1)
        # the interpolant's own error on this texture is a residual too (fine speckle), not a misfit
        explained = (pixels - npar - 2) * (var_f + kw * c2 * var_t) + ke * np.maximum(
            subsets.delta_f[idx] ** 2 - pixels * var_f, 0.0)
        ratio[idx] = observed / explained
        high = ratio[idx] > max_residual_ratio
        flag[idx[high]] = FLAG_RESIDUAL
    total = cov_ref + cov_tgt
    sigma_u = np.sqrt(total[:, 0, 0])
    sigma_v = np.sqrt(total[:, 1, 1])
    factor = np.where(matched[:, None, None], factor, np.nan)
    return MatchUncertainty(sigma_u, sigma_v, cov_ref, cov_tgt, sigma_parameters, ratio, flag, source,
                            noise_reference, noise_target, reference_factor=factor, cross=cross)


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
                    noise_target: NoiseModel | None = None, *, target=None,
                    max_residual_ratio: float = DEFAULT_MAX_RESIDUAL_RATIO, bias: bool = False) -> MatchUncertainty:
    """Uncertainty of a 2-D match in one call: :func:`reference_subsets` + :func:`match_uncertainty` (and, with
    ``bias``, the systematic terms of every point: the interpolation bias bound,
    :func:`measurement.uncertainty.bias.bias_bound_px`, and the shape function's misfit estimated from the measured
    field, :func:`measurement.uncertainty.misfit.misfit_bias_px`).

    Without ``noise_reference`` the noise is fitted to the match's residuals (:func:`noise_from_residuals`, both
    images alike); ``noise_target`` defaults to ``noise_reference``. ``target`` (the match's target image) gives
    the points whose warp strains the target away from the reference their own cross terms
    (:func:`match_uncertainty`).

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
    # with the target image, points the warp strains by more than CROSS_REUSE_TOLERANCE get their cross terms
    unc = match_uncertainty(subsets, result, noise_target, target=target, like=subsets,
                            max_residual_ratio=max_residual_ratio)
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


def static_repeat_sigma_px(reference, x_px, y_px, settings, noise: NoiseModel) -> np.ndarray:
    """The predicted 1-sigma of (u, v) for a static repeat of ``reference`` at the points, (N, 2) px.

    :func:`reference_subsets` at the points with the camera's noise model, then
    :func:`static_repeat_covariance_px2`; NaN where the subset's Hessian is singular or the subset leaves the image.
    ``settings``: the :class:`measurement.dic.DICSettings` the match runs with (subset, order, interpolation,
    low-pass). What a digital twin predicts from one reference image.
    """
    prepared = prepare_image(np.asarray(reference), settings.interpolation, True, "reference",
                             settings.lowpass_sigma_px)
    subsets = reference_subsets(prepared, np.asarray(x_px, dtype=np.int64), np.asarray(y_px, dtype=np.int64),
                                settings.subset_size, settings.order, noise, settings.interpolation)
    from measurement.uncertainty.stereo import sigmas

    return sigmas(static_repeat_covariance_px2(subsets.cov_uv_reference))
