"""Tests for the calibration (systematic) term of the per-point uncertainty: the covariance a stereo calibration
stores (:mod:`measurement.calibration.stepwise`, :mod:`measurement.calibration.io`) and its propagation to points
and displacements (:mod:`measurement.uncertainty.calibration`).

The reference of the propagated covariance is a Monte Carlo over calibrations: the paper's rig (Table 1,
``paper_rig(1.0)``) sees the 11 x 8-corner, 5 mm board in 12 poses; each calibration gets its own Gaussian corner
noise; the same TRUE pixel pairs (projections of a 5 x 5 grid on the specimen plane at the working distance, and
of the grid moved 1 mm along the plane's normal) are triangulated with every calibration; the spread of the
results about the truth is compared with the predicted sigma (median over the calibrations).

Regime. Linear propagation holds where the calibration's estimate is linear in the corner noise. On this rig
(narrow field: fx ~ 10 900 px; tilt and principal point correlated to |r| ~ 0.9999) that needs small noise.
Observed / predicted sigma of (X, Y, Z), measured with 12 views (the displacement's ratios are the same within
0.02, but 1.63 for its Z at 0.05 px):

    corner noise 0.005 px, 150 calibrations:   0.99  1.03  0.99
    corner noise 0.02 px,   60 calibrations:   1.06  1.28  1.05
    corner noise 0.05 px,   60 calibrations:   1.51  2.16  1.79

At 0.05 px the estimate is no longer linear in the noise (its point errors correlate only 0.2-0.8 with the linearised
estimate's for the same noise; 0.999 at 0.005 px), and the covariance evaluated at the estimate varies by tens of
per cent between calibrations: the propagated sigma then under-states the calibration error. The tests run at
0.005 px. A standard deviation from n calibrations scatters by ~1 / sqrt(2 n) (13 % for the 30 of the CI-scale
test, which measures 1.01 1.10 1.00; 6 % for the 150 of the ``slow`` one).

The parametric bootstrap (:mod:`measurement.calibration.bootstrap`: recalibrations of synthetic corners at the fit's
own residual noise) gives, as observed / median predicted over 5 calibrations of 40 draws against 40 calibrations
(X; the displacement's within 0.03 but Z at 0.05 px, 2.04):

    corner noise 0.005 px:   bootstrap 1.03  1.10  1.03     linear (median of 40) 1.04  1.12  1.03
    corner noise 0.02 px:    bootstrap 1.14  1.19  1.12     linear                1.06  1.17  1.06
    corner noise 0.05 px:    bootstrap 1.91  1.64  2.21     linear                1.66  1.46  2.04

so it does not repair 0.05 px: over 200 calibrations there, ~5 % lie 5-13 predicted sigma out along the
tilt/principal-point valley (2 of them a worse local minimum of the stepwise procedure, the rest global minima) and
carry the spread (without them 0.96 1.16 0.97 of the linear sigma; 200 calibrations against the median linear sigma
1.28 1.88 1.47; a 200-draw bootstrap of one calibration 1.48 2.10 1.55). The CI-scale test checks the bootstrap
against the linear covariance at 0.005 px; the ``slow`` one states the issue's goal at 0.05 px as an expected
failure.

Run with ``-s`` to see the measured ratios.
"""
import json
import time
import warnings
from dataclasses import replace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import measurement.uncertainty.calibration as calunc
from measurement.calibration.detection import board_points_mm
from measurement.calibration.io import (
    CalibratedRig,
    FileFormatError,
    load_calibration,
    rig_to_dict,
    save_calibration,
    save_rig,
)
from measurement.calibration.stepwise import STEREO_PARAMETER_NAMES, calibrate_stereo, free_intrinsics
from measurement.camera import INTRINSIC_NAMES
from measurement.stereo import projection_jacobian, triangulate
from measurement.uncertainty.calibration import (
    calibration_covariance_mm2,
    calibration_sensitivity,
    common_mode_summary,
    displacement_calibration_covariance_mm2,
)
from scenes.surfaces.checkerboard import Checkerboard
from workbench.experiments.calibration.views import board_outline_mm
from workbench.experiments.uncertainty.calibration import specimen_points, true_pixels
from workbench.poses import random_board_poses
from workbench.rigs import paper_rig

PATTERN = (11, 8)
BOARD_MM = board_points_mm(PATTERN, 5.0)
N_VIEWS = 12
SIGMA_PX = 0.005
N_CALIBRATIONS = 30
TILT_GUESS = {"left": (0.0, -4.0), "right": (0.0, 4.0)}
#: The issue's goal: predicted and observed calibration sigma within 20 % per component.
GOAL = 0.20
RIG = paper_rig(1.0)


