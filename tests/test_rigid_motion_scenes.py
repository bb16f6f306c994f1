"""Truth side of the rigid-motion test: bending specimen, stage states, per-pixel truth rays, rendered dataset.

Renders use the paper rig at scale 0.2 (491 x 412 px, ~0.17 mm per pixel at the specimen) and crops, so the
module runs in well under a minute on 2 cores.
"""
import json
import warnings

import cv2
import numpy as np
import pytest

from scenes.deformation.stage import STAGE_UP_WORLD, stage_displacements_mm, stage_poses, stage_states_mm
from scenes.rendering.mitsuba import render_view
from scenes.specimens.beam import BendingSpecimen
from scenes.specimens.plate import SpeckledPlate
from scenes.optics.projection import (defocus_blur_px, focal_length_for_focus_mm, in_focus_points_world_mm,
                                      intersect_front_face, material_point_positions, pixel_rays,
                                      points_of_interest_truth, project_points)
from workbench.agreement import fourier_shift_fit
from workbench.experiments.rigid_motion.scenes import (SpecimenOutOfViewError, load_truth, render_rigid_motion,
                                                       rigid_motion_truth)
from workbench.rigs import paper_rig

SCALE = 0.2


@pytest.fixture(scope="module")
def rig():
    return paper_rig(SCALE)


