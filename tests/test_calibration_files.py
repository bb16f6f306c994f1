"""Calibration files and the ``workbench calibrate`` command on image files, including bad input."""
import contextlib
import json
import shutil

import cv2
import numpy as np
import pytest

from measurement.calibration.io import CalibratedRig, export_opencv_yaml, load_calibration, save_calibration
from measurement.calibration.stepwise import calibrate_stereo
from measurement.calibration.detection import board_points_mm
from workbench.cli import main


@pytest.fixture(scope="module")
def synthetic_calibration():
    from scenes.targets import Checkerboard
    from workbench.experiments.checkerboard_views import board_outline_mm
    from workbench.poses import random_board_poses
    from workbench.rigs import paper_rig

    rig = paper_rig(0.5)
    obj = board_points_mm((11, 8), 5.0)
    poses = random_board_poses(rig, board_outline_mm(Checkerboard()), 6, seed=2)
    R, T = rig.pose("right")
    rng = np.random.default_rng(0)
    pl = np.array([rig.left.project(obj @ Rw.T + tw) for Rw, tw in poses]) + rng.normal(0, 0.02, (6, 88, 2))
    pr = np.array([rig.right.project((obj @ Rw.T + tw) @ R.T + T) for Rw, tw in poses]) + rng.normal(0, 0.02, (6, 88, 2))
    return calibrate_stereo(pl, pr, obj, (rig.left.width, rig.left.height), tilt_guess_left_deg=(0, -4),
                            tilt_guess_right_deg=(0, 4), joint=False)


@pytest.mark.parametrize("suffix", [".json", ".yaml"])
def test_file_round_trip_gives_identical_projections(synthetic_calibration, tmp_path, suffix):
    cal = synthetic_calibration
    path = tmp_path / f"calib{suffix}"
    if suffix == ".json":
        save_calibration(cal, path)
        d = json.loads(path.read_text())
        assert "X_right = R_right_from_left @ X_left + T_right_from_left_mm" in d["convention"]
        assert set(d["left"]["intrinsics"]) == {"fx", "fy", "cx", "cy", "alpha_deg", "beta_deg", "k1", "k2", "p1", "p2"}
        assert d["left"]["sigma"]["fx"] > 0
    else:
        export_opencv_yaml(cal, path)
        fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)     # readable by OpenCV itself
        assert fs.getNode("K1").mat().shape == (3, 3) and fs.getNode("D1").mat().shape == (1, 14)
        fs.release()
    rig = load_calibration(path)
    assert isinstance(rig, CalibratedRig)
    X = np.random.default_rng(1).uniform([-20, -15, 320], [20, 15, 380], (500, 3))
    for loaded, original in ((rig.left, cal.left.camera), (rig.right, cal.right.camera)):
        assert np.array_equal(loaded.project(X), original.project(X))
    assert np.array_equal(rig.R_right_from_left, cal.R_right_from_left)
    assert np.array_equal(rig.T_right_from_left_mm, cal.T_right_from_left_mm)


def test_bad_calibration_files(tmp_path):
    with pytest.raises(ValueError, match="does not exist"):
        load_calibration(tmp_path / "missing.json")
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    with pytest.raises(ValueError, match="not valid JSON"):
        load_calibration(bad)
    bad.write_text('{"format": "something else"}')
    with pytest.raises(ValueError, match="unknown format"):
        load_calibration(bad)


@pytest.fixture(scope="module")
def rendered_views(tmp_path_factory):
    """Eight noisy stereo views at a fifth of full resolution, rendered once for the CLI tests."""
    out = tmp_path_factory.mktemp("views")
    assert main(["render", "checkerboard", "--views", "8", "--seed", "1", "--scale", "0.25", "--spp", "16",
                 "--noise-grey", "1", "--out", str(out)]) == 0
    return out


def test_calibrate_command_on_image_files(rendered_views, tmp_path):
    out = tmp_path / "calib.json"
    assert main(["calibrate", "--left", str(rendered_views / "left_*.png"), "--right",
                 str(rendered_views / "right_*.png"), "--square-mm", "5", "--pattern", "11x8",
                 "--tilt-guess-deg", "0,-4", "--out", str(out)]) == 0
    d = json.loads(out.read_text())
    # 1 grey level of noise on 36 px squares: the detector's error is ~0.035 px, so RMS well below 0.1 px.
    assert d["reprojection_rms_px"]["left"] < 0.1 and d["reprojection_rms_px"]["right"] < 0.1
    assert out.with_suffix(".yaml").is_file()
    assert len(d["images"]["left"]) == 8


def test_view_without_board_is_dropped_with_warning(rendered_views, tmp_path):
    views = tmp_path / "v"
    shutil.copytree(rendered_views, views)
    blank = np.full((514, 614), 128, np.uint8)
    cv2.imwrite(str(views / "right_003.png"), blank)
    with pytest.warns(UserWarning, match="board not found in .*right_003.png"):
        code = main(["calibrate", "--left", str(views / "left_*.png"), "--right", str(views / "right_*.png"),
                     "--no-joint", "--out", str(tmp_path / "c.json")])
    assert code == 0
    d = json.loads((tmp_path / "c.json").read_text())
    assert len(d["images"]["left"]) == 7 and any("right_003.png" in f for f in d["images"]["dropped"])


@pytest.mark.parametrize("case, message", [
    ("no_match", "no images match --left"),
    ("count", "7 left images but 8 right images"),
    ("size", "all images must have one size"),
    ("too_few", "at least 3 are needed"),
    ("unreadable", "cannot read image"),
])
def test_calibrate_bad_input(rendered_views, tmp_path, capsys, case, message):
    views = tmp_path / "v"
    shutil.copytree(rendered_views, views)
    left, right = str(views / "left_*.png"), str(views / "right_*.png")
    if case == "no_match":
        left = str(views / "nothing_*.png")
    elif case == "count":
        (views / "left_007.png").unlink()
    elif case == "size":
        img = cv2.imread(str(views / "right_002.png"))
        cv2.imwrite(str(views / "right_002.png"), img[:-10])
    elif case == "too_few":
        for k in range(2, 8):
            cv2.imwrite(str(views / f"left_{k:03d}.png"), np.full((514, 614), 128, np.uint8))
    elif case == "unreadable":
        (views / "left_004.png").write_bytes(b"not an image")
    with pytest.warns(UserWarning) if case == "too_few" else contextlib.nullcontext():
        code = main(["calibrate", "--left", left, "--right", right, "--out", str(tmp_path / "c.json")])
    assert code == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err


def test_fronto_parallel_views_give_clear_error():
    from measurement.calibration.stepwise import CalibrationError, calibrate_camera
    from workbench.rigs import paper_rig

    cam = paper_rig(0.5).left
    obj = board_points_mm((11, 8), 5.0)
    pts = np.array([cam.project(obj + [dx, dy, 340.0]) for dx, dy in ((-25, -17), (-20, -15), (-28, -20), (-22, -12))])
    with pytest.raises(CalibrationError, match="fronto-parallel"):
        calibrate_camera(pts, obj, (cam.width, cam.height))
