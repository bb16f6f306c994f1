"""MultiDIC's real sample data (speckled cylinder, radius 57.0 mm) measured with our instrument.

Needs the data folder from ``scripts/fetch_multidic.sh`` (default ``data/multidic``, or ``$MULTIDIC_DATA``); skipped
without it. Full-resolution 8 MP images: marked ``slow`` (run with ``-m slow``; ~2 min on two cores).

The goals are the issue's: at least 98 % of the points whose left->right DIC match converged are triangulated, and
the radius of a cylinder fitted to the triangulated reference points is within 0.5 % of 57.0 mm.
"""
from __future__ import annotations

import importlib.util
import os
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DATA = Path(os.environ.get("MULTIDIC_DATA", ROOT / "data" / "multidic"))
NEEDED = ("speckledObjectImages/201/201_1.jpg", "speckledObjectImages/202/202_1.jpg",
          "speckledObjectImages/ROIMask_C_201_C_202.mat", "calibrationObjectImages/DLTstruct_cam_201.mat",
          "calibrationObjectImages/DLTstruct_cam_202.mat", "BAcheckerboardImages/201", "BAcheckerboardImages/202")

GOAL_TRIANGULATED = 0.98        # the goals, not tuned to the result
GOAL_RADIUS_REL = 0.005


def _benchmark():
    spec = importlib.util.spec_from_file_location("real_multidic", ROOT / "benchmarks" / "real_multidic.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="module")
def result(tmp_path_factory):
    missing = [n for n in NEEDED if not (DATA / n).exists()]
    if missing:
        pytest.skip(f"MultiDIC sample data not in {DATA} (missing {missing[0]}...): run scripts/fetch_multidic.sh "
                    "[--mirror GIT_DIR] or set MULTIDIC_DATA")
    return _benchmark().measure(DATA, tmp_path_factory.mktemp("real_multidic"), step=20, checks=False)


@pytest.mark.slow
def test_converged_matches_are_triangulated(result):
    counts = result["counts"]
    assert counts["converged"] > 0.5 * counts["points"], counts
    assert result["fraction"] >= GOAL_TRIANGULATED, counts


@pytest.mark.slow
def test_cylinder_radius(result):
    assert abs(result["rel_radius_error"]) <= GOAL_RADIUS_REL, (result["radius_mm"], result["rms_mm"])
