"""Cropped, adaptively sampled renders (scenes.rendering.adaptive) against full fixed-spp renders of the same scene.

The reference is Mitsuba's own film and stratified sampler (scenes.rendering.mitsuba.render_view) over the whole sensor:
an independent implementation of the pixel integral. Claims: outside the crop the full render is exactly
background; inside, the two agree to within their Monte-Carlo noise, without bias; the MC noise the adaptive
render reports is the one two independent renders show; same seed, same image.
"""
from __future__ import annotations

import numpy as np
import pytest

from scenes.rendering.adaptive import AdaptiveSettings, render_view_adaptive, render_views_adaptive
from scenes.rendering.mitsuba import render_view
from scenes.surfaces.checkerboard import Checkerboard
from workbench.experiments.calibration.views import board_outline_mm, sensor_spec_for
from workbench.poses import random_board_poses
from workbench.rigs import get_rig

SCALE = 0.25
TARGET_GREY = 0.3


@pytest.fixture(scope="module")
def board_scene():
    rig = get_rig("paper", SCALE)
    board = Checkerboard()
    R_wb, t_wb = random_board_poses(rig, board_outline_mm(board), 2, 5)[1]
    return sensor_spec_for(rig, "left"), rig.pose("left"), [board.surface(R_wb, t_wb)]


@pytest.fixture(scope="module")
def speckle_scene():
    from workbench.experiments.rigid_motion.scenes import rigid_motion_truth

    truth = rigid_motion_truth(get_rig("scheimpflug", SCALE), lens="thin", seed=0)
    surfaces = truth.specimen.surfaces(*truth.poses[0], texture=truth.specimen.texture())
    return truth.specs["left"], truth.camera_poses["left"], surfaces


def _fixed(spec, pose, surfaces, seed, spp=256):
    return render_view(spec, *pose, surfaces, spp=spp, seed=seed).image_grey


@pytest.mark.parametrize("scene", ["board_scene", "speckle_scene"])
def test_adaptive_render_equals_full_render_within_the_mc_noise_it_reports(scene, request):
    spec, pose, surfaces = request.getfixturevalue(scene)
    settings = AdaptiveSettings(target_mc_grey=TARGET_GREY)
    adaptive = render_view_adaptive(spec, *pose, surfaces, seed=3, settings=settings)
    full_a, full_b = _fixed(spec, pose, surfaces, 11), _fixed(spec, pose, surfaces, 12)
    x0, y0, w, h = adaptive.crop
    outside = np.ones(full_a.shape, dtype=bool)
    outside[y0:y0 + h, x0:x0 + w] = False
    assert outside.any() and np.all(full_a[outside] == 0) and np.all(full_b[outside] == 0)
    assert np.all(adaptive.image_grey[outside] == 0)
    lit = (full_a > 0) | (adaptive.image_grey > 0)
    # MC noise of the 256-spp reference, from its own two seeds
    ref_var = np.mean((full_a - full_b)[lit] ** 2) / 2
    mc = adaptive.mc["mc_rms_grey"]
    diff = (adaptive.image_grey - 0.5 * (full_a + full_b))[lit]
    expected_rms = np.sqrt(mc ** 2 + ref_var / 2)
    assert np.sqrt(np.mean(diff ** 2)) <= 1.25 * expected_rms, (np.sqrt(np.mean(diff ** 2)), expected_rms)
    # unbiased: the mean difference is within 4 standard errors (pixels treated as independent)
    assert abs(diff.mean()) <= 4 * expected_rms / np.sqrt(lit.sum()) + 1e-4
    assert mc <= 1.2 * TARGET_GREY


@pytest.mark.parametrize("scene", ["board_scene", "speckle_scene"])
def test_reported_mc_noise_is_what_two_independent_renders_show(scene, request):
    spec, pose, surfaces = request.getfixturevalue(scene)
    a, b = (render_view_adaptive(spec, *pose, surfaces, seed=s) for s in (21, 22))
    lit = (a.image_grey > 0) | (b.image_grey > 0)
    pair_rms = np.sqrt(np.mean((a.image_grey - b.image_grey)[lit] ** 2) / 2)
    reported = 0.5 * (a.mc["mc_rms_grey"] + b.mc["mc_rms_grey"])
    # the check pixels are ~3 % of the lit pixels: their RMS estimate is good to a few percent; 25 % allows for
    # the pixels that two renders refine differently
    assert reported == pytest.approx(pair_rms, rel=0.25)


def test_a_board_costs_fewer_samples_than_fixed_64_spp_with_less_mc_noise(board_scene):
    spec, pose, surfaces = board_scene
    adaptive = render_view_adaptive(spec, *pose, surfaces, seed=4, settings=AdaptiveSettings(target_mc_grey=0.2))
    f1, f2 = (_fixed(spec, pose, surfaces, s, spp=64) for s in (31, 32))
    lit = f1 > 0
    fixed_rms = np.sqrt(np.mean((f1 - f2)[lit] ** 2) / 2)
    assert adaptive.mc["sensor_spp"] < 64
    assert adaptive.mc["mc_rms_grey"] < fixed_rms
    # flat squares keep the pilot's 9 samples: most of the board
    assert adaptive.mc["spp_histogram"].get(9, 0) > 0.5 * adaptive.mc["lit_pixels"]


def test_same_seed_same_image_and_views_of_one_scene_equal_single_renders(board_scene):
    spec, pose, surfaces = board_scene
    a = render_view_adaptive(spec, *pose, surfaces, seed=7)
    b = render_view_adaptive(spec, *pose, surfaces, seed=7)
    assert np.array_equal(a.image_grey, b.image_grey) and np.array_equal(a.spp_map, b.spp_map)
    both = render_views_adaptive([(spec, pose), (spec, pose)], surfaces, seed=7)
    assert np.array_equal(both[0].image_grey, a.image_grey)
    assert not np.array_equal(both[1].image_grey, a.image_grey)          # view 1 has its own seed


