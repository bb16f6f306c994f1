"""scenes.surfaces.image_texture: a photographed image as a continuous texture, moved in the image plane and painted on a
plane seen through a rig.

References are analytic: smooth functions sampled by hand, and plane points found by an independent ray-plane
intersection built on measurement.camera.ScheimpflugCamera's back-projection (the instrument's camera model,
not scenes.optics.projection's rays that the module itself uses).
"""
from __future__ import annotations

import numpy as np
import pytest

from measurement.camera import ScheimpflugCamera
from scenes.optics.camera import SensorSpec
from scenes.surfaces.image_texture import ImageTexture, TexturedPlane, render_deformed_image, render_plane_view


# ------------------------------------------------------------------------------------------------------------
# ImageTexture
# ------------------------------------------------------------------------------------------------------------
def test_texture_reproduces_pixels_at_integer_points_within_1e_9():
    image = np.random.default_rng(3).uniform(0.0, 255.0, size=(23, 31))
    texture = ImageTexture.from_image(image)
    y, x = np.mgrid[0:23, 0:31].astype(np.float64)
    values, inside = texture(x, y)
    assert inside.all()
    assert np.max(np.abs(values - image)) <= 1e-9
    # integer dtype in, same values
    as_uint8 = np.rint(image).astype(np.uint8)
    values8, _ = ImageTexture.from_image(as_uint8)(x, y)
    assert np.max(np.abs(values8 - as_uint8)) <= 1e-9


def test_texture_outside_the_image_gives_fill_grey_and_inside_false():
    image = np.random.default_rng(4).uniform(10.0, 200.0, size=(12, 15))
    texture = ImageTexture.from_image(image)
    assert texture.fill_grey == pytest.approx(image.mean(), rel=1e-15)
    x = np.array([-0.01, 14.01, 3.0, 3.0, -5.0, 7.5, np.nan, 2.0, 0.0, 14.0])
    y = np.array([5.0, 5.0, -0.01, 11.01, -5.0, 40.0, 3.0, np.inf, 0.0, 11.0])
    values, inside = texture(x, y)
    np.testing.assert_array_equal(inside, [False] * 8 + [True, True])
    np.testing.assert_array_equal(values[:8], np.full(8, texture.fill_grey))
    assert values[8] == pytest.approx(image[0, 0], abs=1e-9)
    assert values[9] == pytest.approx(image[11, 14], abs=1e-9)


def test_texture_refuses_bad_images():
    with pytest.raises(ValueError, match="at least 4 x 4 px"):
        ImageTexture.from_image(np.zeros((3, 10)))
    with pytest.raises(ValueError, match="finite everywhere"):
        ImageTexture.from_image(np.full((5, 5), np.nan))


# ------------------------------------------------------------------------------------------------------------
# render_deformed_image
# ------------------------------------------------------------------------------------------------------------
SMOOTH_AMPLITUDE = 45.0        # |20| + |15| + |10|


def smooth(x, y):
    """Band-limited: three sinusoids of periods 12, 16 and ~11.4 px (>= 12 px along each axis)."""
    return (100.0 + 20.0 * np.sin(2.0 * np.pi * x / 12.0 + 0.4) + 15.0 * np.cos(2.0 * np.pi * y / 16.0 - 1.0)
            + 10.0 * np.sin(2.0 * np.pi * (x / 20.0 + y / 14.0)))


def test_render_deformed_translation_equals_analytic_shift_within_1e_3_of_amplitude():
    """(u, v) = (0.3, -0.2) px: the image is f(x - u, y - v) within 1e-3 of f's amplitude, 8 px from the edges."""
    rows, cols = 64, 80
    y, x = np.mgrid[0:rows, 0:cols].astype(np.float64)
    texture = ImageTexture.from_image(smooth(x, y))
    u, v = 0.3, -0.2
    image, valid = render_deformed_image(texture, lambda X, Y: (np.full_like(X, u), np.full_like(Y, v)))
    interior = np.zeros_like(valid)
    interior[8:-8, 8:-8] = True
    assert valid[interior].all()
    error = np.abs(image - smooth(x - u, y - v))[interior]
    assert error.max() <= 1e-3 * SMOOTH_AMPLITUDE
    # the material point left the texture where x - u < 0 (column 0) or y - v > rows - 1 (last row)
    assert not valid[:, 0].any() and not valid[-1, :].any()
    assert valid[:-1, 1:].all()
    np.testing.assert_array_equal(image[~valid], texture.fill_grey)


def test_render_deformed_without_displacement_is_the_texture_and_shape_is_honoured():
    image = np.random.default_rng(5).uniform(0.0, 255.0, size=(20, 24))
    texture = ImageTexture.from_image(image)
    same, valid = render_deformed_image(texture)
    assert valid.all() and np.max(np.abs(same - image)) <= 1e-9
    larger, valid = render_deformed_image(texture, shape=(25, 30))
    assert larger.shape == (25, 30)
    assert valid[:20, :24].all() and not valid[20:, :].any() and not valid[:, 24:].any()


