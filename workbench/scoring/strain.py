"""Score a tool's surface strain against the truth: exact, and seen through the tool's own strain window.

A strain value averages over a gauge (a window of points, each measured from a subset): near a stress
concentration the exact strain's peak is narrower than any gauge, so a perfect instrument measures less than the
exact peak. The fair reference is the truth **through the same window**: the exact positions of the tool's own
points, reference and deformed, put through :func:`measurement.strain.surface_strain` with the tool's window and fit
(its points' holes included). The error against it is the instrument's (noise, bias); the difference between the
window-filtered and the exact truth is the gauge's (spatial resolution), reported apart.

The tool's points must lie on a regular grid of the left reference image (every DIC tool's output does); the
strain components are compared in the local frame of :mod:`measurement.strain` (e1 = the grid's x direction
projected onto the surface), principal strains in any frame.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


#: The smallest window-filtered peak of e1 whose measured peak is stated relative to it (10 µε).
MIN_PEAK = 1e-5


@dataclass(frozen=True)
class GridLayout:
    """Where each point of a list lies on a regular grid: ``rows``/``cols`` (N,) int, ``shape`` (rows, cols),
    ``step_px``, ``origin_px`` (x, y of node (0, 0))."""

    rows: np.ndarray
    cols: np.ndarray
    shape: tuple[int, int]
    step_px: float
    origin_px: tuple[float, float]

    def on_grid(self, values: np.ndarray) -> np.ndarray:
        """Per-point values (N, ...) laid out on the grid (rows, cols, ...), NaN at nodes without a point."""
        return _layout_values(self, np.asarray(values, float), self.rows >= 0)

    def of_points(self, grid_values: np.ndarray) -> np.ndarray:
        """Grid values (rows, cols, ...) back at the points (N, ...); NaN for a point without a position."""
        out = np.array(grid_values[self.rows, self.cols], dtype=float)
        out[self.rows < 0] = np.nan
        return out


def grid_layout(x_px, y_px, *, tol_px: float = 1e-6) -> GridLayout:
    """The regular grid the points ``(x_px, y_px)`` lie on (the same step along x and y).

    Raises
    ------
    ValueError
        Points not on one regular grid (naming a point that is off it), or two points on one node.
    """
    x, y = np.asarray(x_px, float), np.asarray(y_px, float)
    ok = np.isfinite(x) & np.isfinite(y)
    if ok.sum() < 4:
        raise ValueError(f"strain needs a grid of points; only {int(ok.sum())} have a finite position")
    # the grid step: the most common spacing between neighbouring distinct coordinates, along x and y together (a
    # point off the grid makes two odd spacings, not the step)
    gaps = np.concatenate([np.diff(np.unique(v)) for v in (x[ok], y[ok])])
    gaps = np.round(gaps[gaps > tol_px], 6)
    if not gaps.size:
        raise ValueError("the points do not span a grid (all on one spot)")
    values, counts = np.unique(gaps, return_counts=True)
    step = float(values[np.argmax(counts)])
    x0, y0 = x[ok].min(), y[ok].min()
    j, i = (x - x0) / step, (y - y0) / step
    off = ok & ((np.abs(j - np.round(j)) > tol_px * 1e3 / step) | (np.abs(i - np.round(i)) > tol_px * 1e3 / step))
    if off.any():
        k = int(np.flatnonzero(off)[0])
        raise ValueError(f"the points are not on one regular grid: point {k} at ({x[k]:g}, {y[k]:g}) px is off the "
                         f"grid of step {step:g} px from ({x0:g}, {y0:g})")
    rows = np.where(ok, np.round(i), 0).astype(np.int64)
    cols = np.where(ok, np.round(j), 0).astype(np.int64)
    shape = (int(rows.max()) + 1, int(cols.max()) + 1)
    flat = rows[ok] * shape[1] + cols[ok]
    if np.unique(flat).size != flat.size:
        raise ValueError("two points of the result lie on one grid node: not a grid of points")
    rows[~ok], cols[~ok] = -1, -1
    return GridLayout(rows, cols, shape, float(step), (float(x0), float(y0)))


def windowed_truth(layout: GridLayout, X0_mm: np.ndarray, Xk_mm: np.ndarray, used: np.ndarray, window, fit: str):
    """The exact positions of the points through the tool's strain window: a
    :class:`measurement.strain.SurfaceStrain` on the grid (``window`` None: triangles), using only the ``used``
    points (those the tool measured), NaN elsewhere."""
    from measurement.strain import surface_strain

    keep = used & (layout.rows >= 0)
    nan = np.full_like(X0_mm, np.nan)
    A = np.where(keep[:, None], X0_mm, nan)
    B = np.where(keep[:, None], Xk_mm, nan)
    return surface_strain(_layout_values(layout, A, keep), _layout_values(layout, B, keep), window=window, fit=fit)


def _layout_values(layout: GridLayout, values: np.ndarray, keep: np.ndarray) -> np.ndarray:
    out = np.full(layout.shape + values.shape[1:], np.nan)
    out[layout.rows[keep], layout.cols[keep]] = values[keep]
    return out


def _rms(a) -> float:
    a = np.asarray(a, float)
    a = a[np.isfinite(a)]
    return float(np.sqrt(np.mean(a ** 2))) if a.size else float("nan")


def _peak(values: np.ndarray, x, y, X_mm) -> dict | None:
    ok = np.isfinite(values)
    if not ok.any():
        return None
    i = int(np.argmax(np.where(ok, values, -np.inf)))
    return {"index": i, "microstrain": 1e6 * float(values[i]), "x_px": float(x[i]), "y_px": float(y[i]),
            "X_left_mm": [float(v) for v in X_mm[i]]}


@dataclass(frozen=True)
class StrainScore:
    """Per point (N, ...): the tool's strain, the window-filtered truth and the exact truth (E11, E22, E12, E1, E2 in
    columns, dimensionless; NaN where not compared) and the summary ``metrics``."""

    measured: np.ndarray
    windowed: np.ndarray
    exact: np.ndarray
    metrics: dict


def _with_principal(E: np.ndarray) -> np.ndarray:
    mean = 0.5 * (E[:, 0] + E[:, 1])
    radius = np.hypot(0.5 * (E[:, 0] - E[:, 1]), E[:, 2])
    return np.column_stack([E, mean + radius, mean - radius])


def score_strain(x_px, y_px, measured_E: np.ndarray, scored: np.ndarray, X0_mm: np.ndarray, Xk_mm: np.ndarray,
                 exact_left: np.ndarray, window, fit: str, sigma: np.ndarray | None = None) -> StrainScore:
    """Score a tool's surface strain (module notes).

    Parameters
    ----------
    x_px, y_px : (N,) the points in the left reference image (a regular grid)
    measured_E : (N, 3) the tool's E11, E22, E12 (Green-Lagrange, tensor shear, local frame)
    scored : (N,) bool, the points the tool measured on the specimen
    X0_mm, Xk_mm : (N, 3) the points' exact positions in the reference and the state, left camera frame
    exact_left : (N, 3, 3) the exact strain tensors (:attr:`workbench.scoring.datasets.PointTruth.strain_left`)
    window : int or None (triangles); fit : "linear" or "quadratic" -- the tool's strain window
    sigma : (N, 3) the tool's standard uncertainty of E11, E22, E12, or None
    """
    from workbench.scoring.datasets import strain_components

    layout = grid_layout(x_px, y_px)
    used = scored & np.all(np.isfinite(X0_mm), axis=1) & np.all(np.isfinite(Xk_mm), axis=1)
    filt = windowed_truth(layout, X0_mm, Xk_mm, used, window, fit)
    pts = layout.of_points
    windowed = np.column_stack([pts(filt.E11), pts(filt.E22), pts(filt.E12)])
    e1, e2 = pts(filt.e1), pts(filt.e2)
    exact = strain_components(np.where(np.isfinite(exact_left), exact_left, 0.0), np.nan_to_num(e1),
                              np.nan_to_num(e2))
    exact[~np.all(np.isfinite(exact_left.reshape(-1, 9)), axis=1) | ~np.all(np.isfinite(e1), axis=1)] = np.nan
    measured = np.asarray(measured_E, float)
    both = used & np.all(np.isfinite(measured), axis=1) & np.all(np.isfinite(windowed), axis=1)
    M, W, X = (_with_principal(np.where(both[:, None], a, np.nan)) for a in (measured, windowed, exact))
    names = ("exx", "eyy", "exy", "e1", "e2")
    m = {"strain_points": int(both.sum()), "strain_window_points": window, "strain_fit": fit,
         "strain_grid_step_px": layout.step_px}
    for j, c in enumerate(names):
        m[f"strain_rms_{c}_vs_windowed_microstrain"] = 1e6 * _rms(M[:, j] - W[:, j])
        m[f"strain_bias_{c}_vs_windowed_microstrain"] = 1e6 * float(np.nanmean(M[:, j] - W[:, j])) if both.any() \
            else float("nan")
        m[f"strain_rms_{c}_vs_exact_microstrain"] = 1e6 * _rms(M[:, j] - X[:, j])
    x, y = np.asarray(x_px, float), np.asarray(y_px, float)
    peaks = {"measured": _peak(M[:, 3], x, y, X0_mm), "windowed_truth": _peak(W[:, 3], x, y, X0_mm),
             "exact_truth": _peak(X[:, 3], x, y, X0_mm)}
    if peaks["measured"] and peaks["windowed_truth"]:
        pm, pw = peaks["measured"], peaks["windowed_truth"]
        pm["windowed_truth_here_microstrain"] = 1e6 * float(W[pm["index"], 3])
        pw["measured_here_microstrain"] = 1e6 * float(M[pw["index"], 3])
        m["strain_peak_e1_measured_microstrain"] = pm["microstrain"]
        m["strain_peak_e1_windowed_microstrain"] = pw["microstrain"]
        # a windowed peak under MIN_PEAK (a rigid move, a static repeat) is no concentration: no relative error
        m["strain_peak_e1_error_percent"] = 100.0 * (pm["microstrain"] / pw["microstrain"] - 1.0) \
            if pw["microstrain"] >= 1e6 * MIN_PEAK else float("nan")
        m["strain_peak_distance_px"] = float(np.hypot(pm["x_px"] - pw["x_px"], pm["y_px"] - pw["y_px"]))
    if peaks["exact_truth"]:
        m["strain_peak_e1_exact_microstrain"] = peaks["exact_truth"]["microstrain"]
    for p in peaks.values():
        if p:
            p.pop("index")
    m["strain_peaks"] = peaks
    if sigma is not None:
        s = np.asarray(sigma, float)
        for j, c in enumerate(names[:3]):
            ok = both & np.isfinite(s[:, j]) & (s[:, j] > 0)
            z = (M[ok, j] - W[ok, j]) / s[ok, j]
            m[f"strain_sigma_coverage_95_{c}"] = float(np.mean(np.abs(z) < 1.959964)) if z.size else float("nan")
            m[f"strain_sigma_rms_z_{c}"] = float(np.sqrt(np.mean(z ** 2))) if z.size else float("nan")
    return StrainScore(M, W, X, m)
