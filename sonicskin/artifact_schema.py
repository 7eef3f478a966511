"""The one schema of a deployment artifact's ``skin.json``, checked completely before anything runs.

Every reader goes through :func:`sonicskin.artifact.load_skin` and every writer checks what it writes with
:func:`validate_skin`; a document that does not fit is refused with one :class:`ArtifactError` line naming the field,
what is wrong and what to do.  The files: docs/artifact.md."""

from __future__ import annotations

import math
import re
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np

from . import kinds
from .drift import DriftError, DriftTracker
from .errors import ArtifactError, is_number
from .features import MODES, FeatureSpec
from .force import MODELS, PooledForce, PooledSVR
from .rig import Layout, Rig

__all__ = ["ArtifactError", "ARTIFACT_FORMAT", "ARTIFACT_VERSION", "READABLE_VERSIONS", "REEXPORT", "validate_skin", "nonfinite_field"]

ARTIFACT_FORMAT = "sonicskin-artifact"
ARTIFACT_VERSION = 3
#: Versions this sonicskin reads: 2 (before the network's touch decision moved out of its graph into the head,
#: sonicskin.head; such a graph decides touches itself, so its entry has no detector) and 3.
READABLE_VERSIONS = (2, 3)
MAX_PROBES = 64
REEXPORT = "export the artifact again (`sonicskin export --run DIR` or `sonicskin fit-svm`)"
MAX_ABS_SCORE = 1e4       # per-location SVM scores are votes (< N) and relative dB inputs
MAX_THRESHOLD_DB = 1e3
MAX_ABS_COEF = 1e12       # force curves from one press can be ill-conditioned but stay finite

_TOP = {"format", "version", "sonicskin_version", "rig", "layout", "features", "min_force_n", "calibration", "training",
        "models", "digest", "selection", "drift"}
_RIG_REQUIRED = ("fs_hz", "f_lo_hz", "f_hi_hz", "n_chirp", "pwm_hz", "pwm_halfwidth_hz")
_RIG_OPTIONAL = ("amplitude", "name", "sweep_b64")
_COMMON = {"file", "sha256", "kind", "n_in", "n_locations", "parity", "probe", "force_reliable"}
_CURVE_KEYS = {"model", "theta", "coef", "center", "scale", "r2", "e_lo", "e_hi"}
_SHA = re.compile(r"[0-9a-f]{64}")


def _short(v: Any, n: int = 60) -> str:
    s = repr(v).replace("\n", " ")
    return s if len(s) <= n else s[: n - 3] + "..."


class _Doc:
    """Checks of one document; every failure is one line ``<source>: <field> <problem>; <fix>``."""

    MAX_SCORE, MAX_THRESHOLD = MAX_ABS_SCORE, MAX_THRESHOLD_DB

    def __init__(self, source: str):
        self.source = source

    def force(self, force, field: str, layout_ids: list[int], n_in: int) -> None:
        _check_force(self, force, field, layout_ids, n_in)

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
        if not is_number(v, finite=False):
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
        if not is_number(v, integer=True):
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


def _matrix(doc: _Doc, v: Any, field: str, shape: tuple[int | None, ...], lo: float, hi: float) -> np.ndarray:
    """A JSON list (of lists) of finite numbers in [lo, hi] of ``shape`` (None: any length), as an array."""
    try:
        a = np.asarray(v, dtype=np.float64)
    except (TypeError, ValueError):
        doc.fail(field, f"must be {'a list of equal-length lists' if len(shape) > 1 else 'a list'} of numbers")
    if a.ndim != len(shape) or any(w is not None and n != w for n, w in zip(a.shape, shape)) or 0 in a.shape:
        doc.fail(field, f"has shape {a.shape}, expected {tuple('n' if w is None else w for w in shape)} (non-empty)")
    if not np.all(np.isfinite(a)) or np.any(a < lo) or np.any(a > hi):
        doc.fail(field, f"must hold finite numbers in [{lo:g}, {hi:g}]")
    return a


def _check_svr(doc: _Doc, svr: Any, field: str, n_in: int | None) -> None:
    svr = doc.obj(svr, field)
    doc.keys(svr, {"mean", "scale", "gamma", "intercept", "dual", "support_vectors"}, field)
    mean = _matrix(doc, doc.get(svr, "mean", field), f"{field}.mean", (None,), -MAX_ABS_COEF, MAX_ABS_COEF)
    k = mean.size
    if n_in is not None and k > n_in:
        doc.fail(f"{field}.mean", f"has {k} values, more than the {n_in} inputs")
    _matrix(doc, doc.get(svr, "scale", field), f"{field}.scale", (k,), 1e-300, MAX_ABS_COEF)
    doc.num(doc.get(svr, "gamma", field), f"{field}.gamma", lo=1e-300, hi=MAX_ABS_COEF)
    doc.num(doc.get(svr, "intercept", field), f"{field}.intercept", lo=-MAX_ABS_COEF, hi=MAX_ABS_COEF)
    dual = _matrix(doc, doc.get(svr, "dual", field), f"{field}.dual", (None,), -MAX_ABS_COEF, MAX_ABS_COEF)
    _matrix(doc, doc.get(svr, "support_vectors", field), f"{field}.support_vectors", (dual.size, k), -MAX_ABS_COEF,
            MAX_ABS_COEF)


