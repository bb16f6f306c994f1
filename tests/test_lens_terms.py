"""The "true lens" terms the instrument does not model: OpenCV's k3 (r^6) and thin prism s1..s4.

References are independent of the code under test: ``cv2.projectPoints`` for the distortion formula, the
renderer's own truth channels for render <-> model agreement, a hand-computed k3 / prism term for the
mismatch with ``measurement.camera``, and a verbatim copy of the former Brown-only formula for "defaults
unchanged". Tolerances are in the test names or docstrings.
"""
from __future__ import annotations

import cv2
import numpy as np
import pytest

import scenes.optics.projection as truth
from scenes.optics.backend import mi
from scenes.optics.camera import EXTRA_LENS_TERMS, UNDISTORT_ITERATIONS, SensorSpec, sensor_dict
from scenes.rendering.mitsuba import render_view
from scenes.surfaces.checkerboard import Checkerboard

#: A wide-angle camera (image corners at r ~ 0.5 in normalised units) with every lens term on, at
#: magnitudes the SensorSpec docstring calls realistic (k3 ~ 1, |s_i| ~ 1e-3).
WIDE = dict(fx=2000.0, fy=2012.0, cx=801.3, cy=598.7, width=1600, height=1200,
            k1=-0.3, k2=0.2, p1=1e-3, p2=-5e-4, k3=-1.0, s1=1e-3, s2=-1e-3, s3=-8e-4, s4=6e-4)
BROWN = ("k1", "k2", "p1", "p2")


def _rotation(rvec) -> np.ndarray:
    return cv2.Rodrigues(np.asarray(rvec, dtype=float))[0]


def _points_in_view(spec: SensorSpec, n: int, rng, z_range=(300.0, 600.0), r_max: float = 0.5) -> np.ndarray:
    """(n, 3) camera-frame points (mm) whose ideal normalised radius is below ``r_max``."""
    z = rng.uniform(*z_range, n)
    rho = r_max * np.sqrt(rng.uniform(0, 1, n))
    phi = rng.uniform(0, 2 * np.pi, n)
    return np.stack([rho * np.cos(phi) * z, rho * np.sin(phi) * z, z], axis=1)


# ------------------------------------------------------------------------------------------------------------
# The formula: OpenCV is the independent reference
@pytest.mark.parametrize("terms", [dict(k3=0.8), dict(s1=1e-3), dict(s2=-2e-3), dict(s3=-7e-4), dict(s4=1.5e-3),
                                   dict(k3=-0.6, s1=8e-4, s2=-1e-3, s3=-5e-4, s4=9e-4)],
                         ids=["k3", "s1", "s2", "s3", "s4", "all"])
def test_project_points_equals_opencv_to_1e9_px(terms, rng):
    """Zero tilt: ``project_points`` = ``cv2.projectPoints`` with distCoeffs (k1, k2, p1, p2, k3, 0, 0, 0,
    s1, s2, s3, s4) to 1e-9 px, for random points up to r = 0.5 and a random pose.

    Each term alone too, so that a swapped pair (s1 <-> s3, s2 <-> s4) cannot hide in the sum.
    """
    spec = SensorSpec(**{**WIDE, "k3": 0.0, "s1": 0.0, "s2": 0.0, "s3": 0.0, "s4": 0.0, **terms})
    rvec, tvec = np.array([0.1, -0.2, 0.05]), np.array([12.0, -7.0, 40.0])
    R = _rotation(rvec)
    X_cam = _points_in_view(spec, 500, rng)
    X_world = (X_cam - tvec) @ R                     # rows: R^T (X_cam - t), so R X_world + t = X_cam
    K = np.array([[spec.fx, 0.0, spec.cx], [0.0, spec.fy, spec.cy], [0.0, 0.0, 1.0]])
    dist = np.array([spec.k1, spec.k2, spec.p1, spec.p2, spec.k3, 0, 0, 0, spec.s1, spec.s2, spec.s3, spec.s4])
    expected = cv2.projectPoints(X_world, rvec, tvec, K, dist)[0].reshape(-1, 2)
    got = truth.project_points(spec, R, tvec, X_world)
    assert np.max(np.abs(got - expected)) < 1e-9


