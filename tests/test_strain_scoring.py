"""Strain as the field reads it (issue 37): the exact surface strain at any point of a dataset, a tool's strain scored
against the truth through its own window, the region of interest exported with its holes.

References are analytic: a flat plate with a linear FE displacement ``u = A X`` in the specimen frame, whose
Green-Lagrange strain is ``(F^T F - I) / 2`` with ``F = I + A`` everywhere (homogeneous, so any strain window
reproduces it exactly); synthetic masks whose erosion is checked against scipy's distance transform.
"""
from __future__ import annotations

import json

import numpy as np
import pytest

from test_specimen_dataset import A, _scenario


@pytest.fixture(scope="module")
def plate(tmp_path_factory):
    """The linear plate of test_specimen_dataset rendered at scale 0.1 (4 states: reference, two load steps, a
    static repeat moved in its plane)."""
    from workbench.cli import main
    from workbench.scoring.datasets import open_dataset

    folder = tmp_path_factory.mktemp("plate")
    scenario = _scenario(folder, scale=0.1)
    assert main(["render", "specimen", str(scenario), "--out", str(folder / "data")]) == 0
    return open_dataset(folder / "data")


def _analytic_world_strain(dataset, k: int) -> np.ndarray:
    """Green-Lagrange strain of state k in the left camera (world) frame: E = R (F^T F - I)/2 R^T, F = I + A_k."""
    doc = json.loads((dataset.folder / "truth.json").read_text())
    R = np.array(doc["R_world_from_specimen"])
    F = np.eye(3) + A[k]
    return R @ (0.5 * (F.T @ F - np.eye(3))) @ R.T


def _grid(dataset, step=6, margin=40):
    w, h = dataset.image_size_px
    X, Y = np.meshgrid(np.arange(margin, w - margin, step), np.arange(margin, h - margin, step))
    return X.ravel().astype(float), Y.ravel().astype(float)


def test_point_truth_strain_is_the_linear_plates_green_lagrange(plate):
    """At integer and sub-pixel points the exact surface strain of each load step equals (F^T F - I)/2 of the linear
    field turned into the left camera frame (1e-12; the field has no out-of-plane terms, so the surface strain is the
    whole tensor); the reference and the in-plane rigid repeat (state 3) strain nothing."""
    from workbench.scoring.datasets import point_truth

    x = np.array([120.0, 121.5, 130.25, 140.0])
    y = np.array([100.0, 100.0, 101.75, 120.5])
    pt = point_truth(plate, x, y, strain=True)
    assert pt.valid.all() and pt.strain_left.shape == (4, 4, 3, 3)
    for k in (1, 2):
        np.testing.assert_allclose(pt.strain_left[k], np.broadcast_to(_analytic_world_strain(plate, k), (4, 3, 3)),
                                   atol=1e-12)
    assert np.abs(pt.strain_left[[0, 3]]).max() < 1e-12
    outside = point_truth(plate, np.array([2.0]), np.array([2.0]), strain=True)
    assert not outside.valid[0] and np.isnan(outside.strain_left).all()


def _local_frame(X0_grid: np.ndarray, normal: np.ndarray):
    """e1: the mean grid column step projected onto the plane of ``normal``, e2 = n x e1 (the module's convention,
    written out again here)."""
    d = np.nanmean((X0_grid[:, 1:] - X0_grid[:, :-1]).reshape(-1, 3), axis=0)
    e1 = d - (d @ normal) * normal
    e1 /= np.linalg.norm(e1)
    return e1, np.cross(normal, e1)


