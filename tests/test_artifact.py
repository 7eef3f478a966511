"""Deployment artifacts are validated completely before anything runs (sonicskin.artifact_schema), and nothing
in a file is ever executed (checkpoints load with weights_only=True; no pickle anywhere in the package).

One real artifact is built per module (``fit-svm`` on a tiny simulated recording, plus a network
graph written with ``onnx.helper`` so no torch is needed); every mutation below is applied to a copy
and must be refused with one :class:`ArtifactError` line that names the field.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import re
import shutil
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from sonicskin.artifact import load_skin, skin_json
from sonicskin.artifact_schema import validate_skin
from sonicskin.compare import replay_sessions
from sonicskin.dataset import Dataset
from sonicskin.feature_cache import load_features_cached
from sonicskin.features import FeatureSpec, quiet_mask
from sonicskin.fit import build_svm_artifact
from sonicskin.force import PooledSVR
from sonicskin.integrity import artifact_digest, binding, check_layout, stamp_binding
from sonicskin.rig import Layout, Rig
from sonicskin.runtime import ArtifactError, SkinRuntime
from sonicskin.sim.generate import simulate_dataset
from sonicskin.sim.scenario import Scenario

REPO = Path(__file__).resolve().parent.parent
N_BINS = 40
TINY = dict(sessions=1, layout={"kind": "grid", "nx": 3, "ny": 1, "spacing_cm": 1.2, "x0_cm": 8, "y0_cm": 12},
            touch_s=1.5, gap_s=0.3, calibration_s=3.0, repeats=2, motion={"enabled": False}, moving_s=0.0, seed=5)


def _net_onnx(path: Path, n_in: int, n_loc: int, seed: int = 0) -> None:
    """A linear stand-in for SkinNet with the exported graph's interface: features -> logits (N+1), force (N)."""
    import onnx
    from onnx import TensorProto, helper, numpy_helper

    rng = np.random.default_rng(seed)
    w1 = numpy_helper.from_array(rng.normal(size=(n_in, n_loc + 1)).astype(np.float32), "w1")
    w2 = numpy_helper.from_array(rng.normal(size=(n_in, n_loc)).astype(np.float32), "w2")
    graph = helper.make_graph(
        [helper.make_node("MatMul", ["features", "w1"], ["logits"]), helper.make_node("MatMul", ["features", "w2"], ["force"])],
        "skinnet", [helper.make_tensor_value_info("features", TensorProto.FLOAT, ["batch", n_in])],
        [helper.make_tensor_value_info("logits", TensorProto.FLOAT, ["batch", n_loc + 1]),
         helper.make_tensor_value_info("force", TensorProto.FLOAT, ["batch", n_loc])], initializer=[w1, w2])
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    model.ir_version = 8
    onnx.checker.check_model(model)
    path.write_bytes(model.SerializeToString())


@pytest.fixture(scope="module")
def built(tmp_path_factory, rig):
    """(artifact folder with net + svm, dataset folder): the SVM from `fit-svm`, both written by skin_json."""
    root = tmp_path_factory.mktemp("artifact")
    data, art = root / "data", root / "art"
    simulate_dataset(Scenario(**TINY), rig, data, progress=False, log=lambda *_: None)
    skin = build_svm_artifact(data, art, n_bins=N_BINS, progress=False, log=lambda *_: None)
    _net_onnx(art / "net.onnx", N_BINS, 3)
    net = {"file": "net.onnx", "kind": "skinnet", "n_in": N_BINS, "n_locations": 3, "hparams": {"hidden": [8]}}
    skin_json(art, rig=skin["rig"], layout=skin["layout"], spec=FeatureSpec.from_dict(skin["features"]),
              min_force_n=skin["min_force_n"], training=skin["training"], models={"net": net, **skin["models"]})
    return art, data


@pytest.fixture
def art(built, tmp_path):
    """A private copy to mutate."""
    dst = tmp_path / "art"
    shutil.copytree(built[0], dst)
    return dst


def _meta(a: Path) -> dict:
    return json.loads((a / "skin.json").read_text())


def _write(a: Path, meta) -> None:
    (a / "skin.json").write_text(json.dumps(meta))


def _reseal(a: Path, meta: dict) -> None:
    """What skin_json does after the models are written: binding into each file, its sha256, the digest."""
    for name, m in meta["models"].items():
        stamp_binding(a / m["file"], binding(meta, name))
        _resha(a, meta, name)
    meta["digest"] = artifact_digest(meta)
    _write(a, meta)


def _resha(a: Path, meta: dict, model: str) -> None:
    meta["models"][model]["sha256"] = hashlib.sha256((a / meta["models"][model]["file"]).read_bytes()).hexdigest()


def _refused(a: Path, model: str, field: str) -> str:
    with pytest.raises(ArtifactError) as e:
        SkinRuntime(a, model)
    msg = str(e.value)
    assert "\n" not in msg, msg
    assert field in msg, msg
    return msg


# -- mutations of skin.json: (id, model to load, edit(meta, folder), text the error must contain) --------------
def _set(path: str, value):
    """Edit ``meta`` at a dotted path (``models.svm.threshold``, ``features.bins.0``)."""
    def edit(meta, _a):
        *head, last = path.split(".")
        d = meta
        for k in head:
            d = d[int(k)] if isinstance(d, list) else d[k]
        if isinstance(d, list):
            d[int(last)] = value
        else:
            d[last] = value
    return edit


