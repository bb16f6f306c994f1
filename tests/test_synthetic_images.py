"""Tests for scenes.image_pairs.gaussian_speckle: exact Fourier-shifted and analytic Gaussian-speckle image pairs."""
import numpy as np
import pytest

from scenes.surfaces.speckle import speckle_size_from_pattern
from scenes.image_pairs.gaussian_speckle import (GaussianSpeckle, extent_for_shape, gaussian_speckle,
                                                 radius_for_speckle_size, speckle_size_for_radius)
from scenes.image_pairs.analytic_fields import (HomogeneousStrain, QuadraticField, Rotation, Translation,
                                                solve_reference_positions)
from scenes.image_pairs.fourier_shift import band_limit, fourier_shift, fourier_shifted_pair

SQRT2 = np.sqrt(2.0)


def _random_image(shape, seed=0):
    return np.random.default_rng(seed).uniform(0.0, 255.0, shape)


def _pixel_grid(shape):
    y, x = np.mgrid[0:shape[0], 0:shape[1]].astype(np.float64)
    return x, y


# ------------------------------------------------------------------------------------------------------------
# Fourier shifting
# ------------------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("shape", [(32, 48), (33, 47)])
@pytest.mark.parametrize("shift", [(3, -5), (-50, 17)])
def test_integer_shift_is_a_roll(shape, shift):
    image = _random_image(shape)
    shifted = fourier_shift(image, shift)
    assert shifted.dtype == np.float64 and shifted.shape == shape
    # g(x, y) = f(x - sx, y - sy): columns roll by sx, rows by sy.
    expected = np.roll(band_limit(image), (shift[1], shift[0]), axis=(0, 1))
    np.testing.assert_allclose(shifted, expected, rtol=0, atol=1e-9)
    if shape[0] % 2 and shape[1] % 2:
        # odd sizes have no Nyquist bin: the roll of the image itself
        np.testing.assert_allclose(shifted, np.roll(image, (shift[1], shift[0]), axis=(0, 1)), rtol=0, atol=1e-9)


def test_shift_moves_content_by_plus_s():
    blob = GaussianSpeckle([(10.0, 5.0)], [1.5], background_grey=0.0, amplitude_grey=-1.0,
                           extent_xy_px=extent_for_shape((20, 30)), periodic=True)
    image = blob.render_reference((20, 30))
    assert np.unravel_index(np.argmax(image), image.shape) == (5, 10)  # (row = y, column = x)
    moved = fourier_shift(image, (4.0, 2.0))
    assert np.unravel_index(np.argmax(moved), moved.shape) == (7, 14)


@pytest.mark.parametrize("shape", [(40, 64), (41, 63)])
def test_shift_and_back_gives_band_limited_original(shape):
    image = _random_image(shape, seed=1)
    there_and_back = fourier_shift(fourier_shift(image, (0.37, -2.81)), (-0.37, 2.81))
    np.testing.assert_allclose(there_and_back, band_limit(image), rtol=0, atol=1e-9)


def test_shifts_compose():
    image = _random_image((48, 40), seed=2)
    s1, s2 = (0.3, -1.45), (-2.7, 0.85)
    twice = fourier_shift(fourier_shift(image, s1), s2)
    np.testing.assert_allclose(twice, fourier_shift(image, (s1[0] + s2[0], s1[1] + s2[1])), rtol=0, atol=1e-9)


def test_band_limit_removes_only_the_nyquist_bins():
    even = _random_image((32, 48), seed=3)
    limited = band_limit(even)
    spectrum = np.fft.fft2(limited)
    assert np.abs(spectrum[16, :]).max() < 1e-8 and np.abs(spectrum[:, 24]).max() < 1e-8
    mask = np.ones(even.shape, dtype=bool)
    mask[16, :] = False
    mask[:, 24] = False
    np.testing.assert_allclose(spectrum[mask], np.fft.fft2(even)[mask], rtol=0, atol=1e-8)
    np.testing.assert_allclose(band_limit(limited), limited, rtol=0, atol=1e-9)  # idempotent
    odd = _random_image((33, 47), seed=3)
    np.testing.assert_allclose(band_limit(odd), odd, rtol=0, atol=1e-9)


