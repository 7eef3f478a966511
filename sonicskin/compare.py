"""Side-by-side evaluation of the network and the SVM of one artifact (onnxruntime only)."""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

from .dataset import Dataset, FeatureTable
from .features import load_features_cached, touch_mask
from .metrics import force_report, localization_report, speed_ratio
from .runtime import Predictions, SkinRuntime
from .schema import load_skin

__all__ = ["compare_artifact", "replay_sessions", "stream_metrics", "chirp_latency", "format_comparison", "save_comparison"]


def chirp_latency(rt: SkinRuntime, X_band: np.ndarray, time_s: np.ndarray, *, n: int = 300, warmup: int = 20) -> dict:
    """Per-chirp cost in this run, one chirp per call on one thread: the ONNX call alone, and the
    whole per-chirp path from band features (reference, model, detection, force; :meth:`SkinStream.chirp`).

    ``X_band``/``time_s``: a recorded stream; its first ``beta`` chirps boot the reference.
    """
    st = rt.stream()
    k = 0
    while st.calibrating and k < len(X_band):
        st.chirp(X_band[k], time_s[k])
        k += 1
    if k >= len(X_band):
        raise ValueError(f"the stream has {len(X_band)} chirps, not more than the boot calibration's")
    rows = np.arange(k, len(X_band))
    inputs = st.reference.inputs(X_band[rows][:, st.bins])
    path, onnx = np.empty(n), np.empty(n)
    for i in range(-warmup, n):
        r = rows[i % rows.size]
        t0 = time.perf_counter()
        st.chirp(X_band[r], time_s[r])
        dt = time.perf_counter() - t0
        one = inputs[i % rows.size][None]
        t0 = time.perf_counter()
        rt.run(one)
        dt2 = time.perf_counter() - t0
        if i >= 0:
            path[i], onnx[i] = dt, dt2
    return {"median_ms": float(np.median(path) * 1e3), "p99_ms": float(np.percentile(path, 99) * 1e3),
            "onnx_median_ms": float(np.median(onnx) * 1e3), "onnx_p99_ms": float(np.percentile(onnx, 99) * 1e3)}


def replay_sessions(rt: SkinRuntime, t: FeatureTable, sessions) -> Predictions:
    """Every chirp of ``sessions`` (each a stream, in order) through ``rt`` as the live loop runs it."""
    parts = []
    for s in sessions:
        m = t["session"] == s
        parts.append(rt.replay(t.X[m], t["time_s"][m]))
    return Predictions.concat(parts)


def _force(f_true: np.ndarray, f_pred: np.ndarray, sel: np.ndarray) -> dict:
    """Table I on the selected chirps, or why force is absent (no force sensor: NaN or constant force)."""
    g = f_true[sel]
    if not np.isfinite(g).any() or not np.isfinite(f_pred[sel]).any():
        return {"measurable": False, "reason": "absent: no force sensor (force_n is empty/NaN)"}
    if np.ptp(g[np.isfinite(g)]) == 0:
        return {"measurable": False, "reason": f"absent: force_n is constant ({g[np.isfinite(g)][0]:g} N)"}
    return force_report(g, f_pred[sel])


def stream_metrics(p: Predictions, t: FeatureTable, layout, *, min_force_n: float = 0.5, detection: bool = True) -> dict:
    """Localization, continuous position, force and detection of replayed predictions ``p`` of the
    chirps of ``t`` (same order).  The boot calibration's chirps (no prediction) count as missed
    touches and are left out of everything else.  ``detection=False``: the model has no detector
    (a table of touches only), or the data has no hands-off chirps: detection is not measurable."""
    touch = touch_mask(t, min_force_n)
    run = ~p.calibrating
    no_touch = (t["location"] < 0) & run
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
        "detection": ({"false_touch_rate": float(np.mean(p.touch[no_touch])), "missed_touch_rate": float(np.mean(~p.touch[touch]))}
                      if no_touch.any() and touch.any() and detection else
                      {"measurable": False, "reason": "not measurable on this data: no hands-off chirps"}),
    }


def compare_artifact(artifact: str | Path, data: str | Path | None = None, *, sessions: list[str] | None = None,
                     progress: bool = False, latency: bool = True) -> dict:
    """Evaluate both models of ``artifact`` on the test sessions of its split (or ``sessions``).

    Each test session is replayed as a stream through :meth:`SkinRuntime.replay`, as the live
    loop runs it: the first ``beta`` seconds boot the reference, refreshes follow each model's own
    touch detection.  No test label reaches a model or its reference.
    """
    art = Path(artifact)
    meta = load_skin(art)  # the whole skin.json against the schema: one clear error line, no KeyError
    data = data or meta["training"]["data"]
    res: dict = {"artifact": str(art), "data": str(data), "models": {}}
    rts = {k: SkinRuntime(art, k) for k in ("net", "svm")}
    ds = Dataset(data)
    t = load_features_cached(ds, progress=progress)
    test = sessions or meta["training"]["split"]["test"]
    res["test_sessions"] = list(test)
    te = t.select(np.isin(t["session"], test))
    for k, rt in rts.items():
        p = replay_sessions(rt, te, test)
        r = stream_metrics(p, te, ds.layout, min_force_n=meta.get("min_force_n", 0.5),
                           detection=meta["models"]["svm"].get("detection", True))
        sel = touch_mask(te, meta.get("min_force_n", 0.5)) & p.touch  # the chirps force is scored on (plotted)
        r["force_points"] = {"true_n": te["force_n"][sel].tolist(), "predicted_n": p.force_n[sel].tolist()}
        r["latency"] = chirp_latency(rt, te.X, te["time_s"]) if latency else None
        r["model_bytes"] = int((art / rt.m["file"]).stat().st_size)
        r["train_time_s"] = meta["training"].get(f"{k}_train_time_s")
        res["models"][k] = r
    return res


