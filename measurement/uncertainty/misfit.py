"""Systematic error of a subset match from the shape function's misfit (undermatched displacement fields).

A first-order shape function cannot follow a strain gradient, a second-order one cannot follow a change of
curvature. Linearised at the truth, IC-GN converges where the gradient-weighted least-squares fit of the warp to the
true displacement is best (Schreier & Sutton 2002, *Exp. Mech.* 42: 303), so the part ``d_i`` of the true
displacement that the shape function lacks moves the parameters by

    dp = H0^-1 sum_i J_i (e_i - e_mean),        e_i = f_x d_u(x_i) + f_y d_v(x_i),

with ``J_i = grad f . dW/dp`` and the same Hessian ``H0`` as the random part (:mod:`.match`; the mean is taken out
as ZNSSD does). The lacking part is the next order of the displacement's Taylor series about the subset centre:
``d_u = 1/2 u_xx dx^2 + u_xy dx dy + 1/2 u_yy dy^2`` for first-order subsets, the cubic terms for second-order ones.
Those derivatives are estimated from the measured field itself (:func:`field_derivatives`: a local polynomial fit
over the neighbouring points), so the estimate needs nothing but the match -- never the truth.

For uniform isotropic texture the first-order misfit of u at the centre is ``1/2 (u_xx + u_yy) (M^2 - 1) / 12`` on
an M x M subset (the mean of dx^2 over the subset); the texture's own gradient distribution changes that by a few
per cent per subset, which this module computes exactly. Second-order subsets see the cubic terms only through the
texture's asymmetry (an odd function has no mean over a symmetric subset), so their misfit is small and noisy.

The estimate is signed (it could correct the field) and is reported as a systematic term beside the interpolation
bias bound (:mod:`.bias`), never inside the random sigma. Its own noise is that of the derivative fit: a few per cent
of the misfit where the misfit matters (a curvature carried by many points), more where it does not.
"""
from __future__ import annotations

import math

import numba
import numpy as np

from measurement.dic.correlate import DICResult, PreparedImage, prepare_image

#: Monomials of the misfit per shape-function order: order 1 lacks the quadratic terms, order 2 the cubic ones, as
#: (power of dx, power of dy, Taylor factor). The derivative order of column j is ``px + py``.
_QUADRATIC = ((2, 0, 0.5), (1, 1, 1.0), (0, 2, 0.5))
_CUBIC = ((3, 0, 1.0 / 6.0), (2, 1, 0.5), (1, 2, 0.5), (0, 3, 1.0 / 6.0))


def _misfit_terms(order: int) -> tuple:
    if order not in (1, 2):
        raise ValueError(f"order must be 1 or 2, got {order!r}")
    return _QUADRATIC if order == 1 else _CUBIC


def _fit_powers(degree: int) -> list[tuple[int, int]]:
    return [(i - j, j) for i in range(degree + 1) for j in range(i + 1)]


def field_derivatives(result: DICResult, *, radius_points: int | None = None) -> np.ndarray:
    """The derivatives of u and v the shape function lacks, per point, from the measured field.

    A polynomial of degree ``order + 1`` is fitted (least squares, in px) to u and to v over the
    ``(2 r + 1)^2`` grid neighbours of every point; its ``order + 1``-th derivatives at the point are returned.

    Parameters
    ----------
    result : DICResult
        A match on a regular grid (``grid_index``, ``grid_shape``, ``settings.step``).
    radius_points : int, optional
        Neighbourhood half-width in grid steps; default: the subset's half-width in steps for first order, its
        width for second order (a cubic fit needs the wider support: on a 41 px subset at step 10 with 2 grey of
        noise the wider one leaves 0.6 % of the random sigma as the cubic fit's noise, the narrower one 5 %, and up
        to a third of sigma at the field's edges), at least 2.

    Returns
    -------
    ndarray (N, 2, T)
        For u and v, the derivatives in the order of the misfit terms (order 1: u_xx, u_xy, u_yy; order 2:
        u_xxx, u_xxy, u_xyy, u_yyy), 1/px^(order); NaN where fewer than twice the fit's terms were measured.
    """
    order = int(result.settings.order)
    terms = _misfit_terms(order)
    step = int(result.settings.step)
    if radius_points is None:
        radius_points = max(2, int(math.ceil(result.settings.subset_size * order / (2.0 * step))))
    r = int(radius_points)
    if r < 1:
        raise ValueError(f"radius_points must be at least 1, got {radius_points!r}")
    rows, cols = result.grid_shape
    grid = np.full((2, rows + 2 * r, cols + 2 * r), np.nan)
    gi = np.asarray(result.grid_index)
    grid[0, gi[:, 0] + r, gi[:, 1] + r] = result.u
    grid[1, gi[:, 0] + r, gi[:, 1] + r] = result.v
    powers = _fit_powers(order + 1)
    offsets = np.arange(-r, r + 1) * float(step)
    oy, ox = np.meshgrid(offsets, offsets, indexing="ij")
    # scaled coordinates keep the normal matrix well conditioned
    scale = r * float(step)
    design = np.stack([(ox.ravel() / scale) ** a * (oy.ravel() / scale) ** b for a, b in powers], axis=1)   # (K, P)
    # neighbour values (N, 2, K)
    di, dj = np.meshgrid(np.arange(-r, r + 1), np.arange(-r, r + 1), indexing="ij")
    values = grid[:, gi[:, 0, None] + r + di.ravel()[None, :], gi[:, 1, None] + r + dj.ravel()[None, :]]
    values = np.moveaxis(values, 0, 1)
    out = np.full((gi.shape[0], 2, len(terms)), np.nan)
    n_terms = len(powers)
    for c in range(2):
        y = values[:, c, :]
        w = np.isfinite(y)
        ok = w.sum(axis=1) >= 2 * n_terms
        if not ok.any():
            continue
        yz = np.where(w, y, 0.0)[ok]
        wk = w[ok].astype(np.float64)
        normal = np.einsum("nk,kp,kq->npq", wk, design, design)
        rhs = np.einsum("nk,kp,nk->np", wk, design, yz)
        cond_ok = np.linalg.cond(normal) < 1e10
        coeff = np.full(rhs.shape, np.nan)
        coeff[cond_ok] = np.linalg.solve(normal[cond_ok], rhs[cond_ok][..., None])[..., 0]
        idx = np.flatnonzero(ok)
        for t, (a, b, _) in enumerate(terms):
            j = powers.index((a, b))
            # d^(a+b) / dx^a dy^b of c (x/s)^a (y/s)^b is c a! b! / s^(a+b)
            out[idx, c, t] = coeff[:, j] * math.factorial(a) * math.factorial(b) / scale ** (a + b)
    return out


