"""Calibration files and the ``workbench calibrate`` command on image files, including bad input.

The loaders validate every key (:mod:`labio.schema`): each defect of issue 10 class 1 has a rejection test
below that names the file and the key; the writers are atomic and refuse to write a file that would not load.
Property-based fuzzing of the same loaders: ``tests/test_fuzz_calibration_loaders.py``.
"""
import contextlib
import dataclasses
import errno
import json
import os
import re
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest

from measurement.calibration.io import (CalibratedRig, export_opencv_yaml, load_calibration, load_opencv_yaml,
                                        save_calibration)
from measurement.calibration.stepwise import MODELS, calibrate_stereo
from labio.schema import FileFormatError
from measurement.calibration.detection import board_points_mm
from workbench.cli import main


@pytest.fixture(scope="module")
def synthetic_calibration():
    from scenes.surfaces.checkerboard import Checkerboard
    from workbench.experiments.calibration.views import board_outline_mm
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


# ------------------------------------------------------------------------------------------------------------
# Issue 10, class 1: every defect of a calibration file is a FileFormatError naming the file and the key
# ------------------------------------------------------------------------------------------------------------
def _with_model(cal, model: str):
    """``cal`` relabelled as ``model`` with cameras that model can describe (pinhole: no tilt)."""
    tilt_model = {"rmm": "rmm", "opencv-tilt": "opencv", "pinhole": "rmm"}[model]

    def cam(c):
        changes = {"tilt_model": tilt_model}
        if model == "pinhole":
            changes.update(alpha_deg=0.0, beta_deg=0.0)
        return dataclasses.replace(c, camera=dataclasses.replace(c.camera, **changes))

    return dataclasses.replace(cal, model=model, left=cam(cal.left), right=cam(cal.right))


@pytest.mark.parametrize("model", MODELS)
@pytest.mark.parametrize("suffix", [".json", ".yaml"])
def test_round_trip_of_every_model_gives_the_identical_rig(synthetic_calibration, tmp_path, model, suffix):
    cal = _with_model(synthetic_calibration, model)
    path = tmp_path / f"calib{suffix}"
    (save_calibration if suffix == ".json" else export_opencv_yaml)(cal, path)
    rig = load_calibration(path)
    assert rig.model == model
    assert rig.left == cal.left.camera and rig.right == cal.right.camera        # every field, exactly
    assert np.array_equal(rig.R_right_from_left, cal.R_right_from_left)
    assert np.array_equal(rig.T_right_from_left_mm, cal.T_right_from_left_mm)
    assert rig.T_right_from_left_mm.shape == (3,)
    # and the exported YAML of the loaded rig is the same text (nothing lost on the way)
    if suffix == ".yaml":
        again = tmp_path / "again.yaml"
        export_opencv_yaml(rig, again)
        assert again.read_text() == path.read_text()


REPO = Path(__file__).resolve().parents[1]


@pytest.mark.parametrize("path", sorted(str(p.relative_to(REPO)) for p in REPO.glob("reports/*/calibration*.json")))
def test_committed_calibration_files_pass_the_validation(path):
    """The calibrations in reports/ (YAML written by an older OpenCV) load, JSON and YAML giving the same rig."""
    rig = load_calibration(REPO / path)
    twin = load_opencv_yaml((REPO / path).with_suffix(".yaml"))
    assert rig == dataclasses.replace(twin, R_right_from_left=rig.R_right_from_left,
                                      T_right_from_left_mm=rig.T_right_from_left_mm)
    assert np.array_equal(rig.R_right_from_left, twin.R_right_from_left)
    assert np.array_equal(rig.T_right_from_left_mm, twin.T_right_from_left_mm)


@pytest.fixture(scope="module")
def valid_yaml(synthetic_calibration, tmp_path_factory) -> str:
    path = tmp_path_factory.mktemp("yaml") / "calib.yaml"
    export_opencv_yaml(synthetic_calibration, path)
    return path.read_text()


def _yaml_scalar(text: str, key: str, value: str | None) -> str:
    """``text`` with the top-level scalar ``key`` set to ``value`` (None: the line removed)."""
    pattern = re.compile(rf"^{re.escape(key)}: .*\n", re.M)
    assert len(pattern.findall(text)) == 1, key
    return pattern.sub("" if value is None else f"{key}: {value}\n", text)


