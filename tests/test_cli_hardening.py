"""Issue 10, classes 2-4: files written whole, dataset folders that never mix, stereo results the instrument
must not trust, and clear one-line errors (never a traceback) for bad options and inputs.

Each test names the defect it pins down; every one of them failed on the code before the fix.
"""
import csv
import errno
import json
import os
from types import SimpleNamespace

import cv2
import numpy as np
import pytest

from measurement.calibration.io import CalibratedRig, export_opencv_yaml
from measurement.dic import DICSettings, correlate
from measurement.stereo_dic import StereoQuality, StereoQualityError, check_stereo_quality
from scenes.sensor.noise import SensorNoise
from scenes.rendering.mitsuba import render_view
from scenes.specimens.plate import SpeckledPlate
from scenes.image_pairs.fourier_shift import fourier_shifted_pair
from workbench.cli import main
from workbench.experiments.calibration.views import sensor_spec_for
from workbench.manifest import MANIFEST_NAME, PENDING_NAME, complete_manifest
from workbench.rigs import paper_rig

RIG = paper_rig(0.25)
ROI = "150,120,450,360"


def _fail_fsync_for(monkeypatch, fragment: str) -> None:
    """A full disk for files whose (temporary) name contains ``fragment``: fsync raises ENOSPC."""
    real = os.fsync

    def fsync(fd):
        if fragment in os.readlink(f"/proc/self/fd/{fd}"):
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        return real(fd)

    monkeypatch.setattr(os, "fsync", fsync)


def _error_line(capsys) -> str:
    err = capsys.readouterr().err
    assert "Traceback" not in err
    lines = [line for line in err.strip().splitlines() if ": error: " in line]
    assert lines, err
    return lines[-1]


# ------------------------------------------------------------------------------------------------------------
# Stereo: a speckled plate at the rig's working distance, moved 1 mm up; the true rig as calibration file.
@pytest.fixture(scope="module")
def stereo(tmp_path_factory):
    folder = tmp_path_factory.mktemp("stereo")
    mm_per_px = 85.0 / RIG.left.width
    plate = SpeckledPlate(width_mm=70.0, height_mm=55.0, texel_mm=mm_per_px / 4, speckle_mm=4 * mm_per_px, seed=3)
    texture = plate.texture()
    axis_right = RIG.R_right_from_left.T @ np.array([0.0, 0.0, 1.0])
    z = np.array([0.0, 0.0, 1.0]) + axis_right
    z /= np.linalg.norm(z)
    x = np.array([1.0, 0.0, 0.0]) - z[0] * z
    x /= np.linalg.norm(x)
    R_world_from_plate, centre = np.column_stack([x, np.cross(z, x), z]), RIG.optical_axes_meeting_point_mm()
    noise = SensorNoise(read_noise_grey=1.0, bit_depth=8)
    for state, offset in (("ref", np.zeros(3)), ("def", np.array([0.0, -1.0, 0.0]))):
        surface = plate.surface(R_world_from_plate, centre + offset, texture)
        for k, side in enumerate(("left", "right")):
            image = render_view(sensor_spec_for(RIG, side), *RIG.pose(side), [surface], spp=16,
                                seed=10 * k + (state == "def")).image_grey
            image = noise.apply(image, seed=100 + 10 * k + (state == "def"))
            cv2.imwrite(str(folder / f"{side}_{state}.png"), np.clip(np.rint(image), 0, 255).astype(np.uint8))
    export_opencv_yaml(CalibratedRig("rmm", RIG.left, RIG.right, RIG.R_right_from_left, RIG.T_right_from_left_mm),
                       folder / "rig.yaml")
    return folder


def _stereo_args(folder, out, *, left_ref="left_ref.png", right_ref="right_ref.png", left="left_def.png",
                 right="right_def.png", extra=()):
    return ["stereo", "--calib", str(folder / "rig.yaml"), "--left-ref", str(folder / left_ref), "--right-ref",
            str(folder / right_ref), "--left", str(folder / left), "--right", str(folder / right), "--roi", ROI,
            "--subset", "33", "--step", "20", *extra, "--out", str(out)]


