"""Automatic ROI for whole-image DIC (measurement/dic/roi.py) against images with an exactly known truth.

The scene (built here from the truth side, scenes/synthetic_images): a speckled specimen and, sharing its right
edge, a speckled fixture with another pattern, on a static, out-of-focus background (a Gaussian-blurred noise
field, 3 grey std) in an otherwise whole-image grid. The specimen translates by ``A``, the fixture by ``B`` (a
gap opens between them), the background stays. Region edges are erf ramps (0.8 px), so they move by sub-pixel
amounts exactly; every pixel is the exact blend of the three, and both images get independent Gaussian noise.
The truth at a point of interest is the motion of the region its centre lies in.
"""
from __future__ import annotations

import csv

import cv2
import numpy as np
import pytest
from scipy import ndimage
from scipy.special import ndtr

from measurement.dic import DICSettings, Status, correlate
from measurement.dic.roi import (AutoRoi, consistency_flags, correlate_auto_roi, estimate_noise_sigma,
                                 expected_zncc_deficit, texture_mask)
from scenes.sensor.noise import apply_sensor_noise
from scenes.image_pairs.gaussian_speckle import extent_for_shape, gaussian_speckle

SHAPE = (256, 256)
SPECIMEN = (56, 56, 140, 200)      # x0, y0, x1, y1 px: pixel centres x0 <= x < x1 (edges at x0 - 0.5, x1 - 0.5)
FIXTURE = (140, 56, 200, 200)      # shares the specimen's right edge
A = (-0.6, 0.35)                   # specimen translation, px
B = (0.9, -0.5)                    # fixture translation, px
EDGE_PX = 0.8                      # erf width of the region edges
NOISE_GREY = 2.0
SETTINGS = DICSettings(subset_size=33, step=8)
HALF = SETTINGS.subset_size // 2
#: A subset counts as "fully inside" a region when it stays this far inside its edges: 5 erf widths (blend below
#: 3e-7) plus the biquintic spline's 3 px reach, px.
MARGIN_PX = 4 + 3
#: Accuracy of a kept point: 5 times the default target precision of 0.02 px (noise-limited std), px.
KEPT_ERROR_PX = 0.1
#: Accuracy of a point whose subset lies fully inside the specimen, px: with 2 grey noise on a 30 grey std
#: speckle the predicted std is ~0.006 px; 0.05 px leaves room for the 8-bit rounding and the spline bias.
INSIDE_ERROR_PX = 0.05


def _alpha(box, x, y):
    x0, y0, x1, y1 = box
    return (ndtr((x - x0 + 0.5) / EDGE_PX) * ndtr((x1 - 0.5 - x) / EDGE_PX)
            * ndtr((y - y0 + 0.5) / EDGE_PX) * ndtr((y1 - 0.5 - y) / EDGE_PX))


def _scale_box(box, shape):
    sy, sx = shape[0] / SHAPE[0], shape[1] / SHAPE[1]
    return (round(box[0] * sx), round(box[1] * sy), round(box[2] * sx), round(box[3] * sy))


def make_scene(shape=SHAPE, noise_grey=NOISE_GREY, seed=0, bit_depth=8):
    """Reference and deformed images (float32, grey) of the specimen/fixture/background scene."""
    specimen, fixture = _scale_box(SPECIMEN, shape), _scale_box(FIXTURE, shape)
    y, x = np.mgrid[0:shape[0], 0:shape[1]].astype(np.float64)
    extent = extent_for_shape(shape, margin_px=4.0)
    spec = gaussian_speckle(extent, 1.4, seed=seed + 1)
    fix = gaussian_speckle(extent, 1.8, seed=seed + 2, mean_grey=110.0, std_grey=35.0)
    blur = ndimage.gaussian_filter(np.random.default_rng(seed + 3).normal(size=shape), 8.0)
    background = 40.0 + 3.0 * (blur - blur.mean()) / blur.std()
    images = []
    for (ax, ay), (bx, by) in (((0.0, 0.0), (0.0, 0.0)), (A, B)):
        a_s, a_f = _alpha(specimen, x - ax, y - ay), _alpha(fixture, x - bx, y - by)
        image = (1.0 - a_s - a_f) * background
        image += a_s * spec.evaluate(np.stack([x - ax, y - ay], axis=-1))
        image += a_f * fix.evaluate(np.stack([x - bx, y - by], axis=-1))
        images.append(image)
    return tuple(apply_sensor_noise(image, read_noise_grey=noise_grey, bit_depth=bit_depth, seed=seed + 10 + k)
                 for k, image in enumerate(images))