def test_project_points_with_one_tilt_equals_opencv_tilted_model_to_1e9_px(rng):
    """With one tilt angle the paper's model is OpenCV's tilted model (tau_x = alpha; shared/notes/mitsuba.md):
    k3 and the thin prism are applied before the tilt in both, to 1e-9 px."""
    spec = SensorSpec(**{**WIDE, "alpha_deg": 4.0})
    R, t = np.eye(3), np.zeros(3)
    X = _points_in_view(spec, 300, rng)
    K = np.array([[spec.fx, 0.0, spec.cx], [0.0, spec.fy, spec.cy], [0.0, 0.0, 1.0]])
    dist = np.array([spec.k1, spec.k2, spec.p1, spec.p2, spec.k3, 0, 0, 0, spec.s1, spec.s2, spec.s3, spec.s4,
                     np.deg2rad(spec.alpha_deg), 0.0])
    expected = cv2.projectPoints(X, np.zeros(3), t, K, dist)[0].reshape(-1, 2)
    assert np.max(np.abs(truth.project_points(spec, R, t, X) - expected)) < 1e-9


# ------------------------------------------------------------------------------------------------------------
# The inverse
@pytest.mark.parametrize("lens", [WIDE, {**WIDE, "k1": 0.3, "k2": 0.0, "k3": 1.0}], ids=["barrel", "pincushion"])
def test_undistort_inverts_distort_to_1e12_over_the_image(lens):
    """undistort(distort(x)) = x and distort(undistort(x_d)) = x_d to 1e-12 (normalised; 2e-9 px at fx = 2000)
    on a grid over the whole 1600 x 1200 image (corners at r ~ 0.5)."""
    spec = SensorSpec(**lens)
    jj, ii = np.meshgrid(np.linspace(0, spec.width - 1, 41), np.linspace(0, spec.height - 1, 31))
    xy_d = np.stack([(jj.ravel() - spec.cx) / spec.fx, (ii.ravel() - spec.cy) / spec.fy], axis=1)
    xy_n = truth.undistort(xy_d, spec)
    assert np.all(np.isfinite(xy_n))
    assert np.max(np.abs(truth.distort(xy_n, spec) - xy_d)) < 1e-12
    assert np.max(np.abs(truth.undistort(truth.distort(xy_d, spec), spec) - xy_d)) < 1e-12


def _plugin_chief_rays(spec: SensorSpec, pixels_xy: np.ndarray) -> np.ndarray:
    """Camera-frame ray directions (N, 3) the Mitsuba plugin generates at pixel positions (OpenCV px)."""
    sensor = mi.load_dict(sensor_dict(spec, np.eye(3), np.zeros(3), spp=1))
    u = ((pixels_xy[:, 0] + 0.5) / spec.width).astype(np.float32)    # Mitsuba: pixel centres at +0.5
    v = ((pixels_xy[:, 1] + 0.5) / spec.height).astype(np.float32)
    ray, _ = sensor.sample_ray(0.0, 0.0, mi.Point2f(u, v), mi.Point2f(0.5, 0.5))
    return np.array(ray.d, dtype=float).T


def test_plugin_undistortion_converges_to_float32_resolution():
    """The plugin's per-ray fixed-point undistortion with k3 and prism on a wide-angle lens (8 % barrel, tilted,
    corners at r = 0.58) matches the float64 truth to 2e-7 in normalised units (4e-4 px at fx = 2000 px): the
    float32 floor is 1.0e-7 here, while 8 iterations would leave 2.4e-5 and 12 leave 6.2e-7."""
    spec = SensorSpec(**{**WIDE, "alpha_deg": 2.0, "beta_deg": -3.0})
    jj, ii = np.meshgrid(np.linspace(0, spec.width - 1, 33), np.linspace(0, spec.height - 1, 25))
    px = np.stack([jj.ravel(), ii.ravel()], axis=1)
    d_plugin = _plugin_chief_rays(spec, px)
    _, d_truth = truth.pixel_rays(spec, np.eye(3), np.zeros(3), px)
    xy_plugin = d_plugin[:, :2] / d_plugin[:, 2:3]
    xy_truth = d_truth[:, :2] / d_truth[:, 2:3]
    assert np.max(np.hypot(*xy_truth.T)) > 0.5
    assert np.max(np.abs(xy_plugin - xy_truth)) < 2e-7