def test_stereo_writes_residual_statistics_per_state_and_a_manifest(stereo, tmp_path, capsys):
    out = tmp_path / "out"
    assert main(_stereo_args(stereo, out)) == 0
    printed = capsys.readouterr().out
    assert "reference: 180/180 points triangulated, median residual" in printed and "95th percentile" in printed
    with open(out / "summary.csv", newline="") as handle:
        rows = list(csv.DictReader(handle))
    assert [r["state"] for r in rows] == ["reference", "state_001"]
    for r in rows:
        assert r["result"] == "measured" and int(r["measured"]) == int(r["points"]) == 180
        assert 0 < float(r["median_residual_px"]) <= float(r["p95_residual_px"]) < 0.05
    assert abs(float(rows[1]["mean_D_mm"]) - 1.0) < 0.005
    manifest = json.loads((out / MANIFEST_NAME).read_text())
    assert sorted(manifest["files"]) == ["reference.csv", "reference.vtk", "state_001.csv", "state_001.vtk",
                                         "summary.csv"]
    assert not (out / PENDING_NAME).exists()
    # a second run into the same folder would mix two result sets: refused, unless --overwrite
    assert main(_stereo_args(stereo, out)) == 2
    line = _error_line(capsys)
    assert f"{out} holds an earlier dataset" in line and "--overwrite" in line
    assert main(_stereo_args(stereo, out, extra=["--overwrite"])) == 0


def test_stereo_mask_keeps_only_the_points_it_covers(stereo, tmp_path, capsys):
    """``--mask``: a mask covering the left half of the ROI gives exactly the grid points of that half (computed here
    from the ROI and step), with the same 3-D results as the unmasked run at those points; a mask of another size
    is refused naming both sizes."""
    from workbench.results import read_result

    ref = cv2.imread(str(stereo / "left_ref.png"), cv2.IMREAD_GRAYSCALE)
    mask = np.zeros_like(ref)
    mask[:, :300] = 255
    cv2.imwrite(str(tmp_path / "mask.png"), mask)
    full, half = tmp_path / "full", tmp_path / "half"
    assert main(_stereo_args(stereo, full)) == 0
    assert main(_stereo_args(stereo, half, extra=("--mask", str(tmp_path / "mask.png")))) == 0
    a, b = read_result(full / "reference.csv"), read_result(half / "reference.csv")
    assert b.x_px.size > 0 and np.all(b.x_px < 300)
    assert b.x_px.size == np.count_nonzero(a.x_px < 300)
    ia = np.flatnonzero(a.x_px < 300)
    np.testing.assert_allclose(b.X_mm, a.X_mm[ia], atol=1e-9)
    assert json.loads((half / MANIFEST_NAME).read_text())["settings"]["mask"] == str(tmp_path / "mask.png")
    cv2.imwrite(str(tmp_path / "small.png"), mask[:100, :100])
    assert main(_stereo_args(stereo, tmp_path / "bad", extra=("--mask", str(tmp_path / "small.png")))) == 2
    assert "is 100 x 100 px but the left reference is" in capsys.readouterr().err


def test_swapped_reference_images_are_refused_with_the_likely_cause(stereo, tmp_path, capsys):
    """Swapped left/right references used to give a median residual of ~1.5-2 px, D = 91 mm and exit 0."""
    out = tmp_path / "out"
    assert main(_stereo_args(stereo, out, left_ref="right_ref.png", right_ref="left_ref.png")) == 2
    line = _error_line(capsys)
    assert "reference shape" in line and "median triangulation residual" in line and "above 0.5 px" in line
    assert "swapped" in line and "wrong order" in line and "--max-residual-px" in line
    assert f"calibration {stereo / 'rig.yaml'}" in line      # names the calibration it does not fit
    assert not out.exists()                        # refused before the first write


