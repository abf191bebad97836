import numpy as np
import pytest

from hbeo import config


@pytest.fixture(scope="session")
def sample_dir():
    """../shared/modelnet10_sample: five real ModelNet10 bathtub meshes."""
    d = config.modelnet10_sample_dir()
    if d is None or not d.is_dir():
        pytest.skip("shared/modelnet10_sample not found beside the repository")
    return d


@pytest.fixture(scope="session")
def vox30_file():
    p = config.vox30_path()
    if p is None:
        pytest.skip("shared/modelnet10_vox30 not found beside the repository")
    return p


@pytest.fixture(scope="session")
def vox30(vox30_file):
    with np.load(vox30_file) as z:
        return {k: z[k] for k in ("X_train", "names_train", "y_train", "classes")}
