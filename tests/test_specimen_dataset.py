"""A specimen of one's own through the workbench (issue 23): the scenario's [specimen] section, ``workbench render
specimen``, the dataset's truth at any pixel, the store's hash, the study case and scoring.

References are analytic: a flat plate with a linear FE displacement (its material point under any ray is a
ray-plane intersection, its displacement the linear field's value)."""
from __future__ import annotations

import json

import numpy as np
import pytest
import skfem
from skfem.io.meshio import to_meshio

from scenes.specimens.fe_files import write_exodus

#: The plate's linear displacement per state: u = A_k X + b_k (mm).
A = [np.zeros((3, 3)), np.diag([1e-3, -0.3e-3, 0.0]), np.diag([2e-3, -0.6e-3, 0.0])]
B = [np.zeros(3), np.zeros(3), np.array([0.05, 0.0, 0.02])]


def _plate(folder, name="plate.e"):
    m = to_meshio(skfem.MeshTet.init_tensor(np.linspace(-30, 30, 7), np.linspace(-20, 20, 5), np.linspace(0, 3, 2)))
    P = m.points
    U = np.stack([P @ a.T + b for a, b in zip(A, B)])
    write_exodus(folder / name, P, {"tetra": m.cells[0].data}, U, times=[0.0, 1.0, 2.0])
    return folder / name


def _scenario(folder, scale=0.1, extra=""):
    _plate(folder)
    path = folder / "plate.toml"
    path.write_text(f'experiment = "specimen"\nseed = 3\n[rig]\nname = "paper"\nscale = {scale}\n'
                    f'[specimen]\nmesh = "plate.e"\n{extra}')
    return path


def test_render_specimen_writes_a_dataset_whose_truth_is_the_analytic_plate(tmp_path, capsys):
    """CLI render of an Exodus plate: images and truth of 3 states; at integer and sub-pixel points of the left
    reference image the truth equals the ray-plane intersection moved by the linear field (1e-9 mm); the static state
    is state 0 moved by (0.5, 0.5) pixel footprints."""
    from workbench.cli import main
    from workbench.scoring.datasets import open_dataset, point_truth
    from scenes.optics.projection import pixel_rays

    scenario = _scenario(tmp_path)
    assert main(["render", "specimen", str(scenario), "--out", str(tmp_path / "out")]) == 0
    assert "left reference:" in capsys.readouterr().out
    ds = open_dataset(tmp_path / "out")
    assert ds.kind == "specimen" and ds.n_states == 4 and ds.labels[1] == "step 1 (t = 1)"
    assert ds.labels[3] == "static: state 0 moved by (0.5, 0.5) px in its plane, new noise"
    doc = json.loads((tmp_path / "out" / "truth.json").read_text())
    R0, t0 = np.array(doc["R_world_from_specimen"]), np.array(doc["t_world_from_specimen_mm"])
    spec_cam = doc["cameras"]["left"]
    from scenes.optics.camera import SensorSpec
    spec = SensorSpec(**spec_cam["sensor_spec"])
    # the mesh's origin (default: bounding-box centre in x, y; smallest z) is the specimen frame's origin
    shift = np.array([0.0, 0.0, 0.0])
    x = np.array([120.0, 121.5, 130.25, 140.0])
    y = np.array([100.0, 100.0, 101.75, 120.5])
    pt = point_truth(ds, x, y)
    assert pt.valid.all()
    o, d = pixel_rays(spec, np.array(spec_cam["R_cam_from_world"]), np.array(spec_cam["t_cam_from_world_mm"]),
                      np.column_stack([x, y]))
    o_s, d_s = (o - t0) @ R0, d @ R0
    lam = -o_s[:, 2] / d_s[:, 2]
    X = o_s + lam[:, None] * d_s + shift                     # on the plate's face z = 0 (specimen frame)
    # the static state repeats state 0 moved by half a pixel footprint (at the working distance) along x and y
    offset = np.array([0.5, 0.5, 0.0]) * np.linalg.norm(t0) / spec.fx
    for k in range(4):
        a, b = (A[k], B[k]) if k < 3 else (A[0], B[0] + offset)
        expected = (X + X @ a.T + b) @ R0.T + t0
        assert np.abs(pt.X_left_mm[k] - expected).max() < 1e-9


