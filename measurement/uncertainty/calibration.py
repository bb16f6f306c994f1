"""Systematic (calibration) term of the per-point uncertainty of stereo-DIC.

A calibration is estimated once from noisy board corners; its error ``d theta`` (intrinsics of both cameras, the
stereo pose) then moves every triangulated point of every state by the same rule::

    d X_i = G_i d theta,      G_i = d X_left_mm / d theta at pixel pair i        (3, k), mm per parameter unit
    Cov(X_i)_calibration = G_i C G_i^T                                             (3, 3), mm^2

with ``C`` the calibration's parameter covariance (:attr:`StereoCalibration.covariance
<measurement.calibration.stepwise.StereoCalibration.covariance>`: ``s^2 (J^T J)^-1`` of the final stereo least
squares, board poses marginalised; stored in the calibration JSON, :mod:`measurement.calibration.io`). ``G`` is
the derivative of :func:`measurement.stereo.triangulate` (optimal, ``refine=True``) for FIXED pixel pairs, by
central finite differences over each parameter (:data:`DEFAULT_STEPS`).

The same ``d theta`` acts on the reference and the deformed state, so a displacement ``U_i = X_def,i - X_ref,i``
has ``G_U,i = G_def,i - G_ref,i``: much of the calibration error cancels in displacements, and what is left is
correlated between all points and all states. That is why this term is kept apart from the random (matching)
term, which is independent per state and point, and why :func:`common_mode_summary` reports how much of it is
common to the whole field (an offset of the mean, a scale factor) rather than point-to-point scatter.

Validity: first order in the calibration error. It holds while the calibration's estimate is linear in the corner
noise; on narrow-field rigs, where tilt and principal point are nearly interchangeable, that needs small noise. On
the paper's rig (fx ~ 10 900 px, 12 views of an 11 x 8-corner board) the observed spread over calibrations is
0.99-1.03 x the predicted sigma at 0.005 px of corner noise, 1.05-1.28 x at 0.02 px and 1.5-2.2 x at 0.05 px
(``tests/test_calibration_uncertainty.py``): beyond ~0.01 px there the prediction is a lower bound.

A rig without a covariance (a calibration file written before the covariance was stored, or another tool's)
gives NaN, never zero: the calibration part of the uncertainty is then unknown, and a warning says so once per
process. Non-finite pixels (and pixel pairs that do not triangulate) give NaN rows.

Frames and units: points in the left camera frame, mm; parameters as named in ``covariance_names``
(``left.fx`` px, ``left.alpha_deg`` deg, ``left.k1`` dimensionless, ..., ``stereo.rvec_x`` rad: the rotation vector
of ``R_right_from_left`` perturbed additively, ``stereo.T_x_mm`` mm).
"""
from __future__ import annotations

import warnings
from dataclasses import dataclass, replace
from numbers import Real

import numpy as np
from scipy.spatial.transform import Rotation

from measurement.calibration.stepwise import STEREO_PARAMETER_NAMES
from measurement.camera import EXTRA_NAMES, INTRINSIC_NAMES, ScheimpflugCamera
from measurement.stereo import triangulate

__all__ = ["DEFAULT_STEPS", "NO_COVARIANCE_MESSAGE", "CommonModeSummary", "calibration_sensitivity",
           "calibration_covariance_mm2", "displacement_calibration_covariance_mm2", "common_mode_summary"]

#: Central-difference step of each kind of parameter, in its own unit: far below its calibration sigma (fx ~ 1 px,
#: tilt ~ 1e-2 deg, k1 ~ 1e-3, rvec ~ 1e-5 rad, T ~ 1e-2 mm on the paper's rig) so the difference is linear, and
#: large enough that the triangulated point moves far above its rounding and the triangulation's tolerance. The
#: higher radial terms multiply r^4 and r^6 (r ~ 0.1 on DIC fields), hence their larger steps. On the paper's rig
#: the derivatives agree with an implicit-function derivative within 3e-7 of each column's largest entry, and
#: within 2e-6 for steps 0.1 to 10 times these (``tests/test_calibration_uncertainty.py``).
DEFAULT_STEPS = {"fx": 1e-2, "fy": 1e-2, "cx": 1e-2, "cy": 1e-2, "skew": 1e-2, "alpha_deg": 1e-3, "beta_deg": 1e-3,
                 "k1": 1e-4, "k2": 1e-3, "k3": 1e-2, "p1": 1e-5, "p2": 1e-5,
                 "s1": 1e-4, "s2": 1e-3, "s3": 1e-4, "s4": 1e-3, "rvec": 1e-6, "T": 1e-3}
