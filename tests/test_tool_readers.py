"""Readers of other tools' result files (issue 37): VIC-3D, MatchID and OpenCorr files in each tool's own layout, the
strain conventions they are converted from, and a layout nobody wrote refused with what it lacks.

References: excerpts of files the tools wrote (tests/data/tool_results, sources and licences in its README); the
tools' own principal-strain columns (computed by the tool from its components); scipy's matrix logarithm for the
strain measures; the linear plate's analytic field for the end-to-end score.
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from scipy.linalg import expm, logm

from workbench.readers.conventions import StrainConvention, UnstatedStrainError, to_green_lagrange
from workbench.results import ResultFormatError, read_result

DATA = Path(__file__).parent / "data" / "tool_results"
VIC = DATA / "vic3d_matcal_17_A-4B_pull-sys1-0000_0_excerpt.csv"
MATCHID = DATA / "matchid_pycoatl_Image_0007_0.tiff_excerpt.csv"
OPENCORR_2D = DATA / "opencorr_oht_cfrp_4_fftcc_icgn1_r16_excerpt.csv"
OPENCORR_3D = DATA / "opencorr_GT4-0273_0_epipolar_sift_r16_excerpt.csv"
GL = StrainConvention("green-lagrange", "tensor", "1")


def _rows(path):
    import csv

    lines = [ln for ln in path.read_text().splitlines() if ln.strip()]
    table = list(csv.reader(lines, skipinitialspace=True))
    return table[0], [[float(v) for v in r if v != ""] for r in table[1:]]


def test_vic3d_export_is_read_with_its_failed_points():
    """VIC-3D's own export: the quoted header with spaces, the 3 rows with sigma = -1 are failed points (their
    placeholder X, Y, Z dropped), the 6 correlated rows keep x, y, sigma, and X + U as the deformed position; its
    strain is refused until its convention is stated."""
    with pytest.raises(UnstatedStrainError, match=r"VIC export does not say which .*--strain-measure"):
        read_result(VIC, "vic3d")
    r = read_result(VIC, "auto", strain_convention=GL)
    assert r.tool == "VIC-3D" and r.x_px.size == 9
    np.testing.assert_array_equal(r.valid, [False] * 3 + [True] * 6)
    np.testing.assert_array_equal(r.x_px[3:], [23, 30, 37, 44, 51, 58])
    assert np.isnan(r.X_mm[:3]).all() and np.isnan(r.surface_strain[:3]).all()
    np.testing.assert_allclose(r.X_mm[3], [-20.4429, 14.3056, 1.04376])
    np.testing.assert_allclose(r.sigma_uv_px[3], [0.0137084, 0.0137084])
    ignored = read_result(VIC, "vic3d", ignore_strain=True)
    assert ignored.surface_strain is None and ignored.valid.sum() == 6


def test_matchid_export_follows_tensor_shear_and_its_unit_is_checked():
    """MatchID's 2024 export: recognised by its header; U, V, W in mm; its Exx, Eyy, Exy as tensor shear give the
    file's own principal strains EI, EII (computed by MatchID) to the file's 6 digits; engineering shear stated for it
    is refused naming tensor; a stated unit other than the file's [ ] is refused."""
    header, rows = _rows(MATCHID)
    table = np.array(rows)
    r = read_result(MATCHID, "auto", strain_convention=GL)
    assert r.tool == "MatchID" and r.valid.all() and r.x_px.size == 12
    np.testing.assert_array_equal(r.x_px, table[:, 0])
    np.testing.assert_allclose(r.U_mm, table[:, 5:8])
    np.testing.assert_allclose(r.X_mm, table[:, 2:5] + table[:, 5:8])
    E = r.surface_strain
    mean, radius = 0.5 * (E[:, 0] + E[:, 1]), np.hypot(0.5 * (E[:, 0] - E[:, 1]), E[:, 2])
    np.testing.assert_allclose(mean + radius, table[:, 12], rtol=0, atol=2e-9)
    np.testing.assert_allclose(mean - radius, table[:, 13], rtol=0, atol=2e-9)
    with pytest.raises(ValueError, match=r"--strain-shear engineering, but the file's principal strains .* are those "
                                         r"of tensor shear"):
        read_result(MATCHID, "matchid", strain_convention=StrainConvention("green-lagrange", "engineering", "1"))
    with pytest.raises(ValueError, match=r"--strain-unit % but the file's strain columns are in \[ \]"):
        read_result(MATCHID, "matchid", strain_convention=StrainConvention("green-lagrange", "tensor", "%"))


