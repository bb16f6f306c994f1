"""The parametric bootstrap of a stereo calibration's covariance (:mod:`measurement.calibration.bootstrap`): its
synthetic corners, noise level, reproducibility, the estimator in the calibration JSON, and ``workbench calibrate
--covariance bootstrap``. Whether the bootstrap covariance predicts the spread of calibrations is tested against a
Monte Carlo in ``tests/test_calibration_uncertainty.py``."""
import json
import re
from dataclasses import replace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from measurement.calibration.bootstrap import (
    bootstrap_covariance,
    bootstrap_estimator,
    parameter_vector,
    parse_estimator,
    residual_sigma_px,
    synthetic_corners,
    with_bootstrap_covariance,
)
from measurement.calibration.detection import board_points_mm
from measurement.calibration.io import FileFormatError, load_calibration, rig_to_dict, save_calibration, save_rig
from measurement.calibration.stepwise import calibrate_stereo
from scenes.surfaces.checkerboard import Checkerboard
from workbench.cli import main
from workbench.experiments.calibration.views import board_outline_mm
from workbench.poses import random_board_poses
from workbench.rigs import paper_rig

RIG = paper_rig(0.25)
BOARD_MM = board_points_mm((11, 8), 5.0)
SIZE = (RIG.left.width, RIG.left.height)
OPTIONS = dict(tilt_guess_left_deg=(0.0, -4.0), tilt_guess_right_deg=(0.0, 4.0))
#: Corner noise of the calibration under test: small, so its draws converge in few iterations (cost only).
SIGMA_PX = 0.01


def _exact_corners(n_views=8, seed=2):
    poses = random_board_poses(RIG, board_outline_mm(Checkerboard()), n_views, seed)
    X = np.array([BOARD_MM @ R.T + t for R, t in poses])
    out = []
    for side in ("left", "right"):
        R, T = RIG.pose(side)
        out.append(RIG.camera(side).project((X @ R.T + T).reshape(-1, 3)).reshape(n_views, len(BOARD_MM), 2))
    return out


@pytest.fixture(scope="module")
def calibrated():
    """A calibration of the quarter-scale paper rig from 8 views with 0.01 px of corner noise; a few corners of
    the right camera missing (NaN), as a partly seen board leaves them."""
    rng = np.random.default_rng(11)
    pl, pr = (p + rng.normal(0.0, SIGMA_PX, p.shape) for p in _exact_corners())
    pr[2, :5] = np.nan
    cal = calibrate_stereo(pl, pr, BOARD_MM, SIZE, **OPTIONS)
    return cal, pl, pr


def test_residual_sigma_is_the_noise_drawn(calibrated):
    """~1400 coordinates per camera: the residual's sigma (with the degrees-of-freedom correction) is the drawn
    noise within 5 % (its sampling scatter is ~2 %)."""
    cal, pl, pr = calibrated
    sigma = residual_sigma_px(cal, pl, pr, BOARD_MM)
    print(f"\nresidual sigma {sigma} px (drawn {SIGMA_PX})")
    for side in ("left", "right"):
        assert abs(sigma[side] / SIGMA_PX - 1.0) < 0.05, (side, sigma[side])
    # consistent with the calibration's own RMS (sqrt(du^2 + dv^2) per corner) up to the dof factor (< 1 %)
    for side in ("left", "right"):
        per_coordinate = getattr(cal, side).rms_px / np.sqrt(2.0)
        assert 1.0 < sigma[side] / per_coordinate < 1.05


