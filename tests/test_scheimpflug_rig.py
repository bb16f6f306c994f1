"""The ``scheimpflug`` rig: sensor tilts from the Scheimpflug condition put the specimen face in focus."""
import numpy as np
import pytest
from dataclasses import replace

from workbench.experiments.calibration.views import sensor_spec_for
from workbench.experiments.rigid_motion.scenes import face_blur_px, specimen_reference_pose
from workbench.rigs import (facing_plane_world, get_rig, paper_rig, scheimpflug_rig, scheimpflug_tilt_for_plane)
from scenes.specimens.beam import BendingSpecimen


def _hinge_line_points(alpha_deg, beta_deg, image_distance_mm):
    """Two points of the line where the physical sensor plane meets the lens plane z = 0 (camera frame, mm).

    The physical sensor is the point mirror of the virtual one: the plane through (0, 0, -v) with normal
    R_Y(beta) R_X(alpha) e_z (the same rotation as Table 1's model, written out here independently).
    """
    a, b = np.deg2rad(alpha_deg), np.deg2rad(beta_deg)
    n = np.array([np.sin(b) * np.cos(a), -np.sin(a), np.cos(b) * np.cos(a)])
    # n . (p - (0, 0, -v)) = 0 with p_z = 0  ->  n_x p_x + n_y p_y = -n_z v
    d = np.array([-n[1], n[0], 0.0]) / np.hypot(n[0], n[1])          # direction of the line in z = 0
    p0 = -n[2] * image_distance_mm * np.array([n[0], n[1], 0.0]) / (n[0] ** 2 + n[1] ** 2)
    return p0, p0 + 100.0 * d


def test_solved_tilt_satisfies_the_scheimpflug_intersection_rule_without_distortion():
    """Sensor plane, lens plane and the face plane meet in one line (Scheimpflug), to 1e-6 of the hinge distance."""
    paper = paper_rig(1.0)
    centre, normal = facing_plane_world(paper)
    for side in ("left", "right"):
        cam = replace(paper.camera(side), k1=0.0, k2=0.0, p1=0.0, p2=0.0)
        R, t = paper.pose(side)
        alpha, beta, F, rms = scheimpflug_tilt_for_plane(cam, R, t, centre, normal)
        assert rms < 1e-9                    # without distortion the in-focus surface is exactly a plane
        v = cam.fx * paper.pixel_pitch_mm
        p0, p1 = _hinge_line_points(alpha, beta, v)
        n_cam, c_cam = R @ normal, R @ centre + t
        hinge_distance = abs(p0 @ n_cam - c_cam @ n_cam) + np.linalg.norm(p0)
        for p in (p0, p1):
            assert abs((p - c_cam) @ n_cam) < 1e-6 * hinge_distance
        # and the thin-lens equation holds on the optical axis for the in-focus depth there
        z_axis = c_cam @ n_cam / n_cam[2]
        assert 1.0 / F == pytest.approx(1.0 / v + 1.0 / z_axis, rel=1e-9)


def test_scheimpflug_rig_keeps_the_whole_face_sharp_where_table1_tilts_do_not():
    """Full resolution, f/8: defocus blur over the face below 0.1 px with the solved tilts; > 3 px with Table 1's."""
    rig = scheimpflug_rig(1.0)
    R0, t0 = specimen_reference_pose(rig)
    specimen = BendingSpecimen()
    for side in ("left", "right"):
        spec = sensor_spec_for(rig, side, **rig.thin_lens(side))
        assert face_blur_px(specimen, (R0, t0), spec, *rig.pose(side)) < 0.1
        table1 = sensor_spec_for(paper_rig(1.0), side, **rig.thin_lens(side))
        assert face_blur_px(specimen, (R0, t0), table1, *rig.pose(side)) > 3.0


def test_scheimpflug_rig_shares_table1_except_the_tilt_and_scales():
    paper, rig = paper_rig(0.5), scheimpflug_rig(0.5)
    for side in ("left", "right"):
        a, b = paper.camera(side), rig.camera(side)
        for name in ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "width", "height"):
            assert getattr(a, name) == getattr(b, name)
        assert abs(b.beta_deg) < 2.0 and np.sign(b.beta_deg) == -np.sign(a.beta_deg)
    np.testing.assert_array_equal(rig.R_right_from_left, paper.R_right_from_left)
    assert rig.pixel_pitch_mm == pytest.approx(2 * paper_rig(1.0).pixel_pitch_mm)
    assert get_rig("scheimpflug", 0.5).left == rig.left
    with pytest.raises(ValueError, match="unknown rig 'nope'"):
        get_rig("nope")
    with pytest.raises(ValueError, match="defines no thin lens"):
        paper.thin_lens("left")
    with pytest.raises(ValueError, match="f_number must be positive"):
        scheimpflug_rig(1.0, f_number=0.0)