def _inside(box, x, y, margin=0.0):
    x0, y0, x1, y1 = box
    return (x - margin >= x0 - 0.5) & (x + margin < x1 - 0.5) & (y - margin >= y0 - 0.5) & (y + margin < y1 - 0.5)


def truth(x, y, shape=SHAPE):
    """Exact displacement (u, v) px at reference points: the motion of the region the point lies in."""
    u, v = np.zeros(np.shape(x)), np.zeros(np.shape(x))
    for box, (du, dv) in ((_scale_box(SPECIMEN, shape), A), (_scale_box(FIXTURE, shape), B)):
        inside = _inside(box, x, y)
        u[inside], v[inside] = du, dv
    return u, v


def _error(result, shape=SHAPE):
    u, v = truth(result.x.astype(float), result.y.astype(float), shape)
    return np.hypot(result.u - u, result.v - v)


def _subset_on_background(x, y):
    """Subset (with the margin) touches neither the specimen nor the fixture."""
    reach = HALF + MARGIN_PX
    near = []
    for x0, y0, x1, y1 in (SPECIMEN, FIXTURE):
        near.append((x + reach >= x0 - 0.5) & (x - reach < x1 - 0.5) & (y + reach >= y0 - 0.5) & (y - reach < y1 - 0.5))
    return ~(near[0] | near[1])


@pytest.fixture(scope="module")
def runs():
    reference, deformed = make_scene()
    plain = correlate(reference, deformed, SETTINGS)
    auto, report = correlate_auto_roi(reference, deformed, SETTINGS)
    return reference, deformed, plain, auto, report


# --- (a) (b) (c): the scene -------------------------------------------------------------------------------

def test_every_point_inside_the_specimen_is_kept_and_accurate(runs):
    """Claim (a): every point whose subset lies fully inside the specimen (``MARGIN_PX`` from its edges) is
    CONVERGED and within ``INSIDE_ERROR_PX`` of the exact translation."""
    *_, auto, _ = runs
    x, y = auto.x.astype(float), auto.y.astype(float)
    inside = _inside(SPECIMEN, x, y, HALF + MARGIN_PX)
    assert inside.sum() >= 30
    assert (auto.status[inside] == Status.CONVERGED).all(), auto.status_counts()
    assert _error(auto)[inside].max() <= INSIDE_ERROR_PX


def test_every_background_point_is_flagged_low_texture(runs):
    """Claim (b): every point whose subset (with the margin) lies on the background is LOW_TEXTURE (NaN). Points
    centred on the background next to the specimen, which the plain whole-image run "measures" at the specimen's
    motion with ZNCC >= 0.99 (the issue's symptom), are all flagged too."""
    *_, plain, auto, report = runs
    background = _subset_on_background(auto.x, auto.y)
    assert background.sum() >= 100
    assert (auto.status[background] == Status.LOW_TEXTURE).all()
    assert np.isnan(auto.u[background]).all() and np.isnan(auto.v[background]).all()
    # the plain run is the same grid (same order)
    assert np.array_equal(plain.x, auto.x) and np.array_equal(plain.y, auto.y)
    x, y = plain.x.astype(float), plain.y.astype(float)
    centred_off = ~_inside(SPECIMEN, x, y) & ~_inside(FIXTURE, x, y)
    wrong = plain.converged & centred_off & (_error(plain) > KEPT_ERROR_PX)
    assert (wrong & (plain.zncc >= 0.99)).sum() >= 10
    assert not auto.converged[wrong].any()
    assert report.low_texture == int(np.count_nonzero(auto.status == Status.LOW_TEXTURE))
    assert report.points == auto.x.size


