"""Integrity of the data side (issue 16): mutation corpora generated from small valid inputs.

Every mutation must be refused with one line (a :class:`SonicskinError` naming the file) or handled
correctly (an unfinished session read up to its gap, an old manifest-less dataset read with a
warning, a stale feature cache rebuilt): never a traceback, a hang or a silently wrong result.
The families: dataset manifests and label rows, the feature cache, the two importers, sizes and
config files.  ``CORPUS`` counts the mutations of each family (printed by ``test_corpus_counts``).
"""

from __future__ import annotations

import csv
import io
import json
import shutil
import struct
import zipfile
from pathlib import Path

import numpy as np
import pytest
import soundfile as sf
from cli_helpers import SMALL_RIG, TINY_SCENARIO, assert_one_line_error, run

from sonicskin.dataset import COLUMNS, Dataset, DatasetError, DatasetWriter, FeatureTable, check_name
from sonicskin.errors import SonicskinError
from sonicskin.feature_cache import load_features_cached
from sonicskin.importers import import_spectra, import_wav
from sonicskin.rig import Rig, load_yaml
from sonicskin.sim.generate import simulate_dataset
from sonicskin.sim.scenario import Scenario

QUIET = {"log": lambda *_: None}


def one_line(exc: BaseException) -> str:
    msg = str(exc)
    assert isinstance(exc, (SonicskinError, ValueError, OSError)), repr(exc)
    assert msg and "\n" not in msg and "Traceback" not in msg, msg
    return msg


@pytest.fixture(scope="module")
def small(tmp_path_factory):
    """A 2-session dataset of the small rig cut into ~6 parts per session (1 s parts)."""
    root = tmp_path_factory.mktemp("integrity")
    (root / "small.yaml").write_text(SMALL_RIG)
    (root / "tiny.yaml").write_text(TINY_SCENARIO)
    sc = Scenario.load(root / "tiny.yaml").replace(sessions=2, part_s=1.0)
    rig = Rig.load(root / "small.yaml")
    simulate_dataset(sc, rig, root / "data", progress=False, log=lambda *_: None)
    return {"root": root, "data": root / "data", "rig": rig, "scenario": sc}


def _copy(src: Path, dst: Path) -> Path:
    shutil.copytree(src, dst, ignore=shutil.ignore_patterns(".cache"))
    return dst


def _rows(path: Path) -> list[list[str]]:
    return [r for r in csv.reader(io.StringIO(path.read_text()))]


def _write_rows(path: Path, rows) -> None:
    buf = io.StringIO()
    csv.writer(buf, lineterminator="\n").writerows(rows)
    path.write_text(buf.getvalue())


def _col(name: str) -> int:
    return list(COLUMNS).index(name)


# -- family 1: dataset manifests ---------------------------------------------------------------------------
def _swap(d: Path, a: str, b: str) -> None:
    tmp = d / "swap.tmp"
    (d / a).rename(tmp)
    (d / b).rename(d / a)
    tmp.rename(d / b)


def _edit_json(path: Path, fn) -> None:
    doc = json.loads(path.read_text())
    fn(doc)
    path.write_text(json.dumps(doc))


