"""Thin-lens defocus of curved meshes without Monte Carlo (scenes.rendering.defocus_mesh through
scenes.rendering.defocus_quadrature.fill_defocused_faces) against converged Mitsuba and a textbook ray tracing.

The scene is the depth-of-field experiment's at 0.2 scale (an untilted sensor at f/4 on a plate at 38°, blur
circles up to ~3.5 px), the plate tessellated into 24 x 16 quads and bent into a parabolic cylinder that bulges
2 mm towards the camera: no two neighbouring triangles share a plane, so the flat-face path has nothing to hold
and every blurred pixel is the triangle walk's. The reference is two independent 1024-spp Mitsuba renders (the
systematic error without their noise, as in tests/test_defocus_quadrature.py).
"""
from __future__ import annotations

import numpy as np
import pytest

from scenes.rendering.defocus_mesh import edge_neighbours, integrate_pixels, smooth_components, triangle_table
from scenes.rendering.defocus_quadrature import fill_defocused_faces
from scenes.rendering.defocus_rules import thin_lens_rule
from scenes.rendering.exact import render_view_in_focus
from scenes.rendering.mitsuba import render_view
from scenes.surfaces.textured_surface import TexturedSurface
from test_defocus_quadrature import RENDER_ERROR_GREY, _reference_pixels, _systematic_grey

SAG_MM = 2.0


def _bent_plate(scene, nx: int = 24, ny: int = 16, sag_mm: float = SAG_MM) -> TexturedSurface:
    """The plate as an nx x ny quad grid, z = -sag (1 - (2x/W)^2) in the plate frame (towards the camera)."""
    p = scene.plate
    x = np.linspace(-p.width_mm / 2, p.width_mm / 2, nx + 1)
    y = np.linspace(-p.height_mm / 2, p.height_mm / 2, ny + 1)
    X, Y = np.meshgrid(x, y)
    Z = -sag_mm * (1.0 - (2.0 * X / p.width_mm) ** 2)
    local = np.column_stack([X.ravel(), Y.ravel(), Z.ravel()])
    uv = np.column_stack([(X.ravel() + p.width_mm / 2) / p.width_mm, (Y.ravel() + p.height_mm / 2) / p.height_mm])
    idx = np.arange((nx + 1) * (ny + 1)).reshape(ny + 1, nx + 1)
    c0, c1, c2, c3 = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, 1:].ravel(), idx[1:, :-1].ravel()
    faces = np.concatenate([np.column_stack([c0, c2, c1]), np.column_stack([c0, c3, c2])])   # normal -z
    verts = local @ np.asarray(scene.R_world_from_plate).T + np.asarray(scene.t_world_from_plate_mm)
    return TexturedSurface(vertices_mm=verts, faces=faces, uv=uv, texture=p.texture(), filter="bilinear")


@pytest.fixture(scope="module")
def bent_views():
    from workbench.experiments.depth_of_field.run import depth_of_field_scene

    scene = depth_of_field_scene(scale=0.2, object_tilt_deg=38.0, seed=0)
    surface = _bent_plate(scene)
    spec = scene.specs["conventional"]
    pose = (np.eye(3), np.zeros(3))
    halves = [render_view(spec, *pose, [surface], spp=1024, seed=s, exposure_grey=255.0).image_grey
              for s in (31, 32)]
    return scene, surface, spec, pose, halves


def test_a_bent_defocused_plate_equals_converged_mitsuba_within_0p1_grey(bent_views):
    """The triangle walk makes >= 99 % of the view (the bent plate fills it; measured: all of it), no flat group is
    used, and the made pixels' systematic error against two 1024-spp Mitsuba renders is <= 0.1 grey RMS
    (measured 0.07), also over the pixels blurred by >= 2 px."""
    scene, surface, spec, pose, halves = bent_views
    image, known, _ = render_view_in_focus(spec, *pose, [surface], exposure_grey=255.0)
    before = known.copy()
    image, known, info = fill_defocused_faces(spec, *pose, [surface], image, known, exposure_grey=255.0)
    made = known & ~before
    assert info["defocus_groups"] == 0 and info["defocus_patches"] == 1
    assert made.sum() >= 0.99 * made.size
    assert _systematic_grey(image, halves, made) <= RENDER_ERROR_GREY
    from scenes.optics.projection import defocus_blur_px
    from scenes.specimens.ray_surface import cast_rays

    hits = cast_rays(spec, *pose, surface.vertices_mm, surface.faces)
    r, c = np.nonzero(made)
    pts = np.asarray(surface.vertices_mm)[np.asarray(surface.faces)[hits.triangle[r, c]]].mean(axis=1)
    blurred = np.zeros_like(made)
    blurred[r, c] = defocus_blur_px(spec, *pose, pts) >= 2.0
    assert blurred.sum() > 0.05 * blurred.size
    assert _systematic_grey(image, halves, blurred) <= RENDER_ERROR_GREY