def test_every_state_unmatched_exits_non_zero(stereo, tmp_path, capsys):
    """Left and right deformed images swapped: the state is named and skipped, the run exits 1 (was 0)."""
    out = tmp_path / "out"
    assert main(_stereo_args(stereo, out, left="right_def.png", right="left_def.png")) == 1
    err = capsys.readouterr().err
    assert "state 1 skipped" in err and "swapped" in err and "1 of 1 states could not be measured" in err
    with open(out / "summary.csv", newline="") as handle:
        rows = list(csv.DictReader(handle))
    assert rows[1]["result"] == "skipped" and float(rows[1]["median_residual_px"]) > 0.5
    assert not (out / "state_001.csv").exists()
    assert "state_001.csv" not in json.loads((out / MANIFEST_NAME).read_text())["files"]


def test_zero_points_triangulated_is_an_error(stereo, tmp_path, capsys):
    """A region of interest off the specimen (the image corner): nothing triangulated -> exit 2, not 0."""
    out = tmp_path / "out"
    args = _stereo_args(stereo, out)
    args[args.index("--roi") + 1] = "0,0,40,40"
    with pytest.warns(UserWarning, match="none of the 4 seed"):
        assert main(args) == 2
    assert "no point of 4 was triangulated" in _error_line(capsys)
    assert not out.exists()


def test_no_point_is_never_accepted_even_without_thresholds():
    nothing = StereoQuality(points=100, measured=0, median_residual_px=float("nan"), p95_residual_px=float("nan"))
    with pytest.raises(StereoQualityError, match="no point of 100 was triangulated"):
        check_stereo_quality(nothing, "state 3", max_median_residual_px=None, min_measured_fraction=None)
    few = StereoQuality(points=100, measured=30, median_residual_px=0.01, p95_residual_px=0.02)
    with pytest.raises(StereoQualityError, match=r"state 3: only 30 of 100 points \(30%\) were measured"):
        check_stereo_quality(few, "state 3")
    check_stereo_quality(few, "state 3", min_measured_fraction=0.25)


@pytest.mark.parametrize("defect, message", [("size", "is 614 x 510 px but the calibration is for 614 x 514 px"),
                                             ("unreadable", "cannot read image")])
def test_deformed_images_are_checked_before_anything_is_written(stereo, tmp_path, capsys, defect, message):
    """A bad second state used to be found after reference.csv/.vtk and state_001 were written."""
    folder = tmp_path / "in"
    folder.mkdir()
    for name in ("left_ref.png", "right_ref.png", "left_def.png", "right_def.png", "rig.yaml"):
        (folder / name).write_bytes((stereo / name).read_bytes())
    for side in ("left", "right"):
        (folder / f"{side}_def2.png").write_bytes((stereo / f"{side}_def.png").read_bytes())
    bad = folder / "right_def2.png"
    if defect == "size":
        cv2.imwrite(str(bad), cv2.imread(str(bad), cv2.IMREAD_GRAYSCALE)[:-4])
    else:
        bad.write_bytes(b"not an image")
    out = tmp_path / "out"
    assert main(_stereo_args(folder, out, left="left_def*.png", right="right_def*.png")) == 2
    line = _error_line(capsys)
    assert str(bad) in line and message in line
    assert not out.exists()


def test_stereo_on_a_full_disk_leaves_no_partial_file(stereo, tmp_path, capsys, monkeypatch):
    """ENOSPC while reference.csv is written: exit 2 naming the file, no reference.csv (it used to be left
    0-byte), no temporary file; the folder reads as an incomplete dataset afterwards."""
    out = tmp_path / "out"
    _fail_fsync_for(monkeypatch, "reference.csv")
    assert main(_stereo_args(stereo, out)) == 2
    line = _error_line(capsys)
    assert f"cannot write {out / 'reference.csv'}: No space left on device" in line
    assert sorted(p.name for p in out.iterdir()) == [PENDING_NAME]
    monkeypatch.undo()
    assert main(_stereo_args(stereo, out)) == 2
    assert "holds an incomplete dataset" in _error_line(capsys)