# ------------------------------------------------------------------------------------------------------------
# Render <-> model agreement (as tests/test_render_geometry.py::test_truth_channels_match_model_rays)
def test_rendered_truth_positions_project_back_onto_their_pixels():
    """160 x 120 px, fx = 200 px (corners at r = 0.5), k3 = 2 (3.1 px at the corners) and thin prism
    (~1.5 px), tilted sensor: the footprint-averaged world position of each pixel, projected with
    ``scenes.optics.projection.project_points``, lands on that pixel's centre: mean |residual| < 0.01 px.

    With 8 x 8 stratified samples the sample centroid wanders from the pixel centre by
    sigma = 1 / (spp sqrt(12)) = 0.0045 px per axis: max < 8 sigma, rms < 1.5 sigma, mean offset < 0.2
    sigma. The same positions projected without k3 and the prism miss by > 2 px (the check can see them).
    """
    spec = SensorSpec(fx=200.0, fy=202.0, cx=79.3, cy=59.6, width=160, height=120, alpha_deg=2.0, beta_deg=-3.0,
                      k1=-0.05, p1=1e-3, p2=-2e-3, k3=2.0, s1=0.02, s2=0.03, s3=-0.02, s4=0.03)
    board = Checkerboard()
    theta = np.deg2rad(15)
    R = np.array([[np.cos(theta), 0, np.sin(theta)], [0, 1, 0], [-np.sin(theta), 0, np.cos(theta)]])
    t = np.array([-25.0, -17.5, 60.0])
    spp = 64
    r = render_view(spec, np.eye(3), np.zeros(3), [board.surface(R, t)], spp=spp, seed=11, truth=True)
    jj, ii = np.meshgrid(np.arange(spec.width), np.arange(spec.height))
    inside = r.coverage == 1.0
    assert inside.mean() > 0.9
    X = r.position_world_mm[inside].astype(float)
    centres = np.stack([jj[inside], ii[inside]], axis=1).astype(float)
    residual = truth.project_points(spec, np.eye(3), np.zeros(3), X) - centres
    sigma = 1.0 / (spp * np.sqrt(12.0))
    assert np.mean(np.hypot(*residual.T)) < 0.01
    assert np.max(np.abs(residual)) < 8 * sigma
    assert np.sqrt(np.mean(residual ** 2)) < 1.5 * sigma
    assert np.all(np.abs(residual.mean(axis=0)) < 0.2 * sigma)
    without = spec.with_(**{name: 0.0 for name in EXTRA_LENS_TERMS})
    miss = truth.project_points(without, np.eye(3), np.zeros(3), X) - centres
    assert np.max(np.hypot(*miss.T)) > 2.0


# ------------------------------------------------------------------------------------------------------------
# The mismatch with the instrument is real and of the expected size
def _paper_left(**extra) -> SensorSpec:
    """Table 1's left camera without tilt (so the hand formula is exact), full resolution."""
    return SensorSpec(fx=10912.3651, fy=10896.6062, cx=868.9786, cy=989.9657, width=2456, height=2058,
                      k1=-0.3621, k2=0.8389, p1=-0.0013, p2=-0.0108, **extra)


def test_instrument_without_k3_misses_by_the_hand_computed_k3_term():
    """At the image corners the truth (k3 = 50: up to 3 px at the corner farthest from Table 1's off-centre
    principal point, as on 25-35 mm C-mount lenses) and ``measurement.camera`` (same K and Brown terms, no
    k3) differ by exactly ``(fx x, fy y) k3 r^6``, to 1e-9 px."""
    from measurement.camera import ScheimpflugCamera

    spec = _paper_left(k3=50.0)
    cam = ScheimpflugCamera(**{n: getattr(spec, n) for n in ("fx", "fy", "cx", "cy", *BROWN)},
                            width=spec.width, height=spec.height)
    w, h = spec.width - 1, spec.height - 1
    corners_px = np.array([[0.0, 0.0], [w, 0.0], [w, h], [0.0, h]], dtype=float)
    xy = cam.backproject(corners_px)                       # ideal coordinates the instrument sees at the corners
    X = np.concatenate([xy, np.ones((4, 1))], axis=1) * 376.0
    difference = truth.project_points(spec, np.eye(3), np.zeros(3), X) - cam.project(X)
    r6 = np.sum(xy ** 2, axis=1) ** 3
    by_hand = np.stack([spec.fx * xy[:, 0], spec.fy * xy[:, 1]], axis=1) * spec.k3 * r6[:, None]
    assert np.max(np.abs(difference - by_hand)) < 1e-9
    assert 1.5 < np.max(np.hypot(*by_hand.T)) < 3.5     # the error source is px-sized, not numerical noise


