"""The one schema of a deployment artifact's ``skin.json``, checked completely before anything runs.

Every reader (:class:`sonicskin.runtime.SkinRuntime`, :mod:`sonicskin.compare`) goes through
:func:`load_skin`, and every writer (:func:`sonicskin.artifact.skin_json`) checks what it writes with
:func:`validate_skin`.  A document that does not fit is refused with one :class:`ArtifactError` line
naming the field (``models.svm.threshold``), what is wrong and what to do.

The schema, field by field (``N`` locations, ``B`` selected bins)::

    format              "sonicskin-artifact"
    version             1
    sonicskin_version   string
    rig                 fs_hz, f_lo_hz, f_hi_hz, n_chirp, pwm_hz, pwm_halfwidth_hz (required),
                        amplitude, name, sweep_b64 (optional); finite, in range (see Rig)
    layout              ids: N >= 1 unique ints >= 0; xy_cm: N pairs of finite cm;
                        circumference_cm: null or finite > 0
    features            bins: B >= 1 unique ints, 0 <= b < rig.n_band; mode: absolute | relative;
                        beta_s: finite, 0 < beta_s <= 3600 (s); alpha_s: finite, beta_s <= alpha_s <= 1e7 (s)
    min_force_n         finite >= 0 (N)
    calibration         optional copy of beta_s / alpha_s, equal to the features' ones
    training            provenance: data (string), split {train, val, test: [session names]}, other keys free
    digest              64 lowercase hex digits: sha256 of the canonical JSON of this document without
                        ``digest`` (which holds every model file's sha256): one digest binds the artifact
    drift               optional (version 3): drift tracking's training rest spectrum over the band and its limits
                        (sonicskin.drift.DriftTracker.to_dict); the stream estimates the channel's frequency
                        stretch against it at every Alg. 2 reference and maps each chirp back
    selection           optional: what model selection chose on the training/validation presses and its
                        validation estimate (svm, force, detection, net; see sonicskin.selection), reported only
    models              {"net": ..., "svm": ...}, at least one:
      file              a plain file name inside the artifact folder (no directories, no symlink out of it),
                        at most 256 MB
      sha256            64 lowercase hex digits of that file
      probe             {inputs: 1..64 rows of B finite numbers, outputs: one entry per graph output, null or
                        the export-time output rows}: re-run at load, the model must reproduce them
      kind              "skinnet" (net) | "svc-ovo" (svm)
      n_in              == B;  n_locations == N
      parity            optional dict of export parity figures;  hparams: optional dict (net)
      net only (version 3):
        detector          optional {mode: "head" | "input-rms" | "either", bias: finite, threshold: 0..1e3 (dB RMS),
                          reference: optional 1..B finite numbers, bins: optional int 1..B}: the touch decision the
                          network head applies to the graph's outputs (absent: the graph's own p(touch) >= 0.5)
      svm only:
        reference_scores  N + B finite numbers, |v| <= 1e4 (Alg. 2's initial S_c)
        threshold         finite, 0 < t <= 1e3 (dB RMS); 0 when ``detection`` is false
        detection         optional bool (default true); false: trained on touches only, no detector
        detector          "input-rms" | "paper" (version 3: the paper's max calibrated score);  detector_bins:
                          optional int 1..B (the input-RMS statistic reads the first ones; default all)
        energy_ref_db     finite, |e| <= 1e4
        train_false_touch_rate, train_missed_touch_rate   optional, in [0, 1] (null without detection)
        force             model (a force curve model); curves: {} or one per layout id, each
                          {model, theta, coef (the model's count), center, scale > 0, r2 <= 1, e_lo <= e_hi};
                          or model "pooled-ridge", curves {}, pooled {alpha, coef: B numbers, loc_coef: one
                          per layout id, intercept}

and the ONNX graphs (:func:`check_session`): one float input ``(batch, B)``; the net outputs logits
``(batch, N + 1)`` and force ``(batch, N)``; the SVM a label and ``N (N - 1) / 2`` pairwise values
(2 columns when ``N = 2``).

Integrity (:func:`check_integrity`): every ONNX file carries, in its ``metadata_props`` under
``sonicskin.binding``, what it was trained with: the model's name and kind, the rig, the layout (ids and
coordinates), the features (bins in their order, mode, Alg. 2's beta/alpha), ``min_force_n``, the
training split and the sha256 of its ``skin.json`` entry's parameters (threshold, reference scores, force curves, hparams).
Loading compares that binding with ``skin.json`` field by field, then the document's digest, then
re-runs the probe inputs.  Each step names what differs in one line.
"""

from __future__ import annotations

import hashlib
import json
import math
import re
from collections import Counter
from pathlib import Path
from typing import Any

from .errors import SonicskinError

__all__ = ["ArtifactError", "ARTIFACT_FORMAT", "ARTIFACT_VERSION", "MODEL_KINDS", "load_skin", "validate_skin",
           "model_file", "read_model_file", "check_session", "check_rig", "check_layout", "canonical", "artifact_digest",
           "binding", "check_integrity"]

ARTIFACT_FORMAT = "sonicskin-artifact"
ARTIFACT_VERSION = 3
#: Versions this sonicskin reads: 2 (before the network's touch decision moved out of its graph into the head,
#: sonicskin.head; such a graph decides touches itself, so its entry has no detector) and 3.
READABLE_VERSIONS = (2, 3)
BINDING_KEY = "sonicskin.binding"
MAX_MODEL_BYTES = 256 * 2**20  # an SVM of 31 locations x 300 bins is a few MB; a net < 1 MB
MAX_PROBES = 64
PROBE_RTOL = PROBE_ATOL = 1e-3  # onnxruntime on another CPU may round differently; another model differs by far more
MODEL_KINDS = {"net": "skinnet", "svm": "svc-ovo"}
REEXPORT = "export the artifact again (`sonicskin export --run DIR` or `sonicskin fit-svm`)"
MAX_SKIN_JSON_BYTES = 64 * 2**20
MAX_ABS_SCORE = 1e4       # per-location SVM scores are votes (< N) and relative dB inputs
MAX_THRESHOLD_DB = 1e3
MAX_ABS_COEF = 1e12       # force curves from one press can be ill-conditioned but stay finite

_TOP = {"format", "version", "sonicskin_version", "rig", "layout", "features", "min_force_n", "calibration", "training",
        "models", "digest", "selection", "drift"}
