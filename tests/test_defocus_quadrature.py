"""Thin-lens defocus without Monte Carlo (scenes.rendering.defocus_quadrature) against converged Mitsuba thin-lens renders.

The scene is the depth-of-field experiment's at 0.2 scale: a speckled plate at 38° seen by an untilted sensor
through a thin lens at f/4, in focus on one column and blurred up to a ~3.5 px circle at the sides. The
reference is two independent 1024-spp Mitsuba renders; the renderer's systematic error is estimated without
their noise as ``sqrt(mean((q - a)(q - b)))`` (a, b: the two halves, whose noises are independent).
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from scenes.rendering.defocus_rules import (DEFAULT_TOLERANCE_GREY, choose_rule, rule_size, texture_detail_texels,
                                            thin_lens_rule)
from scenes.rendering.defocus_quadrature import fill_defocused_faces
from scenes.rendering.exact import render_view_in_focus
from scenes.rendering.mitsuba import render_view

#: The issue's bound on a deterministic render's error against converged Mitsuba, grey RMS.
RENDER_ERROR_GREY = 0.1


@pytest.fixture(scope="module")
def plate_views():
    from workbench.experiments.depth_of_field.run import depth_of_field_scene

    scene = depth_of_field_scene(scale=0.2, object_tilt_deg=38.0, seed=0)
    surface = scene.plate.surface(scene.R_world_from_plate, scene.t_world_from_plate_mm, scene.plate.texture())
    spec = scene.specs["conventional"]
    pose = (np.eye(3), np.zeros(3))
    halves = [render_view(spec, *pose, [surface], spp=1024, seed=s, exposure_grey=255.0).image_grey
              for s in (21, 22)]
    return scene, surface, spec, pose, halves


def _systematic_grey(image, halves, mask):
    a, b = (h[mask].astype(np.float64) for h in halves)
    q = image[mask].astype(np.float64)
    cross = float(np.mean((q - a) * (q - b)))
    return float(np.sign(cross) * np.sqrt(abs(cross)))


def test_a_defocused_plate_equals_converged_mitsuba_within_0p1_grey(plate_views):
    """Every pixel of the blurred plate is made (the plate fills the view), and the image's systematic error
    against two 1024-spp Mitsuba thin-lens renders is <= 0.1 grey RMS, over the whole image and over its most
    blurred tenth (blur circle >= 3 px), with no mean offset beyond 4 standard errors of the reference."""
    scene, surface, spec, pose, halves = plate_views
    image, known, info = render_view_in_focus(spec, *pose, [surface], exposure_grey=255.0)
    assert not known.any()                      # nothing is in focus enough for the in-focus renderer
    image, known, info = fill_defocused_faces(spec, *pose, [surface], image, known, exposure_grey=255.0)
    assert known.all() and info["defocus_pixels"] == known.size and info["defocus_groups"] == 1
    assert max(b["error_grey"] for b in info["defocus_bins"]) <= DEFAULT_TOLERANCE_GREY + 1e-12
    everything = np.ones(image.shape, dtype=bool)
    assert _systematic_grey(image, halves, everything) <= RENDER_ERROR_GREY
    from scenes.optics.projection import defocus_blur_px, pixel_rays

    cols = np.arange(image.shape[1])
    rays = pixel_rays(spec, *pose, np.column_stack([cols, np.full(cols.size, image.shape[0] // 2)]))
    normal = scene.R_world_from_plate[:, 2]
    lam = (normal @ scene.t_world_from_plate_mm) / (rays[1] @ normal)
    blur = defocus_blur_px(spec, *pose, rays[1] * lam[:, None])
    blurred = np.zeros(image.shape, dtype=bool)
    blurred[:, blur >= 3.0] = True
    assert blurred.sum() > 0.05 * blurred.size
    assert _systematic_grey(image, halves, blurred) <= RENDER_ERROR_GREY
    noise = 0.5 * (halves[0] - halves[1])
    diff = image - 0.5 * (halves[0] + halves[1])
    assert abs(diff.mean()) < 4 * np.sqrt(np.mean(noise ** 2)) / np.sqrt(diff.size) + 1e-3


def test_a_wrong_blur_radius_misses_mitsuba_by_more_than_the_bound(plate_views):
    """The comparison can fail: the same quadrature with the aperture 10 % too small (f/4.4 for f/4: every blur
    circle 9 % too small) misses the converged render by more than 0.1 grey RMS."""
    scene, surface, spec, pose, halves = plate_views
    wrong = replace(spec, f_number=spec.f_number * 1.1)
    image, known, _ = render_view_in_focus(wrong, *pose, [surface], exposure_grey=255.0)
    image, known, _ = fill_defocused_faces(wrong, *pose, [surface], image, known, exposure_grey=255.0)
    assert known.all()
    assert _systematic_grey(image, halves, np.ones(image.shape, dtype=bool)) > RENDER_ERROR_GREY


def test_pixels_whose_blur_reaches_past_the_face_are_left_for_mitsuba(plate_views):
    """A plate smaller than the view: pixels whose blur circle (+ margin) reaches its edge stay unknown and 0,
    pixels off the plate too; the ones made inside equal Mitsuba within 0.1 grey."""
    from scenes.specimens.plate import SpeckledPlate

    scene, _, spec, pose, _ = plate_views
    p = scene.plate
    small = SpeckledPlate(width_mm=0.5 * p.width_mm, height_mm=0.5 * p.height_mm, texel_mm=p.texel_mm,
                          speckle_mm=p.speckle_mm, seed=3)
    surface = small.surface(scene.R_world_from_plate, scene.t_world_from_plate_mm)
    image, known, _ = render_view_in_focus(spec, *pose, [surface], exposure_grey=255.0)
    image, known, info = fill_defocused_faces(spec, *pose, [surface], image, known, exposure_grey=255.0)
    assert 0.1 * known.size < info["defocus_pixels"] < 0.5 * known.size and not known.all()
    assert np.all(image[~known] == 0)
    halves = [render_view(spec, *pose, [surface], spp=256, seed=s, exposure_grey=255.0).image_grey for s in (1, 2)]
    lit = 0.5 * (halves[0] + halves[1]) > 0
    edge = lit & ~known
    assert edge.sum() > 0                        # the blurred silhouette is Mitsuba's
    assert np.all(image[known & ~lit] == 0)       # off the plate and out of its blur's reach: black
    assert _systematic_grey(image, halves, known) <= RENDER_ERROR_GREY


def test_rules_integrate_constants_and_the_chosen_rule_meets_its_tolerance_against_a_much_denser_one():
    """Every rule's weights sum to 1 (a constant texture is exact); the rule ``choose_rule`` picks for a 4 px
    blur of a 5 px speckle errs by at most 1.5x the tolerance against an independent rule with ~10x the nodes
    of its own dense rule (the selection measures against the dense rule, this checks that rule too)."""
    from scenes.rendering.defocus_rules import _model_values
    from scenes.surfaces.speckle import speckle_pattern

    for sizes in [(2, 1, 1), (3, 4, 7), (6, 2, 5)]:
        rule = thin_lens_rule(*sizes)
        assert rule.shape == (rule_size(*sizes), 5) and abs(rule[:, 4].sum() - 1.0) < 1e-12
        assert np.all(np.hypot(rule[:, 2], rule[:, 3]) <= 1.0 + 1e-12)
    texture = speckle_pattern((1200, 1200), 12.5, contrast=0.8, mean=0.5, seed=4).astype(np.float32)
    J = np.array([[2.5, 0.3], [-0.2, 2.1]])
    choice = choose_rule(texture, J, 4.0, 255.0, tolerance_grey=0.03, seed=0)
    assert choice["nodes"] < rule_size(*choice["dense"]) and choice["error_grey"] <= 0.03
    rng = np.random.default_rng(9)
    centres = rng.uniform(150, 1050, (200, 2))
    fine = _model_values(texture, centres, J, 4.0, np.ascontiguousarray(thin_lens_rule(8, 30, 160)))
    got = _model_values(texture, centres, J, 4.0, np.ascontiguousarray(thin_lens_rule(*choice["rule"])))
    assert 255.0 * np.sqrt(np.mean((got - fine) ** 2)) <= 1.5 * 0.03
    # the detail length of a 5 px (12.5 texel) speckle is ~0.3 of its diameter
    assert 0.25 * 12.5 < texture_detail_texels(texture) < 0.4 * 12.5


def test_a_pinhole_or_a_known_view_is_returned_unchanged(plate_views):
    """Nothing to do: a pinhole view, or every pixel already known, comes back as given."""
    scene, surface, spec, pose, _ = plate_views
    image = np.full((spec.height, spec.width), 7.0, dtype=np.float32)
    known = np.ones(image.shape, dtype=bool)
    out, k, info = fill_defocused_faces(spec, *pose, [surface], image, known)
    assert info["defocus_pixels"] == 0 and np.array_equal(out, image) and k.all()
    pin = replace(spec, lens="pinhole")
    out, k, info = fill_defocused_faces(pin, *pose, [surface], image, ~known)
    assert info["defocus_pixels"] == 0 and not k.any()


def _reference_pixels(spec, surface, rows, cols, rule, exposure_grey):
    """The rule, evaluated the textbook way in float64 (numpy): per node, the ray from the aperture point
    through the sub-pixel's focus point (scenes.optics.projection), its hit on the mesh's triangles, the hit's
    barycentric texture coordinates, Mitsuba's bilinear lookup with clamping. Camera at the world origin."""
    from scenes.optics.projection import in_focus_points_world_mm

    A_mm = 0.5 * spec.focal_length_mm / spec.f_number
    tex = np.asarray(surface.texture, dtype=np.float64)
    th, tw = tex.shape
    V = np.asarray(surface.vertices_mm, dtype=float)
    F_idx = np.asarray(surface.faces, dtype=int)
    uv = np.asarray(surface.uv, dtype=float)
    n_pix, n_nodes = len(rows), len(rule)
    pos = np.column_stack([(cols[:, None] - 0.5 + rule[None, :, 0]).ravel(),
                           (rows[:, None] - 0.5 + rule[None, :, 1]).ravel()])
    F = in_focus_points_world_mm(spec, np.eye(3), np.zeros(3), pos)
    a = np.zeros_like(F)
    a[:, 0] = np.tile(A_mm * rule[:, 2], n_pix)
    a[:, 1] = np.tile(A_mm * rule[:, 3], n_pix)
    d = F - a
    tu = np.full(len(F), np.nan)
    tv = np.full(len(F), np.nan)
    for tri in F_idx:                                        # Moller-Trumbore on each triangle
        p0, p1, p2 = V[tri]
        e1, e2 = p1 - p0, p2 - p0
        h = np.cross(d, e2)
        det = h @ e1
        s = a - p0
        b1 = np.einsum("ij,ij->i", s, h) / det
        q = np.cross(s, e1)
        b2 = np.einsum("ij,ij->i", d, q) / det
        inside = (b1 >= 0) & (b2 >= 0) & (b1 + b2 <= 1)
        w = np.column_stack([1 - b1 - b2, b1, b2])[inside]
        t_uv = w @ uv[tri]
        tu[inside] = t_uv[:, 0] * tw - 0.5
        tv[inside] = t_uv[:, 1] * th - 0.5
    assert np.isfinite(tu).all(), "every node's ray must meet the plate"
    x = np.clip(tu, 0, tw - 1)
    y = np.clip(tv, 0, th - 1)
    i0 = np.minimum(x.astype(int), tw - 2)
    j0 = np.minimum(y.astype(int), th - 2)
    fx, fy = x - i0, y - j0
    top = tex[j0, i0] * (1 - fx) + tex[j0, i0 + 1] * fx
    bottom = tex[j0 + 1, i0] * (1 - fx) + tex[j0 + 1, i0 + 1] * fx
    values = (top * (1 - fy) + bottom * fy).reshape(n_pix, n_nodes)
    return exposure_grey * values @ rule[:, 4]


