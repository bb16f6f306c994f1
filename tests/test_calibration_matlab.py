"""MATLAB stereoParameters calibrations (``toStruct`` as JSON or MAT-file): conventions, round trips, errors, CLI.

The references are independent of the code under test: ``cv2.projectPoints`` given K and the distortion vector
built here from the file's own numbers with the documented MATLAB conventions (K = IntrinsicMatrix', the
principal point 1 px larger than OpenCV's because MATLAB's first pixel centre is (1, 1), x2 = x1 * R + t with row
vectors), and the source rig's own ``camera.project``. ``tests/data/calibration/matlab_stereoParameters_toStruct.json``
is written from the documented field names (see the README there): no public sample was found.
"""
from __future__ import annotations

import copy
import dataclasses
import json
import struct
from pathlib import Path

import cv2
import numpy as np
import pytest
import scipy.io

from measurement.calibration.formats import (FORMATS, detect_format, load_any_calibration, load_dice, load_matlab,
                                             save_calibration_as, save_matlab)
from measurement.calibration.io import CalibratedRig
from measurement.camera import ScheimpflugCamera
from labio.schema import FileFormatError

SAMPLE = Path(__file__).parent / "data" / "calibration" / "matlab_stereoParameters_toStruct.json"

#: Every term MATLAB holds (k3, skew, tangential), no tilt; the right camera differs in every term.
LEFT = ScheimpflugCamera(fx=4800.0, fy=4790.0, cx=1221.3, cy=1030.7, k1=-0.21, k2=0.35, p1=8e-4, p2=-6e-4, k3=-1.7,
                         skew=1.3, width=2448, height=2048)
RIGHT = dataclasses.replace(LEFT, fx=4812.5, fy=4801.0, cx=1208.9, cy=1017.2, k1=-0.18, k2=0.29, p1=-3e-4, p2=5e-4,
                            k3=0.9, skew=-0.7)


def _rig(left=LEFT, right=RIGHT, rvec=(0.01, 0.38, -0.02), T=(-140.0, 1.5, 28.0)) -> CalibratedRig:
    return CalibratedRig("pinhole", left, right, cv2.Rodrigues(np.asarray(rvec, float))[0], np.array(T, float))


def _points(rng, n=400) -> np.ndarray:
    """(n, 3) left-camera-frame points (mm) within a normalised radius of 0.22, 350-450 mm away."""
    z = rng.uniform(350.0, 450.0, n)
    return np.column_stack([rng.uniform(-0.22, 0.22, n) * z, rng.uniform(-0.22, 0.22, n) * z, z])


def _sample() -> dict:
    return json.loads(SAMPLE.read_text())


def _write_json(path: Path, doc) -> Path:
    path.write_text(json.dumps(doc))
    return path


def _as_array(value) -> np.ndarray:
    return np.asarray(value, float)


def _opencv_camera_from_matlab(cam: dict) -> tuple[np.ndarray, np.ndarray, float]:
    """K (0-based principal point, skew removed), D = [k1 k2 p1 p2 k3] and the skew, converted by hand from one
    MATLAB camera struct: K = IntrinsicMatrix' (or K), cx = cx_MATLAB - 1 (stereoParametersToOpenCV's shift)."""
    K = _as_array(cam["K"]) if "K" in cam else _as_array(cam["IntrinsicMatrix"]).T
    K = K.copy()
    K[0, 2] -= 1.0
    K[1, 2] -= 1.0
    skew = float(K[0, 1])
    K[0, 1] = 0.0                                       # cv2.projectPoints ignores K[0, 1]: applied by hand below
    radial = np.ravel(cam["RadialDistortion"])
    k3 = radial[2] if radial.size >= 3 else 0.0
    p1, p2 = np.ravel(cam["TangentialDistortion"])
    return K, np.array([radial[0], radial[1], p1, p2, k3], float), skew