#: Gauss-Newton tolerance of the triangulations inside the differences (mm): far below the ~1e-4 mm a step
#: moves a point (the default 1e-6 mm would be a 1 % error of such a difference).
_XTOL_MM = 1e-11
_MAX_ITER = 60
#: The warning issued (once per process) for a rig without a covariance.
NO_COVARIANCE_MESSAGE = ("the calibration has no parameter covariance (a calibration file written without the "
                         "'covariance' key, or another tool's file): the calibration part of the uncertainty is "
                         "unknown, not zero, and is reported as NaN; recalibrate with this instrument to get it")
_NONFINITE_COVARIANCE_MESSAGE = ("the calibration's parameter covariance is not finite (a singular normal matrix): "
                                 "the calibration part of the uncertainty is unknown and is reported as NaN")
_warned: set[str] = set()


def _warn_once(message: str) -> None:
    if message not in _warned:
        _warned.add(message)
        warnings.warn(message, UserWarning, stacklevel=3)


# --------------------------------------------------------------------------------------------------------
# The rig's parts
# --------------------------------------------------------------------------------------------------------
def _camera(side) -> ScheimpflugCamera:
    """A ScheimpflugCamera (CalibratedRig) or a CameraCalibration's ``.camera`` (StereoCalibration)."""
    return side if isinstance(side, ScheimpflugCamera) else side.camera


def _parts(rig):
    return (_camera(rig.left), _camera(rig.right), np.asarray(rig.R_right_from_left, float),
            np.asarray(rig.T_right_from_left_mm, float).ravel())


def _covariance(rig) -> tuple[np.ndarray | None, tuple[str, ...]]:
    """The rig's (k, k) covariance and its names, or (None, ()) with the warning."""
    cov = getattr(rig, "covariance", None)
    names = tuple(getattr(rig, "covariance_names", ()) or ())
    if cov is None:
        _warn_once(NO_COVARIANCE_MESSAGE)
        return None, ()
    cov = np.asarray(cov, float)
    if cov.shape != (len(names), len(names)):
        raise ValueError(f"rig.covariance has shape {cov.shape} but rig.covariance_names lists {len(names)} "
                         f"parameters")
    if not np.all(np.isfinite(cov)):
        _warn_once(_NONFINITE_COVARIANCE_MESSAGE)
        return None, ()
    return cov, names


def _default_names(rig) -> tuple[str, ...]:
    """The rig's covariance names, else Table 1's intrinsics of both cameras and the stereo pose."""
    names = tuple(getattr(rig, "covariance_names", ()) or ())
    return names or (tuple(f"{s}.{n}" for s in ("left", "right") for n in INTRINSIC_NAMES) + STEREO_PARAMETER_NAMES)


