"""The rigid-motion test's stage as displacement fields: the same truth as the translated poses."""
import numpy as np

from scenes.deformation.stage import stage_fields, stage_poses, stage_states_mm
from scenes.optics.projection import material_point_positions


def test_stage_fields_give_the_positions_of_the_translated_poses():
    """Fields applied before the state-0 pose equal the stage poses to 1e-12 mm, with a zero gradient."""
    rng = np.random.default_rng(2)
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    R0 = q * np.sign(np.linalg.det(q))
    t0 = np.array([10.0, -5.0, 376.0])
    states = stage_states_mm(3.0, 1.0)
    X = rng.uniform(-20, 20, (30, 3))
    by_pose = material_point_positions(X, stage_poses(R0, t0, states))
    fields = stage_fields(R0, states)
    by_field = material_point_positions(X, [(R0, t0)] * len(states), fields)
    np.testing.assert_allclose(by_field, by_pose, rtol=0, atol=1e-12)
    for f in fields:
        np.testing.assert_array_equal(f.gradient(X), np.zeros((30, 3, 3)))
