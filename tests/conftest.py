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


# Long runs defined in modules owned elsewhere, marked slow here (the JACK round trip starts a server).
_LONG_IN_MODULE = {"test_end_to_end_through_jack"}


@pytest.hookimpl(tryfirst=True)
def pytest_collection_modifyitems(config, items):
    """Scheduling for pytest-xdist (``make test``: ``-n 2 --dist loadgroup``): the tests of one module
    run on one worker (an ``xdist_group`` per module unless the module names its own), so module- and
    session-scoped fixtures (simulated datasets, trained artifacts) are built once per worker that needs
    them; the modules with long runs (marked ``slow``) are handed out first, so no worker is left with
    one of them at the end.  Runs before xdist's own hook, which reads the groups.  Tests share no
    mutable path: what they write goes under ``tmp_path`` / ``tmp_path_factory``, per worker."""
    for item in items:
        if item.originalname in _LONG_IN_MODULE:
            item.add_marker(pytest.mark.slow)
        if item.get_closest_marker("xdist_group") is None:
            item.add_marker(pytest.mark.xdist_group(item.module.__name__))
    items.sort(key=lambda it: it.get_closest_marker("slow") is None)  # stable: slow first, else collection order
