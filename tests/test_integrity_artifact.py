"""Integrity by construction, the artifact half (issue 16): a mutation corpus generated from one small
valid artifact.

An artifact is sealed when it is written (:func:`sonicskin.artifact.skin_json`): every ONNX file carries
its binding (bins in order, mode, Alg. 2 settings, rig, layout, its entry's parameters) in
``metadata_props``, ``skin.json`` a digest over itself and every file's sha256, and each model entry a few
probe inputs with the outputs the model gave at export.  Each mutation below is applied to a private copy at
several levels of care (only the edit; the edit with the checksums and the digest recomputed; a replacement
model carrying the original binding) and must be refused with one line, no traceback.  The data side
(``compare``/``live``/``export`` on another layout or rig), atomic replace, bounded reads, byte-identical
``svm.onnx`` and the training YAML's class paths and ranges follow.
"""

from __future__ import annotations

import hashlib
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
from cli_helpers import SMALL_RIG, assert_one_line_error, refusal, refusals, run

from sonicskin.artifact import atomic_artifact, skin_json
from sonicskin.features import FeatureSpec
from sonicskin.fit import build_svm_artifact
from sonicskin.integrity import artifact_digest, binding, read_binding, stamp_binding
from sonicskin.rig import Rig
from sonicskin.runtime import ArtifactError, SkinRuntime

REPO = Path(__file__).resolve().parent.parent


# -- a small sealed artifact with both models ------------------------------------------------------------------
def _net_onnx(path: Path, n_in: int, n_loc: int, *, seed: int = 0, fill: float | None = None) -> None:
    """A linear stand-in for SkinNet with the exported interface (``fill``: every weight that value, e.g. NaN)."""
    from onnx import TensorProto, helper, numpy_helper

    rng = np.random.default_rng(seed)
    w = [rng.normal(size=(n_in, n)).astype(np.float32) for n in (n_loc + 1, n_loc)]
    if fill is not None:
        w = [np.full_like(x, fill) for x in w]
    graph = helper.make_graph(
        [helper.make_node("MatMul", ["features", "w1"], ["logits"]), helper.make_node("MatMul", ["features", "w2"], ["force"])],
        "skinnet", [helper.make_tensor_value_info("features", TensorProto.FLOAT, ["batch", n_in])],
        [helper.make_tensor_value_info("logits", TensorProto.FLOAT, ["batch", n_loc + 1]),
         helper.make_tensor_value_info("force", TensorProto.FLOAT, ["batch", n_loc])],
        initializer=[numpy_helper.from_array(w[0], "w1"), numpy_helper.from_array(w[1], "w2")])
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    model.ir_version = 8
    path.write_bytes(model.SerializeToString())


def _meta(a: Path) -> dict:
    return json.loads((a / "skin.json").read_text())


def _seal_with_net(art: Path, *, seed: int = 0, bins: list[int] | None = None) -> dict:
    """Add a network to the SVM artifact in ``art`` and seal both through the writer."""
    meta = _meta(art)
    spec = FeatureSpec.from_dict({**meta["features"], **({"bins": bins} if bins else {})})
    _net_onnx(art / "net.onnx", len(spec.bins), len(meta["layout"]["ids"]), seed=seed)
    net = {"file": "net.onnx", "kind": "skinnet", "n_in": len(spec.bins), "n_locations": len(meta["layout"]["ids"]),
           "hparams": {"hidden": [8]}}
    return skin_json(art, rig=meta["rig"], layout=meta["layout"], spec=spec, min_force_n=meta["min_force_n"],
                     training=meta["training"], models={"net": net, "svm": meta["models"]["svm"]})


@pytest.fixture(scope="module")
def sealed(cli_files, tmp_path_factory) -> Path:
    """The cli_files SVM artifact plus a network, sealed by skin_json (read-only: copy before mutating)."""
    art = tmp_path_factory.mktemp("sealed") / "art"
    shutil.copytree(cli_files["artifact"], art)
    _seal_with_net(art)
    return art


@pytest.fixture(scope="module")
def foreign(cli_files, tmp_path_factory) -> Path:
    """Another sealed artifact of the same data: trained on one session (other bins, another SVM), other net weights."""
    art = tmp_path_factory.mktemp("foreign") / "art"
    build_svm_artifact(cli_files["data"], art, n_bins=60, train_sessions=["s000"], progress=False, log=lambda *_: None)
    _seal_with_net(art, seed=1)
    return art


@pytest.fixture
def art(sealed, tmp_path) -> Path:
    dst = tmp_path / "art"
    shutil.copytree(sealed, dst)
    return dst


def _write(a: Path, meta: dict) -> None:
    (a / "skin.json").write_text(json.dumps(meta, indent=1))


def _resha(a: Path, meta: dict) -> None:
    for m in meta["models"].values():
        m["sha256"] = hashlib.sha256((a / m["file"]).read_bytes()).hexdigest()


def _refused(a: Path, model: str, pattern: str) -> str:
    with pytest.raises(ArtifactError) as e:
        SkinRuntime(a, model)
    msg = str(e.value)
    assert "\n" not in msg and "Traceback" not in msg, msg
    assert re.search(pattern, msg), msg
    return msg