_SELECTION_KEYS = {"svm", "force", "detection", "net"}
_RIG_REQUIRED = ("fs_hz", "f_lo_hz", "f_hi_hz", "n_chirp", "pwm_hz", "pwm_halfwidth_hz")
_RIG_OPTIONAL = ("amplitude", "name", "sweep_b64")
_COMMON = {"file", "sha256", "kind", "n_in", "n_locations", "parity", "probe"}
_UNBOUND = {"file", "sha256", "parity", "probe"}  # entry keys written after the model file (not in its binding)
_MODEL_KEYS = {"net": _COMMON | {"hparams", "detector"},
               "svm": _COMMON | {"reference_scores", "threshold", "detector", "detector_bins", "detection", "energy_ref_db",
                                 "train_false_touch_rate",
                                 "train_missed_touch_rate", "force"}}
_CURVE_KEYS = {"model", "theta", "coef", "center", "scale", "r2", "e_lo", "e_hi"}
_SHA = re.compile(r"[0-9a-f]{64}")


class ArtifactError(SonicskinError):
    """An artifact that cannot run here; the message names the field, what does not fit and what to do."""


def _short(v: Any, n: int = 60) -> str:
    s = repr(v).replace("\n", " ")
    return s if len(s) <= n else s[: n - 3] + "..."


class _Doc:
    """Checks of one document; every failure is one line ``<source>: <field> <problem>; <fix>``."""

    def __init__(self, source: str):
        self.source = source

    def fail(self, field: str, problem: str, fix: str = REEXPORT):
        raise ArtifactError(f"{self.source}: {field} {problem}; {fix}")

    def obj(self, v: Any, field: str) -> dict:
        if not isinstance(v, dict):
            self.fail(field, f"must be a JSON object, got {type(v).__name__}")
        return v

    def get(self, d: dict, key: str, field: str) -> Any:
        if key not in d:
            self.fail(f"{field}.{key}" if field else key, "is missing")
        return d[key]

    def keys(self, d: dict, allowed: set[str], field: str) -> None:
        unknown = sorted(set(d) - allowed)
        if unknown:
            self.fail(field or "the document", f"has unknown keys {unknown} (known: {sorted(allowed)})")

    def num(self, v: Any, field: str, *, lo: float | None = None, hi: float | None = None, lo_open: bool = False,
            none_ok: bool = False) -> float | None:
        if v is None and none_ok:
            return None
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            self.fail(field, f"must be a number, got {_short(v)}")
        try:
            v = float(v)
        except OverflowError:  # an integer beyond the float range
            self.fail(field, f"must be finite, got an integer of {len(str(v))} digits")
        if not math.isfinite(v):
            self.fail(field, f"must be finite, got {v}")
        if lo is not None and (v <= lo if lo_open else v < lo):
            self.fail(field, f"must be {'>' if lo_open else '>='} {lo:g}, got {v:g}")
        if hi is not None and v > hi:
            self.fail(field, f"must be <= {hi:g}, got {v:g}")
        return float(v)

    def int(self, v: Any, field: str, *, lo: int | None = None, hi: int | None = None) -> int:
        if isinstance(v, bool) or not isinstance(v, int):
            self.fail(field, f"must be an integer, got {_short(v)}")
        if lo is not None and v < lo:
            self.fail(field, f"must be >= {lo}, got {v}")
        if hi is not None and v > hi:
            self.fail(field, f"must be < {hi + 1}, got {v}")
        return v

    def str(self, v: Any, field: str) -> str:
        if not isinstance(v, str):
            self.fail(field, f"must be a string, got {_short(v)}")
        return v

    def list(self, v: Any, field: str, *, n: int | None = None, nonempty: bool = False) -> list:
        if not isinstance(v, list):
            self.fail(field, f"must be a JSON list, got {type(v).__name__}")
        if n is not None and len(v) != n:
            self.fail(field, f"has {len(v)} entries, expected {n}")
        if nonempty and not v:
            self.fail(field, "is empty")
        return v

    def choice(self, v: Any, field: str, options) -> str:
        if not isinstance(v, str) or v not in options:
            self.fail(field, f"must be one of {sorted(options)}, got {_short(v)}")
        return v

    def const(self, v: Any, field: str, want: Any, fix: str = REEXPORT) -> None:
        if type(v) is not type(want) or v != want:
            self.fail(field, f"must be {want!r}, got {_short(v)}", fix)


def _unique(doc: _Doc, values: list, field: str) -> None:
    rep = sorted(k for k, n in Counter(values).items() if n > 1)
    if rep:
        doc.fail(field, f"are not unique (repeated: {rep[:5]})")


def _check_rig(doc: _Doc, rig: Any):
    from .rig import Rig

    rig = doc.obj(rig, "rig")
    doc.keys(rig, set(_RIG_REQUIRED) | set(_RIG_OPTIONAL), "rig")
    for k in _RIG_REQUIRED:
        doc.get(rig, k, "rig")
    doc.num(rig["fs_hz"], "rig.fs_hz", lo=0, lo_open=True, hi=10e6)
    doc.num(rig["f_lo_hz"], "rig.f_lo_hz", lo=0, lo_open=True)
    doc.num(rig["f_hi_hz"], "rig.f_hi_hz", lo=0, lo_open=True)
    doc.int(rig["n_chirp"], "rig.n_chirp", lo=64, hi=2**22)
    for i, f in enumerate(doc.list(rig["pwm_hz"], "rig.pwm_hz")):
        doc.num(f, f"rig.pwm_hz[{i}]", lo=0)
    doc.num(rig["pwm_halfwidth_hz"], "rig.pwm_halfwidth_hz", lo=0)
    if "amplitude" in rig:
        doc.num(rig["amplitude"], "rig.amplitude", lo=0, lo_open=True, hi=1)
    if "name" in rig:
        doc.str(rig["name"], "rig.name")
    if rig.get("sweep_b64") is not None:
        doc.str(rig["sweep_b64"], "rig.sweep_b64")
    try:
        return Rig.from_dict(rig)
    except (ValueError, TypeError) as e:  # cross-field rules of Rig (band inside Nyquist, sweep length, ...)
        doc.fail("rig", f"is not a valid rig ({e})")