def test_opencorr_tables_2d_and_stereo(tmp_path):
    """OpenCorr's 2-D table (older writer) and the same with the current writer's trailing delimiter read alike; a
    negative ZNCC (OpenCorr's failure code -4) is a failed point; the stereo table's deformed position is tar_* and its
    displacement u, v, w, which is tar - ref in the file itself (1e-6 mm)."""
    r = read_result(OPENCORR_2D, "auto", strain_convention=StrainConvention("cauchy", "tensor", "1"))
    header, rows = _rows(OPENCORR_2D)
    table = np.array(rows)
    assert r.tool == "OpenCorr" and r.valid.all()
    np.testing.assert_allclose(np.column_stack([r.u_px, r.v_px]), table[:, 2:4])
    trailing = tmp_path / "trailing.csv"
    lines = OPENCORR_2D.read_text().splitlines()
    lines[3] = lines[3].replace(",0.99756569,", ",-4,")
    trailing.write_text("\n".join(ln + "," for ln in lines) + "\n")
    t = read_result(trailing, "opencorr", strain_convention=StrainConvention("cauchy", "tensor", "1"))
    assert t.valid.sum() == r.valid.sum() - 1 and not t.valid[2]
    np.testing.assert_array_equal(t.u_px[t.valid], r.u_px[t.valid])
    s = read_result(OPENCORR_3D, "auto")
    header, rows = _rows(OPENCORR_3D)
    table = np.array(rows)
    col = {n: table[:, header.index(n)] for n in header}
    assert s.has_3d and s.valid.all() and s.surface_strain is None
    np.testing.assert_allclose(s.X_mm, np.column_stack([col["tar_x"], col["tar_y"], col["tar_z"]]))
    np.testing.assert_allclose(s.U_mm, s.X_mm - np.column_stack([col["ref_x"], col["ref_y"], col["ref_z"]]),
                               atol=1e-6)


def test_a_table_of_no_known_layout_names_its_columns_and_what_each_layout_lacks(tmp_path):
    """A CSV with pixel columns but a displacement named otherwise: refused naming its columns and every layout's
    required columns, with the way out (--format csv --columns)."""
    path = tmp_path / "mine.csv"
    path.write_text("px,py,dx,dy\n1,2,0.1,0.2\n")
    with pytest.raises(ResultFormatError, match=r"its columns \(px, py, dx, dy\) match no known layout\. The layouts "
                                                r"need — native: .*vic3d: x, y, sigma.*--format csv"):
        read_result(path, "auto")


@pytest.mark.parametrize("measure", ["engineering", "hencky", "euler-almansi"])
def test_strain_measures_convert_to_green_lagrange(measure):
    """A stretch U with principal axes at 30 deg (no rotation): Biot U - I, Hencky log U and Euler-Almansi
    (I - U^-2)/2 (scipy's logm), in % with engineering shear, all convert to (U^2 - I)/2 to 1e-12."""
    c, s = np.cos(np.radians(30)), np.sin(np.radians(30))
    Q = np.array([[c, -s], [s, c]])
    U = Q @ np.diag([1.02, 0.994]) @ Q.T
    E = 0.5 * (U @ U - np.eye(2))
    e = {"engineering": U - np.eye(2), "hencky": np.real(logm(U)),
         "euler-almansi": 0.5 * (np.eye(2) - np.linalg.inv(U @ U))}[measure]
    out = to_green_lagrange([100 * e[0, 0]], [100 * e[1, 1]], [200 * e[0, 1]], StrainConvention(measure, "engineering",
                                                                                                 "%"))
    np.testing.assert_allclose(out[0], [E[0, 0], E[1, 1], E[0, 1]], atol=1e-12)
    assert np.allclose(expm(logm(U)), U)          # the reference itself is sound