def test_fourier_shift_matches_analytic_shift_where_aliasing_is_negligible():
    """Fourier shift of the sampled pattern vs the pattern evaluated at x - s.

    They differ only by aliasing (and the zeroed Nyquist bins). Measured, max |difference| over 128 x 96 px:
    1.5e-3 grey at sigma = 1.5 px, 0.10 grey at 1.2 px, 1.1 grey at 1.0 px, 7.6 grey at 0.8 px (grey std 30).
    """
    shape, shift = (128, 96), (0.37, -0.61)
    x, y = _pixel_grid(shape)
    errors = {}
    for sigma in (1.5, 0.8):
        pattern = gaussian_speckle(extent_for_shape(shape), SQRT2 * sigma, 0.5, seed=2, periodic=True)
        reference = pattern.render_reference(shape)
        exact = pattern.evaluate(np.stack([x - shift[0], y - shift[1]], axis=-1))
        errors[sigma] = (fourier_shift(reference, shift) - exact, reference.std())
    difference, _ = errors[1.5]
    assert np.abs(difference).max() < 5e-3
    # The bias that aliasing leaves at sigma = 0.8 px is the documented ~5 % rms of the grey std.
    difference, grey_std = errors[0.8]
    assert 0.02 < difference.std() / grey_std < 0.1


def test_fourier_shifted_pair():
    shape, shift = (256, 256), (0.25, -0.4)
    reference, shifted = fourier_shifted_pair(shape, 2.5, shift, seed=3)
    assert reference.shape == shifted.shape == shape
    assert reference.dtype == shifted.dtype == np.float64
    np.testing.assert_allclose(shifted, fourier_shift(reference, shift), rtol=0, atol=1e-9)
    np.testing.assert_allclose(band_limit(reference), reference, rtol=0, atol=1e-9)
    assert abs(speckle_size_from_pattern(reference) - 2.5) < 0.1  # measured 2.49
    assert abs(reference.mean() - 128.0) < 3.0 and abs(reference.std() - 30.0) < 2.0
    again, _ = fourier_shifted_pair(shape, 2.5, shift, seed=3)
    other, _ = fourier_shifted_pair(shape, 2.5, shift, seed=4)
    np.testing.assert_array_equal(reference, again)
    assert np.mean(np.abs(reference - other)) > 10.0


@pytest.mark.parametrize("shift, match", [((np.nan, 0.0), "finite"), ((0.0, np.inf), "finite"),
                                           ((1.0,), "2 numbers"), ((1.0, 2.0, 3.0), "2 numbers"),
                                           ("ab", "2 numbers")])
def test_fourier_shift_rejects_bad_shifts(shift, match):
    with pytest.raises(ValueError, match=match):
        fourier_shift(np.zeros((8, 8)), shift)


def test_fourier_shift_rejects_bad_images():
    with pytest.raises(ValueError, match="2-D"):
        fourier_shift(np.zeros((4, 4, 3)), (0.5, 0.5))
    with pytest.raises(ValueError, match="2-D"):
        fourier_shift(np.zeros((1, 8)), (0.5, 0.5))
    bad = np.zeros((8, 8))
    bad[2, 3] = np.nan
    with pytest.raises(ValueError, match="non-finite"):
        band_limit(bad)
    with pytest.raises(ValueError, match="real"):
        fourier_shift(np.zeros((8, 8), dtype=complex), (0.5, 0.5))
    with pytest.raises(ValueError, match="shape"):
        fourier_shifted_pair((8, 8), 2.5, (0.5, 0.5))
    with pytest.raises(ValueError, match="speckle_size_px"):
        fourier_shifted_pair((64, 64), 0.0, (0.5, 0.5))