def _check_layout(doc: _Doc, layout: Any):
    from .rig import Layout

    layout = doc.obj(layout, "layout")
    doc.keys(layout, {"ids", "xy_cm", "circumference_cm"}, "layout")
    ids = doc.list(doc.get(layout, "ids", "layout"), "layout.ids", nonempty=True)
    for i, v in enumerate(ids):
        doc.int(v, f"layout.ids[{i}]", lo=0)
    _unique(doc, ids, "layout.ids")
    xy = doc.list(doc.get(layout, "xy_cm", "layout"), "layout.xy_cm", n=len(ids))
    for i, p in enumerate(xy):
        doc.list(p, f"layout.xy_cm[{i}]", n=2)
        for j, c in enumerate(p):
            doc.num(c, f"layout.xy_cm[{i}][{j}]", lo=-1e4, hi=1e4)
    doc.num(layout.get("circumference_cm"), "layout.circumference_cm", lo=0, lo_open=True, hi=1e4, none_ok=True)
    return Layout.from_dict(layout)


def _check_features(doc: _Doc, feats: Any, n_band: int, rig=None):
    from .features import MODES, FeatureSpec

    feats = doc.obj(feats, "features")
    doc.keys(feats, {"bins", "mode", "beta_s", "alpha_s"}, "features")
    bins = doc.list(doc.get(feats, "bins", "features"), "features.bins", nonempty=True)
    for i, b in enumerate(bins):
        doc.int(b, f"features.bins[{i}]")
        if not 0 <= b < n_band:
            doc.fail(f"features.bins[{i}]", f"is {b}, outside the rig's {n_band} band bins (0 <= b < {n_band})")
    _unique(doc, bins, "features.bins")
    if rig is not None:  # OSPA's matched filter never selects a bin inside a PWM band
        allowed = rig.allowed_mask
        for i, b in enumerate(bins):
            if not allowed[b]:
                f_khz = rig.freqs_hz[rig.band_bins[b]] / 1e3
                doc.fail(f"features.bins[{i}]", f"is {b} ({f_khz:.2f} kHz), inside a PWM band of the rig, which no model "
                                                f"reads (the motor's noise is there)")
    doc.choice(doc.get(feats, "mode", "features"), "features.mode", MODES)
    beta = doc.num(doc.get(feats, "beta_s", "features"), "features.beta_s", lo=0, lo_open=True, hi=3600)
    alpha = doc.num(doc.get(feats, "alpha_s", "features"), "features.alpha_s", lo=0, lo_open=True, hi=1e7)
    if alpha < beta:
        doc.fail("features.alpha_s", f"({alpha:g} s) is shorter than the reference it refreshes (beta_s = {beta:g} s)")
    return FeatureSpec.from_dict(feats)


def _check_pooled(doc: _Doc, pooled: Any, field: str, layout_ids: list[int], n_in: int) -> None:
    pooled = doc.obj(pooled, field)
    doc.keys(pooled, {"alpha", "coef", "loc_coef", "intercept"}, field)
    doc.num(doc.get(pooled, "alpha", field), f"{field}.alpha", lo=0, hi=1e12)
    for i, v in enumerate(doc.list(doc.get(pooled, "coef", field), f"{field}.coef", n=n_in)):
        doc.num(v, f"{field}.coef[{i}]", lo=-MAX_ABS_COEF, hi=MAX_ABS_COEF)
    lc = doc.obj(doc.get(pooled, "loc_coef", field), f"{field}.loc_coef")
    if set(lc) != {str(i) for i in layout_ids}:
        doc.fail(f"{field}.loc_coef", "must have one value per layout id")
    for k, v in lc.items():
        doc.num(v, f"{field}.loc_coef.{k}", lo=-MAX_ABS_COEF, hi=MAX_ABS_COEF)
    doc.num(doc.get(pooled, "intercept", field), f"{field}.intercept", lo=-MAX_ABS_COEF, hi=MAX_ABS_COEF)


def _check_force(doc: _Doc, force: Any, field: str, layout_ids: list[int], n_in: int | None = None) -> None:
    from .force import MODELS, PooledForce

    force = doc.obj(force, field)
    if force.get("model") == PooledForce.NAME:  # one linear model over the inputs and the location
        doc.keys(force, {"model", "curves", "pooled"}, field)
        if doc.obj(doc.get(force, "curves", field), f"{field}.curves"):
            doc.fail(f"{field}.curves", "must be empty for the pooled force model")
        _check_pooled(doc, doc.get(force, "pooled", field), f"{field}.pooled", layout_ids, n_in)
        return
    doc.keys(force, {"model", "curves"}, field)
    model = doc.choice(doc.get(force, "model", field), f"{field}.model", MODELS)
    n_coef = MODELS[model].design([0.0], 1.0).shape[1]
    curves = doc.obj(doc.get(force, "curves", field), f"{field}.curves")
    ids = {str(i) for i in layout_ids}
    if curves and set(curves) != ids:
        extra, missing = sorted(set(curves) - ids), sorted(ids - set(curves), key=int)
        doc.fail(f"{field}.curves", f"must have one curve per layout id or none (not in the layout: {extra[:5]}, "
                                    f"missing: {missing[:5]})")
    for k, c in curves.items():
        f = f"{field}.curves.{k}"
        c = doc.obj(c, f)
        doc.keys(c, _CURVE_KEYS, f)
        for key in _CURVE_KEYS:
            doc.get(c, key, f)
        doc.const(c["model"], f"{f}.model", model)
        doc.num(c["theta"], f"{f}.theta", lo=-1e3, hi=1e3)
        for i, v in enumerate(doc.list(c["coef"], f"{f}.coef", n=n_coef)):
            doc.num(v, f"{f}.coef[{i}]", lo=-MAX_ABS_COEF, hi=MAX_ABS_COEF)
        doc.num(c["center"], f"{f}.center", lo=-MAX_ABS_SCORE, hi=MAX_ABS_SCORE)
        doc.num(c["scale"], f"{f}.scale", lo=0, lo_open=True, hi=MAX_ABS_SCORE)
        doc.num(c["r2"], f"{f}.r2", hi=1.0)
        lo = doc.num(c["e_lo"], f"{f}.e_lo", lo=-MAX_ABS_SCORE, hi=MAX_ABS_SCORE)
        hi = doc.num(c["e_hi"], f"{f}.e_hi", lo=-MAX_ABS_SCORE, hi=MAX_ABS_SCORE)
        if lo > hi:
            doc.fail(f"{f}.e_lo", f"({lo:g} dB) is above e_hi ({hi:g} dB)")


