"""Model selection (``--model auto``, ``--lens auto``), term significance, single-camera calibration files and CLI.

The synthetic corners are projected by the truth side (:func:`scenes.optics.projection.project_points`, its own implementation of
the camera) from a rig whose tilt is known to be there (the paper's Table 1, 4.5 deg) or known to be absent (the same
rig with alpha = beta = 0); the real corners are OpenCV's 640 x 480 stereo sample (nominally untilted cameras).
"""
from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pytest

from measurement.calibration.detection import board_points_mm
from measurement.calibration.images import detect_pairs
from measurement.calibration.io import FileFormatError, load_camera_calibration, load_calibration
from measurement.calibration.model_selection import (cross_validate, select_model, significance_lines,
                                                     term_significance)
from measurement.calibration.stepwise import CalibrationError, calibrate_stereo
from scenes.surfaces.checkerboard import Checkerboard
from scenes.optics.projection import project_points
from workbench.cli import main
from workbench.experiments.calibration.views import board_outline_mm, sensor_spec_for
from workbench.poses import random_board_poses
from workbench.rigs import paper_rig

REAL = Path(__file__).parent / "data" / "real" / "opencv_stereo"
PATTERN = (9, 6)
BOARD = Checkerboard()
BOARD_MM = BOARD.corners_board_mm()


def _corners(rig, n_views=12, noise_px=0.05, seed=4):
    """(left, right) corners (V, N, 2) of random board poses, projected by the truth side, plus Gaussian noise."""
    rng = np.random.default_rng(seed)
    poses = random_board_poses(rig, board_outline_mm(BOARD), n_views, seed)
    out = []
    for side in ("left", "right"):
        spec = sensor_spec_for(rig, side)
        R, t = rig.pose(side)
        px = np.array([project_points(spec, R, t, BOARD_MM @ Rb.T + tb) for Rb, tb in poses])
        out.append(px + rng.normal(0.0, noise_px, px.shape))
    return out


@pytest.fixture(scope="module")
def tilted():
    """The paper rig at full size (2448 x 2048). At quarter size, with the same 0.05 px corner noise, the 4.6 deg tilt
    is NOT identified (measured: pinhole 0.0701 / 0.0692 px RMS, rmm 0.0697 / 0.0691, equal held-out error): p1, p2
    and the principal point absorb it over the field the boards cover, so the selection rightly keeps pinhole."""
    return paper_rig(1.0)


@pytest.fixture(scope="module")
def untilted(tilted):
    return replace(tilted, left=replace(tilted.left, alpha_deg=0.0, beta_deg=0.0),
                   right=replace(tilted.right, alpha_deg=0.0, beta_deg=0.0))


def test_auto_picks_the_tilt_model_for_a_tilted_rig_and_pinhole_for_an_untilted_one(tilted, untilted):
    """The held-out test keeps the tilt where the sensor is tilted (4.6 deg, full size) and drops it where it is not;
    on the tilted rig the tilt is significant (z > 3) and the pinhole's held-out error exceeds rmm's by more than
    its standard error."""
    candidates = (("pinhole", "brown4"), ("rmm", "brown4"))
    for rig, expected in ((tilted, "rmm"), (untilted, "pinhole")):
        pl, pr = _corners(rig)
        size = (rig.left.width, rig.left.height)
        sel = select_model(pl, pr, BOARD_MM, size, candidates=candidates, folds=6)
        assert sel.chosen.model == expected, "\n".join(sel.lines())
        assert sel.calibration.model == expected
        rows = {c.model: c for c in sel.candidates}
        if expected == "rmm":
            z = sel.chosen.significance["left"]["beta_deg"]["z"]
            assert z > 3.0
            assert rows["pinhole"].held_out_mse_px2 > rows["rmm"].held_out_mse_px2 + rows["pinhole"].se_px2
        else:
            # the tilt fitted anyway is not determined: the significance check warns for it
            rmm = calibrate_stereo(pl, pr, BOARD_MM, size, model="rmm")
            _, warns = significance_lines(rmm)
            assert any("alpha_deg" in w or "beta_deg" in w for w in warns), warns