def _dataset_mutations(n_parts: int) -> list[tuple[str, object, str]]:
    """(id, mutate(d), what the message must name) for a session s001 of ``n_parts`` parts."""
    out = []
    for k in range(n_parts):
        for ext in ("flac", "csv"):
            out.append((f"delete part {k} {ext}", lambda d, k=k, ext=ext: (d / "s001" / f"part-{k:05d}.{ext}").unlink(),
                        f"part-{k:05d}"))
    for k in range(n_parts - 1):
        for exts in (("flac", "csv"), ("flac",), ("csv",)):
            def swap(d, k=k, exts=exts):
                for ext in exts:
                    _swap(d / "s001", f"part-{k:05d}.{ext}", f"part-{k + 1:05d}.{ext}")
            out.append((f"swap parts {k},{k + 1} {'+'.join(exts)}", swap, f"part-{k:05d}"))

    def dup_row(d, i):
        p = d / "s001" / "part-00001.csv"
        rows = _rows(p)
        r = list(rows[1 + i % (len(rows) - 1)])
        r[_col("location")] = "2" if r[_col("location")] != "2" else "0"  # the same chirp labelled again, otherwise
        rows.insert(2 + i % (len(rows) - 1), r)
        _write_rows(p, rows)

    def del_row(d, i):
        p = d / "s001" / "part-00001.csv"
        rows = _rows(p)
        del rows[1 + i % (len(rows) - 1)]
        _write_rows(p, rows)

    for i in range(4):
        out.append((f"duplicate row {i}", lambda d, i=i: dup_row(d, i), "part-00001.csv"))
        out.append((f"delete row {i}", lambda d, i=i: del_row(d, i), "part-00001.csv"))
    out.append(("empty csv", lambda d: (d / "s001" / "part-00002.csv").write_bytes(b""), "part-00002.csv"))
    out.append(("header-only csv", lambda d: (d / "s001" / "part-00002.csv").write_text(",".join(COLUMNS) + "\n"),
                "part-00002.csv"))

    def edit(d, col, value):
        p = d / "s001" / "part-00000.csv"
        rows = _rows(p)
        rows[3][_col(col)] = value
        _write_rows(p, rows)

    for col, value in [("location", "1"), ("location", "-7"), ("force_n", "inf"), ("force_n", "-5"), ("force_n", "1e300"),
                       ("moving", "2.5"), ("t_s", "0.5"), ("time_s", "nan"), ("subject", "3"), ("segment", "touch"),
                       ("x_cm", "1e9"), ("temperature_c", "30")]:
        out.append((f"edit {col}={value}", lambda d, c=col, v=value: edit(d, c, v), "part-00000.csv"))
    out.append(("truncate flac", lambda d: (d / "s001" / "part-00001.flac").write_bytes(
        (d / "s001" / "part-00001.flac").read_bytes()[:500]), "part-00001.flac"))
    out.append(("extra part", lambda d: [shutil.copy(d / "s001" / f"part-00000.{e}", d / "s001" / f"part-{n_parts:05d}.{e}")
                                         for e in ("flac", "csv")], f"part-{n_parts:05d}"))
    out.append(("part from the other session", lambda d: [shutil.copy(d / "s000" / f"part-00001.{e}", d / "s001" / f"part-00001.{e}")
                                                         for e in ("flac", "csv")], "part-00001"))
    meta_edits = {
        "n_chirp 1023": lambda m: m["rig"].update(n_chirp=1023),
        "f_lo_hz 21000": lambda m: m["rig"].update(f_lo_hz=21000.0),
        "pwm_hz": lambda m: m["rig"].update(pwm_hz=[30000.0]),
        "layout moved": lambda m: m["layout"]["xy_cm"][0].__setitem__(0, m["layout"]["xy_cm"][0][0] + 1.5),
        "layout ids permuted": lambda m: m["layout"].update(ids=m["layout"]["ids"][::-1]),
        "source edited": lambda m: m["source"].update(kind="recorder"),
    }
    for name, fn in meta_edits.items():
        out.append((f"dataset.json {name}", lambda d, fn=fn: _edit_json(d / "dataset.json", fn), "session.json"))

    def dup_key(d, key):
        text = (d / "dataset.json").read_text()
        doc = json.loads(text)
        (d / "dataset.json").write_text(text.rstrip()[:-1] + f', "{key}": {json.dumps(doc[key])}}}')
    for key in ("layout", "rig", "format"):
        out.append((f"dataset.json duplicated {key}", lambda d, key=key: dup_key(d, key), "appears twice"))
    sj = {
        "chirps count": lambda j: j["parts"][1].update(chirps=j["parts"][1]["chirps"] + 1),
        "flac hash": lambda j: j["parts"][0].update(flac_sha256="0" * 64),
        "csv hash": lambda j: j["parts"][0].update(csv_sha256="f" * 64),
        "n_chirps": lambda j: j.update(n_chirps=j["n_chirps"] - 1),
        "dataset digest": lambda j: j.update(dataset_sha256="1" * 64),
        "part dropped": lambda j: j["parts"].pop(),
        "parts reordered": lambda j: j["parts"].reverse(),
        "complete false": lambda j: j.update(complete=False),
        "manifest version": lambda j: j.update(manifest=2),
        "hash not hex": lambda j: j["parts"][0].update(flac_sha256="../../etc/passwd"),
    }
    for name, fn in sj.items():
        out.append((f"session.json {name}", lambda d, fn=fn: _edit_json(d / "s001" / "session.json", fn), "session.json"))
    out.append(("session.json duplicated key", lambda d: (d / "s001" / "session.json").write_text(
        (d / "s001" / "session.json").read_text().rstrip()[:-1] + ', "complete": true}'), "appears twice"))
    return out


N_PARTS = 6  # parts of session s001 of the `small` dataset (checked in the test)
DATASET_MUTATIONS = _dataset_mutations(N_PARTS)
CORPUS = {"dataset (manifest)": len(DATASET_MUTATIONS)}


def _read_all(d: Path):
    ds = Dataset(d)
    return [ds.read_session(s) for s in ds.sessions]


@pytest.mark.parametrize("name, mutate, names", DATASET_MUTATIONS, ids=[m[0] for m in DATASET_MUTATIONS])
def test_dataset_mutation_is_refused_with_one_line(small, tmp_path, name, mutate, names):
    assert len(Dataset(small["data"]).parts("s001")) == N_PARTS
    d = _copy(small["data"], tmp_path / "d")
    mutate(d)
    with pytest.raises(SonicskinError) as e:
        _read_all(d)
    msg = one_line(e.value)
    assert names in msg, msg