def _cv2_project(X_cam: np.ndarray, cam: dict) -> np.ndarray:
    K, D, skew = _opencv_camera_from_matlab(cam)
    uv = cv2.projectPoints(X_cam, np.zeros(3), np.zeros(3), K, D)[0].reshape(-1, 2)
    uv[:, 0] += skew * (uv[:, 1] - K[1, 2]) / K[1, 1]
    return uv


def _matlab_right_frame(X_left: np.ndarray, doc: dict, scale_mm: float = 1.0) -> np.ndarray:
    """MATLAB's documented row-vector formula: [x y z]_2 = [x y z]_1 * RotationOfCamera2 + TranslationOfCamera2."""
    return X_left @ _as_array(doc["RotationOfCamera2"]) + np.ravel(doc["TranslationOfCamera2"]) * scale_mm


def _max_px(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.max(np.linalg.norm(a - b, axis=1)))


# ------------------------------------------------------------------------------------------------------------
# Tiny MAT-files with a MATLAB object (MCOS) in them, as MATLAB writes for save('f.mat', 'stereoParams')
# ------------------------------------------------------------------------------------------------------------
def _element(dtype: int, payload: bytes) -> bytes:
    return struct.pack("<II", dtype, len(payload)) + payload + b"\0" * ((-len(payload)) % 8)


def _flags(mx_class: int) -> bytes:
    return _element(6, struct.pack("<II", mx_class, 0))                       # miUINT32 array flags


def _mcos_object(name: bytes, class_name: bytes) -> bytes:
    """An mxOPAQUE_CLASS (17) element: flags, name, "MCOS", class name, then a uint32 reference array (the layout
    scipy.io documents for such elements; the object's properties would sit in the subsystem data, left out)."""
    ref = np.array([3707764736, 2, 1, 1, 1, 1], "<u4")
    ref_matrix = _element(14, _flags(13) + _element(5, struct.pack("<ii", 6, 1)) + _element(1, b"")
                          + _element(6, ref.tobytes()))
    body = _flags(17) + _element(1, name) + _element(1, b"MCOS") + _element(1, class_name) + ref_matrix
    return _element(14, body)


def _struct_holding(name: bytes, field: str, value: bytes) -> bytes:
    body = (_flags(2) + _element(5, struct.pack("<ii", 1, 1)) + _element(1, name) + _element(5, struct.pack("<i", 32))
            + _element(1, field.encode().ljust(32, b"\0")) + value)
    return _element(14, body)


def _mat_header(version: bytes = b"MATLAB 5.0 MAT-file") -> bytes:
    return (version + b", Platform: GLNXA64, Created on: Mon Jan  1 00:00:00 2024").ljust(116, b" ") + b"\0" * 8 \
        + struct.pack("<H", 0x0100) + b"IM"


# ============================================================================================================
# 1. the sample file against the documented conventions
# ============================================================================================================
def test_sample_json_projects_as_cv2_with_the_documented_matlab_conventions_to_1e6_px(rng):
    doc = _sample()
    rig = load_matlab(SAMPLE)
    X_left = _points(rng)
    assert _max_px(rig.left.project(X_left), _cv2_project(X_left, doc["CameraParameters1"])) < 1e-6
    X_right = X_left @ rig.R_right_from_left.T + rig.T_right_from_left_mm
    reference = _cv2_project(_matlab_right_frame(X_left, doc), doc["CameraParameters2"])
    assert _max_px(rig.right.project(X_right), reference) < 1e-6
    rows, cols = doc["CameraParameters1"]["ImageSize"]
    assert (rig.left.width, rig.left.height) == (cols, rows) and cols != rows