def test_cross_validation_error_of_the_true_model_is_the_noise(untilted):
    """Held-out residuals of the true model on exact + 0.05 px noise corners: their RMS is the noise's
    (0.05 sqrt(2) px per point) within 15 %, less the share the six pose parameters absorb."""
    pl, _ = _corners(untilted, n_views=10)
    e = cross_validate(pl, BOARD_MM, (untilted.left.width, untilted.left.height), model="pinhole", lens="brown4",
                       folds=5)
    rms = np.sqrt(e[:, 0].sum() / e[:, 1].sum())
    n = len(BOARD_MM)
    expected = 0.05 * np.sqrt(2) * np.sqrt((2 * n - 6) / (2 * n))
    assert rms == pytest.approx(expected, rel=0.15)


def test_too_few_views_for_a_held_out_test_are_refused(untilted):
    pl, _ = _corners(untilted, n_views=3)
    with pytest.raises(CalibrationError, match=r"3 views are too few for a held-out test"):
        cross_validate(pl, BOARD_MM, (untilted.left.width, untilted.left.height), model="pinhole", lens="brown4")


def test_term_significance_is_value_over_sigma(tilted):
    pl, pr = _corners(tilted, n_views=8)
    cal = calibrate_stereo(pl, pr, BOARD_MM, (tilted.left.width, tilted.left.height), model="rmm", lens="brown5")
    sig = term_significance(cal)
    assert set(sig["left"]) == {"alpha_deg", "beta_deg", "k3"}
    for side in ("left", "right"):
        c = getattr(cal, side)
        for term, row in sig[side].items():
            assert row["z"] == pytest.approx(abs(getattr(c.camera, term)) / c.sigma[term])


# ------------------------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def real_pairs():
    left, right = sorted(REAL.glob("left*.jpg")), sorted(REAL.glob("right*.jpg"))
    return detect_pairs(left, right, pattern_size=PATTERN, progress=False)


def test_auto_picks_pinhole_on_opencvs_real_stereo_sample(real_pairs):
    """On OpenCV's sample (untilted cameras) the tilt is 2.6-5 sigma "significant" and the BIC prefers it, but it
    does not predict held-out views better: --model auto --lens auto keeps pinhole with the paper's four lens terms
    (the issue's requirement). The chosen calibration is the pinhole one."""
    board = board_points_mm(PATTERN, 1.0)
    sel = select_model(real_pairs.points_left, real_pairs.points_right, board, real_pairs.image_size)
    assert (sel.chosen.model, sel.chosen.lens) == ("pinhole", "brown4"), "\n".join(sel.lines())
    assert len(sel.candidates) == 6
    # the richest candidates fit the calibration views better and predict the held-out ones worse
    rows = {(c.model, c.lens): c for c in sel.candidates}
    full = rows["rmm", "full"]
    assert full.rms_px["left"] < sel.chosen.rms_px["left"]
    assert full.held_out_mse_px2 > sel.chosen.held_out_mse_px2