def test_a_refused_dataset_is_one_line_through_the_cli(small, tmp_path, capsys):
    d = _copy(small["data"], tmp_path / "d")
    (d / "s001" / "part-00002.flac").unlink()  # the first example: a middle part deleted
    code, _, err = run(capsys, ["fit-svm", "--data", d, "--out", tmp_path / "art", "--mode", "absolute", "--n-bins", "20"])
    line = assert_one_line_error(code, err, "fit-svm")
    assert "part-00002.flac is missing but session.json lists it (6 parts)" in line
    assert not (tmp_path / "art").exists()


# -- family 2: label rows of unfinished sessions (no manifest) ------------------------------------------------
def _unfinished_mutations() -> list[tuple[str, object, str]]:
    out = []

    def rows_of(d, k=1):
        return d / "s001" / f"part-{k:05d}.csv"

    def dup(d, i):
        p = rows_of(d)
        rows = _rows(p)
        rows.insert(2 + i, list(rows[1 + i]))
        _write_rows(p, rows)

    def delete(d, i):
        p = rows_of(d)
        rows = _rows(p)
        del rows[1 + i]
        _write_rows(p, rows)

    def renumbered_delete(d, i):  # a row of the last part deleted and the chirp numbers closed up: the stream skips one
        p = rows_of(d, N_PARTS - 1)
        rows = _rows(p)
        del rows[1 + i]
        for r in rows[2 + i - 1:]:
            r[_col("chirp")] = str(int(r[_col("chirp")]) - 1)
        _write_rows(p, rows)

    for i in range(3):
        out.append((f"duplicate row {i}", lambda d, i=i: dup(d, i), "labelled twice"))
        out.append((f"delete row {i}", lambda d, i=i: delete(d, i), "has no label row"))
        out.append((f"delete row {i} and renumber", lambda d, i=i: renumbered_delete(d, i), "a label row was removed"))
    for k in range(N_PARTS - 1):  # a part deleted before later ones: damage, not an interruption
        out.append((f"delete middle part {k} flac", lambda d, k=k: (d / "s001" / f"part-{k:05d}.flac").unlink(), "is missing but"))
        out.append((f"delete middle part {k} csv", lambda d, k=k: (d / "s001" / f"part-{k:05d}.csv").unlink(), "is missing but"))
    for k in range(N_PARTS - 1):
        def swap(d, k=k):
            for ext in ("flac", "csv"):
                _swap(d / "s001", f"part-{k:05d}.{ext}", f"part-{k + 1:05d}.{ext}")
        out.append((f"swap parts {k},{k + 1}", swap, "expected"))
    bad_values = [("location", "-7"), ("location", "99"), ("force_n", "inf"), ("force_n", "-5"), ("force_n", "1e300"),
                  ("moving", "2.5"), ("moving", "-0.1"), ("moving", "nan"), ("t_s", "nan"), ("time_s", "inf"),
                  ("subject", "-1"), ("segment", "dance"), ("x_cm", "inf"), ("temperature_c", "1000"), ("chirp", "-1"),
                  ("location", "1.5"), ("subject", "abc")]
    for col, value in bad_values:
        def edit(d, col=col, value=value):
            p = rows_of(d, 0)
            rows = _rows(p)
            rows[2][_col(col)] = value
            _write_rows(p, rows)
        out.append((f"{col}={value}", edit, "part-00000.csv" if col in ("location", "subject") and value in ("1.5", "abc")
                    else col))
    return out


UNFINISHED_MUTATIONS = _unfinished_mutations()
CORPUS["dataset (label rows, unfinished session)"] = len(UNFINISHED_MUTATIONS)


@pytest.mark.parametrize("name, mutate, words", UNFINISHED_MUTATIONS, ids=[m[0] for m in UNFINISHED_MUTATIONS])
def test_label_rows_are_checked_without_a_manifest(small, tmp_path, name, mutate, words):
    d = _copy(small["data"], tmp_path / "d")
    (d / "s001" / "session.json").unlink()  # an interrupted recording: no manifest, the rows alone
    mutate(d)
    with pytest.raises(SonicskinError) as e:
        Dataset(d).read_session("s001")
    msg = one_line(e.value)
    assert words in msg, msg


def test_unfinished_and_old_sessions_are_read_correctly(small, tmp_path):
    """Handled correctly rather than refused: a session without session.json is read up to its first gap,
    and a dataset of the format before manifests reads with one warning and the same frames."""
    full_frames, full_lab = Dataset(small["data"]).read_session("s001")
    d = _copy(small["data"], tmp_path / "d")
    (d / "s001" / "session.json").unlink()
    for k in range(4, N_PARTS):  # a run killed while writing part 3: its FLAC is there, its CSV is not
        for ext in ("flac", "csv"):
            (d / "s001" / f"part-{k:05d}.{ext}").unlink()
    (d / "s001" / "part-00003.csv").unlink()
    frames, lab = Dataset(d).read_session("s001")
    n3 = sum(len(_rows(d / "s001" / f"part-{k:05d}.csv")) - 1 for k in range(3))
    n = frames.shape[0]  # the last labelled chirp of part 2 may run on into part 3: it is dropped
    assert n in (n3 - 1, n3) and np.array_equal(frames, full_frames[:n])
    np.testing.assert_array_equal(lab["location"], full_lab["location"][:n])
    old = _copy(small["data"], tmp_path / "old")
    for s in ("s000", "s001"):
        info = json.loads((old / s / "session.json").read_text())
        (old / s / "session.json").write_text(json.dumps({"complete": True, "n_chirps": info["n_chirps"]}))
    with pytest.warns(UserWarning, match="older sonicskin.*label rows only"):
        frames, lab = Dataset(old).read_session("s001")
    assert np.array_equal(frames, full_frames) and np.array_equal(lab["force_n"], full_lab["force_n"], equal_nan=True)