# ------------------------------------------------------------------------------------------------------------
# Checkerboard datasets: a manifest written last; an earlier dataset is refused unless --overwrite.
def _render(out, views, *extra):
    return main(["render", "checkerboard", "--views", str(views), "--scale", "0.1", "--spp", "2", *extra,
                 "--out", str(out)])


def test_render_into_an_earlier_dataset_is_refused_and_overwrite_deletes_exactly_its_files(tmp_path, capsys):
    """Rendering 1 view over 2 used to leave left_001/right_001 beside the new truth.json (a glob mixed them)."""
    out = tmp_path / "views"
    assert _render(out, 2) == 0
    (out / "notes.txt").write_text("mine")
    before = {p.name: p.stat().st_mtime_ns for p in out.iterdir()}
    assert _render(out, 1, "--seed", "4") == 2
    line = _error_line(capsys)
    assert f"{out} holds an earlier dataset" in line and "--overwrite" in line
    assert {p.name: p.stat().st_mtime_ns for p in out.iterdir()} == before         # nothing touched
    assert _render(out, 1, "--seed", "4", "--overwrite") == 0
    assert sorted(p.name for p in out.iterdir()) == ["left_000.png", MANIFEST_NAME, "notes.txt", "right_000.png",
                                                     "truth.json"]
    manifest = json.loads((out / MANIFEST_NAME).read_text())
    truth = json.loads((out / "truth.json").read_text())
    assert manifest["files"] == [im["file"] for im in truth["images"]] + ["truth.json"]
    assert manifest["settings"]["seed"] == truth["render"]["seed"] == 4


def test_truth_and_manifest_are_written_last(tmp_path, monkeypatch):
    import workbench.experiments.calibration.views as cbv

    order = []
    for name in ("atomic_write_image", "atomic_write_text", "complete_folder"):
        real = getattr(cbv, name)
        monkeypatch.setattr(cbv, name, lambda path, *a, _real=real, **k: (order.append(os.path.basename(path)),
                                                                           _real(path, *a, **k))[1])
    assert _render(tmp_path / "v", 2) == 0
    assert order == ["left_000.png", "right_000.png", "left_001.png", "right_001.png", "truth.json", "v"]


def test_an_interrupted_render_is_never_a_dataset(tmp_path, capsys, monkeypatch):
    import scenes.rendering.render as render

    real, calls = render.render_views, []

    def render_then_interrupt(*args, **kwargs):      # the one render entry: one call renders a stereo view
        calls.append(1)
        if len(calls) == 2:
            raise KeyboardInterrupt
        return real(*args, **kwargs)

    monkeypatch.setattr(render, "render_views", render_then_interrupt)
    out = tmp_path / "views"
    assert _render(out, 2) == 130
    assert sorted(p.name for p in out.iterdir()) == [PENDING_NAME, "left_000.png", "right_000.png"]
    assert complete_manifest(out) is None
    monkeypatch.undo()
    assert _render(out, 2) == 2
    assert "holds an incomplete dataset" in _error_line(capsys)
    assert _render(out, 2, "--overwrite") == 0
    assert complete_manifest(out, "checkerboard") is not None and not (out / PENDING_NAME).exists()


def test_a_render_on_a_full_disk_names_the_image_and_leaves_no_dataset(tmp_path, capsys, monkeypatch):
    out = tmp_path / "views"
    _fail_fsync_for(monkeypatch, "left_001.png")
    assert _render(out, 2) == 2
    assert f"cannot write {out / 'left_001.png'}: No space left on device" in _error_line(capsys)
    assert sorted(p.name for p in out.iterdir()) == [PENDING_NAME, "left_000.png", "right_000.png"]


