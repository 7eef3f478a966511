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
    from sonicskin.fit import build_svm_artifact
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


# Runs that need the machine to themselves: the JACK round trip is real time (a starved server drops
# chirps), DDP starts two training processes.  Marked slow and serial here: `make test` runs them after
# the parallel part, alone (`-m serial`).
_SERIAL = {"test_end_to_end_through_jack", "test_rig_check_through_jack",
           "test_rig_check_through_jack_names_a_rate_the_server_does_not_run", "test_train_ddp_two_cpu_processes",
           "test_live_exits_when_its_jack_server_dies"}
_LONGEST = {"test_reproduce.py"}  # handed out first: the quick reproduction is most of the suite's time


def pytest_itemcollected(item):
    """Marks as each test is collected."""
    if getattr(item, "originalname", None) in _SERIAL:
        item.add_marker(pytest.mark.slow)
        item.add_marker(pytest.mark.serial)


def pytest_collection_modifyitems(config, items):
    """Scheduling for pytest-xdist (``make test``: ``-n 2 --dist loadfile``): the tests of one module run
    on one worker, in file order, so module-scoped fixtures (simulated datasets, trained artifacts) are
    built once; the longest module and then the modules with long runs (marked ``slow``) come first,
    so no worker is left with one of them at the end.  Modules stay whole (a plain run builds each
    module's fixtures once too).  Tests share no mutable path: what they write goes under ``tmp_path``
    / ``tmp_path_factory``, which are per worker."""
    slow = {item.path for item in items if item.get_closest_marker("slow") is not None}
    # Stable: the longest module first (the quick reproduction, about 4.5 of the suite's 6 minutes), then
    # the other modules with slow runs, then the rest in collection order.
    items.sort(key=lambda it: (it.path.name not in _LONGEST, it.path not in slow))
