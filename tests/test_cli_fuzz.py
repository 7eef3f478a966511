"""Fuzz-style tests of issue 9.5: malformed command lines, dataset files and artifact files are refused
with exit code 2 and one message line, no traceback, and nothing half-made left behind.

Every generated input is malformed by construction (at least one part of it cannot be valid), so an
exit code 0 is a failure too.  The counters at the bottom report how many inputs were tried.
"""

from __future__ import annotations

import json
import shutil
import tempfile
from collections import Counter
from pathlib import Path

import numpy as np
import pytest
from cli_helpers import assert_one_line_error
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from sonicskin.cli import build_parser, main

TRIED: Counter = Counter()
FUZZ = settings(deadline=None, derandomize=True, suppress_health_check=list(HealthCheck))

BAD_VALUES = ["-1", "0", "-0.5", "nan", "inf", "-inf", "abc", "", " ", "1e999", "99999999999999999999", "1.5.2",
              "../../etc/passwd", "/nonexistent/x", "a=b", "=", "{", "[1,", "ünïcode", "host:", ":80000", "70000",
              "s999", "--", "-", "0x10", "1,2", "true"]


def _run(argv, capsys):
    capsys.readouterr()
    code = main([str(a) for a in argv])
    _, err = capsys.readouterr()
    return code, err


def _tree(root: Path) -> list[str]:
    return sorted(str(p.relative_to(root)) for p in root.rglob("*"))


def _options(verb: str) -> list[str]:
    sp = build_parser()._subparsers._group_actions[0].choices[verb]
    return [a.option_strings[-1] for a in sp._actions if a.option_strings and a.dest != "help"]


# -- command lines ----------------------------------------------------------------------------------------
# Each verb gets a base that fails before any work (a missing or malformed input), plus random options with
# malformed values; whichever error is reported, it must be one clean line.
def _base(verb: str, d: Path) -> list[str]:
    listjson = d / "listdata"
    return {
        "simulate": ["--scenario", "no-such-scenario", "--out", d / "out"],
        "record": ["--out", d / "out", "--scenario", "no-such-scenario"],
        "import-wav": ["--wav-dir", d / "nowav", "--labels", d / "nolabels.csv", "--out", d / "out"],
        "import-spectra": ["--table", d / "no.npz", "--out", d / "out"],
        "evaluate": ["--data", listjson, "--out", d / "out"],
        "fit-svm": ["--data", listjson, "--out", d / "out"],
        "train": ["--data", listjson, "--trainer.default_root_dir", d / "out"],
        "export": ["--run", d / "norun", "--out", d / "out"],
        "compare": ["--data", listjson, "--artifact", d / "noart", "--out", d / "out"],
        "live": ["--artifact", d / "noart", "--fast"],
        "info": ["--rig", "no-such-rig"],
        "reproduce": ["--out", d / "out", "--no-such-flag"],
    }[verb]


VERBS = ["simulate", "record", "import-wav", "import-spectra", "evaluate", "fit-svm", "train", "export", "compare",
         "live", "info", "reproduce"]


@st.composite
def command_lines(draw):
    verb = draw(st.sampled_from(VERBS))
    opts = _options(verb)
    extra = []
    for _ in range(draw(st.integers(0, 3))):
        opt = draw(st.sampled_from(opts))
        value = draw(st.one_of(st.sampled_from(BAD_VALUES), st.text(alphabet=st.characters(
            blacklist_categories=("Cs", "Cc")), max_size=8)))
        extra += [opt, value] if not opt.startswith("--no-") and opt not in ("--fast", "--quiet", "--overwrite",
                                                                             "--resume", "--quick") else [opt]
    pos = draw(st.integers(0, len(extra)))
    return verb, extra[:pos], extra[pos:]


@pytest.mark.slow
@settings(FUZZ, max_examples=100)
@given(command_lines())
def test_malformed_command_lines(capsys, monkeypatch, case):
    verb, before, after = case
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        (d / "listdata").mkdir()
        (d / "listdata" / "dataset.json").write_text("[1, 2, 3]")
        argv = [verb, *before, *_base(verb, d), *after]
        with monkeypatch.context() as m:  # back in the old folder before the temporary one goes
            m.chdir(d)
            code, err = _run(argv, capsys)
        assert_one_line_error(code, err)
        assert _tree(d) == ["listdata", "listdata/dataset.json"], argv
    TRIED["command lines"] += 1


