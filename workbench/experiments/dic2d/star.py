"""DIC Challenge 2.0 "Star" metrics on exact Star images: spatial resolution l10, noise floor, MEI, with theory.

Images and truth: :mod:`scenes.image_pairs.star` (``V = A cos(2 pi (Y - y0) / p(X))``, ``p`` linear in ``X``, exact
Gaussian speckle, seeded sensor noise). Any DIC engine's scattered results are scored by
:func:`star_metrics`; :func:`run_star` runs this project's engine (or any ``engine`` callable) on a Star case
and its static pair; :func:`star_report` writes ``metrics.json``, ``report.md`` and ``star.png``.

Metrics (Reu et al. 2022, DIC Challenge 2.0, Exp. Mech. 62:639)
---------------------------------------------------------------
* **Amplitude ratio vs period.** The period is constant along each column, so the measured points are
  grouped in bands of nearly constant period (``band_fraction`` = 4 % of the period wide by default: the
  resolution the steep short-period part needs, and more points where the curve is flat) and in each band the
  measured ``v`` is fitted by least squares as ``r * V_true(x, y)`` with the exact ``V_true`` of each point
  (phase included): ``r = sum(v V) / sum(V^2)``. A subset filter is even, so it leaves the phase alone and
  scales the sinusoid by its transfer function; ``r`` estimates that factor at the band's period (the
  ``V^2``-weighted mean of ``p`` over its points). Only points where the stripes are nearly horizontal are
  used, ``|y - y0| p' / p <= max_stripe_slope`` (0.1 by default, 5.7 deg): the Challenge reads the crest line
  ``y = y0``, where the field across a subset is a pure sinusoid along y; a tilt ``s`` adds an averaging
  along x that lowers ``r`` by about ``(s k L)^2 / 24`` for a first-order subset of width ``L``
  (~0.1 % at ``s = 0.1`` near l10). ``fit_offset=True`` fits ``r V + c`` instead.
* **l10** (spatial resolution): the period at which the ratio *first* reaches 0.9 coming from short
  periods, linearly interpolated between the two bands that bracket it; NaN when no band reaches 0.9 or the
  shortest band already does (l10 outside the measured range).
* **Noise floor** ``n``: the standard deviation of ``v`` over all matched points of the static pair (same
  pattern, two noise draws, zero displacement), px.
* **MEI** (metrological efficiency indicator) ``= n * l10``, in px^2, the Challenge's figure of merit
  for the trade-off between displacement noise and spatial resolution (smaller is better).
* **Bias / RMS error**: mean and RMS of ``v - V_true`` over every matched point of the Star pair (the
  attenuation at short periods dominates them by design), px.

Theory: transfer function of a subset
-------------------------------------
Linearise the matching criterion about the solution: for a subset of ``N = 2M + 1`` pixels centred on
``X0`` and a small displacement field, Gauss-Newton minimises ``sum_s (grad f(s) . (W(s; q) - u(s)))^2``
over the shape-function parameters ``q``. With uniform speckle statistics (``E[f_y^2]`` the same at every
pixel, ``E[f_x f_y] = 0``, gradients uncorrelated with position) the expected normal equations are those
of the *unweighted* least-squares fit of the shape function to ``u`` over the subset pixels; the estimated
displacement at the centre is the fit's constant term. For ``v(s, t) = A cos(k t + phi0)`` (``t`` the row
offset, ``k = 2 pi / p``) the odd part ``sin(k t)`` goes to the odd terms, so the estimate is
``A cos(phi0) H(p)``: the crest is scaled by the transfer function ``H``.

* **First order** (affine, ``1, s, t``): on a symmetric square grid the linear terms are orthogonal to the
  constant, which is the subset mean:
  ``H1(p) = (1/N) sum_{k=-M..M} cos(2 pi k / p) = sin(pi N / p) / (N sin(pi / p))``. The sum over pixel rows
  is the exact discrete fit; the continuous ``sinc(N / p)`` is its limit for ``p >> 1`` (l10 differs by
  0.17 % for N = 17, 0.04 % for N = 33). ``H1 = 0.9`` at ``p ~ 3.99 N``.
* **Second order** (``1, s, t, s^2, s t, t^2``): ``v`` depends on ``t`` only, and on the full square the
  ``s^2`` coefficient vanishes (its normal equation is ``S2`` times the constant's), so the constant term is
  that of the 1-D fit of ``a + b t + c t^2`` over ``t = -M..M``: with ``S2 = sum t^2``, ``S4 = sum t^4``,
  ``a = sum_t w_t v(t)``, ``w_t = (S4 - S2 t^2) / (N S4 - S2^2)`` (a Savitzky-Golay smoother), so
  ``H2(p) = sum_t w_t cos(2 pi t / p)``. ``H2 = 0.9`` at ``p ~ 1.29 N``.

:func:`theoretical_l10_px` solves ``H(p) = 0.9`` at the first crossing from short periods (on the main
lobe; the side lobes stay below 0.25 in magnitude). The theory ignores the speckle-weighted fit (pattern
induced bias), noise, interpolation and the stripes' tilt.
"""
from __future__ import annotations