def test_an_older_dataset_without_manifest_is_refused_and_replaced_by_its_truth(tmp_path, capsys):
    out = tmp_path / "views"
    assert _render(out, 2) == 0
    (out / MANIFEST_NAME).unlink()                  # as written before manifests existed
    assert _render(out, 1) == 2
    assert "truth.json without manifest.json" in _error_line(capsys)
    assert _render(out, 1, "--overwrite") == 0
    assert sorted(p.name for p in out.iterdir()) == ["left_000.png", MANIFEST_NAME, "right_000.png", "truth.json"]


def test_the_render_store_reuses_only_complete_datasets(tmp_path):
    """The one render cache of every experiment: a stored dataset is reused; one with a file missing, or one
    whose manifest was never written (an interrupted render), is never read as valid and is rendered again."""
    from workbench.experiments.calibration.views import write_checkerboard_dataset
    from workbench.experiments.rigid_motion.scenes import load_truth, render_rigid_motion
    from workbench.store import DatasetStore, stored_render

    rig = paper_rig(0.1)
    noise = SensorNoise(read_noise_grey=1.0, bit_depth=8)
    store = DatasetStore(tmp_path / "store")
    calls = []

    def boards(folder):
        calls.append(folder)
        write_checkerboard_dataset(rig, folder, 2, 0, spp=2, noise=noise, progress=False, overwrite=True)

    content = {"experiment": "test boards", "views": 2}
    folder, reused = stored_render("checkerboard", content, boards, store)
    assert not reused and len(calls) == 1
    assert stored_render("checkerboard", content, boards, store) == (folder, True) and len(calls) == 1
    (folder / "right_001.png").unlink()                   # a file of the dataset is gone
    again, reused = stored_render("checkerboard", content, boards, store)
    assert (again, reused, len(calls)) == (folder, False, 2) and (folder / "right_001.png").is_file()
    (folder / MANIFEST_NAME).unlink()                    # images and truth.json all there, never completed
    assert stored_render("checkerboard", content, boards, store)[1] is False and len(calls) == 3

    kw = dict(scale=0.1, lens="pinhole", seed=0, spp=1, states=[0.0, 1.0])
    motion, reused = stored_render("rigid-motion", {"experiment": "test motion"}, lambda f: render_rigid_motion(
        "paper", f, noise_grey=1.0, progress=False, overwrite=True, **kw), store)
    assert not reused and load_truth(motion).states_mm.tolist() == [0.0, 1.0]
    (motion / MANIFEST_NAME).unlink()
    with pytest.raises(ValueError, match="holds an earlier dataset"):     # the folder's own guard stays
        render_rigid_motion("paper", motion, noise_grey=1.0, progress=False, **kw)


def test_reproduce_names_and_skips_a_state_that_fails_the_stereo_check(tmp_path, monkeypatch, capsys):
    """A state refused by the sanity check is skipped like an unmatched one, in the metrics and the report."""
    import workbench.experiments.rigid_motion.run as rm

    real = rm.measure_state

    def refuse_state_1(*args, name="", **kwargs):
        if name == "state 1":
            raise StereoQualityError("state 1: the median triangulation residual is 1.2 px, above 0.5 px. Likely "
                                     "cause: swapped", StereoQuality(100, 100, 1.2, 2.0))
        return real(*args, name=name, **kwargs)

    monkeypatch.setattr(rm, "measure_state", refuse_state_1)
    m = rm.reproduce_rigid_motion(tmp_path, calib="true", scale=0.25, states=[0.0, 1.0, 0.0], spp=16,
                                  subset_size=33, step=24, progress=False)
    first, second = m["states"]
    assert "error" in first and "left_01.png" in first["error"] and "1.2 px" in first["error"]
    assert "error" not in second and second["points"] > 0 and second["p95_residual_px"] > 0
    assert "skipped: " in (tmp_path / "report.md").read_text()
    assert json.loads((tmp_path / "metrics.json").read_text())["states"][0]["error"] == first["error"]

    monkeypatch.setattr(rm, "reproduce_rigid_motion", lambda out, **kw: {
        "calibration": "true rig", "points": 10, "reference_3d_error_um": {"aligned_rms": 1.0, "unaligned_rms": 2.0},
        "states": [{"state": 1, "imposed_mm": 1.0, "error": "left_01.png: refused"}]})
    assert main(["reproduce", "rigid-motion", "--calib", "true", "--out", str(tmp_path / "x")]) == 1
    assert "skipped (left_01.png: refused)" in capsys.readouterr().out


