"""Which camera model do the calibration data support? Tilt and optional lens terms judged, the simplest kept.

A richer model always fits the calibration corners at least as well (the models are nested: alpha = beta = 0 is the
pinhole, k3 = 0 is ``brown4``...), and on real corners, whose errors are not white noise (blur, JPEG, print), the
usual statistics overstate what an extra term is worth: on OpenCV's 640 x 480 stereo sample the RMM tilt is 2.6-5
sigma "significant" and lowers the RMS by 0.004 px while moving the principal point by 8-22 px and the stereo angle
by 3 deg (a tilt with a principal-point shift is nearly a rotation of the camera frame). Two tests, reported side by
side:

1. **parameter / sigma** of every optional term of a fit (:func:`term_significance`): ``z = |value| / sigma`` with
   the calibration's own sigmas; ``z < 3`` means the data do not determine the term.
2. **held-out views** (:func:`cross_validate`): the views are split into ``folds`` interleaved groups; each group is
   left out in turn, the camera calibrated on the others, and each left-out view's corners predicted with only its
   own six pose parameters fitted. The error of a term that describes the lens falls on unseen views too; the error
   of a term that fits the calibration set's peculiarities does not.

:func:`select_model` fits every candidate (model x lens) on all views and cross-validates each, then keeps the
*simplest* candidate whose held-out mean squared error is within one standard error of the best one's (the
"one-standard-error rule", Hastie, Tibshirani & Friedman, *The Elements of Statistical Learning*, 2nd ed., §7.10;
the standard error is that of the per-view difference to the best candidate). The Bayesian information criterion
of each full fit is given beside it (``n ln(SSR / n) + k ln n`` over all residuals), for information.
"""
from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np

from measurement.calibration.stepwise import (LENS_TERMS, CalibrationError, CameraCalibration, StereoCalibration,
                                              free_intrinsics, refine_camera, calibrate_camera, calibrate_stereo,
                                              canonical_lens, project_views)
from measurement.calibration.zhang import homography, pose_from_homography

#: |value| / sigma below which a term counts as not determined by the data (the usual 3-sigma rule).
Z_THRESHOLD = 3.0
#: Candidates of :func:`select_model` by default: (camera model, lens), simplest first.
DEFAULT_CANDIDATES = (("pinhole", "brown4"), ("pinhole", "brown5"), ("rmm", "brown4"), ("rmm", "brown5"),
                      ("pinhole", "full"), ("rmm", "full"))
#: Most folds of the held-out test (fewer when there are fewer views).
DEFAULT_FOLDS = 8


def optional_terms(model: str, lens: str) -> tuple[str, ...]:
    """The terms of ``model`` and ``lens`` beyond the pinhole camera with k1 k2 p1 p2: the tilt angles (for a tilt
    model) and :data:`~measurement.calibration.stepwise.LENS_TERMS`."""
    tilt = () if model == "pinhole" else ("alpha_deg", "beta_deg")
    return tilt + LENS_TERMS[canonical_lens(lens)]


def n_intrinsics(model: str, lens: str) -> int:
    """How many intrinsics ``model`` and ``lens`` estimate per camera."""
    return len(free_intrinsics(model, canonical_lens(lens)))


def _camera_terms(c: CameraCalibration, model: str) -> dict:
    rows = {}
    for term in optional_terms(model, c.lens):
        value, sigma = float(getattr(c.camera, term)), float(c.sigma.get(term, np.nan))
        rows[term] = {"value": value, "sigma": sigma, "z": abs(value) / sigma if sigma > 0 else float("nan")}
    return rows


def term_significance(cal: StereoCalibration | CameraCalibration, model: str | None = None) -> dict:
    """``{side: {term: {"value", "sigma", "z"}}}`` for every optional term of ``cal``'s model and lens; a single
    camera's calibration (give its ``model``) has the one side ``"camera"``."""
    if isinstance(cal, CameraCalibration):
        if model is None:
            raise ValueError("a single camera's calibration does not record its model: give model=")
        return {"camera": _camera_terms(cal, model)}
    return {side: _camera_terms(getattr(cal, side), cal.model) for side in ("left", "right")}