# ------------------------------------------------------------------------------------------------------------
# Gaussian speckle
# ------------------------------------------------------------------------------------------------------------
def test_evaluate_matches_brute_force_sum():
    pattern = gaussian_speckle((-3.0, 40.0, -5.0, 30.0), 1.1, 0.6, seed=4, radius_spread=0.3)
    points = np.random.default_rng(0).uniform((-12.0, -14.0), (52.0, 42.0), (3000, 2))  # also outside
    d2 = ((points[:, None, :] - pattern.centres_xy_px[None, :, :]) ** 2).sum(axis=-1)
    brute = pattern.background_grey - pattern.amplitude_grey * np.exp(
        -d2 / (2.0 * pattern.sigmas_px**2)).sum(axis=1)
    np.testing.assert_allclose(pattern.evaluate(points), brute, rtol=0, atol=1e-9)  # measured 2e-10
    np.testing.assert_array_equal(pattern.evaluate(points.reshape(50, 60, 2)), pattern.evaluate(points).reshape(50, 60))


def test_render_reference_samples_pixel_centres_x_column_y_row():
    blob = GaussianSpeckle([(10.0, 3.0)], [1.0], background_grey=200.0, amplitude_grey=100.0,
                           extent_xy_px=extent_for_shape((12, 20)))
    image = blob.render_reference((12, 20))
    assert image.shape == (12, 20) and image.dtype == np.float64
    assert image[3, 10] == pytest.approx(100.0, abs=1e-12)
    assert image[3, 11] == pytest.approx(200.0 - 100.0 * np.exp(-0.5), abs=1e-12)
    x, y = _pixel_grid((12, 20))
    pattern = gaussian_speckle(extent_for_shape((12, 20)), 1.2, seed=1)
    np.testing.assert_array_equal(pattern.render_reference((12, 20)),
                                  pattern.evaluate(np.stack([x, y], axis=-1)))


def test_periodic_pattern_repeats():
    shape = (40, 56)
    pattern = gaussian_speckle(extent_for_shape(shape), 1.3, 0.5, seed=6, periodic=True)
    assert pattern.period_xy_px == (56.0, 40.0)
    points = np.random.default_rng(1).uniform(-5.0, 60.0, (500, 2))
    for offset in [(56.0, 0.0), (0.0, -40.0), (-112.0, 80.0)]:
        np.testing.assert_allclose(pattern.evaluate(points + offset), pattern.evaluate(points), rtol=0, atol=1e-9)


@pytest.mark.parametrize("size_px, spread", [(2.5, 0.0), (3.0, 0.2)])
def test_grey_statistics_and_speckle_size(size_px, spread):
    shape = (256, 256)
    radius = radius_for_speckle_size(size_px, spread)
    assert speckle_size_for_radius(radius, spread) == pytest.approx(size_px, abs=1e-9)
    image = gaussian_speckle(extent_for_shape(shape), radius, 0.5, seed=8, radius_spread=spread).render_reference(
        shape)
    assert abs(image.mean() - 128.0) < 2.0 and abs(image.std() - 30.0) < 2.0
    assert abs(speckle_size_from_pattern(image) - size_px) < 0.04 * size_px  # measured within 2 %


def test_same_seed_identical_different_seed_different():
    shape = (64, 80)
    a = gaussian_speckle(extent_for_shape(shape, 5), 1.2, seed=11).render_deformed(shape, Rotation(3.0, (40, 32)))
    b = gaussian_speckle(extent_for_shape(shape, 5), 1.2, seed=11).render_deformed(shape, Rotation(3.0, (40, 32)))
    c = gaussian_speckle(extent_for_shape(shape, 5), 1.2, seed=12).render_deformed(shape, Rotation(3.0, (40, 32)))
    np.testing.assert_array_equal(a, b)
    assert np.mean(np.abs(a - c)) > 10.0


def test_translation_renders_pattern_at_x_minus_t():
    shape = (48, 64)
    pattern = gaussian_speckle(extent_for_shape(shape, margin_px=5.0), 1.2, seed=9)
    deformed = pattern.render_deformed(shape, Translation(2.3, -1.7))
    x, y = _pixel_grid(shape)
    np.testing.assert_allclose(deformed, pattern.evaluate(np.stack([x - 2.3, y + 1.7], axis=-1)), rtol=0,
                               atol=1e-9)