def test_sealed_artifact_loads_and_is_bound(sealed):
    meta = _meta(sealed)
    assert meta["version"] == 3 and meta["digest"] == artifact_digest(meta)
    for k in ("net", "svm"):
        rt = SkinRuntime(sealed, k)
        b = read_binding((sealed / f"{k}.onnx").read_bytes())
        assert b == binding(meta, k) and b["features"]["bins"] == meta["features"]["bins"]
        probe = meta["models"][k]["probe"]
        assert len(probe["inputs"]) == 4 and len(probe["inputs"][0]) == len(meta["features"]["bins"])
        out = rt.run(np.asarray(probe["inputs"], np.float32))
        assert np.allclose(out[1], probe["outputs"][1], atol=1e-5)  # the stored outputs are the model's own
    # The SVM's probes are real chirps of the training data (not zeros): its decisions there are not all equal.
    assert np.ptp(np.asarray(meta["models"]["svm"]["probe"]["outputs"][1])) > 0.1


# -- corpus 1: edits of skin.json ------------------------------------------------------------------------------
def _bins_edit(fn):
    def edit(meta, rig):
        meta["features"]["bins"] = fn(list(meta["features"]["bins"]), rig)
    return edit


def _swap(i, j):
    def f(b, _rig):
        b[i], b[j] = b[j], b[i]
        return b
    return f