def test_instrument_without_thin_prism_misses_by_the_hand_computed_prism_term():
    """Thin prism |s_i| ~ 1e-3: truth minus ``measurement.camera`` = (fx (s1 r^2 + s2 r^4), fy (s3 r^2 + s4 r^4))
    to 1e-9 px, at the corners and centre of the paper's image."""
    from measurement.camera import ScheimpflugCamera

    spec = _paper_left(s1=1e-3, s2=-5e-4, s3=-8e-4, s4=4e-4)
    cam = ScheimpflugCamera(**{n: getattr(spec, n) for n in ("fx", "fy", "cx", "cy", *BROWN)})
    px = np.array([[0.0, 0.0], [2455.0, 2057.0], [868.9786, 989.9657]])
    xy = cam.backproject(px)
    X = np.concatenate([xy, np.ones((3, 1))], axis=1) * 376.0
    difference = truth.project_points(spec, np.eye(3), np.zeros(3), X) - cam.project(X)
    r2 = np.sum(xy ** 2, axis=1)
    by_hand = np.stack([spec.fx * (spec.s1 * r2 + spec.s2 * r2 ** 2), spec.fy * (spec.s3 * r2 + spec.s4 * r2 ** 2)], 1)
    assert np.max(np.abs(difference - by_hand)) < 1e-9
    assert np.max(np.hypot(*by_hand.T)) > 0.1


# ------------------------------------------------------------------------------------------------------------
# Defaults unchanged
def _brown_distort_before(xy_n, spec):
    """``scenes.optics.projection.distort`` as it was before k3 and the thin prism (verbatim), the reference for 'unchanged'."""
    x, y = xy_n[:, 0], xy_n[:, 1]
    r2 = x * x + y * y
    radial = 1.0 + r2 * (spec.k1 + spec.k2 * r2)
    dx = 2.0 * spec.p1 * x * y + spec.p2 * (r2 + 2.0 * x * x)
    dy = spec.p1 * (r2 + 2.0 * y * y) + 2.0 * spec.p2 * x * y
    return np.stack([x * radial + dx, y * radial + dy], axis=1)


def _brown_undistort_before(xy_d, spec):
    """``scenes.optics.projection.undistort`` as it was before (verbatim, constants inlined)."""
    xd, yd = xy_d[:, 0], xy_d[:, 1]
    xn, yn = xd.copy(), yd.copy()
    for _ in range(100):
        r2 = xn * xn + yn * yn
        radial = 1.0 + r2 * (spec.k1 + spec.k2 * r2)
        dx = 2.0 * spec.p1 * xn * yn + spec.p2 * (r2 + 2.0 * xn * xn)
        dy = spec.p1 * (r2 + 2.0 * yn * yn) + 2.0 * spec.p2 * xn * yn
        xn_new, yn_new = (xd - dx) / radial, (yd - dy) / radial
        step = np.maximum(np.abs(xn_new - xn), np.abs(yn_new - yn))
        xn, yn = xn_new, yn_new
        if not np.any(step > 1e-15):
            break
    out = np.stack([xn, yn], axis=1)
    out[np.any(~np.isfinite(out), axis=1) | (step > 1e-9)] = np.nan
    return out