def test_specimen_out_of_view_names_the_camera(tmp_path, capsys):
    """A plate moved 500 mm off the axes: the command fails (exit 2) naming the file and the camera; nothing written."""
    from workbench.cli import main

    scenario = _scenario(tmp_path, extra="offset_mm = [0.0, 500.0, 0.0]\n")
    assert main(["render", "specimen", str(scenario), "--out", str(tmp_path / "out")]) == 2
    assert "plate.e: the left camera sees no measurable point of the specimen" in capsys.readouterr().err
    assert not (tmp_path / "out").exists() or not any((tmp_path / "out").iterdir())


def test_dataset_hash_follows_the_file_content_not_its_place(tmp_path):
    from workbench.config import load_config
    from workbench.scenario import Scenario, dataset_parts, with_specimen_paths

    path = _scenario(tmp_path)
    (tmp_path / "b").mkdir()
    _plate(tmp_path / "b")
    a = with_specimen_paths(load_config(Scenario, path), tmp_path)
    b = with_specimen_paths(load_config(Scenario, path), tmp_path / "b")
    assert dataset_parts(a)["states"][0] == dataset_parts(b)["states"][0]
    m = to_meshio(skfem.MeshTet.init_tensor(np.linspace(-30, 30, 7), np.linspace(-20, 20, 5), np.linspace(0, 3, 2)))
    write_exodus(tmp_path / "b" / "plate.e", m.points, {"tetra": m.cells[0].data},
                 np.zeros((2,) + m.points.shape))
    assert dataset_parts(a)["states"][0] != dataset_parts(b)["states"][0]


def test_rigid_move_of_the_plate_is_measured_without_bias(tmp_path):
    """The study case on the plate moved rigidly by 0.1 mm (after its undeformed step): the instrument with the true
    rig measures the move with a mean 3-D error under 2 um (1 % of the 0.17 mm pixel footprint at this scale) and
    every reference point measured."""
    from workbench.config import load_config
    from workbench.scenario import Instrument, Scenario, with_specimen_paths
    from workbench.store import DatasetStore
    from workbench.studies.cases import run_case

    path = _scenario(tmp_path, scale=0.2, extra="steps = [0]\nrigid_states = 1\nrigid_step_mm = [0.1, 0.0, 0.0]\n")
    scenario = with_specimen_paths(load_config(Scenario, path), tmp_path)
    out = run_case(scenario, Instrument(calibration="true", subset_px=33, step_px=12), DatasetStore(tmp_path / "store"))
    m = out["metrics"]
    assert out["coords"]["state"] == [1, 2]            # the move, then the static repeat of state 0
    assert m["points_fraction"][0] == 1.0
    assert m["mean_displacement_error_um"][0] < 2.0


def test_speckle_finer_than_two_pixels_is_warned(tmp_path):
    """Speckles of 0.1 mm on the plate image at ~0.3 px at scale 0.1: the scene is set up with a warning naming
    the file, the camera and the size (aliasing; 3-5 px is good practice)."""
    from workbench.config import load_config
    from workbench.experiments.specimen.scenes import specimen_truth
    from workbench.scenario import Scenario, with_specimen_paths

    path = _scenario(tmp_path, extra="speckle_mm = 0.1\ntexel_mm = 0.02\n")
    scenario = with_specimen_paths(load_config(Scenario, path), tmp_path)
    with pytest.warns(UserWarning, match=r"plate.e in the left camera: speckles of 0.1 mm image at 0.\d+ px \(< 2 px") \
            as record:
        truth = specimen_truth(scenario)
    aliased = [str(w.message) for w in record if "aliased" in str(w.message)]
    assert len(aliased) == 2 and "in the right camera" in aliased[1]
    assert truth.info["paint"]["speckle_mm"] == 0.1              # warned, not refused: the scene is still made


