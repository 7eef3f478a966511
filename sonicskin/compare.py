"""Side-by-side evaluation of the network and the SVM of one artifact (onnxruntime only)."""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

from .features import model_inputs, quiet_mask, touch_mask
from .metrics import error_cdf, force_report, localization_report
from .runtime import SkinRuntime
from .schema import load_skin

__all__ = ["compare_artifact", "format_comparison", "save_comparison"]


def _latency(rt: SkinRuntime, x: np.ndarray, n: int = 300) -> dict:
    """Per-chirp model latency in onnxruntime (one chirp per call, one thread), this run."""
    one = x[:1]
    for _ in range(20):
        rt.predict_inputs(one)
    ts = np.empty(n)
    for i in range(n):
        t = time.perf_counter()
        rt.predict_inputs(x[i % len(x)][None])
        ts[i] = time.perf_counter() - t
    onnx = np.empty(n)
    for i in range(n):
        t = time.perf_counter()
        rt.run(x[i % len(x)][None])
        onnx[i] = time.perf_counter() - t
    return {"median_ms": float(np.median(ts) * 1e3), "p99_ms": float(np.percentile(ts, 99) * 1e3),
            "onnx_median_ms": float(np.median(onnx) * 1e3), "onnx_p99_ms": float(np.percentile(onnx, 99) * 1e3)}


def _force(f_true: np.ndarray, f_pred: np.ndarray, sel: np.ndarray) -> dict:
    """Table I on the selected chirps, or why force is absent (no force sensor: NaN or constant force)."""
    g = f_true[sel]
    if not np.isfinite(g).any() or not np.isfinite(f_pred[sel]).any():
        return {"measurable": False, "reason": "absent: no force sensor (force_n is empty/NaN)"}
    if np.ptp(g[np.isfinite(g)]) == 0:
        return {"measurable": False, "reason": f"absent: force_n is constant ({g[np.isfinite(g)][0]:g} N)"}
    return force_report(g, f_pred[sel])


def compare_artifact(artifact: str | Path, data: str | Path | None = None, *, sessions: list[str] | None = None,
                     progress: bool = False) -> dict:
    """Evaluate both models of ``artifact`` on the test sessions of its split (or ``sessions``).

    Each test session is a stream: relative inputs use its own no-touch chirps (Alg. 2 with the
    artifact's beta/alpha), and the SVM's scores are calibrated the same way.
    """
    art = Path(artifact)
    meta = load_skin(art)  # the whole skin.json against the schema: one clear error line, no KeyError
    data = data or meta["training"]["data"]
    res: dict = {"artifact": str(art), "data": str(data), "models": {}}
    rts = {k: SkinRuntime(art, k) for k in ("net", "svm")}
    ds, t, X = model_inputs(data, rts["net"].spec, progress=progress)
    test = sessions or meta["training"]["split"]["test"]
    res["test_sessions"] = list(test)
    m = np.isin(t["session"], test)
    touch = touch_mask(t, meta.get("min_force_n", 0.5))[m]
    no_touch = (t["location"] < 0)[m]
    for k, rt in rts.items():
        preds = [rt.predict_inputs(X[(t["session"] == s)], quiet=quiet_mask(t)[t["session"] == s],
                                   time_s=t["time_s"][t["session"] == s]) for s in test]
        loc = np.concatenate([p.location for p in preds])
        det = np.concatenate([p.touch for p in preds])
        xy = np.concatenate([p.xy_cm for p in preds])
        # Force at the true location for a like-for-like Table I (both models, all touched chirps).
        f = np.concatenate([p.force_n for p in preds])
        true_loc = t["location"][m]
        L = localization_report(true_loc[touch], loc[touch], ds.layout)
        true_xy = np.column_stack([t["x_cm"][m], t["y_cm"][m]])
        cont_err = ds.layout.distance_cm(xy[touch], true_xy[touch])
        size = (art / rt.m["file"]).stat().st_size
        res["models"][k] = {
            "localization": {kk: v for kk, v in L.items() if kk != "errors_cm"},
            "errors_cm": L["errors_cm"].tolist(),
            "continuous_error_cm": {"median": float(np.median(cont_err)), "mean": float(np.mean(cont_err))},
            "force": _force(t["force_n"][m], f, touch & det),
            "detection": ({"false_touch_rate": float(np.mean(det[no_touch])), "missed_touch_rate": float(np.mean(~det[touch]))}
                          if no_touch.any() and meta["models"]["svm"].get("detection", True) else
                          {"measurable": False, "reason": "not measurable on this data: no hands-off chirps"}),
            "latency": _latency(rt, X[m][touch]),
            "model_bytes": int(size),
            "train_time_s": meta["training"].get(f"{k}_train_time_s"),
        }
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
    speed = svm["latency"]["onnx_median_ms"] / net["latency"]["onnx_median_ms"]
    speed2 = svm["latency"]["median_ms"] / net["latency"]["median_ms"]
    out.append(f"  per chirp, the network is {speed:.1f}x faster than the SVM in onnxruntime ({speed2:.1f}x with "
               f"post-processing; same run)")
    return "\n".join(out)


def save_comparison(res: dict, out_dir: str | Path, layout, title: str = "") -> list[Path]:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    (out / "compare.json").write_text(json.dumps(res, indent=1, default=float))
    fig, ax = plt.subplots(1, 3, figsize=(16, 4.8))
    for a, k in zip(ax[:2], ("net", "svm")):
        r = res["models"][k]
        cm = np.asarray(r["localization"]["confusion"], float)
        cm /= np.maximum(cm.sum(axis=1, keepdims=True), 1)
        a.imshow(cm, cmap="viridis", vmin=0, vmax=1)
        a.set(title=f"{'network' if k == 'net' else 'SVM'}: accuracy {r['localization']['accuracy']:.1%}",
              xlabel="predicted location", ylabel="true location")
    for k, style in (("net", "-"), ("svm", "--")):
        e, c = error_cdf(np.asarray(res["models"][k]["errors_cm"]))
        ax[2].step(e, c, style, where="post", label=f"{'network' if k == 'net' else 'SVM'}")
    ax[2].axvline(2, color="gray", lw=0.8)
    ax[2].set(xlabel="localization error (cm)", ylabel="CDF", ylim=(0, 1.01), xlim=(-0.1, 6), title="error CDF")
    ax[2].legend(); ax[2].grid(alpha=0.3)
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(out / "compare.png", dpi=110)
    plt.close(fig)
    return [out / "compare.json", out / "compare.png"]
