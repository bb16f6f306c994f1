"""Other tools on the workbench's datasets: export, result readers, scoring, the engine interface.

The claims (issue: score any DIC software): a perfect result file made from the truth scores zero; a result
with a known injected error (0.01 px bias, 1 µm offset) scores exactly that; wrong columns, units or pixel
conventions give clear errors or visibly wrong scores; a command-line engine and a Python entry point run
through the same interface and score the same.
"""
import csv
import json
import subprocess
import sys
import xml.etree.ElementTree as ET

import numpy as np
import pytest

from workbench.scoring.datasets import open_dataset, point_truth
from workbench.results import ResultFormatError, parse_columns, read_result
from workbench.scoring.metrics import score_state

STAGE_MM = 0.5


@pytest.fixture(scope="module")
def rigid(tmp_path_factory):
    """A tiny rigid-motion dataset of the paper rig: reference and a 0.5 mm stage move."""
    from workbench.experiments.rigid_motion.scenes import render_rigid_motion

    out = tmp_path_factory.mktemp("rigid")
    render_rigid_motion("paper", out, scale=0.2, lens="pinhole", spp=4, states=[0.0, STAGE_MM], progress=False)
    return open_dataset(out)


@pytest.fixture(scope="module")
def pair(tmp_path_factory):
    """A small dic2d pair (exact 0.25 px Fourier shift, 2 grey noise) rendered through a scenario file."""
    folder = tmp_path_factory.mktemp("pair")
    scenario = folder / "pair.toml"
    scenario.write_text('experiment = "dic2d"\n[render]\nread_noise_grey = 2.0\nbit_depth = 0\n'
                        '[image2d]\nsize_px = 160\nshift_x_px = 0.25\n')
    return open_dataset(scenario)


def _grid(dataset, step=12):
    w, h = dataset.image_size_px
    X, Y = np.meshgrid(np.arange(10, w - 10, step), np.arange(10, h - 10, step))
    return X.ravel().astype(float), Y.ravel().astype(float)


def _write_native_stereo(path, x, y, X, U, valid):
    with open(path, "w") as f:
        f.write("x,y,X,Y,Z,U,V,W,D,zncc,residual,status,status_name\n")
        for i in range(x.size):
            f.write(",".join(map(str, [x[i], y[i], *X[i], *U[i], np.linalg.norm(U[i]), 1, 0, 0,
                                       "converged" if valid[i] else "diverged"])) + "\n")


def test_point_truth_of_a_stage_move_is_the_stage_travel(rigid):
    """Independent of the ray casting: the stage moves the beam 0.5 mm along the stage axis the renderer
    wrote into truth.json, so every material point moves by exactly that vector (1e-9 mm)."""
    x, y = _grid(rigid)
    pt = point_truth(rigid, x, y)
    axis = np.array(json.loads((rigid.folder / "truth.json").read_text())["stage_direction_world"])
    assert pt.valid.sum() > 50
    np.testing.assert_allclose(pt.displacement_left_mm[1][pt.valid], np.tile(STAGE_MM * axis, (pt.valid.sum(), 1)),
                               atol=1e-9)
    # the left image of state 0 shows each point where it was defined (projection of the truth, 1e-6 px)
    np.testing.assert_allclose(pt.uv_left_px[0][pt.valid], 0.0, atol=1e-12)