def test_a_crop_that_misses_the_surface_grows(board_scene):
    """Margin 0 and a board reaching the image border: the crop still covers every lit pixel of a full render."""
    spec, pose, surfaces = board_scene
    adaptive = render_view_adaptive(spec, *pose, surfaces, seed=8, settings=AdaptiveSettings(margin_px=0))
    full = _fixed(spec, pose, surfaces, 9, spp=16)
    x0, y0, w, h = adaptive.crop
    inside = np.zeros(full.shape, dtype=bool)
    inside[y0:y0 + h, x0:x0 + w] = True
    assert np.all(full[~inside] == 0)


@pytest.mark.parametrize("kwargs, message", [
    ({"target_mc_grey": 0.0}, "target_mc_grey must be a positive number"),
    ({"sides": (2, 4)}, "sides must ascend above pilot_side"),
    ({"sides": (8, 4)}, "sides must ascend above pilot_side"),
    ({"check_fraction": 0.0}, "check_fraction must be in"),
    ({"margin_px": -1}, "margin_px must be >= 0"),
])
def test_bad_settings_are_refused(kwargs, message):
    with pytest.raises(ValueError, match=message):
        AdaptiveSettings(**kwargs)


def test_nothing_to_render_is_refused(board_scene):
    spec, pose, _ = board_scene
    with pytest.raises(ValueError, match="nothing to render"):
        render_view_adaptive(spec, *pose, [])


def test_a_target_the_sample_budget_cannot_reach_is_named(board_scene):
    """A 0.02 grey target with at most 5 x 5 samples per pixel cannot be met on the board's edges: the render
    says so (a warning naming the target and why; ``mc["target_met"]`` False) instead of returning quietly. The
    same view and seed with the default budget at 0.3 grey meets its target and says nothing. (Other seeds of
    this quarter-scale board measure up to 0.46 grey for 0.3: the error model under-allocates some views; the
    warning names those too.)"""
    import warnings

    spec, pose, surfaces = board_scene
    with pytest.warns(UserWarning, match=r"view 0: the Monte-Carlo noise target 0.02 grey RMS was not reached: "
                                         r".* of the lit pixels would need more samples"):
        starved = render_view_adaptive(spec, *pose, surfaces, seed=2,
                                       settings=AdaptiveSettings(target_mc_grey=0.02, sides=(4, 5)))
    assert starved.mc["target_met"] is False and starved.mc["mc_rms_grey"] > 0.02
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        fine = render_view_adaptive(spec, *pose, surfaces, seed=2, settings=AdaptiveSettings(target_mc_grey=0.3))
    assert fine.mc["target_met"] is True and fine.mc["mc_rms_grey"] <= 1.25 * 0.3


def test_a_blurred_silhouette_converges_no_worse_than_mitsubas_own_sampler():
    """The aperture strata are permuted per pixel, independently of the film strata: on the blurred silhouette of
    a small plate seen at f/4 (blur up to ~3.5 px; the pixels the deterministic renderers leave), two adaptive
    renders at 32 x 32 samples per pixel differ by no more than two 1024-spp renders of Mitsuba's own film
    (independent sampler), and their mean agrees with Mitsuba's within 4 standard errors. A lattice coupling of
    aperture and film strata (q = a k + b mod n) scattered such pixels by ~10x Mitsuba's noise and fails it."""
    from scenes.rendering.defocus_quadrature import fill_defocused_faces
    from scenes.rendering.exact import render_view_in_focus
    from scenes.specimens.plate import SpeckledPlate
    from workbench.experiments.depth_of_field.run import depth_of_field_scene

    scene = depth_of_field_scene(scale=0.2, object_tilt_deg=38.0, seed=0)
    p = scene.plate
    small = SpeckledPlate(width_mm=0.5 * p.width_mm, height_mm=0.5 * p.height_mm, texel_mm=p.texel_mm,
                          speckle_mm=p.speckle_mm, seed=3)
    surfaces = [small.surface(scene.R_world_from_plate, scene.t_world_from_plate_mm)]
    spec, pose = scene.specs["conventional"], (np.eye(3), np.zeros(3))
    image, known, _ = render_view_in_focus(spec, *pose, surfaces, exposure_grey=255.0)
    image, known, _ = fill_defocused_faces(spec, *pose, surfaces, image, known, exposure_grey=255.0)
    ref = [render_view(spec, *pose, surfaces, spp=1024, seed=s, exposure_grey=255.0).image_grey for s in (5, 6)]
    settings = AdaptiveSettings(target_mc_grey=1e-3, sides=(32,))
    ours = [render_views_adaptive([(spec, pose)], surfaces, seed=s, settings=settings,
                                  known=[(image, known)])[0].image_grey for s in (7, 8)]
    edge = ~known & (0.5 * (ref[0] + ref[1]) > 5.0)
    assert edge.sum() > 200
    spread_ours = np.sqrt(np.mean((ours[0] - ours[1])[edge] ** 2) / 2)
    spread_mitsuba = np.sqrt(np.mean((ref[0] - ref[1])[edge] ** 2) / 2)
    assert spread_ours <= spread_mitsuba, (spread_ours, spread_mitsuba)
    diff = (0.5 * (ours[0] + ours[1]) - 0.5 * (ref[0] + ref[1]))[edge]
    stderr = np.sqrt((spread_ours ** 2 + spread_mitsuba ** 2) / 2 / edge.sum())
    assert abs(diff.mean()) <= 4 * stderr