def test_a_perfect_strain_scores_zero_and_an_offset_scores_itself(plate):
    """A 3-D result holding the analytic strain (components in the local frame worked out by hand) scores 0 against
    the window-filtered truth (1e-9: the window reproduces a homogeneous strain), and its peak e1 is the analytic
    principal strain; the same result with +100 µε on exx scores exactly that bias and RMS, with the peak 100 µε
    higher (the principal axis is x here: A is diagonal along the specimen's axes)."""
    from workbench.scoring.datasets import point_truth
    from workbench.scoring.strain import grid_layout, score_strain

    x, y = _grid(plate)
    pt = point_truth(plate, x, y, strain=True)
    layout = grid_layout(x, y)
    doc = json.loads((plate.folder / "truth.json").read_text())
    normal = np.array(doc["R_world_from_specimen"])[:, 2]
    e1, e2 = _local_frame(layout.on_grid(pt.X_left_mm[0]), normal)
    E = _analytic_world_strain(plate, 2)
    exact = np.array([e1 @ E @ e1, e2 @ E @ e2, e1 @ E @ e2])
    measured = np.where(pt.valid[:, None], exact, np.nan)
    s = score_strain(x, y, measured, pt.valid, pt.X_left_mm[0], pt.X_left_mm[2], pt.strain_left[2], 9, "linear")
    m = s.metrics
    assert m["strain_points"] > 200
    for c in ("exx", "eyy", "exy", "e1", "e2"):
        assert m[f"strain_rms_{c}_vs_windowed_microstrain"] < 1e-3, c
        assert m[f"strain_rms_{c}_vs_exact_microstrain"] < 1e-3, c
    # the largest principal strain of the 3-D tensor (its third, normal, eigenvalue is 0)
    assert m["strain_peak_e1_windowed_microstrain"] == pytest.approx(1e6 * np.linalg.eigvalsh(E)[-1], abs=1e-3)
    shifted = measured + np.array([100e-6, 0.0, 0.0])
    s2 = score_strain(x, y, shifted, pt.valid, pt.X_left_mm[0], pt.X_left_mm[2], pt.strain_left[2], 9, "linear")
    assert s2.metrics["strain_bias_exx_vs_windowed_microstrain"] == pytest.approx(100.0, abs=1e-3)
    assert s2.metrics["strain_rms_exx_vs_windowed_microstrain"] == pytest.approx(100.0, abs=1e-3)
    assert s2.metrics["strain_peak_e1_measured_microstrain"] == pytest.approx(
        m["strain_peak_e1_windowed_microstrain"] + 100.0, abs=0.5)
    assert s2.metrics["strain_peak_e1_error_percent"] == pytest.approx(
        100 * 100.0 / m["strain_peak_e1_windowed_microstrain"], rel=5e-3)


def test_a_strain_sigma_is_scored_by_its_coverage():
    """Synthetic: a measured strain = a homogeneous truth plus Gaussian errors of a known sigma; the sigma stated
    right covers 95 % (+-2 % with 4 000 points), stated at half the truth covers ~68 % (the normal law's 1.96/2)."""
    from scipy.stats import norm

    from workbench.scoring.strain import score_strain

    rng = np.random.default_rng(5)
    X, Y = np.meshgrid(np.arange(80.0), np.arange(50.0))
    x, y = X.ravel(), Y.ravel()
    X0 = np.column_stack([0.1 * x, 0.1 * y, np.full(x.size, 300.0)])
    F = np.array([[1.002, 0, 0], [0, 0.9994, 0], [0, 0, 1]])
    Xk = X0 @ F.T
    E = 0.5 * (F.T @ F - np.eye(3))
    exact = np.broadcast_to(E, (x.size, 3, 3))
    sigma = np.full((x.size, 3), 50e-6)
    measured = np.array([E[0, 0], E[1, 1], E[0, 1]]) + rng.normal(0.0, 50e-6, (x.size, 3))
    ok = np.ones(x.size, bool)
    m = score_strain(x, y, measured, ok, X0, Xk, exact, 5, "linear", sigma).metrics
    for c in ("exx", "eyy", "exy"):
        assert abs(m[f"strain_sigma_coverage_95_{c}"] - 0.95) < 0.02, c
    m_half = score_strain(x, y, measured, ok, X0, Xk, exact, 5, "linear", sigma / 2).metrics
    expected = 2 * norm.cdf(1.959964 / 2) - 1
    for c in ("exx", "eyy", "exy"):
        assert abs(m_half[f"strain_sigma_coverage_95_{c}"] - expected) < 0.03, c


def test_grid_layout_finds_the_grid_and_refuses_what_is_not_one():
    """Points of a 7 px grid (shuffled, holes) are put back on their nodes; a point off the grid and two points on one
    node are refused, naming the point."""
    from workbench.scoring.strain import grid_layout

    X, Y = np.meshgrid(10 + 7 * np.arange(9), 20 + 7 * np.arange(5))
    x, y = X.ravel().astype(float), Y.ravel().astype(float)
    keep = np.ones(x.size, bool)
    keep[[3, 17, 30]] = False
    order = np.random.default_rng(1).permutation(int(keep.sum()))
    xs, ys = x[keep][order], y[keep][order]
    layout = grid_layout(xs, ys)
    assert layout.shape == (5, 9) and layout.step_px == 7.0 and layout.origin_px == (10.0, 20.0)
    np.testing.assert_array_equal(10 + 7 * layout.cols, xs)
    np.testing.assert_array_equal(20 + 7 * layout.rows, ys)
    off_x, off_y = x.copy(), y.copy()
    off_x[12] += 3.5
    with pytest.raises(ValueError, match=r"point 12 at \(34.5, 27\) px is off the grid of step 7 px"):
        grid_layout(off_x, off_y)
    with pytest.raises(ValueError, match="two points of the result lie on one grid node"):
        grid_layout(np.append(x, x[5]), np.append(y, y[5]))