def _yaml_matrix(text: str, key: str, data: list | None) -> str:
    """``text`` with the data of matrix ``key`` replaced (None: the whole matrix removed)."""
    pattern = re.compile(rf"^{re.escape(key)}: !!opencv-matrix\n(   .*\n|       .*\n)+", re.M)
    match = pattern.search(text)
    assert match, key
    if data is None:
        return text[:match.start()] + text[match.end():]
    block = re.sub(r"data: \[[^\]]*\]", "data: [ " + ", ".join(map(repr, data)) + " ]", match.group(0))
    return text[:match.start()] + block + text[match.end():]


def _rotation_z(deg):
    c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
    return [c, -s, 0.0, s, c, 0.0, 0.0, 0.0, 1.0]


YAML_DEFECTS = {
    # the defects named in the issue
    "missing left_k1 (was read as k1 = 0)": (lambda t: _yaml_scalar(t, "left_k1", None),
                                             r"key 'left_k1': required key is missing"),
    "text value (was read as 1.8e308)": (lambda t: _yaml_scalar(t, "left_k1", "abc"),
                                         r"key 'left_k1': must be a number, got a string \('abc'\)"),
    "0-byte file (was a SystemError)": (lambda t: "", r"calibration file is empty"),
    "garbage (was a SystemError)": (lambda t: "this is not yaml at all", r"is not an OpenCV FileStorage YAML file"),
    "fx = 1e300": (lambda t: _yaml_scalar(t, "left_fx", "1e300"), r"key 'left_fx': must be in \(0, 1e\+06\) px"),
    "NaN": (lambda t: _yaml_scalar(t, "right_fy", ".nan"), r"key 'right_fy': must be a finite number, got nan"),
    "infinity": (lambda t: _yaml_scalar(t, "right_cx", "-.inf"), r"key 'right_cx': must be a finite number"),
    # the rest of the schema
    "binary bytes": (lambda t: "\x00\x01\x02 calib", r"calibration file contains NUL bytes: it is not a text file"),
    "truncated": (lambda t: t[:len(t) // 2], r"(is not an OpenCV|key ')"),
    "top level a sequence": (lambda t: "%YAML:1.0\n---\n- 1\n- 2\n", r"the file's top level must be a mapping \(JSON object / YAML map\), got a list of 2"),
    "missing format": (lambda t: _yaml_scalar(t, "format", None), r"key 'format': required key is missing"),
    "other format": (lambda t: _yaml_scalar(t, "format", "something/2"), r"key 'format': unknown format 'something/2'"),
    "unknown model": (lambda t: _yaml_scalar(t, "model", "fisheye"), r"key 'model': must be one of 'rmm'"),
    "numeric model": (lambda t: _yaml_scalar(t, "model", "3"), r"key 'model': must be a string, got a number"),
    "missing tilt model": (lambda t: _yaml_scalar(t, "left_tilt_model", None),
                           r"key 'left_tilt_model': required key is missing"),
    "tilt model contradicting model": (lambda t: _yaml_scalar(t, "left_tilt_model", "opencv"),
                                       r"key 'left_tilt_model': tilt model 'opencv' contradicts the file's model"),
    "tilt beyond the model's range": (lambda t: _yaml_scalar(t, "left_beta_deg", "-50.0"),
                                      r"key 'left_beta_deg': must be in \(-45, 45\) deg"),
    "distortion out of range": (lambda t: _yaml_scalar(t, "right_k2", "5000.0"), r"key 'right_k2': must be in \(-1000, 1000\)"),
    "negative focal length": (lambda t: _yaml_scalar(t, "left_fx", "-10.0"), r"key 'left_fx': must be in \(0, 1e\+06\) px"),
    "image width zero": (lambda t: _yaml_scalar(t, "image_width", "0"), r"key 'image_width': must be an integer in \[1, "),
    "image width fractional": (lambda t: _yaml_scalar(t, "image_width", "1228.5"),
                               r"key 'image_width': must be an integer, got a number \(1228.5\)"),
    "missing image height": (lambda t: _yaml_scalar(t, "image_height", None), r"key 'image_height': required key is missing"),
    "missing R": (lambda t: _yaml_matrix(t, "R", None), r"key 'R': required key is missing"),
    "R not a rotation": (lambda t: _yaml_matrix(t, "R", [1.0, 0, 0, 0, 1, 0, 0, 0, 1.01]), r"key 'R': must be a rotation"),
    "R a reflection": (lambda t: _yaml_matrix(t, "R", [1.0, 0, 0, 0, 1, 0, 0, 0, -1]), r"key 'R': must be a proper rotation"),
    "R with a text entry": (lambda t: _yaml_matrix(t, "R", ["x"] + _rotation_z(3)[1:]),
                            r"key 'R.data\[0\]': must be a number, got a string \('x'\)"),
    "T zero": (lambda t: _yaml_matrix(t, "T", [0.0, 0.0, 0.0]), r"key 'T': the stereo translation's length must be in \(0, "),
    "T too short": (lambda t: _yaml_matrix(t, "T", [1.0, 2.0]), r"key 'T.data': must be a list of 3 entries, got 2"),
    "K1 edited alone": (lambda t: _yaml_matrix(t, "K1", [9000.0, 0, 600, 0, 9000, 500, 0, 0, 1]),
                        r"key 'K1': disagrees with the left_\* parameters"),
    "D2 with a k3": (lambda t: _yaml_matrix(t, "D2", [0.0] * 4 + [0.5] + [0.0] * 9), r"key 'D2': disagrees"),
}


@pytest.mark.parametrize("case", list(YAML_DEFECTS))
def test_yaml_defects_are_refused_naming_file_and_key(valid_yaml, tmp_path, case):
    edit, message = YAML_DEFECTS[case]
    path = tmp_path / "calib.yaml"
    path.write_text(edit(valid_yaml))
    with pytest.raises(FileFormatError, match=re.escape(str(path)) + ": " + message):
        load_calibration(path)


def test_yaml_defect_tests_start_from_a_valid_file(valid_yaml, tmp_path):
    path = tmp_path / "calib.yaml"
    path.write_text(valid_yaml)
    assert load_opencv_yaml(path).model == "rmm"


@pytest.fixture(scope="module")
def valid_json(synthetic_calibration, tmp_path_factory) -> dict:
    path = tmp_path_factory.mktemp("json") / "calib.json"
    save_calibration(synthetic_calibration, path)
    return json.loads(path.read_text())


def _edit(d: dict, key: str, value=...):
    """``d`` (a copy) with the dotted ``key`` set to ``value`` (``...``: removed)."""
    d = json.loads(json.dumps(d))
    *parents, last = key.split(".")
    node = d
    for k in parents:
        node = node[int(k)] if isinstance(node, list) else node[k]
    if value is ...:
        del node[last]
    elif isinstance(node, list):
        node[int(last)] = value
    else:
        node[last] = value
    return d


JSON_DEFECTS = {
    # the defects named in the issue (KeyError / AttributeError tracebacks before; fx = 1e300 accepted)
    "top level a list": (lambda d: [d], r"the file's top level must be a mapping \(JSON object / YAML map\), got a list"),
    "top level null": (lambda d: None, r"the file's top level must be a mapping .*, got null"),
    "missing stereo": (lambda d: _edit(d, "stereo"), r"key 'stereo': required key is missing"),
    "fx = 1e300": (lambda d: _edit(d, "left.intrinsics.fx", 1e300), r"key 'left.intrinsics.fx': must be in \(0, 1e\+06\) px"),
    "NaN": (lambda d: _edit(d, "left.intrinsics.k1", float("nan")), r"key 'left.intrinsics.k1': must be a finite number, got nan"),
    "string number": (lambda d: _edit(d, "right.intrinsics.fx", "5000"),
                      r"key 'right.intrinsics.fx': must be a number, got a string \('5000'\)"),
    # wrong nested types
    "stereo a list": (lambda d: _edit(d, "stereo", [1, 2]), r"key 'stereo': it must be a mapping"),
    "left a string": (lambda d: _edit(d, "left", "camera"), r"key 'left': it must be a mapping"),
    "intrinsics null": (lambda d: _edit(d, "left.intrinsics", None), r"key 'left.intrinsics': it must be a mapping .*got null"),
    "boolean number": (lambda d: _edit(d, "left.intrinsics.cx", True), r"key 'left.intrinsics.cx': must be a number, got a boolean"),
    "huge integer": (lambda d: _edit(d, "left.intrinsics.cy", 10 ** 400),
                     r"key 'left.intrinsics.cy': must be a finite number, got an integer beyond"),
    # the rest of the schema
    "missing fx": (lambda d: _edit(d, "left.intrinsics.fx"), r"key 'left.intrinsics.fx': required key is missing"),
    "unknown intrinsic": (lambda d: _edit(d, "left.intrinsics.k3", 0.1), r"key 'left.intrinsics': unknown key\(s\) 'k3'"),
    "missing format": (lambda d: _edit(d, "format"), r"key 'format': required key is missing"),
    "unknown model": (lambda d: _edit(d, "model", "fisheye"), r"key 'model': must be one of"),
    "missing tilt model": (lambda d: _edit(d, "right.tilt_model"), r"key 'right.tilt_model': required key is missing"),
    "pinhole with a tilt": (lambda d: _edit(d, "model", "pinhole"), r"key 'left.intrinsics.alpha_deg': must be 0 for"),
    "tilt beyond the model's range": (lambda d: _edit(d, "right.intrinsics.beta_deg", 45.0),
                                      r"key 'right.intrinsics.beta_deg': must be in \(-45, 45\) deg"),
    "width zero": (lambda d: _edit(d, "left.width", 0), r"key 'left.width': must be an integer in \[1, 1000000\], got 0"),
    "width a string": (lambda d: _edit(d, "left.width", "1228"), r"key 'left.width': must be an integer, got a string"),
    "width fractional": (lambda d: _edit(d, "right.height", 1029.5), r"key 'right.height': must be an integer"),
    "image size disagreeing": (lambda d: _edit(d, "image_size_px", [100, 100]), r"key 'image_size_px': 100 x 100 disagrees"),
    "R not 3 x 3": (lambda d: _edit(d, "stereo.R_right_from_left", [[1, 0, 0], [0, 1, 0]]),
                    r"key 'stereo.R_right_from_left': must be a list of 3 entries, got 2"),
    "R with a string": (lambda d: _edit(d, "stereo.R_right_from_left.1", [0, "1", 0]),
                        r"key 'stereo.R_right_from_left\[1\]\[1\]': must be a number, got a string"),
    "R not a rotation": (lambda d: _edit(d, "stereo.R_right_from_left", [[1, 0, 0], [0, 1, 0], [0, 0, 1.01]]),
                         r"key 'stereo.R_right_from_left': must be a rotation matrix"),
    "R a reflection": (lambda d: _edit(d, "stereo.R_right_from_left", [[-1, 0, 0], [0, 1, 0], [0, 0, 1]]),
                       r"key 'stereo.R_right_from_left': must be a proper rotation"),
    "rvec disagreeing with R": (lambda d: _edit(d, "stereo.rvec_right_from_left", [0.0, 0.1, 0.0]),
                                r"key 'stereo.rvec_right_from_left': disagrees with R_right_from_left"),
    "T zero": (lambda d: _edit(d, "stereo.T_right_from_left_mm", [0, 0, 0]),
               r"key 'stereo.T_right_from_left_mm': the stereo translation's length must be in \(0, 1e\+06\) mm"),
    "T infinite": (lambda d: _edit(d, "stereo.T_right_from_left_mm.0", float("inf")),
                   r"key 'stereo.T_right_from_left_mm\[0\]': must be a finite number, got inf"),
    "T missing": (lambda d: _edit(d, "stereo.T_right_from_left_mm"), r"key 'stereo.T_right_from_left_mm': required key"),
}


@pytest.mark.parametrize("case", list(JSON_DEFECTS))
def test_json_defects_are_refused_naming_file_and_key(valid_json, tmp_path, case):
    edit, message = JSON_DEFECTS[case]
    path = tmp_path / "calib.json"
    path.write_text(json.dumps(edit(valid_json)))
    with pytest.raises(FileFormatError, match=re.escape(str(path)) + ": " + message):
        load_calibration(path)


def test_json_defect_tests_start_from_a_valid_file(valid_json, tmp_path):
    path = tmp_path / "calib.json"
    path.write_text(json.dumps(valid_json))
    assert load_calibration(path).model == "rmm"


@pytest.mark.parametrize("content, message", [
    (b"", r"calibration file is empty"),
    (b"  \n", r"calibration file is empty"),
    (b"\xff\xfe{}", r"calibration file is not UTF-8 text \(byte 0\)"),
    (b"{\"format\": 1" + b"[" * 100_000, r"is not (valid JSON|a usable JSON file)"),
    (b"1" * 5000, r"is not a usable JSON file: .*digits"),
])
def test_unreadable_json_is_refused_naming_the_file(tmp_path, content, message):
    path = tmp_path / "calib.json"
    path.write_bytes(content)
    with pytest.raises(FileFormatError, match=re.escape(str(path)) + ": " + message):
        load_calibration(path)


def test_deeply_nested_json_is_refused_naming_the_file(tmp_path):
    path = tmp_path / "calib.json"
    path.write_text('{"format": ' + "[" * 100_000)
    with pytest.raises(FileFormatError, match=re.escape(str(path)) + ": is not a usable JSON file: nested too deeply"):
        load_calibration(path)


@pytest.mark.parametrize("text, message", [
    ("a: " + "[" * 100_000, r"has 100001 of the characters '\[\{-:\?' \(more than 10000\): too deeply nested"),
    ("a:\n  " + "- " * 60_000 + "1\n", r"has 60001 of the characters"),
    ("a: 1\n" + "#" * (1 << 20), r"calibration file is 1048581 bytes, more than the 1048576"),
], ids=["deep flow", "deep block", "huge file"])   # the 1 MB text as a test id would reach the subprocess's environment
def test_yaml_that_would_crash_opencv_is_refused_before_parsing(tmp_path, text, message):
    """OpenCV's YAML parser overflows its stack (SIGSEGV) on ~20 000+ nesting levels: refused before it runs.

    Run in a subprocess, so that a regression shows as a failure and not as a crashed test session.
    """
    import subprocess
    import sys

    path = tmp_path / "calib.yaml"
    path.write_text(text)
    code = ("import sys\nfrom measurement.calibration.io import load_opencv_yaml\nfrom labio.schema import "
            "FileFormatError\ntry:\n    load_opencv_yaml(sys.argv[1])\nexcept FileFormatError as err:\n"
            "    print(err)\n")
    run = subprocess.run([sys.executable, "-c", code, str(path)], capture_output=True, text=True, timeout=120,
                         cwd=REPO)
    assert run.returncode == 0, f"the loader crashed (exit {run.returncode}): {run.stderr[-500:]}"
    assert re.match(re.escape(str(path)) + ": " + message, run.stdout), run.stdout


def test_a_folder_is_not_a_calibration_file(tmp_path):
    with pytest.raises(FileFormatError, match=re.escape(str(tmp_path)) + ": calibration file is not a regular file"):
        load_calibration(tmp_path)


# --- the writers: atomic, and never a file that would not load ----------------------------------------------
@pytest.mark.parametrize("suffix", [".json", ".yaml"])
def test_writers_keep_the_old_file_when_the_disk_is_full(synthetic_calibration, tmp_path, monkeypatch, suffix):
    """A write error (ENOSPC at fsync) names the file and leaves the previous file whole, no temporary file."""
    path = tmp_path / f"calib{suffix}"
    path.write_text("previous content")

    def full_disk(fd):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(os, "fsync", full_disk)
    write = save_calibration if suffix == ".json" else export_opencv_yaml
    with pytest.raises(OSError, match=re.escape(f"cannot write {path}") + ": No space left on device"):
        write(synthetic_calibration, path)
    assert path.read_text() == "previous content"
    assert [p.name for p in tmp_path.iterdir()] == [path.name]


@pytest.mark.parametrize("suffix", [".json", ".yaml"])
def test_writers_refuse_a_calibration_the_loader_would_refuse(synthetic_calibration, tmp_path, suffix):
    bad = dataclasses.replace(synthetic_calibration, left=dataclasses.replace(
        synthetic_calibration.left, camera=dataclasses.replace(synthetic_calibration.left.camera, k1=5000.0)))
    path = tmp_path / f"calib{suffix}"
    write = save_calibration if suffix == ".json" else export_opencv_yaml
    key = "left.intrinsics.k1" if suffix == ".json" else "left_k1"
    with pytest.raises(FileFormatError, match=re.escape(f"{path}: key '{key}': must be in (-1000, 1000)")
                       + r".*refusing to write a file that would not load; nothing written"):
        write(bad, path)
    assert not path.exists() and list(tmp_path.iterdir()) == []


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


def test_boards_detected_on_threads_come_back_in_file_order_as_detected_one_by_one(rendered_views):
    """detect_pairs / detect_views detect on all cores; each view's corners are the detector's on that file alone
    (read and detected here one by one), in the order the files were given (a reversed list stays reversed)."""
    from measurement.calibration.detection import detect_checkerboard
    from measurement.calibration.images import detect_pairs, detect_views
    from measurement.image_io import read_grey

    left = sorted(str(p) for p in rendered_views.glob("left_*.png"))[::-1]
    right = sorted(str(p) for p in rendered_views.glob("right_*.png"))[::-1]
    pairs = detect_pairs(left, right, progress=False)
    views = detect_views(right, progress=False)
    assert pairs.left_files == left and views.files == right
    for k, (fl, fr) in enumerate(zip(left, right)):
        assert np.array_equal(pairs.points_left[k], detect_checkerboard(read_grey(fl), (11, 8)))
        assert np.array_equal(pairs.points_right[k], detect_checkerboard(read_grey(fr), (11, 8)))
        assert np.array_equal(views.points[k], pairs.points_right[k])


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


def _write_plain_opencv_yaml(path, K1, D1, K2, D2, R, T, size, size_keys=("image_width", "image_height")):
    """A stereo calibration as a cv2.stereoCalibrate script writes it (cv2.FileStorage, OpenCV's own writer)."""
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    if size_keys == "imageSize":
        fs.write("imageSize", np.array(size, dtype=np.int32).reshape(1, 2))
    else:
        fs.write(size_keys[0], int(size[0]))
        fs.write(size_keys[1], int(size[1]))
    for key, value in (("K1", K1), ("D1", D1), ("K2", K2), ("D2", D2), ("R", R), ("T", T)):
        fs.write(key, np.asarray(value, dtype=np.float64))
    fs.release()


def test_a_plain_opencv_stereo_yaml_loads_and_projects_as_opencv_does(tmp_path):
    """K1 D1 K2 D2 R T + image size, written by cv2.FileStorage: every camera reprojects within 1e-6 px of
    cv2.projectPoints with the file's own K, D, R, T (OpenCV is the reference)."""
    K1 = np.array([[2400.0, 0, 1210.5], [0, 2395.0, 1020.25], [0, 0, 1]])
    K2 = np.array([[2380.0, 0, 1190.0], [0, 2390.5, 1031.0], [0, 0, 1]])
    D1 = np.array([[-0.12, 0.08, 0.0011, -0.0007, 0.0]])           # OpenCV's 5-term vector, k3 = 0
    D2 = np.array([[-0.10, 0.05, -0.0004, 0.0009]])
    R = cv2.Rodrigues(np.array([0.01, 0.38, -0.02]))[0]
    T = np.array([[-140.0], [1.5], [28.0]])
    _write_plain_opencv_yaml(tmp_path / "stereo.yaml", K1, D1, K2, D2, R, T, (2448, 2048))
    rig = load_opencv_yaml(tmp_path / "stereo.yaml")
    assert (rig.left.width, rig.left.height) == (2448, 2048)
    rng = np.random.default_rng(3)
    X = np.column_stack([rng.uniform(-60, 60, 200), rng.uniform(-40, 40, 200), rng.uniform(350, 420, 200)])
    ref_l = cv2.projectPoints(X, np.zeros(3), np.zeros(3), K1, D1)[0].reshape(-1, 2)
    ref_r = cv2.projectPoints(X, cv2.Rodrigues(R)[0], T, K2, D2)[0].reshape(-1, 2)
    assert np.max(np.abs(rig.left.project(X) - ref_l)) < 1e-6
    assert np.max(np.abs(rig.right.project(X @ rig.R_right_from_left.T + rig.T_right_from_left_mm.ravel()) - ref_r)) < 1e-6
    _write_plain_opencv_yaml(tmp_path / "size.yaml", K1, D1, K2, D2, cv2.Rodrigues(R)[0], T, (2448, 2048),
                             size_keys="imageSize")                 # imageSize and a rotation vector R
    other = load_opencv_yaml(tmp_path / "size.yaml")
    np.testing.assert_allclose(other.R_right_from_left, R, atol=1e-12)


def test_a_plain_opencv_yaml_with_terms_the_model_lacks_is_refused_with_their_cost(tmp_path):
    """k4 (OpenCV's rational model) is refused with the px it would cost at the image corners (computed here with
    OpenCV alone); k3 and a skew K[0][1] are held by the camera model and load."""
    K = np.array([[2400.0, 0, 1224.0], [0, 2400.0, 1024.0], [0, 0, 1]])
    R, T = np.eye(3), np.array([[-140.0], [0.0], [28.0]])
    D_k4 = np.array([[-0.1, 0.05, 0.0, 0.0, 0.3, 0.2, 0.0, 0.0]])
    _write_plain_opencv_yaml(tmp_path / "k4.yaml", K, D_k4, K, D_k4[:, :4], R, T, (2448, 2048))
    # the cost, computed here with OpenCV: the four corner pixels' rays projected with and without k4
    corners = np.array([[0.0, 0.0], [2447.0, 0.0], [0.0, 2047.0], [2447.0, 2047.0]])
    rays = np.column_stack([cv2.undistortPoints(corners[:, None], K, D_k4).reshape(-1, 2), np.ones(4)])
    without = D_k4.copy()
    without[0, 5] = 0.0
    cost = np.max(np.linalg.norm(cv2.projectPoints(rays, np.zeros(3), np.zeros(3), K, D_k4)[0].reshape(-1, 2)
                                 - cv2.projectPoints(rays, np.zeros(3), np.zeros(3), K, without)[0].reshape(-1, 2),
                                 axis=1))
    with pytest.raises(ValueError, match=rf"k4\.yaml.*D1.*has k4 = 0\.2: this instrument's lens model has k1, k2, "
                                         rf"p1, p2, k3, s1-s4 \(and tau_x, tau_y\) only; dropping the rest would "
                                         rf"move the "
                                         rf"image corners by up to {cost:.3g} px"):
        load_opencv_yaml(tmp_path / "k4.yaml")
    D_k3 = D_k4[:, :5]
    skewed = K.copy()
    skewed[0, 1] = 2.0
    _write_plain_opencv_yaml(tmp_path / "skew.yaml", skewed, D_k3, K, D_k3[:, :4], R, T, (2448, 2048))
    rig = load_opencv_yaml(tmp_path / "skew.yaml")
    assert rig.left.skew == 2.0 and rig.left.k3 == 0.3 and rig.right.k3 == 0.0
    # k3 loads as OpenCV applies it (cv2.projectPoints with the file's K without skew, D)
    X = np.array([[30.0, -20.0, 400.0], [-60.0, 45.0, 380.0]])
    ref = cv2.projectPoints(X, np.zeros(3), np.zeros(3), K, D_k3)[0].reshape(-1, 2)
    ours = rig.left.project(X)
    # the skew shifts u by skew * y_t: undo it with the tilted-plane y of the point, (v - cy) / fy
    np.testing.assert_allclose(ours[:, 0] - 2.0 * (ours[:, 1] - K[1, 2]) / K[1, 1], ref[:, 0], atol=1e-6)
    np.testing.assert_allclose(ours[:, 1], ref[:, 1], atol=1e-6)
    fs = cv2.FileStorage(str(tmp_path / "nosize.yaml"), cv2.FILE_STORAGE_WRITE)
    for key, value in (("K1", K), ("D1", D_k3[:, :4]), ("K2", K), ("D2", D_k3[:, :4]), ("R", R), ("T", T)):
        fs.write(key, value)
    fs.release()
    with pytest.raises(ValueError, match=r"nosize\.yaml.*has no image size: add image_width and image_height"):
        load_opencv_yaml(tmp_path / "nosize.yaml")


def test_calibration_convert_round_trips_and_states_what_opencv_k_and_d_cost(tmp_path, capsys):
    """plain OpenCV YAML -> JSON -> YAML: every converted camera reprojects within 1e-6 px of cv2.projectPoints
    with the source's K, D; an RMM camera tilted about one axis is exactly OpenCV's tilted model (K/D cost
    < 1e-6 px), one tilted about two axes is not, and the command says by how much."""
    from measurement.calibration.io import opencv_distortion_cost_px
    from measurement.camera import ScheimpflugCamera
    from workbench.cli import main

    K = np.array([[2400.0, 0, 1210.0], [0, 2395.0, 1020.0], [0, 0, 1]])
    D = np.array([[-0.12, 0.08, 0.001, -0.0007]])
    R, T = cv2.Rodrigues(np.array([0.0, 0.38, 0.0]))[0], np.array([[-140.0], [1.0], [28.0]])
    _write_plain_opencv_yaml(tmp_path / "plain.yaml", K, D, K, D, R, T, (2448, 2048))
    assert main(["calibration", "convert", str(tmp_path / "plain.yaml"), str(tmp_path / "rig.json")]) == 0
    assert main(["calibration", "convert", str(tmp_path / "rig.json"), str(tmp_path / "back.yaml")]) == 0
    printed = capsys.readouterr().out
    assert "reprojects within 0 px of the source" in printed and "projects it exactly" in printed
    X = np.column_stack([np.linspace(-50, 50, 30), np.linspace(-40, 40, 30), np.linspace(360, 420, 30)])
    reference = cv2.projectPoints(X, np.zeros(3), np.zeros(3), K, D)[0].reshape(-1, 2)
    for name in ("rig.json", "back.yaml"):
        assert np.max(np.abs(load_calibration(tmp_path / name).left.project(X) - reference)) < 1e-6
    one_axis = ScheimpflugCamera(fx=2400, fy=2400, cx=1224, cy=1024, alpha_deg=0.0, beta_deg=-4.5, k1=-0.1,
                                 width=2448, height=2048)
    two_axis = dataclasses.replace(one_axis, alpha_deg=0.6)
    assert opencv_distortion_cost_px(one_axis) < 1e-6 < 0.1 < opencv_distortion_cost_px(two_axis)
    assert main(["calibration", "convert", str(tmp_path / "rig.json"), str(tmp_path / "rig.txt")]) == 2
    assert "rig.txt: say the target format with --to (json, opencv, dice, vic3d, matchid)" in capsys.readouterr().err


def test_opencv_xml_files_load_and_convert_like_yaml(tmp_path, capsys):
    """The same calibration as OpenCV XML (cv2.FileStorage's other format): a plain K1 D1 K2 D2 R T file loads
    and projects as cv2.projectPoints (1e-6 px); a converted rig written as XML reads back exactly."""
    from workbench.cli import main

    K = np.array([[2400.0, 0, 1210.0], [0, 2395.0, 1020.0], [0, 0, 1]])
    D = np.array([[-0.12, 0.08, 0.001, -0.0007]])
    R, T = cv2.Rodrigues(np.array([0.0, 0.38, 0.0]))[0], np.array([[-140.0], [1.0], [28.0]])
    _write_plain_opencv_yaml(tmp_path / "plain.xml", K, D, K, D, R, T, (2448, 2048))
    assert (tmp_path / "plain.xml").read_text().lstrip().startswith("<?xml")
    X = np.column_stack([np.linspace(-50, 50, 30), np.linspace(-40, 40, 30), np.linspace(360, 420, 30)])
    reference = cv2.projectPoints(X, np.zeros(3), np.zeros(3), K, D)[0].reshape(-1, 2)
    assert np.max(np.abs(load_calibration(tmp_path / "plain.xml").left.project(X) - reference)) < 1e-6
    assert main(["calibration", "convert", str(tmp_path / "plain.xml"), str(tmp_path / "rig.json")]) == 0
    assert main(["calibration", "convert", str(tmp_path / "rig.json"), str(tmp_path / "ours.xml")]) == 0
    back = load_calibration(tmp_path / "ours.xml")
    assert np.max(np.abs(back.left.project(X) - reference)) < 1e-6
    (tmp_path / "broken.xml").write_text("<?xml version='1.0'?><opencv_storage><K1>")
    with pytest.raises(ValueError, match=r"broken\.xml.*OpenCV FileStorage"):
        load_calibration(tmp_path / "broken.xml")
