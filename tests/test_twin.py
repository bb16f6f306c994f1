"""The digital twin of a user's rig (issue 24): predictions against what the instrument measures.

References: a rendered stereo rig whose sensor noise is known (the scenes' renderer, not the twin's; read noise
2 grey, 20 e-/grey), an analytic Star-speckle static pair (2-D), and a real static pair nobody here recorded
(DICe's StaticB, committed excerpt). Bad inputs are refused with messages that name the file or option.
"""
from __future__ import annotations

import numpy as np
import pytest

from measurement.image_io import read_grey

DATA = __import__("pathlib").Path(__file__).parent / "data" / "twin"


def _tolerance(points: int, repeats: int, points_per_independent: float) -> float:
    """Three standard errors of a measured noise figure: the standard deviation over ``points`` points, pooled (RMS)
    over ``repeats`` repeats, scatters by ``1 / sqrt(2 repeats N_eff)`` relative, where overlapping subsets leave
    ``N_eff = points / points_per_independent`` independent values (the prediction itself scatters far less)."""
    return 3.0 / np.sqrt(2.0 * repeats * points / points_per_independent)


#: Points per independent error, second-order subsets: measured on the twins below over 12 seeds (the ratio of
#: instrument sigma to twin noise scattered by 2.2 % per component with 2 repeats of 1456 points in 2-D, 1.7 % per
#: repeat of 3192 points in stereo: N_eff = N / 2.8 and N / 1.9); the larger one is used.
CORRELATED_ORDER2 = 3.0


def _write(path, image, dtype=np.uint8):
    import cv2

    assert cv2.imwrite(str(path), np.asarray(image).astype(dtype))
    return path


@pytest.fixture(scope="module")
def rendered_rig(tmp_path_factory):
    """A flat speckled plate rendered in stereo through the paper rig at quarter scale, state 0 and its static
    repeat at the same position (a real static pair: ``static_offset_px = [0, 0]``), with read noise 2 grey and shot
    noise 20 e-/grey; exported with the rig's calibration."""
    import skfem
    from skfem.io.meshio import to_meshio

    from scenes.specimens.fe_files import write_exodus
    from workbench.cli import main

    tmp = tmp_path_factory.mktemp("rendered_rig")
    m = to_meshio(skfem.MeshTet.init_tensor(np.linspace(-30, 30, 7), np.linspace(-20, 20, 5), np.linspace(0, 3, 2)))
    write_exodus(tmp / "plate.e", m.points, {"tetra": m.cells[0].data}, np.zeros((1, *m.points.shape)), times=[0.0])
    (tmp / "plate.toml").write_text('experiment = "specimen"\nseed = 3\n[rig]\nname = "paper"\nscale = 0.25\n'
                                    '[render]\nread_noise_grey = 2.0\nelectrons_per_grey = 20.0\n'
                                    '[specimen]\nmesh = "plate.e"\nstatic_offset_px = [0.0, 0.0]\n')
    assert main(["render", "specimen", str(tmp / "plate.toml"), "--out", str(tmp / "data")]) == 0
    assert main(["export", str(tmp / "data"), "--format", "native", "--out", str(tmp / "ex")]) == 0
    return tmp / "ex"


def test_twin_of_a_rendered_rig_predicts_the_measured_static_noise_within_10_percent(rendered_rig):
    """Stereo twin from the rendered images and the rig's calibration: predicted U, V, W noise within 10 % of the
    instrument's on the rendered static pair; the noise model it read from that pair recovers the renderer's
    sensor (read noise sqrt(2^2 + 1/12) grey within 5 %, gain 20 e-/grey within 10 %).

    The instrument's own sigma of a static repeat (measurement.uncertainty, on the twin's references with that
    noise model) agrees with the noise the twin's repeats measure within issue 36's goal for std(error / sigma),
    10 % (seen: U 0.993, V 0.952-0.962, W 1.004 -- V is 3.2 +- 0.5 % low over 12 repeats, the estimator's own bias,
    so three standard errors of the measured figure, 4.6 %, is not a claim it can keep; an estimator that forgot the
    reference image's noise would read 1/sqrt(2) = 0.71 and fail), and the rendered static pair within the same
    10 % as the twin (seen 0.96, 0.97, 0.99)."""
    from workbench.twin import TwinSettings, run_twin

    ex = rendered_rig
    result = run_twin(ex / "left_00.png", ex / "right_00.png", ex / "left_01.png", ex / "right_01.png",
                      calibration=ex / "calibration.json", auto_roi=True, repeats=2, whatif=False, bias=False,
                      resolution=False, settings=TwinSettings(subset_px=21, step_px=6))
    for key in ("U_um", "V_um", "W_um"):
        c = result.comparison[key]
        assert abs(c["ratio"] - 1.0) <= 0.10, (key, c)
        assert abs(c["instrument_ratio"] - 1.0) <= 0.10, (key, c)
    p = result.prediction
    for key in ("U_um", "V_um", "W_um"):
        assert abs(p["instrument_sigma"][key] / p["noise"][key] - 1.0) <= 0.10, (key, p["instrument_sigma"], p["noise"])
    for side in ("left", "right"):
        model = result.noise_models[side]
        assert model.read_noise_grey == pytest.approx(np.sqrt(4.0 + 1.0 / 12.0), rel=0.05)
        assert model.electrons_per_grey == pytest.approx(20.0, rel=0.10)