def test_a_vic3d_file_of_the_truth_scores_its_injected_errors(tmp_path):
    """End to end: a VIC-3D export written from the linear plate's truth (VIC's header, sigma = -1 on some rows, X, Y, Z
    the reference position, W off by +1 µm, strain as Hencky in % with engineering shear) is recognised by `score`
    without --format, its W bias is 1 µm (1e-6), its failed rows are not measured, and its strain, converted back,
    equals the truth through the window (1e-3 µε)."""
    from test_specimen_dataset import A, _scenario
    from workbench.cli import main
    from workbench.scoring.datasets import open_dataset, point_truth

    assert main(["render", "specimen", str(_scenario(tmp_path, scale=0.1)), "--out", str(tmp_path / "data")]) == 0
    ds = open_dataset(tmp_path / "data")
    w, h = ds.image_size_px
    X, Y = np.meshgrid(np.arange(40, w - 40, 6), np.arange(40, h - 40, 6))
    x, y = X.ravel().astype(float), Y.ravel().astype(float)
    pt = point_truth(ds, x, y)
    on = pt.valid
    x, y = x[on], y[on]
    X0, Uk = pt.X_left_mm[0][on], (pt.X_left_mm[2] - pt.X_left_mm[0])[on]
    doc = json.loads((tmp_path / "data" / "truth.json").read_text())
    R = np.array(doc["R_world_from_specimen"])
    F = np.eye(3) + A[2]
    E3 = R @ (0.5 * (F.T @ F - np.eye(3))) @ R.T
    from workbench.scoring.strain import grid_layout

    failed = np.zeros(x.size, bool)
    failed[::17] = True
    # the frame's x: the mean column step over the grid's measured neighbours (the strain module's convention)
    G = grid_layout(x, y).on_grid(np.where(failed[:, None], np.nan, X0))
    d = np.nanmean((G[:, 1:] - G[:, :-1]).reshape(-1, 3), axis=0)
    n = R[:, 2]
    e1 = d - (d @ n) * n
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(n, e1)
    E2 = np.array([[e1 @ E3 @ e1, e1 @ E3 @ e2], [e1 @ E3 @ e2, e2 @ E3 @ e2]])
    lam, vec = np.linalg.eigh(E2)
    H = vec @ np.diag(0.5 * np.log1p(2 * lam)) @ vec.T          # Hencky from Green-Lagrange, principal by principal
    path = tmp_path / "vic" / "dataset-0002_0.csv"
    path.parent.mkdir()
    names = ["X", "Y", "Z", "U", "V", "W", "exx", "eyy", "exy", "sigma", "x", "y", "u", "v"]
    lines = [" " + ",  ".join(f'"{c}"' for c in names)]
    for i in range(x.size):
        U = Uk[i] + np.array([0.0, 0.0, 1e-3])
        sigma = -1 if failed[i] else 0.01
        lines.append(",".join(f"{v:.10g}" for v in (*X0[i], *U, 100 * H[0, 0], 100 * H[1, 1], 200 * H[0, 1], sigma,
                                                    x[i], y[i], *pt.uv_left_px[2][on][i])))
    path.write_text("\n".join(lines) + "\n\n")
    assert main(["score", str(tmp_path / "data"), str(path), "--strain-measure", "hencky", "--strain-shear",
                 "engineering", "--strain-unit", "%", "--strain-window", "9", "--out", str(tmp_path / "sc")]) == 0
    m = json.loads((tmp_path / "sc" / "metrics.json").read_text())["states"][0]
    assert m["state"] == 2 and m["not_measured_points"] == failed.sum()
    assert m["bias_W_um"] == pytest.approx(1.0, abs=1e-6)
    assert m["bias_U_um"] == pytest.approx(0.0, abs=1e-6)
    for c in ("exx", "eyy", "exy", "e1"):
        assert m[f"strain_rms_{c}_vs_windowed_microstrain"] < 1e-3, c


MULTIDIC = DATA / "multidic_DIC2DpairResults_C_201_C_202_excerpt.mat"


