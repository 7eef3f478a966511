"""The probe trade-off (issue 17): chirp period and band against accuracy, force, detection and latency.

For every scenario (stationary, moving), simulator seed and probe — chirp period 106.7 / 53.3 / 26.7 /
13.3 / 6.7 ms, band either the full 20-80 kHz or the OSPA region — this simulates the scenario on that
rig, trains both models on its one-shot session exactly as ``sonicskin compare --scenario`` does
(:func:`sonicskin.seeds._one_seed`: gamma, C, kernel width, force model and the network's layers chosen
on the one-shot session's passes; replayed through the live loop's online reference on the later sessions),
and measures the press-to-event latency of the SVM
artifact with ``benchmarks/bench_latency.py``'s scripted presses (seed 0 only).

The OSPA region of a (scenario, seed, period) is measured, not chosen: the 5th-95th percentile of the
frequencies OSPA selects on the full-band run's training session, widened to whole kHz.

Short chirps give many more chirps per press; to compare probes at equal training cost and equal
training-set size, every k-th training chirp is used, with k = n_chirp(paper) / n_chirp (the test
sessions are scored on every chirp).  Presses last 1.5 s here (3 s in the scenarios) to keep the sweep
affordable on 2 cores.

    python benchmarks/sweep_probe.py --out reports/probe            # both bands: ~1.5 h on 2 cores
    python benchmarks/sweep_probe.py --periods 106.7 13.3 --bands full --seeds 0 1 2
Results are cached per configuration under OUT/runs (an interrupted sweep resumes; a run made by other code,
see sonicskin.seeds.run_code, is run again); OUT/probe.md and
OUT/probe.png summarise them.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_latency import run_rig  # noqa: E402

from sonicskin.feature_cache import load_features_cached  # noqa: E402
from sonicskin.ospa import select_bins  # noqa: E402
from sonicskin.rig import Rig  # noqa: E402
from sonicskin.seeds import METRICS, _one_seed, _split, run_code, scenario_dataset, stored_run  # noqa: E402

PAPER_N = 20480
OVERRIDES = {"touch_s": 1.5, "gap_s": 0.5}


def run_key(epochs: int | None) -> dict:
    """What a stored configuration must have been run with to be resumed: the code (:func:`sonicskin.seeds.run_code`),
    the epochs and the scenario overrides (the configuration itself is the file's name)."""
    return {"code": run_code(), "epochs": epochs, "overrides": OVERRIDES}


def probe_rig(period_ms: float, band: tuple[float, float] | None) -> Rig:
    base = Rig.load("jaco")
    n = int(round(period_ms * 1e-3 * base.fs_hz / 256)) * 256
    kw = {"n_chirp": n, "name": f"probe-{n}"}
    if band is not None:
        kw.update(f_lo_hz=float(band[0]), f_hi_hz=float(band[1]), name=f"probe-{n}-{band[0] / 1e3:.0f}-{band[1] / 1e3:.0f}k")
    return dataclasses.replace(base, **kw)


def ospa_region(ds) -> tuple[float, float]:
    t = load_features_cached(ds, progress=False)
    split = _split(t)
    bins = select_bins(t.select(split.mask(t, "train")), ds.rig, 300)
    f = ds.rig.freqs_hz[ds.rig.band_bins[bins]]
    lo, hi = np.percentile(f, [5, 95])
    return float(np.floor(lo / 1e3) * 1e3), float(np.ceil(hi / 1e3) * 1e3)


def run_config(scenario: str, seed: int, period_ms: float, band: str, out: Path, *, epochs: int | None, log) -> dict:
    key = f"{scenario}-seed{seed}-{period_ms:g}ms-{band}"
    done = out / "runs" / f"{key}.json"
    want = run_key(epochs)
    stored = stored_run(done, want, log)
    if stored is not None:
        return stored
    t0 = time.perf_counter()
    cache = out / "data"
    region = None
    if band == "ospa":
        full = scenario_dataset(scenario, seed, cache, rig=probe_rig(period_ms, None), log=log, **OVERRIDES)
        region = ospa_region(full)
    rig = probe_rig(period_ms, region)
    ds = scenario_dataset(scenario, seed, cache, rig=rig, log=log, **OVERRIDES)
    stride = max(1, PAPER_N // rig.n_chirp)
    rows = _one_seed(scenario, ds, [0], out / "artifacts" / key, epochs=epochs, log=lambda *_: None, train_stride=stride)
    row = rows[0]
    res = {"scenario": scenario, "seed": seed, "period_ms": rig.n_chirp / rig.fs_hz * 1e3, "band": band,
           "f_lo_hz": rig.f_lo_hz, "f_hi_hz": rig.f_hi_hz, "n_chirp": rig.n_chirp, "train_stride": stride,
           "net": row["net"], "svm": row["svm"], "wall_s": time.perf_counter() - t0, "key": want}
    if seed == 0 and scenario == "stationary":
        lat = run_rig(rig, out / "artifacts" / key, "svm", scenario=scenario, seed=seed, presses=30, blocksize=256, log=log)
        res["latency"] = {k: lat[k] for k in ("p50_ms", "p95_ms", "max_ms", "missed", "presses", "false_touch_rate")}
    done.parent.mkdir(parents=True, exist_ok=True)
    done.write_text(json.dumps(res))
    log(f"{key}: band {rig.f_lo_hz / 1e3:.0f}-{rig.f_hi_hz / 1e3:.0f} kHz, accuracy net {res['net']['accuracy']:.1%} "
        f"svm {res['svm']['accuracy']:.1%}" + (f", latency p95 {res['latency']['p95_ms']:.1f} ms" if "latency" in res else "")
        + f" ({res['wall_s']:.0f} s)")
    return res


def summarize(results: list[dict]) -> dict:
    """Mean and std over seeds per (scenario, period, band) and model; latency from the seed-0 stationary run."""
    groups: dict = {}
    for r in results:
        groups.setdefault((r["scenario"], r["period_ms"], r["band"]), []).append(r)
    lat = {(r["period_ms"], r["band"]): r["latency"] for r in results if "latency" in r}
    table = []
    for (sc, per, band), rs in sorted(groups.items(), key=lambda kv: (kv[0][0], -kv[0][1], kv[0][2])):
        row = {"scenario": sc, "period_ms": per, "band": band, "n_seeds": len(rs),
               "band_khz": sorted({f"{r['f_lo_hz'] / 1e3:.0f}-{r['f_hi_hz'] / 1e3:.0f}" for r in rs}),
               "latency": lat.get((per, band))}
        for m in METRICS:
            for k in ("net", "svm"):
                v = np.array([r[k][m] for r in rs], float)
                row[f"{k}_{m}"] = (float(np.nanmean(v)), float(np.nanstd(v, ddof=1)) if len(v) > 1 else 0.0)
        table.append(row)
    return {"table": table}


def format_markdown(s: dict) -> str:
    lines = ["| scenario | period | band (kHz) | latency p50 / p95 (SVM) | accuracy net / SVM | < 2 cm net / SVM | force RMSE net / SVM "
             "| false touches net / SVM | missed touches net / SVM |", "|---|---|---|---|---|---|---|---|---|"]

    def pm(row, m, pct=True):
        out = []
        for k in ("net", "svm"):
            mu, sd = row[f"{k}_{m}"]
            out.append(f"{mu:.1%} ± {sd:.1%}" if pct else f"{mu:.2f} ± {sd:.2f}")
        return " / ".join(out)

    for r in s["table"]:
        lat = r["latency"]
        lat_s = f"{lat['p50_ms']:.0f} / {lat['p95_ms']:.0f} ms" if lat else "—"
        lines.append(f"| {r['scenario']} ({r['n_seeds']} seeds) | {r['period_ms']:.1f} ms | {', '.join(r['band_khz'])} | {lat_s} | "
                     f"{pm(r, 'accuracy')} | {pm(r, 'within_2cm')} | {pm(r, 'force_rmse_n', False)} N | {pm(r, 'false_touch')} | "
                     f"{pm(r, 'missed_touch')} |")
    return "\n".join(lines) + "\n"


def plot(s: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import matplotlib.ticker  # noqa: F401

    panels = [("accuracy", "accuracy", True), ("within_2cm", "error < 2 cm", True), ("force_rmse_n", "force RMSE (N)", False),
              ("false_touch", "false touches", True), ("missed_touch", "missed touches", True)]
    fig, grid = plt.subplots(2, 3, figsize=(15, 8.5), constrained_layout=True)
    axes = grid.ravel()[:len(panels)]
    grid.ravel()[-1].axis("off")
    styles = {("net", "full"): ("C0", "-", "o"), ("svm", "full"): ("C1", "--", "s"),
              ("net", "ospa"): ("C2", "-", "^"), ("svm", "ospa"): ("C3", "--", "v")}
    for ax, (m, label, pct) in zip(axes, panels):
        for sc, marker_fill in (("stationary", "full"), ("moving", "none")):
            for (k, band), (c, ls, mk) in styles.items():
                rows = [r for r in s["table"] if r["scenario"] == sc and r["band"] == band and r["latency"] is not None]
                rows = sorted(rows, key=lambda r: r["latency"]["p95_ms"])
                if not rows:
                    continue
                x = [r["latency"]["p95_ms"] for r in rows]
                y = np.array([r[f"{k}_{m}"][0] for r in rows]) * (100 if pct else 1)
                e = np.array([r[f"{k}_{m}"][1] for r in rows]) * (100 if pct else 1)
                # The network's lines are wide and pale underneath, so an SVM line on top of one stays visible.
                ax.errorbar(x, y, yerr=e, color=c, ls=ls if sc == "stationary" else ":", marker=mk, fillstyle=marker_fill,
                            capsize=2, lw=3.5 if k == "net" else 1.2, alpha=0.45 if k == "net" else 1.0, zorder=1 if k == "net" else 2,
                            label=f"{'network' if k == 'net' else 'SVM'}, {band} band, {sc}")
        ax.set_xscale("log")
        ax.set_xticks([10, 20, 25, 50, 100, 200])
        ax.xaxis.set_major_formatter(matplotlib.ticker.ScalarFormatter())
        ax.xaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
        ax.axvline(25, color="gray", lw=0.8, ls="-.")
        ax.set_xlabel("press-to-event latency p95 (ms)")
        ax.set_ylabel(label + (" (%)" if pct else ""))
        ax.grid(alpha=0.3)
    handles, labels = axes[0].get_legend_handles_labels()
    grid.ravel()[-1].legend(handles, labels, loc="center", fontsize=9, title="line: model, band, scenario (wide pale: network)")
    fig.suptitle("Probe trade-off: chirp period 106.7 / 53.3 / 26.7 / 13.3 / 6.7 ms and band, against the measured press-to-event "
                 "latency (p95; dash-dot: 25 ms)\nmean ± std over 3 simulator seeds")
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenarios", nargs="+", default=["stationary", "moving"])
    ap.add_argument("--periods", type=float, nargs="+", default=[106.7, 53.3, 26.7, 13.3, 6.7], help="chirp periods, ms")
    ap.add_argument("--bands", nargs="+", default=["full", "ospa"], choices=("full", "ospa"))
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2], help="simulator seeds (default: 0 1 2)")
    ap.add_argument("--epochs", type=int, help="network epochs (default: training.quick's)")
    ap.add_argument("--out", default="reports/probe")
    a = ap.parse_args(argv)
    out = Path(a.out)
    log = lambda m: print(m, file=sys.stderr, flush=True)  # noqa: E731
    from tqdm.auto import tqdm

    configs = [(sc, seed, per, band) for per in a.periods for band in a.bands for sc in a.scenarios for seed in a.seeds]
    results = [run_config(sc, seed, per, band, out, epochs=a.epochs, log=log)
               for sc, seed, per, band in tqdm(configs, desc="probe sweep", unit="config")]
    s = summarize(results)
    out.mkdir(parents=True, exist_ok=True)
    (out / "probe.json").write_text(json.dumps(s, indent=1))
    md = format_markdown(s)
    (out / "probe.md").write_text(md)
    plot(s, out / "probe.png")
    print(md)
    print(f"wrote {out}/probe.md, probe.json, probe.png")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