def test_perfect_and_offset_3d_results_score_exactly(rigid, tmp_path):
    """A result written from the exported truth scores zero; +1 µm in U scores bias 1 µm, RMS 1 µm."""
    from workbench.scoring.export import export_dataset

    export_dataset(rigid, "native", tmp_path / "export", log=lambda *_: None)
    with open(tmp_path / "export" / "truth" / "points.csv") as f:
        rows = [r for r in csv.DictReader(f) if r["state"] == "1"]
    x = np.array([float(r["x_px"]) for r in rows])
    y = np.array([float(r["y_px"]) for r in rows])
    X = np.array([[float(r[k]) for k in ("X_mm", "Y_mm", "Z_mm")] for r in rows])
    U = np.array([[float(r[k]) for k in ("U_mm", "V_mm", "W_mm")] for r in rows])
    valid = np.array([r["valid"] == "1" for r in rows])
    assert valid.sum() > 100
    _write_native_stereo(tmp_path / "perfect_01.csv", x, y, X, U, valid)
    m = score_state(rigid, 1, read_result(tmp_path / "perfect_01.csv")).metrics
    assert m["valid_fraction"] == 1.0
    # zero up to the CSV's 9 significant digits: 370 mm -> 0.4 nm
    assert m["rms_um"] < 1e-3 and m["position_rms_um"] < 1e-3
    offset = np.array([1e-3, 0.0, 0.0])                                 # 1 µm along x
    _write_native_stereo(tmp_path / "offset_01.csv", x, y, X + offset, U + offset, valid)
    m = score_state(rigid, 1, read_result(tmp_path / "offset_01.csv")).metrics
    assert m["bias_U_um"] == pytest.approx(1.0, abs=1e-6)
    assert m["rms_um"] == pytest.approx(1.0, abs=1e-6) and m["bias_V_um"] == pytest.approx(0.0, abs=1e-6)


def test_rigid_alignment_undoes_another_frame(rigid):
    """A tool reporting in a frame rotated by 10° and shifted 5 mm: --align rigid finds the 10° and scores zero;
    without alignment the error is the rotated displacement (large)."""
    from scipy.spatial.transform import Rotation

    from workbench.results import ToolResult

    x, y = _grid(rigid, 8)
    pt = point_truth(rigid, x, y)
    R = Rotation.from_euler("z", 10.0, degrees=True).as_matrix()
    X_tool = pt.X_left_mm[1] @ R.T + [5.0, 0.0, 0.0]
    U_tool = pt.displacement_left_mm[1] @ R.T
    r = ToolResult(rigid.folder, "t", x, y, pt.valid, X_mm=X_tool, U_mm=U_tool, frame="rotated")
    aligned = score_state(rigid, 1, r, align="rigid").metrics
    assert aligned["alignment"]["rotation_deg"] == pytest.approx(10.0, abs=1e-9)
    assert aligned["rms_um"] < 1e-6
    raw = score_state(rigid, 1, r).metrics
    # |U| (R - I): 2 sin(5°) x 500 µm = 87 µm, and the score says that a rigid fit would remove it
    assert raw["rms_um"] == pytest.approx(2 * np.sin(np.radians(5.0)) * 1e3 * STAGE_MM, rel=1e-6)
    assert "one rigid fit (a 10 deg rotation) cuts the error" in raw["frame_hint"]
    assert "frame_hint" not in aligned


def _dice_solution(path, x, y, u, v, failed):
    lines = ["***", "*** Digital Image Correlation Engine (DICe), (git sha1: test)", "***",
             "SUBSET_ID,COORDINATE_X,COORDINATE_Y,DISPLACEMENT_X,DISPLACEMENT_Y,SIGMA,GAMMA,BETA,STATUS_FLAG,"
             "UNCERTAINTY"]
    for i in range(x.size):
        sigma = -1.0 if failed[i] else 0.005
        lines.append(f"{i},{x[i]:.4E},{y[i]:.4E},{u[i]:.6E},{v[i]:.6E},{sigma:.4E},0.01,0,4,0.001")
    path.write_text("\n".join(lines) + "\n")


def test_dice_solution_with_injected_bias_scores_that_bias(pair, tmp_path):
    """A DICe solution file made from the truth + 0.01 px in u, with 10 % of points marked failed (SIGMA = -1):
    bias 0.01 px exactly, valid fraction 0.9, and DICe's own SIGMA scored by its coverage."""
    x, y = _grid(pair, 10)
    pt = point_truth(pair, x, y)
    failed = np.arange(x.size) % 10 == 3
    _dice_solution(tmp_path / "DICe_solution_1.txt", x, y, pt.uv_left_px[1, :, 0] + 0.01, pt.uv_left_px[1, :, 1],
                   failed)
    m = score_state(pair, 1, read_result(tmp_path / "DICe_solution_1.txt", "dice")).metrics
    assert m["bias_u_px"] == pytest.approx(0.01, abs=1e-6)
    assert m["bias_v_px"] == pytest.approx(0.0, abs=1e-6) and m["std_u_px"] < 1e-6
    assert m["valid_fraction"] == pytest.approx(1 - failed.mean(), abs=1e-12)
    # DICe's own SIGMA (0.005 px here) scored by its coverage: the 0.01 px bias is 2 of its sigmas, outside +-1.96
    # everywhere; v, exact, inside everywhere
    assert m["sigma_coverage_95_u"] == 0.0 and m["sigma_coverage_95_v"] == 1.0


