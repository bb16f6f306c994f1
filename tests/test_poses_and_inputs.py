"""Board poses stay in view; impossible parameters and off-image boards are refused clearly."""
import numpy as np
import pytest

from scenes.optics.camera import SensorSpec, sensor_dict
from scenes.surfaces.checkerboard import Checkerboard
from workbench.experiments.calibration.views import board_outline_mm, render_board_views
from workbench.poses import BoardOutOfViewError, check_in_view, random_board_poses
from workbench.rigs import get_rig, paper_rig


def test_random_poses_are_in_view_and_tilted(paper_rig_quarter):
    board = Checkerboard()
    outline = board_outline_mm(board)
    poses = random_board_poses(paper_rig_quarter, outline, 30, seed=1)
    assert len(poses) == 30
    normals = np.array([R[:, 2] for R, _ in poses])
    tilts = np.degrees(np.arccos(np.clip(normals @ normals.mean(0) / np.linalg.norm(normals.mean(0)), -1, 1)))
    assert tilts.max() > 20                  # realistic calibration poses, not all fronto-parallel
    depths = np.array([t[2] for _, t in poses])
    assert depths.max() - depths.min() > 10  # various distances
    for R, t in poses:
        check_in_view(outline @ R.T + t, paper_rig_quarter)
        assert np.allclose(R @ R.T, np.eye(3)) and np.isclose(np.linalg.det(R), 1)


def test_same_seed_same_poses(paper_rig_quarter):
    outline = board_outline_mm(Checkerboard())
    a = random_board_poses(paper_rig_quarter, outline, 3, seed=4)
    b = random_board_poses(paper_rig_quarter, outline, 3, seed=4)
    assert all(np.array_equal(Ra, Rb) and np.array_equal(ta, tb) for (Ra, ta), (Rb, tb) in zip(a, b))


def test_board_leaving_the_image_is_refused(paper_rig_quarter):
    board = Checkerboard()
    pose = (np.eye(3), np.array([60.0, 0.0, 330.0]))   # far to the right: out of the left image
    with pytest.raises(BoardOutOfViewError, match="leaves the (left|right) image"):
        list(render_board_views(paper_rig_quarter, board, [pose], spp=1, progress=False))


def test_board_behind_camera_is_refused(paper_rig_quarter):
    outline = board_outline_mm(Checkerboard())
    with pytest.raises(BoardOutOfViewError, match="behind the left camera"):
        check_in_view(outline + [0, 0, -50], paper_rig_quarter)


def test_target_too_large_for_view():
    rig = paper_rig(0.1)
    huge = board_outline_mm(Checkerboard(square_mm=50))
    with pytest.raises(BoardOutOfViewError, match="too large"):
        random_board_poses(rig, huge, 2, seed=0, max_tries=200)


def test_unknown_rig():
    with pytest.raises(ValueError, match="unknown rig 'x'; known rigs: paper"):
        get_rig("x")


@pytest.mark.parametrize("changes, message", [
    (dict(fx=0.0), "focal lengths must be positive"),
    (dict(fy=-10.0), "focal lengths must be positive"),
    (dict(alpha_deg=45.0), "tilt must be below 45"),
    (dict(beta_deg=-50.0), "tilt must be below 45"),
    (dict(width=0), "image size must be positive"),
    (dict(lens="fisheye"), "lens must be"),
    (dict(lens="thin"), "thin lens needs"),
    (dict(lens="thin", focal_length_mm=50.0, f_number=4.0), "must exceed the focal length"),
    (dict(k1=float("nan")), "k1 must be finite"),
])
def test_impossible_sensor_parameters(changes, message):
    base = dict(fx=1000.0, fy=1000.0, cx=50.0, cy=40.0, width=100, height=80)
    with pytest.raises(ValueError, match=message):
        SensorSpec(**{**base, **changes})


def test_crop_outside_sensor():
    spec = SensorSpec(fx=1000.0, fy=1000.0, cx=50.0, cy=40.0, width=100, height=80)
    with pytest.raises(ValueError, match="outside the 100 x 80 sensor"):
        sensor_dict(spec, np.eye(3), np.zeros(3), spp=1, crop=(90, 0, 20, 10))


def test_render_needs_samples_and_surfaces():
    from scenes.rendering.mitsuba import render_view

    spec = SensorSpec(fx=1000.0, fy=1000.0, cx=50.0, cy=40.0, width=100, height=80)
    with pytest.raises(ValueError, match="spp"):
        render_view(spec, np.eye(3), np.zeros(3), [Checkerboard().surface(np.eye(3), [0, 0, 300])], spp=0)
    with pytest.raises(ValueError, match="no surfaces"):
        render_view(spec, np.eye(3), np.zeros(3), [], spp=1)


def test_paper_rig_geometry_matches_the_paper():
    """Table 1's R, T put the right camera at about (+144.4, +0.3, +29.9) mm and the axes meet ~376 mm ahead."""
    rig = paper_rig(1.0)
    assert np.allclose(rig.camera_centre_mm("right"), [144.4, 0.3, 29.9], atol=0.1)
    meet = rig.optical_axes_meeting_point_mm()
    assert abs(meet[2] - 376.0) < 1.0 and np.hypot(meet[0], meet[1]) < 1.0