def test_principal_point_moves_by_exactly_one_pixel_between_matlab_and_this_instrument(tmp_path):
    """Reading: cx = K(1,3) - 1; writing: K(1,3) = cx + 1. A point on the optical axis lands on (cx, cy)."""
    doc = _sample()
    rig = load_matlab(SAMPLE)
    for cam, key in ((rig.left, "CameraParameters1"), (rig.right, "CameraParameters2")):
        K = _as_array(doc[key]["K"])
        assert (cam.cx, cam.cy) == (K[0, 2] - 1.0, K[1, 2] - 1.0)
        assert np.allclose(cam.project(np.array([[0.0, 0.0, 400.0]])), [[K[0, 2] - 1.0, K[1, 2] - 1.0]], atol=1e-9)
    save_matlab(_rig(), tmp_path / "out.json", intrinsics_key="K")
    written = json.loads((tmp_path / "out.json").read_text())
    assert _as_array(written["CameraParameters1"]["K"])[0, 2] == LEFT.cx + 1.0
    assert _as_array(written["CameraParameters2"]["K"])[1, 2] == RIGHT.cy + 1.0


def test_pre_r2022b_intrinsic_matrix_reads_as_its_transpose(tmp_path):
    doc = _sample()
    old = copy.deepcopy(doc)
    for key in ("CameraParameters1", "CameraParameters2"):
        old[key]["IntrinsicMatrix"] = _as_array(old[key].pop("K")).T.tolist()
    a, b = load_matlab(SAMPLE), load_matlab(_write_json(tmp_path / "old.json", old))
    assert a.left == b.left and a.right == b.right
    untransposed = copy.deepcopy(doc)
    untransposed["CameraParameters1"]["IntrinsicMatrix"] = untransposed["CameraParameters1"].pop("K")
    with pytest.raises(FileFormatError, match=r"key 'CameraParameters1\.IntrinsicMatrix'.*post-multiply"):
        load_matlab(_write_json(tmp_path / "untransposed.json", untransposed))


def test_a_file_with_k3_and_skew_loads_both_and_projects_as_cv2(tmp_path, rng):
    doc = _sample()
    cam1 = doc["CameraParameters1"]
    cam1["RadialDistortion"] = [-0.2, 0.31, -1.9]
    cam1["TangentialDistortion"] = [6e-4, -2e-4]
    cam1["K"][0][1] = 2.75
    cam1["EstimateSkew"], cam1["NumRadialDistortionCoefficients"] = True, 3
    rig = load_matlab(_write_json(tmp_path / "k3skew.json", doc))
    assert (rig.left.k3, rig.left.skew, rig.left.p1) == (-1.9, 2.75, 6e-4)
    X = _points(rng)
    assert _max_px(rig.left.project(X), _cv2_project(X, cam1)) < 1e-6
    without = dataclasses.replace(rig.left, k3=0.0, skew=0.0)
    assert _max_px(without.project(X), _cv2_project(X, cam1)) > 0.1            # the terms matter at this radius


def test_pose_camera2_alone_gives_the_same_rig_and_a_disagreeing_one_is_refused(tmp_path):
    """PoseCamera2 = rigidtform3d(RotationOfCamera2', TranslationOfCamera2) (stereoParameters.loadobj)."""
    doc = _sample()
    pose_only = copy.deepcopy(doc)
    Rm, t = pose_only.pop("RotationOfCamera2"), pose_only.pop("TranslationOfCamera2")
    pose_only["PoseCamera2"] = {"Dimensionality": 3, "R": _as_array(Rm).T.tolist(), "Translation": t}
    a, b = load_matlab(SAMPLE), load_matlab(_write_json(tmp_path / "pose.json", pose_only))
    assert np.allclose(a.R_right_from_left, b.R_right_from_left, atol=1e-15)
    assert np.allclose(a.T_right_from_left_mm, b.T_right_from_left_mm, atol=1e-12)
    both = copy.deepcopy(doc)
    both["PoseCamera2"] = {"R": _as_array(Rm).tolist(), "Translation": t}          # R not transposed: wrong
    with pytest.raises(FileFormatError, match=r"key 'PoseCamera2'.*disagrees"):
        load_matlab(_write_json(tmp_path / "both.json", both))