def _check_file_name(doc: _Doc, name: Any, field: str) -> str:
    name = doc.str(name, field)
    if (not name or name in (".", "..") or "/" in name or "\\" in name or "\0" in name or ":" in name
            or Path(name).name != name):
        doc.fail(field, f"must be a plain file name inside the artifact folder, got {_short(name)}",
                 "keep the ONNX files next to skin.json and name them without a directory")
    return name


def _check_model(doc: _Doc, name: str, m: Any, *, n_in: int, layout_ids: list[int], sealed: bool = True) -> None:
    f = f"models.{name}"
    m = doc.obj(m, f)
    doc.keys(m, _MODEL_KEYS[name], f)
    _check_file_name(doc, doc.get(m, "file", f), f"{f}.file")
    if sealed:
        sha = doc.str(doc.get(m, "sha256", f), f"{f}.sha256")
        if not _SHA.fullmatch(sha):
            doc.fail(f"{f}.sha256", f"must be 64 lowercase hex digits, got {_short(sha)}")
    doc.const(doc.get(m, "kind", f), f"{f}.kind", MODEL_KINDS[name])
    m_in = doc.int(doc.get(m, "n_in", f), f"{f}.n_in", lo=1)
    if m_in != n_in:
        doc.fail(f"{f}.n_in", f"is {m_in}: the model takes {m_in} features but skin.json lists {n_in} bins in features.bins")
    n_loc = len(layout_ids)
    m_loc = doc.int(doc.get(m, "n_locations", f), f"{f}.n_locations", lo=1)
    if m_loc != n_loc:
        doc.fail(f"{f}.n_locations", f"is {m_loc} but layout.ids lists {n_loc} locations")
    if "parity" in m:
        doc.obj(m["parity"], f"{f}.parity")
    if sealed:
        _check_probe(doc, doc.get(m, "probe", f), f"{f}.probe", n_in, probe_widths(name, n_loc))
    if name == "net":
        if "hparams" in m:
            doc.obj(m["hparams"], f"{f}.hparams")
        if "detector" in m:
            _check_net_detector(doc, m["detector"], f"{f}.detector", n_in)
        return
    if n_loc < 2:
        doc.fail(f"{f}.n_locations", "must be >= 2 for an SVM (it separates locations)")
    ref = doc.list(doc.get(m, "reference_scores", f), f"{f}.reference_scores")
    if len(ref) != n_loc + n_in:
        doc.fail(f"{f}.reference_scores", f"has {len(ref)} values, expected n_locations + n_in = {n_loc} + {n_in} = "
                                          f"{n_loc + n_in}")
    for i, v in enumerate(ref):
        doc.num(v, f"{f}.reference_scores[{i}]", lo=-MAX_ABS_SCORE, hi=MAX_ABS_SCORE)
    detection = m.get("detection", True)
    if not isinstance(detection, bool):
        doc.fail(f"{f}.detection", f"must be true or false, got {detection!r}")
    if detection:
        doc.num(doc.get(m, "threshold", f), f"{f}.threshold", lo=0, lo_open=True, hi=MAX_THRESHOLD_DB)
    elif doc.get(m, "threshold", f) != 0:  # trained on touches only: every chirp is taken as a touch
        doc.fail(f"{f}.threshold", "must be 0 when detection is false (an SVM trained on touches only)")
    doc.choice(doc.get(m, "detector", f), f"{f}.detector", ("input-rms", "paper"))
    if "detector_bins" in m:  # the detector reads the first detector_bins inputs (default: all)
        doc.int(m["detector_bins"], f"{f}.detector_bins", lo=1, hi=n_in)
    doc.num(doc.get(m, "energy_ref_db", f), f"{f}.energy_ref_db", lo=-MAX_ABS_SCORE, hi=MAX_ABS_SCORE)
    for k in ("train_false_touch_rate", "train_missed_touch_rate"):
        if k in m and not (m[k] is None and not detection):
            doc.num(m[k], f"{f}.{k}", lo=0, hi=1)
    _check_force(doc, doc.get(m, "force", f), f"{f}.force", layout_ids, n_in)


def _check_net_detector(doc: _Doc, d: Any, field: str, n_in: int) -> None:
    d = doc.obj(d, field)
    doc.keys(d, {"mode", "bias", "threshold", "reference", "bins"}, field)
    doc.choice(doc.get(d, "mode", field), f"{field}.mode", ("head", "input-rms", "either"))
    if "bias" in d:
        doc.num(d["bias"], f"{field}.bias", lo=-MAX_ABS_SCORE, hi=MAX_ABS_SCORE)
    if "threshold" in d:
        doc.num(d["threshold"], f"{field}.threshold", lo=0, hi=MAX_THRESHOLD_DB)
    elif d["mode"] != "head":
        doc.fail(f"{field}.threshold", f"is missing (mode {d['mode']!r} thresholds the input-RMS statistic)")
    if "reference" in d:
        ref = doc.list(d["reference"], f"{field}.reference", nonempty=True)
        if len(ref) > n_in:
            doc.fail(f"{field}.reference", f"has {len(ref)} values, more than the {n_in} inputs")
        for i, v in enumerate(ref):
            doc.num(v, f"{field}.reference[{i}]", lo=-MAX_ABS_SCORE, hi=MAX_ABS_SCORE)
    if "bins" in d:
        doc.int(d["bins"], f"{field}.bins", lo=1, hi=n_in)