def _or_na(d: dict, fmt) -> str:
    return "n/a" if d.get("measurable") is False else fmt(d)


def format_comparison(res: dict, title: str = "") -> str:
    rows = [
        ("accuracy", lambda r: f"{r['localization']['accuracy']:.1%}"),
        ("error < 2 cm", lambda r: f"{r['localization']['within_2cm']:.1%}"),
        ("error < 3 cm", lambda r: f"{r['localization']['within_3cm']:.1%}"),
        ("continuous xy error (median)", lambda r: f"{r['continuous_error_cm']['median']:.2f} cm"),
        ("force RMSE", lambda r: _or_na(r["force"], lambda d: f"{d['rmse_n']:.2f} N")),
        ("force sigma", lambda r: _or_na(r["force"], lambda d: f"{d['sigma_n']:.2f} N")),
        ("force cross-correlation", lambda r: _or_na(r["force"], lambda d: f"{d['xcorr']:.1%}")),
        ("false touches", lambda r: _or_na(r["detection"], lambda d: f"{d['false_touch_rate']:.2%}")),
        ("missed touches", lambda r: _or_na(r["detection"], lambda d: f"{d['missed_touch_rate']:.2%}")),
        ("ONNX model per chirp, median", lambda r: f"{r['latency']['onnx_median_ms'] * 1e3:.0f} us"),
        ("ONNX model per chirp, p99", lambda r: f"{r['latency']['onnx_p99_ms'] * 1e3:.0f} us"),
        ("inputs -> touch/xy/force, median", lambda r: f"{r['latency']['median_ms'] * 1e3:.0f} us"),
        ("inputs -> touch/xy/force, p99", lambda r: f"{r['latency']['p99_ms'] * 1e3:.0f} us"),
        ("model size", lambda r: f"{r['model_bytes'] / 1e3:.0f} kB"),
        ("training time (to exported epoch)", lambda r: "n/a" if r["train_time_s"] is None else f"{r['train_time_s']:.1f} s"),
    ]
    net, svm = res["models"]["net"], res["models"]["svm"]
    w = max(len(r[0]) for r in rows)
    out = [title or f"{res['data']} (test sessions {', '.join(res['test_sessions'])})",
           f"  {'':{w}}  {'network':>12}  {'SVM':>12}"]
    out += [f"  {name:{w}}  {fmt(net):>12}  {fmt(svm):>12}" for name, fmt in rows]
    for key, what in (("force", "force"), ("detection", "detection")):
        if net[key].get("measurable") is False:
            out.append(f"  {what}: {net[key]['reason']}")
    speed = speed_ratio(net["latency"]["onnx_median_ms"], svm["latency"]["onnx_median_ms"])
    speed2 = speed_ratio(net["latency"]["median_ms"], svm["latency"]["median_ms"])
    out.append(f"  per chirp, the network is {speed} than the SVM in onnxruntime ({speed2} with post-processing; same run)"
               .replace("as fast than", "as fast as"))
    return "\n".join(out)


def save_comparison(res: dict, out_dir: str | Path, layout, title: str = "") -> list[Path]:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    (out / "compare.json").write_text(json.dumps(res, indent=1, default=float))
    from .plots import cdf_panel, confusion_panel, force_panel, location_names

    names = location_names(res.get("data"), layout)
    label = {"net": "network", "svm": "SVM"}
    fig, ax = plt.subplots(2, 2, figsize=(13, 10.5))
    for a, k in zip(ax[0], ("net", "svm")):
        r = res["models"][k]
        confusion_panel(fig, a, r["localization"]["confusion"], names, f"{label[k]}: accuracy {r['localization']['accuracy']:.1%}")
    cdf_panel(ax[1, 0], {label[k]: np.asarray(res["models"][k]["errors_cm"]) for k in ("net", "svm")})
    pts = {label[k]: (lambda q: None if q is None else (q["true_n"], q["predicted_n"]))(res["models"][k].get("force_points"))
           for k in ("net", "svm")}
    force_panel(ax[1, 1], pts, res["models"]["net"]["force"].get("reason", ""))
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(out / "compare.png", dpi=110)
    plt.close(fig)
    return [out / "compare.json", out / "compare.png"]