def test_default_projections_are_bit_identical_to_the_brown_only_model(rng, monkeypatch):
    """A spec without the new fields projects and back-projects exactly (==, not approximately) as before."""
    spec = SensorSpec(fx=2728.1, fy=2724.2, cx=217.2, cy=247.5, width=614, height=514, alpha_deg=0.6156,
                      beta_deg=-4.5583, k1=-0.3621, k2=0.8389, p1=-0.0013, p2=-0.0108)
    R, t = _rotation([0.02, 0.3, -0.01]), np.array([-140.0, 1.4, 28.0])
    X = rng.uniform([-40, -40, 300], [40, 40, 450], (400, 3))
    X = np.concatenate([X, [[0, 0, -10.0], [1e3, 1e3, 1e-3]]])           # behind the camera, far outside
    px = rng.uniform([-50, -50], [664, 564], (400, 2))
    new_uv = truth.project_points(spec, R, t, X)
    new_rays = truth.pixel_rays(spec, R, t, px)[1]
    xy_n = rng.uniform(-0.3, 0.3, (400, 2))
    assert np.array_equal(truth.distort(xy_n, spec), _brown_distort_before(xy_n, spec))
    assert np.array_equal(truth.undistort(xy_n, spec), _brown_undistort_before(xy_n, spec), equal_nan=True)
    monkeypatch.setattr(truth, "distort", _brown_distort_before)
    monkeypatch.setattr(truth, "undistort", _brown_undistort_before)
    assert np.array_equal(new_uv, truth.project_points(spec, R, t, X), equal_nan=True)
    assert np.array_equal(new_rays, truth.pixel_rays(spec, R, t, px)[1], equal_nan=True)


def test_default_sensor_dict_only_gains_zero_lens_terms():
    """``sensor_dict`` of a spec without the new fields: the former entries exactly, plus k3, s1..s4 = 0.0;
    the plugin then keeps the former 8 undistortion iterations (its renders are bit-identical)."""
    spec = SensorSpec(fx=2728.1, fy=2724.2, cx=217.2, cy=247.5, width=614, height=514, alpha_deg=0.6, k1=-0.36,
                      k2=0.84, p1=-0.0013, p2=-0.0108, lens="thin", focal_length_mm=8.0, f_number=8.0)
    R, t = _rotation([0.02, 0.3, -0.01]), np.array([-140.0, 1.4, 28.0])
    d = sensor_dict(spec, R, t, spp=16, seed=3)
    before = {"fx": 2728.1, "fy": 2724.2, "cx": 217.2, "cy": 247.5, "alpha_deg": 0.6, "beta_deg": 0.0, "k1": -0.36,
              "k2": 0.84, "p1": -0.0013, "p2": -0.0108, "lens": "thin", "focal_length_mm": 8.0, "f_number": 8.0,
              "pixel_pitch_mm": 0.00345}
    assert set(d) == {"type", "to_world", "film", "sampler", *before, *EXTRA_LENS_TERMS}
    assert {k: d[k] for k in before} == before
    assert all(type(d[k]) is float and d[k] == 0.0 for k in EXTRA_LENS_TERMS)
    assert d["sampler"] == {"type": "stratified", "sample_count": 16, "seed": 3}
    assert d["film"]["width"] == 614 and d["film"]["height"] == 514
    assert mi.load_dict(sensor_dict(spec, R, t, spp=1)).undistort_iterations == UNDISTORT_ITERATIONS == 8


def test_specs_from_the_instrument_and_from_to_dict_still_build():
    """``SensorSpec(**camera.intrinsics(), ...)`` (no k3: checkerboard_views) gives zero extra terms, and
    ``SensorSpec(**spec.to_dict())`` round-trips a spec that has them."""
    from measurement.camera import ScheimpflugCamera
    from workbench.experiments.calibration.views import camera_to_sensor_spec

    cam = ScheimpflugCamera(fx=2728.1, fy=2724.2, cx=217.2, cy=247.5, alpha_deg=0.6, k1=-0.36, width=614, height=514)
    spec = camera_to_sensor_spec(cam)
    assert all(getattr(spec, name) == 0.0 for name in EXTRA_LENS_TERMS)
    full = SensorSpec(**WIDE)
    assert SensorSpec(**full.to_dict()) == full
    assert [full.to_dict()[n] for n in EXTRA_LENS_TERMS] == [WIDE[n] for n in EXTRA_LENS_TERMS]


# ------------------------------------------------------------------------------------------------------------
# Validation
@pytest.mark.parametrize("name", EXTRA_LENS_TERMS)
@pytest.mark.parametrize("value", [float("nan"), float("inf"), -float("inf")])
def test_non_finite_lens_terms_are_refused_naming_the_field(name, value):
    base = dict(fx=1000.0, fy=1000.0, cx=50.0, cy=40.0, width=100, height=80)
    with pytest.raises(ValueError, match=f"sensor parameter {name} must be finite"):
        SensorSpec(**base, **{name: value})
