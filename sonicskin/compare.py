"""Side-by-side evaluation of every model of one artifact (the network, the SVM, the LDA; onnxruntime only)."""

from __future__ import annotations

import json
import os
import time
import warnings
from pathlib import Path

import numpy as np

from . import kinds
from .artifact import load_skin
from .dataset import Dataset, FeatureTable, other_wall, wall_record, write_file
from .feature_cache import load_features_cached
from .features import touch_mask
from .integrity import check_layout, check_rig
from .jsonio import json_safe
from .metrics import force_report, localization_report, speed_ratio
from .plots import cdf_panel, confusion_panel, detection_panel, force_panel, location_names, pyplot
from .runtime import Predictions, SkinRuntime

__all__ = ["compare_artifact", "replay_sessions", "stream_metrics", "chirp_latency", "format_comparison", "save_comparison",
           "chirps_per_location", "coverage_note", "split_line", "counts_line", "leading_rest"]


def chirp_latency(rt: SkinRuntime, X_band: np.ndarray, time_s: np.ndarray, *, n: int = 300, warmup: int = 20,
                  boot: bool = True) -> dict:
    """Per-chirp cost, one chirp per call on one thread: the ONNX call alone, and the whole path from band features."""
    st = rt.stream()
    k = 0
    while boot and st.calibrating and k < len(X_band):
        st.chirp(X_band[k], time_s[k])
        k += 1
    if k >= len(X_band):
        raise ValueError(f"the stream has {len(X_band)} chirps, not more than the boot calibration's")
    rows = np.arange(k, len(X_band))
    inputs = st.reference.inputs(X_band[rows][:, st.bins]) if boot else rt.inputs(X_band[rows])
    path, onnx = np.empty(n), np.empty(n)
    for i in range(-warmup, n):
        r = rows[i % rows.size]
        t0 = time.perf_counter()
        if boot:
            st.chirp(X_band[r], time_s[r])
        else:
            rt.predict_inputs(rt.inputs(X_band[r][None]))
        dt = time.perf_counter() - t0
        one = inputs[i % rows.size][None]
        t0 = time.perf_counter()
        rt.run(one)
        dt2 = time.perf_counter() - t0
        if i >= 0:
            path[i], onnx[i] = dt, dt2
    return {"median_ms": float(np.median(path) * 1e3), "p99_ms": float(np.percentile(path, 99) * 1e3),
            "onnx_median_ms": float(np.median(onnx) * 1e3), "onnx_p99_ms": float(np.percentile(onnx, 99) * 1e3)}


def replay_sessions(rt: SkinRuntime, t: FeatureTable, sessions, *, drift: dict | None = None) -> Predictions:
    """Every chirp of ``sessions`` (each a stream) through ``rt`` as the live loop runs it; a stream with too little
    rest to boot Alg. 2 on is scored as it is (absolute inputs) or refused (relative).  ``drift``: receives what drift
    tracking found per session."""
    parts = []
    beta = rt.spec.reference(rt.rig.chirps_per_s).beta
    for s in sessions:
        m = t["session"] == s
        lead_rest = leading_rest(t, s)
        if lead_rest < beta:
            if rt.spec.mode != "absolute":
                raise ValueError(f"session {s} starts with {lead_rest} hands-off chirps, fewer than the {beta} "
                                 f"({rt.spec.beta_s:g} s) the artifact's relative inputs boot their no-touch reference on; "
                                 f"record {rt.spec.beta_s:g} s of rest first, or train with --mode absolute")
            p = rt.predict_inputs(rt.inputs(t.X[m]))
            p.calibrating = np.zeros(int(m.sum()), bool)
            parts.append(p)
        else:
            st = rt.stream()
            parts.append(st.replay(t.X[m], t["time_s"][m]))
            if drift is not None and st.drift is not None:
                drift[str(s)] = st.drift.report()
    return Predictions.concat(parts)


def leading_rest(t: FeatureTable, session: str) -> int:
    """Hands-off chirps at the start of ``session`` (before its first touch): what a boot calibration can use."""
    touched = t["location"][t["session"] == session] >= 0
    return int(np.argmax(touched)) if touched.any() else int(touched.size)


def chirps_per_location(t: FeatureTable, scored: np.ndarray, layout) -> dict[str, int]:
    """How many touch chirps of each layout location were scored (0 for a location never touched)."""
    loc = t["location"][scored]
    return {str(i): int(np.sum(loc == i)) for i in layout.ids}