# -- dataset files ----------------------------------------------------------------------------------------
NOT_A_NUMBER = st.one_of(st.text(max_size=5), st.booleans(), st.none(), st.lists(st.integers(), max_size=2),
                         st.dictionaries(st.text(max_size=2), st.integers(), max_size=1))
BAD_META = {  # field -> values it can never take
    "format": st.one_of(st.text(max_size=8), st.integers()),
    "version": st.one_of(st.integers(2, 99), st.integers(-5, 0), st.text(max_size=3), st.booleans(), st.none()),
    "rig": st.one_of(st.lists(st.integers(), max_size=3), st.text(max_size=5), st.none(), st.integers()),
    "layout": st.one_of(st.lists(st.integers(), max_size=3), st.text(max_size=5), st.none(), st.integers()),
    "source": st.one_of(st.lists(st.integers(), max_size=2), st.text(max_size=5), st.integers()),
    "rig.fs_hz": st.one_of(NOT_A_NUMBER, st.floats(max_value=0), st.floats(min_value=1e7, exclude_min=True)),
    "rig.n_chirp": st.one_of(NOT_A_NUMBER, st.integers(max_value=63), st.integers(min_value=(1 << 22) + 1),
                             st.floats(64.5, 1e4)),
    "rig.f_lo_hz": st.one_of(NOT_A_NUMBER, st.floats(max_value=0), st.floats(80_000, 1e9)),
    "rig.f_hi_hz": st.one_of(NOT_A_NUMBER, st.floats(max_value=20_000), st.floats(96_001, 1e9)),
    "rig.amplitude": st.one_of(NOT_A_NUMBER, st.floats(max_value=0), st.floats(min_value=1, exclude_min=True)),
    "rig.pwm_hz": st.one_of(st.text(max_size=3), st.integers(), st.lists(st.text(max_size=2), min_size=1, max_size=2)),
    "rig.pwm_halfwidth_hz": st.one_of(NOT_A_NUMBER, st.floats(max_value=0, exclude_max=True)),
    "layout.ids": st.one_of(st.just([]), st.lists(st.text(max_size=2), min_size=1, max_size=3),
                            st.lists(st.integers(max_value=-1), min_size=1, max_size=3), st.just([0, 0, 1]),
                            st.just([0, 1]), st.text(max_size=3), st.none()),
    "layout.xy_cm": st.one_of(st.just([]), st.just([[0, 0]]), st.lists(st.lists(st.text(max_size=2), min_size=2,
                                                                                   max_size=2), min_size=3, max_size=3),
                              st.just([[0, 0, 0], [1, 1, 1], [2, 2, 2]]), st.text(max_size=3), st.none()),
    "layout.circumference_cm": st.one_of(st.text(min_size=1, max_size=3), st.floats(max_value=0), st.booleans()),
}
META_DELETE = ["format", "version", "rig", "layout", "layout.ids", "layout.xy_cm"]
CSV_NUMERIC = ["chirp", "t_s", "time_s", "location", "x_cm", "y_cm", "force_n", "moving", "temperature_c", "subject"]


def _set(doc: dict, dotted: str, value, delete: bool = False) -> None:
    *path, last = dotted.split(".")
    for k in path:
        doc = doc[k]
    if delete:
        del doc[last]
    else:
        doc[last] = value


DATASET_KINDS = ["meta-delete", "meta-doc", "meta-text", "csv-header", "csv-cell", "csv-short-row", "csv-t-shift",
                 "csv-location", "csv-bytes", "flac-bytes", "session-json"]
DATASET_CASES = [("meta-field", f) for f in sorted(BAD_META)] + [(k, None) for k in DATASET_KINDS]