@numba.njit(parallel=True, cache=True)
def _projections(grad_x, grad_y, xs, ys, half, order, powers_x, powers_y, factors, derivatives, out):
    nm = 3 if order == 1 else 6
    npar = 2 * nm
    for k in numba.prange(xs.size):
        sje = np.zeros(npar)
        sj = np.zeros(npar)
        se = 0.0
        n = 0
        ok = True
        for t in range(factors.size):
            if not (np.isfinite(derivatives[k, 0, t]) and np.isfinite(derivatives[k, 1, t])):
                ok = False
        if not ok:
            for c in range(npar):
                out[k, c] = np.nan
            continue
        m = np.empty(nm)
        for iy in range(-half, half + 1):
            for ix in range(-half, half + 1):
                gx = grad_x[ys[k] + iy, xs[k] + ix]
                gy = grad_y[ys[k] + iy, xs[k] + ix]
                dx = float(ix)
                dy = float(iy)
                du = 0.0
                dv = 0.0
                for t in range(factors.size):
                    mono = factors[t] * dx ** powers_x[t] * dy ** powers_y[t]
                    du += derivatives[k, 0, t] * mono
                    dv += derivatives[k, 1, t] * mono
                e = gx * du + gy * dv
                m[0] = 1.0
                m[1] = dx
                m[2] = dy
                if order == 2:
                    m[3] = 0.5 * dx * dx
                    m[4] = dx * dy
                    m[5] = 0.5 * dy * dy
                for j in range(nm):
                    sje[j] += gx * m[j] * e
                    sje[nm + j] += gy * m[j] * e
                    sj[j] += gx * m[j]
                    sj[nm + j] += gy * m[j]
                se += e
                n += 1
        for c in range(npar):
            out[k, c] = sje[c] - sj[c] * se / n


def misfit_bias_px(reference, result: DICResult, uv_rows: np.ndarray, *,
                   derivatives: np.ndarray | None = None) -> np.ndarray:
    """Signed systematic error of u and v from the shape function's misfit, px, (N, 2) (module notes).

    Parameters
    ----------
    reference : ndarray (rows, cols) or PreparedImage (with gradients)
        The reference image of the match.
    result : DICResult
        The match (its points, settings and measured field).
    uv_rows : ndarray (N, 2, np)
        The u and v rows of ``H0^-1`` per point (:attr:`measurement.uncertainty.match.ReferenceSubsets.uv_rows`).
    derivatives : ndarray (N, 2, T), optional
        The lacking derivatives (:func:`field_derivatives`); estimated from ``result`` when not given (pass the
        truth's to test the projection alone).

    Returns
    -------
    ndarray (N, 2)
        NaN where the point has no derivatives or no Hessian.
    """
    settings = result.settings
    order = int(settings.order)
    terms = _misfit_terms(order)
    if isinstance(reference, PreparedImage):
        prepared = reference
    else:
        prepared = prepare_image(np.asarray(reference), settings.interpolation, True, "reference",
                                 settings.lowpass_sigma_px)
    if prepared.spline.grad_x is None:
        raise ValueError("the prepared reference has no gradients (prepare_image(..., gradients=True))")
    if derivatives is None:
        derivatives = field_derivatives(result)
    derivatives = np.ascontiguousarray(derivatives, dtype=np.float64)
    n = result.x.size
    if derivatives.shape != (n, 2, len(terms)):
        raise ValueError(f"derivatives must have shape {(n, 2, len(terms))} for order {order}, got "
                         f"{derivatives.shape}")
    uv_rows = np.asarray(uv_rows, dtype=np.float64)
    npar = 6 if order == 1 else 12
    if uv_rows.shape != (n, 2, npar):
        raise ValueError(f"uv_rows must have shape {(n, 2, npar)}, got {uv_rows.shape}")
    half = int(settings.subset_size) // 2
    xs = np.asarray(result.x, dtype=np.int64)
    ys = np.asarray(result.y, dtype=np.int64)
    rows, cols = prepared.values.shape
    inside = (xs - half >= 0) & (ys - half >= 0) & (xs + half < cols) & (ys + half < rows)
    b = np.full((n, npar), np.nan)
    if inside.any():
        sub = np.full((int(inside.sum()), npar), np.nan)
        _projections(prepared.spline.grad_x, prepared.spline.grad_y, xs[inside], ys[inside], half, order,
                     np.array([t[0] for t in terms], dtype=np.int64), np.array([t[1] for t in terms], dtype=np.int64),
                     np.array([t[2] for t in terms]), derivatives[inside], sub)
        b[inside] = sub
    return np.einsum("kcp,kp->kc", uv_rows, b)