def coverage_note(counts: dict[str, int]) -> str | None:
    """A sentence when the scored chirps cover fewer locations than the layout has, else ``None``."""
    missing = [k for k, n in counts.items() if n == 0]
    if not missing:
        return None
    shown = ", ".join(missing[:12]) + (", ..." if len(missing) > 12 else "")
    return (f"the scored chirps touch {len(counts) - len(missing)} of the layout's {len(counts)} locations "
            f"(never touched: {shown}); accuracy is over the touched ones only")


def _force(f_true: np.ndarray, f_pred: np.ndarray, sel: np.ndarray) -> dict:
    """Table I on the selected chirps, or why force is absent (no force sensor: NaN or constant force)."""
    g = f_true[sel]
    if not np.isfinite(g).any() or not np.isfinite(f_pred[sel]).any():
        return {"measurable": False, "reason": "absent: no force sensor (force_n is empty/NaN)"}
    if np.ptp(g[np.isfinite(g)]) == 0:
        return {"measurable": False, "reason": f"absent: force_n is constant ({g[np.isfinite(g)][0]:g} N)"}
    return force_report(g, f_pred[sel])


def stream_metrics(p: Predictions, t: FeatureTable, layout, *, min_force_n: float = 0.5, detection: bool = True) -> dict:
    """Localization, position, force and detection of replayed predictions ``p`` of ``t`` (boot chirps: missed touches)."""
    touch = touch_mask(t, min_force_n)
    run = ~p.calibrating
    no_touch = (t["location"] < 0) & run
    if not (touch & run).any():
        raise ValueError(f"no touch chirp left to score ({int(touch.sum())} touch chirps, {int((touch & ~run).sum())} of them "
                         f"in the boot calibration); test on longer sessions or on more of them")
    L = localization_report(t["location"][touch & run], p.location[touch & run], layout)
    true_xy = np.column_stack([t["x_cm"], t["y_cm"]])
    ok_xy = touch & run & np.isfinite(p.xy_cm).all(axis=1)
    cont = layout.distance_cm(p.xy_cm[ok_xy], true_xy[ok_xy])
    return {
        "localization": {k: v for k, v in L.items() if k != "errors_cm"},
        "errors_cm": L["errors_cm"].tolist(),
        "continuous_error_cm": {"median": float(np.median(cont)) if cont.size else float("nan"),
                                "mean": float(np.mean(cont)) if cont.size else float("nan")},
        "force": _force(t["force_n"], p.force_n, touch & p.touch),
        "chirps_per_location": chirps_per_location(t, touch & run, layout),
        "no_touch_chirps": int(no_touch.sum()),
        "detection": ({"false_touch_rate": float(np.mean(p.touch[no_touch])), "missed_touch_rate": float(np.mean(~p.touch[touch]))}
                      if no_touch.any() and touch.any() and detection else
                      {"measurable": False, "reason": "not measurable on this data: no hands-off chirps"}),
    }


def compare_artifact(artifact: str | Path, data: str | Path | None = None, *, sessions: list[str] | None = None,
                     progress: bool = False, latency: bool = True) -> dict:
    """Evaluate every model of ``artifact`` on the test sessions of its split (or ``sessions``), replayed as live."""
    art = Path(artifact)
    meta = load_skin(art)  # the whole skin.json against the schema: one clear error line, no KeyError
    data = data or meta["training"]["data"]
    split = meta["training"]["split"]
    res: dict = {"artifact": str(art), "data": str(data), "models": {}, "labels": kinds.labels()}
    names = [k for k in kinds.names() if k in meta["models"]]
    ds = Dataset(data)
    # The data's rig and marker layout must be the artifact's (else the scores are of the wrong places).
    check_rig(meta, ds.rig, here=f"dataset {ds.root}")
    check_layout(meta, ds.layout, here=f"dataset {ds.root}")
    rts = {k: SkinRuntime(art, k, rig=ds.rig, layout=ds.layout) for k in names}
    t = load_features_cached(ds, progress=progress)
    test = list(dict.fromkeys(sessions or split["test"]))  # a session named twice is scored once
    if not test:
        raise ValueError(f"{art} was trained on every session of its data ({', '.join(split['train'])}) and names no test "
                         f"session; choose the sessions to score with --test SESSION...")
    unknown = sorted(set(test) - set(ds.sessions))
    if unknown:
        raise ValueError(f"test session(s) {', '.join(unknown)} are not in {data} (it has {', '.join(ds.sessions)})")
    res["split"] = {"train": list(split["train"]), "val": list(split["val"]), "test": test,
                    **({"refit": True} if meta["training"].get("refit") else {})}
    res["test_sessions"] = test
    what = other_wall(meta["training"].get("wall"), wall_record(ds.meta.get("source"), ds.rig, ds.layout), "this dataset's")
    if what:
        warnings.warn(f"dataset {ds.root} was recorded on {what} than {art} was trained on: these are the artifact's "
                      f"numbers on a wall it never saw, not its accuracy", stacklevel=2)
    own = os.path.realpath(ds.root) == os.path.realpath(meta["training"]["data"])  # session names are only names
    res["trained_on_test"] = sorted(set(test) & (set(split["train"]) | set(split["val"]))) if own else []
    te = t.select(np.isin(t["session"], test))
    detection = all(m.get("detection", True) for m in meta["models"].values())  # False: trained on touches only
    for k, rt in rts.items():
        drift: dict = {}
        p = replay_sessions(rt, te, test, drift=drift)
        r = stream_metrics(p, te, ds.layout, min_force_n=meta.get("min_force_n", 0.5), detection=detection)
        sel = touch_mask(te, meta.get("min_force_n", 0.5)) & p.touch  # the chirps force is scored on (plotted)
        r["force_points"] = {"true_n": te["force_n"][sel].tolist(), "predicted_n": p.force_n[sel].tolist()}
        if latency:  # on the first test stream, as it was scored (booted, or without a boot: replay_sessions)
            first = te["session"] == test[0]
            boot = leading_rest(te, test[0]) >= rt.spec.reference(rt.rig.chirps_per_s).beta
            r["latency"] = chirp_latency(rt, te.X[first], te["time_s"][first], boot=boot)
        else:
            r["latency"] = None
        r["model_bytes"] = int((art / rt.m["file"]).stat().st_size)
        r["drift"] = drift or None  # per test session: the stretch drift tracking estimated and its warning
        r["train_time_s"] = meta["training"].get(f"{k}_train_time_s")
        res["models"][k] = r
    beta = rts[names[0]].spec.reference(rts[names[0]].rig.chirps_per_s).beta
    res["boot_chirps"] = beta
    res["no_boot_sessions"] = [s for s in test if leading_rest(te, s) < beta]
    first = res["models"][names[0]]
    res["chirps_per_location"] = first["chirps_per_location"]
    res["coverage_note"] = coverage_note(first["chirps_per_location"])
    return res