def _write_mat73(path, variables: dict) -> None:
    """A MATLAB v7.3 file as MATLAB writes one (HDF5 behind a 512-byte user block naming it): dicts are structs,
    ``("cell", [arrays])`` cells, ``("structarray", {field: [arrays]})`` struct arrays, arrays stored transposed."""
    import h5py

    with h5py.File(path, "w", userblock_size=512) as f:
        refs = f.create_group("#refs#")
        count = [0]

        def array(group, name, value):
            ds = group.create_dataset(name, data=np.asarray(value, float).T)
            ds.attrs["MATLAB_class"] = np.bytes_("double")
            return ds

        def ref_list(group, name, arrays, cls):
            rs = []
            for a in arrays:
                count[0] += 1
                rs.append(array(refs, f"r{count[0]}", a).ref)
            ds = group.create_dataset(name, data=np.array(rs, dtype=h5py.ref_dtype).reshape(-1, 1))
            ds.attrs["MATLAB_class"] = np.bytes_(cls)

        def put(group, name, value):
            if isinstance(value, dict):
                sub = group.create_group(name)
                sub.attrs["MATLAB_class"] = np.bytes_("struct")
                for k, v in value.items():
                    put(sub, k, v)
            elif isinstance(value, tuple) and value[0] == "cell":
                ref_list(group, name, value[1], "cell")
            elif isinstance(value, tuple) and value[0] == "cellstruct":        # a cell of structs
                rs = []
                for k, struct in enumerate(value[1]):
                    count[0] += 1
                    sub = refs.create_group(f"s{count[0]}")
                    sub.attrs["MATLAB_class"] = np.bytes_("struct")
                    for key, v in struct.items():
                        put(sub, key, v)
                    rs.append(sub.ref)
                ds = group.create_dataset(name, data=np.array(rs, dtype=h5py.ref_dtype).reshape(-1, 1))
                ds.attrs["MATLAB_class"] = np.bytes_("cell")
            elif isinstance(value, tuple) and value[0] == "structarray":
                sub = group.create_group(name)
                sub.attrs["MATLAB_class"] = np.bytes_("struct")
                for k, arrays in value[1].items():
                    ref_list(sub, k, arrays, "double")
            else:
                array(group, name, np.atleast_2d(value))

        for k, v in variables.items():
            put(f, k, v)
    with open(path, "r+b") as handle:
        handle.write(b"MATLAB 7.3 MAT-file, Platform: GLNXA64, written by the workbench's tests".ljust(128, b" "))


def test_multidic_pair_results_are_read_from_its_own_file():
    """MultiDIC's DIC2DpairResults (an excerpt of its committed sample: 40 points, 5 images x 2 cameras): recognised,
    4 deformed states of camera 201, x, y the 1-based Points{1} minus 1, u, v = Points{k+1} - Points{1}, as h5py
    reads the file directly (an independent read of the same file)."""
    import h5py

    from workbench.results import detect_format, read_results

    assert detect_format(MULTIDIC) == "multidic"
    results = read_results(MULTIDIC)
    assert [r.state for r in results] == [1, 2, 3, 4] and all(r.valid.all() for r in results)
    with h5py.File(MULTIDIC, "r") as f:
        cells = [np.array(f[ref]) for ref in f["DIC2DpairResults/Points"][0]]
    np.testing.assert_array_equal(results[0].x_px, cells[0][0] - 1)
    np.testing.assert_array_equal(results[0].y_px, cells[0][1] - 1)
    np.testing.assert_allclose(results[2].u_px, cells[3][0] - cells[0][0])
    np.testing.assert_allclose(results[2].v_px, cells[3][1] - cells[0][1])
    with pytest.raises(ValueError, match="holds every state; read it with read_results"):
        read_result(MULTIDIC, "multidic")