def test_twin_of_a_rendered_rig_without_a_static_pair_is_within_15_percent(rendered_rig):
    """With only the reference images the noise comes from one image (Immerkaer on the weakest-textured blocks);
    the prediction still lands within 15 % of the noise the instrument measures on the rendered static pair."""
    from workbench.twin import TwinSettings, run_twin
    from workbench.twin.measure import static_noise_stereo
    from measurement.dic import DICSettings
    from workbench.rigs import rig_from_calibration

    ex = rendered_rig
    settings = TwinSettings(subset_px=21, step_px=6)
    result = run_twin(ex / "left_00.png", ex / "right_00.png", calibration=ex / "calibration.json", auto_roi=True,
                      repeats=2, whatif=False, bias=False, resolution=False, settings=settings)
    assert result.noise_models["left"].source == "single image"
    rig = rig_from_calibration(ex / "calibration.json")
    images = [read_grey(ex / n).astype(float) for n in ("left_00.png", "right_00.png", "left_01.png", "right_01.png")]
    measured = static_noise_stereo(rig, *images, DICSettings(subset_size=21, step=6, order=2), mask=result.mask)
    for key in ("U_um", "V_um", "W_um"):
        ratio = result.prediction["noise"][key] / measured.noise[key]
        assert abs(ratio - 1.0) <= 0.15, (key, ratio)


def test_twin_2d_on_an_analytic_static_pair_within_10_percent(tmp_path):
    """One camera, no calibration: an exact Star-speckle static pair (4 px speckles, read noise 2 grey, 8 bit);
    predicted u, v noise within 10 % of the instrument's on the pair; l10 on the pattern within 15 % of the theory
    for the subset and order (DIC Challenge 2.0)."""
    from scenes.image_pairs.star import star_images
    from workbench.twin import TwinSettings, run_twin

    images = star_images((201, 600), 4.0, noise_grey=2.0, seed=4, deformed=False, static=True)
    a = _write(tmp_path / "ref.png", images.reference)
    b = _write(tmp_path / "static.png", images.static)
    result = run_twin(a, static_left=b, repeats=2, whatif=False, bias=True, resolution=True,
                      settings=TwinSettings(subset_px=21, step_px=5, order=2))
    for key in ("u_px", "v_px"):
        assert abs(result.comparison[key]["ratio"] - 1.0) <= 0.10, result.comparison[key]
    res = result.prediction["resolution"]
    assert res["l10_px"] == pytest.approx(res["l10_theory_px"], rel=0.15)
    assert result.prediction["bias"]["max_abs_px"] < 0.02