# ------------------------------------------------------------------------------------------------------------
# Synthetic data
# ------------------------------------------------------------------------------------------------------------
def _board_pixels(rig, n_views, seed):
    """Exact projections of the board corners in ``n_views`` random poses, {side: (V, N, 2) px}."""
    poses = random_board_poses(rig, board_outline_mm(Checkerboard()), n_views, seed)
    X = np.array([BOARD_MM @ R.T + t for R, t in poses])
    out = {}
    for side in ("left", "right"):
        R, T = rig.pose(side)
        out[side] = rig.camera(side).project((X @ R.T + T).reshape(-1, 3)).reshape(n_views, len(BOARD_MM), 2)
    return out


def _specimen_points(rig):
    """A 5 x 5 grid (+-15 mm) on the plane the rig faces and that grid moved 1 mm along its normal (the calibration
    class's points, :func:`workbench.experiments.uncertainty.calibration.specimen_points`)."""
    return specimen_points(rig)


def _pixels(rig, X_left_mm):
    """True pixel pairs of left-frame points."""
    return true_pixels(rig, X_left_mm)


def _calibrate(board, sigma_px, seed):
    rng = np.random.default_rng(seed)
    noisy = {s: board[s] + rng.normal(0.0, sigma_px, board[s].shape) for s in ("left", "right")}
    # the paper's single start: on these board poses it reaches the least-squares minimum (the multi-start guard
    # keeps the same solution there, at 4 x the time); what the guard changes is the calibration class's test
    return calibrate_stereo(noisy["left"], noisy["right"], BOARD_MM, (RIG.left.width, RIG.left.height),
                            tilt_guess_left_deg=TILT_GUESS["left"], tilt_guess_right_deg=TILT_GUESS["right"],
                            multi_start=False)


def _monte_carlo(n_calibrations, sigma_px, first_seed=1000, pose_seed=3):
    """Observed errors and predicted sigmas over ``n_calibrations`` calibrations (module docstring)."""
    board = _board_pixels(RIG, N_VIEWS, pose_seed)
    X_ref, X_def = _specimen_points(RIG)
    (l0, r0), (l1, r1) = _pixels(RIG, X_ref), _pixels(RIG, X_def)
    out = {k: [] for k in ("err_X", "err_U", "pred_X", "pred_U", "summary_X", "summary_U", "cal")}
    t0 = time.perf_counter()
    for i in range(n_calibrations):
        cal = _calibrate(board, sigma_px, first_seed + i)
        args = (cal.left.camera, cal.right.camera, cal.R_right_from_left, cal.T_right_from_left_mm)
        Y0 = triangulate(*args, l0, r0).X_left_mm
        Y1 = triangulate(*args, l1, r1).X_left_mm
        out["err_X"].append(Y0 - X_ref)
        out["err_U"].append((Y1 - Y0) - (X_def - X_ref))
        out["pred_X"].append(np.sqrt(np.diagonal(calibration_covariance_mm2(cal, l0, r0), axis1=1, axis2=2)))
        out["pred_U"].append(np.sqrt(np.diagonal(displacement_calibration_covariance_mm2(cal, l0, r0, l1, r1),
                                                 axis1=1, axis2=2)))
        if i % 2 == 0:               # half the calibrations: the median of their predictions, half the time
            out["summary_X"].append(common_mode_summary(cal, l0, r0))
            out["summary_U"].append(common_mode_summary(cal, l0, r0, l1, r1))
        if i == 0:
            out["cal"].append(cal)
    out = {k: (np.array(v) if k.startswith(("err", "pred")) else v) for k, v in out.items()}
    out.update(X_ref=X_ref, X_def=X_def, pixels=(l0, r0, l1, r1),
               seconds_per_calibration=(time.perf_counter() - t0) / n_calibrations)
    return out


def _ratios(mc):
    """Observed / predicted sigma per component (RMS over the points of each): {"X": (3,), "U": (3,)}.

    Observed: the RMS of the errors about the truth over the calibrations (the mean error is zero to first
    order: the true rig triangulates the true pixels exactly); predicted: the median over the calibrations."""
    out = {}
    for f in ("X", "U"):
        observed = np.sqrt(np.mean(mc[f"err_{f}"] ** 2, axis=(0, 1)))
        predicted = np.sqrt(np.mean(np.median(mc[f"pred_{f}"], axis=0) ** 2, axis=0))
        out[f] = observed / predicted
        print(f"  {f}: observed {np.round(1e3 * observed, 3)} um, predicted {np.round(1e3 * predicted, 3)} um, "
              f"ratio {np.round(out[f], 3)}")
    return out


@pytest.fixture(scope="module")
def mc():
    result = _monte_carlo(N_CALIBRATIONS, SIGMA_PX)
    print(f"\n[{N_CALIBRATIONS} calibrations, {result['seconds_per_calibration']:.2f} s each]")
    return result