def test_straddling_points_with_a_wrong_displacement_are_flagged(runs):
    """Claim (c): the plain run measures points whose subset straddles the specimen/fixture boundary with errors
    above ``KEPT_ERROR_PX`` (against the exact motion at their centre), at ZNCC above 0.8; the auto ROI flags
    every one of them, and no point it keeps anywhere is wrong by more than ``KEPT_ERROR_PX``."""
    *_, plain, auto, report = runs
    straddling = np.abs(plain.x - (FIXTURE[0] - 0.5)) < HALF + MARGIN_PX
    straddling &= (plain.y > SPECIMEN[1]) & (plain.y < SPECIMEN[3])
    wrong = plain.converged & straddling & (_error(plain) > KEPT_ERROR_PX)
    assert wrong.sum() >= 10
    assert not auto.converged[wrong].any()
    assert (auto.status[wrong] == Status.INCONSISTENT).any()
    assert np.nanmax(_error(auto)[auto.converged]) <= KEPT_ERROR_PX
    assert report.inconsistent == int(np.count_nonzero(auto.status == Status.INCONSISTENT)) > 0
    # the fixture's own interior is measured (it moves differently, but consistently)
    fixture = _inside(FIXTURE, auto.x, auto.y, HALF + MARGIN_PX)
    assert fixture.sum() >= 10 and auto.converged[fixture].all()


# --- (d): noise -------------------------------------------------------------------------------------------

@pytest.mark.parametrize("sigma", [0.5, 2.0, 5.0])
@pytest.mark.parametrize("bit_depth", [None, 8])
def test_noise_estimate_recovers_the_added_sigma(sigma, bit_depth):
    """Claim (d): on the scene (a third of it background) the estimate is within 10 % of the noise added,
    ``sqrt(sigma^2 + 1/12)`` with 8-bit rounding (the uniform rounding error is noise to DIC too)."""
    reference, _ = make_scene(noise_grey=sigma, seed=7, bit_depth=bit_depth)
    expected = sigma if bit_depth is None else np.hypot(sigma, np.sqrt(1.0 / 12.0))
    assert abs(estimate_noise_sigma(reference) / expected - 1.0) < 0.10


def test_noise_estimate_of_pure_noise_and_of_a_flat_image():
    """Pure Gaussian noise (sigma 3) within 5 %; an exactly flat image has no noise; a frame that is flat and black
    except for a noisy square ignores the clipped (0) plateau."""
    rng = np.random.default_rng(3)
    assert abs(estimate_noise_sigma(rng.normal(100.0, 3.0, (200, 200))) / 3.0 - 1.0) < 0.05
    assert estimate_noise_sigma(np.full((100, 100), 7.0)) == 0.0
    image = np.zeros((200, 200))
    image[50:150, 50:150] = np.clip(rng.normal(60.0, 3.0, (100, 100)), 0, 255)
    assert abs(estimate_noise_sigma(image) / 3.0 - 1.0) < 0.10


# --- the two tests on their own ---------------------------------------------------------------------------

def test_texture_threshold_follows_the_predicted_precision():
    """A noise-free sinusoid ``a (sin kx + sin ky)`` has per-subset ``SSSIG_x = n a^2 sin(k)^2 / 2`` (central
    differences); with a stated noise sigma the subset passes iff ``sqrt(2) sigma / sqrt(SSSIG - n sigma^2 / 2)``
    is at most the target. Amplitudes 10 % either side of the critical one fall either side of the mask."""
    subset, sigma, target, period = 21, 1.5, 0.02, 8.0
    n, k = subset * subset, 2 * np.pi / period
    critical = np.sqrt((2 * sigma ** 2 / target ** 2 + n * sigma ** 2 / 2) * 2 / (n * np.sin(k) ** 2))
    y, x = np.mgrid[0:96, 0:96].astype(float)
    for factor, passes in ((0.9, False), (1.1, True)):
        amplitude = factor * critical
        image = 100.0 + amplitude * (np.sin(k * x + 0.3) + np.sin(k * y + 0.7))
        mask = texture_mask(image, subset, noise_sigma_grey=sigma, target_precision_px=target)
        assert mask[48, 48] == passes
        assert mask[30:66, 30:66].all() == passes