def test_world_units_scale_the_translation_to_mm(tmp_path):
    doc = _sample()
    for key in ("CameraParameters1", "CameraParameters2"):
        doc[key]["WorldUnits"] = "m"
    doc["TranslationOfCamera2"] = [v / 1000.0 for v in doc["TranslationOfCamera2"]]
    rig = load_matlab(_write_json(tmp_path / "metres.json", doc))
    assert np.allclose(rig.T_right_from_left_mm, load_matlab(SAMPLE).T_right_from_left_mm, rtol=1e-12)
    doc["CameraParameters2"]["WorldUnits"] = "mm"
    with pytest.raises(FileFormatError, match=r"key 'CameraParameters2\.WorldUnits'.*differs"):
        load_matlab(_write_json(tmp_path / "mixed.json", doc))


# ============================================================================================================
# 2. round trips
# ============================================================================================================
@pytest.mark.parametrize("suffix, intrinsics_key", [(".json", "IntrinsicMatrix"), (".json", "K"),
                                                    (".mat", "IntrinsicMatrix"), (".mat", "K")])
def test_round_trip_projects_within_1e6_px_of_the_source_and_of_cv2_from_the_files_numbers(tmp_path, rng, suffix,
                                                                                          intrinsics_key):
    rig = _rig()
    path = tmp_path / f"calib{suffix}"
    report = save_matlab(rig, path, intrinsics_key=intrinsics_key)
    assert report.exact and report.max_px <= 1e-6
    back = load_any_calibration(path)
    X_left = _points(rng)
    X_right = X_left @ rig.R_right_from_left.T + rig.T_right_from_left_mm
    assert _max_px(back.left.project(X_left), rig.left.project(X_left)) < 1e-6
    assert _max_px(back.right.project(X_left @ back.R_right_from_left.T + back.T_right_from_left_mm),
                   rig.right.project(X_right)) < 1e-6
    doc = (json.loads(path.read_text()) if suffix == ".json" else scipy.io.loadmat(path, simplify_cells=True))
    assert intrinsics_key in doc["CameraParameters1"] and ({"K", "IntrinsicMatrix"} - {intrinsics_key}).isdisjoint(
        doc["CameraParameters1"])
    assert _max_px(_cv2_project(X_left, doc["CameraParameters1"]), rig.left.project(X_left)) < 1e-6
    assert _max_px(_cv2_project(_matlab_right_frame(X_left, doc), doc["CameraParameters2"]),
                   rig.right.project(X_right)) < 1e-6


def test_written_json_has_jsonencode_layout_and_image_size_rows_first(tmp_path):
    rig = _rig(left=dataclasses.replace(LEFT, k3=0.0), right=dataclasses.replace(RIGHT, width=2000, height=1500))
    save_matlab(rig, tmp_path / "calib.json", intrinsics_key="K")
    doc = json.loads((tmp_path / "calib.json").read_text())
    cam1, cam2 = doc["CameraParameters1"], doc["CameraParameters2"]
    assert cam1["ImageSize"] == [2048, 2448] and cam2["ImageSize"] == [1500, 2000]
    assert len(cam1["RadialDistortion"]) == 2 and len(cam2["RadialDistortion"]) == 3      # k3 only where non-zero
    assert np.shape(cam1["K"]) == (3, 3) and np.shape(doc["RotationOfCamera2"]) == (3, 3)
    assert np.shape(doc["TranslationOfCamera2"]) == (3,)
    assert cam1["WorldUnits"] == "mm" and cam1["EstimateSkew"] is True