# ------------------------------------------------------------------------------------------------------------
# The propagated covariance against the Monte Carlo
# ------------------------------------------------------------------------------------------------------------
def test_predicted_calibration_sigma_matches_monte_carlo(mc):
    """Observed spread of X, Y, Z and of the 1 mm displacement within 20 % of the predicted calibration sigma."""
    print(f"\ncorner noise {SIGMA_PX} px, {N_VIEWS} views, {N_CALIBRATIONS} calibrations:")
    ratios = _ratios(mc)
    for f in ("X", "U"):
        for c, r in zip("xyz", ratios[f]):
            assert abs(r - 1.0) <= GOAL, f"{f}_{c}: observed / predicted = {r:.3f}"
    # The same calibration error moves both states, so most of it cancels in U: treating the two states as
    # independent (sqrt(2) x a point's sigma) would over-state U's calibration sigma more than 20-fold here.
    observed_U = np.sqrt(np.mean(mc["err_U"] ** 2, axis=(0, 1)))
    independent_states = np.sqrt(2.0) * np.sqrt(np.mean(np.median(mc["pred_X"], axis=0) ** 2, axis=0))
    assert np.all(independent_states > 20 * observed_U)


@pytest.mark.slow
def test_predicted_calibration_sigma_matches_monte_carlo_150_calibrations():
    """The same claims with 150 calibrations (sampling scatter of each ratio ~6 %, so 20 % is > 3 sigma), the
    common-mode summaries' too."""
    mc = _monte_carlo(150, SIGMA_PX)
    print(f"\n150 calibrations ({mc['seconds_per_calibration']:.2f} s each):")
    ratios = _ratios(mc)
    for f in ("X", "U"):
        assert np.all(np.abs(ratios[f] - 1.0) <= GOAL), (f, ratios[f])
    for f, (mean, scale) in _summary_ratios(mc).items():
        assert np.all(np.abs(mean - 1.0) <= GOAL) and abs(scale - 1.0) <= GOAL, (f, mean, scale)


def _summary_ratios(mc):
    """Observed / predicted of the common-mode summary: sigma of the field's mean (3,) and of its scale factor,
    {"X": (mean (3,), scale), "U": (...)}; observed with CommonModeSummary's definitions over the calibrations,
    predicted as the median of the summaries."""
    X_ref, X_def = mc["X_ref"], mc["X_def"]
    U = X_def - X_ref
    centred = X_ref - X_ref.mean(axis=0)
    scales = {"X": np.array([np.sum(centred * (e - e.mean(axis=0))) / np.sum(centred ** 2) for e in mc["err_X"]]),
              "U": np.array([np.sum(U * e) / np.sum(U * U) for e in mc["err_U"]])}
    out = {}
    for f in ("X", "U"):
        s = mc[f"summary_{f}"]
        assert all(x.field == ("position" if f == "X" else "displacement") for x in s)
        assert all(x.n_points == len(X_ref) for x in s)
        predicted_mean = np.median([x.sigma_mean_mm for x in s], axis=0)
        predicted_scale = np.median([x.sigma_scale for x in s])
        observed_mean = np.sqrt(np.mean(mc[f"err_{f}"].mean(axis=1) ** 2, axis=0))
        observed_scale = np.sqrt(np.mean(scales[f] ** 2))
        out[f] = (observed_mean / predicted_mean, observed_scale / predicted_scale)
        print(f"  {f}: sigma of the mean {np.round(1e3 * observed_mean, 3)} um observed, "
              f"{np.round(1e3 * predicted_mean, 3)} um predicted; scale {observed_scale:.3g} observed, "
              f"{predicted_scale:.3g} predicted; ratios {np.round(out[f][0], 3)}, {out[f][1]:.3f}")
    return out


#: Tolerance of the summaries in the CI-scale test: each is ONE figure from 30 calibrations (sampling scatter ~13 %,
#: and the median of 15 predictions ~3 %), so 20 % would be 1.5 sigma; 25 % is ~2 sigma. The 150-calibration
#: test holds them to 20 % (measured with 120: 1.00-1.06 for the means, 1.06 for both scales).
SUMMARY_TOLERANCE_CI = 0.25


def test_common_mode_summary_matches_monte_carlo(mc):
    """Predicted sigma of the field's mean and of its scale factor against their spread over the calibrations."""
    print()
    for f, (mean, scale) in _summary_ratios(mc).items():
        assert np.all(np.abs(mean - 1.0) <= SUMMARY_TOLERANCE_CI), (f, mean)
        assert abs(scale - 1.0) <= SUMMARY_TOLERANCE_CI, (f, scale)
        # the common part can be no more than the whole: sigma_mean^2 <= mean of the per-point variances
        for x in mc[f"summary_{f}"]:
            assert np.all(x.sigma_mean_mm <= x.rms_sigma_mm * (1 + 1e-12))
            np.testing.assert_allclose(x.common_fraction, (x.sigma_mean_mm / x.rms_sigma_mm) ** 2, rtol=1e-12)


