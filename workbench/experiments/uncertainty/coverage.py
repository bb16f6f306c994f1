"""How honest a per-point sigma is: normalised errors, interval coverage and sigma binned by decile.

The *random part* of a point's error is its deviation from its own mean over ``K`` noise draws of one scene
(render, interpolation and calibration errors do not change with the noise and drop out), scaled by
``sqrt(K / (K - 1))`` so that its variance is the noise's. ``z = deviation / sigma`` must then be N(0, 1).
"""
from __future__ import annotations

import math

import numpy as np

#: Two-sided quantiles of N(0, 1) for the 68.27 % and 95 % intervals.
Z68, Z95 = 1.0, 1.959964


def random_deviation(values: np.ndarray) -> np.ndarray:
    """Deviation of each draw from the per-point mean over draws, (K, N, C) -> (K, N, C), variance-unbiased."""
    values = np.asarray(values, dtype=np.float64)
    k = values.shape[0]
    if k < 2:
        raise ValueError(f"need at least 2 noise draws, got {k}")
    return (values - values.mean(axis=0)) * math.sqrt(k / (k - 1))


def coverage_figures(deviation: np.ndarray, sigma: np.ndarray, names: tuple[str, ...]) -> dict:
    """Per component: std(z), 68 % and 95 % coverage, the largest decile mismatch, the count.

    Parameters
    ----------
    deviation, sigma : ndarray (K, N, C)
        Random deviations and the sigma claimed for them (same units); points with a NaN in any draw are left out.
    names : the C component names

    Returns
    -------
    dict ``{name: {"std_z", "coverage_68", "coverage_95", "decile_ratio" (list of 10 RMS / mean sigma),
    "decile_worst" (largest |ratio - 1|), "points", "draws"}}``
    """
    keep = np.all(np.isfinite(deviation), axis=(0, 2)) & np.all(np.isfinite(sigma), axis=(0, 2)) & \
        np.all(sigma > 0, axis=(0, 2))
    d, s = deviation[:, keep], sigma[:, keep]
    out = {}
    for c, name in enumerate(names):
        z = (d[..., c] / s[..., c]).ravel()
        if z.size < 20:
            out[name] = {"std_z": math.nan, "coverage_68": math.nan, "coverage_95": math.nan, "decile_ratio": [],
                         "decile_worst": math.nan, "points": int(keep.sum()), "draws": int(d.shape[0])}
            continue
        # deciles of the points' claimed sigma (its mean over draws) against the RMS deviation in the bin
        per_point_sigma = s[..., c].mean(axis=0)
        edges = np.quantile(per_point_sigma, np.linspace(0, 1, 11))
        which = np.clip(np.searchsorted(edges, per_point_sigma, side="right") - 1, 0, 9)
        ratios = []
        for b in range(10):
            sel = which == b
            if sel.sum() < 2:
                continue
            rmse = float(np.sqrt(np.mean(d[:, sel, c] ** 2)))
            claim = float(np.sqrt(np.mean(s[:, sel, c] ** 2)))
            ratios.append(rmse / claim)
        out[name] = {"std_z": float(np.std(z)), "coverage_68": float(np.mean(np.abs(z) < Z68)),
                     "coverage_95": float(np.mean(np.abs(z) < Z95)), "decile_ratio": ratios,
                     "decile_worst": float(np.max(np.abs(np.array(ratios) - 1.0))) if ratios else math.nan,
                     "points": int(keep.sum()), "draws": int(d.shape[0])}
    return out


def z_values(deviation: np.ndarray, sigma: np.ndarray) -> np.ndarray:
    """Pooled z of every component, (K, N, C) -> (M, C), points with NaN left out (for histograms)."""
    keep = np.all(np.isfinite(deviation), axis=(0, 2)) & np.all(np.isfinite(sigma), axis=(0, 2))
    return (deviation[:, keep] / sigma[:, keep]).reshape(-1, deviation.shape[2])


#: The goals of issue 36 for the random part.
GOALS = {"std_z": (0.9, 1.1), "coverage_95": (0.93, 0.97), "decile_worst": (0.0, 0.15), "flagged_fraction": (0.0, 0.05)}


def verdict(figures: dict, flagged_fraction: float) -> dict:
    """Which goals a class meets: ``{goal: bool}`` over all its components."""
    def within(key, value):
        lo, hi = GOALS[key]
        return bool(np.isfinite(value) and lo <= value <= hi)

    comps = list(figures.values())
    return {"std_z": all(within("std_z", f["std_z"]) for f in comps),
            "coverage_95": all(within("coverage_95", f["coverage_95"]) for f in comps),
            "decile": all(within("decile_worst", f["decile_worst"]) for f in comps),
            "flagged": within("flagged_fraction", flagged_fraction)}