def significance_lines(cal: StereoCalibration | CameraCalibration, z_threshold: float = Z_THRESHOLD,
                       model: str | None = None) -> tuple[list[str], list[str]]:
    """(report lines, warnings) for :func:`term_significance` of ``cal``: one line per camera; a warning per camera
    whose tilt or optional lens terms the data do not determine (z < ``z_threshold``)."""
    sig = term_significance(cal, model)
    lines, warns = [], []
    for side, rows in sig.items():
        if not rows:
            continue
        parts = [f"{t} = {r['value']:.4g} ± {r['sigma']:.2g} ({r['z']:.1f} σ)" for t, r in rows.items()]
        lines.append(f"  {side}: " + "; ".join(parts))
        weak = [t for t, r in rows.items() if not r["z"] >= z_threshold]
        if weak:
            warns.append(f"{side}{'' if side == 'camera' else ' camera'}: {', '.join(weak)} below {z_threshold:g} σ: "
                         f"the data do not determine {'them' if len(weak) > 1 else 'it'}; a simpler model "
                         f"(--model pinhole, --lens k1k2p1p2) or --model auto may describe this camera as well")
    return lines, warns


# --------------------------------------------------------------------------------------------------------------
def _pose_for_view(camera, board_mm, points) -> tuple[np.ndarray, np.ndarray]:
    """Initial pose of one view with known intrinsics: homography of the board to the undistorted rays."""
    found = np.all(np.isfinite(points), axis=-1)
    xy = camera.backproject(points[found])
    ok = np.all(np.isfinite(xy), axis=1)
    H = homography(board_mm[found][ok, :2], xy[ok])
    return pose_from_homography(H, np.eye(3))