def test_the_float32_kernel_equals_a_float64_ray_tracing_of_the_same_rule_within_0p002_grey(plate_views):
    """Precision and geometry of the kernel: on 300 pixels across the blur range, one rule (4 pixel nodes x
    3 rings) evaluated by the float32 kernel and by a float64 numpy ray tracing of the same nodes against the
    plate's triangles differ by at most 0.002 grey. A float32 evaluation at absolute texel positions (~10^-3
    texel at 10^4 texels), a wrong plane, texel map or focus point would fail it."""
    from scenes.rendering.defocus_quadrature import _affine_texel_map, _integrate_pixels, _node_table
    from scenes.rendering.exact import sensor_corner_coordinates
    from scenes.optics.projection import tilted_sensor_axes

    scene, surface, spec, pose, _ = plate_views
    rng = np.random.default_rng(5)
    rows = rng.integers(20, spec.height - 20, 300)
    cols = rng.integers(20, spec.width - 20, 300)
    rule = np.ascontiguousarray(thin_lens_rule(2, 3, 9))
    faces = np.asarray(surface.faces, dtype=int)
    V = np.asarray(surface.vertices_mm, dtype=float)          # camera = world frame here
    n, d, M, m = _affine_texel_map(surface, V, faces)
    A_mm = 0.5 * spec.focal_length_mm / spec.f_number
    axes = tilted_sensor_axes(spec.alpha_deg, spec.beta_deg)
    out = np.empty(len(rows))
    _integrate_pixels(rows.astype(np.int64), cols.astype(np.int64), np.zeros(len(rows), dtype=np.int64),
                      np.array([0, len(rule)], dtype=np.int64), _node_table(rule, A_mm, n, M),
                      sensor_corner_coordinates(spec), spec.cx, spec.cy, spec.fx, spec.fy, axes[2, 0], axes[2, 1],
                      spec.image_distance_mm, spec.focal_length_mm, n, d, M, m, 200,
                      np.ascontiguousarray(surface.texture, dtype=np.float32), out)
    ref = _reference_pixels(spec, surface, rows, cols, rule, 255.0)
    assert np.abs(255.0 * out - ref).max() <= 0.002
    assert np.ptp(ref) > 50                                    # the pixels see the speckle, not a flat grey