def test_roi_polygons_and_mask_exclude_a_hole_grown_by_the_margin():
    """A 200 x 160 px specimen view with a 40 px square hole: the outer polygon is the view shrunk by the margin, the
    one hole polygon the hole grown by it (a few px of polygon fit), and the mask is exactly the pixels whose
    Chebyshev distance to the nearest invalid pixel exceeds the margin (scipy's chessboard distance transform)."""
    from scipy.ndimage import distance_transform_cdt

    from workbench.scoring.datasets import poi_mask, roi_polygons_px

    valid = np.zeros((160, 200), bool)
    valid[10:150, 10:190] = True
    valid[60:100, 80:120] = False
    xs, ys = np.arange(200), np.arange(160)
    outer, holes = roi_polygons_px(valid, xs, ys, 5)
    assert np.allclose(outer.min(0), [15, 15], atol=1) and np.allclose(outer.max(0), [184, 144], atol=1)
    assert len(holes) == 1
    assert np.allclose(holes[0].min(0), [74, 54], atol=1.5) and np.allclose(holes[0].max(0), [125, 105], atol=1.5)
    mask = poi_mask(valid, xs, ys, (200, 160), 5)
    np.testing.assert_array_equal(mask, distance_transform_cdt(valid, metric="chessboard") > 5)
    with pytest.raises(ValueError, match="no region of the reference image sees the specimen 90 px from its edge"):
        roi_polygons_px(valid, xs, ys, 90)


def test_strain_window_option_is_checked():
    """--strain-window takes an odd number >= 3, 'triangles' or 'none' and names what it got otherwise."""
    import argparse

    from workbench.commands.options import strain_window_arg
    from measurement.stereo_strain import StrainSettings

    assert strain_window_arg("15") == 15 and strain_window_arg("Triangles") == "triangles"
    assert strain_window_arg("none") is None
    with pytest.raises(argparse.ArgumentTypeError, match=r"odd number of grid points >= 3, 'triangles' or 'none', got '8'"):
        strain_window_arg("8")
    with pytest.raises(ValueError, match="a quadratic strain fit needs a strain window"):
        StrainSettings(None, "quadratic")


def test_dense_truth_files_read_back_with_the_strain(plate, tmp_path):
    """The specimen dataset's truth_states.npz read by read_dense_truth: its strain tensor of each load step is the
    analytic one on every pixel that sees the plate (1e-6: the file is float32) and zero for the reference; the
    export's points.csv carries the same tensor per point (Exx_left ... columns), and its truth_reference.npz reads
    back as the export kind; a file of other keys is refused naming them."""
    import csv

    from workbench.scoring.datasets import DatasetError, read_dense_truth
    from workbench.scoring.export import export_dataset

    d = read_dense_truth(plate.folder / "truth_states.npz")
    assert d["kind"] == "specimen" and d["valid"].sum() > 100
    for k in (1, 2):
        np.testing.assert_allclose(d["strain_left"][k][d["valid"]], np.broadcast_to(
            _analytic_world_strain(plate, k), (int(d["valid"].sum()), 3, 3)), atol=1e-6)
    assert np.abs(d["strain_left"][0][d["valid"]]).max() < 1e-6
    export_dataset(plate, "native", tmp_path / "ex", log=lambda *a: None)
    with open(tmp_path / "ex" / "truth" / "points.csv") as f:
        rows = [r for r in csv.DictReader(f) if r["state"] == "2" and r["valid"] == "1"]
    E = _analytic_world_strain(plate, 2)
    assert len(rows) > 20
    for r in rows[:50]:
        got = np.array([float(r[f"E{c}_left"]) for c in ("xx", "yy", "zz", "yz", "xz", "xy")])
        np.testing.assert_allclose(got, [E[0, 0], E[1, 1], E[2, 2], E[1, 2], E[0, 2], E[0, 1]], atol=1e-9)
    assert read_dense_truth(tmp_path / "ex" / "truth" / "truth_reference.npz")["kind"] == "export"
    np.savez(tmp_path / "other.npz", a=np.zeros(2))
    with pytest.raises(DatasetError, match=r"other.npz: not a dense truth file \(keys a\)"):
        read_dense_truth(tmp_path / "other.npz")