def test_render_deformed_nonuniform_field_solves_the_material_point_within_1e_3():
    """u = 1e-2 (x - 40), v = -5e-3 (y - 32) (a stretch): pixel x shows f(X) with X + u(X) = x, solved by hand."""
    rows, cols = 64, 80
    y, x = np.mgrid[0:rows, 0:cols].astype(np.float64)
    texture = ImageTexture.from_image(smooth(x, y))
    a, b = 1e-2, -5e-3
    image, valid = render_deformed_image(texture, lambda X, Y: (a * (X - 40.0), b * (Y - 32.0)))
    X = (x + 40.0 * a) / (1.0 + a)          # X + a (X - 40) = x
    Y = (y + 32.0 * b) / (1.0 + b)
    interior = np.zeros_like(valid)
    interior[8:-8, 8:-8] = True
    assert valid[interior].all()
    assert np.abs(image - smooth(X, Y))[interior].max() <= 1e-3 * SMOOTH_AMPLITUDE


# ------------------------------------------------------------------------------------------------------------
# render_plane_view through a stereo rig
# ------------------------------------------------------------------------------------------------------------
WIDTH, HEIGHT, F_PX = 320, 240, 2000.0
PLANE_Z_MM = 500.0
PLANE_AMPLITUDE = 45.0          # |30| + |15|


def g(P):
    """A smooth pattern on the plane z = 500 mm, P = (x, y) world mm; periods 7-9 mm (28-36 px at 0.25 mm/px)."""
    x, y = P[..., 0], P[..., 1]
    return (128.0 + 30.0 * np.sin(2.0 * np.pi * x / 7.0 + 0.3) * np.cos(2.0 * np.pi * y / 9.0 - 0.2)
            + 15.0 * np.cos(2.0 * np.pi * (x + y) / 11.0))


def rotation_about_y(deg):
    c, s = np.cos(np.deg2rad(deg)), np.sin(np.deg2rad(deg))
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


@pytest.fixture(scope="module")
def rig():
    """Left camera at the origin looking along +z; right camera 100 mm to the right, its axis turned 15 deg
    toward the left one (R_cam_from_world = R_y(15 deg), so the camera z axis is (-sin 15, 0, cos 15))."""
    spec = SensorSpec(fx=F_PX, fy=F_PX, cx=(WIDTH - 1) / 2.0, cy=(HEIGHT - 1) / 2.0, width=WIDTH, height=HEIGHT)
    left = (np.eye(3), np.zeros(3))
    R = rotation_about_y(15.0)
    centre = np.array([100.0, 0.0, 0.0])
    right = (R, -R @ centre)
    return spec, left, right


def plane_points_by_hand(pose):
    """Each pixel's chief ray (ScheimpflugCamera.rays, camera frame -> world by R^T) meets z = 500 mm: (H, W, 3)."""
    camera = ScheimpflugCamera(fx=F_PX, fy=F_PX, cx=(WIDTH - 1) / 2.0, cy=(HEIGHT - 1) / 2.0, width=WIDTH,
                               height=HEIGHT)
    R, t = pose
    centre = -R.T @ t
    yy, xx = np.mgrid[0:HEIGHT, 0:WIDTH]
    pixels = np.column_stack([xx.ravel(), yy.ravel()]).astype(np.float64)
    directions = camera.rays(pixels) @ R                  # rows R^T d
    s = (PLANE_Z_MM - centre[2]) / directions[:, 2]
    return (centre + s[:, None] * directions).reshape(HEIGHT, WIDTH, 3)


@pytest.fixture(scope="module")
def textured(rig):
    """The left camera's photograph of g, painted on the plane it shows."""
    spec, left, _ = rig
    photograph = g(plane_points_by_hand(left)[..., :2])
    plane = TexturedPlane(np.array([0.0, 0.0, PLANE_Z_MM]), np.array([0.0, 0.0, -1.0]),
                          ImageTexture.from_image(photograph), spec, left)
    return photograph, plane


def texture_pixels_of(points_mm):
    """Where the left (texture) camera sees world points, px, by the pinhole formula u = cx + f X / Z."""
    return np.stack([(WIDTH - 1) / 2.0 + F_PX * points_mm[..., 0] / points_mm[..., 2],
                     (HEIGHT - 1) / 2.0 + F_PX * points_mm[..., 1] / points_mm[..., 2]], axis=-1)