def _check_probe(doc: _Doc, probe: Any, field: str, n_in: int, widths: list[int | None]) -> None:
    """Probe inputs (k rows of n_in) and the outputs the model gave on them at export (null: not compared)."""
    probe = doc.obj(probe, field)
    doc.keys(probe, {"inputs", "outputs"}, field)
    rows = doc.list(doc.get(probe, "inputs", field), f"{field}.inputs", nonempty=True)
    if len(rows) > MAX_PROBES:
        doc.fail(f"{field}.inputs", f"has {len(rows)} rows, more than {MAX_PROBES}")
    for i, r in enumerate(rows):
        for j, v in enumerate(doc.list(r, f"{field}.inputs[{i}]", n=n_in)):
            doc.num(v, f"{field}.inputs[{i}][{j}]", lo=-MAX_ABS_SCORE, hi=MAX_ABS_SCORE)
    outs = doc.list(doc.get(probe, "outputs", field), f"{field}.outputs", n=len(widths))
    for k, (o, w) in enumerate(zip(outs, widths)):
        if w is None:
            if o is not None:
                doc.fail(f"{field}.outputs[{k}]", "must be null (this output is not compared)")
            continue
        for i, r in enumerate(doc.list(o, f"{field}.outputs[{k}]", n=len(rows))):
            for j, v in enumerate(doc.list(r, f"{field}.outputs[{k}][{i}]", n=w)):
                doc.num(v, f"{field}.outputs[{k}][{i}][{j}]", lo=-MAX_ABS_COEF, hi=MAX_ABS_COEF)


def _check_selection(doc: _Doc, sel: Any) -> None:
    """Model selection's report (reported only, never run): an object of objects that
    :func:`sonicskin.selection.format_selection` (what ``compare --artifact`` prints) can read."""
    from .selection import format_selection

    sel = doc.obj(sel, "selection")
    doc.keys(sel, _SELECTION_KEYS, "selection")
    for k, v in sel.items():
        if v is not None:
            doc.obj(v, f"selection.{k}")
    try:
        format_selection(sel)
    except (KeyError, TypeError, AttributeError, ValueError, IndexError) as e:
        what = f"{type(e).__name__} {e}" if isinstance(e, KeyError) else f"{type(e).__name__}: {' '.join(str(e).split())[:80]}"
        doc.fail("selection", f"is not the report model selection writes (reading it fails with {what})")


def _check_training(doc: _Doc, tr: Any) -> None:
    tr = doc.obj(tr, "training")
    doc.str(doc.get(tr, "data", "training"), "training.data")
    split = doc.obj(doc.get(tr, "split", "training"), "training.split")
    for k in ("train", "val", "test"):
        for i, s in enumerate(doc.list(doc.get(split, k, "training.split"), f"training.split.{k}")):
            doc.str(s, f"training.split.{k}[{i}]")


def nonfinite_field(obj: Any, path: str = "") -> tuple[str, float] | None:
    """The first field of a JSON-like document holding NaN or +-Infinity (``"models.net.hparams.lr"``, the value),
    or ``None``: Python's json reads and writes them, strict JSON (and :func:`canonical`) has no such numbers."""
    if isinstance(obj, dict):
        items = obj.items()
    elif isinstance(obj, (list, tuple)):
        items = ((f"[{i}]", v) for i, v in enumerate(obj))
    else:
        try:
            return None if isinstance(obj, (bool, str)) or obj is None or math.isfinite(obj) else (path, float(obj))
        except (TypeError, OverflowError):  # not a number, or an integer beyond the float range (a finite one)
            return None
    for k, v in items:
        sub = f"{path}{k}" if str(k).startswith("[") else (f"{path}.{k}" if path else str(k))
        hit = nonfinite_field(v, sub)
        if hit is not None:
            return hit
    return None


def validate_skin(meta: Any, *, source: str = "skin.json", sealed: bool = True) -> dict:
    """Check a parsed ``skin.json`` against the schema (without touching any file); return it.

    Raises :class:`ArtifactError` naming the first field that does not fit.  ``sealed=False`` (the
    writer, before the model files are stamped): checksums, probes and the digest are not there yet.
    """
    doc = _Doc(source)
    if not isinstance(meta, dict):
        doc.fail("the top level", f"must be a JSON object, got {type(meta).__name__}")
    doc.const(doc.get(meta, "format", ""), "format", ARTIFACT_FORMAT,
              "this is not a sonicskin artifact; point to a folder written by `sonicskin export` or `fit-svm`")
    version = doc.get(meta, "version", "")
    if isinstance(version, bool) or version not in READABLE_VERSIONS:
        doc.fail("version", f"is {_short(version)}; this sonicskin reads version "
                            f"{' and '.join(map(str, READABLE_VERSIONS))} artifacts", REEXPORT)
    doc.keys(meta, _TOP, "")
    doc.str(doc.get(meta, "sonicskin_version", ""), "sonicskin_version")
    rig = _check_rig(doc, doc.get(meta, "rig", ""))
    layout = _check_layout(doc, doc.get(meta, "layout", ""))
    spec = _check_features(doc, doc.get(meta, "features", ""), rig.n_band, rig)
    doc.num(doc.get(meta, "min_force_n", ""), "min_force_n", lo=0, hi=1e4)
    if "calibration" in meta:
        cal = doc.obj(meta["calibration"], "calibration")
        doc.keys(cal, {"beta_s", "alpha_s"}, "calibration")
        for k in ("beta_s", "alpha_s"):
            if k in cal and cal[k] != getattr(spec, k):
                doc.fail(f"calibration.{k}", f"({_short(cal[k])}) differs from features.{k} ({getattr(spec, k)})")
    _check_training(doc, doc.get(meta, "training", ""))
    if "drift" in meta:  # drift tracking's training reference (sonicskin.drift.DriftTracker.to_dict), version 3
        from .drift import DriftError, DriftTracker

        try:
            DriftTracker.from_dict(meta["drift"], rig)
        except DriftError as e:
            doc.fail("drift", f"is not a drift tracker for this rig ({e})")
    if "selection" in meta:  # what model selection chose and its validation estimate (sonicskin.selection); reported only
        _check_selection(doc, meta["selection"])
    models = doc.obj(doc.get(meta, "models", ""), "models")
    if not models:
        doc.fail("models", "is empty")
    doc.keys(models, set(MODEL_KINDS), "models")
    for name, m in models.items():
        _check_model(doc, name, m, n_in=len(spec.bins), layout_ids=list(layout.ids), sealed=sealed)
    bad = nonfinite_field(meta)  # in a free-form field (parity, hparams, training): the checked ones name their own
    if bad is not None:  # json.loads reads NaN/Infinity literals; the digest (strict JSON) cannot hold them
        doc.fail(bad[0], f"is {bad[1]}: NaN and Infinity are not JSON numbers")
    if not sealed:
        return meta
    digest = doc.str(doc.get(meta, "digest", ""), "digest")
    if not _SHA.fullmatch(digest):
        doc.fail("digest", f"must be 64 lowercase hex digits, got {_short(digest)}")
    return meta


