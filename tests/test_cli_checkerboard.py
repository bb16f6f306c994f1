"""``workbench render checkerboard``: images + truth.json, and clear errors on bad input."""
import json
import subprocess
import sys

import cv2
import numpy as np
import pytest

from scenes.optics.projection import project_points
from workbench.cli import main
from workbench.experiments.calibration.views import sensor_spec_for
from workbench.rigs import get_rig


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    out = tmp_path_factory.mktemp("cb")
    assert main(["render", "checkerboard", "--rig", "paper", "--views", "2", "--seed", "3", "--scale", "0.2",
                 "--spp", "4", "--out", str(out)]) == 0
    return out, json.loads((out / "truth.json").read_text())


def test_truth_json_describes_every_image(dataset):
    """Every image is listed with the rig's intrinsics; its truth pixels are where the *renderer's* projection
    (scenes.optics.projection.project_points: its own distortion and tilted-sensor code, the camera as rendered) puts the
    corners, not merely where the model that wrote them does."""
    out, truth = dataset
    rig = get_rig("paper", 0.2)
    assert len(truth["images"]) == 4
    assert {im["camera"] for im in truth["images"]} == {"left", "right"}
    for im in truth["images"]:
        image = cv2.imread(str(out / im["file"]), cv2.IMREAD_UNCHANGED)
        intr = im["intrinsics"]
        assert image.dtype == np.uint8 and image.shape == (intr["height"], intr["width"])
        assert intr == rig.camera(im["camera"]).to_dict()
        pts, pix = np.array(im["points_cam_mm"]), np.array(im["pixels"])
        assert pts.shape == (88, 3) and pix.shape == (88, 2)
        rendered = project_points(sensor_spec_for(rig, im["camera"]), np.eye(3), np.zeros(3), pts)
        np.testing.assert_allclose(pix, rendered, rtol=0, atol=1e-6)
        assert np.all((pix > 0) & (pix < [intr["width"] - 1, intr["height"] - 1]))


def test_truth_pixels_are_where_opencv_finds_the_corners(dataset):
    """Independent of any camera model: OpenCV's detector on the rendered images finds the 88 inner corners at
    the truth pixels (at this scale, 4 spp, the detector itself errs by ~0.1 px; a wrong corner order, a flipped
    board or a model error of a fraction of a pixel would show)."""
    out, truth = dataset
    for im in truth["images"]:
        image = cv2.imread(str(out / im["file"]), cv2.IMREAD_GRAYSCALE)
        found, corners = cv2.findChessboardCornersSB(image, (11, 8), cv2.CALIB_CB_ACCURACY)
        assert found, im["file"]
        corners = corners.reshape(-1, 2).astype(float)
        pix = np.array(im["pixels"])
        if np.linalg.norm(corners[0] - pix[0]) > np.linalg.norm(corners[-1] - pix[0]):
            corners = corners[::-1]          # OpenCV may start from the opposite corner
        error = np.linalg.norm(corners - pix, axis=1)
        assert np.sqrt(np.mean(error ** 2)) < 0.25 and error.max() < 0.5, (im["file"], error.max())


def test_truth_is_consistent_between_cameras(dataset):
    _, truth = dataset
    R = np.array(truth["rig"]["R_right_from_left"])
    T = np.array(truth["rig"]["T_right_from_left_mm"])
    by_view = {}
    for im in truth["images"]:
        by_view.setdefault(im["view"], {})[im["camera"]] = np.array(im["points_cam_mm"])
    for pair in by_view.values():
        assert np.allclose(pair["left"] @ R.T + T, pair["right"], atol=1e-9)


def test_board_is_where_truth_says(dataset):
    """The printed pattern sits where the truth says: the centre of the square between corners 0, 1, 11 and 12
    (and every square with even row + column) is dark, the others light (a flipped texture or swapped
    camera would fail)."""
    out, truth = dataset
    for im in truth["images"]:
        image = cv2.imread(str(out / im["file"]), cv2.IMREAD_GRAYSCALE).astype(float)
        pix = np.array(im["pixels"]).reshape(8, 11, 2)
        centres_dark = 0.25 * (pix[:-1, :-1] + pix[1:, :-1] + pix[:-1, 1:] + pix[1:, 1:])
        values = image[np.rint(centres_dark[..., 1]).astype(int), np.rint(centres_dark[..., 0]).astype(int)]
        parity = (np.add.outer(np.arange(7), np.arange(10)) % 2) == 0   # (row + col) even -> dark
        assert values[parity].mean() < 80 and values[~parity].mean() > 170


def test_same_seed_same_images(tmp_path):
    a, b = tmp_path / "a", tmp_path / "b"
    for d in (a, b):
        assert main(["render", "checkerboard", "--views", "1", "--seed", "5", "--scale", "0.1", "--spp", "2",
                     "--noise-grey", "1", "--out", str(d)]) == 0
    for name in ("left_000.png", "right_000.png"):
        assert np.array_equal(cv2.imread(str(a / name)), cv2.imread(str(b / name)))


@pytest.mark.parametrize("args, message", [
    (["--rig", "nonexistent"], "unknown rig 'nonexistent'"),
])
def test_bad_input_gives_clear_error(tmp_path, capsys, args, message):
    code = main(["render", "checkerboard", "--views", "1", "--scale", "0.1", "--out", str(tmp_path)] + args)
    assert code == 2
    assert message in capsys.readouterr().err


@pytest.mark.parametrize("args", [["--scale", "0"], ["--scale", "-1"], ["--views", "0"], ["--spp", "0"]])
def test_bad_numbers_rejected_by_parser(tmp_path, args):
    proc = subprocess.run([sys.executable, "-m", "workbench.cli", "render", "checkerboard", "--out", str(tmp_path)]
                          + args, capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2
    assert "Traceback" not in proc.stderr and "error" in proc.stderr