def test_stored_covariance_is_consistent_with_the_sigmas(mc):
    """Names in the order of the parameter vector: the diagonal is the reported sigmas squared."""
    cal = mc["cal"][0]
    names = free_intrinsics(cal.model, cal.lens)
    assert cal.covariance_names == (tuple(f"left.{n}" for n in names) + tuple(f"right.{n}" for n in names)
                                    + STEREO_PARAMETER_NAMES)
    k = len(cal.covariance_names)
    assert cal.covariance.shape == (k, k)
    np.testing.assert_array_equal(cal.covariance, cal.covariance.T)
    assert np.all(np.linalg.eigvalsh(cal.covariance / np.sqrt(np.outer(np.diag(cal.covariance),
                                                                       np.diag(cal.covariance)))) > 0)
    sigma = ([cal.left.sigma[n] for n in names] + [cal.right.sigma[n] for n in names]
             + list(cal.sigma_stereo["rvec"]) + list(cal.sigma_stereo["T_mm"]))
    np.testing.assert_allclose(np.sqrt(np.diag(cal.covariance)), sigma, rtol=1e-12)


# ------------------------------------------------------------------------------------------------------------
# The sensitivity G against an independent derivative
# ------------------------------------------------------------------------------------------------------------
def _true_rig():
    return CalibratedRig("rmm", RIG.left, RIG.right, RIG.R_right_from_left, RIG.T_right_from_left_mm)


def _implicit_sensitivity(rig, X_left_mm, names):
    """dX/dtheta of the optimal triangulation by the implicit-function theorem, for pixels that reproject exactly
    (zero residual): ``dX = -(J^T J)^-1 J^T dr/dtheta``, J = d residual / dX (analytic projection Jacobians),
    dr/dtheta from finite differences of the PROJECTIONS alone (no triangulation), T analytically."""
    R, T = rig.R_right_from_left, rig.T_right_from_left_mm
    Xr = X_left_mm @ R.T + T
    Jr_cam = projection_jacobian(rig.right, Xr)
    J = np.concatenate([projection_jacobian(rig.left, X_left_mm), Jr_cam @ R], axis=1)     # (N, 4, 3)
    out = np.empty((len(X_left_mm), 3, len(names)))
    for j, name in enumerate(names):
        side, _, what = name.partition(".")
        dr = np.zeros((len(X_left_mm), 4))
        if side in ("left", "right"):
            cam = getattr(rig, side)
            X = X_left_mm if side == "left" else Xr
            # projections are linear in fx, cx..., nearly so in the rest: a large step keeps rounding far away
            h = 1e-4 * max(1.0, abs(getattr(cam, what)))
            plus = replace(cam, **{what: getattr(cam, what) + h}).project(X)
            minus = replace(cam, **{what: getattr(cam, what) - h}).project(X)
            dr[:, [0, 1] if side == "left" else [2, 3]] = (plus - minus) / (2 * h)
        elif what.startswith("T_"):
            dr[:, 2:] = Jr_cam[:, :, "xyz".index(what[2])]                                  # d X_right / d T = I
        else:
            axis = "xyz".index(what[-1])
            rv = Rotation.from_matrix(R).as_rotvec()
            dR = []
            for s in (1.0, -1.0):
                v = rv.copy()
                v[axis] += s * 1e-7
                dR.append(Rotation.from_rotvec(v).as_matrix())
            dXr = X_left_mm @ ((dR[0] - dR[1]) / 2e-7).T
            dr[:, 2:] = np.einsum("nij,nj->ni", Jr_cam, dXr)
        out[:, :, j] = -np.linalg.solve(np.swapaxes(J, 1, 2) @ J, np.einsum("nki,nk->ni", J, dr)[..., None])[..., 0]
    return out


def test_sensitivity_matches_the_implicit_function_derivative():
    rig = _true_rig()
    X_ref, _ = _specimen_points(RIG)
    pl, pr = _pixels(RIG, X_ref)
    names = tuple(f"{s}.{n}" for s in ("left", "right") for n in INTRINSIC_NAMES) + STEREO_PARAMETER_NAMES
    G = calibration_sensitivity(rig, pl, pr, names)
    ref = _implicit_sensitivity(rig, X_ref, names)
    assert G.shape == (len(X_ref), 3, len(names))
    scale = np.max(np.abs(ref), axis=(0, 1))                   # per parameter
    err = np.max(np.abs(G - ref), axis=(0, 1)) / scale
    print(f"\nworst relative difference {err.max():.2e} ({names[int(np.argmax(err))]})")
    # The triangulation's differences agree with the projections' within 1e-6 (measured: 3e-7, k2, whose
    # column is smallest); the T columns' reference is analytic.
    assert np.all(err < 1e-6), dict(zip(names, err))
    assert np.all(err[-3:] < 1e-8)