def test_texture_mask_needs_the_texture_at_the_point():
    """A subset centred on flat ground beside a speckle field has SSSIG to spare but its texture is off-centre:
    flagged; a subset half a subset inside the speckle passes; noise-free images still flag the flat ground."""
    speckle = gaussian_speckle(extent_for_shape((128, 128), 2.0), 1.4, seed=5).render_reference((128, 128))
    image = np.where(np.arange(128)[None, :] >= 64, speckle, 60.0)
    mask = texture_mask(image, 21)
    assert not mask[64, 60]                 # centre 4 px onto the flat side
    assert mask[64, 64 + 11]                # whole subset on the speckle
    assert not mask[64, 20:50].any()        # flat ground
    assert mask[20:108, 80:108].all()


def test_consistency_flags_an_outlier_and_a_low_zncc_point():
    """A linear field (5e-4 strain at an 8 px step) with 0.005 px noise: a 0.2 px outlier is flagged
    'displacement', a point with ZNCC deficit 20 times the noise's 'zncc', a point with no measured neighbour
    'isolated'; no other point."""
    rng = np.random.default_rng(11)
    rows, cols = np.mgrid[0:12, 0:15]
    grid_index = np.column_stack([rows.ravel(), cols.ravel()])
    u = 0.004 * cols.ravel() + 0.3 + rng.normal(0, 0.005, rows.size)
    v = -0.004 * rows.ravel() + rng.normal(0, 0.005, rows.size)
    zncc = 1.0 - 0.004 * (1.0 + 0.2 * rng.random(rows.size))
    expected = np.full(rows.size, 0.004)
    outlier, low, lonely = 5 * 15 + 7, 8 * 15 + 3, 0
    u[outlier] += 0.2
    zncc[low] = 1.0 - 20 * 0.004
    u[[1, 15, 16]] = np.nan                  # node (0, 0) loses its three neighbours
    flags = consistency_flags(grid_index, (12, 15), u, v, zncc, expected_zncc_deficit=expected)
    assert flags.reason[outlier] == "displacement" and flags.residual[outlier] > 2.0
    assert flags.reason[low] == "zncc"
    assert flags.reason[lonely] == "isolated"
    others = np.ones(rows.size, dtype=bool)
    others[[outlier, low, lonely]] = False
    assert not flags.flagged[others].any()
    assert flags.counts() == {"displacement": 1, "zncc": 1, "isolated": 1}


def test_expected_zncc_deficit_matches_noise_on_a_perfect_match():
    """Two noisy copies of one speckle image (sigma 4): the ZNCC of co-located subsets is ``1 - sigma^2 / var(f)``
    within 15 % of the deficit (64 subsets of 31 px)."""
    rng = np.random.default_rng(2)
    clean = gaussian_speckle(extent_for_shape((160, 160), 2.0), 2.0, seed=9).render_reference((160, 160))
    f, g = clean + rng.normal(0, 4.0, clean.shape), clean + rng.normal(0, 4.0, clean.shape)
    xs, ys = np.meshgrid(np.arange(24, 136, 14), np.arange(24, 136, 14))
    xs, ys = xs.ravel(), ys.ravel()
    measured = []
    for x, y in zip(xs, ys):
        a, b = f[y - 15:y + 16, x - 15:x + 16].ravel(), g[y - 15:y + 16, x - 15:x + 16].ravel()
        measured.append(1.0 - np.corrcoef(a, b)[0, 1])
    ratio = np.array(measured) / expected_zncc_deficit(f, xs, ys, 31, 4.0)
    assert abs(np.median(ratio) - 1.0) < 0.15


# --- errors -----------------------------------------------------------------------------------------------