def test_a_tilted_camera_is_converted_and_its_cost_reported(tmp_path, paper_rig_quarter):
    """The paper's Scheimpflug cameras: MATLAB has no tilt, so the writer fits the nearest camera and reports a
    non-zero cost that matches the distance measured here between the source and the reloaded camera."""
    src = paper_rig_quarter
    rig = CalibratedRig("rmm", src.left, src.right, src.R_right_from_left, src.T_right_from_left_mm)
    assert rig.left.is_tilted
    report = save_calibration_as(rig, tmp_path / "tilted.mat", "matlab")
    back = load_matlab(tmp_path / "tilted.mat")
    for conv, source, loaded in zip(report.cameras, (rig.left, rig.right), (back.left, back.right)):
        assert not conv.exact and conv.max_px > 1e-3 and any("tilt" in n for n in conv.notes)
        u, v = np.meshgrid(np.linspace(0, source.width - 1, 101), np.linspace(0, source.height - 1, 101))
        pixels = np.column_stack([u.ravel(), v.ravel()])
        rays = np.column_stack([source.backproject(pixels), np.ones(len(pixels))])
        measured = _max_px(loaded.project(rays), pixels)
        assert abs(measured - conv.max_px) <= 1e-6 + 1e-6 * conv.max_px
        assert not loaded.is_tilted
    assert any("tilt" in line for line in report.lines())


def test_mat_file_with_the_struct_as_one_variable_loads_and_two_are_refused(tmp_path):
    doc = _sample()
    mat = {"CameraParameters1": doc["CameraParameters1"], "CameraParameters2": doc["CameraParameters2"],
           "RotationOfCamera2": np.array(doc["RotationOfCamera2"]),
           "TranslationOfCamera2": np.array([doc["TranslationOfCamera2"]])}
    for cam in ("CameraParameters1", "CameraParameters2"):
        mat[cam] = {k: (np.array(v) if isinstance(v, list) else v) for k, v in mat[cam].items()
                    if k not in ("Version", "DetectedKeypoints", "ReprojectionErrors")}
    scipy.io.savemat(tmp_path / "one.mat", {"stereoParams": mat})
    a, b = load_matlab(SAMPLE), load_matlab(tmp_path / "one.mat")
    assert a.left == b.left and a.right == b.right
    assert np.allclose(a.R_right_from_left, b.R_right_from_left, atol=1e-15)
    scipy.io.savemat(tmp_path / "two.mat", {"stereoA": mat, "stereoB": mat})
    with pytest.raises(FileFormatError, match=r"several stereo calibrations \(stereoA, stereoB\)"):
        load_matlab(tmp_path / "two.mat")


# ============================================================================================================
# 3. errors name the file and the key
# ============================================================================================================
def _broken(tmp_path, name, change) -> Path:
    doc = _sample()
    change(doc)
    return _write_json(tmp_path / f"{name}.json", doc)


@pytest.mark.parametrize("name, change, message", [
    ("no_camera2", lambda d: d.pop("CameraParameters2"), r"key 'CameraParameters2': required key is missing"),
    ("k_2x3", lambda d: d["CameraParameters1"].__setitem__("K", d["CameraParameters1"]["K"][:2]),
     r"key 'CameraParameters1\.K': must be a 3 x 3 matrix"),
    ("k_rows_short", lambda d: d["CameraParameters2"].__setitem__("K", [r[:2] for r in d["CameraParameters2"]["K"]]),
     r"key 'CameraParameters2\.K': must be a 3 x 3 matrix"),
    ("fx_negative", lambda d: d["CameraParameters2"]["K"][0].__setitem__(0, -4800.0),
     r"key 'CameraParameters2\.K': fx = K\(1,1\) must be in \(0, 1e\+06\) px"),
    ("fy_zero", lambda d: d["CameraParameters1"]["K"][1].__setitem__(1, 0.0),
     r"key 'CameraParameters1\.K': fy = K\(2,2\) must be in \(0, 1e\+06\) px"),
    ("k_lower_triangle", lambda d: d["CameraParameters1"]["K"][2].__setitem__(0, 1224.0),
     r"key 'CameraParameters1\.K': must be MATLAB's \[fx s cx; 0 fy cy; 0 0 1\]"),
    ("no_k", lambda d: d["CameraParameters1"].pop("K"), r"key 'CameraParameters1\.K': required key is missing"),
    ("not_rotation", lambda d: d["RotationOfCamera2"][0].__setitem__(0, 2.0),
     r"key 'RotationOfCamera2': must be a rotation matrix"),
    ("no_translation", lambda d: d.pop("TranslationOfCamera2"), r"key 'TranslationOfCamera2': required key"),
    ("rational_k4", lambda d: d["CameraParameters1"].__setitem__("RadialDistortion", [-0.1, 0.2, 0.0, 0.01, 0, 0]),
     r"key 'CameraParameters1\.RadialDistortion': has the rational terms"),
    ("radial_4", lambda d: d["CameraParameters1"].__setitem__("RadialDistortion", [-0.1, 0.2, 0.0, 0.01]),
     r"key 'CameraParameters1\.RadialDistortion': must be a vector of 2 or 3 or 6 numbers, got 4"),
    ("units", lambda d: d["CameraParameters1"].__setitem__("WorldUnits", "furlongs"),
     r"key 'CameraParameters1\.WorldUnits': must be a length unit"),
    ("image_size", lambda d: d["CameraParameters2"].__setitem__("ImageSize", [2048.5, 2448]),
     r"key 'CameraParameters2\.ImageSize': must be \[rows cols\]"),
    ("zero_baseline", lambda d: d.__setitem__("TranslationOfCamera2", [0, 0, 0]),
     r"key 'TranslationOfCamera2': the stereo translation's length"),
], ids=lambda v: v if isinstance(v, str) and " " not in v and "\\" not in v else None)
def test_defects_raise_file_format_error_naming_the_key(tmp_path, name, change, message):
    path = _broken(tmp_path, name, change)
    with pytest.raises(FileFormatError, match=message) as info:
        load_any_calibration(path)
    assert info.value.file == str(path)