def test_nan_rows_are_not_measured_points_and_the_rest_is_scored(pair, tmp_path):
    """`workbench score --format csv` on a file where every 4th row holds NaN in u, v (and some rows NaN in x, y
    too) used to stop with KeyError 'bias_u_px'. The NaN rows count as not measured; the rest, made from the truth
    + 0.02 px in v, scores exactly that; the counts are printed and stored. A file with no finite row is an error
    naming the file."""
    x, y = _grid(pair, 10)
    pt = point_truth(pair, x, y)
    assert pt.valid.all()
    nan_uv = np.arange(x.size) % 4 == 1
    nan_all = np.arange(x.size) % 9 == 2
    path = tmp_path / "tool.csv"
    with open(path, "w") as f:
        f.write("px,py,du,dv\n")
        for i in range(x.size):
            u, v = pt.uv_left_px[1, i, 0], pt.uv_left_px[1, i, 1] + 0.02
            if nan_all[i]:
                f.write("nan,nan,nan,nan\n")
            else:
                f.write(f"{x[i]:g},{y[i]:g},{'nan' if nan_uv[i] else f'{u:.12g}'},{'nan' if nan_uv[i] else f'{v:.12g}'}\n")
    out = tmp_path / "scored"
    proc = subprocess.run([sys.executable, "-m", "workbench.cli", "score", str(pair.folder), str(path), "--format",
                           "csv", "--columns", "x=px,y=py,u=du,v=dv", "--out", str(out)], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    m = json.loads((out / "metrics.json").read_text())["states"][0]
    measured = ~nan_uv & ~nan_all
    assert m["valid_points"] == measured.sum()
    assert m["not_measured_points"] == (nan_uv & ~nan_all).sum()
    assert m["rows_without_position"] == nan_all.sum()
    assert m["bias_v_px"] == pytest.approx(0.02, abs=1e-9) and m["bias_u_px"] == pytest.approx(0.0, abs=1e-9)
    assert f"{(nan_uv & ~nan_all).sum()} not measured" in proc.stdout
    assert f"{nan_all.sum()} rows without a finite x, y" in proc.stdout
    # --columns alone means a CSV: the same file scores the same without --format
    alone = subprocess.run([sys.executable, "-m", "workbench.cli", "score", str(pair.folder), str(path), "--columns",
                            "x=px,y=py,u=du,v=dv", "--out", str(tmp_path / "alone")], capture_output=True, text=True)
    assert alone.returncode == 0, alone.stderr
    again = json.loads((tmp_path / "alone" / "metrics.json").read_text())["states"][0]
    assert (again["valid_points"], again["bias_v_px"]) == (m["valid_points"], m["bias_v_px"])

    empty = tmp_path / "all_nan.csv"
    empty.write_text("px,py,du,dv\n" + "".join(f"{x[i]:g},{y[i]:g},nan,nan\n" for i in range(5)))
    proc = subprocess.run([sys.executable, "-m", "workbench.cli", "score", str(pair.folder), str(empty), "--format",
                           "csv", "--columns", "x=px,y=py,u=du,v=dv", "--out", str(tmp_path / "none")],
                          capture_output=True, text=True)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    assert "all_nan.csv: no row holds a finite position and displacement (u, v); all 5 rows" in proc.stderr
    with pytest.raises(ResultFormatError, match=r"all_nan\.csv: no row holds a finite"):
        read_result(empty, "csv", "x=px,y=py,u=du,v=dv")


def test_result_files_with_wrong_columns_are_refused(pair, tmp_path):
    bad = tmp_path / "bad.txt"
    bad.write_text("SUBSET_ID,COORD_X,COORDINATE_Y,DISPLACEMENT_X,DISPLACEMENT_Y\n0,1,2,3,4\n")
    with pytest.raises(ResultFormatError, match=r"bad.txt: no column 'COORDINATE_X'"):
        read_result(bad, "dice")
    text = tmp_path / "text.csv"
    text.write_text("px,py,du,dv\n1,2,abc,4\n")
    with pytest.raises(ResultFormatError, match=r"column 'du'.*row 1: 'abc' is not a number"):
        read_result(text, "csv", "x=px,y=py,u=du,v=dv")
    with pytest.raises(ValueError, match=r"--columns: 'q' is not one of"):
        parse_columns("x=px,y=py,q=du")
    with pytest.raises(ValueError, match=r"names no y column"):
        parse_columns("x=px,u=du,v=dv")
    with pytest.raises(ValueError, match=r"--format csv needs --columns"):
        read_result(text, "csv")


def test_pixel_origin_and_length_unit_are_applied(rigid, tmp_path):
    """One-based pixel coordinates and 3-D in µm: stated right they score zero; stated wrong the score shows it."""
    x, y = _grid(rigid, 8)
    pt = point_truth(rigid, x, y)
    path = tmp_path / "matlab.csv"
    with open(path, "w") as f:
        f.write("col,row,dX_um,dY_um,dZ_um\n")
        for i in np.flatnonzero(pt.valid):
            f.write(f"{x[i] + 1:g},{y[i] + 1:g}," + ",".join(f"{1e3 * d:.9g}" for d in pt.displacement_left_mm[1, i]) + "\n")
    cols = "x=col,y=row,U=dX_um,V=dY_um,W=dZ_um"
    right = score_state(rigid, 1, read_result(path, "csv", cols, "one-based", "um")).metrics
    assert right["rms_um"] < 1e-5
    wrong_unit = score_state(rigid, 1, read_result(path, "csv", cols, "one-based", "mm")).metrics
    assert wrong_unit["rms_um"] > 1e5                                    # 500 mm read where 0.5 mm was meant


def test_command_engine_and_python_engine_score_the_same(pair, tmp_path):
    """`workbench score --engine` with a real subprocess (our own CLI as 'another tool') and with the Python entry
    point give identical figures; both measure the known 0.25 px shift (|bias| < 0.005 px)."""
    docs = []
    for name, engine in (("cmd", "python -m workbench.cli dic {ref} {def} --subset {subset} --step {step} "
                                  "--roi {roi} --out {out}"),
                         ("py", "workbench.engines:ours")):
        out = tmp_path / name
        proc = subprocess.run([sys.executable, "-m", "workbench.cli", "score", str(pair.folder), "--engine",
                               engine.replace("python ", f"{sys.executable} ", 1), "--subset", "21", "--step", "6",
                               "--out", str(out)], capture_output=True, text=True)
        assert proc.returncode == 0, proc.stderr
        docs.append(json.loads((out / "metrics.json").read_text())["states"][0])
    assert docs[0]["valid_points"] == docs[1]["valid_points"] > 100
    assert docs[0]["rms_u_px"] == pytest.approx(docs[1]["rms_u_px"], abs=1e-9)
    assert abs(docs[0]["bias_u_px"]) < 0.005 and docs[0]["valid_fraction"] > 0.99


def test_engine_failures_are_named(pair, tmp_path):
    from workbench.engines import parse_engine, run_engine

    with pytest.raises(ValueError, match=r"unknown placeholder\(s\) \{reff\}"):
        parse_engine("tool {reff} {def} {out}")
    with pytest.raises(ValueError, match=r"the template needs \{out\}"):
        parse_engine("tool {ref} {def}")
    engine = parse_engine(f"{sys.executable} -c 'import sys; sys.exit(3)' {{ref}} {{def}} {{out}}")
    with pytest.raises(RuntimeError, match=r"engine exited with 3"):
        run_engine(engine, pair.images[0]["left"], pair.images[1]["left"], tmp_path / "r.csv", subset_px=21,
                   step_px=6, roi_xyxy_px=(20, 20, 100, 100))
    silent = parse_engine(f"{sys.executable} -c pass {{ref}} {{def}} {{out}}")
    with pytest.raises(RuntimeError, match=r"engine wrote no result file"):
        run_engine(silent, pair.images[0]["left"], pair.images[1]["left"], tmp_path / "r.csv", subset_px=21,
                   step_px=6, roi_xyxy_px=(20, 20, 100, 100))


def test_dice_export_is_a_complete_dice_input(pair, tmp_path):
    """The DICe layout: input.xml parses, names images that exist (same pixels as the dataset), the subset file
    holds the ROI polygon, and the truth array has the image's shape."""
    from measurement.image_io import read_grey
    from workbench.scoring.export import export_dataset

    out = tmp_path / "dice"
    export_dataset(pair, "dice", out, log=lambda *_: None)
    params = {p.get("name"): p.get("value") for p in ET.parse(out / "input.xml").getroot().iter("Parameter")}
    assert params["subset_size"] == "33" and params["subset_file"] == "subset_defs.txt"
    ref = out / params["reference_image"]
    np.testing.assert_array_equal(read_grey(ref), read_grey(pair.images[0]["left"]))
    deformed = [p.get("name") for p in ET.parse(out / "input.xml").getroot().find("ParameterList").iter("Parameter")]
    assert (out / deformed[0]).is_file()
    assert "begin region_of_interest" in (out / "subset_defs.txt").read_text()
    assert "dice -i input.xml" in (out / "README.md").read_text()
    with np.load(out / "truth" / "truth_reference.npz") as z:
        assert z["uv_left_px"].shape == (2, 160, 160, 2)
        assert float(z["uv_left_px"][1, 50, 50, 0]) == pytest.approx(0.25)
    with pytest.raises(ValueError, match=r"the export folder exists and is not empty"):
        export_dataset(pair, "dice", out, log=lambda *_: None)


def test_strain_columns_are_scored_against_the_exact_strain(pair, tmp_path):
    """A translation has zero strain: strain columns of 100 µε in exx (and 0 elsewhere) score a bias of exactly
    100 µε in xx and 0 in yy, xy; the same columns stated in µε score the same; unstated, they are refused."""
    from workbench.readers.conventions import StrainConvention, UnstatedStrainError

    x, y = _grid(pair, 16)
    pt = point_truth(pair, x, y)
    path = tmp_path / "strain.csv"
    with open(path, "w") as f:
        f.write("x,y,u,v,exx,eyy,exy\n")
        for i in range(x.size):
            f.write(f"{x[i]:g},{y[i]:g},{pt.uv_left_px[1, i, 0]:.9g},{pt.uv_left_px[1, i, 1]:.9g},1e-4,0,0\n")
    mapping = "x=x,y=y,u=u,v=v,exx=exx,eyy=eyy,exy=exy"
    with pytest.raises(UnstatedStrainError, match="maps strain columns, but not their convention"):
        read_result(path, "csv", mapping)
    m = score_state(pair, 1, read_result(path, "csv", mapping, strain_convention=StrainConvention())).metrics
    assert m["strain_bias_xx_microstrain"] == pytest.approx(100.0, abs=1e-6)
    micro = tmp_path / "micro.csv"
    micro.write_text(path.read_text().replace(",1e-4,0,0", ",100,0,0"))
    m2 = score_state(pair, 1, read_result(micro, "csv", mapping, strain_convention=StrainConvention(
        "green-lagrange", "tensor", "microstrain"))).metrics
    assert m2["strain_bias_xx_microstrain"] == pytest.approx(100.0, abs=1e-6)
    assert m["strain_rms_yy_microstrain"] == pytest.approx(0.0, abs=1e-6)
    assert m["strain_rms_xy_microstrain"] == pytest.approx(0.0, abs=1e-6)


@pytest.mark.parametrize("fmt", ["native", "dice", "vic3d", "matchid", "opencv"])
def test_exported_calibration_loads_back_and_its_reported_cost_is_true(rigid, tmp_path, fmt):
    """Each format's calibration loads back through our readers; its projection over the image against the true
    cameras (evaluated here on another grid) is what export.json reports: <= 1e-6 px where the format holds the
    model (our JSON, and our OpenCV YAML's named parameters), > 0.01 px where the paper rig's two-axis tilt does
    not fit (DICe's OpenCV tilt, VIC-3D and MatchID without tilt)."""
    from measurement.calibration.formats import load_any_calibration
    from workbench.scoring.datasets import true_rig
    from workbench.scoring.export import CALIBRATION_NAME, export_dataset

    out = tmp_path / fmt
    record = export_dataset(rigid, fmt, out, log=lambda *_: None)
    loaded = load_any_calibration(out / CALIBRATION_NAME[fmt], image_size_px=rigid.image_size_px)
    rig, _ = true_rig(rigid)
    for cam in record["calibration"]["cameras"]:
        true_cam, back = getattr(rig, cam["camera"]), getattr(loaded, cam["camera"])
        u, v = np.meshgrid(np.linspace(0, true_cam.width - 1, 37), np.linspace(0, true_cam.height - 1, 29))
        X = true_cam.rays(np.column_stack([u.ravel(), v.ravel()])) * 376.0
        d = np.linalg.norm(back.project(X) - true_cam.project(X), axis=1)
        if fmt == "native":
            assert d.max() < 1e-6 and cam["max_px"] < 1e-6
        elif fmt == "opencv":
            assert d.max() < 1e-6                  # our loader reads the exact named parameters
            assert cam["max_px"] > 0.01            # a K/D-only tool gets OpenCV's tilt order: the reported cost
        else:
            assert cam["max_px"] > 0.01
            assert d.max() <= cam["max_px"] * (1 + 1e-6) + 1e-9      # the report's grid includes the corners
            assert d.max() >= 0.5 * cam["max_px"] and d.mean() == pytest.approx(cam["mean_px"], rel=0.25)


def test_a_results_own_sigma_is_scored_by_its_coverage(rigid, tmp_path):
    """A native result with sigma columns: truth + Gaussian noise of 2 µm (seeded) claiming sigma 2 µm covers
    95 % +- 2.5 % of its errors within 1.96 sigma (RMS z ~ 1); claiming 1 µm covers far fewer."""
    from workbench.scoring.export import export_dataset

    export_dataset(rigid, "native", tmp_path / "export", log=lambda *_: None)
    with open(tmp_path / "export" / "truth" / "points.csv") as f:
        rows = [r for r in csv.DictReader(f) if r["state"] == "1" and r["valid"] == "1"]
    x = np.array([float(r["x_px"]) for r in rows])
    y = np.array([float(r["y_px"]) for r in rows])
    X = np.array([[float(r[k]) for k in ("X_mm", "Y_mm", "Z_mm")] for r in rows])
    U = np.array([[float(r[k]) for k in ("U_mm", "V_mm", "W_mm")] for r in rows])
    noise = np.random.default_rng(7).normal(0.0, 2e-3, U.shape)
    for claim_um, name in ((2.0, "honest_01.csv"), (1.0, "overconfident_01.csv")):
        with open(tmp_path / name, "w") as f:
            f.write("x,y,X,Y,Z,U,V,W,D,zncc,residual,status,status_name,sigma_U_um,sigma_V_um,sigma_W_um,"
                    "sigma_U_calib_um,sigma_V_calib_um,sigma_W_calib_um\n")
            for i in range(x.size):
                Ui = U[i] + noise[i]
                f.write(",".join(map(str, [x[i], y[i], *(X[i] + noise[i]), *Ui, np.linalg.norm(Ui), 1, 0, 0,
                                           "converged", claim_um, claim_um, claim_um, "nan", "nan", "nan"])) + "\n")
    honest = score_state(rigid, 1, read_result(tmp_path / "honest_01.csv")).metrics
    over = score_state(rigid, 1, read_result(tmp_path / "overconfident_01.csv")).metrics
    for c in "UVW":
        assert abs(honest[f"sigma_coverage_95_{c}"] - 0.95) < 0.025 + 2 * np.sqrt(0.05 * 0.95 / x.size), honest
        assert abs(honest[f"sigma_rms_z_{c}"] - 1.0) < 0.1
        assert over[f"sigma_coverage_95_{c}"] < 0.8