def test_bad_arguments_raise_value_errors():
    image = np.random.default_rng(0).normal(100, 2, (64, 64))
    with pytest.raises(ValueError, match="odd and >= 5"):
        texture_mask(image, 20)
    with pytest.raises(ValueError, match="noise_sigma_grey"):
        texture_mask(image, 21, noise_sigma_grey=-1.0)
    with pytest.raises(ValueError, match="target_precision_px"):
        texture_mask(image, 21, target_precision_px=0.0)
    with pytest.raises(ValueError, match="2-D grey"):
        texture_mask(image[None], 21)
    with pytest.raises(ValueError, match="at least 8"):
        estimate_noise_sigma(image[:20, :20])
    with pytest.raises(ValueError, match="quantile"):
        estimate_noise_sigma(image, quantile=0.9)
    index = np.array([[0, 0], [0, 1]])
    with pytest.raises(ValueError, match="at least 3 x 3"):
        consistency_flags(index, (2, 5), np.zeros(2), np.zeros(2))
    with pytest.raises(ValueError, match="shape"):
        consistency_flags(index, (4, 4), np.zeros(3), np.zeros(2))
    with pytest.raises(ValueError, match="outside"):
        consistency_flags(np.array([[0, 9]]), (4, 4), np.zeros(1), np.zeros(1))
    with pytest.raises(ValueError, match="zncc_ratio"):
        AutoRoi(zncc_ratio=0.5)
    with pytest.raises(ValueError, match="enough texture"):
        correlate_auto_roi(np.full((96, 96), 50.0), np.full((96, 96), 50.0), DICSettings(subset_size=21, step=8))


# --- wiring: workbench dic and the stereo hook ------------------------------------------------------------

def test_workbench_dic_auto_roi_writes_statuses_and_counts(runs, tmp_path, capsys):
    """``workbench dic --auto-roi``: the CSV holds every grid point, flagged ones NaN with their status name, and
    the printed count matches the CSV."""
    from workbench.cli import main

    reference, deformed, *_ = runs
    for name, image in (("ref.png", reference), ("def.png", deformed)):
        assert cv2.imwrite(str(tmp_path / name), np.clip(np.rint(image), 0, 255).astype(np.uint8))
    out = tmp_path / "points.csv"
    assert main(["dic", str(tmp_path / "ref.png"), str(tmp_path / "def.png"), "--subset", "33", "--step", "8",
                 "--auto-roi", "--out", str(out)]) == 0
    rows = list(csv.DictReader(out.open()))
    names = [r["status_name"] for r in rows]
    low, bad = names.count("low_texture"), names.count("inconsistent")
    assert low > 0 and bad > 0
    assert all(r["u"] == "nan" for r in rows if r["status_name"] in ("low_texture", "inconsistent"))
    printed = capsys.readouterr().out
    assert (f"auto ROI: {low + bad} of {len(rows)} points flagged: {low} low texture, {bad} inconsistent"
            in printed), printed
    assert main(["dic", str(tmp_path / "ref.png"), str(tmp_path / "def.png"), "--noise-sigma", "2",
                 "--out", str(tmp_path / "p.csv")]) == 2
    assert "--noise-sigma needs --auto-roi" in capsys.readouterr().err


def test_stereo_reference_shape_auto_roi_hook():
    """The stereo hook on a fake pair (the scene's deformed image as the right view, so the DIC truth is known and
    the triangulation is meaningless: its thresholds are off): background is LOW_TEXTURE, no kept match is
    wrong by more than ``KEPT_ERROR_PX``, and the measured fraction is of the textured points."""
    from measurement.stereo_dic import reference_shape
    from workbench.rigs import paper_rig

    rig = paper_rig(0.25)
    shape_px = (rig.left.height, rig.left.width)
    reference, deformed = make_scene(shape=shape_px, seed=4)
    settings = DICSettings(subset_size=33, step=12, order=1)
    shape = reference_shape(rig.left, rig.right, rig.R_right_from_left, rig.T_right_from_left_mm, reference,
                            deformed, settings, max_median_residual_px=None, min_measured_fraction=None,
                            auto_roi=AutoRoi())
    match, report = shape.right_match, shape.auto_roi_report
    assert match.x.size == shape.grid.count == report.points
    specimen, fixture = _scale_box(SPECIMEN, shape_px), _scale_box(FIXTURE, shape_px)
    reach = HALF + MARGIN_PX
    on_background = ~(_inside((specimen[0] - reach, specimen[1] - reach, fixture[2] + reach, fixture[3] + reach),
                              match.x, match.y))
    assert on_background.sum() > 100 and (match.status[on_background] == Status.LOW_TEXTURE).all()
    assert np.nanmax(_error(match, shape_px)[match.converged]) <= KEPT_ERROR_PX
    assert report.low_texture == int(np.count_nonzero(match.status == Status.LOW_TEXTURE))
    assert shape.quality.points == report.points - report.low_texture