def test_a_mat_file_holding_the_matlab_object_itself_says_how_to_export_it(tmp_path):
    """MATLAB's save('f.mat', 'stereoParams') stores an MCOS object, which scipy cannot decode; built here as a
    minimal MAT-file (top-level object, and an object inside a struct as MultiDIC's sample files hold)."""
    (tmp_path / "object.mat").write_bytes(_mat_header() + _mcos_object(b"stereoParams", b"stereoParameters"))
    (tmp_path / "nested.mat").write_bytes(_mat_header() + _struct_holding(
        b"calib", "cameraParameters", _mcos_object(b"", b"cameraParameters")))
    with pytest.raises(FileFormatError, match=r"MATLAB stereoParameters object.*MCOS.*toStruct\(stereoParams\).*"
                                              r"-v7.*jsonencode"):
        load_any_calibration(tmp_path / "object.mat")
    with pytest.raises(FileFormatError, match=r"key 'calib\.cameraParameters': is a MATLAB cameraParameters object"):
        load_matlab(tmp_path / "nested.mat")


def test_other_unreadable_mat_files_are_refused_clearly(tmp_path):
    (tmp_path / "v73.mat").write_bytes(_mat_header(b"MATLAB 7.3 MAT-file") + b"\x89HDF\r\n\x1a\n" + b"\0" * 64)
    with pytest.raises(FileFormatError, match=r"7\.3 MAT-file \(HDF5\).*-v7"):
        load_matlab(tmp_path / "v73.mat")
    (tmp_path / "cut.mat").write_bytes(_mat_header() + _mcos_object(b"x", b"stereoParameters")[:40])
    with pytest.raises(FileFormatError, match=r"cut\.mat.*not a readable MAT-file"):
        load_matlab(tmp_path / "cut.mat")
    scipy.io.savemat(tmp_path / "packed.mat", {"imagePoints": np.arange(5000.0)}, do_compression=True)
    data = bytearray((tmp_path / "packed.mat").read_bytes())
    data[200:260] = b"\xff" * 60                                              # inside the zlib stream
    (tmp_path / "packed.mat").write_bytes(bytes(data))
    with pytest.raises(FileFormatError, match=r"packed\.mat.*not a readable MAT-file"):
        load_matlab(tmp_path / "packed.mat")
    scipy.io.savemat(tmp_path / "other.mat", {"imagePoints": np.zeros((3, 2))})
    with pytest.raises(FileFormatError, match=r"key 'CameraParameters1'.*no MATLAB stereoParameters struct.*"
                                              r"imagePoints"):
        load_matlab(tmp_path / "other.mat")


