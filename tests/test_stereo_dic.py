"""Stereo-DIC (measurement/stereo_dic.py) on renders of a speckled plate through the paper rig (test scale).

The plate sits where the optical axes meet, facing the bisector of the two cameras; the true rig is used, so
the figures measure matching + triangulation alone. Truth: the plate plane, and its rigid translation.
"""
import numpy as np
import pytest

from measurement.dic import DICSettings, Status
from measurement.stereo_dic import StereoMatchError, match_features, measure_state, reference_shape
from scenes.noise import SensorNoise
from scenes.render import render_view
from scenes.specimens import SpeckledPlate
from workbench.experiments.calibration.views import sensor_spec_for
from workbench.rigs import paper_rig

SCALE = 0.25
RIG = paper_rig(SCALE)
NOISE = SensorNoise(read_noise_grey=1.0, bit_depth=8)
MM_PER_PX = 85.0 / RIG.left.width
SETTINGS = DICSettings(subset_size=33, step=10, order=2)
MOVE_MM = np.array([0.0, -1.0, 0.0])


def _plate_pose():
    axis_left = np.array([0.0, 0.0, 1.0])
    axis_right = RIG.R_right_from_left.T @ axis_left
    z = axis_left + axis_right
    z /= np.linalg.norm(z)
    x = np.array([1.0, 0.0, 0.0]) - z[0] * z
    x /= np.linalg.norm(x)
    return np.column_stack([x, np.cross(z, x), z]), RIG.optical_axes_meeting_point_mm()


@pytest.fixture(scope="module")
def renders():
    plate = SpeckledPlate(width_mm=70.0, height_mm=55.0, texel_mm=MM_PER_PX / 4, speckle_mm=4 * MM_PER_PX, seed=3)
    texture = plate.texture()
    R_world_from_plate, centre_mm = _plate_pose()
    images = {}
    for state, offset in (("ref", np.zeros(3)), ("def", MOVE_MM)):
        surface = plate.surface(R_world_from_plate, centre_mm + offset, texture)
        for k, side in enumerate(("left", "right")):
            R_cw, t_cw = RIG.pose(side)
            image = render_view(sensor_spec_for(RIG, side), R_cw, t_cw, [surface], spp=64,
                                seed=10 * k + (state == "def")).image_grey
            images[f"{side}_{state}"] = NOISE.apply(image, seed=100 + 10 * k + (state == "def"))
    return images, R_world_from_plate, centre_mm


def _roi():
    w, h = RIG.left.width, RIG.left.height
    return (int(0.3 * w), int(0.3 * h), int(0.7 * w), int(0.7 * h))


def test_reference_shape_lies_on_the_plate(renders):
    images, R_world_from_plate, centre_mm = renders
    shape = reference_shape(RIG.left, RIG.right, RIG.R_right_from_left, RIG.T_right_from_left_mm,
                            images["left_ref"], images["right_ref"], SETTINGS, roi=_roi())
    assert shape.valid.mean() > 0.95, shape.right_match.status_counts()
    normal = R_world_from_plate[:, 2]
    distance_um = 1e3 * (shape.X_mm[shape.valid] - centre_mm) @ normal
    print(f"reference shape: {shape.valid.sum()} points, plane distance RMS {np.sqrt(np.mean(distance_um ** 2)):.2f} "
          f"um, max {np.abs(distance_um).max():.2f} um; residual median {np.median(shape.residual_px[shape.valid]):.4f} px")
    # 1 px ~ 0.14 mm at this scale; 0.01 px of matching noise is ~3 um in depth through the 23 deg stereo angle
    assert np.sqrt(np.mean(distance_um ** 2)) < 10.0
    assert np.median(shape.residual_px[shape.valid]) < 0.05


def test_rigid_translation_is_measured(renders):
    images, _, _ = renders
    shape = reference_shape(RIG.left, RIG.right, RIG.R_right_from_left, RIG.T_right_from_left_mm,
                            images["left_ref"], images["right_ref"], SETTINGS, roi=_roi())
    state = measure_state(RIG.left, RIG.right, RIG.R_right_from_left, RIG.T_right_from_left_mm, shape,
                          images["left_ref"], images["left_def"], images["right_def"], SETTINGS)
    ok = state.valid
    assert ok.mean() > 0.95, {s: int((state.status == s).sum()) for s in np.unique(state.status)}
    error_um = 1e3 * (state.U_mm[ok] - MOVE_MM)
    print(f"translation 1 mm: mean error {error_um.mean(axis=0).round(2)} um, std {error_um.std(axis=0).round(2)} um; "
          f"D mean {state.D_mm[ok].mean():.5f} mm")
    assert np.abs(error_um.mean(axis=0)).max() < 5.0
    assert error_um.std(axis=0).max() < 10.0
    assert abs(state.D_mm[ok].mean() - 1.0) < 0.005
    assert np.all(state.status[~ok] != Status.CONVERGED)
    assert np.isnan(state.U_mm[~ok]).all()


def test_images_with_no_overlap_are_refused(renders):
    images, _, _ = renders
    flat = np.full_like(images["right_ref"], 128)
    with pytest.raises(StereoMatchError, match="right reference"):
        match_features(images["left_ref"], flat, name="right reference")


def test_image_size_must_match_the_calibration(renders):
    images, _, _ = renders
    with pytest.raises(ValueError, match="calibration is for"):
        reference_shape(RIG.left, RIG.right, RIG.R_right_from_left, RIG.T_right_from_left_mm,
                        images["left_ref"][:-2], images["right_ref"][:-2], SETTINGS)


def test_workbench_stereo_cli(renders, tmp_path, capsys):
    import csv

    import cv2

    from measurement.calibration.io import CalibratedRig, export_opencv_yaml
    from workbench.cli import main

    images, _, _ = renders
    for name, image in images.items():
        cv2.imwrite(str(tmp_path / f"{name}.png"), np.clip(np.rint(image), 0, 255).astype(np.uint8))
    export_opencv_yaml(CalibratedRig("rmm", RIG.left, RIG.right, RIG.R_right_from_left, RIG.T_right_from_left_mm),
                       tmp_path / "rig.yaml")
    x0, y0, x1, y1 = _roi()
    args = ["stereo", "--calib", str(tmp_path / "rig.yaml"), "--left-ref", str(tmp_path / "left_ref.png"),
            "--right-ref", str(tmp_path / "right_ref.png"), "--left", str(tmp_path / "left_def.png"),
            "--right", str(tmp_path / "right_def.png"), "--roi", f"{x0},{y0},{x1},{y1}", "--subset", "33",
            "--step", "20", "--out", str(tmp_path / "out")]
    assert main(args) == 0
    rows = list(csv.DictReader((tmp_path / "out" / "state_001.csv").open()))
    assert rows and set(rows[0]) >= {"x", "y", "X", "Y", "Z", "U", "V", "W", "zncc", "residual", "status"}
    V = np.array([float(r["V"]) for r in rows if r["status_name"] == "converged"])
    assert V.size > 0.9 * len(rows) and abs(V.mean() + 1.0) < 0.01
    vtk = (tmp_path / "out" / "state_001.vtk").read_text()
    assert vtk.startswith("# vtk DataFile") and "VECTORS displacement_mm" in vtk
    # missing calibration file: one clear line, exit code 2
    assert main(args[:2] + [str(tmp_path / "none.json")] + args[3:]) == 2
    assert "calibration file not found" in capsys.readouterr().err