FIELDS = {
    "rotation": Rotation(25.0, (60.0, 50.0)),
    "large rotation": Rotation(170.0, (60.0, 50.0)),
    "strain": HomogeneousStrain(0.02, -0.01, 0.015, (60.0, 50.0)),
    "quadratic": QuadraticField((1e-4, -2e-4, 3e-4), (2e-4, 1e-4, -1e-4), (60.0, 50.0)),
}


@pytest.mark.parametrize("name", list(FIELDS))
def test_solved_material_points_map_onto_the_pixels(name):
    field, shape = FIELDS[name], (100, 120)
    x, y = _pixel_grid(shape)
    X, Y = solve_reference_positions(x, y, field)
    U, V = field(X, Y)
    assert np.abs(X + U - x).max() < 1e-9 and np.abs(Y + V - y).max() < 1e-9
    pattern = gaussian_speckle(extent_for_shape(shape, margin_px=60.0), 1.2, seed=5)
    np.testing.assert_array_equal(pattern.render_deformed(shape, field), pattern.evaluate(np.stack([X, Y], -1)))


def test_rotation_is_a_finite_rigid_rotation():
    rotation = Rotation(30.0, (5.0, -2.0))
    U, V = rotation(np.array([15.0, 5.0]), np.array([-2.0, 8.0]))
    # +x turns towards +y: (10, 0) from the centre goes to (10 cos 30, 10 sin 30)
    np.testing.assert_allclose([15.0 + U[0], -2.0 + V[0]], [5.0 + 10 * np.cos(np.pi / 6), -2.0 + 5.0], atol=1e-12)
    np.testing.assert_allclose([5.0 + U[1], 8.0 + V[1]], [5.0 - 5.0, -2.0 + 10 * np.cos(np.pi / 6)], atol=1e-12)


@pytest.mark.parametrize("field", [Translation(1.5, -0.5), *FIELDS.values()], ids=lambda f: type(f).__name__)
def test_gradients_match_finite_differences(field):
    X, Y = np.meshgrid(np.linspace(0.0, 120.0, 7), np.linspace(0.0, 100.0, 5))
    h = 1e-4
    u_xp, v_xp = field(X + h, Y)
    u_xm, v_xm = field(X - h, Y)
    u_yp, v_yp = field(X, Y + h)
    u_ym, v_ym = field(X, Y - h)
    numeric = ((u_xp - u_xm) / (2 * h), (u_yp - u_ym) / (2 * h), (v_xp - v_xm) / (2 * h), (v_yp - v_ym) / (2 * h))
    for analytic, approx in zip(field.gradient(X, Y), numeric, strict=True):
        assert analytic.shape == X.shape
        np.testing.assert_allclose(analytic, approx, rtol=0, atol=1e-8)


def test_fixed_point_inversion_of_a_plain_callable():
    def wavy(X, Y):
        return 0.3 * np.sin(X / 10.0), 0.2 * np.cos(Y / 7.0) + 0.01 * X

    x, y = _pixel_grid((30, 40))
    X, Y = solve_reference_positions(x, y, wavy)
    U, V = wavy(X, Y)
    assert np.abs(X + U - x).max() < 1e-9 and np.abs(Y + V - y).max() < 1e-9


# ------------------------------------------------------------------------------------------------------------
# Bad inputs
# ------------------------------------------------------------------------------------------------------------
def test_non_convergent_fields_raise():
    x, y = _pixel_grid((10, 10))
    with pytest.raises(ValueError, match="did not converge.*fixed-point"):
        solve_reference_positions(x, y, lambda X, Y: (1.5 * X, 0.0 * Y))
    folding = QuadraticField((0.2, 0.0, 0.0), (0.0, 0.0, 0.0), (5.0, 5.0))  # x = X + 0.2 (X - 5)^2 folds
    with pytest.raises(ValueError, match="did not converge|folds"):
        solve_reference_positions(x, y, folding)
    pattern = gaussian_speckle(extent_for_shape((10, 10), 50.0), 1.2)
    with pytest.raises(ValueError, match="did not converge|folds"):
        pattern.render_deformed((10, 10), folding)