def dataset_mutation(kind: str, field: str | None):
    """Arguments of one malformed-by-construction mutation of ``kind``."""
    if kind == "meta-field":
        return st.tuples(st.just(field), BAD_META[field])
    if kind == "meta-delete":
        return st.sampled_from(META_DELETE)
    if kind == "meta-doc":
        return st.one_of(st.lists(st.integers(), max_size=3), st.integers(), st.text(max_size=5), st.none(),
                         st.floats(allow_nan=False))
    if kind in ("meta-text", "csv-bytes", "flac-bytes"):
        return st.tuples(st.floats(0, 0.98), st.binary(max_size=16))
    if kind == "csv-header":
        return st.tuples(st.integers(0, 10), st.sampled_from(["drop", "rename", "swap"]))
    if kind == "csv-cell":
        bad = st.one_of(st.sampled_from(["abc", "", "1.2.3", "0x", "--1", "1e", "[]"]),
                        st.text(alphabet="xyz!?#", min_size=1, max_size=4))
        return st.tuples(st.sampled_from(CSV_NUMERIC), st.integers(0, 1000), bad)
    if kind == "csv-short-row":
        return st.tuples(st.integers(0, 1000), st.integers(1, 10))  # a blank line is skipped, not an error
    if kind == "csv-t-shift":
        return st.tuples(st.integers(0, 1000), st.floats(0.4, 0.6))  # the reader tolerates 0.25 chirp; labels sit within 0.1
    if kind == "csv-location":
        return st.tuples(st.integers(0, 1000), st.integers(3, 10_000))
    return st.one_of(st.text(max_size=6), st.just("[]"), st.just('{"complete": false}'), st.just("{}"))


def _mutate_dataset(d: Path, kind: str, arg) -> None:
    meta_path, csv_path, flac = d / "dataset.json", d / "s001" / "part-00000.csv", d / "s001" / "part-00000.flac"
    if kind.startswith("meta-"):
        meta = json.loads(meta_path.read_text())
        if kind == "meta-field":
            _set(meta, arg[0], arg[1])
            meta_path.write_text(json.dumps(meta))
        elif kind == "meta-delete":
            _set(meta, arg, None, delete=True)
            meta_path.write_text(json.dumps(meta))
        elif kind == "meta-doc":
            meta_path.write_text(json.dumps(arg))
        else:  # truncated (never complete JSON), then garbage bytes
            text = meta_path.read_bytes().rstrip()
            meta_path.write_bytes(text[: int(arg[0] * (len(text) - 1))] + arg[1])
        return
    if kind in ("csv-bytes", "flac-bytes"):
        path = csv_path if kind == "csv-bytes" else flac
        data = path.read_bytes()
        cut = int(arg[0] * len(data)) if kind == "flac-bytes" else min(int(arg[0] * 40), 40)  # inside the header
        path.write_bytes(data[:cut] + arg[1] + (b"\xff\xfe\x00" if kind == "csv-bytes" else b""))
        return
    if kind == "session-json":
        (d / "s001" / "session.json").write_text(arg)
        return
    rows = [ln.split(",") for ln in csv_path.read_text().splitlines()]
    header, body = rows[0], rows[1:]
    if kind == "csv-header":
        j, how = arg
        if how == "drop":
            header, body = header[:j] + header[j + 1:], [r[:j] + r[j + 1:] for r in body]
        elif how == "rename":
            header[j] = header[j] + "_x"
        else:
            k = (j + 1) % len(header)
            header[j], header[k] = header[k], header[j]
    elif kind == "csv-cell":
        col, i, bad = arg
        body[i % len(body)][header.index(col)] = bad
    elif kind == "csv-short-row":
        i, n = arg
        body[i % len(body)] = body[i % len(body)][:n]
    elif kind == "csv-t-shift":  # a label between two chirps (the chirp period of the small rig is 1024 samples)
        i, frac = arg
        r = body[i % len(body)]
        r[header.index("t_s")] = f"{float(r[header.index('t_s')]) + frac * 1024 / 192000:.9g}"
    elif kind == "csv-location":  # an id the layout does not have
        i, loc = arg
        body[i % len(body)][header.index("location")] = str(loc)
    csv_path.write_text("\n".join(",".join(r) for r in [header, *body]) + "\n")


def _two_sessions(cli_files, tmp: Path) -> Path:
    """A copy of the CLI tests' dataset with its first two sessions, to mutate."""
    d = tmp / "data"
    d.mkdir()
    shutil.copy(cli_files["data"] / "dataset.json", d)
    for s in ("s000", "s001"):
        shutil.copytree(cli_files["data"] / s, d / s)
    return d


@pytest.mark.slow
@pytest.mark.parametrize("kind, field", DATASET_CASES)
@settings(FUZZ, max_examples=4)
@given(data=st.data())
def test_malformed_dataset_files(capsys, cli_files, kind, field, data):
    arg = data.draw(dataset_mutation(kind, field), label="mutation")
    with tempfile.TemporaryDirectory() as tmp:
        d = _two_sessions(cli_files, Path(tmp))
        _mutate_dataset(d, kind, arg)
        out = Path(tmp) / "art"
        code, err = _run(["fit-svm", "--data", d, "--out", out, "--mode", "absolute", "--n-bins", "20"], capsys)
        assert_one_line_error(code, err, "fit-svm")
        assert not out.exists()
    TRIED["dataset files"] += 1
    TRIED[f"dataset files: {kind}"] += 1


