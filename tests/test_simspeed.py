"""The simulator's speed work keeps its output: the FLAC level only changes the bytes, the 24-bit integer render
writes the same FLAC as the float frames, and ``simulate`` does not import what it does not use."""

import io
import json
import subprocess
import sys

import numpy as np
import soundfile as sf

from sonicskin import dataset, dsp
from sonicskin.dataset import FLAC_LEVEL, Dataset
from sonicskin.sim.generate import simulate_dataset
from sonicskin.sim.scenario import Scenario

# Two short sessions with a moving robot (the motion ripple and the robot's noise are on the path).
MOVING = dict(sessions=2, layout={"kind": "grid", "nx": 2, "ny": 1, "spacing_cm": 1.2, "x0_cm": 8, "y0_cm": 12},
              touch_s=0.6, gap_s=0.2, calibration_s=0.4, moving_s=0.8, part_s=0.5, seed=5, motion={"enabled": True})


def _codes(path) -> np.ndarray:
    return sf.read(path, dtype="int32")[0]


def test_flac_level_changes_the_bytes_never_the_samples(tmp_path):
    # 24-bit codes as the simulator writes them (k / (2^23 - 1)), full scale included: a chirp train with
    # noise, which the levels' predictors compress differently; every level must decode to the same integers.
    rng = np.random.default_rng(0)
    q = 2 ** 23 - 1
    x = np.tile(dsp.chirp(sr=192000, f_lo_hz=20000, f_hi_hz=60000, n_samples=20480, amplitude=0.3), 10)
    k = np.round((x + 0.01 * rng.standard_normal(x.size)) * q).clip(-q, q)
    k[:4] = [q, -q, 0, 1]
    audio = (k / q).astype(np.float32)
    decoded, sizes = {}, {}
    for level in (0, 5, 8):
        buf = io.BytesIO()
        sf.write(buf, audio, 192000, format="FLAC", subtype="PCM_24", compression_level=level / 8)
        sizes[level] = len(buf.getvalue())
        buf.seek(0)
        decoded[level] = sf.read(buf, dtype="int32")[0]
    assert sizes[0] > sizes[5] >= sizes[8]  # the levels really differ
    np.testing.assert_array_equal(decoded[0], decoded[5])
    np.testing.assert_array_equal(decoded[0], decoded[8])
    # The integers are the audio's 24-bit codes (libsndfile: round(x 2^23), clipped to 2^23 - 1).
    np.testing.assert_array_equal(decoded[0] >> 8, np.clip(np.rint(audio.astype(np.float64) * 2 ** 23), -2 ** 23, q))


def test_simulated_dataset_at_the_writer_level_decodes_like_the_default_level(tmp_path, rig, monkeypatch):
    assert 0 <= FLAC_LEVEL <= 8
    sc = Scenario(**MOVING)
    simulate_dataset(sc, rig, tmp_path / "fast", progress=False, log=lambda *_: None)
    monkeypatch.setattr(dataset, "FLAC_LEVEL", 5)  # libsndfile's default
    simulate_dataset(sc, rig, tmp_path / "default", progress=False, log=lambda *_: None)
    parts = sorted((tmp_path / "fast").glob("s*/part-*.flac"))
    assert len(parts) >= 4
    differ = 0
    for p in parts:
        other = tmp_path / "default" / p.relative_to(tmp_path / "fast")
        np.testing.assert_array_equal(_codes(p), _codes(other))
        differ += p.read_bytes() != other.read_bytes()
        assert p.with_suffix(".csv").read_bytes() == other.with_suffix(".csv").read_bytes()
    assert differ == len(parts) if FLAC_LEVEL != 5 else differ == 0
    # The manifests hash what was written, and the reader accepts it.
    man = json.loads((tmp_path / "fast" / "s000" / "session.json").read_text())
    assert len(man["parts"]) == len(list((tmp_path / "fast" / "s000").glob("part-*.flac")))
    fa, la = Dataset(tmp_path / "fast").read_session("s001")
    fb, lb = Dataset(tmp_path / "default").read_session("s001")
    np.testing.assert_array_equal(fa, fb)
    np.testing.assert_array_equal(la["chirp"], lb["chirp"])
    assert (la["moving"] > 0).any()


def test_simulate_imports_only_what_it_uses(tmp_path):
    # A fresh interpreter runs the CLI's simulate (moving robot included), then lists the heavy modules loaded.
    code = f"""
import sys
from sonicskin.cli import main
from sonicskin.sim.scenario import Scenario
import yaml
cfg = {MOVING!r}
open({str(tmp_path / 'sc.yaml')!r}, 'w').write(yaml.safe_dump(dict(name='m', **cfg)))
assert main(['simulate', '--scenario', {str(tmp_path / 'sc.yaml')!r}, '--out', {str(tmp_path / 'ds')!r}]) == 0
heavy = ('scipy.optimize', 'scipy.stats', 'sklearn', 'onnxruntime', 'matplotlib', 'torch', 'pandas')
print(sorted(m for m in sys.modules if m.split('.')[0] in heavy and m.startswith(heavy)))
"""
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-2000:]
    assert r.stdout.strip().splitlines()[-1] == "[]"
    assert (tmp_path / "ds" / "s001" / "session.json").is_file()


def test_int32_render_writes_the_same_flac_as_the_float_frames(tmp_path, rig):
    # simulate renders 24-bit codes (int32) and hands them to the writer: the FLAC must be the very file the
    # float frames give through libsndfile's own conversion, byte for byte.
    from sonicskin.dataset import COLUMNS, DatasetWriter
    from sonicskin.sim import Simulator, build_timeline

    sc = Scenario(**MOVING)
    sim = Simulator(sc, rig)
    tl = build_timeline(sc, rig)
    st = tl.select(tl.session == 0)
    st = st.select(np.arange(min(len(st), 70)))  # two render chunks, the second one short
    assert (st.moving > 0).any() or (st.force_n > 0).any()
    x = sim.render(st)
    codes = sim.render(st, out=np.empty(x.shape, np.int32))
    want = np.clip(np.rint(x.astype(np.float64) * 2 ** 23), -2 ** 23, 2 ** 23 - 1).astype(np.int64) * 256
    np.testing.assert_array_equal(codes, want)
    assert np.abs(codes).max() > 2 ** 27  # a real signal in the upper bits
    labels = {c: np.zeros(len(st)) for c in COLUMNS}
    labels.update(chirp=np.arange(len(st)), location=-np.ones(len(st), int), segment=np.array(["gap"] * len(st)),
                  subject=np.zeros(len(st), int))
    paths = []
    for name, audio in (("f", x.ravel()), ("i", codes.ravel())):
        w = DatasetWriter(tmp_path / name, rig, sim.layout, source={})
        w.write_part("s000", 0, audio, labels)
        paths.append(tmp_path / name / "s000" / "part-00000.flac")
    assert paths[0].read_bytes() == paths[1].read_bytes()