def test_a_sag_5_percent_short_misses_mitsuba_by_more_than_the_bound(bent_views):
    """The comparison can fail: the same view rendered with the bent plate's 2 mm sag 5 % short (0.1 mm, a few
    pixel footprints of depth) misses the converged render of the real one by more than 0.1 grey RMS."""
    scene, surface, spec, pose, halves = bent_views
    wrong = _bent_plate(scene, sag_mm=0.95 * SAG_MM)
    image, known, _ = render_view_in_focus(spec, *pose, [wrong], exposure_grey=255.0)
    before = known.copy()
    image, known, _ = fill_defocused_faces(spec, *pose, [wrong], image, known, exposure_grey=255.0)
    made = known & ~before
    assert made.sum() >= 0.99 * made.size
    assert _systematic_grey(image, halves, made) > RENDER_ERROR_GREY


def test_the_walk_equals_a_textbook_ray_tracing_of_the_same_rule_within_1e_6_grey(bent_views):
    """Geometry of the walk: on 300 pixels, one rule (3 pixel nodes x 4 rings) by the kernel and by a float64
    numpy Moller-Trumbore test of every node's ray against every triangle differ by <= 1e-6 grey. A walk that
    stopped on the wrong triangle, a wrong barycentric dual basis or texel map would fail it."""
    from scenes.rendering.exact import sensor_corner_coordinates
    from scenes.specimens.ray_surface import cast_rays
    from scenes.optics.projection import tilted_sensor_axes

    scene, surface, spec, pose, _ = bent_views
    rng = np.random.default_rng(7)
    hits = cast_rays(spec, *pose, surface.vertices_mm, surface.faces)
    r, c = np.nonzero(hits.triangle >= 0)
    inner = (r > 30) & (r < spec.height - 30) & (c > 30) & (c < spec.width - 30)
    pick = rng.choice(np.flatnonzero(inner), 300, replace=False)
    rows, cols = r[pick], c[pick]
    rule = np.ascontiguousarray(thin_lens_rule(3, 4, 12))
    faces = np.asarray(surface.faces)
    V = np.asarray(surface.vertices_mm, dtype=float)             # camera = world frame here
    tab = triangle_table(V, faces, surface.uv, np.asarray(surface.texture).shape)
    axes = tilted_sensor_axes(spec.alpha_deg, spec.beta_deg)
    out = np.empty(len(rows))
    integrate_pixels(rows.astype(np.int64), cols.astype(np.int64), hits.triangle[rows, cols],
                     np.zeros(len(rows), dtype=np.int64), np.array([0, len(rule)], dtype=np.int64), rule,
                     0.5 * spec.focal_length_mm / spec.f_number, sensor_corner_coordinates(spec), spec.cx, spec.cy,
                     spec.fx, spec.fy, axes[2, 0], axes[2, 1], spec.image_distance_mm, spec.focal_length_mm, tab,
                     edge_neighbours(faces, V), np.ascontiguousarray(surface.texture, dtype=np.float32), out)
    ref = _reference_pixels(spec, surface, rows, cols, rule, 255.0)
    assert np.isfinite(out).all()
    assert np.abs(255.0 * out - ref).max() <= 1e-6
    assert np.ptp(ref) > 50


def test_a_walk_that_leaves_the_patch_gives_nan():
    """Two triangles of a unit square 100 mm in front of a pinhole-like thin lens: a pixel whose rays all land in
    the square is made, one whose rays cross the square's edge is NaN (left for Mitsuba), not a clamped value."""
    from scenes.optics.camera import SensorSpec
    from scenes.rendering.exact import sensor_corner_coordinates
    from scenes.optics.projection import tilted_sensor_axes

    # image distance 400 px x 0.0625 mm = 25 mm: a 20 mm lens focused at 100 mm, where a pixel covers 0.25 mm
    spec = SensorSpec(fx=400.0, fy=400.0, cx=19.5, cy=19.5, width=40, height=40, lens="thin", focal_length_mm=20.0,
                      f_number=2.0, pixel_pitch_mm=0.0625)
    V = np.array([[-2.0, -2.0, 100.0], [2.0, -2.0, 100.0], [2.0, 2.0, 100.0], [-2.0, 2.0, 100.0]])
    faces = np.array([[0, 2, 1], [0, 3, 2]])
    uv = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    tex = np.ones((8, 8), dtype=np.float32)
    tab = triangle_table(V, faces, uv, tex.shape)
    rule = np.ascontiguousarray(thin_lens_rule(2, 2, 8))
    axes = tilted_sensor_axes(spec.alpha_deg, spec.beta_deg)
    # in focus: pixel (20, 20) sees x in [0.125, 0.375] mm, inside the square; (20, 28) x in [2.0, 2.25] mm, past
    # its edge at x = 2 mm
    rows = np.array([20, 20], dtype=np.int64)
    cols = np.array([20, 28], dtype=np.int64)
    out = np.empty(2)
    integrate_pixels(rows, cols, np.zeros(2, dtype=np.int64), np.zeros(2, dtype=np.int64),
                     np.array([0, len(rule)], dtype=np.int64), rule, 0.5 * spec.focal_length_mm / spec.f_number,
                     sensor_corner_coordinates(spec), spec.cx, spec.cy, spec.fx, spec.fy, axes[2, 0], axes[2, 1],
                     spec.image_distance_mm, spec.focal_length_mm, tab, edge_neighbours(faces, V), tex, out)
    assert out[0] == pytest.approx(1.0, abs=1e-6)
    assert np.isnan(out[1])