def test_manifest_binds_what_the_writer_wrote(small):
    d = small["data"]
    info = json.loads((d / "s001" / "session.json").read_text())
    import hashlib

    assert info["complete"] is True and info["manifest"] == 1 and len(info["parts"]) == N_PARTS
    for k, e in enumerate(info["parts"]):
        assert e["part"] == f"part-{k:05d}"
        assert e["flac_sha256"] == hashlib.sha256((d / "s001" / f"part-{k:05d}.flac").read_bytes()).hexdigest()
        assert e["csv_sha256"] == hashlib.sha256((d / "s001" / f"part-{k:05d}.csv").read_bytes()).hexdigest()
        assert e["chirps"] == len(_rows(d / "s001" / f"part-{k:05d}.csv")) - 1
    assert info["n_chirps"] == sum(e["chirps"] for e in info["parts"]) == Dataset(d).read_session("s001")[0].shape[0] + 0 * 1
    assert info["dataset_sha256"] == Dataset(d).meta_sha256


def test_writer_refuses_bad_labels_and_unsafe_names(small, tmp_path):
    ds = Dataset(small["data"])
    w = DatasetWriter(tmp_path / "w", ds.rig, ds.layout)
    n = 3
    good = {"chirp": np.arange(n), "t_s": np.arange(n) * 0.01, "time_s": np.arange(n) * 0.01, "segment": np.array(["gap"] * n),
            "location": np.full(n, -1), "x_cm": np.full(n, np.nan), "y_cm": np.full(n, np.nan), "force_n": np.zeros(n),
            "moving": np.zeros(n), "temperature_c": np.full(n, 23.0), "subject": np.zeros(n, int)}
    audio = np.zeros(4000, np.float32)
    for name in ("../x", "/abs", "", ".", "..", "a/b", ".hidden", "x" * 65, "a b", "s0\x00"):
        with pytest.raises(DatasetError, match="not a plain name"):
            w.write_part(name, 0, audio, good)
    assert sorted(p.name for p in (tmp_path / "w").iterdir()) == ["dataset.json"] and not (tmp_path / "x").exists()
    with pytest.raises(DatasetError, match=r"force_n = inf"):
        w.write_part("s000", 0, audio, {**good, "force_n": np.array([0, np.inf, 0])})
    with pytest.raises(DatasetError, match="NaN, inf"):
        w.write_part("s000", 0, np.full(10, np.nan, np.float32), good)
    assert check_name("s000") == "s000" and check_name("run-1.a_b") == "run-1.a_b"


# -- family 3: the feature cache -------------------------------------------------------------------------------
def _cache_mutations():
    def rewrite(path: Path, **changes):
        with np.load(path, allow_pickle=False) as z:
            arrays = {k: z[k] for k in z.files}
        for k, v in changes.items():
            if v is None:
                arrays.pop(k)
            else:
                arrays[k] = v(arrays) if callable(v) else v
        np.savez(path, **arrays)

    return [
        ("one label short", lambda p: rewrite(p, label_location=lambda a: a["label_location"][:-1])),
        ("X one row short", lambda p: rewrite(p, X=lambda a: a["X"][:-1])),
        ("X narrower", lambda p: rewrite(p, X=lambda a: a["X"][:, :-1])),
        ("X with NaN", lambda p: rewrite(p, X=lambda a: np.where(np.arange(a["X"].shape[1]) == 3, np.nan, a["X"]))),
        ("label column missing", lambda p: rewrite(p, label_force_n=None)),
        ("key of other data", lambda p: rewrite(p, key=np.array("0" * 64))),
        ("key missing", lambda p: rewrite(p, key=None)),
        ("labels stale (location edited)", lambda p: rewrite(p, label_location=lambda a: np.where(a["label_location"] >= 0,
                                                                                                 0, -1), key=None)),
        ("truncated", lambda p: p.write_bytes(p.read_bytes()[:200])),
        ("garbage", lambda p: p.write_bytes(b"not a zip at all" * 10)),
        ("empty", lambda p: p.write_bytes(b"")),
        ("object array", lambda p: rewrite(p, label_segment=lambda a: a["label_segment"].astype(object))),
        ("location as text", lambda p: rewrite(p, label_location=lambda a: a["label_location"].astype(str))),
    ]


