import numpy as np
import pytest

import snac_gym  # noqa: F401  (registers the envs)
from snac_gym.kinematics import Kinematics


@pytest.fixture(scope="session")
def ur10() -> Kinematics:
    return Kinematics("ur10")


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(1234)