def test_twin_on_a_real_static_pair_within_25_percent_and_its_top_recommendation_helps():
    """DICe's StaticB camera 0 (committed excerpt, 480 x 240 px): predicted u, v noise within 25 % of the measured
    (issue 24's goal for real data), the twin's repeats and the instrument's own sigma alike (seen 1.00, 0.99 and
    1.00, 1.00); the what-if table's top recommendation, applied to the real pair, lowers the measured displacement
    noise as predicted (sign, and the size within 10 percentage points).

    The instrument's sigma (measurement.uncertainty) agrees with the noise the twin's repeats measure: pooled over
    the 2 repeats within three standard errors of second-order subsets (:func:`_tolerance`, 1456 points: 6.8 %;
    seen u 0.998, v 1.016), and in every what-if row (one repeat each) within three standard errors counting one
    independent error per subset area, ``N_eff = N (step / subset)^2`` -- first-order subsets correlate that far
    (12 seeds: 5.2 % scatter per component, N_eff = N / 11.5 at subset 27, step 8); seen within 0.98-1.08."""
    from workbench.twin import TwinSettings, run_twin

    result = run_twin(DATA / "staticb_cam0_0.png", static_left=DATA / "staticb_cam0_1.png", repeats=2,
                      settings=TwinSettings(subset_px=27, step_px=8), bias=False, resolution=False)
    for key in ("u_px", "v_px"):
        assert abs(result.comparison[key]["ratio"] - 1.0) <= 0.25, result.comparison[key]
        assert abs(result.comparison[key]["instrument_ratio"] - 1.0) <= 0.25, result.comparison[key]
    p = result.prediction
    tol = _tolerance(p["points"], p["repeats"], CORRELATED_ORDER2)
    for key in ("u_px", "v_px"):
        assert abs(p["instrument_sigma"][key] / p["noise"][key] - 1.0) <= tol, (key, p["instrument_sigma"], p["noise"])
    for row in (r for r in result.whatif if "displacement_noise" in r):
        tol = _tolerance(row["points"], 1, (row["subset_px"] / row["step_px"]) ** 2)
        for key in ("u_px", "v_px"):
            assert abs(row["instrument_sigma"][key] / row["noise"][key] - 1.0) <= tol, (row["label"], key, tol)
    w = result.whatif_real
    assert w is not None and w["measured_after"] < w["measured_before"]
    assert abs(w["measured_change"] - w["predicted_change"]) < 0.10
    ranked = [r for r in result.whatif if r.get("rank")]
    assert ranked[0]["rank"] == 1 and ranked[0]["change"] == min(r["change"] for r in ranked)
    # first-order subsets buy their noise with resolution (l10 ~ 3.99 N vs 1.29 N, DIC Challenge 2.0); a coarser step
    # widens the strain gauge; a finer step costs nothing in resolution
    rows = {r["label"]: r for r in result.whatif}
    assert not rows["shape function order 2 -> 1"]["keeps_resolution"]
    assert not rows["step 8 -> 16 px"]["keeps_resolution"] and rows["step 8 -> 4 px"]["keeps_resolution"]


# --- bad input ---------------------------------------------------------------------------------------------

def test_a_calibration_for_another_image_size_is_refused(rendered_rig, tmp_path):
    from workbench.twin import run_twin

    left = read_grey(rendered_rig / "left_00.png")
    cropped = _write(tmp_path / "left.png", left[:-8])
    with pytest.raises(ValueError, match=r"calibration .* is for \d+ x \d+ px images but the left image .*left.png is "
                                         r"\d+ x \d+ px"):
        run_twin(cropped, rendered_rig / "right_00.png", calibration=rendered_rig / "calibration.json")


def _speckle(shape, size_px, seed=0, noise=1.0):
    from scenes.sensor.noise import apply_sensor_noise
    from scenes.image_pairs.gaussian_speckle import extent_for_shape, gaussian_speckle, radius_for_speckle_size

    pattern = gaussian_speckle(extent_for_shape(shape, 8.0), radius_for_speckle_size(size_px), 0.5, seed,
                               mean_grey=120.0, std_grey=35.0)
    clean = pattern.render_reference(shape)
    return clean, apply_sensor_noise(clean, read_noise_grey=noise, seed=seed + 1)


def test_a_roi_saturated_over_a_large_part_is_refused(tmp_path):
    _, image = _speckle((160, 200), 4.0)
    image = np.array(image)
    image[:40, :] = 255                 # 25 % of the frame clipped
    path = _write(tmp_path / "glare.png", image)
    from workbench.twin import run_twin

    with pytest.raises(ValueError, match=r"glare.png: 25.0 % of the ROI is saturated \(grey 255\)"):
        run_twin(path)


def test_a_speckle_too_fine_or_too_coarse_for_any_subset_is_said_with_the_subset_it_needs(tmp_path):
    from workbench.twin import TwinSettings, run_twin

    # a 4 px speckle imaged at a quarter of the magnification (4 x 4 pixel binning): ~1 px speckles
    _, sharp = _speckle((800, 960), 4.0, seed=2, noise=0.0)
    fine = np.asarray(sharp, float).reshape(200, 4, 240, 4).mean(axis=(1, 3))
    with pytest.raises(ValueError, match=r"speckle too fine: speckles of [01]\.\d+ px are under-sampled"):
        run_twin(_write(tmp_path / "fine.png", fine), settings=TwinSettings(subset_px=21))
    _, coarse = _speckle((200, 240), 45.0, seed=3, noise=4.0)
    with pytest.raises(ValueError, match=r"speckle too coarse: .* it would need a subset of about \d+ px"):
        run_twin(_write(tmp_path / "coarse.png", coarse), settings=TwinSettings(subset_px=21))