def test_sensitivity_does_not_depend_on_the_step():
    rig = _true_rig()
    X_ref, _ = _specimen_points(RIG)
    pl, pr = _pixels(RIG, X_ref)
    small, large = (calibration_sensitivity(rig, pl, pr, step=f) for f in (0.1, 10.0))
    err = np.max(np.abs(small - large), axis=(0, 1)) / np.max(np.abs(large), axis=(0, 1))
    assert np.all(err < 1e-5), err.max()                     # measured 1.6e-6 (rounding at the small step)
    # an absolute step per name replaces that name's default only
    custom = calibration_sensitivity(rig, pl, pr, names=("stereo.T_x_mm", "left.k2"), step={"left.k2": 1e-3})
    np.testing.assert_allclose(custom[:, :, 0], large[:, :, -3], rtol=1e-6, atol=1e-9)


def test_zero_displacement_has_zero_calibration_covariance(mc):
    """G_U = G_def - G_ref: the same calibration error acts on both states, so an unmoved point's U has none."""
    cal = mc["cal"][0]
    l0, r0, _, _ = mc["pixels"]
    assert np.all(displacement_calibration_covariance_mm2(cal, l0, r0, l0, r0) == 0.0)
    assert np.all(np.diagonal(calibration_covariance_mm2(cal, l0, r0), axis1=1, axis2=2) > 0)


def test_non_finite_pixels_give_nan_rows(mc):
    cal = mc["cal"][0]
    l0, r0, _, _ = mc["pixels"]
    l0 = l0.copy()
    l0[3] = np.nan
    cov = calibration_covariance_mm2(cal, l0, r0)
    assert np.all(np.isnan(cov[3]))
    assert np.all(np.isfinite(np.delete(cov, 3, axis=0)))
    assert np.all(np.isnan(calibration_sensitivity(cal, l0, r0)[3]))


def test_loaded_rig_and_calibration_give_the_same_covariance(mc, tmp_path):
    """A CalibratedRig (cameras directly) and a StereoCalibration (CameraCalibration.camera) are both accepted."""
    cal = mc["cal"][0]
    save_calibration(cal, tmp_path / "cal.json")
    l0, r0, l1, r1 = mc["pixels"]
    a = displacement_calibration_covariance_mm2(cal, l0, r0, l1, r1)
    b = displacement_calibration_covariance_mm2(load_calibration(tmp_path / "cal.json"), l0, r0, l1, r1)
    np.testing.assert_allclose(a, b, rtol=1e-9, atol=1e-18)


def test_unknown_parameter_name_raises():
    X_ref, _ = _specimen_points(RIG)
    pl, pr = _pixels(RIG, X_ref)
    with pytest.raises(ValueError, match="unknown calibration parameter 'left.focal'"):
        calibration_sensitivity(_true_rig(), pl, pr, names=("left.focal",))
    with pytest.raises(ValueError, match="step must be a positive factor"):
        calibration_sensitivity(_true_rig(), pl, pr, step=0.0)


# ------------------------------------------------------------------------------------------------------------
# A rig without a covariance
# ------------------------------------------------------------------------------------------------------------
def test_no_covariance_gives_nan_and_warns_once(monkeypatch, tmp_path):
    monkeypatch.setattr(calunc, "_warned", set())           # "once per process": start this test afresh
    path = tmp_path / "old.json"
    save_rig(_true_rig(), path)                             # a file without the covariance key
    assert "covariance" not in json.loads(path.read_text())
    rig = load_calibration(path)
    assert rig.covariance is None and rig.covariance_names == ()
    X_ref, X_def = _specimen_points(RIG)
    (l0, r0), (l1, r1) = _pixels(RIG, X_ref), _pixels(RIG, X_def)
    with pytest.warns(UserWarning, match="no parameter covariance.*unknown, not zero"):
        cov = calibration_covariance_mm2(rig, l0, r0)
    assert cov.shape == (len(l0), 3, 3) and np.all(np.isnan(cov))
    with warnings.catch_warnings():
        warnings.simplefilter("error")                      # a second warning would raise
        assert np.all(np.isnan(displacement_calibration_covariance_mm2(rig, l0, r0, l1, r1)))
        summary = common_mode_summary(rig, l0, r0, l1, r1)
    assert np.all(np.isnan(summary.sigma_mean_mm)) and np.isnan(summary.sigma_scale)


