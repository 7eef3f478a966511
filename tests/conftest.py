import numpy as np
import pytest

from sonicskin.rig import Rig


@pytest.fixture(scope="session")
def rig() -> Rig:
    return Rig.load("jaco")


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(12345)