# -- artifact files ---------------------------------------------------------------------------------------
@st.composite
def artifact_mutations(draw):
    kind = draw(st.sampled_from(["doc", "text", "delete", "model-file", "onnx-bytes", "sha"]))
    if kind == "doc":
        return kind, draw(st.one_of(st.lists(st.integers(), max_size=3), st.integers(), st.text(max_size=5), st.none()))
    if kind == "text":
        return kind, (draw(st.floats(0, 0.98)), draw(st.binary(max_size=8)))
    if kind == "delete":
        return kind, draw(st.sampled_from(["format", "version", "rig", "layout", "features", "models", "models.svm",
                                           "models.svm.file", "models.svm.sha256"]))
    if kind == "model-file":
        return kind, draw(st.sampled_from(["../svm.onnx", "/etc/passwd", "nope.onnx", "", "skin.json"]))
    if kind == "onnx-bytes":
        return kind, (draw(st.floats(0, 0.98)), draw(st.binary(min_size=1, max_size=8)))
    return kind, draw(st.text(alphabet="0123456789abcdef", min_size=0, max_size=64))


def _mutate_artifact(a: Path, kind: str, arg) -> None:
    skin = a / "skin.json"
    meta = json.loads(skin.read_text())
    if kind == "doc":
        skin.write_text(json.dumps(arg))
    elif kind == "text":
        text = skin.read_bytes().rstrip()
        skin.write_bytes(text[: int(arg[0] * (len(text) - 1))] + arg[1])
    elif kind == "delete":
        _set(meta, arg, None, delete=True)
        skin.write_text(json.dumps(meta))
    elif kind == "model-file":
        meta["models"]["svm"]["file"] = arg
        skin.write_text(json.dumps(meta))
    elif kind == "onnx-bytes":
        data = (a / "svm.onnx").read_bytes()
        cut = int(arg[0] * len(data))
        (a / "svm.onnx").write_bytes(data[:cut] + arg[1] + data[cut + len(arg[1]):] if data[cut:cut + len(arg[1])] != arg[1]
                                     else data[:cut] + bytes(b ^ 0xFF for b in arg[1]) + data[cut + len(arg[1]):])
    else:
        meta["models"]["svm"]["sha256"] = arg if arg != meta["models"]["svm"]["sha256"] else "0" * 64
        skin.write_text(json.dumps(meta))


@pytest.mark.slow
@settings(FUZZ, max_examples=40)
@given(artifact_mutations())
def test_malformed_artifact_files(capsys, cli_files, case):
    kind, arg = case
    with tempfile.TemporaryDirectory() as tmp:
        a = Path(tmp) / "art"
        shutil.copytree(cli_files["artifact"], a)
        _mutate_artifact(a, kind, arg)
        for argv in (["live", "--artifact", a, "--scenario", cli_files["scenario"], "--rig", cli_files["rig"], "--fast",
                      "--duration", "0.5", "--no-status"],
                     ["compare", "--data", cli_files["data"], "--artifact", a, "--out", Path(tmp) / "rep"]):
            code, err = _run(argv, capsys)
            assert_one_line_error(code, err, argv[0])
        assert not (Path(tmp) / "rep").exists()
    TRIED["artifact files"] += 1


def test_dataset_mutations_are_malformed_for_the_reader(cli_files):
    """The fuzzer's own sanity: the unmutated copy is accepted by the same command."""
    with tempfile.TemporaryDirectory() as tmp:
        d = _two_sessions(cli_files, Path(tmp))
        assert main(["fit-svm", "--data", str(d), "--out", str(Path(tmp) / "art"), "--mode", "absolute",
                     "--n-bins", "20"]) == 0
        assert np.isfinite(json.loads((Path(tmp) / "art" / "skin.json").read_text())["min_force_n"])


def test_fuzz_counts(capsys):
    """Runs last in this file: the number of malformed inputs tried (see the README figures)."""
    if not TRIED:
        pytest.skip("the fuzz tests did not run (-m 'not slow')")
    with capsys.disabled():
        print("\nmalformed inputs tried: " + ", ".join(f"{k} {v}" for k, v in sorted(TRIED.items())))
    assert TRIED["command lines"] >= 100 and TRIED["dataset files"] >= 90