# ------------------------------------------------------------------------------------------------------------
# The covariance in the calibration file
# ------------------------------------------------------------------------------------------------------------
NAMES = tuple(f"{s}.{n}" for s in ("left", "right") for n in INTRINSIC_NAMES) + STEREO_PARAMETER_NAMES


def _spd(k, seed=0):
    """A random symmetric positive-definite (k, k) matrix with very different scales per row."""
    rng = np.random.default_rng(seed)
    A = rng.normal(size=(k, k))
    scale = 10.0 ** rng.uniform(-12, 1, k)
    return (A @ A.T + k * np.eye(k)) * np.outer(scale, scale)


def _rig_with_covariance(cov=None, names=NAMES):
    r = _true_rig()
    return CalibratedRig(r.model, r.left, r.right, r.R_right_from_left, r.T_right_from_left_mm,
                         _spd(len(names)) if cov is None else cov, names)


def test_covariance_round_trips_through_the_file(mc, tmp_path):
    cal = mc["cal"][0]
    save_calibration(cal, tmp_path / "cal.json")
    doc = json.loads((tmp_path / "cal.json").read_text())
    assert doc["covariance"]["names"] == list(cal.covariance_names)
    assert "marginalised" in doc["covariance"]["convention"]
    loaded = load_calibration(tmp_path / "cal.json")
    np.testing.assert_array_equal(loaded.covariance, cal.covariance)
    assert loaded.covariance_names == cal.covariance_names
    # ... and through save_rig / rig_to_dict of the loaded rig
    save_rig(loaded, tmp_path / "rig.json")
    again = load_calibration(tmp_path / "rig.json")
    np.testing.assert_array_equal(again.covariance, cal.covariance)
    assert again.covariance_names == cal.covariance_names
    # a rig's own (hand-made) covariance too
    rig = _rig_with_covariance()
    save_rig(rig, tmp_path / "spd.json")
    np.testing.assert_array_equal(load_calibration(tmp_path / "spd.json").covariance, rig.covariance)


def _write_with(tmp_path, edit):
    """A valid calibration JSON with a covariance, changed by ``edit(doc["covariance"])``."""
    doc = rig_to_dict(_rig_with_covariance())
    edit(doc["covariance"])
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(doc))
    return path


def _asymmetric(c):
    c["matrix"][0][1] *= 1.0 + 1e-6


def _drop_row(c):
    c["matrix"].pop()


def _drop_column(c):
    for row in c["matrix"]:
        row.pop()


def _rename(c):
    c["names"][2] = "left.focal_px"


def _duplicate(c):
    c["names"][3] = c["names"][2]


def _negative_variance(c):
    c["matrix"][4][4] = -1.0


def _not_finite(c):
    c["matrix"][1][1] = float("nan")


def _unknown_key(c):
    c["matrixx"] = c["matrix"]


@pytest.mark.parametrize("edit, message", [
    (_asymmetric, r"covariance\.matrix.*not symmetric"),
    (_drop_row, r"covariance\.matrix.*25 rows but covariance\.names lists 26 names"),
    (_drop_column, r"covariance\.matrix\[0\].*list of 26 entries"),
    (_rename, r"covariance\.names\[2\].*unknown parameter 'left\.focal_px'"),
    (_duplicate, r"covariance\.names\[3\].*listed twice"),
    (_negative_variance, r"covariance\.matrix\[4\]\[4\].*must not be negative"),
    (_not_finite, r"covariance\.matrix\[1\]\[1\]"),
    (_unknown_key, r"covariance.*unknown key\(s\) 'matrixx'"),
])
def test_malformed_covariance_is_refused(tmp_path, edit, message):
    path = _write_with(tmp_path, edit)
    with pytest.raises(FileFormatError, match=message) as err:
        load_calibration(path)
    assert str(path) in str(err.value)


def test_malformed_covariance_is_not_written(tmp_path):
    cov = _spd(len(NAMES))
    cov[0, 1] *= 1.01
    path = tmp_path / "never.json"
    with pytest.raises(FileFormatError, match=r"covariance\.matrix.*not symmetric.*nothing written"):
        save_rig(_rig_with_covariance(cov), path)
    assert not path.exists()


def test_singular_covariance_is_left_out_of_the_file(mc, tmp_path):
    """A covariance from a singular normal matrix (NaN) must not make the whole calibration unwritable."""
    cal = replace(mc["cal"][0], covariance=np.full_like(mc["cal"][0].covariance, np.nan))
    save_calibration(cal, tmp_path / "cal.json")
    assert "covariance" not in json.loads((tmp_path / "cal.json").read_text())
    assert load_calibration(tmp_path / "cal.json").covariance is None