def _kind(name: str) -> tuple[str, str, int | None]:
    """``"left.fx"`` -> ("left", "fx", None); ``"stereo.rvec_y"`` -> ("stereo", "rvec", 1); ``"stereo.T_z_mm"``
    -> ("stereo", "T", 2); ValueError naming the parameter otherwise."""
    side, _, rest = name.partition(".")
    if side in ("left", "right") and rest in INTRINSIC_NAMES + EXTRA_NAMES:
        return side, rest, None
    if name in STEREO_PARAMETER_NAMES:
        i = STEREO_PARAMETER_NAMES.index(name)
        return "stereo", ("rvec", "T")[i // 3], i % 3
    raise ValueError(f"unknown calibration parameter {name!r}: expected left.<intrinsic>, right.<intrinsic> "
                     f"({', '.join(INTRINSIC_NAMES + EXTRA_NAMES)}) or one of {', '.join(STEREO_PARAMETER_NAMES)}")


def _steps(names, step) -> np.ndarray:
    """(k,) absolute steps: DEFAULT_STEPS by kind, times ``step`` (a number), or ``step[name]`` (a mapping; names
    it does not list keep their default)."""
    base = np.array([DEFAULT_STEPS[_kind(n)[1]] for n in names])
    if step is None:
        return base
    if isinstance(step, Real) and not isinstance(step, bool):
        if not (np.isfinite(step) and step > 0):
            raise ValueError(f"step must be a positive factor, got {step!r}")
        return base * float(step)
    if isinstance(step, dict):
        unknown = sorted(set(step) - set(names))
        if unknown:
            raise ValueError(f"step names parameter(s) {', '.join(map(repr, unknown))} not among names")
        out = np.array([float(step.get(n, b)) for n, b in zip(names, base)])
        if not np.all(np.isfinite(out) & (out > 0)):
            raise ValueError("every step must be finite and positive")
        return out
    raise TypeError(f"step must be None, a positive factor or a mapping name -> step, got {type(step).__name__}")


def _perturbed(left, right, R, T, name: str, delta: float):
    """(left, right, R, T) with parameter ``name`` moved by ``delta`` (its own unit)."""
    side, what, axis = _kind(name)
    if side == "left":
        return replace(left, **{what: getattr(left, what) + delta}), right, R, T
    if side == "right":
        return left, replace(right, **{what: getattr(right, what) + delta}), R, T
    if what == "rvec":                 # the calibration's parametrisation: R = from_rotvec(rotvec)
        rv = Rotation.from_matrix(R).as_rotvec()
        rv[axis] += delta
        return left, right, Rotation.from_rotvec(rv).as_matrix(), T
    T = T.copy()
    T[axis] += delta
    return left, right, R, T


def _pixels(name: str, pixels) -> np.ndarray:
    p = np.asarray(pixels, float)
    if p.ndim != 2 or p.shape[1] != 2:
        raise ValueError(f"{name} must have shape (N, 2) px, got {p.shape}")
    return p


# --------------------------------------------------------------------------------------------------------
# Public API
# --------------------------------------------------------------------------------------------------------
def calibration_sensitivity(rig, pixels_left_px, pixels_right_px, names=None, step=None) -> np.ndarray:
    """Derivative of the triangulated points with respect to the calibration parameters, for fixed pixels.

    Parameters
    ----------
    rig : CalibratedRig or StereoCalibration
        Anything with ``left``, ``right`` (ScheimpflugCamera, or CameraCalibration with ``.camera``),
        ``R_right_from_left`` (3, 3) and ``T_right_from_left_mm`` (3,) mm.
    pixels_left_px, pixels_right_px : array, shape (N, 2), px
        Matched pixel pairs.
    names : sequence of k str, optional
        Parameters to differentiate by (``"left.fx"``, ..., ``"stereo.rvec_x"``, ``"stereo.T_z_mm"``); default the
        rig's ``covariance_names``, or Table 1's intrinsics of both cameras and the stereo pose.
    step : None, float or dict, optional
        Central-difference steps: :data:`DEFAULT_STEPS` by parameter kind (None), those times a factor (float),
        or absolute steps per name (dict; unlisted names keep the default).

    Returns
    -------
    ndarray, shape (N, 3, k), mm per parameter unit
        ``G[i, :, j] = d X_left_mm[i] / d theta_j`` (triangulation with ``refine=True``); NaN rows where the
        pixels are not finite or a point does not triangulate at either side of a difference.
    """
    pl, pr = _pixels("pixels_left_px", pixels_left_px), _pixels("pixels_right_px", pixels_right_px)
    if len(pl) != len(pr):
        raise ValueError(f"pixels_left_px and pixels_right_px differ in length: {len(pl)} vs {len(pr)}")
    names = _default_names(rig) if names is None else tuple(names)
    for n in names:
        _kind(n)                                          # refuse an unknown name before any work
    h = _steps(names, step)
    left, right, R, T = _parts(rig)
    G = np.full((len(pl), 3, len(names)), np.nan)
    ok = np.all(np.isfinite(pl), axis=1) & np.all(np.isfinite(pr), axis=1)
    if not ok.any():
        return G
    pl, pr = pl[ok], pr[ok]
    out = np.empty((len(pl), 3, len(names)))
    for j, (name, hj) in enumerate(zip(names, h)):
        X = [triangulate(*_perturbed(left, right, R, T, name, s * hj), pl, pr, refine=True, xtol_mm=_XTOL_MM,
                         max_iter=_MAX_ITER).X_left_mm for s in (1.0, -1.0)]
        out[:, :, j] = (X[0] - X[1]) / (2.0 * hj)
    G[ok] = out
    G[~np.all(np.isfinite(G), axis=(1, 2))] = np.nan       # a point lost at one side of one difference
    return G


def _propagate(G: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """(N, 3, k), (k, k) -> (N, 3, 3): G C G^T per point, exactly symmetric."""
    out = np.einsum("nik,kl,njl->nij", G, cov, G)
    return 0.5 * (out + np.swapaxes(out, 1, 2))


def calibration_covariance_mm2(rig, pixels_left_px, pixels_right_px) -> np.ndarray:
    """Calibration part of the covariance of each triangulated point, ``G_i C G_i^T``.

    Parameters
    ----------
    rig : CalibratedRig or StereoCalibration (see :func:`calibration_sensitivity`), with ``covariance`` (k, k)
        and ``covariance_names`` (k,)
    pixels_left_px, pixels_right_px : array, shape (N, 2), px

    Returns
    -------
    ndarray, shape (N, 3, 3), mm^2
        In the left camera frame. All NaN (and a warning, once per process) when the rig has no covariance;
        NaN for the points that do not triangulate.
    """
    pl, pr = _pixels("pixels_left_px", pixels_left_px), _pixels("pixels_right_px", pixels_right_px)
    cov, names = _covariance(rig)
    if cov is None:
        return np.full((len(pl), 3, 3), np.nan)
    return _propagate(calibration_sensitivity(rig, pl, pr, names), cov)


def displacement_calibration_covariance_mm2(rig, ref_left_px, ref_right_px, def_left_px,
                                            def_right_px) -> np.ndarray:
    """Calibration part of the covariance of each displacement ``U = X_def - X_ref``, ``G_U C G_U^T``.

    ``G_U = G_def - G_ref``: the same calibration error moves both states' points, so most of it cancels in U
    (a rigid motion of the frame cancels entirely for a zero displacement). This is the only correct way to get
    U's calibration term: adding the two states' covariances would double-count what cancels.

    Parameters
    ----------
    rig : CalibratedRig or StereoCalibration with a covariance (see :func:`calibration_covariance_mm2`)
    ref_left_px, ref_right_px : array, shape (N, 2), px
        The points' pixel pairs in the reference state.
    def_left_px, def_right_px : array, shape (N, 2), px
        The same points' pixel pairs in the deformed state.

    Returns
    -------
    ndarray, shape (N, 3, 3), mm^2
        NaN where the rig has no covariance (with the warning) or a point does not triangulate in either state.
    """
    pixels = [_pixels(n, p) for n, p in (("ref_left_px", ref_left_px), ("ref_right_px", ref_right_px),
                                         ("def_left_px", def_left_px), ("def_right_px", def_right_px))]
    if len({len(p) for p in pixels}) != 1:
        raise ValueError(f"the four pixel arrays must have the same length, got {[len(p) for p in pixels]}")
    cov, names = _covariance(rig)
    if cov is None:
        return np.full((len(pixels[0]), 3, 3), np.nan)
    G_U = calibration_sensitivity(rig, pixels[2], pixels[3], names) - calibration_sensitivity(rig, pixels[0],
                                                                                              pixels[1], names)
    return _propagate(G_U, cov)


@dataclass(frozen=True)
class CommonModeSummary:
    """How much of the calibration error of a field is common to all its points (:func:`common_mode_summary`).

    Attributes
    ----------
    field : ``"position"`` (the points X of one state) or ``"displacement"`` (U = X_def - X_ref)
    n_points : points that triangulate (in both states for a displacement); the others are left out
    sigma_mean_mm : (3,) mm
        Predicted standard deviation of the mean of the field over the points, per component (left frame):
        ``sqrt(diag(G_mean C G_mean^T))``, ``G_mean`` the mean sensitivity. A calibration error that shifts all
        points alike shows here in full; point-to-point scatter averages out.
    rms_sigma_mm : (3,) mm
        Root mean square over the points of each point's own calibration sigma, per component.
    common_fraction : (3,)
        ``(sigma_mean / rms_sigma)^2``: the share of a point's calibration variance that is common to all points
        (1: the calibration error of this field is a uniform offset; 0: it averages out over the points).
    sigma_scale : float, dimensionless
        Predicted standard deviation of a scale factor of the field. Position: ``s`` with
        ``dX_i - mean(dX) ~= s (X_i - mean(X))`` (least squares over the points), the uniform strain a
        calibration error makes the whole surface show. Displacement: ``s`` with ``dU_i ~= s U_i`` (a relative
        error of every displacement alike); NaN where U is zero at every point.
    """

    field: str
    n_points: int
    sigma_mean_mm: np.ndarray
    rms_sigma_mm: np.ndarray
    common_fraction: np.ndarray
    sigma_scale: float


def common_mode_summary(rig, ref_left_px, ref_right_px, def_left_px=None, def_right_px=None) -> CommonModeSummary:
    """The part of the calibration error shared by all points of a field: offset of the mean and a scale factor.

    Parameters
    ----------
    rig : CalibratedRig or StereoCalibration with a covariance (see :func:`calibration_covariance_mm2`)
    ref_left_px, ref_right_px : array, shape (N, 2), px
        The points' pixel pairs (the reference state).
    def_left_px, def_right_px : array, shape (N, 2), px, optional
        The same points in a deformed state: the field is then the displacement ``U = X_def - X_ref``;
        without them it is the position ``X`` of the reference state.

    Returns
    -------
    CommonModeSummary
        NaN figures when the rig has no covariance (with the warning) or no point triangulates.
    """
    displacement = def_left_px is not None or def_right_px is not None
    if displacement and (def_left_px is None or def_right_px is None):
        raise ValueError("give both def_left_px and def_right_px, or neither")
    pl, pr = _pixels("ref_left_px", ref_left_px), _pixels("ref_right_px", ref_right_px)
    field = "displacement" if displacement else "position"
    cov, names = _covariance(rig)
    nan3 = np.full(3, np.nan)
    if cov is None:
        return CommonModeSummary(field, 0, nan3, nan3, nan3, float("nan"))
    left, right, R, T = _parts(rig)
    G = calibration_sensitivity(rig, pl, pr, names)
    X = triangulate(left, right, R, T, pl, pr, refine=True, xtol_mm=_XTOL_MM, max_iter=_MAX_ITER).X_left_mm
    if displacement:
        dl, dr = _pixels("def_left_px", def_left_px), _pixels("def_right_px", def_right_px)
        if not len(dl) == len(dr) == len(pl):
            raise ValueError("the reference and deformed pixel arrays must have the same length")
        G = calibration_sensitivity(rig, dl, dr, names) - G
        X = triangulate(left, right, R, T, dl, dr, refine=True, xtol_mm=_XTOL_MM, max_iter=_MAX_ITER).X_left_mm - X
    ok = np.all(np.isfinite(G), axis=(1, 2)) & np.all(np.isfinite(X), axis=1)
    if not ok.any():
        return CommonModeSummary(field, 0, nan3, nan3, nan3, float("nan"))
    G, X = G[ok], X[ok]
    G_mean = G.mean(axis=0)                                            # (3, k)
    sigma_mean = np.sqrt(np.clip(np.diag(G_mean @ cov @ G_mean.T), 0, None))
    per_point_var = np.clip(np.diagonal(_propagate(G, cov), axis1=1, axis2=2), 0, None)   # (n, 3)
    rms_sigma = np.sqrt(per_point_var.mean(axis=0))
    with np.errstate(divide="ignore", invalid="ignore"):
        common = np.where(rms_sigma > 0, (sigma_mean / rms_sigma) ** 2, np.nan)
    # The scale factor is linear in d theta: s = g_s . d theta, so var(s) = g_s C g_s.
    if displacement:
        ref, G_s = X, G                                                # dU_i ~= s U_i
    else:
        ref, G_s = X - X.mean(axis=0), G - G_mean                      # about the centroid
    norm2 = float(np.sum(ref * ref))
    if norm2 > 0:
        g_s = np.einsum("ni,nik->k", ref, G_s) / norm2
        sigma_scale = float(np.sqrt(max(g_s @ cov @ g_s, 0.0)))
    else:
        sigma_scale = float("nan")
    return CommonModeSummary(field, int(ok.sum()), sigma_mean, rms_sigma, common, sigma_scale)


def rig_covariance(rig) -> tuple[np.ndarray | None, tuple[str, ...]]:
    """The rig's (k, k) calibration covariance and its parameter names, or ``(None, ())`` -- with the warning,
    once per process -- when it has none (the calibration part is then unknown, never zero)."""
    return _covariance(rig)