def split_line(split: dict) -> str:
    """``train s000 | validation none | test s002, s003``."""
    def names(v):
        return ", ".join(v) if v else "none"
    refit = (f" (deployed models refitted on {' + '.join(list(split['train']) + list(split['val']))})"
             if split.get("refit") and split.get("val") else "")
    return f"train {names(split.get('train'))} | validation {names(split.get('val'))}{refit} | test {names(split.get('test'))}"


def counts_line(counts: dict[str, int]) -> str:
    """``scored 160 touch chirps: 40 at each of 4 locations`` or the spread when they differ."""
    n = np.array(list(counts.values()))
    touched = n[n > 0]
    if not touched.size:
        return "scored no touch chirp"
    each = (f"{touched[0]} at each of {touched.size} locations" if np.ptp(touched) == 0 else
            f"{touched.min()}-{touched.max()} per location over {touched.size} locations (median {np.median(touched):g})")
    return f"scored {int(n.sum())} touch chirps: {each}"


def _or_na(d: dict, fmt) -> str:
    return "n/a" if d.get("measurable") is False else fmt(d)


def format_comparison(res: dict, title: str = "") -> str:
    lat = lambda k, f: (lambda r: "n/a" if r["latency"] is None else f(r["latency"][k]))  # noqa: E731
    rows = [
        ("accuracy", lambda r: f"{r['localization']['accuracy']:.1%}"),
        ("error < 2 cm", lambda r: f"{r['localization']['within_2cm']:.1%}"),
        ("error < 3 cm", lambda r: f"{r['localization']['within_3cm']:.1%}"),
        ("continuous xy error (median)", lambda r: f"{r['continuous_error_cm']['median']:.2f} cm"),
        ("force RMSE", lambda r: _or_na(r["force"], lambda d: f"{d['rmse_n']:.2f} N" + (
            f" ({d['n']} of {d['n'] + d['n_unmeasured']} chirps with a force)" if d.get("n_unmeasured") else ""))),
        ("force sigma", lambda r: _or_na(r["force"], lambda d: f"{d['sigma_n']:.2f} N")),
        ("force cross-correlation", lambda r: _or_na(r["force"], lambda d: f"{d['xcorr']:.1%}")),
        ("false touches", lambda r: _or_na(r["detection"], lambda d: f"{d['false_touch_rate']:.2%}")),
        ("missed touches", lambda r: _or_na(r["detection"], lambda d: f"{d['missed_touch_rate']:.2%}")),
        ("ONNX model per chirp, median", lat("onnx_median_ms", lambda v: f"{v * 1e3:.0f} us")),
        ("ONNX model per chirp, p99", lat("onnx_p99_ms", lambda v: f"{v * 1e3:.0f} us")),
        ("inputs -> touch/xy/force, median", lat("median_ms", lambda v: f"{v * 1e3:.0f} us")),
        ("inputs -> touch/xy/force, p99", lat("p99_ms", lambda v: f"{v * 1e3:.0f} us")),
        ("model size", lambda r: f"{r['model_bytes'] / 1e3:.0f} kB"),
        ("training time (to exported epoch)", lambda r: "n/a" if r["train_time_s"] is None else f"{r['train_time_s']:.1f} s"),
    ]
    models = res["models"]
    head = kinds.labels()
    w = max(len(r[0]) for r in rows)
    split = res.get("split") or {"test": res["test_sessions"]}
    out = [title or f"{res['data']}", f"  sessions: {split_line(split)}"]
    if res.get("chirps_per_location"):
        out.append(f"  {counts_line(res['chirps_per_location'])}")
    if res.get("coverage_note"):
        out.append(f"  note: {res['coverage_note']}")
    if res.get("no_boot_sessions"):
        out.append(f"  note: no boot calibration on {', '.join(res['no_boot_sessions'])} (fewer than the {res['boot_chirps']} "
                   f"hands-off chirps it needs at the start): every chirp scored, against the training reference")
    if res.get("trained_on_test"):
        out.append(f"  note: {', '.join(res['trained_on_test'])} trained or validated this artifact: not a held-out test")
    out.append(f"  {'':{w}}" + "".join(f"  {head[k]:>12}" for k in models))
    out += [f"  {name:{w}}" + "".join(f"  {fmt(r):>12}" for r in models.values()) for name, fmt in rows]
    first = next(iter(models.values()))
    for key, what in (("force", "force"), ("detection", "detection")):
        if first[key].get("measurable") is False:
            out.append(f"  {what}: {first[key]['reason']}")
    drift = first.get("drift")  # the models share the reference's chirps: one line
    if drift:
        out.append("  drift tracking (the frequency stretch each test session showed): " + ", ".join(
            f"{s} {d['stretch']:+.1e}" + ("" if d.get("kelvin") is None else f" ({d['kelvin']:+.1f} K)")
            for s, d in drift.items()))
        warned = [f"{s}: {d['warning']}" for s, d in drift.items() if d.get("warning")]
        if warned:
            out.append(f"  warning: drift tracking on {warned[0]}" + (f" (and {len(warned) - 1} more)" if len(warned) > 1 else ""))
    net, svm = models.get(kinds.NETWORK), models.get(kinds.BASELINE)
    if net and svm and net["latency"] and svm["latency"]:
        speed = speed_ratio(net["latency"]["onnx_median_ms"], svm["latency"]["onnx_median_ms"])
        speed2 = speed_ratio(net["latency"]["median_ms"], svm["latency"]["median_ms"])
        out.append(f"  per chirp, the network is {speed} than the SVM in onnxruntime ({speed2} with post-processing; same run)"
                   .replace("as fast than", "as fast as"))
    return "\n".join(out)