def test_stereo_results_carry_the_calibration_term_interpolated_within_2_percent():
    """`measurement.stereo_dic.calibration_uncertainty` differentiates the triangulation at a sample of points and
    interpolates over the field: against the direct per-point propagation
    (:func:`displacement_calibration_covariance_mm2` at every point) within 2 % of each sigma; NaN for a rig
    without covariance."""
    import warnings
    from types import SimpleNamespace

    from measurement.calibration.io import CalibratedRig
    from measurement.stereo_dic import calibration_uncertainty
    from measurement.uncertainty.calibration import displacement_calibration_covariance_mm2
    from workbench.rigs import paper_rig

    rig_true = paper_rig(0.25)
    names = tuple(f"{side}.{n}" for side in ("left", "right") for n in ("fx", "fy", "cx", "cy", "alpha_deg",
                                                                         "beta_deg", "k1", "k2", "p1", "p2"))
    names += ("stereo.rvec_x", "stereo.rvec_y", "stereo.rvec_z", "stereo.T_x_mm", "stereo.T_y_mm", "stereo.T_z_mm")
    rng = np.random.default_rng(4)
    A = rng.normal(size=(len(names), len(names))) * 1e-3
    cov = A @ A.T + np.diag(np.full(len(names), 1e-6))
    rig = CalibratedRig("rmm", rig_true.left, rig_true.right, rig_true.R_right_from_left,
                        rig_true.T_right_from_left_mm, covariance=cov, covariance_names=names)
    # a grid of points on a plane seen by both cameras, moved by 0.5 mm: pixels from the true projections
    X = rig_true.optical_axes_meeting_point_mm() + np.stack(np.meshgrid(np.linspace(-8, 8, 25), np.linspace(-6, 6, 21),
                                                                        [0.0]), -1).reshape(-1, 3)
    R, T = rig_true.R_right_from_left, rig_true.T_right_from_left_mm
    pl, pr = rig_true.left.project(X), rig_true.right.project(X @ R.T + T)
    X2 = X + np.array([0.5, -0.2, 0.3])
    pl2, pr2 = rig_true.left.project(X2), rig_true.right.project(X2 @ R.T + T)
    x, y = pl[:, 0], pl[:, 1]          # consistent pixel pairs (a POI and its matches)
    base = np.column_stack([x, y])
    m = lambda d: SimpleNamespace(u=d[:, 0], v=d[:, 1])  # noqa: E731
    shape = SimpleNamespace(x=x, y=y, right_match=m(pr - base), calibration_G_ref=None, calibration_cov_X_mm2=None)
    state = SimpleNamespace(left_match=m(pl2 - base), right_match=m(pr2 - base), valid=np.ones(x.size, bool))
    calibration_uncertainty(shape, state, rig, max_points=60)
    direct = displacement_calibration_covariance_mm2(rig, base, pr - base + base, pl2 - base + base, pr2 - base + base)
    s_interp = np.sqrt(np.einsum("nii->ni", state.calibration_cov_U_mm2))
    s_direct = np.sqrt(np.einsum("nii->ni", direct))
    assert np.all(np.abs(s_interp / s_direct - 1) < 0.02), np.abs(s_interp / s_direct - 1).max()
    # the field's common part (sigma of the mean U) against common_mode_summary's direct figure
    from measurement.uncertainty.calibration import common_mode_summary

    common = common_mode_summary(rig, base, pr, pl2, pr2)
    np.testing.assert_allclose(state.calibration_sigma_mean_U_mm, common.sigma_mean_mm, rtol=0.02)
    bare = CalibratedRig("rmm", rig_true.left, rig_true.right, R, T)
    shape.calibration_G_ref = None
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")       # the no-covariance warning is issued once per process (tested above)
        calibration_uncertainty(shape, None, bare)
    assert np.all(np.isnan(shape.calibration_cov_X_mm2))


# ------------------------------------------------------------------------------------------------------------
# The bootstrap covariance (measurement.calibration.bootstrap) against the linear one and the Monte Carlo
# ------------------------------------------------------------------------------------------------------------
def _noisy_corners(board, sigma_px, seed):
    """The corners :func:`_calibrate` calibrates from for ``seed``."""
    rng = np.random.default_rng(seed)
    return [board[s] + rng.normal(0.0, sigma_px, board[s].shape) for s in ("left", "right")]


def _bootstrap_sigmas(cal, corners, draws, seed, pixels):
    """Predicted calibration sigma of X and of the 1 mm displacement (RMS over the points, (3,) mm each) from a
    ``draws``-draw bootstrap of ``cal``, and the BootstrapCovariance."""
    from measurement.calibration.bootstrap import with_bootstrap_covariance

    boot_cal, boot = with_bootstrap_covariance(cal, *corners, BOARD_MM, (RIG.left.width, RIG.left.height),
                                               draws=draws, seed=seed, tilt_guess_left_deg=TILT_GUESS["left"],
                                               tilt_guess_right_deg=TILT_GUESS["right"])
    l0, r0, l1, r1 = pixels
    rms = lambda c: np.sqrt(np.mean(np.diagonal(c, axis1=1, axis2=2), axis=0))  # noqa: E731
    return {"X": rms(calibration_covariance_mm2(boot_cal, l0, r0)),
            "U": rms(displacement_calibration_covariance_mm2(boot_cal, l0, r0, l1, r1))}, boot