def _no_duplicates(pairs):
    keys = [k for k, _ in pairs]
    if len(set(keys)) != len(keys):
        raise ValueError(f"duplicate key {sorted({k for k in keys if keys.count(k) > 1})[0]!r}")
    return dict(pairs)


def load_skin(folder: str | Path) -> dict:
    """Read and validate ``folder/skin.json`` (no duplicate keys; a NaN or Infinity is refused by the field
    that holds it)."""
    folder = Path(folder)
    path = folder / "skin.json"
    if not path.is_file():
        raise ArtifactError(f"{folder} is not a sonicskin artifact (skin.json missing); create one with "
                            f"`sonicskin export` or `sonicskin fit-svm`")
    raw = _read_bounded(path, MAX_SKIN_JSON_BYTES, "an artifact's metadata")
    try:
        meta = json.loads(raw.decode("utf-8"), object_pairs_hook=_no_duplicates)
    except (ValueError, RecursionError) as e:  # JSONDecodeError and UnicodeDecodeError are ValueErrors
        raise ArtifactError(f"{path} is corrupt ({str(e).splitlines()[0][:120]}); {REEXPORT}") from None
    return validate_skin(meta, source=str(path))


def _read_bounded(path: Path, limit: int, what: str) -> bytes:
    """The bytes of ``path``, refused by its size before reading (and never more than ``limit`` read)."""
    size = path.stat().st_size
    if size > limit:
        raise ArtifactError(f"{path} is {size / 2**20:,.0f} MB, more than {what} can be ({limit / 2**20:.0f} MB at most); "
                            f"{REEXPORT}")
    with open(path, "rb") as fh:
        data = fh.read(limit + 1)
    if len(data) > limit:  # grew while being read
        raise ArtifactError(f"{path} is larger than {what} can be ({limit / 2**20:.0f} MB at most); {REEXPORT}")
    return data


def model_file(folder: str | Path, meta: dict, model: str) -> Path:
    """Path of ``model``'s ONNX file, confined to ``folder`` (a symlink may not lead out of it)."""
    folder = Path(folder)
    models = meta["models"]
    if model not in models:
        raise ArtifactError(f"model {model!r} is not in the artifact (it has {sorted(models)}); choose one of those "
                            f"with --model")
    doc = _Doc(str(folder / "skin.json"))
    name = _check_file_name(doc, models[model]["file"], f"models.{model}.file")
    path = folder / name
    if path.is_symlink() or path.exists():
        try:
            real, root = path.resolve(strict=True), folder.resolve()
        except (OSError, RuntimeError) as e:  # a symlink loop (RuntimeError before Python 3.13), a dangling link
            doc.fail(f"models.{model}.file", f"({name}) is a link that leads nowhere ({type(e).__name__}: "
                                             f"{' '.join(str(e).split())[:80]})",
                     "copy the model file into the artifact folder instead of linking it")
        if real.parent != root:
            doc.fail(f"models.{model}.file", f"({name}) is a link to {real}, outside the artifact folder",
                     "copy the model file into the artifact folder instead of linking it")
    if not path.exists():
        raise ArtifactError(f"{path} is missing; copy the whole artifact folder or {REEXPORT}")
    if not path.is_file():
        raise ArtifactError(f"{path} is not a regular file (a folder, FIFO or device); copy the whole artifact folder or "
                            f"{REEXPORT}")
    return path


def read_model_file(folder: str | Path, meta: dict, model: str) -> bytes:
    """The bytes of ``model``'s ONNX file after the confinement and checksum checks."""
    path = model_file(folder, meta, model)
    data = _read_bounded(path, MAX_MODEL_BYTES, "a model file")
    if hashlib.sha256(data).hexdigest() != meta["models"][model]["sha256"]:
        raise ArtifactError(f"{path} does not match its checksum in skin.json: the file is corrupt or was "
                            f"replaced; {REEXPORT}")
    _no_external_data(data, path)
    return data


def _no_external_data(data: bytes, path: Path) -> None:
    """An ONNX file must carry its weights: external data would be read from outside the artifact folder."""
    import onnx

    m = onnx.ModelProto()
    try:
        m.ParseFromString(data)  # the protobuf only: nothing outside the file is read
    except Exception:  # not parseable: onnxruntime reports it when loading
        return
    graphs, ext = [m.graph], []
    while graphs:
        g = graphs.pop()
        ext += [t.name for t in g.initializer if t.data_location == onnx.TensorProto.EXTERNAL]
        for node in g.node:
            for a in node.attribute:
                graphs += ([a.g] if a.HasField("g") else []) + list(a.graphs)
                if a.HasField("t") and a.t.data_location == onnx.TensorProto.EXTERNAL:
                    ext.append(node.name or node.op_type)
    if ext:
        raise ArtifactError(f"{path} keeps weights in external files ({ext[:3]}); an artifact's ONNX files must be "
                            f"self-contained; {REEXPORT}")


def _last_dim(shape) -> int | None:
    return shape[-1] if shape and isinstance(shape[-1], int) else None