# ------------------------------------------------------------------------------------------------------------
# calibrate: every check before detection; calib.json and the YAML both or neither.
@pytest.fixture
def board_images(tmp_path):
    """Three readable pairs (the calibration itself is replaced in these tests)."""
    folder = tmp_path / "views"
    folder.mkdir()
    for k in range(3):
        for side in ("left", "right"):
            cv2.imwrite(str(folder / f"{side}_{k}.png"), np.full((40, 50), 100 + k, np.uint8))
    return folder


@pytest.fixture(scope="module")
def synthetic_calibration():
    from measurement.calibration.detection import board_points_mm
    from measurement.calibration.stepwise import calibrate_stereo
    from scenes.surfaces.checkerboard import Checkerboard
    from workbench.experiments.calibration.views import board_outline_mm
    from workbench.poses import random_board_poses

    rig = paper_rig(0.5)
    obj = board_points_mm((11, 8), 5.0)
    poses = random_board_poses(rig, board_outline_mm(Checkerboard()), 6, seed=2)
    R, T = rig.pose("right")
    pl = np.array([rig.left.project(obj @ Rw.T + tw) for Rw, tw in poses])
    pr = np.array([rig.right.project((obj @ Rw.T + tw) @ R.T + T) for Rw, tw in poses])
    return calibrate_stereo(pl, pr, obj, (rig.left.width, rig.left.height), tilt_guess_left_deg=(0, -4),
                            tilt_guess_right_deg=(0, 4), joint=False)


def _calibrate(folder, out, *extra):
    return main(["calibrate", "--left", str(folder / "left_*.png"), "--right", str(folder / "right_*.png"), *extra,
                 "--out", str(out)])


@pytest.fixture
def no_detection(monkeypatch):
    """Fails the test if a board detection starts."""
    import measurement.calibration.images as images

    calls = []
    monkeypatch.setattr(images, "calibrate_from_files", lambda *a, **k: calls.append(a) or pytest.fail("detected"))
    return calls


@pytest.mark.parametrize("case, message", [
    ("square", "argument --square-mm: must be > 0, got '0'"),
    ("unreadable", "cannot read image"),
    ("size", "all images must have one size"),
    ("yaml_out", "names the YAML export"),
    ("same", "--left and --right both match"),
    ("two", "calibration needs at least 3 stereo pairs"),
])
def test_calibrate_checks_everything_before_detecting_a_board(board_images, tmp_path, capsys, no_detection, case,
                                                               message):
    out, extra = tmp_path / "calib.json", []
    if case == "square":
        extra = ["--square-mm", "0"]
    elif case == "unreadable":
        (board_images / "right_2.png").write_bytes(b"\x89PNG broken")          # the last image read
    elif case == "size":
        cv2.imwrite(str(board_images / "right_2.png"), np.zeros((41, 50), np.uint8))
    elif case == "yaml_out":
        out = tmp_path / "calib.yaml"
    elif case == "two":
        for side in ("left", "right"):
            (board_images / f"{side}_2.png").unlink()
    if case == "same":
        code = main(["calibrate", "--left", str(board_images / "left_*.png"), "--right",
                     str(board_images / "left_*.png"), "--out", str(out)])
    else:
        code = _calibrate(board_images, out, *extra)
    assert code == 2
    assert message in _error_line(capsys)
    assert not no_detection and not out.exists()