def _check_force(doc: _Doc, force: Any, field: str, layout_ids: list[int], n_in: int | None = None) -> None:
    force = doc.obj(force, field)
    if force.get("model") == PooledSVR.NAME:  # one RBF support-vector regression over the first inputs
        doc.keys(force, {"model", "curves", "svr"}, field)
        if doc.obj(doc.get(force, "curves", field), f"{field}.curves"):
            doc.fail(f"{field}.curves", "must be empty for the pooled SVR force model")
        _check_svr(doc, doc.get(force, "svr", field), f"{field}.svr", n_in)
        return
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
    if (not name or name in (".", "..") or "/" in name or "\\" in name or "\0" in name or ":" in name or Path(name).name != name):
        doc.fail(field, f"must be a plain file name inside the artifact folder, got {_short(name)}",
                 "keep the ONNX files next to skin.json and name them without a directory")
    return name


def _check_model(doc: _Doc, name: str, m: Any, *, n_in: int, layout_ids: list[int], sealed: bool = True) -> None:
    f = f"models.{name}"
    kind = kinds.get(name)
    m = doc.obj(m, f)
    doc.keys(m, _COMMON | kind.keys, f)
    _check_file_name(doc, doc.get(m, "file", f), f"{f}.file")
    if sealed:
        sha = doc.str(doc.get(m, "sha256", f), f"{f}.sha256")
        if not _SHA.fullmatch(sha):
            doc.fail(f"{f}.sha256", f"must be 64 lowercase hex digits, got {_short(sha)}")
    doc.const(doc.get(m, "kind", f), f"{f}.kind", kind.graph)
    m_in = doc.int(doc.get(m, "n_in", f), f"{f}.n_in", lo=1)
    if m_in > n_in:  # a model reads the first n_in bins of features.bins (OSPA order; version 3: the SVM a prefix)
        doc.fail(f"{f}.n_in", f"is {m_in}: the model takes {m_in} features but skin.json lists {n_in} bins in features.bins")
    n_loc = len(layout_ids)
    m_loc = doc.int(doc.get(m, "n_locations", f), f"{f}.n_locations", lo=1)
    if m_loc != n_loc:
        doc.fail(f"{f}.n_locations", f"is {m_loc} but layout.ids lists {n_loc} locations")
    if "parity" in m:
        doc.obj(m["parity"], f"{f}.parity")
    if not isinstance(m.get("force_reliable", False), bool):
        doc.fail(f"{f}.force_reliable", f"must be true or false, got {_short(m['force_reliable'])}")
    if sealed:
        _check_probe(doc, doc.get(m, "probe", f), f"{f}.probe", m_in, kind.outputs(n_loc))
    kind.check_entry(doc, m, f, n_in=m_in, layout_ids=layout_ids)


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
    """Model selection's report (never run): what each kind's :meth:`~sonicskin.kinds.ModelKind.selection_lines` can read."""
    sel = doc.obj(sel, "selection")
    doc.keys(sel, {k for kind in kinds.KINDS.values() for k in kind.selection_keys}, "selection")
    for k, v in sel.items():
        if v is not None:
            doc.obj(v, f"selection.{k}")
    for kind in kinds.KINDS.values():
        try:
            kind.selection_lines(sel)
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
    or ``None``: Python's json reads and writes them, strict JSON (and :func:`sonicskin.integrity.canonical`) has no such numbers."""
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
    """Check a parsed ``skin.json`` and return it; ``sealed=False``, the writer's: no checksums, probes or digest yet."""
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
        try:
            DriftTracker.from_dict(meta["drift"], rig)
        except DriftError as e:
            doc.fail("drift", f"is not a drift tracker for this rig ({e})")
    if "selection" in meta:  # what model selection chose and its validation estimate (sonicskin.selection); reported only
        _check_selection(doc, meta["selection"])
    models = doc.obj(doc.get(meta, "models", ""), "models")
    if not models:
        doc.fail("models", "is empty")
    doc.keys(models, set(kinds.KINDS), "models")
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
