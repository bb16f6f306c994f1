"""The DIC engine on Mitsuba renders of a speckled plate with a known motion (the second source of truth).

A fronto-parallel plate seen by a pinhole camera: moving it in its plane by (dx, dy) Z / f mm shifts the image
by (dx, dy) px; turning it by an angle about the optical axis turns the image by the same angle about the
principal point; scaling the plate (and its texture) by s stretches the image by s about the principal point.
"""
import numpy as np
import pytest

from measurement.dic import DICSettings, correlate
from scenes.optics.camera import SensorSpec
from scenes.sensor.noise import SensorNoise
from scenes.rendering.mitsuba import render_view
from scenes.specimens.plate import SpeckledPlate

W = H = 192
FX = 2000.0
Z_MM = 400.0
PX_MM = Z_MM / FX
CX, CY = (W - 1) / 2, (H - 1) / 2
SPEC = SensorSpec(fx=FX, fy=FX, cx=CX, cy=CY, width=W, height=H)
NOISE = SensorNoise(read_noise_grey=1.0, bit_depth=8)


@pytest.fixture(scope="module")
def plate_and_texture():
    plate = SpeckledPlate(width_mm=1.6 * W * PX_MM, height_mm=1.6 * H * PX_MM, texel_mm=PX_MM / 4,
                          speckle_mm=4 * PX_MM, seed=11)
    return plate, plate.texture()


def _render(plate, texture, R=np.eye(3), shift_px=(0.0, 0.0), seed=1):
    surface = plate.surface(R, [shift_px[0] * PX_MM, shift_px[1] * PX_MM, Z_MM], texture)
    image = render_view(SPEC, np.eye(3), np.zeros(3), [surface], spp=64, seed=seed).image_grey
    return NOISE.apply(image, seed=seed + 100)


def _rot_z(angle_deg):
    a = np.deg2rad(angle_deg)
    return np.array([[np.cos(a), -np.sin(a), 0.0], [np.sin(a), np.cos(a), 0.0], [0.0, 0.0, 1.0]])


SETTINGS = DICSettings(subset_size=31, step=8)
ROI = (24, 24, W - 24, H - 24)


def test_rendered_translation(plate_and_texture):
    plate, texture = plate_and_texture
    reference = _render(plate, texture, seed=1)
    deformed = _render(plate, texture, shift_px=(0.3, -0.17), seed=2)
    result = correlate(reference, deformed, SETTINGS, roi=ROI)
    assert result.converged.all(), result.status_counts()
    assert abs(np.mean(result.u) - 0.3) < 0.005 and abs(np.mean(result.v) + 0.17) < 0.005
    assert np.std(result.u) < 0.02


@pytest.mark.parametrize("angle_deg", [10.0, 30.0])
def test_rendered_rotation(plate_and_texture, angle_deg):
    plate, texture = plate_and_texture
    reference = _render(plate, texture, seed=1)
    deformed = _render(plate, texture, R=_rot_z(angle_deg), seed=3)
    result = correlate(reference, deformed, SETTINGS, roi=ROI)
    dx, dy = result.x - CX, result.y - CY
    c, s = np.cos(np.deg2rad(angle_deg)), np.sin(np.deg2rad(angle_deg))
    u_true, v_true = c * dx - s * dy - dx, s * dx + c * dy - dy
    radius = np.hypot(dx, dy)
    inside = radius + 16 * np.sqrt(2) < CX - 4      # the turned subset stays in the image
    assert result.converged[inside].all(), result.status_counts()
    ok = result.converged
    error = np.hypot(result.u[ok] - u_true[ok], result.v[ok] - v_true[ok])
    assert np.sqrt(np.mean(error ** 2)) < 0.02


def test_rendered_stretch(plate_and_texture):
    plate, texture = plate_and_texture
    stretch = 1.005
    bigger = SpeckledPlate(width_mm=plate.width_mm * stretch, height_mm=plate.height_mm * stretch,
                           texel_mm=plate.texel_mm * stretch, speckle_mm=plate.speckle_mm * stretch, seed=plate.seed)
    reference = _render(plate, texture, seed=1)
    deformed = _render(bigger, texture, seed=4)
    result = correlate(reference, deformed, SETTINGS, roi=ROI)
    assert result.converged.all(), result.status_counts()
    u_true = (stretch - 1) * (result.x - CX)
    v_true = (stretch - 1) * (result.y - CY)
    assert np.sqrt(np.mean((result.u - u_true) ** 2 + (result.v - v_true) ** 2)) < 0.02
    assert np.median(result.parameters[:, 1]) == pytest.approx(stretch - 1, abs=5e-4)
    assert np.median(result.parameters[:, 8]) == pytest.approx(stretch - 1, abs=5e-4)