def _delete(path: str):
    def edit(meta, _a):
        *head, last = path.split(".")
        d = meta
        for k in head:
            d = d[k]
        del d[last]
    return edit


def _do(fn):
    return lambda meta, a: fn(meta, a)


def _drop_location(meta, _a):  # fewer layout ids than the models' outputs
    meta["layout"]["ids"].pop()
    meta["layout"]["xy_cm"].pop()


def _drop_location_consistent(meta, _a):  # the document agrees with itself, the ONNX graph does not
    _drop_location(meta, _a)
    meta["models"]["net"]["n_locations"] = 2
    outs = meta["models"]["net"]["probe"]["outputs"]
    outs[:] = [[row[:n] for row in o] for o, n in zip(outs, (3, 2))]  # the probes too: only the graph disagrees
    del meta["models"]["svm"]


def _symlink_out(meta, a):
    outside = a.parent / "elsewhere.onnx"
    shutil.copy(a / "svm.onnx", outside)  # same bytes: the checksum matches, the place does not
    (a / "svm.onnx").unlink()
    os.symlink(outside, a / "svm.onnx")


def _swap_onnx(meta, a):  # the SVM graph where the network should be, checksum updated
    meta["models"]["net"]["file"] = "svm.onnx"
    _resha(a, meta, "net")


def _corrupt_onnx(meta, a):
    (a / "svm.onnx").write_bytes(b"\x08\x07garbage" * 10)
    _resha(a, meta, "svm")


def _net_wrong_width(meta, a):  # a network graph for 39 inputs, checksum updated
    _net_onnx(a / "net.onnx", N_BINS - 1, 3)
    _resha(a, meta, "net")


def _net_wrong_outputs(meta, a):  # a network graph for 4 locations on a 3-marker layout
    _net_onnx(a / "net.onnx", N_BINS, 4)
    _resha(a, meta, "net")


def _net_external_data(meta, a):  # weights "beside" the graph, i.e. read from wherever the path points
    import onnx

    m = onnx.load(str(a / "net.onnx"))
    onnx.save_model(m, str(a / "net.onnx"), save_as_external_data=True, all_tensors_to_one_file=True,
                    location="weights.bin", size_threshold=0)
    _resha(a, meta, "net")


def _curve(meta):
    return meta["models"]["svm"]["force"]["curves"]["0"]


def _drop_curve(meta, _a):
    del meta["models"]["svm"]["force"]["curves"]["1"]


def _extra_curve(meta, _a):
    meta["models"]["svm"]["force"]["curves"]["99"] = _curve(meta)


def _svr_force(edit=None):
    """The SVM's force replaced by a pooled SVR over its inputs, then ``edit``-ed (its ``svr`` numbers)."""
    def fn(meta, _a):
        n_in = meta["models"]["svm"]["n_in"]
        rng = np.random.default_rng(0)
        d = PooledSVR().fit(rng.normal(size=(30, n_in)), rng.uniform(0, 5, 30)).to_dict()
        if edit is not None:
            edit(d["svr"], n_in)
        meta["models"]["svm"]["force"] = d
    return fn