def test_synthetic_corners_are_the_fitted_projections_plus_noise(calibrated):
    cal, pl, pr = calibrated
    found_l, found_r = np.isfinite(pl).all(-1), np.isfinite(pr).all(-1)
    sigma = {"left": 0.3, "right": 0.1}
    a = synthetic_corners(cal, found_l, found_r, BOARD_MM, sigma, np.random.default_rng(5))
    b = synthetic_corners(cal, found_l, found_r, BOARD_MM, sigma, np.random.default_rng(5))
    np.testing.assert_array_equal(a[0], b[0])
    assert np.all(np.isnan(a[1][2, :5])) and np.all(np.isfinite(a[1][found_r]))
    for side, pts, found in (("left", a[0], found_l), ("right", a[1], found_r)):
        c = getattr(cal, side)
        # the fitted model's projection, built here from the camera and the pose directly
        X = np.array([BOARD_MM @ Rotation.from_rotvec(r).as_matrix().T + t for r, t in zip(c.rvecs, c.tvecs_mm)])
        exact = c.camera.project(X.reshape(-1, 3)).reshape(pts.shape)
        noise = (pts - exact)[found]
        assert abs(noise.std() / sigma[side] - 1.0) < 0.05 and abs(noise.mean()) < 0.01


def test_bootstrap_is_reproducible_and_named(calibrated):
    cal, pl, pr = calibrated
    with_boot, one = with_bootstrap_covariance(cal, pl, pr, BOARD_MM, SIZE, draws=2, seed=7, **OPTIONS)
    assert with_boot.covariance_estimator == "bootstrap (2 draws)" and cal.covariance_estimator == "linear"
    np.testing.assert_array_equal(with_boot.covariance, one.covariance)
    assert with_boot.left.sigma == cal.left.sigma                # the fit's own sigmas stay the linear ones
    assert one.names == cal.covariance_names and one.draws == 2 and one.failed == 0
    k = len(cal.covariance_names)
    assert one.covariance.shape == (k, k) and one.deviations.shape == (2, k)
    np.testing.assert_array_equal(one.covariance, one.covariance.T)
    np.testing.assert_allclose(one.covariance, np.cov(one.deviations, rowvar=False), rtol=1e-12, atol=0)
    # draw k's noise depends on (seed, k) alone: the same seed gives the same draws, another seed others
    first = bootstrap_covariance(cal, pl, pr, BOARD_MM, SIZE, draws=2, seed=7, **OPTIONS)
    np.testing.assert_array_equal(first.deviations, one.deviations)
    other = bootstrap_covariance(cal, pl, pr, BOARD_MM, SIZE, draws=2, seed=8, **OPTIONS)
    assert not np.allclose(other.deviations, one.deviations)


def test_rotation_deviation_is_the_difference_of_rotation_vectors(calibrated):
    """The stereo rotation's convention is the propagation's: R = from_rotvec(rvec + d)."""
    cal, _, _ = calibrated
    d = np.array([2e-4, -1e-4, 3e-4])
    turned = replace(cal, R_right_from_left=Rotation.from_rotvec(
        Rotation.from_matrix(cal.R_right_from_left).as_rotvec() + d).as_matrix())
    names = ("stereo.rvec_x", "stereo.rvec_y", "stereo.rvec_z", "left.cx")
    np.testing.assert_allclose(parameter_vector(turned, names) - parameter_vector(cal, names), [*d, 0.0],
                               rtol=0, atol=1e-12)


def test_bootstrap_refuses_bad_arguments(calibrated):
    cal, pl, pr = calibrated
    with pytest.raises(ValueError, match="draws must be at least 2"):
        bootstrap_covariance(cal, pl, pr, BOARD_MM, SIZE, draws=1)
    with pytest.raises(ValueError, match="8 board poses but the corners 7 views"):
        bootstrap_covariance(cal, pl[:7], pr[:7], BOARD_MM, SIZE, draws=2)
    with pytest.raises(ValueError, match="workers must be at least 1"):
        bootstrap_covariance(cal, pl, pr, BOARD_MM, SIZE, draws=2, workers=0)


@pytest.mark.parametrize("text, parsed", [("linear", ("linear", None)), ("bootstrap (40 draws)", ("bootstrap", 40)),
                                          ("bootstrap (2 draws)", ("bootstrap", 2))])
