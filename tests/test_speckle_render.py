"""Rendered speckle: sub-pixel translations are rendered exactly; Monte-Carlo noise is below sensor noise."""
import numpy as np
import pytest

from scenes.optics.camera import SensorSpec
from scenes.sensor.noise import SensorNoise
from scenes.rendering.mitsuba import render_view
from scenes.specimens.plate import SpeckledPlate
from workbench.agreement import fourier_shift_fit

W = H = 192
FX = 2000.0
Z_MM = 400.0
PX_MM = Z_MM / FX
SPEC = SensorSpec(fx=FX, fy=FX, cx=(W - 1) / 2, cy=(H - 1) / 2, width=W, height=H)


@pytest.fixture(scope="module")
def plate_and_texture():
    plate = SpeckledPlate(width_mm=1.6 * W * PX_MM, height_mm=1.6 * H * PX_MM, texel_mm=PX_MM / 4,
                          speckle_mm=5 * PX_MM, seed=11)
    return plate, plate.texture()


def _render(plate_and_texture, dx_px, dy_px, seed, spp=64):
    plate, tex = plate_and_texture
    surf = plate.surface(np.eye(3), [dx_px * PX_MM, dy_px * PX_MM, Z_MM], tex)
    return render_view(SPEC, np.eye(3), np.zeros(3), [surf], spp=spp, seed=seed).image_grey.astype(float)


@pytest.mark.parametrize("shift_px", [(0.3, -0.17), (0.5, 0.25), (-0.73, 1.41)])
def test_known_translation_is_recovered(plate_and_texture, shift_px):
    """A fronto-parallel plate moved by (dx, dy) * Z / f mm shifts the image by exactly (dx, dy) px."""
    a = _render(plate_and_texture, 0.0, 0.0, seed=1)
    b = _render(plate_and_texture, *shift_px, seed=2)
    est = fourier_shift_fit(a, b, border_px=24)
    assert np.max(np.abs(est - np.array(shift_px))) <= 0.01


def test_zero_translation_measures_zero(plate_and_texture):
    a = _render(plate_and_texture, 0.0, 0.0, seed=1)
    b = _render(plate_and_texture, 0.0, 0.0, seed=9)
    assert np.max(np.abs(fourier_shift_fit(a, b, border_px=24))) <= 0.005


def test_sampler_seed_noise_below_sensor_noise(plate_and_texture):
    """Two renders of one state with different sampler seeds differ by less than 1 grey level of read noise."""
    noise = SensorNoise(read_noise_grey=1.0, bit_depth=8)
    a = _render(plate_and_texture, 0.0, 0.0, seed=1)
    b = _render(plate_and_texture, 0.0, 0.0, seed=2)
    mc_sigma = np.std(a - b) / np.sqrt(2)
    assert 0 < mc_sigma < noise.read_noise_grey
    same = _render(plate_and_texture, 0.0, 0.0, seed=1)
    assert np.array_equal(a, same)      # same seed, same image: deterministic


def test_speckle_contrast_and_resolution(plate_and_texture):
    a = _render(plate_and_texture, 0.0, 0.0, seed=1)
    assert a.std() > 30      # well-contrasted pattern in 8-bit grey levels
    assert a.min() >= 0 and a.max() <= 255
