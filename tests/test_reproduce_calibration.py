"""``workbench reproduce calibration`` at the test scale: the whole protocol, scored against the true rig.

At scale 0.25 a pixel covers 4x more of the specimen than at full resolution, so 3D errors that come from
image-plane errors are 4x larger; the 3D bounds below are the issue's full-resolution goals times 1/scale.
The full-resolution figures are in reports/calibration; ``pytest -m slow tests/test_reproduce_calibration.py``
re-runs that protocol (``workbench reproduce calibration``'s defaults: 2456 x 2058 px, 30 + 20 views, 64 spp) and
checks the same goals at scale 1 (:func:`test_full_resolution_protocol_meets_the_goals`; it renders 100 full-size
images, so it is long: corner detection alone took 327 s on 2 cores for the report).
"""
import json

import pytest

from workbench.experiments.calibration.run import reproduce_calibration

SCALE = 0.25


@pytest.fixture(scope="module")
def metrics(tmp_path_factory):
    out = tmp_path_factory.mktemp("repro")
    m = reproduce_calibration(out, scale=SCALE, seed=3, spp=16, noise_grey=1.0, n_calibration=14, n_validation=4,
                              progress=False)
    return out, m


def test_outputs_written(metrics):
    out, m = metrics
    for name in ("calibration.json", "calibration.yaml", "calibration_pinhole.json", "metrics.json", "report.md",
                 "plane_fit.png"):
        assert (out / name).is_file(), name
    assert json.loads((out / "metrics.json").read_text())["models"]["rmm"]["views_used"] == 14
    report = (out / "report.md").read_text()
    assert "| alpha_deg |" in report and "plane-fit" in report


def test_reprojection_rms(metrics):
    _, m = metrics
    for side, rms in m["models"]["rmm"]["reprojection_rms_px"].items():
        assert rms <= 0.05, side


def test_3d_and_projection_accuracy(metrics):
    _, m = metrics
    v = m["models"]["rmm"]["validation_exact"]
    print(f"\nrmm: 3D aligned {v['rms_3d_aligned_um']:.2f} um, unaligned {v['rms_3d_unaligned_um']:.0f} um, "
          f"projection {v['projection_rms_px']:.4f} px, frame rotation {v['alignment_rotation_deg']:.2f} deg")
    assert v["valid"] == v["points"]
    assert v["rms_3d_aligned_um"] <= 1.0 / SCALE
    assert v["projection_rms_px"] <= 0.05


def test_pinhole_model_reported_side_by_side(metrics):
    _, m = metrics
    p, r = m["models"]["pinhole"], m["models"]["rmm"]
    print(f"\npinhole: reprojection {p['reprojection_rms_px']}, 3D aligned {p['validation_exact']['rms_3d_aligned_um']:.2f} um;"
          f" rmm: {r['reprojection_rms_px']}, {r['validation_exact']['rms_3d_aligned_um']:.2f} um")
    assert p["estimate"]["left"]["alpha_deg"] == 0.0 and p["estimate"]["left"]["beta_deg"] == 0.0
    assert p["sigma"]["left"]["alpha_deg"] == 0.0          # held fixed, not estimated
    assert p["validation_exact"]["valid"] == p["validation_exact"]["points"]


def test_identical_renders_are_reused_and_others_are_not(tmp_path):
    """A second run with the same rig, views, seed, spp and noise reuses the images; a new seed re-renders."""
    kwargs = dict(scale=SCALE, spp=4, noise_grey=1.0, n_calibration=4, n_validation=2, progress=False,
                  models=("rmm",))
    first = reproduce_calibration(tmp_path, seed=5, **kwargs)
    assert first["render_s"] != "reused"
    again = reproduce_calibration(tmp_path, seed=5, **kwargs)
    assert again["render_s"] == "reused"
    assert again["models"]["rmm"]["reprojection_rms_px"] == first["models"]["rmm"]["reprojection_rms_px"]
    other = reproduce_calibration(tmp_path, seed=6, **kwargs)
    assert other["render_s"] != "reused"


@pytest.mark.slow
def test_full_resolution_protocol_meets_the_goals(tmp_path):
    """The protocol of reports/calibration at full resolution: the goals of the tests above at scale 1.

    The report's figures (rmm): reprojection RMS 0.037 / 0.031 px, validation projection RMS 0.0034 px, 3D
    error after one rigid alignment 0.26 um RMS, every validation point triangulated.
    """
    m = reproduce_calibration(tmp_path, progress=False)
    assert m["scale"] == 1.0 and m["image_size_px"] == [2456, 2058]
    r = m["models"]["rmm"]
    assert r["views_used"] == 30
    for side, rms in r["reprojection_rms_px"].items():
        assert rms <= 0.05, side
    v = r["validation_exact"]
    print(f"\nrmm full resolution: 3D aligned {v['rms_3d_aligned_um']:.3f} um, projection {v['projection_rms_px']:.4f} px")
    assert v["valid"] == v["points"]
    assert v["rms_3d_aligned_um"] <= 1.0
    assert v["projection_rms_px"] <= 0.05
    p = m["models"]["pinhole"]
    assert p["estimate"]["left"]["alpha_deg"] == 0.0 and p["validation_exact"]["valid"] == p["validation_exact"]["points"]