def test_estimator_names_parse(text, parsed):
    assert parse_estimator(text) == parsed
    if parsed[1] is not None:
        assert bootstrap_estimator(parsed[1]) == text


@pytest.mark.parametrize("text, message", [("jackknife", "unknown covariance estimator 'jackknife'"),
                                           ("bootstrap (1 draws)", "needs at least 2 draws"),
                                           ("bootstrap(40 draws)", "unknown covariance estimator"),
                                           ("Linear", "unknown covariance estimator")])
def test_bad_estimator_names_are_refused(text, message):
    with pytest.raises(ValueError, match=re.escape(message)):
        parse_estimator(text)


# ------------------------------------------------------------------------------------------------------------
# The estimator in the calibration file
# ------------------------------------------------------------------------------------------------------------
def test_estimator_round_trips_through_the_file(calibrated, tmp_path):
    cal, _, _ = calibrated
    boot = replace(cal, covariance=cal.covariance * 2.0, covariance_estimator="bootstrap (40 draws)")
    save_calibration(boot, tmp_path / "boot.json")
    entry = json.loads((tmp_path / "boot.json").read_text())["covariance"]
    assert entry["estimator"] == "bootstrap (40 draws)" and "sample covariance" in entry["convention"]
    rig = load_calibration(tmp_path / "boot.json")
    assert rig.covariance_estimator == "bootstrap (40 draws)"
    np.testing.assert_array_equal(rig.covariance, boot.covariance)
    save_rig(rig, tmp_path / "again.json")                    # a loaded rig keeps it too
    assert load_calibration(tmp_path / "again.json").covariance_estimator == "bootstrap (40 draws)"
    save_calibration(cal, tmp_path / "linear.json")
    entry = json.loads((tmp_path / "linear.json").read_text())["covariance"]
    assert entry["estimator"] == "linear" and "(J^T J)^-1" in entry["convention"]
    assert load_calibration(tmp_path / "linear.json").covariance_estimator == "linear"


def test_file_without_estimator_is_linear(calibrated, tmp_path):
    """Files written before the key: their covariance is the least squares' one."""
    cal, _, _ = calibrated
    save_calibration(cal, tmp_path / "c.json")
    doc = json.loads((tmp_path / "c.json").read_text())
    del doc["covariance"]["estimator"]
    (tmp_path / "old.json").write_text(json.dumps(doc))
    assert load_calibration(tmp_path / "old.json").covariance_estimator == "linear"


@pytest.mark.parametrize("value, message", [("jackknife", r"covariance\.estimator.*unknown covariance estimator"),
                                            ("bootstrap (0 draws)", r"covariance\.estimator.*at least 2 draws"),
                                            (40, r"covariance\.estimator"), ("", r"covariance\.estimator")])
def test_malformed_estimator_is_refused(calibrated, tmp_path, value, message):
    cal, _, _ = calibrated
    doc = json.loads(json.dumps(rig_to_dict(load_calibration(_saved(cal, tmp_path)))))
    doc["covariance"]["estimator"] = value
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(doc))
    with pytest.raises(FileFormatError, match=message) as err:
        load_calibration(path)
    assert str(path) in str(err.value)


def _saved(cal, tmp_path):
    path = tmp_path / "good.json"
    save_calibration(cal, path)
    return path


def test_unknown_estimator_is_not_written(calibrated, tmp_path):
    cal, _, _ = calibrated
    with pytest.raises(ValueError, match="unknown covariance estimator 'guess'"):
        save_calibration(replace(cal, covariance_estimator="guess"), tmp_path / "never.json")
    assert not (tmp_path / "never.json").exists()


