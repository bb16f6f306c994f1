import numpy as np
import pytest


@pytest.fixture(scope="session")
def paper_rig_quarter():
    """The paper rig at a quarter of its resolution (614 x 514 px): the default test scale."""
    from workbench.rigs import paper_rig

    return paper_rig(0.25)


@pytest.fixture
def rng():
    return np.random.default_rng(12345)