#: Draws of the CI-scale bootstrap test: a sigma from 20 draws scatters by ~16 %, so 35 % is 2.2 sigma.
BOOTSTRAP_DRAWS_CI = 20


def test_bootstrap_agrees_with_the_linear_covariance_at_small_noise(mc):
    """At 0.005 px the calibration is linear in the noise (the linear covariance predicts the Monte Carlo, above):
    a bootstrap of the first calibration predicts the same sigma of X and U within its sampling scatter."""
    cal = mc["cal"][0]
    corners = _noisy_corners(_board_pixels(RIG, N_VIEWS, 3), SIGMA_PX, 1000)
    boot, b = _bootstrap_sigmas(cal, corners, BOOTSTRAP_DRAWS_CI, 0, mc["pixels"])
    l0, r0, l1, r1 = mc["pixels"]
    rms = lambda c: np.sqrt(np.mean(np.diagonal(c, axis1=1, axis2=2), axis=0))  # noqa: E731
    linear = {"X": rms(calibration_covariance_mm2(cal, l0, r0)),
              "U": rms(displacement_calibration_covariance_mm2(cal, l0, r0, l1, r1))}
    print(f"\nbootstrap ({b.draws} draws, corner noise {b.corner_sigma_px} px) / linear: "
          f"X {np.round(boot['X'] / linear['X'], 3)}, U {np.round(boot['U'] / linear['U'], 3)}; Monte Carlo / "
          f"bootstrap: X {np.round(np.sqrt(np.mean(mc['err_X'] ** 2, axis=(0, 1))) / boot['X'], 3)}, "
          f"U {np.round(np.sqrt(np.mean(mc['err_U'] ** 2, axis=(0, 1))) / boot['U'], 3)}")
    assert b.draws == BOOTSTRAP_DRAWS_CI and b.failed == 0 and b.wrong_minimum == 0
    for f in ("X", "U"):
        assert np.all(np.abs(boot[f] / linear[f] - 1.0) <= 0.35), (f, boot[f] / linear[f])
    # the noise the bootstrap draws is the fit's residual: the 0.005 px the corners had, within 3 %
    assert all(abs(s / SIGMA_PX - 1.0) < 0.03 for s in b.corner_sigma_px.values())


@pytest.mark.slow
@pytest.mark.xfail(strict=True, reason=(
    "issue 36's goal at realistic corner noise is not met by a covariance estimated at the calibration: at 0.05 px "
    "the Monte Carlo spread of 40 calibrations is 1.91 / 1.64 / 2.21 (X) and 1.91 / 1.64 / 2.04 (U) x the median "
    "bootstrap sigma (5 calibrations x 40 draws), 1.7 / 1.5 / 2.0 x the linear one: the spread is carried by ~5 % "
    "of calibrations 5-13 sigma out along the tilt/principal-point valley (2 of 200 a worse local minimum of the "
    "stepwise procedure, the rest global minima), which a bootstrap around one estimate sees at a rate of its own"))
def test_bootstrap_predicts_the_monte_carlo_at_realistic_corner_noise():
    """The issue's goal at 0.05 px: predicted (median over 5 bootstraps of 40 draws) and observed (40
    calibrations) calibration sigma of X and of the displacement within 20 % per component."""
    sigma = 0.05
    mc = _monte_carlo(40, sigma)
    board = _board_pixels(RIG, N_VIEWS, 3)
    predicted = {"X": [], "U": []}
    for i in range(5):
        cal = _calibrate(board, sigma, 1000 + i)
        boot, b = _bootstrap_sigmas(cal, _noisy_corners(board, sigma, 1000 + i), 40, i, mc["pixels"])
        print(f"  bootstrap {i}: {b.wrong_minimum} wrong minima, {b.not_converged} not converged")
        for f in ("X", "U"):
            predicted[f].append(boot[f])
    ratios = {f: np.sqrt(np.mean(mc[f"err_{f}"] ** 2, axis=(0, 1))) / np.median(predicted[f], axis=0)
              for f in ("X", "U")}
    print(f"  observed / bootstrap: X {np.round(ratios['X'], 3)}, U {np.round(ratios['U'], 3)}")
    for f in ("X", "U"):
        assert np.all(np.abs(ratios[f] - 1.0) <= GOAL), (f, ratios[f])
