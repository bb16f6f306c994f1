"""What a candidate rig will measure, before it is built: per-point noise of U, V, W and strain over the ROI.

Per ROI sample point and per camera (each point at the reference and at both ends of the depth travel):

* **where it is imaged** and how the face maps to the image there (the 2 x 2 Jacobian ``A`` = d pixel / d mm along
  the face's x and y tangents, by central differences of the renderer's projection): the local image scale, the
  speckle's diameter in px (``d sqrt(det A)``) and the foreshortening (``A / sqrt(det A)``);
* **blur**: the thin lens' defocus circle (:func:`scenes.optics.projection.defocus_blur_px`, a uniform disc of diameter ``c``)
  and diffraction (Airy ~ Gaussian sigma ``0.42 lambda N``), both tabulated (:mod:`~workbench.design.pattern`);
* **light**: the image irradiance goes as ``1 / (N (1 + m))^2`` (m: magnification at the face centre); the
  lighting states the mean grey at one f-number; the exposure is cut where the brightest paint would pass
  ``lighting.max_fraction`` of full scale. Noise ``sigma^2 = read^2 + I / gain + 1/12`` (read and shot noise of the
  camera's data sheet, quantisation) at the paint's mean grey ``I``;
* **the match**: the instrument's covariance of (u, v) for that speckle and blur (:mod:`workbench.design.pattern`:
  the instrument's :func:`~measurement.uncertainty.match.reference_subsets` on the paint), scaled by noise and
  exposure and turned by the foreshortening; the right image's part of the stereo match as the instrument's
  cross-Hessian gives it (:func:`_stereo_target_part`: the right camera's own scale and blur against the left
  reference's), with the interpolant's noise gain;
* **stereo**: the instrument's triangulation sensitivity (:func:`~measurement.uncertainty.stereo.
  triangulation_sensitivity`, both cameras) and its static-repeat covariance (:func:`~measurement.uncertainty.
  stereo.static_repeat_covariance_mm2`): the noise floor of a static pair, what a twin predicts for a built rig.
  U, V, W are stated in the **specimen frame** (along the face's x, y and its normal);
* **strain**: the windowed least-squares slope of U (V) over ``window x window`` grid points ``step`` px apart,
  neighbouring points correlated by their subsets' overlap (``(1 - |dx|/S)(1 - |dy|/S)``): the strain window's
  noise, for the instrument's default strain (a plane fit per window).

The point's figures are the worst over the depth travel; a candidate's summary is their RMS over the ROI, the
fraction of (point, depth) samples in focus in both cameras (blur circle <= ``search.in_focus_blur_px``), the mean
MIG, the spatial resolution (the subset's footprint, mm) and the virtual strain gauge.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from measurement.uncertainty.stereo import sigmas, static_repeat_covariance_mm2, triangulation_sensitivity
from scenes.optics.projection import defocus_blur_px, project_points

from .geometry import SIDES, CandidateRig
from .pattern import AIRY_SIGMA, E0_GREY, PatternTable

#: Finite-difference step along the face for the image Jacobian, mm.
JACOBIAN_STEP_MM = 0.05


class OutOfViewError(ValueError):
    """A ROI point is not imaged inside a camera (with a subset's margin); the message says which and where."""


@dataclass
class Prediction:
    """A candidate's predicted measurement (module notes).

    Per point (N, the surface's samples): ``sigma_U_um`` (N, 3) in the specimen frame (U, V, W; worst over the
    depth travel), ``sigma_strain_ue`` (N, 2) (exx, eyy), ``blur_px`` (N, 2) (left, right; defocus circle diameter,
    worst over the depth travel), ``speckle_px`` (N,) (left camera), ``footprint_mm`` (N,) (mm per px, left).
    Summary in ``summary``.
    """

    candidate: CandidateRig
    sigma_U_um: np.ndarray = field(repr=False)
    sigma_strain_ue: np.ndarray = field(repr=False)
    blur_px: np.ndarray = field(repr=False)
    speckle_px: np.ndarray = field(repr=False)
    footprint_mm: np.ndarray = field(repr=False)
    pixels_left: np.ndarray = field(repr=False)
    summary: dict = field(default_factory=dict)


def _rms(a) -> float:
    a = np.asarray(a, float)
    a = a[np.isfinite(a)]
    return float(np.sqrt(np.mean(a ** 2))) if a.size else math.nan


def exposure_grey(camera, lighting, f_number: float, magnification: float, contrast: float) -> tuple[float, bool]:
    """Grey of paint value 1 (the paint's mean is ~half of it) and whether the light was cut to avoid saturation."""
    fs = camera.full_scale_grey
    E = 2.0 * lighting.mean_fraction * fs * (lighting.f_number / f_number) ** 2 / (1.0 + magnification) ** 2
    brightest = 0.5 + 0.5 * contrast
    cap = lighting.max_fraction * fs / brightest
    return (min(E, cap), E > cap)


def noise_variance_grey2(camera, grey: float) -> float:
    """Read, shot and quantisation noise variance at a grey level (grey^2)."""
    return camera.read_noise_grey ** 2 + max(grey, 0.0) / camera.electrons_per_grey + 1.0 / 12.0


def _jacobian(spec, R, t, X, tx, ty) -> np.ndarray:
    """d pixel / d mm along the tangents, (N, 2, 2), columns along tx and ty."""
    h = JACOBIAN_STEP_MM
    cols = []
    for d in (tx, ty):
        cols.append((project_points(spec, R, t, X + h * d) - project_points(spec, R, t, X - h * d)) / (2 * h))
    return np.stack(cols, axis=2)


def _stereo_target_part(table, candidate, poses, X, tx, ty, d_mm, det_left, blur, diffr, unit_var) -> np.ndarray:
    """The right image's part of the stereo match's (u, v) covariance, right px^2 (N, 2, 2): what the instrument's
    cross-Hessian (:func:`measurement.uncertainty.match.cross_hessians`) gives a left reference matched to a right
    image of another scale and blur.

    In the right image's own frame the right camera's table value ``T(s_R, c_R)`` would hold for a reference that
    repeats its view; the left reference covers ``1 / |det A_LR|`` of the right pixels a right subset would
    (``A_LR``: d right px / d left px, the target's pixel density) and has the left camera's blur ``c_L'`` (in right
    px), which the cross-Hessian weighs by ``H(c_L') H(c_R) / H_x^2`` (``H = 1 / T`` the gradient energy, ``H_x`` the
    cross term): exact for Gaussian blurs, whose cross term is the energy at the RMS blur
    ``sqrt((c_L'^2 + c_R^2) / 2)``, taken so for the discs here. So ``C_R = kappa T(c_m)^2 / T(c_L') / |det A_LR|``
    turned by the right camera's foreshortening."""
    A = _jacobian(candidate.specs["right"], *poses["right"], X, tx, ty)
    det = np.abs(np.linalg.det(A))
    density = det_left / det                       # 1 / |det A_LR|
    c_left = blur[:, 0] * np.sqrt(det / det_left)  # the left blur circle in right px
    c_mean = np.sqrt(0.5 * (c_left ** 2 + blur[:, 1] ** 2))
    kappa = table.noise_gain(d_mm * np.sqrt(det), blur[:, 1], diffr)
    return unit_var * (kappa * density)[:, None, None] * _principal_covariance(
        table, A, d_mm, lambda s: table.covariance(s, c_mean, diffr) ** 2 / table.covariance(s, c_left, diffr))


def _principal_covariance(table, A, d_mm, value) -> np.ndarray:
    """A foreshortened speckle's (u, v) covariance per unit noise, (N, 2, 2): along each principal direction of the
    face-to-image Jacobian ``A`` (N, 2, 2) the table's value at that direction's speckle size ``d sigma_i(A)`` (the
    image's isotropic blur and pixels take more from the direction the view compresses)."""
    U, S, _ = np.linalg.svd(A)
    D = np.zeros(A.shape)
    D[:, 0, 0] = value(d_mm * S[:, 0])
    D[:, 1, 1] = value(d_mm * S[:, 1])
    return U @ D @ np.swapaxes(U, 1, 2)


def window_slope_factor(window: int, step_px: int, subset_px: int) -> float:
    """Noise of a windowed least-squares slope per unit point noise and unit spacing: ``sqrt(w^T C w)`` with ``w``
    the plane fit's slope weights over ``window x window`` points ``step_px`` apart and ``C`` their correlation
    through the subsets' overlap (module notes)."""
    k = np.arange(window) - (window - 1) / 2
    gx, gy = (v.ravel() for v in np.meshgrid(k, k))
    M = np.column_stack([np.ones_like(gx), gx, gy])
    w = np.linalg.solve(M.T @ M, M.T)[1]            # slope along x per unit spacing
    dx = np.abs(gx[:, None] - gx[None, :]) * step_px / subset_px
    dy = np.abs(gy[:, None] - gy[None, :]) * step_px / subset_px
    C = np.clip(1 - dx, 0, None) * np.clip(1 - dy, 0, None)
    return float(np.sqrt(w @ C @ w))


def predict(candidate: CandidateRig, surface, camera, lighting, search, table: PatternTable, *,
            speckle_mm: float | None = None, speckle_px_at_centre: float = 4.0, depth_range_mm: float = 0.0,
            contrast: float = 0.8) -> Prediction:
    """The candidate's predicted static noise over the ROI (module notes).

    Raises
    ------
    OutOfViewError
        A ROI point (at some depth of the travel) falls outside a camera's image less a half subset.
    """
    rig = candidate.rig
    Rws, tws = candidate.R_world_from_spec, candidate.t_world_from_spec_mm
    poses = {side: rig.pose(side) for side in SIDES}
    tx_s, ty_s = surface.tangents()
    tx, ty = tx_s @ Rws.T, ty_s @ Rws.T
    half = search.subset_px // 2
    N = len(surface.points_mm)
    F = rig.lens_focal_length_mm[0]
    f_number = rig.f_number
    # magnification at the face centre (left camera): m = v / u
    u0 = float(np.linalg.norm(tws))
    m = F / max(u0 - F, 1e-9)
    E, light_cut = exposure_grey(camera, lighting, f_number, m, contrast)
    mean_grey = 0.5 * E
    var = noise_variance_grey2(camera, mean_grey)
    diffraction_px = AIRY_SIGMA * search.wavelength_nm * 1e-6 * f_number / camera.pixel_pitch_mm

    # the speckle: the design's, or the candidate's own (speckle_px at the face centre in the left camera)
    centre_w = (np.zeros(3) @ Rws.T + tws)[None]
    A0 = _jacobian(candidate.specs["left"], *poses["left"], centre_w, (np.array([1.0, 0, 0]) @ Rws.T)[None],
                   (np.array([0, 1.0, 0]) @ Rws.T)[None])[0]
    scale0 = math.sqrt(abs(np.linalg.det(A0)))            # px per mm at the centre
    d_mm = float(speckle_mm) if speckle_mm is not None else speckle_px_at_centre / scale0

    sig = np.full((N, 3), -np.inf)
    blur_worst = np.zeros((N, 2))
    in_focus = []
    mig = []
    pixels_left = None
    speckle_left = footprint = None
    for offset, P in surface.depth_samples(depth_range_mm):
        X = P @ Rws.T + tws
        pix = {}
        for side in SIDES:
            spec = candidate.specs[side]
            p = project_points(spec, *poses[side], X)
            inside = (np.all(np.isfinite(p), axis=1) & (p[:, 0] >= half) & (p[:, 0] <= spec.width - 1 - half)
                      & (p[:, 1] >= half) & (p[:, 1] <= spec.height - 1 - half))
            if not inside.all():
                k = int(np.flatnonzero(~inside)[0])
                raise OutOfViewError(f"the {side} camera does not see ROI point {P[k].round(2).tolist()} mm (depth "
                                     f"offset {offset:+g} mm) inside its image with a half subset's margin "
                                     f"({int((~inside).sum())} of {N} points outside)")
            pix[side] = p
        blur = np.stack([defocus_blur_px(candidate.specs[s], *poses[s], X) for s in SIDES], axis=1)
        blur_worst = np.maximum(blur_worst, blur)
        in_focus.append(np.all(blur <= search.in_focus_blur_px, axis=1))
        diffr = np.full(len(X), diffraction_px)
        A = _jacobian(candidate.specs["left"], *poses["left"], X, tx, ty)
        det = np.abs(np.linalg.det(A))
        s_px = d_mm * np.sqrt(det)
        # px^2 per grey^2 at E0, along the view's principal directions
        C_L = var * (E0_GREY / E) ** 2 * _principal_covariance(
            table, A, d_mm, lambda s: table.covariance(s, blur[:, 0], diffr))
        C_R = _stereo_target_part(table, candidate, poses, X, tx, ty, d_mm, det, blur, diffr, var * (E0_GREY / E) ** 2)
        G = triangulation_sensitivity(rig.left, rig.right, rig.R_right_from_left, rig.T_right_from_left_mm, X)
        cov = static_repeat_covariance_mm2(G, C_L, C_R)
        cov_spec = Rws.T @ cov @ Rws
        s = 1e3 * sigmas(cov_spec)
        sig = np.maximum(sig, s)
        if offset == 0.0:
            pixels_left = pix["left"]
            speckle_left = s_px
            footprint = 1.0 / np.sqrt(det)
            mig.append(table.mig(s_px, blur[:, 0], diffr) * E)
    slope = window_slope_factor(search.strain_window, search.step_px, search.subset_px)
    spacing_mm = search.step_px * footprint
    strain = 1e6 * 1e-3 * sig[:, :2] * slope / spacing_mm[:, None]      # um / mm -> strain
    focus_fraction = float(np.mean(np.concatenate(in_focus)))
    summary = {
        "sigma_U_um": _rms(sig[:, 0]), "sigma_V_um": _rms(sig[:, 1]), "sigma_W_um": _rms(sig[:, 2]),
        "sigma_inplane_um": _rms(np.sqrt(0.5 * (sig[:, 0] ** 2 + sig[:, 1] ** 2))),
        "sigma_exx_ue": _rms(strain[:, 0]), "sigma_eyy_ue": _rms(strain[:, 1]),
        "max_sigma_W_um": float(np.nanmax(sig[:, 2])),
        "in_focus_fraction": focus_fraction,
        "max_blur_px": float(blur_worst.max()),
        "diffraction_sigma_px": float(diffraction_px),
        "mig_grey_per_px": float(np.mean(np.concatenate(mig))),
        "mean_grey": float(mean_grey), "noise_grey": float(math.sqrt(var)), "light_cut": bool(light_cut),
        "magnification": float(m),
        "speckle_mm": d_mm, "speckle_px": [float(np.min(speckle_left)), float(np.max(speckle_left))],
        "footprint_mm_per_px": float(np.mean(footprint)),
        "subset_mm": float(search.subset_px * np.mean(footprint)),
        "vsg_mm": float(((search.strain_window - 1) * search.step_px + search.subset_px) * np.mean(footprint)),
        "table_extrapolated_fraction": float(np.mean(table.out_of_range(speckle_left, blur_worst[:, 0],
                                                                         np.full(N, diffraction_px)))),
    }
    return Prediction(candidate, sig, strain, blur_worst, speckle_left, footprint, pixels_left, summary)


def objective(summary: dict, quantity: str, component: str) -> float:
    """The figure a design is ranked by (smaller is better)."""
    if quantity == "displacement":
        return summary["sigma_W_um"] if component == "out-of-plane" else summary["sigma_inplane_um"]
    if component == "out-of-plane":
        raise ValueError("out-of-plane strain is not measured on a surface: choose component = 'in-plane'")
    return math.sqrt(0.5 * (summary["sigma_exx_ue"] ** 2 + summary["sigma_eyy_ue"] ** 2))