def check_session(session, meta: dict, model: str, *, source: str = "") -> None:
    """The ONNX graph of ``model`` against ``skin.json``: input width, output count and widths.

    Declared shapes are checked where they are fixed, and one probe batch of zeros is run to check the
    shapes the graph really produces.
    """
    import numpy as np

    n_in = len(meta["features"]["bins"])
    n_loc = len(meta["layout"]["ids"])
    where = source or f"the {model} model"
    ins, outs = session.get_inputs(), session.get_outputs()
    if len(ins) != 1 or ins[0].type != "tensor(float)" or len(ins[0].shape) != 2:
        raise ArtifactError(f"{where} must take one float input (batch, {n_in}), it takes "
                            f"{[(i.type, i.shape) for i in ins]}; {REEXPORT}")
    if ins[0].shape[-1] != n_in:
        raise ArtifactError(f"{where} takes {ins[0].shape[-1]} features but skin.json lists {n_in} bins; {REEXPORT}")
    if model == "net":
        want = {0: n_loc + 1, 1: n_loc}
        what = f"logits (batch, {n_loc + 1}) and force (batch, {n_loc})"
    else:
        want = {1: n_loc * (n_loc - 1) // 2 if n_loc > 2 else 2}
        what = f"a label and {want[1]} pairwise decision values for {n_loc} locations"
    if len(outs) != 2:
        raise ArtifactError(f"{where} has {len(outs)} outputs, expected {what}; {REEXPORT}")
    declared = {k: _last_dim(outs[k].shape) for k in want}
    # skl2onnx declares the SVC's score output as (batch, n_classes) even with decision_function_shape="ovo",
    # which really yields the K (K - 1) / 2 pairwise values: the probe run below is what counts there.
    allowed = {k: (None, n, n_loc) if model == "svm" else (None, n) for k, n in want.items()}
    try:
        got = session.run(None, {ins[0].name: np.zeros((2, n_in), np.float32)})
    except Exception as e:  # onnxruntime raises its own exception types
        raise ArtifactError(f"{where} fails on a probe input ({str(e).splitlines()[0][:120]}); {REEXPORT}") from None
    for k, n in want.items():
        shape = np.shape(got[k])
        if declared[k] not in allowed[k] or len(shape) != 2 or shape != (2, n):
            raise ArtifactError(f"{where} output {outs[k].name!r} has shape {shape} (declared {outs[k].shape}), "
                                f"expected {what}: the model does not fit layout.ids; {REEXPORT}")


def check_rig(meta: dict, rig, *, what: str = "the artifact", here: str = "") -> None:
    """Refuse to run an artifact on a rig it was not trained for (sample rate, chirp, bands)."""
    from .rig import Rig

    diffs = Rig.from_dict(meta["rig"]).mismatch(rig)
    if diffs:
        raise ArtifactError(f"{what} was trained for another rig ({'; '.join(diffs)}){f' than {here}' if here else ''}; "
                            f"record and train on this rig, or run with {what}'s rig")


def check_layout(meta: dict, layout, *, what: str = "the artifact", here: str = "the surface here") -> None:
    """Refuse to run an artifact on a marker layout it was not trained for.

    ``layout`` is the :class:`sonicskin.rig.Layout` of the surface it will run on (e.g. a scenario's
    ``make_layout()`` or a dataset's layout).  Different ids or count is an error; the same ids at other
    positions too (the model's locations would be reported at the wrong places).
    """
    import numpy as np

    from .rig import Layout

    mine = Layout.from_dict(meta["layout"])
    if mine.ids != layout.ids:
        def span(ids):
            return f"{len(ids)} locations (ids {ids[0]}..{ids[-1]})" if ids else "no locations"
        order = " in another order" if sorted(mine.ids) == sorted(layout.ids) else ""
        raise ArtifactError(f"{what} was trained for {span(mine.ids)} but {here} has {span(layout.ids)}{order}; "
                            f"record and train on this layout, or use data of {what}'s layout")
    if mine != layout:
        d = float(np.max(np.abs(mine.xy_cm - np.asarray(layout.xy_cm, float)))) if mine.xy_cm.shape == np.shape(layout.xy_cm) \
            else float("nan")
        raise ArtifactError(f"{what}'s markers sit elsewhere than those of {here} (up to {d:.2g} cm apart, or another "
                            f"circumference); record and train on this layout, or use data of {what}'s layout")


# -- integrity: one digest over the document, a binding inside every model, probes re-run at load -----------------
RESTORE = "restore the artifact folder as it was exported, or " + REEXPORT


def probe_widths(model: str, n_loc: int) -> list[int | None]:
    """Width of each graph output compared on the probes (``None``: not compared, the SVM's label)."""
    return [n_loc + 1, n_loc] if model == "net" else [None, n_loc * (n_loc - 1) // 2 if n_loc > 2 else 2]


def canonical(obj: Any) -> bytes:
    """One byte string per JSON value: sorted keys, no spaces, ASCII, no NaN (a ``ValueError``)."""
    return json.dumps(obj, sort_keys=True, separators=(",", ":"), ensure_ascii=True, allow_nan=False).encode("ascii")


def artifact_digest(meta: dict) -> str:
    """sha256 of the canonical document without ``digest`` and of every model file's sha256: one value covers
    ``skin.json`` and the model files together."""
    body = {k: v for k, v in meta.items() if k != "digest"}
    models = body.get("models") if isinstance(body.get("models"), dict) else {}
    files = b"".join(f"{k}={m.get('sha256') if isinstance(m, dict) else None}\n".encode() for k, m in sorted(models.items()))
    return hashlib.sha256(b"sonicskin-artifact/2\0" + canonical(body) + b"\0" + files).hexdigest()


def binding(meta: dict, model: str) -> dict:
    """What ``model`` was trained and exported with, as stored inside its ONNX file (``metadata_props``)."""
    entry = {k: v for k, v in meta["models"][model].items() if k not in _UNBOUND}
    return {"model": model, "kind": MODEL_KINDS[model], "rig": meta["rig"], "layout": meta["layout"],
            "features": meta["features"], "min_force_n": meta["min_force_n"], "split": meta["training"]["split"],
            "entry_sha256": hashlib.sha256(canonical(entry)).hexdigest()}


def _describe_order(have: list, want: list, what: str) -> str:
    """How the list in skin.json (``have``) differs from the model's (``want``)."""
    if len(have) != len(want):
        return f"{len(have)} {what} listed, the model has {len(want)}"
    def order(v):  # numbers by value (bins, ids), anything else after them by its text
        return (0, v, "") if isinstance(v, (int, float)) and not isinstance(v, bool) else (1, 0, repr(v))
    if sorted(have, key=order) == sorted(want, key=order):
        if have == sorted(want, key=order) and have != want:
            return f"the model's {what} sorted"
        if have == want[::-1]:
            return f"the model's {what} reversed"
        diff = [i for i, (a, b) in enumerate(zip(have, want)) if a != b]
        return (f"the model's {what} in another order: {len(diff)} positions differ, first index {diff[0]} "
                f"({have[diff[0]]} where the model has {want[diff[0]]})")
    extra = [(i, a) for i, a in enumerate(have) if a not in want]
    i, a = extra[0]
    return f"{len(extra)} not among the model's, first {a} at index {i} where the model has {want[i]}"


def _binding_diff(have: dict, want: dict, file: str) -> tuple[str, str] | None:
    """The first field where skin.json (``want``, from the document) and the model's binding (``have``) differ."""
    if have.get("model") != want["model"] or have.get("kind") != want["kind"]:
        return (f"models.{want['model']}.file", f"({file}) is the {have.get('model')!r} model of an artifact "
                                                f"({have.get('kind')}), not its {want['model']!r} ({want['kind']})")
    hf = have.get("features") if isinstance(have.get("features"), dict) else {}
    wf = want["features"]
    if hf.get("bins") != wf["bins"]:
        return "features.bins", (f"are not the bins {file} was trained with "
                                 f"({_describe_order(wf['bins'], list(hf.get('bins') or []), 'bins')})")
    for k in ("mode", "beta_s", "alpha_s"):
        if hf.get(k) != wf.get(k):
            return f"features.{k}", f"is {wf.get(k)!r} but {file} was trained with {hf.get(k)!r}"
    if hf != wf:
        return "features", f"has other keys than {file} was trained with"
    if have.get("rig") != want["rig"]:
        hr = have.get("rig") if isinstance(have.get("rig"), dict) else {}
        wr = want["rig"]
        keys = sorted(k for k in set(hr) | set(wr) if hr.get(k) != wr.get(k))
        what = ", ".join(f"{k}: {_short(wr.get(k), 24)} vs {_short(hr.get(k), 24)}" for k in keys[:3])
        return "rig", f"differs from the rig {file} was trained on ({what})"
    hl = have.get("layout") if isinstance(have.get("layout"), dict) else {}
    wl = want["layout"]
    if hl.get("ids") != wl["ids"]:
        return "layout.ids", (f"are not the location ids {file} was trained with "
                              f"({_describe_order(wl['ids'], list(hl.get('ids') or []), 'ids')})")
    if hl.get("xy_cm") != wl["xy_cm"]:
        hxy = hl.get("xy_cm") if isinstance(hl.get("xy_cm"), list) else []
        bad = [i for i, a in enumerate(wl["xy_cm"]) if i >= len(hxy) or a != hxy[i]] or [0]
        return "layout.xy_cm", (f"differs from the marker positions {file} was trained with (first at location "
                                f"{wl['ids'][bad[0]]}: {wl['xy_cm'][bad[0]]} vs {hxy[bad[0]] if bad[0] < len(hxy) else None} cm)")
    if hl != wl:
        return "layout", f"differs from the layout {file} was trained with (circumference)"
    if have.get("min_force_n") != want["min_force_n"]:
        return "min_force_n", f"is {want['min_force_n']!r} but {file} was trained with {have.get('min_force_n')!r}"
    if have.get("split") != want["split"]:
        return "training.split", f"is not the split {file} was trained on (the test sessions would include training ones)"
    if have.get("entry_sha256") != want["entry_sha256"]:
        return (f"models.{want['model']}", f"holds other parameters than were exported with {file} (threshold, reference "
                                           f"scores, force curves, hparams, n_in or n_locations changed)")
    if have != want:
        return "the document", f"does not match the binding inside {file}"
    return None


def read_binding(data: bytes) -> dict | None:
    """The binding stored in an ONNX file's ``metadata_props`` (``None``: none, or not parseable)."""
    import onnx

    m = onnx.ModelProto()
    try:
        m.ParseFromString(data)
    except Exception:  # protobuf's DecodeError and friends
        return None
    props = {p.key: p.value for p in m.metadata_props}
    if BINDING_KEY not in props:
        return None
    try:
        b = json.loads(props[BINDING_KEY])
    except (ValueError, RecursionError):
        return None
    return b if isinstance(b, dict) else None


def stamp_binding(path: Path, b: dict) -> None:
    """Store binding ``b`` in the ONNX file at ``path`` (replacing an older one); the graph is unchanged."""
    import onnx

    m = onnx.ModelProto()
    m.ParseFromString(Path(path).read_bytes())
    keep = [(p.key, p.value) for p in m.metadata_props if p.key != BINDING_KEY]
    del m.metadata_props[:]
    for k, v in [*keep, (BINDING_KEY, canonical(b).decode("ascii"))]:
        m.metadata_props.add(key=k, value=v)
    Path(path).write_bytes(m.SerializeToString())


def run_probe(session, inputs) -> list:
    import numpy as np

    return session.run(None, {session.get_inputs()[0].name: np.asarray(inputs, np.float32)})


def check_integrity(session, meta: dict, model: str, data: bytes, *, folder: str | Path) -> None:
    """The model file belongs to this ``skin.json``, and the document is the one exported.

    1. the binding inside the ONNX file equals what ``skin.json`` says (features, rig, layout, parameters);
    2. the document's digest matches its content (every model file's sha256 included);
    3. the probe inputs give the export-time outputs (finite, within 1e-3).
    """
    import numpy as np

    folder = Path(folder)
    src = str(folder / "skin.json")
    file = meta["models"][model]["file"]
    have = read_binding(data)
    if have is None:
        raise ArtifactError(f"{folder / file} carries no sonicskin binding (the bins, layout and rig it was trained with): "
                            f"it is not a model this sonicskin exported; {REEXPORT}")
    diff = _binding_diff(have, binding(meta, model), file)
    if diff:
        raise ArtifactError(f"{src}: {diff[0]} {diff[1]}; {RESTORE}")
    if artifact_digest(meta) != meta["digest"]:
        raise ArtifactError(f"{src} was changed after export: its digest does not match its content; {RESTORE}")
    probe = meta["models"][model]["probe"]
    try:
        got = run_probe(session, probe["inputs"])
    except Exception as e:  # onnxruntime raises its own exception types
        raise ArtifactError(f"{folder / file} fails on its probe inputs ({str(e).splitlines()[0][:120]}); {REEXPORT}") from None
    for k, want in enumerate(probe["outputs"]):
        if want is None:
            continue
        g, w = np.asarray(got[k], np.float64), np.asarray(want, np.float64)
        if g.shape != w.shape or not np.isfinite(g).all() or not np.allclose(g, w, rtol=PROBE_RTOL, atol=PROBE_ATOL):
            why = (f"shape {g.shape} vs {w.shape}" if g.shape != w.shape else "non-finite outputs" if not np.isfinite(g).all()
                   else f"max |difference| {np.abs(g - w).max():.3g}")
            raise ArtifactError(f"{folder / file} does not reproduce the outputs it gave at export on the probe inputs in "
                                f"skin.json (output {k}: {why}): it is not the model this artifact was exported with; {RESTORE}")