def test_an_ncorr_file_of_the_truth_scores_its_injected_bias(tmp_path):
    """An Ncorr data_dic_save written from a dic2d pair's truth (0.25 px shift) in mm (pixtounits 0.02), on Ncorr's
    reduced grid (spacing 4: pixel = 5 x grid index), zeros outside its ROI, u off by +0.01 px: `score` recognises
    it, leaves the zeros out and scores a u bias of 0.01 px (1e-9), v 0."""
    from workbench.cli import main
    from workbench.scoring.datasets import open_dataset, point_truth

    scenario = tmp_path / "pair.toml"
    scenario.write_text('experiment = "dic2d"\n[render]\nread_noise_grey = 2.0\nbit_depth = 0\n'
                        '[image2d]\nsize_px = 160\nshift_x_px = 0.25\n')
    ds = open_dataset(scenario, tmp_path / "store")
    rows, cols = np.indices((32, 32))
    x, y = 5.0 * cols, 5.0 * rows
    uv = point_truth(ds, x.ravel(), y.ravel()).uv_left_px[1].reshape(32, 32, 2)
    inside = (x >= 20) & (x <= 140) & (y >= 20) & (y <= 140)
    u = np.where(inside, (uv[..., 0] + 0.01) * 0.02, 0.0)
    v = np.where(inside, uv[..., 1] * 0.02, 0.0)
    path = tmp_path / "ncorr_results.mat"
    _write_mat73(path, {"data_dic_save": {
        "dispinfo": {"spacing": 4.0, "radius": 15.0, "pixtounits": 0.02},
        "displacements": ("structarray", {"plot_u_ref_formatted": [u], "plot_v_ref_formatted": [v]})}})
    assert main(["score", str(scenario), str(path), "--store", str(tmp_path / "store"), "--out",
                 str(tmp_path / "sc")]) == 0
    m = json.loads((tmp_path / "sc" / "metrics.json").read_text())["states"][0]
    assert m["state"] == 1 and m["valid_points"] == int(inside.sum())
    assert m["bias_u_px"] == pytest.approx(0.01, abs=1e-9) and m["bias_v_px"] == pytest.approx(0.0, abs=1e-9)


def test_multidic_3d_results_in_their_own_frame_score_after_one_rigid_fit(tmp_path):
    """MultiDIC's DIC3Dcombined written from the linear plate's truth in another frame (turned 20 deg, moved 100 mm:
    its calibration object's): the pixels from its first pair's Points{1} (1-based); scored with --align rigid, the
    displacement error is 0 (1e-6 µm); without, the report says the frame is not the left camera's."""
    from scipy.spatial.transform import Rotation

    from test_specimen_dataset import _scenario
    from workbench.cli import main
    from workbench.scoring.datasets import open_dataset, point_truth

    assert main(["render", "specimen", str(_scenario(tmp_path, scale=0.1)), "--out", str(tmp_path / "data")]) == 0
    ds = open_dataset(tmp_path / "data")
    w, h = ds.image_size_px
    X, Y = np.meshgrid(np.arange(40, w - 40, 8.0), np.arange(40, h - 40, 8.0))
    pt = point_truth(ds, X.ravel(), Y.ravel())
    keep = pt.valid
    x, y = X.ravel()[keep], Y.ravel()[keep]
    R = Rotation.from_euler("xyz", [20, -5, 8], degrees=True).as_matrix()
    t = np.array([100.0, -20.0, 5.0])
    P = [pt.X_left_mm[k][keep] @ R.T + t for k in range(ds.n_states)]
    pixels = np.column_stack([x + 1, y + 1])                       # MATLAB's 1-based
    pair = {"nImages": float(ds.n_states), "nCamRef": 1.0, "nCamDef": 2.0,
            "Points": ("cell", [pixels] * ds.n_states + [pixels] * ds.n_states)}
    path = tmp_path / "DIC3Dcombined_1Pairs.mat"
    _write_mat73(path, {"DIC3Dcombined": {"Points3D": ("cell", P), "AllPairsResults": ("cellstruct", [pair])}})
    assert main(["score", str(tmp_path / "data"), str(path), "--align", "rigid", "--out", str(tmp_path / "sc")]) == 0
    states = json.loads((tmp_path / "sc" / "metrics.json").read_text())["states"]
    assert [s["state"] for s in states] == list(range(1, ds.n_states))
    assert all(s["rms_um"] < 1e-6 and s["valid_points"] == keep.sum() for s in states)
    assert main(["score", str(tmp_path / "data"), str(path), "--out", str(tmp_path / "sc2")]) == 0
    hint = json.loads((tmp_path / "sc2" / "metrics.json").read_text())["states"][0]["frame_hint"]
    assert "does not look like the left camera frame" in hint
