from pathlib import Path

import numpy as np
import pytest
from cli_helpers import SMALL_RIG, TINY_SCENARIO

from sonicskin.rig import Rig


@pytest.fixture(scope="session")
def rig() -> Rig:
    return Rig.load("jaco")


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(12345)


@pytest.fixture(scope="session")
def cli_files(tmp_path_factory) -> dict[str, Path]:
    """Rig and scenario YAMLs, the tiny dataset and its SVM artifact (read-only for the tests)."""
    from sonicskin.artifact import build_svm_artifact
    from sonicskin.rig import Rig
    from sonicskin.sim.generate import simulate_dataset
    from sonicskin.sim.scenario import Scenario

    root = tmp_path_factory.mktemp("cli")
    (root / "small.yaml").write_text(SMALL_RIG)
    (root / "tiny.yaml").write_text(TINY_SCENARIO)
    simulate_dataset(Scenario.load(root / "tiny.yaml"), Rig.load(root / "small.yaml"), root / "tiny", progress=False,
                     log=lambda *_: None)
    build_svm_artifact(root / "tiny", root / "art", n_bins=60, progress=False, log=lambda *_: None)
    return {"root": root, "rig": root / "small.yaml", "scenario": root / "tiny.yaml", "data": root / "tiny",
            "artifact": root / "art"}
