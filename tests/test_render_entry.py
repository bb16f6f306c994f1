"""The one render entry (scenes.rendering.render.render_views): which renderer it picks, what it records, and why.

Claims:
* a pinhole view of a flat board is made by the exact renderer with nothing to explain; a thin lens at a fixed
  spp is rendered by Mitsuba whole, with the exact renderer's refusal (the thin lens blurs) and the refused view
  recorded; asked for ``exact`` it raises that refusal naming the view;
* a fixed-spp Monte-Carlo view ``c`` is seeded ``seed + c``, so two views of one scene never share their noise
  (equal to Mitsuba's renderer called with that seed, different from the neighbour's seed);
* a photographed texture seen by the camera that took it is that photograph, pixel for pixel (the photograph
  is the independent reference);
* bad options are refused naming the option.
"""
from __future__ import annotations

import numpy as np
import pytest

from scenes.rendering.exact import NotExactError
from scenes.rendering.mitsuba import render_view
from scenes.rendering.render import RENDERER_MITSUBA, RENDERER_PHOTO, render_views
from scenes.surfaces.checkerboard import Checkerboard
from scenes.surfaces.image_texture import ImageTexture, TexturedPlane
from workbench.experiments.calibration.views import board_outline_mm, sensor_spec_for
from workbench.poses import random_board_poses
from workbench.rigs import get_rig


@pytest.fixture(scope="module")
def board_scene():
    rig = get_rig("paper", 0.1)
    board = Checkerboard()
    R_wb, t_wb = random_board_poses(rig, board_outline_mm(board), 1, 0)[0]
    views = [(sensor_spec_for(rig, side), rig.pose(side)) for side in ("left", "right")]
    return views, [board.surface(R_wb, t_wb)]


def test_a_pinhole_board_is_made_exactly_and_a_thin_lens_by_mitsuba_with_the_reason(board_scene):
    views, surfaces = board_scene
    made = render_views(views, surfaces)
    assert [v.renderer for v in made] == ["exact-polygon", "exact-polygon"]
    assert all(v.reason is None and v.mc is None for v in made)
    thin = [(spec.with_(lens="thin", focal_length_mm=16.0, f_number=8.0), pose) for spec, pose in views]
    made = render_views(thin, surfaces, spp=2, seed=5)
    assert [v.renderer for v in made] == [RENDERER_MITSUBA, RENDERER_MITSUBA]
    assert made[0].reason_view == 0 and "the thin lens blurs (defocus)" in made[0].reason
    with pytest.raises(NotExactError, match=r"the thin lens blurs \(defocus\)") as err:
        render_views(thin, surfaces, renderer="exact")
    assert err.value.view_index == 0


def test_fixed_spp_views_are_seeded_apart_as_mitsuba_renders_them(board_scene):
    views, surfaces = board_scene
    made = render_views(views, surfaces, renderer="mitsuba", spp=2, seed=7)
    for c, (spec, pose) in enumerate(views):
        same = render_view(spec, *pose, surfaces, spp=2, seed=7 + c).image_grey
        other = render_view(spec, *pose, surfaces, spp=2, seed=7 + 1 - c).image_grey
        assert np.array_equal(made[c].image_grey, same)
        assert not np.array_equal(made[c].image_grey, other)


def test_a_photograph_seen_by_its_own_camera_is_the_photograph():
    rig = get_rig("paper", 0.1)
    spec = sensor_spec_for(rig, "left")
    photo = np.random.default_rng(3).uniform(20.0, 230.0, (spec.height, spec.width))
    plane = TexturedPlane(np.array([0.0, 0.0, 400.0]), np.array([0.0, 0.0, -1.0]), ImageTexture.from_image(photo),
                          spec, rig.pose("left"))
    (view,) = render_views([(spec, rig.pose("left"))], plane)
    assert view.renderer == RENDERER_PHOTO
    assert view.valid.all()
    assert np.max(np.abs(view.image_grey - photo)) < 1e-6


def test_bad_options_are_refused_naming_them(board_scene):
    views, surfaces = board_scene
    with pytest.raises(ValueError, match=r"renderer 'fast': choose one of auto, exact, mitsuba"):
        render_views(views, surfaces, renderer="fast")
    with pytest.raises(ValueError, match=r"displacement_mm moves a photographed plane only"):
        render_views(views, surfaces, displacement_mm=lambda X: 0 * X)
    with pytest.raises(ValueError, match=r"view_seeds: one seed per view \(2\), got 1"):
        render_views(views, surfaces, renderer="mitsuba", spp=1, view_seeds=[1])