def save_comparison(res: dict, out_dir: str | Path, layout, title: str = "") -> list[Path]:
    plt = pyplot()
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    # strict JSON: a metric that is not measurable here (NaN) is null, never a NaN literal other readers refuse
    write_file(out / "compare.json", json.dumps(json_safe(res), indent=1, allow_nan=False))
    names = location_names(res.get("data"), layout)
    label = kinds.labels()
    models = [k for k in kinds.names() if k in res["models"]]
    panels = models + ["off"] * (len(models) % 2)  # the confusion matrices two per row
    rows = [panels[i:i + 2] for i in range(0, len(panels), 2)]
    fig, ax = plt.subplot_mosaic([*rows, ["cdf", "force"], ["detect", "detect"]], figsize=(13, 7 * len(rows) + 7),
                                 height_ratios=[1] * len(rows) + [1, 0.45])
    if "off" in ax:
        ax["off"].axis("off")
    for k in models:
        r = res["models"][k]
        confusion_panel(fig, ax[k], r["localization"]["confusion"], names, f"{label[k]}: accuracy {r['localization']['accuracy']:.1%}")
    cdf_panel(ax["cdf"], {label[k]: np.asarray(res["models"][k]["errors_cm"]) for k in models})
    pts = {label[k]: (lambda q: None if q is None else (q["true_n"], q["predicted_n"]))(res["models"][k].get("force_points"))
           for k in models}
    force_panel(ax["force"], pts, res["models"][models[0]]["force"].get("reason", ""))
    detection_panel(ax["detect"], {label[k]: res["models"][k].get("detection") for k in models})
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(out / "compare.png", dpi=110)
    plt.close(fig)
    return [out / "compare.json", out / "compare.png"]