@pytest.mark.parametrize("full", ["calib.yaml", "calib.json"])
def test_calibrate_on_a_full_disk_writes_neither_file(board_images, tmp_path, capsys, monkeypatch,
                                                      synthetic_calibration, full):
    """ENOSPC on either file: exit 2 naming it, neither calib.json nor calib.yaml (calib.json used to be written
    before the YAML failed, and a 0-byte YAML was reported as written with exit 0)."""
    import measurement.calibration.images as images

    pairs = SimpleNamespace(left_files=["l"], right_files=["r"], dropped=[])
    monkeypatch.setattr(images, "calibrate_from_files", lambda *a, **k: (synthetic_calibration, pairs))
    out = tmp_path / "out" / "calib.json"
    real_fsync = os.fsync
    _fail_fsync_for(monkeypatch, full)
    assert _calibrate(board_images, out) == 2
    assert f"cannot write {out.parent / full}: No space left on device" in _error_line(capsys)
    assert not out.parent.exists() or sorted(p.name for p in out.parent.iterdir()) == []
    monkeypatch.setattr(os, "fsync", real_fsync)
    assert _calibrate(board_images, out) == 0
    assert json.loads(out.read_text())["images"]["left"] == ["l"] and out.with_suffix(".yaml").is_file()


# ------------------------------------------------------------------------------------------------------------
# Options of every subcommand: refused by the parser (or before any work), one line naming the option.
@pytest.mark.parametrize("argv, option", [
    (["render", "checkerboard", "--seed", "-1"], "--seed"),            # was "expected non-negative integer"
    (["render", "checkerboard", "--seed", "50000"], "--seed"),         # was a sampler error after rendering began
    (["render", "checkerboard", "--noise-grey", "nan"], "--noise-grey"),
    (["render", "checkerboard", "--noise-grey", "-1"], "--noise-grey"),
    (["render", "checkerboard", "--views", "100000"], "--views"),
    (["render", "checkerboard", "--scale", "inf"], "--scale"),
    (["reproduce", "agreement", "--views", "0"], "--views"),
    (["reproduce", "agreement", "--seed", "-3"], "--seed"),
    (["reproduce", "calibration", "--noise-grey", "inf"], "--noise-grey"),
    (["reproduce", "calibration", "--calibration-views", "0"], "--calibration-views"),
    (["reproduce", "rigid-motion", "--subset", "64"], "--subset"),
    (["reproduce", "rigid-motion", "--step", "0"], "--step"),
    (["reproduce", "rigid-motion", "--seed", "x"], "--seed"),
    (["reproduce", "bending", "--subset", "3"], "--subset"),
    (["reproduce", "bending", "--noise-grey", "nan"], "--noise-grey"),
    (["reproduce", "bending", "--window", "x"], "--window"),
    (["reproduce", "depth-of-field", "--f-number", "0"], "--f-number"),
    (["reproduce", "depth-of-field", "--f-number", "inf"], "--f-number"),
    (["reproduce", "depth-of-field", "--object-tilt-deg", "nan"], "--object-tilt-deg"),
    (["reproduce", "depth-of-field", "--object-tilt-deg", "90"], "--object-tilt-deg"),
    (["calibrate", "--left", "a*", "--right", "b*", "--square-mm", "nan"], "--square-mm"),
    (["calibrate", "--left", "a*", "--right", "b*", "--tilt-guess-deg", "inf,0"], "--tilt-guess-deg"),
    (["calibrate", "--left", "a*", "--right", "b*", "--tilt-guess-right-deg", "0,90"], "--tilt-guess-right-deg"),
    (["calibrate", "--left", "a*", "--right", "b*", "--pattern", "1x8"], "--pattern"),
    (["stereo", "--calib", "c", "--left-ref", "l", "--right-ref", "r", "--left", "a", "--right", "b",
      "--roi", "inf,0,10,10"], "--roi"),
    (["stereo", "--calib", "c", "--left-ref", "l", "--right-ref", "r", "--left", "a", "--right", "b",
      "--max-residual-px", "0"], "--max-residual-px"),
    (["stereo", "--calib", "c", "--left-ref", "l", "--right-ref", "r", "--left", "a", "--right", "b",
      "--min-measured-fraction", "1.5"], "--min-measured-fraction"),
    (["stereo", "--calib", "c", "--left-ref", "l", "--right-ref", "r", "--left", "a", "--right", "b",
      "--subset", "64"], "--subset"),
    (["stereo", "--calib", "c", "--left-ref", "l", "--right-ref", "r", "--left", "a", "--right", "b",
      "--min-zncc", "5"], "--min-zncc"),
])
def test_every_subcommand_refuses_bad_numbers_naming_the_option(tmp_path, capsys, argv, option):
    out = tmp_path / "out"
    assert main(argv + ["--out", str(out)]) == 2
    line = _error_line(capsys)
    assert f"argument {option}:" in line, line
    assert not out.exists()


