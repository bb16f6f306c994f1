"""Full-resolution checks (2456 x 2058 px): run with ``pytest -m slow`` (several minutes on 2 cores)."""
import pytest

from workbench.experiments.calibration.agreement import GOAL_MAX_PX, GOAL_MEAN_PX, measure_agreement, summary_lines
from workbench.rigs import paper_rig

pytestmark = pytest.mark.slow


def test_full_resolution_render_agreement():
    summary = measure_agreement(paper_rig(1.0), n_views=1, seed=11, spp=256, progress=False)
    print("\n".join(summary_lines(summary)))
    for e in summary["cameras"].values():
        assert e["mean_px"] <= GOAL_MEAN_PX
        assert e["max_px"] <= GOAL_MAX_PX