def test_specimen_through_export_stereo_and_score_clis(tmp_path, capsys):
    """The README's path for a specimen of one's own: render, export (calibration + images), `workbench stereo`, then
    `workbench score` of all its state CSVs at once, no --state: each is scored against the state of the images it
    measured (issue 35: state_000.csv was taken for the reference and every other file scored against the next load
    step). Every state within 10 um RMS at scale 0.2 (the plate's linear field, 30-60 um of motion that grows with
    the state: a file scored against another state's truth is off by 25 um or more)."""
    import json as _json

    from workbench.cli import main

    scenario = _scenario(tmp_path, scale=0.2)
    data, ex, st, sc = (tmp_path / n for n in ("data", "export", "stereo", "score"))
    assert main(["render", "specimen", str(scenario), "--out", str(data)]) == 0
    assert main(["export", str(data), "--format", "native", "--out", str(ex)]) == 0
    images = sorted(p.name for p in ex.iterdir() if p.suffix == ".png")
    left = [n for n in images if n.startswith("left")]
    right = [n for n in images if n.startswith("right")]
    assert len(left) == 4 and len(right) == 4
    assert main(["stereo", "--calib", str(ex / "calibration.json"), "--left-ref", str(ex / left[0]),
                 "--right-ref", str(ex / right[0]), "--left", str(ex / "left_0[1-3]*"),
                 "--right", str(ex / "right_0[1-3]*"), "--subset", "33", "--step", "12", "--auto-roi",
                 "--out", str(st)]) == 0
    results = sorted(st.glob("state_*.csv"))
    # one numbering of states everywhere: the reference is state 0, the first deformed pair state 1
    assert [p.name for p in results] == ["state_001.csv", "state_002.csv", "state_003.csv"]
    capsys.readouterr()
    assert main(["score", str(data), *map(str, results), "--out", str(sc)]) == 0
    m = _json.loads((sc / "metrics.json").read_text())
    assert [s["state"] for s in m["states"]] == [1, 2, 3]
    for state in m["states"]:
        assert state["valid_points"] > 100
        assert state["rms_um"] < 10.0, state
    # strain (issue 37): every state file carries it, its window is in the manifest, and score compares it with the
    # truth through that window: for the linear field the filtered peak is the analytic (F^T F - I)/2's largest
    # principal value, a + a^2/2 with a = 1e-3, 2e-3 (1e-6 relative), and the measured peak is within 10 % of it
    header = results[0].read_text().splitlines()[0].split(",")
    assert header[-9:] == ["exx", "eyy", "exy", "e1", "e2", "strain_angle_deg", "sigma_exx", "sigma_eyy", "sigma_exy"]
    strain = _json.loads((st / "manifest.json").read_text())["settings"]["strain"]
    assert strain["window_points"] == 9 and strain["measure"] == "green-lagrange"
    assert strain["gauge_px"] == (9 - 1) * 12 + 33
    for state, a in zip(m["states"][:2], (1e-3, 2e-3)):
        assert state["strain_peak_e1_windowed_microstrain"] == pytest.approx(1e6 * (a + a * a / 2), rel=1e-6)
        assert abs(state["strain_peak_e1_error_percent"]) < 10.0, state
    assert np.isnan(m["states"][2]["strain_peak_e1_error_percent"])       # the static repeat has no peak

    # the score report a user would show: a line profile, a virtual extensometer and the user's mask (the exported
    # ROI mask, cut to its left half); report.html is whole (every figure decodes)
    import cv2

    from workbench.reporting.html_report import check_html_report
    from workbench.scoring.datasets import open_dataset, point_truth

    mask = cv2.imread(str(ex / "truth" / "roi_mask_left.png"), cv2.IMREAD_GRAYSCALE)
    half = mask.copy()
    half[:, half.shape[1] // 2:] = 0
    cv2.imwrite(str(tmp_path / "half.png"), half)
    ds = open_dataset(data)
    h, w = mask.shape
    ends = (w * 0.25, h * 0.5, w * 0.45, h * 0.5)
    sc4 = tmp_path / "sc4"
    assert main(["score", str(data), *map(str, results), "--line", f"{w * 0.1:g},{h / 2:g},{w * 0.45:g},{h / 2:g}",
                 "--extensometer", ",".join(f"{v:g}" for v in ends), "--mask", str(tmp_path / "half.png"),
                 "--out", str(sc4)]) == 0
    m4 = _json.loads((sc4 / "metrics.json").read_text())
    rows = [r.split(",") for r in results[0].read_text().splitlines()[1:]]
    x, y = np.array([float(r[0]) for r in rows]), np.array([float(r[1]) for r in rows])
    outside = int(np.sum(half[np.rint(y).astype(int), np.rint(x).astype(int)] == 0))
    assert m4["states"][0]["outside_mask_points"] == outside > 0
    assert m4["states"][0]["valid_points"] < m["states"][0]["valid_points"]
    # the extensometer's truth is the linear field's stretch of the chord between its two material points: |F d| / |d|
    doc = _json.loads((data / "truth.json").read_text())
    R = np.array(doc["R_world_from_specimen"])
    X0 = point_truth(ds, [ends[0], ends[2]], [ends[1], ends[3]]).X_left_mm[0]
    d = R.T @ (X0[1] - X0[0])
    for row, k in zip(m4["extensometers"][0]["states"], (1, 2)):
        stretch = np.linalg.norm((np.eye(3) + A[k]) @ d) / np.linalg.norm(d) - 1.0
        assert row["true_strain_microstrain"] == pytest.approx(1e6 * stretch, abs=1e-3)
        assert abs(row["error_microstrain"]) < 200.0, row          # ~2 µm noise at the ends of a ~9 mm gauge
    assert (sc4 / "profiles.csv").is_file() and (sc4 / "profile_L1.png").is_file()
    assert len(check_html_report(sc4 / "report.html")["figures"]) >= 5
    # a mask of another size is refused naming both sizes, and nothing is written
    cv2.imwrite(str(tmp_path / "small.png"), half[:-2])
    assert main(["score", str(data), str(results[0]), "--mask", str(tmp_path / "small.png"),
                 "--out", str(tmp_path / "sc5")]) == 2
    assert f"is {w} x {h - 2} px but the dataset's images are {w} x {h} px" in capsys.readouterr().err
    assert not (tmp_path / "sc5").exists()

    # a wrong --state beside the images' own state is refused naming both
    assert main(["score", str(data), str(results[0]), "--state", "2", "--out", str(tmp_path / "sc2")]) == 2
    err = capsys.readouterr().err
    assert "--state 2" in err and "images of state 1" in err and "left_01.png" in err

    # the same result against a dataset of other images (another speckle seed): refused, both named
    (tmp_path / "o").mkdir()
    other = _scenario(tmp_path / "o", scale=0.2)
    other.write_text(other.read_text().replace("seed = 3", "seed = 4"))
    assert main(["render", "specimen", str(other), "--out", str(tmp_path / "data_other")]) == 0
    assert main(["score", str(tmp_path / "data_other"), str(results[1]), "--out", str(tmp_path / "sc3")]) == 2
    err = capsys.readouterr().err
    assert "reference images (left_00.png + right_00.png) are not the reference of dataset" in err
    assert str(tmp_path / "data_other") in err and str(st / "manifest.json") in err
    assert not (tmp_path / "sc3" / "metrics.json").exists()


def test_render_through_ones_own_calibration_file(tmp_path):
    """A scenario whose rig is a calibration file (the paper rig saved by the instrument's writer as its JSON, which
    holds every parameter): the dataset carries the file, and its per-pixel truth equals the named paper rig's at
    the same scale (the same cameras read back from a file) to 1e-6 in the material coordinates."""
    from measurement.calibration.formats import save_calibration_as
    from measurement.calibration.io import CalibratedRig
    from workbench.cli import main
    from workbench.experiments.specimen.scenes import load_specimen_truth
    from workbench.rigs import get_rig

    paper = get_rig("paper", 1.0)
    save_calibration_as(CalibratedRig("rmm", paper.left, paper.right, paper.R_right_from_left,
                                      paper.T_right_from_left_mm), tmp_path / "cal.json", "json")
    named = _scenario(tmp_path)
    own = tmp_path / "own.toml"
    own.write_text(named.read_text().replace('[rig]\n', '[rig]\ncalibration = "cal.json"\n'))
    assert main(["render", "specimen", str(named), "--out", str(tmp_path / "a")]) == 0
    assert main(["render", "specimen", str(own), "--out", str(tmp_path / "b")]) == 0
    assert (tmp_path / "b" / "cal.json").is_file()
    a, b = load_specimen_truth(tmp_path / "a"), load_specimen_truth(tmp_path / "b")
    fa, fb = a.maps["left"].face, b.maps["left"].face
    both = (fa >= 0) & (fb >= 0)
    assert both.sum() > 0.99 * max((fa >= 0).sum(), (fb >= 0).sum())
    assert np.nanmax(np.abs(a.maps["left"].st[both] - b.maps["left"].st[both])) < 1e-6



def _rendered(folder, rig_extra="", render_extra=""):
    """(left reference image as float, truth.json) of the plate scenario rendered with extra [rig] and [render]
    lines."""
    from measurement.image_io import read_grey
    from workbench.cli import main

    folder.mkdir()
    _plate(folder)
    path = folder / "plate.toml"
    path.write_text(f'experiment = "specimen"\nseed = 3\n[rig]\nname = "paper"\nscale = 0.1\n{rig_extra}'
                    f'[render]\n{render_extra}[specimen]\nmesh = "plate.e"\n')
    assert main(["render", "specimen", str(path), "--out", str(folder / "out")]) == 0
    doc = json.loads((folder / "out" / "truth.json").read_text())
    return read_grey(folder / "out" / doc["states"][0]["files"]["left"]).astype(float), doc


def _gradient_energy(image):
    gy, gx = np.gradient(image)
    return float(np.mean(gx ** 2 + gy ** 2))


def test_the_lens_diffraction_is_in_the_images_and_their_truth(tmp_path):
    """By default a specimen is recorded through the diffraction of an f/8 lens at 550 nm on the rig's pixels:
    truth.json states it (Airy radius 1.22 lambda N / pitch). At f/32 (cut-off 1.96 cycles per 34.5 um pixel,
    the OTF about 0.87 at the 5 px speckle's 0.2 cycles/px) the mean squared gradient is at least 15 % below the
    ideal optics' (``rig.diffraction = false``); rendered 2 x 2 finer and binned, ideal optics give the same
    image within 1 grey RMS (the supersampled sensor is the same sensor)."""
    from workbench.rigs import get_rig

    diffracted, doc = _rendered(tmp_path / "a")
    optics = doc["render"]["optics"]
    pitch = get_rig("paper", 0.1).pixel_pitch_mm
    assert optics["f_number"] == 8.0 and optics["airy_radius_px"] == pytest.approx(1.22 * 550e-6 * 8.0 / pitch)
    ideal, doc = _rendered(tmp_path / "b", rig_extra="diffraction = false\n")
    assert "optics" not in doc["render"]
    blurred, _ = _rendered(tmp_path / "d", rig_extra="f_number = 32.0\n")
    assert _gradient_energy(blurred) < 0.85 * _gradient_energy(ideal)
    fine, _ = _rendered(tmp_path / "c", rig_extra="diffraction = false\n", render_extra="supersample = 2\n")
    assert np.sqrt(np.mean((fine - ideal) ** 2)) < 1.0