def _into_notch(b, rig):  # one bin moved into the 30 kHz PWM band
    notch = [k for k in range(rig.n_band) if not rig.allowed_mask[k]]
    b[len(b) // 2] = notch[len(notch) // 2]
    return b


def _unused_allowed(b, rig):  # one bin replaced by an allowed bin the model never read
    free = [k for k in range(rig.n_band) if rig.allowed_mask[k] and k not in b]
    b[3] = free[0]
    return b


def _layout_edit(fn):
    def edit(meta, _rig):
        fn(meta["layout"])
    return edit


def _permute(order):
    def f(lay):
        lay["ids"] = [lay["ids"][i] for i in order]
    return f


def _scale_xy(factor):  # markers 1.5 cm apart instead of 1.2 (around the first marker)
    def f(lay):
        x0, y0 = lay["xy_cm"][0]
        lay["xy_cm"] = [[round(x0 + (x - x0) * factor, 6), round(y0 + (y - y0) * factor, 6)] for x, y in lay["xy_cm"]]
    return f


def _set(path, value):
    def edit(meta, _rig):
        *head, last = path.split(".")
        d = meta
        for k in head:
            d = d[int(k)] if isinstance(d, list) else d[k]
        if isinstance(d, list):
            d[int(last)] = value(d[int(last)]) if callable(value) else value
        else:
            d[last] = value(d[last]) if callable(value) else value
    return edit


def _force_coef_edit(meta, _rig):
    """One coefficient of the SVM's force model, whichever model selection chose (per-location curves, pooled ridge or SVR)."""
    f = meta["models"]["svm"]["force"]
    if f.get("curves"):
        c = f["curves"]["1"]["coef"]
    else:
        c = f["pooled"]["coef"] if "pooled" in f else f["svr"]["dual"]
    c[0] = c[0] * 1.5 + 0.1


def _both(*edits):
    def edit(meta, rig):
        for e in edits:
            e(meta, rig)
    return edit


BINS = "features.bins are not the bins {f} was trained with"
SVM_PARAMS = r"models.svm holds other parameters than were exported with svm.onnx"
DIGEST = "was changed after export: its digest does not match"
N_BINS = 60
# (id, edit(meta, rig), models it concerns, message pattern ({f}: the model's file))
DOC_EDITS = [
    ("bins-sorted", _bins_edit(lambda b, r: sorted(b)), ("net", "svm"), BINS + r" \(the model's bins sorted\)"),
    ("bins-reversed", _bins_edit(lambda b, r: b[::-1]), ("net", "svm"), BINS + r" \(the model's bins reversed\)"),
    *[(f"bins-swap-{i}-{j}", _bins_edit(_swap(i, j)), ("net", "svm"), BINS + r" \(.*2 positions differ")
      for i, j in ((0, 1), (0, N_BINS - 1), (7, 8), (20, 41), (N_BINS - 2, N_BINS - 1))],
    ("bins-rotated", _bins_edit(lambda b, r: b[1:] + b[:1]), ("net", "svm"), BINS),
    ("bins-into-pwm-notch", _bins_edit(_into_notch), ("net", "svm"), r"features.bins\[30\] is \d+ \(\d+\.\d\d kHz\), inside a PWM band"),
    ("bins-unused-bin", _bins_edit(_unused_allowed), ("net", "svm"), BINS + r" \(1 not among the model's"),
    ("mode-absolute", _set("features.mode", "absolute"), ("net", "svm"),
     r"features.mode is 'absolute' but {f} was trained with 'relative'"),
    ("beta-changed", _both(_set("features.beta_s", 5.0), _set("calibration.beta_s", 5.0)), ("net", "svm"), "features.beta_s is 5.0"),
    ("alpha-changed", _both(_set("features.alpha_s", 60.0), _set("calibration.alpha_s", 60.0)), ("net", "svm"), "features.alpha_s is 60.0"),
    ("min-force-changed", _set("min_force_n", 2.0), ("net", "svm"), "min_force_n is 2.0 but {f}"),
    *[(f"layout-ids-permuted-{''.join(map(str, o))}", _layout_edit(_permute(o)), ("net", "svm"),
       r"layout.ids are not the location ids {f} was trained with \(the model's ids") for o in ((1, 0, 2), (2, 1, 0), (1, 2, 0))],
    ("layout-ids-renumbered", _set("layout.ids", [5, 6, 7]), ("net", "svm"),
     "force.curves must have one curve per layout id|force.pooled.loc_coef must have one value per layout id|"
     r"layout.ids are not the location ids {f} was trained with \(3 not among the model's"),  # a pooled SVR has no ids
    ("layout-spacing-1.5cm", _layout_edit(_scale_xy(1.5 / 1.2)), ("net", "svm"), r"layout.xy_cm differs from the marker positions"),
    ("layout-one-marker-moved", _set("layout.xy_cm.1.1", lambda v: v + 0.5), ("net", "svm"), "layout.xy_cm differs"),
    ("layout-tube", _set("layout.circumference_cm", 23.5), ("net", "svm"), r"layout differs from the layout {f} was trained with"),
    ("rig-pwm-halfwidth", _set("rig.pwm_halfwidth_hz", 3000), ("net", "svm"),
     r"rig differs from the rig {f} was trained on \(pwm_halfwidth_hz"),
    ("rig-amplitude", _set("rig.amplitude", 0.25), ("net", "svm"), r"rig differs .*amplitude"),
    ("rig-name", _set("rig.name", "jaco"), ("net", "svm"), r"rig differs .*name"),
    ("svm-threshold-doubled", _set("models.svm.threshold", lambda v: 2 * v), ("svm",), SVM_PARAMS),
    ("svm-reference-shifted", _set("models.svm.reference_scores.0", lambda v: v + 1.0), ("svm",), SVM_PARAMS),
    ("svm-energy-ref", _set("models.svm.energy_ref_db", lambda v: v + 3.0), ("svm",), SVM_PARAMS),
    ("svm-force-curve", _force_coef_edit, ("svm",), SVM_PARAMS),
    ("svm-no-detection", _both(_set("models.svm.detection", False), _set("models.svm.threshold", 0.0)), ("svm",), SVM_PARAMS),
    ("net-hparams", _set("models.net.hparams", {"hidden": [16]}), ("net",), "models.net holds other parameters"),
    ("training-data", _set("training.data", "/elsewhere"), ("net", "svm"), DIGEST),
    ("training-split", _set("training.split.test", ["s000"]), ("net", "svm"), r"training.split is not the split {f} was trained on"),
    ("parity-edited", _set("models.svm.parity.max_abs_scores", 0.0), ("net", "svm"), DIGEST),
    ("version-string-edited", _set("sonicskin_version", "9.9"), ("net", "svm"), DIGEST),
    ("digest-other", _set("digest", "0" * 64), ("net", "svm"), DIGEST),
    ("digest-upper", _set("digest", lambda v: v.upper()), ("net", "svm"), "digest must be 64 lowercase hex digits"),
    ("digest-missing", lambda m, r: m.pop("digest"), ("net", "svm"), "digest is missing"),
    ("probe-output-edited", _set("models.net.probe.outputs.0.0.0", lambda v: v + 1.0), ("net",), DIGEST),
    ("probe-input-edited", _set("models.svm.probe.inputs.0", lambda row: [v + 20.0 for v in row]), ("svm",), DIGEST),
]


@pytest.mark.parametrize("name, edit, models, pattern", DOC_EDITS, ids=[d[0] for d in DOC_EDITS])
@pytest.mark.parametrize("level", ["edit", "edit+digest"])
def test_skin_json_edit_is_refused(art, cli_files, name, edit, models, pattern, level):
    """Every edit is refused, whether or not the editor recomputed the digest (the binding inside the model
    file names what differs; the digest catches what no model is bound to)."""
    meta = _meta(art)
    edit(meta, Rig.load(cli_files["rig"]))
    if level == "edit+digest" and "digest" in meta and "digest" not in name:
        meta["digest"] = artifact_digest(meta)
        if pattern == DIGEST:  # nothing bound to a model changed: the probes' and training fields are the document's
            pattern = "does not reproduce the outputs|" + DIGEST if name.startswith("probe") else None
    _write(art, meta)
    for model in models:
        if pattern is None:  # provenance only (training, parity, version) edited and resealed: that is a valid document
            SkinRuntime(art, model)
        else:
            _refused(art, model, pattern.format(f=f"{model}.onnx"))


# -- corpus 2: the model files replaced -------------------------------------------------------------------------
def _replace_net(kind):
    def act(a, foreign):
        meta = _meta(a)
        orig = (a / "net.onnx").read_bytes()
        if kind == "raw":  # a network graph without a binding
            _net_onnx(a / "net.onnx", N_BINS, 3, seed=2)
        elif kind == "nan":  # outputs NaN, the original binding copied in
            _net_onnx(a / "net.onnx", N_BINS, 3, fill=float("nan"))
            stamp_binding(a / "net.onnx", read_binding(orig))
        elif kind == "other-weights":  # another network for the same bins and layout, binding copied
            _net_onnx(a / "net.onnx", N_BINS, 3, seed=3)
            stamp_binding(a / "net.onnx", read_binding(orig))
        elif kind == "foreign":  # the net of another artifact (bins in another order)
            shutil.copy(foreign / "net.onnx", a / "net.onnx")
        elif kind == "svm-as-net":
            shutil.copy(a / "svm.onnx", a / "net.onnx")
        return meta
    return act


def _replace_svm(kind):
    def act(a, foreign):
        meta = _meta(a)
        if kind == "net-as-svm":
            shutil.copy(a / "net.onnx", a / "svm.onnx")
        elif kind == "foreign-binding-kept":  # another fit's SVM graph (other bins order) carrying this binding
            orig = (a / "svm.onnx").read_bytes()
            shutil.copy(foreign / "svm.onnx", a / "svm.onnx")
            stamp_binding(a / "svm.onnx", read_binding(orig))
        elif kind == "no-binding":
            import onnx

            m = onnx.load_model_from_string((a / "svm.onnx").read_bytes())
            del m.metadata_props[:]
            (a / "svm.onnx").write_bytes(m.SerializeToString())
        return meta
    return act


FOREIGN_NET = "features.bins are not the bins net.onnx was trained with|does not reproduce the outputs"
# (id, model, act, refusal with the checksum updated, refusal with checksum and digest updated)
FILE_SWAPS = [
    ("net-raw", "net", _replace_net("raw"), "carries no sonicskin binding", "carries no sonicskin binding"),
    ("net-nan", "net", _replace_net("nan"), DIGEST, r"does not reproduce the outputs .*non-finite outputs"),
    ("net-other-weights", "net", _replace_net("other-weights"), DIGEST, r"does not reproduce the outputs .*max \|difference\|"),
    ("net-foreign", "net", _replace_net("foreign"), FOREIGN_NET, FOREIGN_NET),
    ("net-is-svm", "net", _replace_net("svm-as-net"), "output 'label' has shape", "output 'label' has shape"),
    ("svm-is-net", "svm", _replace_svm("net-as-svm"), r"svm.onnx\) is the 'net' model", r"svm.onnx\) is the 'net' model"),
    ("svm-foreign-binding-kept", "svm", _replace_svm("foreign-binding-kept"), DIGEST, "does not reproduce the outputs"),
    ("svm-binding-stripped", "svm", _replace_svm("no-binding"), "carries no sonicskin binding", "carries no sonicskin binding"),
]


@pytest.mark.parametrize("name, model, act, at_sha, at_digest", FILE_SWAPS, ids=[f[0] for f in FILE_SWAPS])
@pytest.mark.parametrize("level", ["file", "file+sha", "file+sha+digest"])
def test_replaced_model_is_refused(art, foreign, name, model, act, at_sha, at_digest, level):
    meta = act(art, foreign)
    pattern = "does not match its checksum"
    if level != "file":
        _resha(art, meta)
        pattern = at_sha
        if level == "file+sha+digest":
            meta["digest"] = artifact_digest(meta)
            pattern = at_digest
    _write(art, meta)
    _refused(art, model, pattern)


def test_the_other_model_file_is_checked_too(art):
    """The artifact is one unit: serving the SVM still refuses a damaged net.onnx."""
    b = bytearray((art / "net.onnx").read_bytes())
    b[-5] ^= 0xFF
    (art / "net.onnx").write_bytes(bytes(b))
    _refused(art, "svm", r"net.onnx does not match its checksum")


# -- corpus 3: files that cannot be read safely -------------------------------------------------------------
def _huge(a):  # a sparse 2 GB file: refused by its size, never read
    with open(a / "net.onnx", "wb") as fh:
        fh.truncate(2 * 2**30)


def _loop(a):
    (a / "svm.onnx").unlink()
    os.symlink("svm.onnx", a / "svm.onnx")


def _loop2(a):
    (a / "svm.onnx").unlink()
    os.symlink("b.onnx", a / "svm.onnx")
    os.symlink("svm.onnx", a / "b.onnx")


def _dangling(a):
    (a / "svm.onnx").unlink()
    os.symlink("nowhere.onnx", a / "svm.onnx")


def _dir(a):
    (a / "svm.onnx").unlink()
    (a / "svm.onnx").mkdir()


def _fifo(a):
    (a / "svm.onnx").unlink()
    os.mkfifo(a / "svm.onnx")


def _huge_skin(a):
    with open(a / "skin.json", "ab") as fh:
        fh.truncate(200 * 2**20)


FILES = [
    ("net-2GB", "net", _huge, r"net.onnx is 2,048 MB, more than a model file can be \(256 MB at most\)"),
    ("net-2GB-serving-svm", "svm", _huge, r"net.onnx is 2,048 MB"),
    ("svm-symlink-loop", "svm", _loop, r"models.svm.file \(svm.onnx\) is a link that leads nowhere"),
    ("svm-symlink-loop-2", "svm", _loop2, r"models.svm.file \(svm.onnx\) is a link that leads nowhere"),
    ("svm-dangling-link", "svm", _dangling, r"is a link that leads nowhere"),
    ("svm-is-a-folder", "svm", _dir, r"svm.onnx is not a regular file"),
    ("svm-is-a-fifo", "svm", _fifo, r"svm.onnx is not a regular file"),
    ("skin-json-200MB", "svm", _huge_skin, r"skin.json is 200 MB, more than an artifact's metadata can be"),
]


@pytest.mark.parametrize("name, model, act, pattern", FILES, ids=[f[0] for f in FILES])
def test_unreadable_files_are_one_line(art, name, model, act, pattern):
    import resource

    act(art)
    before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    _refused(art, model, pattern)
    assert resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - before < 200_000  # kB: nothing big was read


# -- the data must be the artifact's: compare, live, export ---------------------------------------------------
@pytest.fixture(scope="module")
def other_data(cli_files, tmp_path_factory) -> dict[str, Path]:
    """The tiny scenario with markers 1.5 cm apart, and one on a rig with narrower PWM notches (1 session each)."""
    from sonicskin.sim.generate import simulate_dataset
    from sonicskin.sim.scenario import Scenario

    root = tmp_path_factory.mktemp("other")
    sc = Scenario.load(cli_files["scenario"]).replace(sessions=1)
    out = {"spacing": root / "spacing", "rig": root / "rig"}
    simulate_dataset(sc.replace(layout={**sc.layout, "spacing_cm": 1.5}), Rig.load(cli_files["rig"]), out["spacing"],
                     progress=False, log=lambda *_: None)
    (root / "rig.yaml").write_text(SMALL_RIG.replace("pwm_halfwidth_hz: 3250", "pwm_halfwidth_hz: 3000"))
    simulate_dataset(sc, Rig.load(root / "rig.yaml"), out["rig"], progress=False, log=lambda *_: None)
    return out


def test_compare_refuses_another_layout_or_rig(sealed, other_data, capsys):
    from sonicskin.compare import compare_artifact

    with pytest.raises(ArtifactError, match=r"the artifact's markers sit elsewhere than those of dataset .*spacing \(up to 0\.6 cm"):
        compare_artifact(sealed, other_data["spacing"])
    with pytest.raises(ArtifactError, match=r"trained for another rig \(pwm_halfwidth_hz: 3250 vs 3000\) than dataset"):
        compare_artifact(sealed, other_data["rig"])
    code, _, err = run(capsys, ["compare", "--data", other_data["spacing"], "--artifact", sealed, "--test", "s000"])
    assert "markers sit elsewhere" in assert_one_line_error(code, err, "compare")


def test_compare_refuses_a_mutated_artifact_in_one_line(art, cli_files, capsys):
    meta = _meta(art)
    meta["features"]["bins"] = sorted(meta["features"]["bins"])
    _write(art, meta)
    code, _, err = run(capsys, ["compare", "--data", cli_files["data"], "--artifact", art, "--test", "s000"])
    assert "features.bins are not the bins" in assert_one_line_error(code, err, "compare")


def test_live_refuses_a_mutated_artifact_in_one_line(art, cli_files, capsys):
    meta = _meta(art)
    meta["layout"]["ids"] = meta["layout"]["ids"][::-1]
    meta["digest"] = artifact_digest(meta)
    _write(art, meta)
    for model in ("svm", "net"):
        code, _, err = run(capsys, ["live", "--artifact", art, "--model", model, "--rig", cli_files["rig"], "--scenario",
                                    cli_files["scenario"], "--fast", "--duration", "1", "--no-status"])
        assert "layout.ids are not the location ids" in assert_one_line_error(code, err, "live")


def _checkpoint(path: Path, sealed: Path, data: Path) -> Path:
    """A checkpoint as `sonicskin train` writes it (untrained weights), for the sealed artifact's data."""
    torch = pytest.importorskip("torch")
    from sonicskin.training.module import SkinLitModule

    meta = _meta(sealed)
    lit = SkinLitModule(n_in=len(meta["features"]["bins"]), n_locations=3, hidden=(8,), kernel=False)
    torch.save({"state_dict": lit.state_dict(), "hyper_parameters": dict(lit.hparams),
                "sonicskin": {"data": str(data), "rig": meta["rig"], "layout": meta["layout"], "spec": meta["features"],
                              "split": meta["training"]["split"], "min_force_n": 0.5}}, path)
    return path


@pytest.mark.slow  # ~10 s: torch and two feature runs / two processes
def _bad_meta(edit):
    def f(meta):
        edit(meta)
        return meta
    return f


CKPT_META = [
    ("rig-string", _bad_meta(lambda m: m.update(rig="small")), "its sonicskin metadata rig must be a JSON object"),
    ("rig-band-above-nyquist", _bad_meta(lambda m: m["rig"].update(f_hi_hz=120_000)), "metadata rig is not a valid rig"),
    ("layout-ids-duplicate", _bad_meta(lambda m: m["layout"].update(ids=[0, 0, 1])), "metadata layout.ids are not unique"),
    ("layout-xy-nan", _bad_meta(lambda m: m["layout"]["xy_cm"][0].__setitem__(0, float("nan"))), "metadata layout.xy_cm[0][0]"),
    ("spec-bin-beyond-band", _bad_meta(lambda m: m["spec"]["bins"].__setitem__(0, 10**6)), r"metadata features.bins[0] is 1000000"),
    ("spec-mode", _bad_meta(lambda m: m["spec"].update(mode="log")), "metadata features.mode"),
    ("spec-fewer-bins-than-inputs", _bad_meta(lambda m: m["spec"].update(bins=m["spec"]["bins"][:10])),
     "metadata spec.bins lists 10 bins but the network takes 60 inputs"),
    ("layout-fewer-than-outputs", _bad_meta(lambda m: m.update(layout={"ids": [0, 1], "xy_cm": [[0, 0], [1, 0]]})),
     "metadata layout.ids lists 2 locations but the network has 3"),
    ("split-not-object", _bad_meta(lambda m: m.update(split=["s000"])), "metadata split must be a JSON object"),
    ("min-force-inf", _bad_meta(lambda m: m.update(min_force_n=float("inf"))), "metadata min_force_n must be finite"),
    ("data-number", _bad_meta(lambda m: m.update(data=7)), "metadata data must be a string"),
]


@pytest.mark.parametrize("name, edit, message", CKPT_META, ids=[c[0] for c in CKPT_META])
def test_checkpoint_metadata_is_checked(sealed, cli_files, tmp_path, capsys, name, edit, message):
    torch = pytest.importorskip("torch")
    ckpt = _checkpoint(tmp_path / "run.ckpt", sealed, cli_files["data"])
    c = torch.load(ckpt, weights_only=True)
    c["sonicskin"] = edit(c["sonicskin"])
    torch.save(c, ckpt)
    code, _, err = run(capsys, ["export", "--run", ckpt, "--out", tmp_path / "out"])
    assert message in assert_one_line_error(code, err, "export")
    assert not (tmp_path / "out").exists()


def test_huge_checkpoint_is_refused_by_its_size(tmp_path, capsys):
    pytest.importorskip("torch")
    with open(tmp_path / "run.ckpt", "wb") as fh:
        fh.truncate(3 * 2**30)
    code, _, err = run(capsys, ["export", "--run", tmp_path / "run.ckpt", "--out", tmp_path / "out"])
    assert "run.ckpt is 3,072 MB, more than a sonicskin checkpoint can be" in assert_one_line_error(code, err, "export")


def test_export_refuses_other_data(sealed, cli_files, other_data, tmp_path, capsys):
    ckpt = _checkpoint(tmp_path / "run.ckpt", sealed, cli_files["data"])
    for which, pattern in (("spacing", "checkpoint run.ckpt's markers sit elsewhere than those of dataset"),
                           ("rig", r"checkpoint run.ckpt was trained for another rig \(pwm_halfwidth_hz")):
        code, _, err = run(capsys, ["export", "--run", ckpt, "--out", tmp_path / "out", "--data", other_data[which]])
        assert re.search(pattern, assert_one_line_error(code, err, "export"))
        assert not (tmp_path / "out").exists()


# -- atomic replace: an interrupted writer keeps the old artifact -----------------------------------------------
def _fingerprint(a: Path) -> dict[str, str]:
    return {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(a.iterdir())}


@pytest.mark.parametrize("where", ["export_pipeline", "skin_json", "swap"])
@pytest.mark.parametrize("exc", [KeyboardInterrupt, RuntimeError])
def test_interrupted_fit_svm_keeps_the_old_artifact(cli_files, tmp_path, monkeypatch, where, exc):
    import sonicskin.artifact as A
    import sonicskin.kinds.svm as S

    out = tmp_path / "art"
    shutil.copytree(cli_files["artifact"], out)
    before = _fingerprint(out)

    def boom(*a, **k):
        raise exc("interrupted")
    module, target = {"export_pipeline": (S, "export_pipeline"), "skin_json": (A, "stamp_binding"), "swap": (A, "swap_folders")}[where]
    monkeypatch.setattr(module, target, boom)
    with pytest.raises(exc):
        build_svm_artifact(cli_files["data"], out, n_bins=60, progress=False, log=lambda *_: None)
    assert _fingerprint(out) == before
    SkinRuntime(out, "svm")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["art"]  # no partial folder left behind


def test_interrupted_export_keeps_the_old_artifact(sealed, cli_files, tmp_path, monkeypatch):
    import sonicskin.training.fit as X  # the network's kind exports through the export_net it imported
    from sonicskin.training.fit import artifact_from_checkpoint

    ckpt = _checkpoint(tmp_path / "run.ckpt", sealed, cli_files["data"])
    out = tmp_path / "art"
    shutil.copytree(sealed, out)
    before = _fingerprint(out)

    def boom(*a, **k):
        raise KeyboardInterrupt
    monkeypatch.setattr(X, "export_net", boom)  # after svm.onnx was written: the old one must survive
    with pytest.raises(KeyboardInterrupt):
        artifact_from_checkpoint(ckpt, out, log=lambda *_: None)
    assert _fingerprint(out) == before
    SkinRuntime(out, "net")


KILL_SCRIPT = textwrap.dedent("""
    import os, signal, sys
    import sonicskin.artifact as A
    real = A.stamp_binding
    def stamp(path, b):  # killed once svm.onnx is written into the new folder
        real(path, b)
        os.kill(os.getpid(), signal.SIGKILL)
    A.stamp_binding = stamp
    import sonicskin.fit as F
    F.build_svm_artifact(sys.argv[1], sys.argv[2], n_bins=60, progress=False, log=lambda *_: None)
""")


def test_sigkill_during_fit_svm_keeps_the_old_artifact(cli_files, tmp_path):
    out = tmp_path / "art"
    shutil.copytree(cli_files["artifact"], out)
    before = _fingerprint(out)
    r = subprocess.run([sys.executable, "-c", KILL_SCRIPT, str(cli_files["data"]), str(out)], capture_output=True, text=True,
                       env={**os.environ, "OMP_NUM_THREADS": "1"})
    assert r.returncode == -signal.SIGKILL, r.stderr[-2000:]
    assert _fingerprint(out) == before
    SkinRuntime(out, "svm")
    partial = [p.name for p in tmp_path.iterdir() if p.name != "art"]
    assert len(partial) == 1 and partial[0].startswith(".art.partial-")  # the killed run's folder, beside it
    build_svm_artifact(cli_files["data"], out, n_bins=60, progress=False, log=lambda *_: None)  # a new run tidies up
    assert sorted(p.name for p in tmp_path.iterdir()) == ["art"]
    assert _fingerprint(out)["svm.onnx"] == before["svm.onnx"]  # same inputs, same bytes


@pytest.mark.parametrize("exchange", [True, False], ids=["renameat2", "two-renames"])
def test_atomic_replace_swaps_the_whole_folder(tmp_path, monkeypatch, exchange):
    import sonicskin.dataset as D

    if not exchange:
        monkeypatch.setattr(D, "_exchange", lambda a, b: False)
    out = tmp_path / "art"
    out.mkdir()
    (out / "skin.json").write_text("old")
    (out / "net.onnx").write_text("old net")
    with atomic_artifact(out) as tmp:
        assert tmp.parent == tmp_path and tmp != out and not list(tmp.iterdir())
        (tmp / "skin.json").write_text("new")
        assert (out / "skin.json").read_text() == "old"  # untouched until the end
    assert sorted(p.name for p in out.iterdir()) == ["skin.json"] and (out / "skin.json").read_text() == "new"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["art"]


def test_atomic_artifact_refuses_to_replace_other_files(tmp_path):
    out = tmp_path / "notes"
    out.mkdir()
    (out / "thesis.tex").write_text("years of work")
    with pytest.raises(ArtifactError, match=r"holds files that are not part of an artifact \(thesis.tex\)"):
        with atomic_artifact(out):
            pass
    assert (out / "thesis.tex").read_text() == "years of work"
    (tmp_path / "file").write_text("x")
    with pytest.raises(ArtifactError, match="exists and is not a folder"):
        with atomic_artifact(tmp_path / "file"):
            pass


# -- fit-svm is reproducible to the byte ------------------------------------------------------------------------
@pytest.mark.slow  # ~10 s: torch and two feature runs / two processes
def test_fit_svm_writes_identical_bytes(cli_files, tmp_path):
    """Two processes with different hash seeds (skl2onnx listed its opsets in set order) write the same svm.onnx."""
    digests = []
    for seed in ("1", "2"):
        out = tmp_path / f"art{seed}"
        r = subprocess.run([sys.executable, "-m", "sonicskin", "fit-svm", "--data", str(cli_files["data"]), "--out", str(out),
                            "--n-bins", "60"], capture_output=True, text=True,
                           env={**os.environ, "PYTHONHASHSEED": seed, "OMP_NUM_THREADS": "1"})
        assert r.returncode == 0, r.stderr[-2000:]
        digests.append(hashlib.sha256((out / "svm.onnx").read_bytes()).hexdigest())
    assert digests[0] == digests[1]
    assert digests[0] == hashlib.sha256((cli_files["artifact"] / "svm.onnx").read_bytes()).hexdigest()  # and this process's


# -- training YAML: class paths are checked before anything is imported; numbers in range -----------------------
EVIL = "import pathlib; pathlib.Path({marker!r}).write_text('imported')\nclass Thing:\n    pass\n"


@pytest.fixture
def evil_module(tmp_path, monkeypatch):
    pytest.importorskip("lightning")
    marker = tmp_path / "imported.txt"
    (tmp_path / "evilmod.py").write_text(EVIL.format(marker=str(marker)))
    monkeypatch.syspath_prepend(str(tmp_path))
    yield marker
    sys.modules.pop("evilmod", None)


def _evil_config(tmp_path: Path, text_edit) -> Path:
    cfg = tmp_path / "evil.yaml"
    cfg.write_text(text_edit((REPO / "configs/train/moving.yaml").read_text()))
    return cfg


CLASS_CASES = [
    ("yaml-logger", lambda p: ["--config", _evil_config(p, lambda t: t.replace("lightning.pytorch.loggers.CSVLogger",
                                                                                 "evilmod.Thing"))]),
    ("yaml-callback", lambda p: ["--config", _evil_config(p, lambda t: t.replace("lightning.pytorch.callbacks.ModelCheckpoint",
                                                                                   "evilmod.Thing"))]),
    ("yaml-nested", lambda p: ["--config", _evil_config(p, lambda t: t.replace("init_args: {save_dir: runs/moving, name: logs}",
                                                                                 "init_args: {save_dir: {class_path: evilmod.Thing}}"))]),
    ("option-logger", lambda p: ["--trainer.logger", "evilmod.Thing"]),
    ("option-class-path", lambda p: ["--trainer.logger.class_path=evilmod.Thing"]),
    ("option-callbacks-append", lambda p: ["--trainer.callbacks+=evilmod.Thing"]),
    ("option-json", lambda p: ["--trainer.logger", '{"class_path": "evilmod.Thing"}']),
    ("option-strategy", lambda p: ["--trainer.strategy", "evilmod.Thing"]),
    ("option-optimizer", lambda p: ["--optimizer", "evilmod.Thing"]),
]


@pytest.mark.parametrize("name, argv", CLASS_CASES, ids=[c[0] for c in CLASS_CASES])
def test_training_class_path_refused_before_import(evil_module, cli_files, tmp_path, capsys, name, argv):
    code, _, err = run(capsys, ["train", "--data", cli_files["data"], *argv(tmp_path)])
    line = assert_one_line_error(code, err, "train")
    assert "names the class 'evilmod.Thing', which sonicskin train does not load" in line, line
    assert not evil_module.exists() and "evilmod" not in sys.modules


RANGE_CASES = [
    (["--trainer.max_epochs", "-5"], "--trainer.max_epochs must be -1 (no limit) or an integer from 1 to 1000000, got -5"),
    (["--trainer.max_epochs=0"], "--trainer.max_epochs must be -1"),
    (["--trainer.max_epochs", "10000000000"], "--trainer.max_epochs must be"),
    (["--trainer.max_steps", "-7"], "--trainer.max_steps must be"),
    (["--trainer.log_every_n_steps", "0"], "--trainer.log_every_n_steps must be an integer >= 1"),
    (["--trainer.accumulate_grad_batches", "-1"], "--trainer.accumulate_grad_batches must be"),
    (["--trainer.limit_train_batches", "1.5"], "--trainer.limit_train_batches must be a fraction"),
    (["--trainer.limit_train_batches", "0"], "--trainer.limit_train_batches must be"),
    (["--trainer.gradient_clip_val", "-1"], "--trainer.gradient_clip_val must be"),
    (["--trainer.check_val_every_n_epoch", "0"], "--trainer.check_val_every_n_epoch must be"),
    (["--data.batch_size", "0"], "--data.batch_size must be an integer from 1"),
    (["--data.batch_size", "-128"], "--data.batch_size must be"),
    (["--model.lr", "-0.1"], "--model.lr must be a finite number > 0"),
    (["--model.lr", "inf"], "model.lr"),
    (["--model.dropout", "1.5"], "--model.dropout must be"),
    (["--model.tau", "0"], "--model.tau must be"),
    (["--model.hidden", "[64, -3]"], "--model.hidden must be a list of layer widths"),
    (["--data.min_force_n", "-1"], "--data.min_force_n must be"),
    (["--seed_everything", "-4"], "--seed_everything must be"),
]


@pytest.mark.parametrize("argv, message", refusals(RANGE_CASES))
def test_training_numbers_out_of_range_are_one_line(cli_files, capsys, argv, message):
    pytest.importorskip("lightning")
    assert message in refusal(capsys, ["train", "--data", cli_files["data"], "--trainer.default_root_dir",
                                       str(cli_files["root"] / "never"), *argv])
    assert not (cli_files["root"] / "never").exists()


def test_training_yaml_syntax_error_is_one_line(cli_files, tmp_path, capsys):
    pytest.importorskip("lightning")
    bad = tmp_path / "bad.yaml"
    bad.write_text("trainer:\n  max_epochs: [1\n")
    code, _, err = run(capsys, ["train", "--data", cli_files["data"], "--config", bad])
    assert "is not a valid YAML training config" in assert_one_line_error(code, err, "train")


def test_corpus_counts():
    """The counts notes/art-README.md states (kept in step here)."""
    doc = len(DOC_EDITS) * 2
    files = len(FILE_SWAPS) * 3 + 1 + len(FILES)
    data = 3 + 1 + 2 + 2 + len(CKPT_META) + 1
    atomic = 6 + 1 + 1 + 2 + 2
    train = len(CLASS_CASES) + len(RANGE_CASES) + 1
    assert (doc, files, data, atomic, train) == (78, 33, 20, 12, 29)