def test_workbench_stereo_auto_roi(tmp_path, capsys):
    """``workbench stereo --auto-roi`` on the fake pair (thresholds off, as above): the reference and state CSVs
    carry low_texture and inconsistent points, and both counts are printed and match the reference CSV."""
    from measurement.calibration.io import CalibratedRig, export_opencv_yaml
    from workbench.cli import main
    from workbench.rigs import paper_rig

    rig = paper_rig(0.25)
    reference, deformed = make_scene(shape=(rig.left.height, rig.left.width), seed=4)
    for name, image in (("left_ref", reference), ("right_ref", deformed), ("left_def", deformed),
                        ("right_def", deformed)):
        assert cv2.imwrite(str(tmp_path / f"{name}.png"), np.clip(np.rint(image), 0, 255).astype(np.uint8))
    export_opencv_yaml(CalibratedRig("rmm", rig.left, rig.right, rig.R_right_from_left, rig.T_right_from_left_mm),
                       tmp_path / "rig.yaml")
    out = tmp_path / "out"
    assert main(["stereo", "--calib", str(tmp_path / "rig.yaml"), "--left-ref", str(tmp_path / "left_ref.png"),
                 "--right-ref", str(tmp_path / "right_ref.png"), "--left", str(tmp_path / "left_def.png"),
                 "--right", str(tmp_path / "right_def.png"), "--subset", "33", "--step", "12", "--order", "1",
                 "--max-residual-px", "1e9", "--min-measured-fraction", "0", "--auto-roi", "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    names = [r["status_name"] for r in csv.DictReader((out / "reference.csv").open())]
    low, bad = names.count("low_texture"), names.count("inconsistent")
    assert low > 0 and bad > 0
    assert (f"reference auto ROI: {low + bad} of {len(names)} points flagged: {low} low texture, {bad} inconsistent"
            in printed), printed
    state = [r["status_name"] for r in csv.DictReader((out / "state_001.csv").open())]
    assert state.count("low_texture") == low and state.count("inconsistent") >= 1
    assert "state 1 auto ROI:" in printed


def test_the_edges_of_a_region_with_a_steep_gradient_are_not_peeled():
    """A smooth, steep field (a stereo disparity: 3 px per grid step, with curvature) measured on an irregular
    region (a D-shaped specimen with a hole) and 0.01 px noise: at most 2 % of the points are flagged (measured:
    4 of 320, corner nodes with three neighbours, whose median of three is noisy). The plain neighbour-median
    test flags every node whose neighbours lie on one side (it differs from their median by a gradient step while
    their spread is ~0), and iterating peeled five columns of good points on the Stereo-DIC Challenge's Sample 3; a
    0.5 px outlier on the region's edge is still flagged."""
    rng = np.random.default_rng(3)
    rows, cols = np.mgrid[0:18, 0:30]
    inside = (((cols - 14.5) / 14.0) ** 2 + ((rows - 2.0) / 15.0) ** 2 < 1.0) \
        & ~((((cols - 14.5) / 6.0) ** 2 + ((rows - 3.0) / 2.5) ** 2) < 1.0) & (rows >= 1)
    r, c = rows[inside], cols[inside]
    u = 3.0 * c + 0.02 * c ** 2 - 0.5 * r + rng.normal(0, 0.01, r.size)
    v = 0.4 * c - 1.5 * r + 0.01 * r ** 2 + rng.normal(0, 0.01, r.size)
    grid_index = np.column_stack([r, c])
    flags = consistency_flags(grid_index, rows.shape, u, v)
    assert flags.counts().get("displacement", 0) <= 0.02 * r.size, flags.counts()
    edge = int(np.flatnonzero((c == c.min()) & ~flags.flagged)[0])
    u_bad = u.copy()
    u_bad[edge] += 0.5
    bad = consistency_flags(grid_index, rows.shape, u_bad, v)
    assert bad.reason[edge] == "displacement"
    assert bad.counts().get("displacement", 0) <= flags.counts().get("displacement", 0) + 1
