"""A short causal context on short chirps (issue 17, item 4): does the mean of the last k frames help?

With 13.3 or 6.7 ms chirps, consecutive frames of one press carry the same channel with independent noise.
A causal window — the mean of the band spectrum (dB) over the last k frames, in front of either model —
trades noise for response time: a press fully enters the window k - 1 frames later.  This replays the test
sessions of ``benchmarks/sweep_probe.py``'s artifacts (both models, trained on single frames) with
k = 1, 2, 4 and prints accuracy, < 2 cm, force and detection with the latency the window adds, so the
network and the SVM are compared at the same latency.

    python benchmarks/context_probe.py --sweep reports/probe --periods 13.3 6.7
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from sonicskin.compare import stream_metrics  # noqa: E402
from sonicskin.dataset import Dataset  # noqa: E402
from sonicskin.feature_cache import load_features_cached  # noqa: E402
from sonicskin.runtime import Predictions, SkinRuntime  # noqa: E402
from sonicskin.seeds import METRICS  # noqa: E402


def causal_mean(X: np.ndarray, k: int) -> np.ndarray:
    """Mean of the last ``k`` rows (fewer at the start of the stream), row by row: (n, d) -> (n, d)."""
    if k <= 1:
        return X
    c = np.cumsum(np.vstack([np.zeros((1, X.shape[1]), np.float64), X.astype(np.float64)]), axis=0)
    i = np.arange(1, len(X) + 1)
    lo = np.maximum(i - k, 0)
    return ((c[i] - c[lo]) / (i - lo)[:, None]).astype(np.float32)


def evaluate(run: dict, sweep: Path, ks) -> list[dict]:
    key = f"{run['scenario']}-seed{run['seed']}-{run['period_ms_arg']:g}ms-{run['band']}"
    art = sweep / "artifacts" / key
    meta = json.loads((art / "skin.json").read_text())
    ds = Dataset(meta["training"]["data"])
    t = load_features_cached(ds, progress=False)
    test = meta["training"]["split"]["test"]
    te = t.select(np.isin(t["session"], test))
    out = []
    for model in ("net", "svm"):
        rt = SkinRuntime(art, model)
        for k in ks:
            parts = []
            for s in test:
                m = te["session"] == s
                parts.append(rt.replay(causal_mean(te.X[m], k), te["time_s"][m]))
            r = stream_metrics(Predictions.concat(parts), te, ds.layout)
            out.append({"key": key, "model": model, "k": k, "added_latency_ms": (k - 1) * run["period_ms"],
                        **{name: float(f(r)) for name, (f, _, _) in METRICS.items()}})
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sweep", default="reports/probe", help="the sweep_probe.py output folder (default: reports/probe)")
    ap.add_argument("--periods", type=float, nargs="+", default=[13.3, 6.7])
    ap.add_argument("--band", default="full", choices=("full", "ospa"))
    ap.add_argument("--windows", type=int, nargs="+", default=[1, 2, 4])
    a = ap.parse_args(argv)
    sweep = Path(a.sweep)
    runs = []
    for p in sorted((sweep / "runs").glob("*.json")):
        r = json.loads(p.read_text())
        per_arg = float(p.stem.split("-")[2].removesuffix("ms"))
        if r["band"] == a.band and any(abs(per_arg - q) < 0.05 for q in a.periods):
            runs.append({**r, "period_ms_arg": per_arg})
    if not runs:
        print(f"no sweep runs for periods {a.periods} and band {a.band} under {sweep}/runs", file=sys.stderr)
        return 2
    rows = [row for r in runs for row in evaluate(r, sweep, a.windows)]
    groups: dict = {}
    for r, row in ((r, row) for r in runs for row in rows if row["key"].startswith(f"{r['scenario']}-seed{r['seed']}-")
                   and row["key"].endswith(f"{r['period_ms_arg']:g}ms-{a.band}")):
        groups.setdefault((r["scenario"], r["period_ms_arg"], row["model"], row["k"]), {})[row["key"]] = row
    print("| scenario | period | model | window k | added latency | accuracy | < 2 cm | force RMSE | false touches | missed touches |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for (sc, per, model, k), d in sorted(groups.items(), key=lambda kv: (kv[0][0], -kv[0][1], kv[0][2], kv[0][3])):
        v = list(d.values())

        def ms(name, pct=True, v=v):
            x = np.array([r[name] for r in v], float)
            mu, sd = np.nanmean(x), (np.nanstd(x, ddof=1) if len(x) > 1 else 0.0)
            return f"{mu:.1%} ± {sd:.1%}" if pct else f"{mu:.2f} ± {sd:.2f} N"

        name = "network" if model == "net" else "SVM"
        print(f"| {sc} ({len(v)} seeds) | {per:g} ms | {name} | {k} | {v[0]['added_latency_ms']:.1f} ms | "
              f"{ms('accuracy')} | {ms('within_2cm')} | {ms('force_rmse_n', False)} | {ms('false_touch')} | {ms('missed_touch')} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