def test_bad_displacement_callables_raise():
    x, y = _pixel_grid((4, 5))
    with pytest.raises(ValueError, match="shape"):
        solve_reference_positions(x, y, lambda X, Y: (np.zeros(3), np.zeros(3)))
    with pytest.raises(ValueError, match="pair"):
        solve_reference_positions(x, y, lambda X, Y: X)
    with pytest.raises(TypeError, match="callable"):
        solve_reference_positions(x, y, 3.0)
    with pytest.raises(ValueError, match="same shape"):
        solve_reference_positions(x, y[:2], Translation(0, 0))


def test_deformed_image_must_stay_inside_the_extent():
    pattern = gaussian_speckle(extent_for_shape((20, 20)), 1.2)
    with pytest.raises(ValueError, match="outside the pattern extent"):
        pattern.render_deformed((20, 20), Translation(3.0, 0.0))
    with pytest.raises(ValueError, match="outside the pattern extent"):
        pattern.render_reference((30, 20))


@pytest.mark.parametrize("kwargs, match", [
    ({"mean_radius_px": 0.0}, "mean_radius_px must be > 0"),
    ({"mean_radius_px": -1.0}, "mean_radius_px must be > 0"),
    ({"mean_radius_px": 0.6}, "alias"),
    ({"mean_radius_px": 1.0, "radius_spread": 0.5}, "alias"),
    ({"radius_spread": 1.0}, "radius_spread"),
    ({"density": 0.0}, "density"),
    ({"density": 1.0}, "density"),
    ({"std_grey": 0.0}, "std_grey"),
    ({"extent_xy_px": (0.0, -1.0, 0.0, 5.0)}, "x_min < x_max"),
    ({"extent_xy_px": (0.0, 5.0, 0.0)}, "extent_xy_px must be 4 numbers"),
    ({"extent_xy_px": (0.0, 5.0, 0.0, 5.0), "periodic": True}, "periodic"),
])
def test_gaussian_speckle_rejects_bad_arguments(kwargs, match):
    arguments = {"extent_xy_px": (0.0, 50.0, 0.0, 40.0), "mean_radius_px": 1.2} | kwargs
    with pytest.raises(ValueError, match=match):
        gaussian_speckle(**arguments)


def test_bad_points_shapes_and_field_parameters_raise():
    pattern = gaussian_speckle(extent_for_shape((10, 10)), 1.2)
    with pytest.raises(ValueError, match=r"\(\.\.\., 2\)"):
        pattern.evaluate(np.zeros((5, 3)))
    with pytest.raises(ValueError, match="finite"):
        pattern.evaluate(np.array([[0.0, np.nan]]))
    with pytest.raises(ValueError, match="shape"):
        pattern.render_reference((0, 10))
    with pytest.raises(ValueError, match="sigmas_px"):
        GaussianSpeckle([(1.0, 1.0)], [0.0], 1.0, 1.0, (0.0, 5.0, 0.0, 5.0))
    with pytest.raises(ValueError, match="centres_xy_px"):
        GaussianSpeckle([(1.0, 1.0, 1.0)], [1.0], 1.0, 1.0, (0.0, 5.0, 0.0, 5.0))
    with pytest.raises(ValueError, match="ux_px must be finite"):
        Translation(np.nan, 0.0)
    with pytest.raises(ValueError, match="centre_xy_px"):
        Rotation(10.0, (1.0, 2.0, 3.0))
    with pytest.raises(ValueError, match="u_coeffs"):
        QuadraticField((1.0, 2.0), (0.0, 0.0, 0.0))
    with pytest.raises(ValueError, match="margin_px"):
        extent_for_shape((10, 10), -1.0)
    with pytest.raises(ValueError, match="below"):
        radius_for_speckle_size(1.2)