def test_writer_refuses_an_unknown_suffix_and_writes_nothing(tmp_path):
    with pytest.raises(ValueError, match=r"\.json \(jsonencode\) or \.mat"):
        save_matlab(_rig(), tmp_path / "calib.txt")
    assert not list(tmp_path.iterdir())


# ============================================================================================================
# 4. detection, the format list and the command line
# ============================================================================================================
def test_detect_format_recognises_matlab_json_and_mat_files_by_content(tmp_path):
    assert detect_format(SAMPLE) == "matlab" and "matlab" in FORMATS
    save_matlab(_rig(), tmp_path / "calib.mat")
    (tmp_path / "calib.bin").write_bytes((tmp_path / "calib.mat").read_bytes())
    assert detect_format(tmp_path / "calib.mat") == "matlab" and detect_format(tmp_path / "calib.bin") == "matlab"
    (tmp_path / "calib.txt").write_text(SAMPLE.read_text())
    assert detect_format(tmp_path / "calib.txt") == "matlab"
    save_calibration_as(_rig(), tmp_path / "native.json", "json")
    assert detect_format(tmp_path / "native.json") == "native"
    assert load_any_calibration(tmp_path / "calib.bin").left == load_matlab(tmp_path / "calib.mat").left


def test_cli_converts_matlab_to_dice_and_back_within_1e6_px(tmp_path, capsys, rng):
    from workbench.cli import main
    from workbench.commands.stereo import load_rig as _load_rig

    xml, mat, back_json = tmp_path / "cal.xml", tmp_path / "cal.mat", tmp_path / "back.json"
    assert main(["calibration", "convert", str(SAMPLE), str(xml), "--to", "dice"]) == 0
    assert main(["calibration", "convert", str(xml), str(mat)]) == 0                        # .mat: matlab by suffix
    assert main(["calibration", "convert", str(mat), str(back_json), "--to", "matlab"]) == 0
    printed = capsys.readouterr().out
    assert f"wrote {mat} as matlab" in printed and f"wrote {back_json} as matlab" in printed
    doc, source = _sample(), load_matlab(SAMPLE)
    assert detect_format(back_json) == "matlab"
    for path in (xml, mat, back_json):
        rig = load_dice(path) if path == xml else _load_rig(path)
        X = _points(rng)
        assert _max_px(rig.left.project(X), _cv2_project(X, doc["CameraParameters1"])) < 1e-6
        X_right = X @ rig.R_right_from_left.T + rig.T_right_from_left_mm
        assert _max_px(rig.right.project(X_right),
                       _cv2_project(_matlab_right_frame(X, doc), doc["CameraParameters2"])) < 1e-6
        assert np.allclose(rig.T_right_from_left_mm, source.T_right_from_left_mm, atol=1e-9)


def test_a_mat_file_that_inflates_beyond_the_limit_is_refused_before_loading(tmp_path, monkeypatch):
    from measurement.calibration.formats import matlab

    scipy.io.savemat(tmp_path / "zeros.mat", {"big": np.zeros(100_000)}, do_compression=True)
    assert (tmp_path / "zeros.mat").stat().st_size < 10_000                    # compressed well below the limit
    monkeypatch.setattr(matlab, "MAX_MAT_DECOMPRESSED_BYTES", 100_000)
    with pytest.raises(FileFormatError, match=r"zeros\.mat: inflates to more than"):
        load_matlab(tmp_path / "zeros.mat")
    monkeypatch.setattr(matlab, "MAX_MAT_DECOMPRESSED_BYTES", 10_000_000)
    with pytest.raises(FileFormatError, match=r"no MATLAB stereoParameters struct"):     # passes the check, then
        load_matlab(tmp_path / "zeros.mat")                                              # found to hold no calibration