@pytest.mark.parametrize("command", [["reproduce", "rigid-motion"], ["reproduce", "bending"]])
def test_a_missing_or_directory_calibration_is_refused_before_rendering(tmp_path, capsys, command):
    out = tmp_path / "out"
    assert main(command + ["--calib", str(tmp_path / "missing.json"), "--out", str(out)]) == 2
    assert f"calibration file not found: {tmp_path / 'missing.json'}" in _error_line(capsys)
    assert main(command + ["--calib", str(tmp_path), "--out", str(out)]) == 2
    assert f"--calib {tmp_path} is a directory" in _error_line(capsys)
    assert not out.exists()


def test_an_output_folder_that_is_a_file_is_refused(tmp_path, capsys):
    a_file = tmp_path / "report"
    a_file.write_text("x")
    assert main(["reproduce", "dic-accuracy", "--out", str(a_file)]) == 2
    assert f"--out {a_file} is a file, not a folder" in _error_line(capsys)
    assert _render(a_file, 1) == 2
    assert f"--out {a_file} is a file, not a folder" in _error_line(capsys)


# ------------------------------------------------------------------------------------------------------------
# The DIC library: a seed point that is not finite, outside the image or near no point of interest is refused
# (it used to be silently ignored); a non-finite seed guess too (it used to raise OverflowError).
@pytest.fixture(scope="module")
def shifted_pair():
    return fourier_shifted_pair((96, 120), 4.0, (1.25, -0.5), seed=4)


@pytest.mark.parametrize("points, message", [
    ([(np.nan, 10.0)], r"seed point \(nan, 10\) is not finite"),
    ([(200.0, 10.0)], r"seed point \(200, 10\) px is outside the 120 x 96 px image"),
    ([(-1.0, 10.0)], r"seed point \(-1, 10\) px is outside"),
    ([(60.0, 48.0), (5.0, 90.0)], r"seed point \(5, 90\) px is not near any point of interest"),
])
def test_correlate_refuses_a_bad_seed_point(shifted_pair, points, message):
    reference, deformed = shifted_pair
    with pytest.raises(ValueError, match=message):
        correlate(reference, deformed, DICSettings(subset_size=21, step=6), roi=(30, 30, 90, 70),
                  seed_points_xy=points)


def test_correlate_refuses_a_non_finite_seed_guess_and_uses_a_good_seed_point(shifted_pair):
    reference, deformed = shifted_pair
    settings = DICSettings(subset_size=21, step=6)
    with pytest.raises(ValueError, match="seed_guess_px must be two finite numbers"):
        correlate(reference, deformed, settings, roi=(30, 30, 90, 70), seed_guess_px=(np.inf, 0.0))
    with pytest.raises(ValueError, match=r"seed_guess_px \(1e\+300, 0\) px moves the seed search outside"):
        correlate(reference, deformed, settings, roi=(30, 30, 90, 70), seed_guess_px=(1e300, 0.0))
    result = correlate(reference, deformed, settings, roi=(30, 30, 90, 70), seed_points_xy=[(61.0, 49.0)])
    assert result.converged.all() and np.abs(result.u - 1.25).max() < 2e-3
