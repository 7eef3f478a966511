import json

import numpy as np
import pytest
import soundfile as sf

from sonicskin.dataset import Dataset, DatasetError, DatasetWriter
from sonicskin.sim.generate import simulate_dataset
from sonicskin.sim.scenario import Scenario

TINY = dict(sessions=2, layout={"kind": "grid", "nx": 2, "ny": 1, "spacing_cm": 1.2, "x0_cm": 8, "y0_cm": 12},
            touch_s=0.6, gap_s=0.2, calibration_s=0.4, part_s=0.5, seed=3)


@pytest.fixture(scope="module")
def tiny(tmp_path_factory, rig):
    out = tmp_path_factory.mktemp("ds") / "tiny"
    simulate_dataset(Scenario(**TINY), rig, out, progress=False, log=lambda *_: None)
    return out


def test_roundtrip_frames_and_labels(tiny, rig):
    ds = Dataset(tiny)
    assert ds.sessions == ["s000", "s001"] and ds.rig == rig and len(ds.layout) == 2
    assert len(ds.parts("s000")) > 2  # several parts per session
    frames, lab = ds.read_session("s000")
    assert frames.shape[1] == rig.n_chirp
    np.testing.assert_array_equal(lab["chirp"], np.arange(frames.shape[0]))  # every chirp found, in order
    assert set(lab["segment"]) == {"calibration", "touch", "gap"}
    assert (lab["force_n"][lab["location"] < 0] == 0).all() and lab["force_n"].max() > 0.5
    t = ds.features(progress=False)
    assert t.X.shape == (len(t), rig.n_band) and np.isfinite(t.X).all()


def test_interrupted_session_keeps_written_parts(tiny, tmp_path, rig):
    import shutil
    d = tmp_path / "cut"
    shutil.copytree(tiny, d)
    full = Dataset(d).read_session("s001")[0].shape[0]
    last = Dataset(d).parts("s001")[-1]
    (d / "s001" / f"part-{last:05d}.csv").unlink()  # killed while writing the last part
    (d / "s001" / "session.json").unlink()
    kept = Dataset(d).read_session("s001")[0].shape[0]
    assert 0 < kept < full
    # --resume re-renders the unfinished session and leaves the finished one alone.
    before = (d / "s000" / "part-00000.flac").stat().st_mtime_ns
    simulate_dataset(Scenario(**TINY), rig, d, mode="resume", progress=False, log=lambda *_: None)
    assert Dataset(d).read_session("s001")[0].shape[0] == full
    assert (d / "s000" / "part-00000.flac").stat().st_mtime_ns == before


def test_bad_datasets_are_named(tiny, tmp_path, rig):
    import shutil
    with pytest.raises(DatasetError, match="dataset.json is missing"):
        Dataset(tmp_path)
    d = tmp_path / "bad"
    shutil.copytree(tiny, d)
    (d / "dataset.json").write_text("{not json")
    with pytest.raises(DatasetError, match="not valid JSON"):
        Dataset(d)
    shutil.copy(tiny / "dataset.json", d / "dataset.json")
    meta = json.loads((d / "dataset.json").read_text())
    meta["version"] = 99
    (d / "dataset.json").write_text(json.dumps(meta))
    with pytest.raises(DatasetError, match="version 99 is not supported"):
        Dataset(d)
    shutil.copy(tiny / "dataset.json", d / "dataset.json")
    x, sr = sf.read(d / "s000" / "part-00000.flac")
    sf.write(d / "s000" / "part-00000.flac", x, 48000, format="FLAC", subtype="PCM_24")
    with pytest.raises(DatasetError, match="part-00000.flac does not match its sha256 in session.json"):
        Dataset(d).read_session("s000")
    (d / "s000" / "session.json").unlink()  # an unfinished session: no manifest, the reader's own checks
    with pytest.raises(DatasetError, match="sample rate 48000 Hz, but the dataset's rig runs at 192000 Hz"):
        Dataset(d).read_session("s000")
    (d / "s001" / "part-00000.csv").write_text("chirp,time\n1,2\n")
    (d / "s001" / "session.json").unlink()
    with pytest.raises(DatasetError, match="header must be"):
        Dataset(d).read_session("s001")
    with pytest.raises(FileExistsError, match="--resume"):
        DatasetWriter(tiny, rig, Dataset(tiny).layout)
    with pytest.raises(DatasetError, match="other settings"):
        simulate_dataset(Scenario(**{**TINY, "seed": 4}), rig, tiny, mode="resume", progress=False)


def test_a_rig_name_that_is_no_string_is_named(tiny):
    """dataset.json's rig.name / rig.sweep_b64 said "must be a text"; every other config says "must be a string"."""
    from sonicskin.dataset import check_meta

    for k in ("name", "sweep_b64"):
        meta = json.loads((tiny / "dataset.json").read_text())
        meta["rig"][k] = 5
        with pytest.raises(DatasetError) as e:
            check_meta(meta, "d/dataset.json")
        assert str(e.value) == f"d/dataset.json: rig.{k} must be a string, got 5"


def _cached_features(root: str, barrier) -> tuple[int, float]:
    from sonicskin.feature_cache import load_features_cached

    barrier.wait()  # every process computes and writes the cache at the same moment
    t = load_features_cached(Dataset(root), progress=False)
    return len(t), float(t.X.sum())


def test_feature_cache_survives_concurrent_builders(tiny, tmp_path):
    """DDP ranks (or parallel `compare` runs) build the same feature cache at once: each gets the
    features, and one complete cache file is left (CI once lost a DDP rank to a shared temp name)."""
    import multiprocessing as mp
    import shutil
    from concurrent.futures import ProcessPoolExecutor

    from sonicskin.dataset import FeatureTable

    root = tmp_path / "ds"
    shutil.copytree(tiny, root, ignore=shutil.ignore_patterns(".cache"))
    ctx = mp.get_context("spawn")
    n = 4
    with ctx.Manager() as manager, ProcessPoolExecutor(n, mp_context=ctx) as pool:
        barrier = manager.Barrier(n)
        results = list(pool.map(_cached_features, [str(root)] * n, [barrier] * n))
    assert len(set(results)) == 1
    files = sorted(p.name for p in (root / ".cache").iterdir())
    assert len(files) == 1 and files[0].startswith("features-"), files  # no temporary file left behind
    assert len(FeatureTable.load_npz(root / ".cache" / files[0])) == results[0][0]


def test_damaged_feature_cache_is_rebuilt(tiny, tmp_path):
    import shutil

    from sonicskin.feature_cache import load_features_cached

    root = tmp_path / "ds"
    shutil.copytree(tiny, root, ignore=shutil.ignore_patterns(".cache"))
    want = load_features_cached(Dataset(root), progress=False)
    (cache,) = (root / ".cache").glob("features-*.npz")
    cache.write_bytes(cache.read_bytes()[:100])  # e.g. a copy cut short
    got = load_features_cached(Dataset(root), progress=False)
    np.testing.assert_array_equal(got.X, want.X)
    np.testing.assert_array_equal(load_features_cached(Dataset(root), progress=False).X, want.X)  # and rewritten