@pytest.fixture(scope="module")
def scene(rig):
    """Thin-lens setup with two states (0 and 10 mm), its texture, and the same setup with a pinhole."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")       # the f/8 defocus warning is tested separately
        thin = rigid_motion_truth(rig, lens="thin", states_mm=[0.0, 10.0])
    pin = rigid_motion_truth(rig, lens="pinhole", states_mm=[0.0, 10.0])
    return {"thin": thin, "pinhole": pin, "texture": thin.specimen.texture()}


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    out = tmp_path_factory.mktemp("rigid_motion")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        truth = render_rigid_motion("paper", out, scale=SCALE, lens="thin", spp=16, seed=3, noise_grey=1.0,
                                    states=[0.0, 1.0, 10.0], progress=False)
    return out, truth


# ------------------------------------------------------------------------------------------------------------
def test_stage_states_out_and_back():
    s = stage_states_mm()
    assert len(s) == 21
    np.testing.assert_array_equal(s, [0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 9, 8, 7, 6, 5, 4, 3, 2, 1, 0])
    np.testing.assert_allclose(stage_states_mm(1.0, 0.1)[10], 1.0, rtol=0, atol=1e-15)
    assert len(stage_states_mm(2.0, 0.5)) == 9
    for bad, message in [((10, 3), "whole number of steps"), ((0, 1), "positive and finite, got 0 and 1"),
                         ((-1, 1), "positive and finite, got -1 and 1"), ((10, 0), "positive and finite, got 10 and 0"),
                         ((np.nan, 1), "positive and finite, got nan and 1")]:
        with pytest.raises(ValueError, match=message):
            stage_states_mm(*bad)
    # "up" in the left image is -y of the left camera (= world) frame; poses are pure translations.
    np.testing.assert_array_equal(STAGE_UP_WORLD, [0, -1, 0])
    np.testing.assert_allclose(stage_displacements_mm([0, 2.5]), [[0, 0, 0], [0, -2.5, 0]])
    R0, t0 = np.eye(3), np.array([1.0, 2.0, 300.0])
    poses = stage_poses(R0, t0, [0.0, 4.0], direction_world=[0, 0, 2])
    np.testing.assert_allclose(poses[1][1], [1, 2, 304])
    np.testing.assert_array_equal(poses[1][0], R0)
    with pytest.raises(ValueError, match="stage direction must be a non-zero 3-vector"):
        stage_poses(R0, t0, [1.0], direction_world=[0, 0, 0])


def test_bending_specimen_solid_and_validation():
    sp = BendingSpecimen()
    solid = sp.solid()
    assert solid.is_watertight and solid.is_winding_consistent
    assert solid.volume == pytest.approx(120 * 30 * 10)                    # > 0: outward normals
    np.testing.assert_allclose(solid.bounds, [[-60, -15, 0], [60, 15, 10]])
    # ~3.5 texels per full-resolution pixel (0.0345 mm at 376 mm), 5 px speckles.
    assert sp.texture_shape == (3000, 12000)
    assert 0.0345 / sp.texel_mm == pytest.approx(3.45, rel=0.01)
    small = BendingSpecimen.for_pixel_size(0.17, speckle_px=5, texels_per_px=3.5)
    assert small.speckle_mm == pytest.approx(0.85) and small.texel_mm == pytest.approx(0.17 / 3.5)
    front, _ = small.surfaces(np.eye(3), np.zeros(3))
    n = np.cross(front.vertices_mm[front.faces[:, 1]] - front.vertices_mm[front.faces[:, 0]],
                 front.vertices_mm[front.faces[:, 2]] - front.vertices_mm[front.faces[:, 0]])
    assert np.all(n[:, 2] < 0)                          # the painted face emits towards -z (the cameras)
    assert np.all(front.vertices_mm[:, 2] == 0) and front.uv.min() == 0 and front.uv.max() == 1
    np.testing.assert_allclose(np.diff(np.unique(front.vertices_mm[:, 0])), 1.0)     # 1 mm grid (120 cells)
    np.testing.assert_allclose(np.diff(np.unique(front.vertices_mm[:, 1])), 1.0)
    for bad, message in [(dict(length_mm=-1), "length_mm must be positive and finite, got -1"),
                         (dict(height_mm=0), "height_mm must be positive and finite, got 0"),
                         (dict(thickness_mm=np.nan), "thickness_mm must be positive and finite, got nan"),
                         (dict(texel_mm=0.1, speckle_mm=0.1), "under 2 texels"),
                         (dict(side_grey=2.0), r"side_grey must be in \[0, 1\], got 2.0"),
                         (dict(grid_mm=0), "grid_mm must be positive and finite, got 0")]:
        with pytest.raises(ValueError, match=message):
            BendingSpecimen(**bad)
    with pytest.raises(ValueError, match="too large"):
        BendingSpecimen(texel_mm=0.001)
    with pytest.raises(ValueError, match="shape"):
        small.surfaces(np.eye(3), np.zeros(3), displacement_mm=lambda X: np.zeros((1, 3)))


def test_truth_rays_agree_with_measurement_camera(rig):
    """scenes.optics.projection and measurement.camera are independent implementations of the same camera."""
    from workbench.experiments.calibration.views import sensor_spec_for

    rng = np.random.default_rng(0)
    for side in ("left", "right"):
        cam, spec, (R, t) = rig.camera(side), sensor_spec_for(rig, side), rig.pose(side)
        px = rng.uniform([-0.5, -0.5], [cam.width - 0.5, cam.height - 0.5], (500, 2))
        o, d = pixel_rays(spec, R, t, px)
        np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, atol=1e-15)
        np.testing.assert_allclose(o, np.repeat(rig.camera_centre_mm(side)[None], 500, 0), atol=1e-12)
        X = o + d * rng.uniform(300, 450, (500, 1))
        assert np.max(np.abs(project_points(spec, R, t, X) - px)) < 1e-9
        assert np.max(np.abs(cam.project(X @ R.T + t) - px)) < 1e-9
        assert np.max(np.abs(cam.rays(px) - d @ R.T)) < 1e-12


@pytest.mark.parametrize("lens", ["pinhole", "thin"])
@pytest.mark.parametrize("side", ["left", "right"])
def test_truth_rays_match_rendered_positions(scene, lens, side):
    """THE truth test: footprint-averaged hit positions and texture coordinates of the render agree with the
    chief ray of each pixel centre intersected with the front face (state 10 mm, strip across the face).

    Pinhole: n x n stratified samples move the footprint centroid by sigma = 1 / (n^2 sqrt 12) px per axis
    (0.0011 px at 256 spp); the bounds are a few sigma and the mean is unbiased. Thin lens: the aperture
    samples add noise (the face is up to ~3.6 px out of focus at its ends at this scale) and a second-order
    offset of the blur cone's hit centroid from the chief ray (~1e-4 px), hence the looser bounds.
    """
    truth, spp = scene[lens], 256
    sp, pose = truth.specimen, truth.poses[1]
    spec, (R, t) = truth.specs[side], truth.camera_poses[side]
    # A 24-row strip through the face centre, the full image width (defocus, tilt and distortion all vary).
    centre = truth.project(side, pose[1][None])[0]
    crop = (0, int(centre[1]) - 12, spec.width, 24)
    r = render_view(spec, R, t, sp.surfaces(*pose, texture=scene["texture"]), spp=spp, seed=5, truth=True, crop=crop)
    jj, ii = np.meshgrid(np.arange(crop[2]) + crop[0], np.arange(crop[3]) + crop[1])
    px = np.stack([jj.ravel(), ii.ravel()], 1).astype(float)
    X_world, X_spec = intersect_front_face(*pixel_rays(spec, R, t, px), sp, *pose)
    hit = np.isfinite(X_world[:, 0])
    assert hit.mean() > 0.98                      # the 120 mm beam spans the whole image width
    inside = hit & (r.coverage.ravel() == 1.0)
    pos = r.position_world_mm.reshape(-1, 3)[inside].astype(float)
    sigma = 1.0 / (spp * np.sqrt(12.0))
    residual_px = project_points(spec, R, t, pos) - px[inside]
    rms_px, max_px, mean_px = np.sqrt(np.mean(residual_px ** 2)), np.max(np.abs(residual_px)), residual_px.mean(0)
    if lens == "pinhole":
        assert max_px < 8 * sigma and rms_px < 1.5 * sigma and np.all(np.abs(mean_px) < 0.1 * sigma)
    else:
        assert max_px < 0.03 and rms_px < 0.004 and np.all(np.abs(mean_px) < 5e-4)
    # In 3-D: the averaged points lie on the face (float32 accumulation only) next to the truth hit.
    X_s = (pos - pose[1]) @ pose[0]
    assert np.max(np.abs(X_s[:, 2])) < 1e-3
    pixel_mm = np.linalg.norm(pose[1] - truth.camera_poses[side][0].T @ -t) / spec.fx
    in_plane_mm = np.linalg.norm(X_s[:, :2] - X_spec[inside, :2], axis=1)
    assert np.max(in_plane_mm) < (0.03 if lens == "thin" else 8 * sigma) * pixel_mm
    # Texture coordinates are the material coordinates of the face.
    uv = r.uv.reshape(-1, 2)[inside]
    uv_mm = np.stack([uv[:, 0] * sp.length_mm - sp.length_mm / 2, uv[:, 1] * sp.height_mm - sp.height_mm / 2], 1)
    assert np.max(np.abs(uv_mm - X_spec[inside, :2])) < (0.03 if lens == "thin" else 8 * sigma) * pixel_mm


def test_points_of_interest_follow_the_stage(scene):
    truth = scene["pinhole"]
    px = np.array([[245.0, 190.0], [100.0, 150.0], [5.0, 5.0]])       # the last one sees the background
    X_s, X_w = truth.points_of_interest(px)
    assert np.all(np.isfinite(X_s[:2])) and np.all(np.isnan(X_s[2]))
    np.testing.assert_allclose(X_s[:2, 2], 0.0)
    np.testing.assert_allclose(X_w[1, :2] - X_w[0, :2], [[0, -10, 0], [0, -10, 0]], atol=1e-12)
    np.testing.assert_allclose(truth.project("left", X_w[0, :2]), px[:2], atol=1e-9)
    # displacement fields act in the specimen frame, before the pose
    X_def = material_point_positions(X_s[:2], truth.poses, [None, lambda X: np.tile([0.0, 0.0, 1.0], (len(X), 1))])
    np.testing.assert_allclose(X_def[1] - X_w[1, :2], np.tile(truth.poses[1][0][:, 2], (2, 1)), atol=1e-12)
    with pytest.raises(ValueError, match="reference_state 5 is not one of the"):
        points_of_interest_truth(truth.specs["left"], *truth.camera_poses["left"], px, truth.specimen,
                                 truth.poses, reference_state=5)


def test_zero_and_uniform_displacement_render_like_rigid_motion(scene):
    """u = 0 renders bit-identically to the rigid beam; a uniform u renders as the rigid translation R u."""
    truth = scene["pinhole"]
    sp, (R, t), tex = truth.specimen, truth.poses[0], scene["texture"]
    spec, cam = truth.specs["left"], truth.camera_poses["left"]
    crop = (200, 160, 64, 64)
    render = lambda surfaces: render_view(spec, *cam, surfaces, spp=16, seed=1, crop=crop).image_grey  # noqa: E731 (short local helper)
    rigid = render(sp.surfaces(R, t, texture=tex))
    zero = render(sp.surfaces(R, t, texture=tex, displacement_mm=lambda X: np.zeros_like(X)))
    np.testing.assert_array_equal(rigid, zero)
    u = np.array([0.3, -0.7, 0.2])
    moved = render(sp.surfaces(R, t, texture=tex, displacement_mm=lambda X: np.tile(u, (len(X), 1))))
    translated = render(sp.surfaces(R, t + R @ u, texture=tex))
    assert np.max(np.abs(moved - translated)) < 1e-3 * 255       # float32 vertex rounding only
    assert np.max(np.abs(moved - rigid)) > 50                      # and it did move


def test_thin_lens_focus_and_blur(rig, scene):
    truth = scene["thin"]
    spec, cam = truth.specs["left"], truth.camera_poses["left"]
    centre = truth.poses[0][1]
    assert focal_length_for_focus_mm(spec, *cam, centre[None]) == pytest.approx(spec.focal_length_mm, rel=1e-12)
    assert defocus_blur_px(spec, *cam, centre[None])[0] < 1e-9
    pix = np.array([[10.0, 20.0], [480.0, 400.0], [245.0, 200.0]])
    X_focus = in_focus_points_world_mm(spec, *cam, pix)
    np.testing.assert_allclose(project_points(spec, *cam, X_focus), pix, atol=1e-9)
    assert np.max(defocus_blur_px(spec, *cam, X_focus)) < 1e-9
    assert np.all(defocus_blur_px(scene["pinhole"].specs["left"], *cam, X_focus) == 0)
    # Table 1's tilt puts the plane of sharp focus ~50 deg from a face looking along the bisector.
    for side in ("left", "right"):
        assert 40 < truth.info["focus_plane_to_face_deg"][side] < 60
        assert 2 < truth.info["max_defocus_blur_px"][side] < 6
    with pytest.warns(UserWarning, match="blurred by up to"):
        rigid_motion_truth(rig, lens="thin", states_mm=[0.0])


def test_in_focus_plane_is_sharp_in_the_render(scene):
    """A speckled plate laid on the predicted plane of sharp focus renders through the wide-open thin lens like
    through a pinhole; the specimen face (50 deg away from that plane) does not."""
    truth = scene["thin"]
    spec, cam = truth.specs["left"].with_(f_number=2.8), truth.camera_poses["left"]
    u, v = np.meshgrid(np.linspace(0, spec.width - 1, 5), np.linspace(0, spec.height - 1, 5))
    X = in_focus_points_world_mm(spec, *cam, np.stack([u.ravel(), v.ravel()], 1))
    centroid = X.mean(0)
    _, _, Vt = np.linalg.svd(X - centroid)
    normal = Vt[2] if Vt[2][2] > 0 else -Vt[2]           # plate z points away from the camera
    x_axis = np.cross([0.0, 1.0, 0.0], normal)
    x_axis /= np.linalg.norm(x_axis)
    R_plate = np.stack([x_axis, np.cross(normal, x_axis), normal], 1)
    pixel_mm = centroid[2] / spec.fx
    plate = SpeckledPlate(width_mm=200, height_mm=100, texel_mm=pixel_mm / 3, speckle_mm=4 * pixel_mm, seed=2)
    tex = plate.texture()
    crop = (0, int(spec.cy) - 10, spec.width, 20)
    diffs = {}
    for name, R_obj in (("focus plane", R_plate), ("face", truth.poses[0][0])):
        surf = [plate.surface(R_obj, truth.poses[0][1], tex)]
        pin = render_view(spec.with_(lens="pinhole"), *cam, surf, spp=256, seed=1, crop=crop).image_grey
        thin = render_view(spec, *cam, surf, spp=256, seed=2, crop=crop).image_grey
        edges = np.r_[0:40, spec.width - 40:spec.width]       # the image sides, far from the sharp centre line
        diffs[name] = np.sqrt(np.mean((thin - pin)[:, edges] ** 2))
    assert diffs["focus plane"] < 2.0                   # grey levels: Monte-Carlo noise
    assert diffs["face"] > 5 * diffs["focus plane"]


# ------------------------------------------------------------------------------------------------------------
def test_dataset_files_and_truth_json(dataset):
    out, truth = dataset
    d = json.loads((out / "truth.json").read_text())
    assert [s["stage_mm"] for s in d["states"]] == [0.0, 1.0, 10.0]
    assert d["lens"] == "thin" and d["render"]["read_noise_grey"] == 1.0 and d["rig"]["scale"] == SCALE
    np.testing.assert_allclose(d["states"][2]["displacement_left_cam_mm"], [0, -10, 0], atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(d["states"][2]["displacement_right_cam_mm"]), 10.0)
    assert d["specimen"]["length_mm"] == 120 and d["specimen"]["height_mm"] == 30
    loaded = load_truth(out)
    assert loaded.specimen == truth.specimen and loaded.specs == truth.specs
    np.testing.assert_array_equal(loaded.states_mm, truth.states_mm)
    np.testing.assert_allclose(loaded.displacements_world_mm, truth.displacements_world_mm, atol=1e-12)
    px = np.array([[250.0, 200.0], [60.0, 170.0]])
    np.testing.assert_allclose(loaded.points_of_interest(px)[1], truth.points_of_interest(px)[1], atol=1e-12)
    for k, names in enumerate(loaded.files):
        assert names == {"left": f"left_{k:02d}.png", "right": f"right_{k:02d}.png"}
        for side in ("left", "right"):
            img = cv2.imread(str(out / names[side]), cv2.IMREAD_UNCHANGED)
            assert img.dtype == np.uint8 and img.shape == (truth.specs[side].height, truth.specs[side].width)
    with pytest.raises(FileNotFoundError, match="no truth.json in .*nowhere"):
        load_truth(out / "nowhere")


def test_face_fills_both_images(dataset):
    """The face covers the full width and ~40 % of the height of both images; it is bright, the rest black."""
    out, truth = dataset
    for side in ("left", "right"):
        spec = truth.specs[side]
        jj, ii = np.meshgrid(np.arange(spec.width), np.arange(spec.height))
        px = np.stack([jj.ravel(), ii.ravel()], 1).astype(float)
        for k in (0, 2):
            X_w, _ = intersect_front_face(*pixel_rays(spec, *truth.camera_poses[side], px), truth.specimen,
                                          *truth.poses[k])
            face = np.isfinite(X_w[:, 0]).reshape(spec.height, spec.width)
            assert 0.3 < face.mean() < 0.5
            assert face[:, 0].any() and face[:, -1].any()          # the beam runs across the whole image
            img = cv2.imread(str(out / truth.files[k][side]), cv2.IMREAD_UNCHANGED).astype(float)
            assert img[face].mean() > 100 and img[face].std() > 30 and img[~face].mean() < 3


@pytest.mark.parametrize("side", ["left", "right"])
@pytest.mark.parametrize("k", [1, 2])
def test_image_shift_matches_projected_truth(dataset, side, k):
    """State k is state 0 shifted upwards by what the projected truth positions predict (within 0.02 px)."""
    out, truth = dataset
    spec, cam = truth.specs[side], truth.camera_poses[side]
    ref = cv2.imread(str(out / truth.files[0][side]), cv2.IMREAD_UNCHANGED).astype(float)
    cur = cv2.imread(str(out / truth.files[k][side]), cv2.IMREAD_UNCHANGED).astype(float)
    half = 32
    c = np.round(truth.project(side, truth.poses[0][1][None])[0] + [0, 6]).astype(int)   # near the face centre
    jj, ii = np.meshgrid(np.arange(c[0] - half, c[0] + half), np.arange(c[1] - half, c[1] + half))
    px = np.stack([jj.ravel(), ii.ravel()], 1).astype(float)
    _, X_w = points_of_interest_truth(spec, *cam, px, truth.specimen, truth.poses)
    predicted = truth.project(side, X_w[k]) - px
    assert np.all(np.isfinite(predicted))
    shift = predicted.mean(0)
    assert shift[1] < -0.9 * truth.states_mm[k] * spec.fx / 376.0    # up in the image, ~fx/Z px per mm
    assert np.ptp(predicted, axis=0).max() < 0.3      # nearly uniform (perspective and distortion: 0.2 px at 10 mm)
    offset = np.round(shift).astype(int)
    moved = cur[c[1] - half + offset[1]:c[1] + half + offset[1], c[0] - half + offset[0]:c[0] + half + offset[0]]
    window = ref[c[1] - half:c[1] + half, c[0] - half:c[0] + half]
    measured = offset + fourier_shift_fit(window, moved, border_px=8)
    np.testing.assert_allclose(measured, shift, atol=0.02)       # measured ~0.002 px


def test_same_seed_same_images(tmp_path):
    kw = dict(scale=0.15, lens="pinhole", spp=4, states=[0.0, 2.0], progress=False)
    a = render_rigid_motion("paper", tmp_path / "a", seed=7, **kw)
    render_rigid_motion("paper", tmp_path / "b", seed=7, **kw)
    render_rigid_motion("paper", tmp_path / "c", seed=8, **kw)
    for names in a.files:
        for name in names.values():
            assert (tmp_path / "a" / name).read_bytes() == (tmp_path / "b" / name).read_bytes()
            assert (tmp_path / "a" / name).read_bytes() != (tmp_path / "c" / name).read_bytes()
    assert (tmp_path / "a" / "truth.json").read_text() == (tmp_path / "b" / "truth.json").read_text()


def test_bad_input(rig, tmp_path):
    # The left image sees x in ~[-30, 58] mm around the axes' meeting point, the right one ~[-60, 42] mm.
    with pytest.raises(SpecimenOutOfViewError, match="left image"):
        rigid_motion_truth(rig, lens="pinhole", centre_world_mm=rig.optical_axes_meeting_point_mm() + [-45, 0, 0])
    with pytest.raises(SpecimenOutOfViewError, match="right image"):
        rigid_motion_truth(rig, lens="pinhole", centre_world_mm=rig.optical_axes_meeting_point_mm() + [50, 0, 0],
                           states_mm=[0.0])
    with pytest.raises(ValueError, match=r"in state \d+"):     # 30 mm up: leaves the images on the way
        rigid_motion_truth(rig, lens="pinhole", states_mm=stage_states_mm(30.0, 3.0))
    with pytest.raises(ValueError, match="lens"):
        rigid_motion_truth(rig, lens="fisheye")
    with pytest.raises(ValueError, match="f_number"):
        rigid_motion_truth(rig, lens="thin", f_number=-2)
    with pytest.raises(ValueError, match="scale"):
        render_rigid_motion(rig, tmp_path, scale=0.5)
    with pytest.raises(ValueError, match="states"):
        rigid_motion_truth(rig, lens="pinhole", states_mm=[0.0, np.nan])
    # a specimen taller than the view is refused before anything is rendered or written
    with pytest.raises(SpecimenOutOfViewError, match="front face leaves the left image"):
        render_rigid_motion("paper", tmp_path / "tall", scale=SCALE,
                            specimen=BendingSpecimen(height_mm=80, texel_mm=0.05, speckle_mm=0.5))
    assert not (tmp_path / "tall").exists()