def test_skipping_sharp_face_groups_changes_no_pixel(monkeypatch):
    """A face group in focus (blur <= the in-focus limit) is not integrated unless an unknown pixel of the
    sensor's outer ring lies under it (the in-focus pass cannot see coverage past the edge). The skip must change
    nothing: the bending beam's views (sharp front face, reference and loaded) and the depth-of-field scene's
    tilted camera (whose ring the quadrature fills: 1 800 px at this scale) give the same pixels with the skip
    forced off."""
    import scenes.rendering.defocus_quadrature as dq
    from scenes.rendering.exact import render_view_in_focus
    from workbench.experiments.bending.scenes import bending_truth
    from workbench.experiments.depth_of_field.run import depth_of_field_scene
    from workbench.rigs import get_rig

    truth = bending_truth(get_rig("scheimpflug", 0.15), lens="thin", f_number=8.0, loads_N=(20.0, 2000.0))
    texture = truth.specimen.texture()
    cases = []
    for k in (0, 1):
        surfaces = truth.specimen.surfaces(*truth.pose, texture=texture, displacement_mm=truth.field(k))
        for side in ("left", "right"):
            cases.append((truth.specs[side], truth.camera_poses[side], surfaces))
    dof = depth_of_field_scene(scale=0.2, seed=0)
    plate = dof.plate.surface(dof.R_world_from_plate, dof.t_world_from_plate_mm, dof.plate.texture())
    cases.append((dof.specs["scheimpflug"], (np.eye(3), np.zeros(3)), [plate]))
    made = []
    for spec, pose, surfaces in cases:
        image, known, _ = render_view_in_focus(spec, *pose, surfaces, exposure_grey=255.0)
        skipped = dq.fill_defocused_faces(spec, *pose, surfaces, image, known, exposure_grey=255.0)
        with monkeypatch.context() as m:
            m.setattr(dq, "_ring_open", lambda known, P: True)
            full = dq.fill_defocused_faces(spec, *pose, surfaces, image, known, exposure_grey=255.0)
        assert np.array_equal(skipped[1], full[1])
        assert np.array_equal(skipped[0], full[0])
        made.append(int(full[2]["defocus_pixels"]))
    assert made[-1] > 1000       # the ring of the tilted camera: the case the exception is for
