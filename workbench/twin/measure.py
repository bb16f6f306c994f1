"""The instrument on a static pair: the one noise measurement the twin's predictions and the real pair share.

A static pair is two exposures of an unmoved specimen; whatever the instrument reports between them is noise.
:func:`static_noise_stereo` (two cameras and a calibration) and :func:`static_noise_2d` (one camera) run the
instrument exactly as ``workbench stereo`` / ``workbench dic`` do and reduce the result the same way whether the
images are real or the twin's, so a prediction and a measurement are compared like for like:

* displacement noise = standard deviation over the measured points of each component after its mean is removed
  (the DIC Challenge's noise floor, 1 sigma on a static pair), U, V, W in µm (left camera frame) or u, v in px;
* the same after a rigid-body fit is removed (stereo) or a plane per component (2-D): a gap between the two
  says the "static" pair moved (vibration, a mount settling), which is not noise;
* strain noise = standard deviation of E11, E22, E12 (µε) with the strain window;
* the mean motion of the left camera's temporal match, px (the "is it static?" test);
* with the cameras' noise models given, the instrument's own predicted sigma of a static repeat at each point
  (:mod:`measurement.uncertainty`: :func:`~measurement.uncertainty.stereo.static_repeat_covariance_mm2` from the
  reference shape, :func:`~measurement.uncertainty.match.static_repeat_covariance_px2` from the reference subsets),
  and its RMS over the same points as the noise figures: what the measured noise should read.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from measurement.dic import DICSettings, correlate
from measurement.rigid import remove_rigid_motion
from measurement.stereo_dic import measure_state, reference_shape
from measurement.strain import surface_strain
from measurement.uncertainty.match import static_repeat_sigma_px
from measurement.uncertainty.stereo import static_repeat_sigma_um

#: A point whose value lies beyond this many robust sigma (1.4826 MAD) of the median is an outlier (a bad match),
#: dropped from the noise figures alike for the real pair and the twin.
OUTLIER_SIGMA = 6.0


@dataclass
class StaticNoise:
    """Noise figures of one static pair (module notes).

    Attributes
    ----------
    kind : {"stereo", "2d"}
    noise : dict
        ``{"U_um", "V_um", "W_um"}`` (stereo) or ``{"u_px", "v_px"}`` (2-D): 1 sigma, mean removed.
    detrended : dict
        The same after a rigid-body fit (stereo) or a plane per component (2-D).
    strain_ue : dict
        ``{"E11", "E22", "E12"}`` strain noise, µε (1 sigma); empty when no strain could be computed.
    mean_motion_px : float
        |mean (u, v)| of the left camera's temporal match, px.
    motion_sigma_px : float
        1 sigma of that match's u and v (RMS of the two), px.
    points : int
        Points measured (after outliers).
    outliers : int
    x_px, y_px : ndarray, shape (N,)
        The points (left reference image), px.
    values : ndarray, shape (N, 3) or (N, 2)
        Per-point U, V, W in µm (stereo) or u, v in px, mean removed, NaN where not measured or an outlier.
    X_ref_mm : ndarray, shape (N, 3) or None
        Reference positions (stereo), left camera frame.
    right_xy_px : ndarray, shape (N, 2) or None
        The points' match in the right reference image (stereo), px.
    mean_motion_uv_px : (float, float)
        Mean (u, v) of the left camera's temporal match, px.
    right_motion_uv_px : (float, float)
        Mean motion of the right camera's image between the exposures (stereo), px: the static right match less the
        reference right match.
    instrument_sigma : dict
        The instrument's predicted static-repeat sigma (module notes), RMS over the points of ``noise``, same keys
        and units; empty without noise models.
    sigma : ndarray, shape (N, 3) or (N, 2), or None
        That sigma per point (µm or px), NaN where undefined; None without noise models.
    """

    kind: str
    noise: dict
    detrended: dict
    strain_ue: dict
    mean_motion_px: float
    motion_sigma_px: float
    points: int
    outliers: int
    x_px: np.ndarray = field(repr=False)
    y_px: np.ndarray = field(repr=False)
    values: np.ndarray = field(repr=False)
    X_ref_mm: np.ndarray | None = field(default=None, repr=False)
    right_xy_px: np.ndarray | None = field(default=None, repr=False)
    mean_motion_uv_px: tuple = (0.0, 0.0)
    right_motion_uv_px: tuple = (0.0, 0.0)
    instrument_sigma: dict = field(default_factory=dict)
    sigma: np.ndarray | None = field(default=None, repr=False)

    def summary(self) -> dict:
        out = {"kind": self.kind, **{k: float(v) for k, v in self.noise.items()},
               **{f"{k}_instrument_sigma": float(v) for k, v in self.instrument_sigma.items()},
               **{f"{k}_detrended": float(v) for k, v in self.detrended.items()},
               **{f"{k}_ue": float(v) for k, v in self.strain_ue.items()},
               "mean_motion_px": float(self.mean_motion_px), "motion_sigma_px": float(self.motion_sigma_px),
               "points": int(self.points), "outliers": int(self.outliers)}
        return out


def _outliers(values: np.ndarray) -> np.ndarray:
    """Rows with any component beyond OUTLIER_SIGMA robust sigma of its median (NaN rows are not outliers)."""
    bad = np.zeros(values.shape[0], dtype=bool)
    for k in range(values.shape[1]):
        v = values[:, k]
        ok = np.isfinite(v)
        if ok.sum() < 10:
            continue
        med = np.median(v[ok])
        mad = 1.4826 * np.median(np.abs(v[ok] - med))
        bad |= ok & (np.abs(v - med) > OUTLIER_SIGMA * max(mad, 1e-12))
    return bad


def _std(values: np.ndarray) -> float:
    v = values[np.isfinite(values)]
    return float(np.std(v)) if v.size >= 2 else math.nan


def _grid(x: np.ndarray, y: np.ndarray, values: np.ndarray) -> np.ndarray:
    """Scatter per-point vectors onto their (rows, cols) grid (NaN where no point)."""
    xs, ix = np.unique(x, return_inverse=True)
    ys, iy = np.unique(y, return_inverse=True)
    out = np.full((ys.size, xs.size, values.shape[1]), np.nan)
    out[iy, ix] = values
    return out


def _rms_over(sigma: np.ndarray, ok: np.ndarray, names) -> dict:
    """RMS over the rows ``ok`` of each column of ``sigma`` (finite values only): the pooled predicted sigma."""
    out = {}
    for k, name in enumerate(names):
        v = sigma[ok, k]
        v = v[np.isfinite(v)]
        out[name] = float(np.sqrt(np.mean(v * v))) if v.size else math.nan
    return out


def strain_noise(X_ref: np.ndarray, X_def: np.ndarray, x, y, window: int | None) -> dict:
    """1 sigma of E11, E22, E12 (µε) of a static pair's points on their grid (``surface_strain`` with ``window``
    grid points, or triangles for None); empty when the grid is smaller than the window."""
    ref, de = _grid(x, y, X_ref), _grid(x, y, X_def)
    if min(ref.shape[:2]) < 3 or (window is not None and min(ref.shape[:2]) < window):
        return {}
    try:
        strain = surface_strain(ref, de, window=window)
    except ValueError:              # too few measured neighbours left to span the grid: no strain figure
        return {}
    return {name: _std(getattr(strain, name).ravel()) * 1e6 for name in ("E11", "E22", "E12")}


def static_noise_stereo(rig, left_ref, right_ref, left_static, right_static, settings: DICSettings, *,
                        roi=None, mask=None, strain_window: int | None = 5, shape=None,
                        noise: dict | None = None) -> StaticNoise:
    """Measure a stereo static pair with the instrument (module notes).

    Parameters
    ----------
    rig : object with ``left``, ``right`` (ScheimpflugCamera), ``R_right_from_left``, ``T_right_from_left_mm``
    left_ref, right_ref, left_static, right_static : ndarray, shape (rows, cols)
    settings : DICSettings
    roi, mask
        As :func:`measurement.stereo_dic.reference_shape`.
    strain_window : int or None
        Strain window in grid points (None: triangles).
    shape : StereoShape, optional
        A reference shape already measured from ``left_ref``/``right_ref`` (saves one match).
    noise : {"left": NoiseModel, "right": NoiseModel}, optional
        The cameras' noise models: the reference shape's uncertainty is computed with them and the instrument's
        predicted static sigma is returned beside the measured noise (``instrument_sigma``, ``sigma``).

    Returns
    -------
    StaticNoise

    Raises
    ------
    ValueError
        Both ``shape`` and ``noise`` given, the shape measured with other noise models.
    """
    cams = (rig.left, rig.right, rig.R_right_from_left, rig.T_right_from_left_mm)
    if shape is None:
        shape = reference_shape(*cams, left_ref, right_ref, settings, roi=roi, mask=mask, noise=noise)
    elif noise is not None and shape.noise is not noise:
        raise ValueError("the given reference shape's uncertainty was computed with other noise models than `noise`")
    state = measure_state(*cams, shape, left_ref, left_static, right_static, settings, name="static repeat")
    U_um = state.U_mm * 1e3
    bad = _outliers(U_um)
    ok = state.valid & ~bad & np.all(np.isfinite(U_um), axis=1)
    sigma = None
    if noise is not None:
        sigma = static_repeat_sigma_um(rig, shape)
    values = np.where(ok[:, None], U_um - np.nanmean(U_um[ok], axis=0), np.nan)
    figures = {f"{c}_um": _std(values[:, k]) for k, c in enumerate("UVW")}
    detrended = {}
    if ok.sum() >= 10:
        removal = remove_rigid_motion(shape.X_mm[ok], state.X_mm[ok])
        resid = removal.residual_mm * 1e3
        detrended = {f"{c}_um": _std(resid[:, k]) for k, c in enumerate("UVW")}
    X_def = np.where(ok[:, None], state.X_mm, np.nan)
    strain = strain_noise(np.where(ok[:, None], shape.X_mm, np.nan), X_def, shape.x, shape.y, strain_window)
    lm = state.left_match
    conv = np.isfinite(lm.u) & np.isfinite(lm.v)
    mean_uv = (float(np.mean(lm.u[conv])), float(np.mean(lm.v[conv]))) if conv.any() else (math.nan, math.nan)
    motion_sigma = float(np.sqrt(0.5 * (np.var(lm.u[conv]) + np.var(lm.v[conv])))) if conv.any() else math.nan
    rm = shape.right_match
    right_xy = np.column_stack([rm.x + rm.u, rm.y + rm.v]).astype(np.float64)
    du, dv = state.right_match.u - rm.u, state.right_match.v - rm.v
    both = np.isfinite(du) & np.isfinite(dv)
    right_uv = (float(np.mean(du[both])), float(np.mean(dv[both]))) if both.any() else (0.0, 0.0)
    predicted = _rms_over(sigma, ok, list(figures)) if sigma is not None else {}
    return StaticNoise("stereo", figures, detrended, strain, float(np.hypot(*mean_uv)), motion_sigma, int(ok.sum()),
                       int(bad.sum()), shape.x.astype(np.float64), shape.y.astype(np.float64), values, shape.X_mm,
                       right_xy, mean_uv, right_uv, predicted, sigma)


def static_noise_2d(reference, static, settings: DICSettings, *, roi=None, mask=None,
                    strain_window: int | None = 5, noise=None) -> StaticNoise:
    """Measure a one-camera static pair with the instrument (module notes); u, v in px.

    With the camera's ``noise`` (a :class:`~measurement.speckle_quality.NoiseModel`) the instrument's predicted
    static sigma is returned beside the measured noise (``instrument_sigma``, ``sigma``)."""
    result = correlate(reference, static, settings, roi=roi, mask=mask)
    uv = np.column_stack([result.u, result.v]).astype(np.float64)
    bad = _outliers(uv)
    ok = result.converged & ~bad & np.all(np.isfinite(uv), axis=1)
    sigma = None
    if noise is not None:
        sigma = static_repeat_sigma_px(reference, result.x, result.y, settings, noise)
        sigma[~result.converged] = np.nan           # as the stereo shape: no match, no sigma
    values = np.where(ok[:, None], uv - np.nanmean(uv[ok], axis=0), np.nan)
    figures = {"u_px": _std(values[:, 0]), "v_px": _std(values[:, 1])}
    x, y = result.x.astype(np.float64), result.y.astype(np.float64)
    detrended = {}
    if ok.sum() >= 10:
        A = np.column_stack([np.ones(ok.sum()), x[ok], y[ok]])
        for k, c in enumerate("uv"):
            coef, *_ = np.linalg.lstsq(A, uv[ok, k], rcond=None)
            detrended[f"{c}_px"] = float(np.std(uv[ok, k] - A @ coef))
    X_ref = np.column_stack([x, y, np.zeros_like(x)])
    X_def = X_ref + np.column_stack([uv, np.zeros_like(x)])
    strain = strain_noise(np.where(ok[:, None], X_ref, np.nan), np.where(ok[:, None], X_def, np.nan), x, y,
                           strain_window)
    mean_uv = tuple(float(m) for m in np.nanmean(uv[ok], axis=0)) if ok.any() else (math.nan, math.nan)
    motion_sigma = float(np.sqrt(0.5 * (figures["u_px"] ** 2 + figures["v_px"] ** 2)))
    predicted = _rms_over(sigma, ok, list(figures)) if sigma is not None else {}
    return StaticNoise("2d", figures, detrended, strain, float(np.hypot(*mean_uv)), motion_sigma, int(ok.sum()),
                       int(bad.sum()), x, y, values, None, None, mean_uv, (0.0, 0.0), predicted, sigma)