def test_cli_calibrate_model_auto_writes_the_selection_and_the_significance(tmp_path, capsys):
    out = tmp_path / "auto.json"
    assert main(["calibrate", "--left", str(REAL / "left*.jpg"), "--right", str(REAL / "right*.jpg"),
                 "--pattern", "9x6", "--square-mm", "1", "--model", "auto", "--folds", "4", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "model selection (4-fold held-out views" in text and "chosen: pinhole / brown4" in text
    doc = json.loads(out.read_text())
    assert doc["model"] == "pinhole"
    assert doc["model_selection"]["chosen"] == {"model": "pinhole", "lens": "brown4"}
    assert [c["model"] for c in doc["model_selection"]["candidates"]] == ["pinhole", "rmm"]
    assert set(doc["significance"]["left"]) == set()                 # pinhole + brown4: no optional terms
    assert load_calibration(out).left.alpha_deg == 0.0


def test_cli_single_camera_calibration_equals_opencv_calibratecamera(tmp_path, real_pairs):
    """``workbench calibrate --camera`` on the left images: the camera file's intrinsics equal
    cv2.calibrateCamera's (k3 fixed) on the same corners within 1e-3 px; its YAML (OpenCV's calibration-sample
    keys) loads to the same camera; the JSON holds the images used."""
    out = tmp_path / "left.json"
    assert main(["calibrate", "--camera", str(REAL / "left*.jpg"), "--pattern", "9x6", "--square-mm", "1",
                 "--model", "pinhole", "--out", str(out)]) == 0
    cam = load_camera_calibration(out)
    board = board_points_mm(PATTERN, 1.0).astype(np.float32)
    img = [p.astype(np.float32).reshape(-1, 1, 2) for p in real_pairs.points_left]
    _, K, D, _, _ = cv2.calibrateCamera([board] * len(img), img, real_pairs.image_size, None, None,
                                        flags=cv2.CALIB_FIX_K3,
                                        criteria=(cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 200, 1e-12))
    np.testing.assert_allclose([cam.fx, cam.fy, cam.cx, cam.cy], [K[0, 0], K[1, 1], K[0, 2], K[1, 2]], atol=1e-3)
    np.testing.assert_allclose([cam.k1, cam.k2, cam.p1, cam.p2], D.ravel()[:4], atol=1e-5)
    assert load_camera_calibration(out.with_suffix(".yaml")) == cam
    doc = json.loads(out.read_text())
    assert len(doc["images"]["files"]) == 13 and doc["format"] == "scheimpflug-camera-calibration/1"


def test_opencv_calibration_sample_yaml_loads_as_a_camera(tmp_path):
    """A file as OpenCV's calibration sample writes it (camera_matrix, distortion_coefficients, image size)."""
    K = np.array([[1200.0, 0.0, 640.0], [0.0, 1201.0, 500.0], [0.0, 0.0, 1.0]])
    D = np.array([[-0.2, 0.1, 1e-3, -2e-3, 0.05]])
    fs = cv2.FileStorage(str(tmp_path / "out_camera_data.yml"), cv2.FILE_STORAGE_WRITE)
    fs.write("image_width", 1280)
    fs.write("image_height", 1000)
    fs.write("camera_matrix", K)
    fs.write("distortion_coefficients", D)
    fs.release()
    cam = load_camera_calibration(tmp_path / "out_camera_data.yml")
    X = np.array([[10.0, -20.0, 300.0], [-50.0, 40.0, 280.0], [70.0, 60.0, 350.0]])
    np.testing.assert_allclose(cam.project(X), cv2.projectPoints(X, np.zeros(3), np.zeros(3), K, D)[0].reshape(-1, 2),
                               atol=1e-9)
    bad = tmp_path / "nodist.yml"
    fs = cv2.FileStorage(str(bad), cv2.FILE_STORAGE_WRITE)
    fs.write("image_width", 1280)
    fs.write("image_height", 1000)
    fs.write("camera_matrix", K)
    fs.release()
    with pytest.raises(FileFormatError, match=r"nodist\.yml.*has no distortion vector \(looked for "
                                              r"distortion_coefficients"):
        load_camera_calibration(bad)


def test_a_stereo_file_is_not_a_camera_file(tmp_path, untilted):
    pl, pr = _corners(untilted, n_views=4)
    from measurement.calibration.io import save_calibration
    save_calibration(calibrate_stereo(pl, pr, BOARD_MM, (untilted.left.width, untilted.left.height),
                                      model="pinhole"), tmp_path / "stereo.json")
    with pytest.raises(FileFormatError, match=r"a stereo calibration: load it with load_calibration"):
        load_camera_calibration(tmp_path / "stereo.json")


def test_cli_calibrate_refuses_mixed_or_missing_image_options(tmp_path, capsys):
    out = tmp_path / "c.json"
    assert main(["calibrate", "--camera", "a*.png", "--left", "b*.png", "--out", str(out)]) == 2
    assert "--camera calibrates one camera: give its images with --camera only" in capsys.readouterr().err
    assert main(["calibrate", "--left", "b*.png", "--out", str(out)]) == 2
    assert "give --left and --right (a stereo pair) or --camera (one camera)" in capsys.readouterr().err


def test_cli_single_camera_model_auto_keeps_pinhole_on_the_real_left_camera(tmp_path, capsys):
    """One camera alone carries less evidence than the pair: the held-out errors of pinhole and rmm differ by less
    than their standard error at 6, 8 and 13 folds (pinhole kept; measured 0.0594 vs 0.0590 +- 0.0009 px^2 at 13),
    while 4 folds (3 views held out per fold) tip it to rmm. The default (8) is tested."""
    out = tmp_path / "left_auto.json"
    assert main(["calibrate", "--camera", str(REAL / "left*.jpg"), "--pattern", "9x6", "--square-mm", "1",
                 "--model", "auto", "--out", str(out)]) == 0
    doc = json.loads(out.read_text())
    rows = doc["model_selection"]["candidates"]
    assert [(r["model"], r["chosen"]) for r in rows] == [("pinhole", True), ("rmm", False)]
    assert doc["model"] == "pinhole" and doc["significance"] == {}
    assert "calibrated one camera (pinhole, lens brown4)" in capsys.readouterr().out