# ------------------------------------------------------------------------------------------------------------
# workbench calibrate --covariance bootstrap
# ------------------------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def rendered_views(tmp_path_factory):
    """Eight noisy stereo views at a quarter of full resolution (as tests/test_calibration_files.py renders)."""
    out = tmp_path_factory.mktemp("views")
    assert main(["render", "checkerboard", "--views", "8", "--seed", "1", "--scale", "0.25", "--spp", "16",
                 "--noise-grey", "1", "--out", str(out)]) == 0
    return out


def test_calibrate_command_writes_a_bootstrap_covariance(rendered_views, tmp_path, capsys):
    def run(out, *extra):
        return main(["calibrate", "--left", str(rendered_views / "left_*.png"), "--right",
                     str(rendered_views / "right_*.png"), "--tilt-guess-deg", "0,-4", *extra, "--out", str(out)])

    assert run(tmp_path / "boot.json", "--covariance", "bootstrap", "--bootstrap-draws", "4",
               "--bootstrap-seed", "3") == 0
    printed = capsys.readouterr().out
    assert "bootstrap covariance: 4 calibrations" in printed and "4 draws kept, 0 refused" in printed
    doc = json.loads((tmp_path / "boot.json").read_text())
    assert doc["covariance"]["estimator"] == "bootstrap (4 draws)"
    assert doc["covariance_bootstrap"]["draws"] == 4 and doc["covariance_bootstrap"]["seed"] == 3
    sigma = doc["covariance_bootstrap"]["corner_sigma_px"]
    for side in ("left", "right"):            # the residual's noise: the RMS per coordinate, dof-corrected
        assert 1.0 < sigma[side] / (doc["reprojection_rms_px"][side] / np.sqrt(2)) < 1.1
    assert load_calibration(tmp_path / "boot.json").covariance_estimator == "bootstrap (4 draws)"
    assert run(tmp_path / "linear.json") == 0                 # the default stays linear
    linear = json.loads((tmp_path / "linear.json").read_text())
    assert linear["covariance"]["estimator"] == "linear" and "covariance_bootstrap" not in linear
    # same corners, same fit: only the covariance differs
    assert linear["left"]["intrinsics"] == doc["left"]["intrinsics"]
    assert not np.allclose(linear["covariance"]["matrix"], doc["covariance"]["matrix"])


def test_calibrate_command_refuses_a_bootstrap_of_one_camera(tmp_path, capsys):
    code = main(["calibrate", "--camera", str(tmp_path / "*.png"), "--covariance", "bootstrap", "--out",
                 str(tmp_path / "c.json")])
    assert code == 2
    assert "--covariance bootstrap is for a stereo calibration" in capsys.readouterr().err


@pytest.mark.parametrize("draws", ["1", "0", "x", "20000"])
def test_calibrate_command_refuses_bad_draw_counts(tmp_path, capsys, draws):
    code = main(["calibrate", "--left", "a*", "--right", "b*", "--bootstrap-draws", draws, "--out",
                 str(tmp_path / "c.json")])
    assert code == 2
    assert "argument --bootstrap-draws:" in capsys.readouterr().err


def test_rendered_calibration_rig_carries_the_covariance(calibrated):
    """The rig the calibration experiment scores (and the rigid-motion test measures with) keeps the covariance
    and its estimator."""
    from workbench.experiments.calibration.run import _as_rig

    cal, _, _ = calibrated
    boot = replace(cal, covariance=cal.covariance * 3.0, covariance_estimator="bootstrap (40 draws)")
    rig = _as_rig(boot)
    np.testing.assert_array_equal(rig.covariance, boot.covariance)
    assert rig.covariance_names == cal.covariance_names and rig.covariance_estimator == "bootstrap (40 draws)"


def test_calibration_experiment_refuses_an_unknown_covariance(tmp_path):
    from workbench.experiments.calibration.run import reproduce_calibration

    with pytest.raises(ValueError, match="covariance must be 'linear' or 'bootstrap', got 'jackknife'"):
        reproduce_calibration(tmp_path, covariance="jackknife")
    assert list(tmp_path.iterdir()) == []                    # refused before anything is rendered or written