def held_out_errors(train: CameraCalibration, board_mm: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Squared reprojection errors of views the calibration did not see: per view, only its pose is fitted.

    Parameters
    ----------
    train : the calibration (its camera is used, fixed)
    board_mm : (N, 3) board points, mm
    points : (W, N, 2) the held-out views' points, px (NaN rows for missing points)

    Returns
    -------
    (W, 2) array: per view, the sum of squared residuals (px^2) and the number of points found.
    """
    out = np.zeros((len(points), 2))
    for w, p in enumerate(points):
        rvec, tvec = _pose_for_view(train.camera, board_mm, p)
        cam, rv, tv, _ = refine_camera(train.camera, (), rvec[None], tvec[None], board_mm, p[None], "schur-lm")
        r = project_views(cam, rv, tv, board_mm)[0] - p
        found = np.all(np.isfinite(p), axis=-1)
        out[w] = float(np.sum(r[found] ** 2)), float(found.sum())
    return out


def cross_validate(points: np.ndarray, board_mm: np.ndarray, image_size, *, model: str, lens: str,
                   folds: int = DEFAULT_FOLDS, tilt_guess_deg=(0.0, 0.0), name: str = "camera") -> np.ndarray:
    """Held-out errors of every view of one camera, each from a calibration on the other folds.

    Views ``f, f + folds, f + 2 folds...`` form fold ``f`` (interleaved, so that every fold spans the poses).

    Returns
    -------
    (V, 2) array: per view, the sum of squared held-out residuals (px^2) and the number of its points.
    """
    points = np.asarray(points, float)
    V = len(points)
    folds = int(min(folds, V))
    if V - int(np.ceil(V / folds)) < 3 or folds < 2:
        raise CalibrationError(f"{name}: {V} views are too few for a held-out test (each calibration needs 3 views "
                               f"besides the ones left out)")
    out = np.zeros((V, 2))
    for f in range(folds):
        test = np.arange(f, V, folds)
        train = np.setdiff1d(np.arange(V), test)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")          # a fold's fit may warn; the full fit reports for itself
            cal = calibrate_camera(points[train], board_mm, image_size, model=model, lens=lens,
                                   tilt_guess_deg=tilt_guess_deg, name=f"{name} (fold {f + 1} of {folds})")
        out[test] = held_out_errors(cal, board_mm, points[test])
    return out


@dataclass(frozen=True)
class CandidateScore:
    """One candidate of :func:`select_model`.

    Attributes
    ----------
    model, lens : the candidate
    n_intrinsics : intrinsics per camera
    rms_px : {"left", "right"}: reprojection RMS of the fit on all views
    held_out_rms_px : RMS of the held-out residuals over both cameras
    held_out_mse_px2 : mean over views of the per-view mean squared held-out residual (both cameras)
    se_px2 : standard error of the per-view difference of that to the best candidate's (0 for the best)
    bic : Bayesian information criterion of the full fit (both cameras; lower is better)
    significance : :func:`term_significance` of the full fit
    """

    model: str
    lens: str
    n_intrinsics: int
    rms_px: dict
    held_out_rms_px: float
    held_out_mse_px2: float
    se_px2: float
    bic: float
    significance: dict


@dataclass(frozen=True)
class ModelSelection:
    """Result of :func:`select_model`: the candidates (simplest first), the chosen one's fit, and why."""

    candidates: tuple[CandidateScore, ...]
    chosen: CandidateScore
    calibration: StereoCalibration
    reason: str
    folds: int

    def to_dict(self) -> dict:
        def row(c: CandidateScore) -> dict:
            return {"model": c.model, "lens": c.lens, "n_intrinsics": c.n_intrinsics, "rms_px": c.rms_px,
                    "held_out_rms_px": c.held_out_rms_px, "held_out_mse_px2": c.held_out_mse_px2,
                    "se_px2": c.se_px2, "bic": c.bic, "significance": c.significance}
        return {"rule": "simplest candidate within one standard error of the lowest held-out MSE", "folds": self.folds,
                "chosen": {"model": self.chosen.model, "lens": self.chosen.lens}, "reason": self.reason,
                "candidates": [row(c) for c in self.candidates]}

    def lines(self) -> list[str]:
        out = [f"  model selection ({self.folds}-fold held-out views; simplest within one standard error of the best):",
               "    model    lens    k/cam   RMS L / R px     held-out RMS px   held-out MSE ± SE px²    BIC"]
        for c in self.candidates:
            mark = "  <- chosen" if c is self.chosen else ""
            out.append(f"    {c.model:<8} {c.lens:<7} {c.n_intrinsics:>4}   {c.rms_px['left']:.4f} / "
                       f"{c.rms_px['right']:.4f}   {c.held_out_rms_px:>10.4f}        {c.held_out_mse_px2:.5f} ± "
                       f"{c.se_px2:.5f}   {c.bic:10.1f}{mark}")
        out.append(f"  chosen: {self.chosen.model} / {self.chosen.lens}: {self.reason}")
        return out


def one_standard_error_choice(candidates, errors: dict):
    """The simplest of ``candidates`` (ordered simplest first) whose held-out MSE is within one standard error of
    the lowest; ``errors[c]``: (V, 2) per-view squared-residual sums and point counts (:func:`cross_validate`).

    Returns ``(chosen, best, mse, se)``: ``mse[c]`` the mean over views of each view's mean squared error (px^2),
    ``se[c]`` the standard error of the per-view difference to ``best`` (0 for ``best`` itself)."""
    per_view = {c: errors[c][:, 0] / np.maximum(errors[c][:, 1], 1) for c in candidates}
    mse = {c: float(np.mean(v)) for c, v in per_view.items()}
    best = min(candidates, key=lambda c: mse[c])
    n = len(per_view[best])
    se = {c: float(np.std(per_view[c] - per_view[best], ddof=1) / np.sqrt(n)) if c != best else 0.0
          for c in candidates}
    chosen = next(c for c in candidates if mse[c] - mse[best] <= se[c])
    return chosen, best, mse, se


def select_camera_model(points: np.ndarray, board_mm: np.ndarray, image_size, *, candidates=DEFAULT_CANDIDATES,
                        folds: int = DEFAULT_FOLDS, tilt_guess_deg=(0.0, 0.0)) -> tuple[tuple[str, str], list[dict]]:
    """:func:`select_model` for one camera (its own views only): ``((model, lens), rows)``, a row per candidate
    (simplest first) with ``model``, ``lens``, ``n_intrinsics``, ``held_out_mse_px2``, ``se_px2``, ``chosen``."""
    cands = sorted(((m, canonical_lens(ln)) for m, ln in candidates), key=lambda c: n_intrinsics(*c))
    errors = {c: cross_validate(points, board_mm, image_size, model=c[0], lens=c[1], folds=folds,
                                tilt_guess_deg=tilt_guess_deg) for c in cands}
    chosen, _, mse, se = one_standard_error_choice(cands, errors)
    rows = [{"model": c[0], "lens": c[1], "n_intrinsics": n_intrinsics(*c), "held_out_mse_px2": mse[c],
             "se_px2": se[c], "chosen": c == chosen} for c in cands]
    return chosen, rows


def _bic(cal: StereoCalibration, n_points: dict) -> float:
    n = 2 * (n_points["left"] + n_points["right"])
    ssr = sum(cal.rms_px[s] ** 2 * n_points[s] for s in ("left", "right"))
    k = 2 * n_intrinsics(cal.model, cal.lens) + 6 + 6 * len(cal.left.rvecs)
    return float(n * np.log(ssr / n) + k * np.log(n))


def select_model(points_left: np.ndarray, points_right: np.ndarray, board_mm: np.ndarray, image_size, *,
                 candidates=DEFAULT_CANDIDATES, folds: int = DEFAULT_FOLDS, tilt_guess_left_deg=(0.0, 0.0),
                 tilt_guess_right_deg=(0.0, 0.0), joint: bool = True, progress=None) -> ModelSelection:
    """Calibrate the pair with every candidate and keep the simplest that the held-out views support.

    Parameters
    ----------
    points_left, points_right : (V, N, 2) corners, px (NaN rows for missing points)
    board_mm : (N, 3)
    image_size : (width, height) px
    candidates : (model, lens) pairs; sorted here by the number of intrinsics (stable)
    folds : most folds of the held-out test
    progress : optional callable(str) told what is being fitted

    Returns
    -------
    :class:`ModelSelection`; its ``calibration`` is the chosen candidate's fit on all views.
    """
    cands = sorted(((m, canonical_lens(ln)) for m, ln in candidates), key=lambda c: n_intrinsics(*c))
    if not cands:
        raise ValueError("select_model needs at least one candidate")
    points_left, points_right = np.asarray(points_left, float), np.asarray(points_right, float)
    n_points = {s: int(np.all(np.isfinite(p), -1).sum()) for s, p in (("left", points_left), ("right", points_right))}
    V = len(points_left)
    fits, errors = {}, {}
    for i, (model, lens) in enumerate(cands):
        if progress:
            progress(f"candidate {i + 1} of {len(cands)}: {model} / {lens}")
        fits[model, lens] = calibrate_stereo(points_left, points_right, board_mm, image_size, model=model, lens=lens,
                                             tilt_guess_left_deg=tilt_guess_left_deg,
                                             tilt_guess_right_deg=tilt_guess_right_deg, joint=joint)
        e = np.zeros((V, 2))
        for side, pts, guess in (("left", points_left, tilt_guess_left_deg),
                                 ("right", points_right, tilt_guess_right_deg)):
            e += cross_validate(pts, board_mm, image_size, model=model, lens=lens, folds=folds,
                                tilt_guess_deg=guess, name=f"{side} camera")
        errors[model, lens] = e
    chosen, best, mse, se = one_standard_error_choice(cands, errors)
    scores = {}
    for c in cands:
        e = errors[c]
        scores[c] = CandidateScore(c[0], c[1], n_intrinsics(*c), dict(fits[c].rms_px),
                                   float(np.sqrt(e[:, 0].sum() / e[:, 1].sum())), mse[c], se[c],
                                   _bic(fits[c], n_points), term_significance(fits[c]))
    if chosen == best:
        reason = f"the lowest held-out error ({mse[best]:.5f} px²)"
    else:
        reason = (f"held-out error {mse[chosen]:.5f} px², within one standard error ({se[chosen]:.5f} px²) of the "
                  f"lowest ({best[0]} / {best[1]}: {mse[best]:.5f} px²) with fewer terms")
    folds_used = int(min(folds, V))
    return ModelSelection(tuple(scores[c] for c in cands), scores[chosen], fits[chosen], reason, folds_used)