CACHE_MUTATIONS = _cache_mutations()
CORPUS["feature cache"] = len(CACHE_MUTATIONS) + 2  # + the label edit and the replaced part below


@pytest.fixture(scope="module")
def cached(small, tmp_path_factory):
    d = _copy(small["data"], tmp_path_factory.mktemp("cache") / "d")
    t = load_features_cached(Dataset(d), progress=False)
    (cache,) = (d / ".cache").glob("features-*.npz")
    return d, t, cache.read_bytes(), cache.name


@pytest.mark.parametrize("name, mutate", CACHE_MUTATIONS, ids=[m[0] for m in CACHE_MUTATIONS])
def test_a_bad_feature_cache_is_rebuilt(cached, tmp_path, name, mutate):
    src, want, data, cname = cached
    d = _copy(src, tmp_path / "d")
    (d / ".cache").mkdir()
    path = d / ".cache" / cname
    path.write_bytes(data)
    if name == "object array":
        with np.load(path, allow_pickle=False) as z:
            arrays = {k: z[k] for k in z.files}
        arrays["label_segment"] = arrays["label_segment"].astype(object)
        np.savez(path, **arrays)  # stored as a pickle
    else:
        mutate(path)
    got = load_features_cached(Dataset(d), progress=False)
    np.testing.assert_array_equal(got.X, want.X)
    for k in want.labels:
        np.testing.assert_array_equal(got[k], want[k])
    again = FeatureTable.load_npz(path)  # rewritten whole
    assert len(again) == len(want)


def test_a_label_edit_or_a_replaced_part_invalidates_the_cache(small, tmp_path):
    """The issue's stale-label case: after a label edit fit-svm trained on the old labels."""
    d = _copy(small["data"], tmp_path / "d")
    (d / "s001" / "session.json").unlink()  # an unfinished session: its CSV may be edited and still read
    before = load_features_cached(Dataset(d), progress=False)
    p = next(p for p in sorted((d / "s001").glob("part-*.csv")) if any(r[_col("location")] == "0" for r in _rows(p)[1:]))
    rows = _rows(p)
    k = next(i for i, r in enumerate(rows[1:], 1) if r[_col("location")] == "0")
    rows[k][_col("location")] = "2"
    st = p.stat()
    _write_rows(p, rows)
    import os

    os.utime(p, ns=(st.st_atime_ns, st.st_mtime_ns))  # the same mtime: only the content tells
    after = load_features_cached(Dataset(d), progress=False)
    changed = np.flatnonzero(before["location"] != after["location"])
    assert changed.size == 1 and after["location"][changed[0]] == 2
    assert len(list((d / ".cache").glob("features-*.npz"))) == 1
    # A part's audio replaced (its mtime kept): the content key changes, the features follow the new audio.
    f0 = d / "s000" / "part-00000.flac"
    st = f0.stat()
    x = sf.read(f0)[0]
    sf.write(f0, 0.5 * x, int(small["rig"].fs_hz), format="FLAC", subtype="PCM_24")
    os.utime(f0, ns=(st.st_atime_ns, st.st_mtime_ns))
    with pytest.raises(DatasetError, match="part-00000.flac does not match its sha256"):  # the manifest refuses it
        load_features_cached(Dataset(d), progress=False)
    (d / "s000" / "session.json").unlink()
    halved = load_features_cached(Dataset(d), progress=False)
    first = np.flatnonzero(halved["session"] == "s000")[:5]
    diff = halved.X[first] - after.X[first]  # -6.02 dB, up to 24-bit quantisation in the quietest bins
    assert abs(np.median(diff) - 20 * np.log10(0.5)) < 0.02 and np.all(np.abs(diff - 20 * np.log10(0.5)) < 1.0)


