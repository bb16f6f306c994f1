"""Rendered truth channels, thin-lens focus and the Scheimpflug focal plane, against independent geometry."""
import numpy as np
import pytest

from measurement.camera import ScheimpflugCamera
from scenes.optics.camera import SensorSpec
from scenes.rendering.mitsuba import render_view
from scenes.specimens.plate import SpeckledPlate
from scenes.surfaces.checkerboard import Checkerboard
from workbench.experiments.calibration.views import camera_to_sensor_spec
from workbench.experiments.depth_of_field.run import scheimpflug_sensor_tilt_deg

W, H, FX = 160, 120, 1500.0
PITCH_MM = 0.0138
Z_MM = 376.0


def _plate(seed=1, size_mm=60.0):
    px_mm = Z_MM / FX
    return SpeckledPlate(width_mm=size_mm, height_mm=size_mm, texel_mm=px_mm / 3, speckle_mm=4 * px_mm, seed=seed)


def test_truth_channels_match_model_rays():
    """The footprint-averaged world position of every pixel projects back onto that pixel's centre.

    With n x n stratified samples the sample centroid wanders from the pixel centre by
    sigma = 1 / (n^2 sqrt(12)) px per axis (0.0011 px at 256 spp): the bounds below are a few sigma.
    """
    cam = ScheimpflugCamera(fx=FX, fy=FX * 1.01, cx=75.3, cy=61.2, alpha_deg=3.0, beta_deg=-5.0, k1=-0.3,
                            k2=0.8, p1=-0.001, p2=-0.01, width=W, height=H)
    board = Checkerboard()
    theta = np.deg2rad(20)
    R = np.array([[np.cos(theta), 0, np.sin(theta)], [0, 1, 0], [-np.sin(theta), 0, np.cos(theta)]])
    t = np.array([-25.0, -17.5, Z_MM])
    spp = 256
    r = render_view(camera_to_sensor_spec(cam), np.eye(3), np.zeros(3), [board.surface(R, t)], spp=spp,
                    truth=True)
    jj, ii = np.meshgrid(np.arange(W), np.arange(H))
    inside = r.coverage == 1.0
    assert inside.mean() > 0.5
    centres = np.stack([jj[inside], ii[inside]], 1).astype(float)
    residual = cam.project(r.position_world_mm[inside].astype(float)) - centres
    sigma = 1.0 / (spp * np.sqrt(12.0))
    assert np.max(np.abs(residual)) < 8 * sigma
    assert np.sqrt(np.mean(residual ** 2)) < 1.5 * sigma
    assert np.all(np.abs(residual.mean(axis=0)) < 0.1 * sigma)   # no bias, e.g. from a +0.5 px slip
    # The points lie on the board plane, and uv is the same footprint average in board coordinates.
    X_board = (r.position_world_mm[inside].astype(float) - t) @ R
    assert np.max(np.abs(X_board[:, 2])) < 1e-3
    x0, x1, y0, y1 = board.extent_board_mm()
    uv_expected = np.stack([(X_board[:, 0] - x0) / (x1 - x0), (X_board[:, 1] - y0) / (y1 - y0)], 1)
    assert np.max(np.abs(r.uv[inside] - uv_expected)) < 1e-6


def test_thin_lens_in_focus_plane_matches_pinhole():
    """A plane at the focus distance renders through a wide-open thin lens as through a pinhole."""
    v = FX * PITCH_MM
    F = 1.0 / (1.0 / v + 1.0 / Z_MM)
    plate = _plate()
    tex = plate.texture()
    surf = plate.surface(np.eye(3), [0, 0, Z_MM], tex)
    base = dict(fx=FX, fy=FX, cx=(W - 1) / 2, cy=(H - 1) / 2, width=W, height=H, pixel_pitch_mm=PITCH_MM)
    pin = render_view(SensorSpec(**base), np.eye(3), np.zeros(3), [surf], spp=256, seed=1).image_grey
    thin = render_view(SensorSpec(**base, lens="thin", focal_length_mm=F, f_number=1.4), np.eye(3), np.zeros(3),
                       [surf], spp=256, seed=2).image_grey
    far = render_view(SensorSpec(**base, lens="thin", focal_length_mm=F, f_number=1.4), np.eye(3), np.zeros(3),
                      [plate.surface(np.eye(3), [0, 0, Z_MM + 15], tex)], spp=256, seed=3).image_grey
    pin_far = render_view(SensorSpec(**base), np.eye(3), np.zeros(3), [plate.surface(np.eye(3), [0, 0, Z_MM + 15], tex)],
                          spp=256, seed=4).image_grey
    in_focus_rms = np.sqrt(np.mean((thin - pin) ** 2))
    defocus_rms = np.sqrt(np.mean((far - pin_far) ** 2))
    assert in_focus_rms < 1.0            # grey levels: Monte-Carlo noise only
    assert defocus_rms > 10 * in_focus_rms


def test_scheimpflug_tilt_puts_oblique_plane_in_focus():
    """With the sensor tilted per the Scheimpflug condition, an oblique plane is sharp across the field:
    thin lens == pinhole everywhere. Untilted, the same plane blurs towards the image sides."""
    v = FX * PITCH_MM
    F = 1.0 / (1.0 / v + 1.0 / Z_MM)
    object_tilt = 40.0
    beta = scheimpflug_sensor_tilt_deg(object_tilt, v, F)
    th = np.deg2rad(object_tilt)
    R = np.array([[np.cos(th), 0, np.sin(th)], [0, 1, 0], [-np.sin(th), 0, np.cos(th)]])
    plate = _plate(size_mm=80.0)
    surf = plate.surface(R, [0, 0, Z_MM])
    errors = {}
    for name, tilt in (("scheimpflug", beta), ("untilted", 0.0)):
        base = dict(fx=FX, fy=FX, cx=(W - 1) / 2, cy=(H - 1) / 2, width=W, height=H, beta_deg=tilt,
                    pixel_pitch_mm=PITCH_MM)
        pin = render_view(SensorSpec(**base), np.eye(3), np.zeros(3), [surf], spp=256, seed=5).image_grey
        thin = render_view(SensorSpec(**base, lens="thin", focal_length_mm=F, f_number=1.4), np.eye(3),
                           np.zeros(3), [surf], spp=256, seed=6).image_grey
        diff = np.abs(thin - pin)
        errors[name] = (np.sqrt(np.mean(diff[:, :20] ** 2)), np.sqrt(np.mean(diff[:, -20:] ** 2)))
    assert max(errors["scheimpflug"]) < 1.5
    assert min(errors["untilted"]) > 5 * max(errors["scheimpflug"])


def test_scheimpflug_tilt_matches_hinge_rule():
    """tan(sensor tilt) ~ (v / u) tan(object tilt) for small tilts (Scheimpflug); sign opposite."""
    v, u = 37.65, 376.0
    F = 1 / (1 / v + 1 / u)
    beta = scheimpflug_sensor_tilt_deg(38.0, v, F)
    assert np.tan(np.deg2rad(abs(beta))) == pytest.approx(v / u * np.tan(np.deg2rad(38.0)), rel=0.02)
    assert beta < 0