SVR_FIELD = "models.svm.force.svr"
SVM = "models.svm"
MUTATIONS = [
    # features
    ("bins-negative", "svm", _set("features.bins.0", -1), "features.bins[0]"),
    ("bins-float", "svm", _set("features.bins.0", 141.0), "features.bins[0]"),
    ("bins-string", "svm", _set("features.bins.0", "141"), "features.bins[0]"),
    ("bins-bool", "svm", _set("features.bins.0", True), "features.bins[0]"),
    ("bins-beyond-band", "svm", _set("features.bins.0", 99_999), "features.bins[0]"),
    ("bins-duplicate", "svm", _do(lambda m, a: m["features"]["bins"].__setitem__(1, m["features"]["bins"][0])),
     "features.bins"),
    ("bins-empty", "svm", _set("features.bins", []), "features.bins"),
    ("bins-not-list", "svm", _set("features.bins", 40), "features.bins"),
    ("bins-fewer-than-model", "svm", _do(lambda m, a: m["features"].__setitem__("bins", m["features"]["bins"][:10])),
     "takes 40 features but skin.json lists 10 bins"),
    ("mode-unknown", "svm", _set("features.mode", "bogus"), "features.mode"),
    ("beta-zero", "svm", _set("features.beta_s", 0), "features.beta_s"),
    ("beta-negative", "svm", _set("features.beta_s", -3.0), "features.beta_s"),
    ("beta-string", "svm", _set("features.beta_s", "3"), "features.beta_s"),
    ("beta-nan", "svm", _set("features.beta_s", math.nan), "features.beta_s"),
    ("beta-absurd", "svm", _set("features.beta_s", 1e9), "features.beta_s"),
    ("alpha-zero", "svm", _set("features.alpha_s", 0), "features.alpha_s"),
    ("alpha-below-beta", "svm", _set("features.alpha_s", 1.0), "features.alpha_s"),
    ("alpha-null", "svm", _set("features.alpha_s", None), "features.alpha_s"),
    ("alpha-missing", "svm", _delete("features.alpha_s"), "features.alpha_s is missing"),
    ("features-null", "svm", _set("features", None), "features must be a JSON object"),
    ("features-unknown-key", "svm", _set("features.bin", [1]), "features has unknown keys"),
    ("calibration-differs", "svm", _set("calibration.beta_s", 5.0), "calibration.beta_s"),
    ("min-force-negative", "svm", _set("min_force_n", -1), "min_force_n"),
    # SVM entry
    ("threshold-nan", "svm", _set(f"{SVM}.threshold", math.nan), f"{SVM}.threshold"),
    ("threshold-inf", "svm", _set(f"{SVM}.threshold", math.inf), f"{SVM}.threshold"),
    ("threshold-zero", "svm", _set(f"{SVM}.threshold", 0.0), f"{SVM}.threshold"),
    ("threshold-negative", "svm", _set(f"{SVM}.threshold", -0.5), f"{SVM}.threshold"),
    ("threshold-string", "svm", _set(f"{SVM}.threshold", "0.6"), f"{SVM}.threshold"),
    ("threshold-absurd", "svm", _set(f"{SVM}.threshold", 1e30), f"{SVM}.threshold"),
    ("threshold-missing", "svm", _delete(f"{SVM}.threshold"), f"{SVM}.threshold is missing"),
    ("reference-short", "svm", _do(lambda m, a: m["models"]["svm"]["reference_scores"].pop()), f"{SVM}.reference_scores"),
    ("reference-long", "svm", _do(lambda m, a: m["models"]["svm"]["reference_scores"].append(0.0)), f"{SVM}.reference_scores"),
    ("reference-absurd", "svm", _set(f"{SVM}.reference_scores.3", 1e30), f"{SVM}.reference_scores[3]"),
    ("reference-null", "svm", _set(f"{SVM}.reference_scores.0", None), f"{SVM}.reference_scores[0]"),
    ("reference-nan", "svm", _set(f"{SVM}.reference_scores.5", math.nan), f"{SVM}.reference_scores[5]"),
    ("reference-not-list", "svm", _set(f"{SVM}.reference_scores", 0.0), f"{SVM}.reference_scores"),
    ("reference-missing", "svm", _delete(f"{SVM}.reference_scores"), f"{SVM}.reference_scores is missing"),
    ("energy-ref-nan", "svm", _set(f"{SVM}.energy_ref_db", math.nan), f"{SVM}.energy_ref_db"),
    ("energy-ref-missing", "svm", _delete(f"{SVM}.energy_ref_db"), f"{SVM}.energy_ref_db is missing"),
    ("detector-old", "svm", _set(f"{SVM}.detector", "max-score"), f"{SVM}.detector"),
    ("detector-missing", "svm", _delete(f"{SVM}.detector"), f"{SVM}.detector is missing"),
    ("false-touch-rate-2", "svm", _set(f"{SVM}.train_false_touch_rate", 2.0), f"{SVM}.train_false_touch_rate"),
    ("kind-wrong", "svm", _set(f"{SVM}.kind", "svc-ovr"), f"{SVM}.kind"),
    ("n-in-wrong", "svm", _set(f"{SVM}.n_in", 41), f"{SVM}.n_in"),
    ("n-locations-wrong", "svm", _set(f"{SVM}.n_locations", 31), f"{SVM}.n_locations"),
    ("svm-unknown-key", "svm", _set(f"{SVM}.thresold", 0.5), f"{SVM} has unknown keys"),
    ("force-model-unknown", "svm", _set(f"{SVM}.force.model", "spline"), f"{SVM}.force.model"),
    ("force-missing", "svm", _delete(f"{SVM}.force"), f"{SVM}.force is missing"),
    ("force-curve-missing-location", "svm", _drop_curve, f"{SVM}.force.curves"),
    ("force-curve-unknown-location", "svm", _extra_curve, f"{SVM}.force.curves"),
    ("force-coef-short", "svm", _do(lambda m, a: _curve(m)["coef"].pop()), f"{SVM}.force.curves.0.coef"),
    ("force-coef-nan", "svm", _do(lambda m, a: _curve(m)["coef"].__setitem__(0, math.nan)), f"{SVM}.force.curves.0.coef[0]"),
    ("force-scale-zero", "svm", _do(lambda m, a: _curve(m).__setitem__("scale", 0.0)), f"{SVM}.force.curves.0.scale"),
    ("force-e-range-inverted", "svm", _do(lambda m, a: _curve(m).update(e_lo=1.0, e_hi=-1.0)), f"{SVM}.force.curves.0.e_lo"),
    ("force-curve-model-differs", "svm", _do(lambda m, a: _curve(m).__setitem__("model", "poly1")),
     f"{SVM}.force.curves.0.model"),
    ("force-theta-missing", "svm", _do(lambda m, a: _curve(m).pop("theta")), f"{SVM}.force.curves.0.theta is missing"),
    # files
    ("file-absolute", "svm", _do(lambda m, a: m["models"]["svm"].__setitem__("file", str((a / "svm.onnx").resolve()))),
     f"{SVM}.file"),
    ("file-dotdot", "svm", _set(f"{SVM}.file", "../art/svm.onnx"), f"{SVM}.file"),
    ("file-subfolder", "svm", _set(f"{SVM}.file", "sub/svm.onnx"), f"{SVM}.file"),
    ("file-dotdot-only", "svm", _set(f"{SVM}.file", ".."), f"{SVM}.file"),
    ("file-backslash", "svm", _set(f"{SVM}.file", "..\\svm.onnx"), f"{SVM}.file"),
    ("file-not-string", "svm", _set(f"{SVM}.file", 7), f"{SVM}.file"),
    ("file-missing-key", "svm", _delete(f"{SVM}.file"), f"{SVM}.file is missing"),
    ("file-symlink-outside", "svm", _symlink_out, f"{SVM}.file"),
    ("file-absent", "svm", _do(lambda m, a: (a / "svm.onnx").unlink()), "svm.onnx is missing"),
    ("sha-wrong", "svm", _set(f"{SVM}.sha256", "0" * 64), "does not match its checksum"),
    ("sha-not-hex", "svm", _set(f"{SVM}.sha256", "xyz"), f"{SVM}.sha256"),
    ("sha-missing", "svm", _delete(f"{SVM}.sha256"), f"{SVM}.sha256 is missing"),
    ("onnx-corrupt", "svm", _corrupt_onnx, "cannot be loaded by onnxruntime"),
    ("onnx-swapped", "net", _swap_onnx, "svm.onnx output"),
    ("onnx-net-width", "net", _net_wrong_width, "takes 39 features but skin.json lists 40 bins"),
    ("onnx-external-data", "net", _net_external_data, "keeps weights in external files"),
    ("onnx-net-outputs", "net", _net_wrong_outputs, "output 'logits' has shape (2, 5)"),
    # layout
    ("layout-fewer-ids-than-outputs", "net", _drop_location, "models.net.n_locations is 3 but layout.ids lists 2"),
    ("layout-fewer-ids-consistent-doc", "net", _drop_location_consistent, "output 'logits' has shape (2, 4)"),
    ("layout-ids-duplicate", "svm", _set("layout.ids.1", 0), "layout.ids"),
    ("layout-ids-float", "svm", _set("layout.ids.0", 0.0), "layout.ids[0]"),
    ("layout-ids-negative", "svm", _set("layout.ids.0", -1), "layout.ids[0]"),
    ("layout-ids-empty", "svm", _do(lambda m, a: m["layout"].update(ids=[], xy_cm=[])), "layout.ids"),
    ("layout-xy-short", "svm", _do(lambda m, a: m["layout"]["xy_cm"].pop()), "layout.xy_cm"),
    ("layout-xy-nan", "svm", _do(lambda m, a: m["layout"]["xy_cm"][0].__setitem__(0, math.nan)), "layout.xy_cm[0][0]"),
    ("layout-xy-triple", "svm", _do(lambda m, a: m["layout"]["xy_cm"][1].append(0.0)), "layout.xy_cm[1]"),
    ("layout-circumference-negative", "svm", _set("layout.circumference_cm", -23.5), "layout.circumference_cm"),
    ("layout-missing-ids", "svm", _delete("layout.ids"), "layout.ids is missing"),
    # rig
    ("rig-fs-missing", "svm", _delete("rig.fs_hz"), "rig.fs_hz is missing"),
    ("rig-fs-string", "svm", _set("rig.fs_hz", "192k"), "rig.fs_hz"),
    ("rig-fs-zero", "svm", _set("rig.fs_hz", 0), "rig.fs_hz"),
    ("rig-band-above-nyquist", "svm", _set("rig.f_hi_hz", 120_000), "rig is not a valid rig"),
    ("rig-n-chirp-float", "svm", _set("rig.n_chirp", 20480.5), "rig.n_chirp"),
    ("rig-pwm-not-list", "svm", _set("rig.pwm_hz", 30000), "rig.pwm_hz"),
    ("rig-unknown-key", "svm", _set("rig.gain_db", 3), "rig has unknown keys"),
    ("rig-string", "svm", _set("rig", "jaco"), "rig must be a JSON object"),
    # document
    ("format-wrong", "svm", _set("format", "onnx-bundle"), "format"),
    ("version-1", "svm", _set("version", 1), "version is 1; this sonicskin reads version 2 and 3"),  # written before artifacts were sealed
    ("version-4", "svm", _set("version", 4), "version is 4; this sonicskin reads version 2 and 3"),
    ("version-string", "svm", _set("version", "1"), "version"),
    ("unknown-top-key", "svm", _set("modles", {}), "has unknown keys ['modles']"),
    ("models-list", "svm", _set("models", ["svm"]), "models must be a JSON object"),
    ("models-empty", "svm", _set("models", {}), "models is empty"),
    ("models-unknown-name", "svm", _do(lambda m, a: m["models"].__setitem__("cnn", m["models"]["svm"])), "models has unknown keys"),
    ("net-kind-wrong", "net", _set("models.net.kind", "svc-ovo"), "models.net.kind"),
    ("net-hparams-list", "net", _set("models.net.hparams", [1]), "models.net.hparams"),
    ("training-missing-split", "svm", _delete("training.split"), "training.split is missing"),
    ("training-test-not-list", "svm", _set("training.split.test", "s000"), "training.split.test"),
    ("sonicskin-version-number", "svm", _set("sonicskin_version", 0.1), "sonicskin_version"),
    # the pooled SVR force model (issue 36): its numbers are bound to each other and to the inputs
    ("svr-ragged", "svm", _svr_force(lambda v, n: v["support_vectors"][0].pop()), f"{SVR_FIELD}.support_vectors"),
    ("svr-dual-short", "svm", _svr_force(lambda v, n: v["dual"].pop()), f"{SVR_FIELD}.support_vectors has shape"),
    ("svr-more-than-the-inputs", "svm", _svr_force(lambda v, n: v.update(mean=v["mean"] + [0.0], scale=v["scale"] + [1.0])),
     f"{SVR_FIELD}.mean has"),
    ("svr-huge", "svm", _svr_force(lambda v, n: v["dual"].__setitem__(0, 1e300)), f"{SVR_FIELD}.dual must hold finite"),
    ("svr-scale-zero", "svm", _svr_force(lambda v, n: v["scale"].__setitem__(0, 0.0)), f"{SVR_FIELD}.scale"),
    ("svr-gamma-string", "svm", _svr_force(lambda v, n: v.update(gamma="0.1")), f"{SVR_FIELD}.gamma"),
    ("svr-missing", "svm", _svr_force(lambda v, n: v.pop("support_vectors")), f"{SVR_FIELD}.support_vectors is missing"),
    ("svr-curves", "svm", _do(lambda m, a: (_svr_force()(m, a), m["models"]["svm"]["force"].__setitem__("curves", {"0": 1}))),
     "models.svm.force.curves must be empty"),
]
MUTATIONS += [(f"missing-{k}", "svm", _delete(k), f"{k} is missing")
              for k in ("format", "version", "sonicskin_version", "rig", "layout", "features", "min_force_n", "training",
                        "models")]