# -- family 4: import-spectra ------------------------------------------------------------------------------------
def _table(n=60, **over):
    rng = np.random.default_rng(0)
    f = np.arange(23, 188) * 48000 / 450
    loc = np.tile([0, 1, 2, -1], n // 4)
    z = {"freqs_hz": f, "magnitude_db": -40 + 3 * rng.standard_normal((n, f.size)) + 5 * (loc[:, None] >= 0),
         "location": loc, "session": np.array(["a"] * (n // 2) + ["b"] * (n - n // 2)), "force_n": np.where(loc >= 0, 2.0, 0.0),
         "moving": np.zeros(n), "subject": np.zeros(n, int), "x_cm": np.where(loc >= 0, loc * 1.0, np.nan),
         "y_cm": np.where(loc >= 0, 0.0, np.nan)}
    z.update(over)
    return z


def _with(col, k, v):
    def fn(z):
        a = np.array(z[col], dtype=float if not isinstance(v, str) else object)
        a[k] = v
        z[col] = a.astype(str) if isinstance(v, str) else a
    return fn


SPECTRA_MUTATIONS = [(f"session {name!r}", _with("session", 3, name), "not a plain name")
                     for name in ("../x", "/tmp/abs", "", ".", "..", "a/b", ".hidden", "x" * 65, "a b", "..\\x")]
SPECTRA_MUTATIONS += [(f"force {v}", _with("force_n", 1, v), "force_n") for v in (np.inf, -np.inf, 1e300, -5.0, 1e4)]
SPECTRA_MUTATIONS += [(f"subject {v}", _with("subject", 2, v), "subject") for v in (np.nan, -1.0, 1.5, np.inf, 1e20)]
SPECTRA_MUTATIONS += [(f"moving {v}", _with("moving", 2, v), "moving") for v in (2.5, -0.1, np.nan)]
SPECTRA_MUTATIONS += [(f"x_cm {v}", _with("x_cm", 1, v), "x_cm") for v in (np.inf, 1e300)]
SPECTRA_MUTATIONS += [("freqs NaN", _with("freqs_hz", 4, np.nan), "freqs_hz"),
                      ("magnitude inf", lambda z: z["magnitude_db"].__setitem__((0, 0), np.inf), "magnitude_db"),
                      ("session 2-D", lambda z: z.update(session=np.array([["a"]] * 60)), "session"),
                      ("location object", lambda z: z.update(location=np.array([None] * 60, dtype=object)), "location"),
                      ("magnitude 3-D", lambda z: z.update(magnitude_db=z["magnitude_db"][None]), "magnitude_db")]
CORPUS["import-spectra"] = len(SPECTRA_MUTATIONS) + 4  # + the header checks and --frame below


@pytest.mark.parametrize("name, mutate, words", SPECTRA_MUTATIONS, ids=[m[0] for m in SPECTRA_MUTATIONS])
def test_import_spectra_mutation_is_refused(tmp_path, name, mutate, words):
    z = _table()
    mutate(z)
    table = tmp_path / "t.npz"
    np.savez(table, **z)
    out = tmp_path / "out"
    with pytest.raises((SonicskinError, ValueError)) as e:
        import_spectra(table, out, **QUIET)
    assert words in one_line(e.value)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["t.npz"]  # nothing written, nowhere


def _npz_member_with_header(shape, dtype="<f8") -> bytes:
    """An .npy member whose header claims ``shape`` but holds 16 bytes of data."""
    header = repr({"descr": dtype, "fortran_order": False, "shape": tuple(shape)}).encode()
    header += b" " * (64 - (10 + len(header) + 1) % 64) + b"\n"
    return b"\x93NUMPY\x01\x00" + struct.pack("<H", len(header)) + header + b"\0" * 16


def test_import_spectra_reads_only_what_it_needs(tmp_path, capsys):
    """An unused array that claims 8 TB is never read; a needed one is checked from its header."""
    table = tmp_path / "t.npz"
    np.savez(table, **_table())
    with zipfile.ZipFile(table, "a") as zf:
        zf.writestr("junk.npy", _npz_member_with_header((10**12,)))
    ds = Dataset(import_spectra(table, tmp_path / "ok", **QUIET))
    assert ds.sessions == ["a", "b"]
    z = _table()
    del z["force_n"]
    np.savez(table, **z)
    with zipfile.ZipFile(table, "a") as zf:
        zf.writestr("force_n.npy", _npz_member_with_header((10**12,)))
    with pytest.raises(DatasetError, match="array 'force_n' is cut short"):
        import_spectra(table, tmp_path / "bad", **QUIET)
    code, _, err = run(capsys, ["import-spectra", "--table", table, "--out", tmp_path / "bad"])
    assert "force_n" in assert_one_line_error(code, err, "import-spectra")
    np.savez(table, **_table())
    code, _, err = run(capsys, ["import-spectra", "--table", table, "--out", tmp_path / "bad", "--frame", "1000000000000"])
    assert "fs_hz must be in (0, 1e+07] Hz" in assert_one_line_error(code, err, "import-spectra")
    code, _, err = run(capsys, ["import-spectra", "--table", table, "--out", tmp_path / "bad", "--fs", "1e12"])
    assert_one_line_error(code, err, "import-spectra")
    assert not (tmp_path / "bad").exists()


# -- family 5: import-wav ----------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def wavs(small, tmp_path_factory):
    """The `small` dataset as two WAV recordings with an interval CSV."""
    root = tmp_path_factory.mktemp("wavs")
    ds = Dataset(small["data"])
    (root / "rec").mkdir()
    rows = [["file", "start_s", "end_s", "location", "x_cm", "y_cm", "force_n", "moving", "subject"]]
    durations = {}
    for s in ds.sessions:
        audio = np.concatenate([sf.read(ds.root / s / f"part-{p:05d}.flac", dtype="float32")[0] for p in ds.parts(s)])
        sf.write(root / "rec" / f"{s}.wav", audio, int(ds.rig.fs_hz), subtype="FLOAT")
        durations[f"{s}.wav"] = audio.size / ds.rig.fs_hz
        _, lab = ds.read_session(s)
        for v in range(3):
            k = np.flatnonzero(lab["location"] == v)
            rows.append([f"{s}.wav", f"{lab['t_s'][k[0]] - 0.002:.6f}", f"{lab['t_s'][k[-1]] + 0.002:.6f}", v, "", "", 2.0, 0, 0])
    _write_rows(root / "labels.csv", rows)
    return {"root": root, "rig": ds.rig, "rows": rows, "durations": durations}


def _wav_mutations():
    out = []

    def cell(i, col, v):
        def fn(root, rows):
            rows[i][rows[0].index(col)] = v
        return fn

    for col, v, words in [("force_n", "inf", "force_n"), ("force_n", "-5", "force_n"), ("force_n", "1e300", "force_n"),
                          ("moving", "2.5", "moving"), ("moving", "nan", "moving"), ("subject", "-1", "subject"),
                          ("subject", "nan", "line 2"), ("start_s", "-1", "start_s"), ("start_s", "nan", "start_s"),
                          ("end_s", "inf", "start_s"), ("x_cm", "inf", "x_cm"), ("end_s", "1e6", "past the end"),
                          ("start_s", "1e5", "line 2")]:
        out.append((f"{col}={v}", cell(1, col, v), words))

    def overlap(root, rows):  # the second interval starts inside the first, at another marker
        rows[2][1] = f"{(float(rows[1][1]) + float(rows[1][2])) / 2:.6f}"
    out.append(("overlapping intervals, different markers", overlap, "overlap with different labels"))

    def past_end(root, rows):
        rows.append([rows[1][0], "1.0", "1000.0", "1", "", "", "2", "0", "0"])
    out.append(("interval past the end", past_end, "past the end"))

    def silent(root, rows):
        f = root / "rec" / "s000.wav"
        sf.write(f, np.zeros(sf.info(f).frames, np.float32), sf.info(f).samplerate, subtype="FLOAT")
    out.append(("silent recording", silent, "silent"))

    def header_30(root, rows):
        f = root / "rec" / "s001.wav"
        f.write_bytes(f.read_bytes()[:30])
    out.append(("WAV header cut to 30 bytes", header_30, "s001.wav"))

    def nan_wav(root, rows):
        f = root / "rec" / "s001.wav"
        x, sr = sf.read(f, dtype="float32")
        x[100] = np.nan
        sf.write(f, x, sr, subtype="FLOAT")
    out.append(("float WAV with NaN", nan_wav, "NaN"))

    def garbage_wav(root, rows):
        (root / "rec" / "s001.wav").write_bytes(b"RIFF" + b"\xff" * 100)
    out.append(("garbage WAV", garbage_wav, "s001.wav"))

    def binary_csv(root, rows):
        rows.clear()
    out.append(("labels not UTF-8", binary_csv, "UTF-8"))
    return out


WAV_MUTATIONS = _wav_mutations()
CORPUS["import-wav"] = len(WAV_MUTATIONS) + 1  # + the NaN sweep below


@pytest.mark.parametrize("name, mutate, words", WAV_MUTATIONS, ids=[m[0] for m in WAV_MUTATIONS])
def test_import_wav_mutation_is_refused(wavs, tmp_path, name, mutate, words):
    root = tmp_path / "in"
    shutil.copytree(wavs["root"], root)
    rows = [list(r) for r in wavs["rows"]]
    mutate(root, rows)
    if rows:
        _write_rows(root / "labels.csv", rows)
    else:
        (root / "labels.csv").write_bytes(b"file,start_s\n\xff\xfe\x00bad")
    rig = wavs["rig"]
    with pytest.raises((SonicskinError, ValueError)) as e:
        import_wav(root / "rec", root / "labels.csv", tmp_path / "out", chirp_hz=(rig.f_lo_hz, rig.f_hi_hz),
                   period_s=rig.period_s, amplitude=rig.amplitude, **QUIET)
    assert words in one_line(e.value)
    assert not (tmp_path / "out").exists() and not list(tmp_path.glob(".out*"))


def test_import_wav_round_trip_and_nan_sweep(wavs, tmp_path, capsys):
    rig = wavs["rig"]
    out = import_wav(wavs["root"] / "rec", wavs["root"] / "labels.csv", tmp_path / "ok", chirp_hz=(rig.f_lo_hz, rig.f_hi_hz),
                     period_s=rig.period_s, amplitude=rig.amplitude, **QUIET)
    assert Dataset(out).sessions == ["s000", "s001"]
    from sonicskin.dsp import rig_chirp

    sweep = rig_chirp(rig).astype(np.float32)
    sweep[5] = np.nan
    sf.write(tmp_path / "sweep.wav", sweep, int(rig.fs_hz), subtype="FLOAT")
    code, _, err = run(capsys, ["import-wav", "--wav-dir", wavs["root"] / "rec", "--labels", wavs["root"] / "labels.csv",
                                "--sweep", tmp_path / "sweep.wav", "--out", tmp_path / "bad"])
    assert "NaN" in assert_one_line_error(code, err, "import-wav")


# -- family 6: sizes and config files ------------------------------------------------------------------------------
BAD_YAML = {
    "syntax: unclosed bracket": "name: x\nlayout: {kind: grid\n",
    "syntax: bad indent": "name: x\n  fs_hz: 1\n fs: 2\n",
    "syntax: tab": "name: x\n\tfs_hz: 1\n",
    "python object": "!!python/object:collections.OrderedDict {}\n",
    "python apply": "name: !!python/object/apply:os.system ['true']\n",
    "python name": "name: !!python/name:os.system\n",
    "python tuple": "pwm_hz: !!python/tuple [1, 2]\n",
    "unknown tag": "name: !custom x\n",
    "duplicated key": "name: a\nfs_hz: 192000\nfs_hz: 48000\n",
    "top-level list": "- 1\n- 2\n",
    "top-level text": "hello\n",
    "empty": "",
    "not UTF-8": b"name: \xff\xfe\n",
    "binary": b"\x00\x01\x02\x03",
}
CORPUS["config files (rig and scenario YAML)"] = 2 * len(BAD_YAML)


@pytest.mark.parametrize("kind", ["rig", "scenario"])
@pytest.mark.parametrize("name", sorted(BAD_YAML))
def test_bad_yaml_is_one_line(tmp_path, capsys, kind, name):
    text = BAD_YAML[name]
    f = tmp_path / "bad.yaml"
    f.write_bytes(text if isinstance(text, bytes) else text.encode())
    with pytest.raises(SonicskinError) as e:
        load_yaml(f)
    msg = one_line(e.value)
    assert str(f) in msg
    if name.startswith("python"):
        assert "plain values only" in msg and not (tmp_path / "pwned").exists()
    if name == "duplicated key":
        assert "'fs_hz' appears twice" in msg
    argv = ["simulate", "--out", tmp_path / "o", f"--{kind}", f]
    code, _, err = run(capsys, argv)
    assert_one_line_error(code, err, "simulate")
    assert not (tmp_path / "o").exists()


SIZE_CASES = [
    (["simulate", "--sessions", "1000000000"], "sessions"),
    (["simulate", "--set", "touch_s=1.0e+12"], "shorten the scenario"),
    (["simulate", "--set", "gap_s=1.0e+9"], "shorten the scenario"),
    (["simulate", "--set", "moving_s=1.0e+12", "--set", "motion={enabled: true}"], "shorten the scenario"),
    (["simulate", "--set", "repeats=100000000"], "shorten the scenario"),
    (["simulate", "--set", "layout={kind: grid, nx: 100000, ny: 100000, spacing_cm: 1}"], "markers"),
    (["simulate", "--set", "motion={enabled: true, level: 3}"], "motion.level"),
    (["simulate", "--set", "geometry=[1, 2]"], "geometry"),
    (["record", "--moving-s", "1e9", "--fast"], "record shorter prompts"),
    (["record", "--touch-s", "1e12", "--fast"], "record shorter prompts"),
    (["record", "--calibration-s", "1e15", "--fast"], "record shorter prompts"),
]
CORPUS["sizes (simulate, record, import-spectra --frame/--fs)"] = len(SIZE_CASES) + 2


@pytest.mark.parametrize("argv, words", SIZE_CASES, ids=[" ".join(a) for a, _ in SIZE_CASES])
def test_sizes_beyond_the_machine_are_refused_before_allocating(small, tmp_path, capsys, argv, words):
    code, _, err = run(capsys, [*argv, "--out", tmp_path / "o", "--rig", small["root"] / "small.yaml",
                                "--scenario", small["root"] / "tiny.yaml"])
    line = assert_one_line_error(code, err, argv[0])  # how long the refusal takes: benchmarks/bench_input_checks.py
    assert words in line, line
    assert not (tmp_path / "o").exists()


def test_rig_bounds(tmp_path):
    for kw, words in [({"n_chirp": 10**12}, "n_chirp must be 64..4194304"), ({"fs_hz": float("inf")}, "finite"),
                      ({"fs_hz": 1e12}, "fs_hz must be in"), ({"pwm_hz": ["x"]}, "pwm_hz"), ({"amplitude": "0.5"}, "amplitude")]:
        with pytest.raises(ValueError, match=words):
            Rig(**kw)


def test_corpus_counts(capsys):
    """The corpus sizes the README quotes (printed with -s)."""
    total = sum(CORPUS.values())
    with capsys.disabled():
        for k, v in CORPUS.items():
            print(f"  {k}: {v}")
        print(f"  total: {total}")
    assert total >= 150


@pytest.mark.parametrize("name", ["two-points", "moving", "multi-person"])
def test_the_size_estimate_counts_the_chirps_build_timeline_makes(name):
    """check_size's count is exact (it is what the memory estimate rests on), also with train_repeats."""
    from sonicskin.sim.scenario import build_timeline, check_size

    rig = Rig.load("jaco")
    for sc in (Scenario.load(name), Scenario.load(name).replace(train_repeats=2, sessions=2)):
        assert check_size(sc, rig) == len(build_timeline(sc, rig))