import argparse
import json
import math
import shutil
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import scipy.optimize

from labio.atomic import atomic_write_bytes, atomic_write_text
from scenes.image_pairs.star import (CHALLENGE_PERIODS_PX, CHALLENGE_SHAPE, DEFAULT_NOISE_GREY, DEFAULT_SPECKLE_PX,
                                     StarDisplacement, StarImages, star_images)

#: The amplitude ratio that defines the spatial resolution l10.
LEVEL = 0.9

#: Largest stripe tilt ``|y - y0| p' / p`` of the points used for the amplitude ratio (tangent).
DEFAULT_MAX_STRIPE_SLOPE = 0.1

#: Relative width of the period bands of the amplitude-ratio curve: band edges ``p_min (1 + f)^k``.
DEFAULT_BAND_FRACTION = 0.04

#: Bands with fewer matched points are left out of the curve.
DEFAULT_MIN_POINTS = 3

#: Shape-function orders the theory covers.
ORDERS = (1, 2)

#: Signature of a pluggable engine: ``(reference, deformed, subset_px, step_px) -> (x_px, y_px, u_px, v_px)``.
Engine = Callable[[np.ndarray, np.ndarray, int, int], tuple]


# ------------------------------------------------------------------------------------------------------------
# Theory
# ------------------------------------------------------------------------------------------------------------
def subset_weights(subset_px: int, order: int) -> np.ndarray:
    """Weights ``w_t`` of the fitted constant term along the sinusoid: ``v_hat = sum_t w_t v(t)``.

    Parameters
    ----------
    subset_px : int
        Odd subset width ``N = 2M + 1``, px (>= 5).
    order : {1, 2}
        Shape-function order.

    Returns
    -------
    ndarray of float64, shape (N,)
        For ``t = -M..M``: ``1/N`` (order 1) or ``(S4 - S2 t^2) / (N S4 - S2^2)`` (order 2); they sum to 1.
    """
    n = _check_subset(subset_px)
    _check_order(order)
    t = np.arange(-(n // 2), n // 2 + 1, dtype=np.float64)
    if order == 1:
        return np.full(n, 1.0 / n)
    s2, s4 = float(np.sum(t ** 2)), float(np.sum(t ** 4))
    return (s4 - s2 * t ** 2) / (n * s4 - s2 ** 2)


def subset_transfer(period_px, subset_px: int, order: int) -> np.ndarray:
    """Transfer function ``H(p)`` of a subset for a sinusoidal displacement of period ``p`` (module notes).

    Parameters
    ----------
    period_px : float or ndarray, any shape
        Periods, px (finite, > 0).
    subset_px : int
        Odd subset width, px.
    order : {1, 2}
        Shape-function order.

    Returns
    -------
    ndarray of float64, shape of ``period_px``
        Estimated / imposed amplitude on the crest, dimensionless (1 for a uniform field).
    """
    period = np.asarray(period_px, dtype=np.float64)
    if not (np.all(np.isfinite(period)) and np.all(period > 0)):
        raise ValueError("period_px must be finite and > 0")
    weights = subset_weights(subset_px, order)
    t = np.arange(weights.size, dtype=np.float64) - weights.size // 2
    flat = period.ravel()
    return (np.cos(2.0 * np.pi * t[None, :] / flat[:, None]) @ weights).reshape(period.shape)


def theoretical_l10_px(subset_px: int, order: int, level: float = LEVEL) -> float:
    """Period (px) at which :func:`subset_transfer` first reaches ``level`` coming from short periods.

    Scans ``p`` from 2 px (Nyquist) to ``100 N`` on a fine log grid, then refines the first bracket with
    Brent's method to ~1e-10 px. About ``3.99 N`` for first order and ``1.29 N`` for second order.

    Parameters
    ----------
    subset_px : int
        Odd subset width, px.
    order : {1, 2}
        Shape-function order.
    level : float
        Amplitude ratio, ``0 < level < 1``.

    Returns
    -------
    float
        l10 in px (for ``level = 0.9``).
    """
    n = _check_subset(subset_px)
    _check_order(order)
    level = _check_level(level)
    grid = np.geomspace(2.0, 100.0 * n, 20001)
    h = subset_transfer(grid, n, order)
    above = np.nonzero(h >= level)[0]
    if above.size == 0 or above[0] == 0:
        raise ValueError(f"the transfer function of a {n} px subset (order {order}) does not cross level={level} "
                         "between 2 px and 100 subset widths")
    i = int(above[0])
    return float(scipy.optimize.brentq(lambda p: float(subset_transfer(p, n, order)) - level, grid[i - 1], grid[i],
                                       xtol=1e-10, rtol=1e-13))


# ------------------------------------------------------------------------------------------------------------
# Metrics
# ------------------------------------------------------------------------------------------------------------
def first_crossing_px(period_px, ratio, level: float = LEVEL) -> float:
    """The period at which ``ratio`` first reaches ``level``, coming from short periods (linear interpolation).

    Parameters
    ----------
    period_px, ratio : array_like, shape (n,)
        A curve, any order (sorted here by period); non-finite entries are skipped.
    level : float
        Crossing level, 0.9 for l10.

    Returns
    -------
    float
        The interpolated period, px; NaN when no point reaches ``level`` or the shortest period already does.
    """
    period = np.asarray(period_px, dtype=np.float64).ravel()
    ratio = np.asarray(ratio, dtype=np.float64).ravel()
    if period.shape != ratio.shape:
        raise ValueError(f"period_px and ratio must have the same length, got {period.size} and {ratio.size}")
    level = _check_level(level)
    ok = np.isfinite(period) & np.isfinite(ratio)
    order = np.argsort(period[ok], kind="stable")
    p, r = period[ok][order], ratio[ok][order]
    above = np.nonzero(r >= level)[0]
    if above.size == 0 or above[0] == 0:
        return float("nan")
    i = int(above[0])
    return float(p[i - 1] + (level - r[i - 1]) * (p[i] - p[i - 1]) / (r[i] - r[i - 1]))


def amplitude_ratio_curve(x_px, y_px, v_px, truth: StarDisplacement, *,
                          band_fraction: float = DEFAULT_BAND_FRACTION,
                          max_stripe_slope: float = DEFAULT_MAX_STRIPE_SLOPE,
                          min_points: int = DEFAULT_MIN_POINTS, fit_offset: bool = False) -> dict:
    """Measured / imposed amplitude per band of period (module notes).

    Parameters
    ----------
    x_px, y_px : array_like, shape (n,)
        Reference positions of the measured points (column, row), px.
    v_px : array_like, shape (n,)
        Measured vertical displacement, px; NaN marks a failed point.
    truth : StarDisplacement
        The imposed field.
    band_fraction : float
        Relative width of a band in period (> 0): bands ``[p_min (1 + f)^k, p_min (1 + f)^(k + 1))``.
    max_stripe_slope : float
        Use points with ``truth.stripe_slope(x, y) <= max_stripe_slope`` only (> 0).
    min_points : int
        Bands with fewer usable points are dropped (>= 1; 2 with ``fit_offset``).
    fit_offset : bool
        Fit ``r V + c`` rather than ``r V``.

    Returns
    -------
    dict
        ``period_px``, ``ratio`` (float64 arrays, shape (bands,), sorted by period) and ``points``
        (int64 array, usable points per band).
    """
    x, y, v = _check_points(x_px, y_px, v_px)
    band = _require_positive(band_fraction, "band_fraction")
    slope_max = _require_positive(max_stripe_slope, "max_stripe_slope")
    if isinstance(min_points, bool) or int(min_points) != min_points or min_points < (2 if fit_offset else 1):
        raise ValueError(f"min_points must be an integer >= {2 if fit_offset else 1}, got {min_points!r}")
    use = np.isfinite(v)
    use[use] = truth.stripe_slope(x[use], y[use]) <= slope_max
    x, y, v = x[use], y[use], v[use]
    period = truth.period_px(x)
    imposed = truth(x, y)[1]
    index = np.floor(np.log(period / truth.period_min_px) / np.log1p(band)).astype(np.int64)
    periods, ratios, counts = [], [], []
    for k in np.unique(index):
        members = index == k
        w, m = imposed[members], v[members]
        weight = float(np.sum(w * w))
        if members.sum() < min_points or weight <= 0:
            continue
        if fit_offset:
            design = np.column_stack([w, np.ones_like(w)])
            ratio = float(np.linalg.lstsq(design, m, rcond=None)[0][0])
        else:
            ratio = float(np.sum(w * m) / weight)
        periods.append(float(np.sum(w * w * period[members]) / weight))
        ratios.append(ratio)
        counts.append(int(members.sum()))
    return {"period_px": np.array(periods), "ratio": np.array(ratios), "points": np.array(counts, dtype=np.int64)}


def star_metrics(x_px, y_px, v_px, truth: StarDisplacement, *, static_v_px=None, subset_px: int | None = None,
                 order: int | None = None, band_fraction: float = DEFAULT_BAND_FRACTION,
                 max_stripe_slope: float = DEFAULT_MAX_STRIPE_SLOPE, min_points: int = DEFAULT_MIN_POINTS,
                 fit_offset: bool = False) -> dict:
    """Score any DIC tool's results on a Star case: l10, noise floor, MEI, bias and RMS error (module notes).

    Parameters
    ----------
    x_px, y_px : array_like, shape (n,)
        Reference positions of the points (column, row), px; finite.
    v_px : array_like, shape (n,)
        Measured vertical displacement at those points, px; NaN for a failed point.
    truth : StarDisplacement
        The imposed field (:func:`scenes.image_pairs.star.star_pair`'s third value).
    static_v_px : array_like, optional
        Measured vertical displacement on the static pair (any points; NaN skipped), px: gives the noise
        floor and the MEI (NaN without it).
    subset_px, order : int, optional
        The subset width and shape-function order of the tool: with both, the theoretical l10
        (:func:`theoretical_l10_px`) and the measured / theoretical ratio are added.
    band_fraction, max_stripe_slope, min_points, fit_offset
        As in :func:`amplitude_ratio_curve`.

    Returns
    -------
    dict
        ``l10_px``, ``noise_floor_px``, ``mei_px2`` (``noise_floor_px * l10_px``), ``bias_px``,
        ``rms_error_px``, ``valid_fraction``, ``points``, ``static_bias_px``, ``static_points``, the curve
        (``curve_period_px``, ``curve_ratio``, ``curve_points``: lists) and, with ``subset_px`` and
        ``order``, ``l10_theory_px`` and ``l10_ratio``; NaN where undefined.
    """
    x, y, v = _check_points(x_px, y_px, v_px)
    curve = amplitude_ratio_curve(x, y, v, truth, band_fraction=band_fraction, max_stripe_slope=max_stripe_slope,
                                  min_points=min_points, fit_offset=fit_offset)
    l10 = first_crossing_px(curve["period_px"], curve["ratio"])
    ok = np.isfinite(v)
    error = v[ok] - truth(x[ok], y[ok])[1]
    out = {"l10_px": l10,
           "bias_px": float(np.mean(error)) if error.size else math.nan,
           "rms_error_px": float(np.sqrt(np.mean(error ** 2))) if error.size else math.nan,
           "valid_fraction": float(ok.mean()) if ok.size else math.nan, "points": int(ok.sum()),
           "noise_floor_px": math.nan, "static_bias_px": math.nan, "static_points": 0}
    if static_v_px is not None:
        static = np.asarray(static_v_px, dtype=np.float64).ravel()
        static = static[np.isfinite(static)]
        if static.size >= 2:
            out.update(noise_floor_px=float(np.std(static)), static_bias_px=float(np.mean(static)),
                       static_points=int(static.size))
    out["mei_px2"] = out["noise_floor_px"] * l10
    if (subset_px is None) != (order is None):
        raise ValueError("give both subset_px and order for the theoretical l10, or neither")
    if subset_px is not None:
        theory = theoretical_l10_px(subset_px, order)
        out.update(subset_px=int(subset_px), order=int(order), l10_theory_px=theory, l10_ratio=l10 / theory)
    out.update(curve_period_px=curve["period_px"].tolist(), curve_ratio=curve["ratio"].tolist(),
               curve_points=curve["points"].tolist(),
               method={"band_fraction": float(band_fraction), "max_stripe_slope": float(max_stripe_slope),
                       "min_points": int(min_points), "fit_offset": bool(fit_offset), "level": LEVEL})
    return out


# ------------------------------------------------------------------------------------------------------------
# Running an engine
# ------------------------------------------------------------------------------------------------------------
def icgn_engine(order: int, interpolation: str = "biquintic", tolerance_px: float = 1e-4) -> Engine:
    """This project's engine (:func:`measurement.dic.correlate`) as an :data:`Engine` callable.

    Every point starts from a zero guess (no propagation); the grid covers the image less a border of
    ``M + 3`` px (the quintic spline's support and the 0.5 px motion).

    Parameters
    ----------
    order : {1, 2}
        Shape-function order.
    interpolation : {'biquintic', 'bicubic'}
        B-spline interpolation.
    tolerance_px : float
        IC-GN convergence tolerance, px.

    Returns
    -------
    callable
        ``(reference, deformed, subset_px, step_px) -> (x_px, y_px, u_px, v_px)``, arrays of shape (n,),
        NaN where a point failed.
    """
    from measurement.dic import DICSettings, correlate

    _check_order(order)

    def engine(reference, deformed, subset_px, step_px):
        rows, cols = np.shape(reference)
        border = int(subset_px) // 2 + 3
        settings = DICSettings(subset_size=int(subset_px), step=int(step_px), order=order,
                               interpolation=interpolation, tolerance_px=tolerance_px)
        result = correlate(reference, deformed, settings, roi=(border, border, cols - border, rows - border),
                           initial_parameters=lambda x, y: (0.0 * x, 0.0 * y))
        return result.x.astype(np.float64), result.y.astype(np.float64), result.u, result.v

    return engine


def default_step_px(subset_px: int) -> int:
    """POI spacing used when none is given: a quarter subset, between 2 and 4 px.

    Near the crest line the usable rows are few at short periods (``|y - y0| <= s p / p'``), so the grid
    must stay fine there whatever the subset size.
    """
    return min(4, max(2, _check_subset(subset_px) // 4))


def run_star(subset_px: int, order: int, *, images: StarImages | None = None,
             shape: tuple[int, int] = CHALLENGE_SHAPE, periods_px=CHALLENGE_PERIODS_PX,
             speckle_size_px: float = DEFAULT_SPECKLE_PX, noise_grey: float = DEFAULT_NOISE_GREY, seed: int = 0,
             step_px: int | None = None, engine: Engine | None = None, **metric_options) -> dict:
    """Measure a Star case and its static pair with an engine and score it (:func:`star_metrics`).

    Parameters
    ----------
    subset_px : int
        Odd subset width, px.
    order : {1, 2}
        Shape-function order: of this project's engine when ``engine`` is None, else the order the given
        engine uses (for the theoretical l10 only).
    images : StarImages, optional
        A rendered case (:func:`scenes.image_pairs.star.star_images` with ``static=True``) to reuse across runs; else one
        is rendered from ``shape``, ``periods_px``, ``speckle_size_px``, ``noise_grey`` and ``seed``.
    shape, periods_px, speckle_size_px, noise_grey, seed
        As in :func:`scenes.image_pairs.star.star_images`.
    step_px : int, optional
        POI spacing, px; default :func:`default_step_px`.
    engine : callable, optional
        ``engine(reference, deformed, subset_px, step_px) -> (x_px, y_px, u_px, v_px)``; default
        :func:`icgn_engine` ``(order)``.
    **metric_options
        Passed to :func:`star_metrics` (``band_fraction``, ``max_stripe_slope``, ...).

    Returns
    -------
    dict
        :func:`star_metrics`' dict plus ``step_px``, ``dic_s`` (wall time of the two correlations, s),
        ``image_shape`` and ``engine`` (its name).
    """
    subset_px = _check_subset(subset_px)
    _check_order(order)
    step_px = default_step_px(subset_px) if step_px is None else _check_step(step_px)
    if images is None:
        images = star_images(shape, speckle_size_px, periods_px=periods_px, noise_grey=noise_grey, seed=seed)
    if images.deformed is None or images.static is None:
        raise ValueError("images must hold the deformed image and the static repeat (star_images(..., "
                         "deformed=True, static=True))")
    name = "measurement.dic (IC-GN)" if engine is None else getattr(engine, "__name__", type(engine).__name__)
    engine = icgn_engine(order) if engine is None else engine
    start = time.perf_counter()
    x, y, _, v = _call_engine(engine, images.reference, images.deformed, subset_px, step_px)
    _, _, _, v_static = _call_engine(engine, images.reference, images.static, subset_px, step_px)
    seconds = time.perf_counter() - start
    metrics = star_metrics(x, y, v, images.truth, static_v_px=v_static, subset_px=subset_px, order=order,
                           **metric_options)
    metrics.update(step_px=step_px, dic_s=seconds, image_shape=list(np.shape(images.reference)), engine=name)
    return metrics


# ------------------------------------------------------------------------------------------------------------
# Report
# ------------------------------------------------------------------------------------------------------------
def scaled_shape(scale: float) -> tuple[int, int]:
    """Star image size for ``scale`` times the Challenge's 501 x 4000 px: ``(2 round(250 s) + 1, round(4000 s))``.

    The period range stays 10 -> 300 px, so smaller images fan the stripes out faster.
    """
    scale = _require_positive(scale, "scale")
    if scale > 1.0:
        raise ValueError(f"scale must be in (0, 1] (1 = the Challenge's 501 x 4000 px), got {scale}")
    half_rows = (CHALLENGE_SHAPE[0] - 1) // 2
    return 2 * int(round(half_rows * scale)) + 1, int(round(CHALLENGE_SHAPE[1] * scale))


def star_report(out_dir: str | Path, subsets=(17, 33, 65), orders=(1, 2), scale: float = 1.0, *, seed: int = 0,
                noise_grey: float = DEFAULT_NOISE_GREY, speckle_size_px: float = DEFAULT_SPECKLE_PX,
                step_px: int | None = None, progress: bool = False, engine_spec: str | None = None) -> dict:
    """Run every (subset, order) on one Star case and write ``metrics.json``, ``report.md`` and ``star.png``.

    Parameters
    ----------
    out_dir : path
        Output folder (created if missing); files are written atomically.
    subsets : sequence of int
        Odd subset widths, px.
    orders : sequence of {1, 2}
        Shape-function orders.
    scale : float
        Image size relative to the Challenge's (:func:`scaled_shape`), ``0 < scale <= 1``.
    seed, noise_grey, speckle_size_px
        As in :func:`scenes.image_pairs.star.star_images`.
    step_px : int, optional
        POI spacing for every run; default :func:`default_step_px` per subset.
    progress : bool
        Print one line per run.
    engine_spec : str, optional
        Any engine of :mod:`workbench.engines` (``'cmd {ref} {def} {out}'`` or ``module:function``; a Python
        engine is passed ``order``); default this project's IC-GN.

    Returns
    -------
    dict
        What ``metrics.json`` holds: ``case`` (the images) and ``runs`` (one :func:`run_star` dict each).
    """
    out_dir = Path(out_dir)
    subsets = [_check_subset(s) for s in subsets]
    orders = [_check_order(o) for o in orders]
    if not subsets or not orders:
        raise ValueError("subsets and orders must not be empty")
    shape = scaled_shape(scale)
    biggest = max(subsets)
    if shape[0] < biggest + 2 * 3 + 1:
        raise ValueError(f"scale={scale} gives {shape[0]} rows, too few for a {biggest} px subset "
                         f"(needs {biggest + 7}); use a larger scale or smaller subsets")
    start = time.perf_counter()
    images = star_images(shape, speckle_size_px, noise_grey=noise_grey, seed=seed)
    render_s = time.perf_counter() - start
    runs = []
    for order in orders:
        for subset in subsets:
            engine = None
            if engine_spec is not None:
                from workbench.engines import array_engine, parse_engine

                # the engine's image and result files are scratch: only the report stays in out_dir
                scratch = Path(tempfile.mkdtemp(prefix="star-engine-"))
                engine = array_engine(parse_engine(engine_spec), scratch, {"order": order})
            try:
                run = run_star(subset, order, images=images, step_px=step_px, engine=engine)
            finally:
                if engine is not None:
                    shutil.rmtree(scratch, ignore_errors=True)
            runs.append(run)
            if progress:
                print(f"subset {subset} px, order {order}: l10 {run['l10_px']:.1f} px (theory "
                      f"{run['l10_theory_px']:.1f} px), noise {run['noise_floor_px']:.4f} px, MEI "
                      f"{run['mei_px2']:.3f} px^2, {run['dic_s']:.1f} s")
    truth = images.truth
    case = {"shape": list(shape), "scale": float(scale), "amplitude_px": truth.amplitude_px,
            "periods_px": [truth.period_min_px, truth.period_max_px], "period_slope": truth.period_slope,
            "centre_y_px": truth.centre_y_px, "speckle_size_px": float(speckle_size_px),
            "noise_grey": float(noise_grey), "bit_depth": 8, "seed": int(seed), "render_s": render_s,
            "about": "V = A cos(2 pi (Y - y0) / p(X)), p(X) = p_min + (p_max - p_min) X / W, U = 0 (DIC Challenge "
                     "2.0 Star, Reu et al. 2022); exact Gaussian speckle, read noise + 8-bit quantisation"}
    metrics = {"case": case, "runs": runs}
    atomic_write_text(out_dir / "metrics.json", json.dumps(_json_ready(metrics), indent=1))
    atomic_write_bytes(out_dir / "star.png", _plot_png(runs, case["periods_px"]))
    atomic_write_text(out_dir / "report.md", _report_markdown(case, runs))
    return metrics


def _plot_png(runs: list[dict], periods_px) -> bytes:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    orders = sorted({r["order"] for r in runs})
    fig, axes = plt.subplots(1, len(orders), figsize=(6.5 * len(orders), 4.5), squeeze=False)
    for ax, order in zip(axes[0], orders):
        for k, run in enumerate(r for r in runs if r["order"] == order):
            colour = f"C{k}"
            period = np.asarray(run["curve_period_px"])
            ax.plot(period, run["curve_ratio"], ".", ms=3, color=colour,
                    label=f"{run['subset_px']} px: l10 {run['l10_px']:.0f} px")
            grid = np.linspace(periods_px[0], periods_px[1], 600)
            ax.plot(grid, subset_transfer(grid, run["subset_px"], order), "--", color=colour, lw=1,
                    label=f"{run['subset_px']} px theory: {run['l10_theory_px']:.0f} px")
        ax.axhline(LEVEL, color="k", lw=0.8)
        ax.set(xlabel="period p (px)", ylabel="measured / imposed amplitude", ylim=(-0.3, 1.15),
               title=f"Star, shape function order {order}")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8, loc="lower right")
    fig.tight_layout()
    from labio.figures import png_bytes

    return png_bytes(fig, dpi=120)


def _report_markdown(case: dict, runs: list[dict]) -> str:
    rows, cols = case["shape"]
    lines = ["# DIC Challenge 2.0 Star: spatial resolution, noise floor, MEI", "",
             f"Exact Star pair, {cols} x {rows} px (scale {case['scale']:g} of the Challenge's 4000 x 501 px): "
             f"V = {case['amplitude_px']:g} cos(2 pi (Y - {case['centre_y_px']:g}) / p(X)) px, p from "
             f"{case['periods_px'][0]:g} to {case['periods_px'][1]:g} px across the width; Gaussian speckle "
             f"{case['speckle_size_px']:g} px, read noise {case['noise_grey']:g} grey + 8-bit quantisation, seed "
             f"{case['seed']}. Engine: " + (f"`{runs[0]['engine']}` (through the engine interface)"
                                            if runs and not str(runs[0].get("engine", "")).startswith("measurement.dic")
                                            else "this project's IC-GN, biquintic, zero initial guess") + ".", "",
             "l10: period at which measured / imposed amplitude first reaches 0.9 from short periods (bands of "
             "4 % of the period wide, near the crest line); theory: the subset's least-squares transfer function "
             "(mean of the sinusoid over the subset for order 1, constant term of a quadratic fit for order 2). "
             "Noise floor: std of v on the static pair. MEI = noise floor x l10 (px^2).", "",
             "| subset (px) | order | step (px) | l10 measured (px) | l10 theory (px) | measured / theory | "
             "noise floor (px) | MEI (px^2) | bias (px) | RMS error (px) | valid | DIC (s) |",
             "|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for r in runs:
        lines.append(f"| {r['subset_px']} | {r['order']} | {r['step_px']} | {r['l10_px']:.1f} | "
                     f"{r['l10_theory_px']:.1f} | {r['l10_ratio']:.3f} | {r['noise_floor_px']:.4f} | "
                     f"{r['mei_px2']:.3f} | {r['bias_px']:.4f} | {r['rms_error_px']:.4f} | "
                     f"{r['valid_fraction']:.3f} | {r['dic_s']:.1f} |")
    lines += ["", "![amplitude ratio vs period](star.png)", ""]
    return "\n".join(lines)


def _json_ready(value):
    """NaN and inf as None, numpy scalars as Python numbers (strict JSON)."""
    if isinstance(value, dict):
        return {k: _json_ready(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_json_ready(v) for v in value]
    if isinstance(value, (np.floating, float)):
        return float(value) if np.isfinite(value) else None
    if isinstance(value, np.integer):
        return int(value)
    return value


# ------------------------------------------------------------------------------------------------------------
# Command line: ``workbench reproduce star`` (workbench/commands/reproduce.py)
# ------------------------------------------------------------------------------------------------------------
def add_star_parser(subparsers) -> argparse.ArgumentParser:
    """Add the ``star`` command to the ``reproduce`` subparsers and return its parser."""
    parser = subparsers.add_parser("star", help="DIC Challenge 2.0 Star: spatial resolution l10, noise floor, MEI "
                                                "vs subset theory")
    parser.add_argument("--scale", type=_scale_arg, default=1.0,
                        help="image size relative to the Challenge's 4000 x 501 px, in (0, 1] (default 1)")
    parser.add_argument("--subsets", type=_int_list_arg, default=(17, 33, 65),
                        help="odd subset widths, comma-separated (default 17,33,65)")
    parser.add_argument("--orders", type=_orders_arg, default=(1, 2),
                        help="shape-function orders, comma-separated, from 1,2 (default 1,2)")
    parser.add_argument("--seed", type=int, default=0, help="pattern and noise seed (default 0)")
    parser.add_argument("--engine", default=None, help="any 2-D engine: 'cmd {ref} {def} {out}' or module:function "
                                                       "(default: this project's IC-GN)")
    parser.add_argument("--out", type=Path, default=Path("reports/star"), help="output folder (default reports/star)")
    return parser


def star_command(args) -> int:
    """Run :func:`star_report` from parsed arguments; 0 when every run gave an l10, else 1."""
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise ValueError(f"--out {out} is a file, not a folder")
    metrics = star_report(out, subsets=args.subsets, orders=args.orders, scale=args.scale, seed=args.seed,
                          progress=True, engine_spec=args.engine)
    print(f"wrote {out / 'report.md'}")
    return 0 if all(np.isfinite(r["l10_px"]) for r in metrics["runs"]) else 1


def _scale_arg(text: str) -> float:
    try:
        scale = float(text)
        scaled_shape(scale)
    except ValueError as err:
        raise argparse.ArgumentTypeError(f"scale must be a number in (0, 1], got {text!r} ({err})") from None
    return scale


def _int_list_arg(text: str) -> tuple[int, ...]:
    try:
        values = tuple(int(part) for part in text.split(","))
        for value in values:
            _check_subset(value)
    except ValueError as err:
        raise argparse.ArgumentTypeError(f"expected odd integers >= 5 separated by commas, got {text!r} ({err})") \
            from None
    return values


def _orders_arg(text: str) -> tuple[int, ...]:
    try:
        values = tuple(int(part) for part in text.split(","))
        for value in values:
            _check_order(value)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected orders from 1,2 separated by commas, got {text!r}") from None
    return values


# ------------------------------------------------------------------------------------------------------------
# Checks
# ------------------------------------------------------------------------------------------------------------
def _call_engine(engine: Engine, reference, deformed, subset_px: int, step_px: int):
    result = engine(reference, deformed, subset_px, step_px)
    try:
        x, y, u, v = result
    except (TypeError, ValueError):
        raise ValueError(f"engine must return (x_px, y_px, u_px, v_px), got {type(result).__name__}") from None
    x, y, v = _check_points(x, y, v)
    u = np.asarray(u, dtype=np.float64).ravel()
    if u.size != v.size:
        raise ValueError(f"engine returned {u.size} u values for {v.size} points")
    return x, y, u, v


def _check_points(x_px, y_px, v_px) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    x = np.asarray(x_px, dtype=np.float64).ravel()
    y = np.asarray(y_px, dtype=np.float64).ravel()
    v = np.asarray(v_px, dtype=np.float64).ravel()
    if not (x.size == y.size == v.size):
        raise ValueError(f"x_px, y_px and v_px must have the same length, got {x.size}, {y.size} and {v.size}")
    if not (np.all(np.isfinite(x)) and np.all(np.isfinite(y))):
        raise ValueError("x_px and y_px must be finite (mark a failed point by v_px = NaN)")
    if np.any(np.isinf(v)):
        raise ValueError("v_px must not be infinite (NaN marks a failed point)")
    return x, y, v


def _check_subset(subset_px) -> int:
    if isinstance(subset_px, bool) or int(subset_px) != subset_px or subset_px < 5 or int(subset_px) % 2 == 0:
        raise ValueError(f"subset_px must be an odd integer >= 5, got {subset_px!r}")
    return int(subset_px)


def _check_order(order) -> int:
    if isinstance(order, bool) or order not in ORDERS:
        raise ValueError(f"order must be 1 or 2, got {order!r}")
    return int(order)


def _check_step(step_px) -> int:
    if isinstance(step_px, bool) or int(step_px) != step_px or step_px < 1:
        raise ValueError(f"step_px must be an integer >= 1, got {step_px!r}")
    return int(step_px)


def _check_level(level) -> float:
    level = float(level)
    if not 0.0 < level < 1.0:
        raise ValueError(f"level must be in (0, 1), got {level}")
    return level


def _require_positive(value, name: str) -> float:
    try:
        value = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a number, got {value!r}") from None
    if not (np.isfinite(value) and value > 0):
        raise ValueError(f"{name} must be finite and > 0, got {value}")
    return value