def test_wrong_bit_depth_claims_are_refused(tmp_path):
    import cv2

    from workbench.twin import run_twin

    _, image = _speckle((120, 160), 4.0)
    low_bits = np.random.default_rng(0).integers(0, 16, np.shape(image))
    twelve = _write(tmp_path / "twelve.png", np.asarray(image) * 16 + low_bits, np.uint16)   # 12-bit data in 16 bits
    with pytest.raises(ValueError, match=r"twelve.png holds 12-bit data in a 16-bit container .* but --bit-depth "
                                         r"claims 8-bit data: give --bit-depth 12"):
        run_twin(twelve, bit_depth=8)
    eight = _write(tmp_path / "eight.png", image)
    with pytest.raises(ValueError, match=r"twelve.png holds 12-bit data .* but the left reference .*eight.png holds "
                                         r"8-bit data .*: all images of a twin come from the same cameras"):
        run_twin(eight, static_left=twelve)
    colour = tmp_path / "colour.png"
    cv2.imwrite(str(colour), np.repeat(np.asarray(image, np.uint8)[..., None], 3, axis=2))
    with pytest.raises(ValueError, match=r"colour.png: a colour image .* cannot hold 12-bit data"):
        run_twin(colour, bit_depth=12)


def test_a_static_pair_that_moved_is_refused_with_its_motion(tmp_path):
    from scenes.image_pairs.fourier_shift import fourier_shift
    from scenes.sensor.noise import apply_sensor_noise
    from workbench.twin import NotStaticError, TwinSettings, run_twin

    clean, image = _speckle((200, 240), 4.0, seed=5)
    moved = apply_sensor_noise(fourier_shift(clean, (0.6, 0.0)), read_noise_grey=1.0, seed=9)
    a, b = _write(tmp_path / "a.png", image), _write(tmp_path / "b.png", moved)
    with pytest.raises(NotStaticError, match=r"the static pair a.png -> b.png is not static: its mean motion is "
                                             r"\(\+0\.6\d+, [+-]0\.0\d+\) px, above the 0\.\d+ px that the "
                                             r"image noise"):
        run_twin(a, static_left=b, settings=TwinSettings(subset_px=21))


def test_incomplete_stereo_inputs_are_refused(tmp_path):
    from workbench.twin import load_inputs

    _, image = _speckle((64, 64), 4.0)
    p = _write(tmp_path / "x.png", image)
    with pytest.raises(ValueError, match=r"a stereo twin \(--right\) needs the rig's calibration \(--calib\)"):
        load_inputs(p, p)
    with pytest.raises(ValueError, match=r"--static-right needs --right"):
        load_inputs(p, static_right=p)


