import os

import numpy as np
import pytest


@pytest.fixture(scope="session", autouse=True)
def isolated_dataset_store(tmp_path_factory):
    """Every test (and every command it starts) renders into one fresh dataset store, never the user's cache."""
    previous = os.environ.get("WORKBENCH_STORE")
    os.environ["WORKBENCH_STORE"] = str(tmp_path_factory.mktemp("dataset-store"))
    yield os.environ["WORKBENCH_STORE"]
    if previous is None:
        os.environ.pop("WORKBENCH_STORE", None)
    else:
        os.environ["WORKBENCH_STORE"] = previous


@pytest.fixture(scope="session")
def paper_rig_quarter():
    """The paper rig at a quarter of its resolution (614 x 514 px): the default test scale."""
    from workbench.rigs import paper_rig

    return paper_rig(0.25)


@pytest.fixture
def rng():
    return np.random.default_rng(12345)