def test_edge_neighbours_match_a_brute_force_search_and_stop_at_creases():
    """On the bent plate's grid every interior edge pairs its two triangles (checked against a brute-force search
    over shared vertex pairs); a 90° fold of the same grid cuts it in two smooth components at the crease."""
    from workbench.experiments.depth_of_field.run import depth_of_field_scene

    scene = depth_of_field_scene(scale=0.05, object_tilt_deg=38.0, seed=0)
    surface = _bent_plate(scene, nx=6, ny=4)
    F = np.asarray(surface.faces)
    nb = edge_neighbours(F)
    for i, tri in enumerate(F):
        for k in range(3):
            edge = {tri[(k + 1) % 3], tri[(k + 2) % 3]}
            others = [j for j, o in enumerate(F) if j != i and edge <= set(o)]
            assert nb[i, k] == (others[0] if others else -1)
    V = np.asarray(surface.vertices_mm, dtype=float).copy()
    # fold the grid along its middle column of vertices: x > 0 turned 90° about the fold line
    local = (V - scene.t_world_from_plate_mm) @ scene.R_world_from_plate
    right = local[:, 0] > 1e-9
    local[right, 2] = local[right, 2] - local[right, 0]
    local[right, 0] = 0.0 + 1e-3 * local[right, 0]
    folded = local @ scene.R_world_from_plate.T + scene.t_world_from_plate_mm
    parts = smooth_components(F, edge_neighbours(F, folded))
    assert len(parts) == 2 and sum(len(p) for p in parts) == len(F)
    assert len(smooth_components(F, edge_neighbours(F, V))) == 1


def test_a_degenerate_triangle_is_refused_by_name():
    V = np.array([[0.0, 0.0, 10.0], [1.0, 0.0, 10.0], [2.0, 0.0, 10.0]])
    with pytest.raises(ValueError, match="1 degenerate"):
        triangle_table(V, np.array([[0, 1, 2]]), np.zeros((3, 2)), (4, 4))


def test_a_face_behind_the_patch_hides_nothing_and_one_in_front_is_kept_clear_of(bent_views):
    """A large flat plate 20 mm behind the bent plate (its footprint overlaps the whole view) leaves every pixel
    the walk made alone made, bit for bit (its depth is behind the patch along every chief ray); a small plate
    10 mm in front of the patch's middle is an occluder: no pixel within 1 px of its projected outline is made
    by quadrature (its blurred edge is Mitsuba's)."""
    from scenes.specimens.plate import SpeckledPlate
    from scenes.optics.projection import project_points

    scene, surface, spec, pose, _ = bent_views
    n = np.asarray(scene.R_world_from_plate)[:, 2]                  # plate normal (+z: away from the camera)
    p = scene.plate
    back = SpeckledPlate(width_mm=2 * p.width_mm, height_mm=2 * p.height_mm, texel_mm=p.texel_mm,
                         speckle_mm=p.speckle_mm, seed=9).surface(scene.R_world_from_plate,
                                                                   scene.t_world_from_plate_mm + 20.0 * n)
    alone, known0, _ = fill_defocused_faces(spec, *pose, [surface], *render_view_in_focus(
        spec, *pose, [surface], exposure_grey=255.0)[:2], exposure_grey=255.0)
    both, known1, _ = fill_defocused_faces(spec, *pose, [surface, back], *render_view_in_focus(
        spec, *pose, [surface, back], exposure_grey=255.0)[:2], exposure_grey=255.0)
    assert known1.sum() >= 0.99 * known0.sum()
    assert np.array_equal(both[known0 & known1], alone[known0 & known1])

    small = SpeckledPlate(width_mm=0.2 * p.width_mm, height_mm=0.2 * p.height_mm, texel_mm=p.texel_mm,
                          speckle_mm=p.speckle_mm, seed=11)
    front = small.surface(scene.R_world_from_plate, scene.t_world_from_plate_mm - 10.0 * n)
    image, known, _ = render_view_in_focus(spec, *pose, [surface, front], exposure_grey=255.0)
    image, known, _ = fill_defocused_faces(spec, *pose, [surface, front], image, known, exposure_grey=255.0)
    V = np.asarray(front.vertices_mm)
    edge = np.concatenate([V[i] + np.linspace(0, 1, 200)[:, None] * (V[(i + 1) % 4] - V[i]) for i in range(4)])
    xy = project_points(spec, *pose, edge)
    r = np.clip(np.round(xy[:, 1]).astype(int), 0, spec.height - 1)
    c = np.clip(np.round(xy[:, 0]).astype(int), 0, spec.width - 1)
    near = np.zeros_like(known)
    for dr in (-1, 0, 1):
        for dc in (-1, 0, 1):
            near[np.clip(r + dr, 0, spec.height - 1), np.clip(c + dc, 0, spec.width - 1)] = True
    assert not known[near].any()
    assert known.sum() > 0.5 * known.size