def test_cli_twin_writes_the_report_and_says_errors_in_one_line(tmp_path, capsys):
    """``workbench twin`` on the real excerpt: exit 0, report.html with its sections, twin.json and the points CSV;
    a missing file is exit 2 with one line naming it. The terminal's advice is the report's verdict (issue 35: it
    printed "top recommendation: shape function order 2 -> 1" while the report said that change triples l10 and no
    change keeps the resolution), and the report describes the automatic ROI it used (it said "whole image")."""
    import json

    from workbench.cli import main

    out = tmp_path / "twin"
    assert main(["twin", "--left", str(DATA / "staticb_cam0_0.png"), "--static-left", str(DATA / "staticb_cam0_1.png"),
                 "--subset", "27", "--step", "10", "--repeats", "1", "--auto-roi", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "predicted static noise (1 sigma): u " in text
    rows = json.loads((out / "twin.json").read_text())["whatif"]
    ranked = sorted((r for r in rows if r.get("rank")), key=lambda r: r["rank"])
    keeper = next((r for r in ranked if r["keeps_resolution"]), None)
    assert ranked and not ranked[0]["keeps_resolution"]     # on this pair the lowest noise costs resolution
    verdict = next(line for line in text.splitlines() if line.startswith("best change that keeps your spatial"))
    assert (keeper["label"] in verdict) if keeper else verdict.endswith("none; every change that lowers the noise "
                                                                        "costs resolution")
    assert ranked[0]["label"] not in verdict and "top recommendation" not in text
    cost = next(line for line in text.splitlines() if line.startswith("lowest noise at any resolution: "))
    assert ranked[0]["label"] in cost and f"l10 {rows[0]['l10_theory_px']:.3g} -> " in cost
    md = (out / "report.md").read_text()
    for line in (verdict, cost):                       # word for word in the report
        assert f"{line[0].upper()}{line[1:]}." in md
    roi = next(line for line in md.splitlines() if "**ROI**" in line)
    assert "whole image, then the automatic ROI (--auto-roi" in roi and " px kept (" in roi, roi
    html = (out / "report.html").read_text()
    for heading in ("Predicted noise floor", "What if", "Speckle quality", "Maps over the ROI"):
        assert heading in html
    doc = json.loads((out / "twin.json").read_text())
    assert doc["kind"] == "2d" and doc["comparison"]["u_px"]["measured"] > 0
    header = (out / "twin_points.csv").read_text().splitlines()[0]
    assert header.startswith("x_px,y_px,predicted_sigma_u_px,predicted_sigma_v_px,instrument_sigma_u_px,"
                             "instrument_sigma_v_px,measured_u_px")
    assert "instrument's sigma (measurement.uncertainty): u " in text
    assert main(["twin", "--left", str(tmp_path / "nope.png"), "--out", str(tmp_path / "o2")]) == 2
    assert "nope.png" in capsys.readouterr().err


def test_lens_rows_of_a_thin_lens_rig(rendered_rig):
    """With the lens stated (f/8, pixel pitch of the quarter-scale sensor), the what-if table gets one stop up and
    down and the focus moved: one stop up halves the light ((N0/N)^2 = 0.5), halves the defocus blur's variance
    and sets diffraction to 0.42 lambda N (exact to 1e-9); fewer photons raise the predicted noise, one stop down
    lowers it; an optics row is never applied to the recorded pair."""
    from workbench.twin import TwinSettings, run_twin
    from workbench.twin.optics import Lens

    ex = rendered_rig
    lens = Lens(f_number=8.0, pixel_pitch_um=13.8)
    result = run_twin(ex / "left_00.png", ex / "right_00.png", ex / "left_01.png", ex / "right_01.png",
                      calibration=ex / "calibration.json", auto_roi=True, repeats=1, bias=False, resolution=False,
                      settings=TwinSettings(subset_px=21, step_px=8), lens=lens)
    rows = {r["label"]: r for r in result.whatif}
    base = rows["baseline (your settings)"]["displacement_noise"]
    up, down = rows["f-number 8 -> 11"], rows["f-number 8 -> 5.7"]
    assert up["optics"]["left"]["light_factor"] == pytest.approx(0.5)
    assert down["optics"]["left"]["light_factor"] == pytest.approx(2.0)
    # defocus scales with the aperture F/N, diffraction with N: sigma^2 = defocus^2 + (0.42 lambda N / pitch)^2
    d0, d1 = (0.42 * 0.55 * n / 13.8 for n in (8.0, 8.0 * np.sqrt(2)))
    o = up["optics"]["left"]
    assert o["sigma_new_px"] ** 2 == pytest.approx((o["sigma_now_px"] ** 2 - d0 ** 2) / 2 + d1 ** 2, rel=1e-9)
    assert o["extra_blur_px"] == pytest.approx(np.sqrt(max(o["sigma_new_px"] ** 2 - o["sigma_now_px"] ** 2, 0)))
    assert down["displacement_noise"] < base < up["displacement_noise"]
    assert any(label.startswith("focus ") for label in rows)
    assert result.whatif_real is None or not result.whatif_real["label"].startswith(("f-number", "focus"))


def test_a_generated_pattern_twin_has_the_photographs_statistics(tmp_path):
    """``texture="generated"``: the twin's pattern is an analytic speckle whose autocorrelation size is within 10 %
    of the photograph's and whose mean and standard deviation are within 3 %; the choice is stated in the notes."""
    from measurement.speckle_quality import grey_statistics, speckle_size_px
    from workbench.twin import TwinSettings, run_twin

    result = run_twin(DATA / "staticb_cam0_0.png", static_left=DATA / "staticb_cam0_1.png", repeats=1, whatif=False,
                      bias=False, resolution=False, texture="generated", settings=TwinSettings(subset_px=27, step_px=8))
    pattern = result.scene.clean["left"]
    photo = read_grey(DATA / "staticb_cam0_0.png").astype(float)
    assert speckle_size_px(pattern) == pytest.approx(speckle_size_px(photo), rel=0.10)
    g, p = grey_statistics(pattern), grey_statistics(photo)
    assert g.mean_grey == pytest.approx(p.mean_grey, rel=0.03) and g.std_grey == pytest.approx(p.std_grey, rel=0.03)
    assert any("generated Gaussian speckle" in n for n in result.notes)
    with pytest.raises(ValueError, match="texture must be 'photo' or 'generated', got 'paint'"):
        run_twin(DATA / "staticb_cam0_0.png", texture="paint")