def away_from_texture_edge(texture_px, margin=3.0):
    """Points at least ``margin`` px inside the texture image: next to its edges the cubic spline's mirror
    boundary, not the pattern, sets the values (errors of a few % of the amplitude within 1 px)."""
    u, v = texture_px[..., 0], texture_px[..., 1]
    return (u >= margin) & (v >= margin) & (u <= WIDTH - 1 - margin) & (v <= HEIGHT - 1 - margin)


def test_plane_view_of_the_texture_camera_is_its_photograph_inside_within_1e_6(rig, textured):
    """Every pixel not on the image's outer ring: the texture camera's own view is its photograph (1e-6 grey)."""
    spec, left, _ = rig
    photograph, plane = textured
    image, valid = render_plane_view(spec, left, plane)
    assert valid[1:-1, 1:-1].all()
    assert np.max(np.abs(image - photograph)[1:-1, 1:-1]) <= 1e-6


def test_plane_view_of_the_texture_camera_is_its_photograph_pixel_for_pixel(rig, textured):
    """The module's promise: 'The texture camera's own view of the unmoved plane is its photograph, pixel for
    pixel' -- including row 0 and column 0, whose round trip lands ~1e-14 px outside [0, size - 1]."""
    spec, left, _ = rig
    photograph, plane = textured
    image, valid = render_plane_view(spec, left, plane)
    flagged = np.argwhere(~valid)
    assert flagged.size == 0, (f"{len(flagged)} pixels (row, col) flagged outside the texture, e.g. "
                               f"{flagged[:4].tolist()}")
    assert np.max(np.abs(image - photograph)) <= 1e-6


def test_plane_view_of_the_right_camera_equals_g_at_its_plane_points_within_1_percent(rig, textured):
    """The right camera (15 deg, 100 mm baseline) sees g at its pixels' plane points within 1 % of g's
    amplitude, where the texture covers them (3 px from the texture's edges); elsewhere it shows fill_grey."""
    spec, _, right = rig
    _, plane = textured
    image, valid = render_plane_view(spec, right, plane)
    points = plane_points_by_hand(right)
    in_texture = away_from_texture_edge(texture_pixels_of(points))
    assert in_texture.mean() > 0.3                         # the views overlap on a good part of the image
    assert valid[in_texture].all()
    error = np.abs(image - g(points[..., :2]))[in_texture]
    assert error.max() <= 0.01 * PLANE_AMPLITUDE
    # pixels whose plane point the left camera does not see
    outside = ~away_from_texture_edge(texture_pixels_of(points), margin=-0.5)
    assert outside.mean() > 0.3
    assert not valid[outside].any()
    np.testing.assert_array_equal(image[~valid], plane.texture.fill_grey)


def test_plane_view_with_an_in_plane_translation_equals_g_of_p_minus_t_within_1_percent(rig, textured):
    """displacement_mm = t = (0.6, -0.35, 0) mm everywhere: the left view is g(P - t) within 1 % of the amplitude
    (3 px from the texture's edges)."""
    spec, left, _ = rig
    _, plane = textured
    t = np.array([0.6, -0.35, 0.0])
    image, valid = render_plane_view(spec, left, plane, lambda X: np.broadcast_to(t, X.shape))
    points = plane_points_by_hand(left)
    material = points - t
    in_texture = away_from_texture_edge(texture_pixels_of(material))
    assert in_texture.mean() > 0.9
    assert valid[in_texture].all()
    error = np.abs(image - g(material[..., :2]))[in_texture]
    assert error.max() <= 0.01 * PLANE_AMPLITUDE
    # the translation really moved the view (|grad g| t is many times the tolerance)
    assert np.abs(image - g(points[..., :2]))[in_texture].max() > 0.1 * PLANE_AMPLITUDE


def test_plane_view_rows_renders_only_those_rows(rig, textured):
    spec, _, right = rig
    _, plane = textured
    full, full_valid = render_plane_view(spec, right, plane)
    part, part_valid = render_plane_view(spec, right, plane, rows=slice(100, 140))
    np.testing.assert_array_equal(part[100:140], full[100:140])
    np.testing.assert_array_equal(part_valid[100:140], full_valid[100:140])
    assert not part_valid[:100].any() and not part_valid[140:].any()
    np.testing.assert_array_equal(part[:100], plane.texture.fill_grey)


def test_textured_plane_refuses_a_texture_of_another_size(rig):
    spec, left, _ = rig
    with pytest.raises(ValueError, match="but its camera is"):
        TexturedPlane(np.array([0.0, 0.0, PLANE_Z_MM]), np.array([0.0, 0.0, -1.0]),
                      ImageTexture.from_image(np.zeros((10, 10))), spec, left)
    with pytest.raises(ValueError, match="normal is zero"):
        TexturedPlane(np.array([0.0, 0.0, PLANE_Z_MM]), np.zeros(3),
                      ImageTexture.from_image(np.zeros((HEIGHT, WIDTH))), spec, left)