# -- raw files that are not a skin.json document -----------------------------------------------------------------
RAW = [
    ("truncated", lambda text: text[: len(text) // 2], "is corrupt"),
    ("empty", lambda text: "", "is corrupt"),
    ("json-list", lambda text: json.dumps([json.loads(text)]), "the top level must be a JSON object, got list"),
    ("json-string", lambda text: json.dumps("skin"), "the top level must be a JSON object, got str"),
    ("json-null", lambda text: "null", "the top level must be a JSON object, got NoneType"),
    ("not-utf8", lambda text: "\udcff", "is corrupt"),
    ("duplicate-key", lambda text: text[:-1] + ', "version": 1}', "the key 'version' appears twice"),
    ("deeply-nested", lambda text: "[" * 100_000 + "]" * 100_000, "is corrupt"),
    ("threshold-nan-literal", lambda text: re.sub(r'"threshold": [^,]+', '"threshold": NaN', text),
     "models.svm.threshold must be finite"),
    ("bins-infinity-literal", lambda text: text.replace('"bins": [', '"bins": [Infinity, ', 1), "features.bins[0]"),
]


@pytest.mark.parametrize("name, model, edit, field", MUTATIONS, ids=[m[0] for m in MUTATIONS])
def test_mutated_artifact_is_refused(art, name, model, edit, field):
    meta = _meta(art)
    edit(meta, art)
    _write(art, meta)
    _refused(art, model, field)


@pytest.mark.parametrize("name, mangle, field", RAW, ids=[r[0] for r in RAW])
def test_malformed_skin_json_is_refused(art, name, mangle, field):
    text = mangle((art / "skin.json").read_text())
    (art / "skin.json").write_bytes(text.encode("utf-8", "surrogateescape"))
    _refused(art, "svm", field)


def test_a_pooled_svr_force_loads_and_predicts_what_it_was_fitted_to(art):
    """A well-formed pooled SVR force, sealed as a writer seals it, loads; the runtime's force is the model's."""
    meta = _meta(art)
    _svr_force()(meta, art)
    _reseal(art, meta)
    rt = SkinRuntime(art, "svm")
    want = PooledSVR.from_dict(meta["models"]["svm"]["force"])
    x = np.random.default_rng(1).normal(size=(3, meta["models"]["svm"]["n_in"]))
    np.testing.assert_allclose(rt.head.force_model.predict(None, np.zeros(3, int), inputs=x), want.predict(None, None, inputs=x))


def test_mutation_count():
    """The README states how many malformed artifacts the tests try; keep it in step."""
    assert len(MUTATIONS) + len(RAW) + len(OTHER_REFUSALS) >= 120


def test_valid_artifact_loads_and_predicts(built):
    art, data = built
    meta = load_skin(art)
    assert set(meta["models"]) == {"net", "svm"}
    t = load_features_cached(Dataset(data), progress=False)
    for model in ("net", "svm"):
        rt = SkinRuntime(art, model)
        p = replay_sessions(rt, t, sorted(set(t["session"])))  # each session a stream, as the live loop runs it
        assert p.location.shape == (len(t),) and set(np.unique(p.location[~p.calibrating])) <= {0, 1, 2}
        assert np.all(p.force_n[~p.touch] == 0) and np.isfinite(p.force_n).all()
    # The SVM on its own training recording: it finds the pressed marker and sees the presses.
    rt = SkinRuntime(art, "svm")
    p = replay_sessions(rt, t, sorted(set(t["session"])))
    firm = (t["location"] >= 0) & (t["force_n"] > 2)
    assert np.mean(p.location[firm] == t["location"][firm]) > 0.9
    assert np.mean(p.touch[firm]) > 0.8 and np.mean(p.touch[quiet_mask(t)]) < 0.1


def _refresh_often(meta, _a):
    meta["features"]["alpha_s"] = meta["calibration"]["alpha_s"] = 3.0


@pytest.mark.parametrize("edit", [_refresh_often, _set("layout.circumference_cm", None),
                                  _set("models.svm.force.curves", {}), _delete("calibration"),
                                  _delete("models.svm.parity"), _set("training.extra_note", "free text")],
                         ids=["refresh-every-reference", "flat-layout", "no-force-sensor", "no-calibration-copy", "no-parity",
                              "training-free-key"])
def test_valid_variants_still_load(art, edit):
    meta = _meta(art)
    edit(meta, art)
    _write(art, meta)
    with pytest.raises(ArtifactError, match="svm.onnx was trained with|exported with svm.onnx|digest does not match"):
        SkinRuntime(art, "svm")  # an edit after export is refused ...
    _reseal(art, meta)  # ... and the same variant sealed as a writer seals it loads
    rt = SkinRuntime(art, "svm")
    assert rt.predict_inputs(np.zeros((3, N_BINS), np.float32)).location.shape == (3,)


def test_two_location_svm_artifact(tmp_path, rig):
    """The 2-class SVM graph (2 output columns instead of N (N-1) / 2 = 1) passes the ONNX check."""
    data = tmp_path / "data"
    simulate_dataset(Scenario(**{**TINY, "layout": {**TINY["layout"], "nx": 2}}), rig, data, progress=False,
                     log=lambda *_: None)
    build_svm_artifact(data, tmp_path / "art", n_bins=20, progress=False, log=lambda *_: None)
    rt = SkinRuntime(tmp_path / "art", "svm")
    assert rt.n_locations == 2 and rt.predict_inputs(np.zeros((2, 20), np.float32)).scores.shape == (2, 2)


# -- refusals that are not a skin.json edit ---------------------------------------------------------------------
def _other_rig(a):
    SkinRuntime(a, "svm", rig=Rig(fs_hz=96_000, f_hi_hz=40_000))


def _other_layout(a):  # an artifact for 3 markers run on the 31-marker link of a scenario
    SkinRuntime(a, "svm", layout=Scenario.load("moving").make_layout())


def _moved_markers(a):
    lay = Layout.from_dict(_meta(a)["layout"])
    SkinRuntime(a, "svm", layout=Layout(lay.ids, lay.xy_cm + [0.0, 3.0], lay.circumference_cm))


def _no_skin_json(a):
    (a / "skin.json").unlink()
    SkinRuntime(a, "svm")


def _folder_is_file(a):
    SkinRuntime(a / "svm.onnx", "svm")


def _model_not_in_artifact(a):
    SkinRuntime(a, "cnn")


def _net_absent(a):
    meta = _meta(a)
    del meta["models"]["net"]
    _write(a, meta)
    SkinRuntime(a, "net")


def _compare_reads_schema(a):
    from sonicskin.compare import compare_artifact

    meta = _meta(a)
    del meta["training"]
    _write(a, meta)
    compare_artifact(a)


OTHER_REFUSALS = [
    ("other-rig", _other_rig, "trained for another rig (fs_hz: 192000"),
    ("other-layout", _other_layout, "trained for 3 locations (ids 0..2) but the surface here has 31 locations"),
    ("moved-markers", _moved_markers, "markers sit elsewhere"),
    ("no-skin-json", _no_skin_json, "skin.json missing"),
    ("folder-is-a-file", _folder_is_file, "skin.json missing"),
    ("model-not-in-artifact", _model_not_in_artifact, "model 'cnn' is not in the artifact"),
    ("net-not-in-artifact", _net_absent, "model 'net' is not in the artifact (it has ['svm'])"),
    ("compare-missing-training", _compare_reads_schema, "training is missing"),
]


@pytest.mark.parametrize("name, act, field", OTHER_REFUSALS, ids=[o[0] for o in OTHER_REFUSALS])
def test_other_refusals(art, name, act, field):
    with pytest.raises(ArtifactError) as e:
        act(art)
    assert "\n" not in str(e.value) and field in str(e.value), str(e.value)


def test_check_layout_31_markers_on_the_36_marker_plate():
    link, plate = Scenario.load("moving").make_layout(), Scenario.load("plate-aluminium").make_layout()
    meta = {"layout": link.to_dict()}
    check_layout(meta, link)  # its own layout: fine
    with pytest.raises(ArtifactError, match=r"trained for 31 locations \(ids 0\.\.30\) but the surface here has 36"):
        check_layout(meta, plate)


def test_writer_refuses_what_the_reader_would(built, tmp_path):
    """skin_json validates before writing: a NaN threshold or a short reference never reaches disk."""
    art, _ = built
    meta = _meta(art)
    out = tmp_path / "out"
    out.mkdir()
    shutil.copy(art / "svm.onnx", out / "svm.onnx")
    for field, value in (("threshold", math.nan), ("reference_scores", meta["models"]["svm"]["reference_scores"][:-1])):
        svm = {**meta["models"]["svm"], field: value}
        with pytest.raises(ArtifactError, match=f"models.svm.{field}"):
            skin_json(out, rig=meta["rig"], layout=meta["layout"], spec=FeatureSpec.from_dict(meta["features"]),
                      min_force_n=0.5, training=meta["training"], models={"svm": svm})
        assert not (out / "skin.json").exists()
    # A NaN in a free-form field is refused too (NaN is not JSON).
    with pytest.raises(ArtifactError, match="NaN or infinite"):
        skin_json(out, rig=meta["rig"], layout=meta["layout"], spec=FeatureSpec.from_dict(meta["features"]),
                  min_force_n=0.5, training={**meta["training"], "svm_train_time_s": math.nan},
                  models={"svm": dict(meta["models"]["svm"])})
    assert not (out / "skin.json").exists()


def test_validate_skin_accepts_what_the_writer_wrote(built):
    art, _ = built
    meta = _meta(art)
    assert validate_skin(meta) is meta
    assert json.loads(json.dumps(meta, allow_nan=False)) == meta  # strict JSON on disk


# -- section 3: no code from files --------------------------------------------------------------------------------
class _Payload:
    """Unpickling this runs ``exec``: what a crafted checkpoint does."""

    def __init__(self, marker: Path):
        self.marker = marker

    def __reduce__(self):
        return exec, (f"open({str(self.marker)!r}, 'w').write('pwned')",)


def _cli(argv, capsys) -> tuple[int, str]:
    from sonicskin.cli import main

    rc = main(argv)
    return rc, capsys.readouterr().err


def test_malicious_checkpoint_is_refused_without_running(tmp_path, capsys):
    torch = pytest.importorskip("torch")
    marker = tmp_path / "pwned.txt"
    evil = tmp_path / "evil.ckpt"
    torch.save({"state_dict": {}, "hyper_parameters": {}, "sonicskin": {"x": _Payload(marker)}}, evil)
    rc, err = _cli(["export", "--run", str(evil), "--out", str(tmp_path / "out")], capsys)
    assert rc == 2 and not marker.exists()
    assert err.count("\n") == 1 and "Traceback" not in err, err
    assert "refused to load" in err and "could run code" in err and "global exec" in err, err
    assert not (tmp_path / "out").exists()
    # The payload is live: an unsafe load (what export did before) runs it.  Keep this test honest.
    torch.load(evil, weights_only=False)
    assert marker.read_text() == "pwned"


def test_raw_pickle_and_non_checkpoints_are_refused(tmp_path, capsys):
    pytest.importorskip("torch")
    import pickle

    marker = tmp_path / "pwned.txt"
    raw = tmp_path / "raw.ckpt"
    raw.write_bytes(pickle.dumps({"state_dict": _Payload(marker)}))
    for run, why in ((raw, "not the zip archive"), (REPO / "README.md", "is not a checkpoint"),
                     (tmp_path / "nothing", "does not exist")):
        rc, err = _cli(["export", "--run", str(run), "--out", str(tmp_path / "out")], capsys)
        assert rc == 2 and err.count("\n") == 1 and "Traceback" not in err and why in err, err
    assert not marker.exists() and not (tmp_path / "out").exists()


def test_checkpoint_loader_rebuilds_the_module(tmp_path):
    """A plain checkpoint (numpy strings in its metadata, as before the metadata was kept plain) loads
    with weights_only=True; one whose weights do not fit its hyper-parameters, or without metadata, is refused."""
    torch = pytest.importorskip("torch")
    from sonicskin.training.checkpoint import CheckpointError, load_checkpoint
    from sonicskin.training.module import SkinLitModule

    lit = SkinLitModule(n_in=6, n_locations=2, hidden=(8,))
    meta = {"data": "d", "rig": Rig.load("jaco").to_dict(), "layout": {"ids": [0, 1], "xy_cm": [[0.0, 0.0], [1.2, 0.0]]},
            "spec": {"bins": [0, 1, 2, 3, 4, 5], "mode": "relative", "beta_s": 3.0, "alpha_s": 1200.0},
            "split": {"train": [np.str_("s000")], "val": [], "test": []}, "min_force_n": 0.5}
    hp = {**dict(lit.hparams), "_instantiator": "lightning.pytorch.cli.instantiate_module"}
    good = tmp_path / "good.ckpt"
    torch.save({"state_dict": lit.state_dict(), "hyper_parameters": hp, "sonicskin": meta}, good)
    back = load_checkpoint(good)
    assert back.meta["split"]["train"] == ["s000"] and not back.training
    x = torch.randn(3, 6)
    assert torch.equal(back(x)[0], lit.eval()(x)[0])
    bad = tmp_path / "bad.ckpt"
    torch.save({"state_dict": lit.state_dict(), "hyper_parameters": {**hp, "n_in": 7}, "sonicskin": meta}, bad)
    with pytest.raises(CheckpointError, match="weights do not fit"):
        load_checkpoint(bad)
    torch.save({"state_dict": lit.state_dict(), "hyper_parameters": hp}, bad)
    with pytest.raises(CheckpointError, match="no sonicskin metadata"):
        load_checkpoint(bad)
    torch.save({"state_dict": lit.state_dict(), "hyper_parameters": hp, "sonicskin": {"data": "d"}}, bad)
    with pytest.raises(CheckpointError, match=r"metadata lacks \['layout', 'min_force_n', 'rig', 'spec', 'split'\]"):
        load_checkpoint(bad)
    torch.save([1, 2], bad)
    with pytest.raises(CheckpointError, match="holds a list"):
        load_checkpoint(bad)


# Code that loads objects (not data) from files: never in the package.
UNSAFE = [
    (r"^\s*(import|from)\s+(c?pickle|dill|joblib|shelve|marshal|cloudpickle)\b", "pickle-family import"),
    (r"\b(pickle|joblib|dill)\.loads?\(", "pickle load"),
    (r"\byaml\.(load|unsafe_load|full_load|load_all)\(", "yaml.load (use yaml.safe_load)"),
    (r"allow_pickle\s*=\s*True", "allow_pickle=True"),
    (r"weights_only\s*=\s*False", "weights_only=False"),
    (r"\btorch\.load\((?![^)]*weights_only\s*=\s*True)", "torch.load without weights_only=True"),
    (r"\.load_from_checkpoint\(", "Lightning load_from_checkpoint (unpickles)"),
    (r"\bread_pickle\(|\bto_pickle\(", "pandas pickle"),
]
PACKAGE_DIRS = ("sonicskin", "training", "export", "models", "benchmarks", "examples")


def _unsafe_lines(text: str) -> list[tuple[int, str]]:
    return [(i + 1, why) for i, line in enumerate(text.splitlines())
            for pat, why in UNSAFE if re.search(pat, line)]


def test_scanner_flags_unsafe_loading():
    for snippet in ("import pickle", "x = pickle.load(fh)", "yaml.load(fh, Loader=yaml.Loader)", "np.load(p, allow_pickle=True)",
                    "torch.load(p, weights_only=False)", "torch.load(p)", "M.load_from_checkpoint(p)", "import joblib"):
        assert _unsafe_lines(snippet), snippet
    for snippet in ("yaml.safe_load(fh)", "np.load(p, allow_pickle=False)", "torch.load(p, map_location='cpu', weights_only=True)"):
        assert not _unsafe_lines(snippet), snippet


def test_no_code_from_files_in_the_package():
    files = [p for d in PACKAGE_DIRS if (REPO / d).is_dir() for p in (REPO / d).rglob("*.py")]
    assert len(files) > 20
    hits = [f"{p.relative_to(REPO)}:{n}: {why}" for p in files for n, why in _unsafe_lines(p.read_text())]
    assert not hits, hits


# -- fuzz: any edit of any field is either accepted (and the model runs) or refused with one line ----------------
def _leaves(d, path=()):
    """Every (path, value) of a JSON document, containers included."""
    yield path, d
    if isinstance(d, dict):
        for k, v in d.items():
            yield from _leaves(v, (*path, k))
    elif isinstance(d, list):
        for i, v in enumerate(d[:4]):  # the first few entries of long lists (bins, reference scores)
            yield from _leaves(v, (*path, i))


JSON_VALUES = st.recursive(
    st.none() | st.booleans() | st.integers(-(2**70), 2**70) | st.floats() | st.text(max_size=6),
    lambda inner: st.lists(inner, max_size=3) | st.dictionaries(st.text(max_size=4), inner, max_size=2), max_leaves=4)


@pytest.fixture(scope="module")
def fuzz_art(built, tmp_path_factory):
    a = tmp_path_factory.mktemp("fuzz") / "art"
    shutil.copytree(built[0], a)
    return a


@settings(max_examples=int(os.environ.get("SONICSKIN_FUZZ_EXAMPLES", 200)), deadline=None,
          suppress_health_check=[HealthCheck.too_slow])
@given(data=st.data())
def test_fuzzed_skin_json_is_accepted_or_refused_in_one_line(fuzz_art, data):
    a = fuzz_art  # only skin.json changes; the ONNX files stay
    meta = _meta(a)
    paths = [p for p, _ in _leaves(meta) if p]
    path = data.draw(st.sampled_from(paths), label="path")
    parent = meta
    for k in path[:-1]:
        parent = parent[k]
    if data.draw(st.booleans(), label="delete") and isinstance(parent, dict):
        del parent[path[-1]]
    else:
        parent[path[-1]] = data.draw(JSON_VALUES, label="value")
    original = (a / "skin.json").read_text()
    try:
        (a / "skin.json").write_text(json.dumps(meta))
        for model in ("net", "svm"):
            try:
                rt = SkinRuntime(a, model)
            except ArtifactError as e:
                assert "\n" not in str(e) and str(e).strip(), str(e)
                continue
            p = rt.predict_inputs(np.zeros((2, len(rt.spec.bins)), np.float32))  # what loads, runs
            assert p.location.shape == (2,) and np.isfinite(p.force_n).all()
    finally:
        (a / "skin.json").write_text(original)
