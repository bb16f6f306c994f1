"""The lens' diffraction (scenes.optics.mtf): the closed-form OTF against the Airy pattern's own Fourier transform,
and the image filter against it."""
from __future__ import annotations

import numpy as np
import pytest
from scipy import integrate, special

from scenes.optics.mtf import Optics, airy_radius_px, apply_optics, diffraction_otf

F_NUMBER, WAVELENGTH_NM, PITCH_MM = 8.0, 550.0, 0.00345


def _airy_otf_by_hankel(nu_cyc_per_px: float) -> float:
    """The Airy pattern's 2-D Fourier transform at radial frequency nu (a Hankel transform of
    (2 J1(x) / x)^2, x = pi r / (lambda N), r in px), normalised to 1 at 0: independent of the closed form."""
    scale = np.pi * PITCH_MM / (WAVELENGTH_NM * 1e-6 * F_NUMBER)          # x per px

    def psf(r):
        x = scale * r
        return 1.0 if x == 0 else (2.0 * special.j1(x) / x) ** 2

    def transform(nu):
        return integrate.quad(lambda r: psf(r) * special.j0(2 * np.pi * nu * r) * r, 0, 400, limit=4000)[0]

    return transform(nu_cyc_per_px) / transform(0.0)


@pytest.mark.parametrize("nu", [0.05, 0.2, 0.35, 0.5, 0.7])
def test_the_otf_is_the_airy_patterns_fourier_transform_within_2e_3(nu):
    expected = _airy_otf_by_hankel(nu)
    assert diffraction_otf(nu, F_NUMBER, WAVELENGTH_NM, PITCH_MM) == pytest.approx(expected, abs=2e-3)


def test_airy_radius_is_1_22_lambda_n_in_pixels():
    assert airy_radius_px(F_NUMBER, WAVELENGTH_NM, PITCH_MM) == pytest.approx(1.22 * 0.55e-3 * 8 / PITCH_MM, rel=1e-12)


def test_a_cosine_image_keeps_its_shape_and_loses_the_airy_transforms_share_of_its_amplitude():
    """A cosine across the image (a whole number of half periods, so its mirrored copy is smooth) comes out
    multiplied by the Airy pattern's transform at its frequency (2e-3 of the amplitude), its mean kept."""
    rows, cols, k = 48, 64, 26
    nu = k / (2 * cols)
    x = np.arange(cols)
    image = 100.0 + 50.0 * np.cos(np.pi * k * (x + 0.5) / cols)[None, :].repeat(rows, axis=0)
    out = apply_optics(image, F_NUMBER, WAVELENGTH_NM, PITCH_MM)
    expected = 100.0 + 50.0 * _airy_otf_by_hankel(nu) * (image - 100.0) / 50.0
    assert np.abs(out - expected).max() < 2e-3 * 50.0


def test_supersampled_render_is_binned_to_the_sensors_pixels():
    """A 4x supersampled flat image comes back flat at the sensor's size; ideal optics only bin."""
    fine = np.full((32, 40), 77.0)
    out = apply_optics(fine, F_NUMBER, WAVELENGTH_NM, PITCH_MM, supersample=4)
    assert out.shape == (8, 10) and np.allclose(out, 77.0, atol=1e-9)
    ramp = np.arange(32 * 40, dtype=float).reshape(32, 40)
    assert np.allclose(Optics().apply(ramp, supersample=4), ramp.reshape(8, 4, 10, 4).mean(axis=(1, 3)))
    assert np.array_equal(Optics().apply(ramp), ramp)


def test_bad_optics_input_is_refused_by_name():
    with pytest.raises(ValueError, match="f_number must be a positive number, got 0"):
        Optics(f_number=0)
    with pytest.raises(ValueError, match="not a whole number of 4 x 4 blocks"):
        apply_optics(np.zeros((10, 12)), 8.0, supersample=4)
    with pytest.raises(ValueError, match="must be a finite 2-D array"):
        apply_optics(np.full((4, 4), np.nan), 8.0)


def _box_mean(f, centres, width):
    """Mean of f over [c - width/2, c + width/2] for each centre, by adaptive quadrature."""
    return np.array([integrate.quad(f, c - width / 2, c + width / 2)[0] / width for c in centres])


@pytest.mark.parametrize("fill", [0.5, 0.8])
def test_a_smaller_pixel_aperture_records_the_scene_averaged_over_that_aperture(fill):
    """A render of a cosine scene (each pixel its whole-area mean) through pixels of aperture ``fill`` comes out as
    the scene's mean over the smaller aperture, integrated independently (1e-3 of the amplitude, 4 px from the
    edges), with no diffraction."""
    n, k = 64, 19
    scene = lambda x: np.cos(np.pi * k * (x + 0.5) / n)                     # noqa: E731
    x = np.arange(n, dtype=float)
    rendered = np.repeat(_box_mean(scene, x, 1.0)[None, :], 8, axis=0)
    recorded = apply_optics(rendered, None, fill_factor=fill)
    expected = _box_mean(scene, x, fill)
    assert np.abs(recorded[:, 4:-4] - expected[None, 4:-4]).max() < 1e-3


def test_a_sensor_mtf_table_scales_each_frequency_by_its_interpolated_value():
    """A measured MTF of (0.25, 0.8), (0.5, 0.5): a cosine at 0.15 cycles/px keeps 1 - 0.2 * 0.6 = 0.88 of its
    amplitude (linear between 1 at 0 and 0.8 at 0.25)."""
    n, k = 80, 24
    x = np.arange(n)
    image = np.repeat((10.0 * np.cos(np.pi * k * (x + 0.5) / n))[None, :], 6, axis=0)
    out = apply_optics(image, None, sensor_mtf=((0.25, 0.8), (0.5, 0.5)))
    assert np.abs(out - 0.88 * image).max() < 1e-9 * 10
    with pytest.raises(ValueError, match="sensor_mtf must be"):
        apply_optics(image, None, sensor_mtf=((0.5, 0.5), (0.25, 0.8)))
