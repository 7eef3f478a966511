"""``report.md``: every measured number beside the paper's."""

from __future__ import annotations

import numpy as np

from ..force import MODELS
from .aggregate import pool
from .context import MODEL, QUICK_SIZE, datasets
from .experiments import fig11_sizes

PAPER = {
    "fig6b": "54.3 % -> 96.7 %", "fig11": "> 95 % from a few hundred bins; drops with more", "fig12": "drops after 30 min "
    "without updating; stable for two months with it", "fig13": "Fourier-1 best (R2 0.92 with E^O), poly-1 0.9",
    "table1": "stationary 0.59 N / 0.58 N / 99.4 %; moving 1.86 N / 1.73 N / 96.7 %",
    "stationary": "99.4 %", "fig14": "96.2 %, 97.0 % < 3 cm", "fig15": "97.2 %, 98.5 % < 3 cm", "fig16": "100 % on 2 points; force < 0.5 N",
}


def _pct(x) -> str:
    return "n/a" if x is None else f"{x:.1%}"


def sizes(ctx, seeds) -> list[str]:
    """What this run ran: dataset sizes, training, Fig. 11's sweep, and where the time went."""
    f11 = fig11_sizes(ctx.quick)
    ds = ", ".join(f"{n} ({sc}" + (", " + ", ".join(f"{k} {v}" for k, v in o.items() if k in ("sessions", "repeats")) if
                                     any(k in o for k in ("sessions", "repeats")) else "") + ")"
                   for n, (sc, o) in datasets(ctx.quick).items())
    out = ["## What ran\n",
           f"- Datasets per simulator seed (scenario, what the experiments set): {ds}."
           + (f" Quick: every press {QUICK_SIZE['touch_s']} s and {QUICK_SIZE['moving_s']} s of moving no-touch per session."
              if ctx.quick else ""),
           f"- Every number is an exported artifact replayed as the live loop runs it (sonicskin.head.Stream). SVM: the "
           f"paper's (C 10, kernel width 'scale', per-location Fourier-1 force, the input-RMS detector). Network: "
           f"{ctx.epochs} epochs, as the package deploys it (its location layer, touch decision and force chosen on the "
           f"training session's held-out pass). A model with the same inputs and training chirps is fitted once per seed "
           f"and shared by the experiments that use it (the moving robot's OSPA model serves the OSPA comparison, the "
           f"gamma sweep and the force table)."]
    if "fig11" in getattr(ctx, "names", ()):
        out.append(f"- Accuracy vs gamma: gamma {', '.join(map(str, f11['gammas']))}; SVM {len(f11['svm_seeds'])} training "
                   f"resamples (the first on every training chirp, the others on 80 %), network {len(f11['net_seeds'])} "
                   f"training seed(s) {list(f11['net_seeds'])}, per simulator seed.")
    out.append(f"- {getattr(ctx, 'jobs', 1)} worker process(es).")
    timing = getattr(ctx, "timing", {})
    if timing:
        names = list(dict.fromkeys(n for _, n in timing))
        ss = sorted({s for s, _ in timing})
        out += ["", "Wall seconds per experiment and seed (CPU seconds of its process in brackets; with several workers "
                "the experiments run side by side):\n", "| experiment | " + " | ".join(f"seed {s}" for s in ss) + " |",
                "|---|" + "---|" * len(ss)]
        out += [f"| {n} | " + " | ".join(f"{timing[(s, n)][0]:.0f} ({timing[(s, n)][1]:.0f})" if (s, n) in timing else ""
                                         for s in ss) + " |" for n in names]
    return out + [""]


def report(res: dict, ctx, runtime_s: float, seeds=(0,)) -> str:
    ks = ctx.kinds
    col = " | ".join(MODEL[k] for k in ks)
    lines = ["# SonicSkin on the simulated rig: the paper's Sec. V, SVM and network\n",
             f"Mode: {'quick' if ctx.quick else 'full'}; run time {runtime_s / 60:.1f} min on this machine. "
             f"Every number below is measured in this run as mean +- standard deviation over {len(seeds)} simulator "
             f"seeds {list(seeds)} (each seed is another simulated link and other presses, noise and aims); "
             "the paper's are quoted for comparison. Figures show the first seed.\n"]
    lines += sizes(ctx, seeds)
    if "fig6b" in res:
        r = res["fig6b"]
        lines += ["## Fig. 6b: OSPA on the moving robot (paper: " + PAPER["fig6b"] + ")\n", f"| | {col} |", "|---|" + "---|" * len(ks),
                  "| all 6400 band bins | " + " | ".join(_pct(r[k]["all_bins"]) for k in ks) + " |",
                  "| OSPA, 300 bins | " + " | ".join(_pct(r[k]["ospa"]) for k in ks) + " |", "", "![](fig6b.png)\n"]
    if "fig11" in res:
        r = res["fig11"]
        gs = sorted(next(iter(r.values())))
        lines += ["## Fig. 11: accuracy vs gamma (paper: " + PAPER["fig11"] + ")\n", "| gamma | " + col + " |", "|---|" + "---|" * len(ks)]
        lines += [f"| {g} | " + " | ".join(f"{np.mean(pool(r[k][g])):.1%} +- {np.std(pool(r[k][g])):.1%}" for k in ks) + " |" for g in gs]
        lines += ["", "![](fig11.png)\n"]
    if "fig12" in res:
        r = res["fig12"]
        keys = [k for k in r if k not in ("minutes", "temperature_c", "two_months")]
        lines += ["## Fig. 12: warm-up and online updating (paper: " + PAPER["fig12"] + ")\n",
                  "| min | temp (C) | " + " | ".join(keys) + " |", "|---|---|" + "---|" * len(keys)]
        # Session times and temperatures are the same scenario on every seed: their mean, no spread.
        lines += [f"| {float(m):.0f} | {float(T):.2f} | " + " | ".join(_pct(r[k][i]) for k in keys) + " |"
                  for i, (m, T) in enumerate(zip(r["minutes"], r["temperature_c"]))]
        tm = r["two_months"]
        keys2 = [k for k in tm if k not in ("days", "temperature_c")]
        lines += ["", "Two months (ambient +-3 C daily swing):\n", "| day | temp (C) | " + " | ".join(keys2) + " |",
                  "|---|---|" + "---|" * len(keys2)]
        lines += [f"| {float(d):.0f} | {float(T):.2f} | " + " | ".join(_pct(tm[k][i]) for k in keys2) + " |"
                  for i, (d, T) in enumerate(zip(tm["days"], tm["temperature_c"]))]
        lines += ["", "![](fig12.png)\n"]
    if "fig13" in res:
        r = res["fig13"]
        feats = [k for k in r if isinstance(r[k], dict)]
        lines += ["## Fig. 13: force curve models, mean R2 per location (paper: " + PAPER["fig13"] + ")\n",
                  "| model | " + " | ".join(feats) + " |", "|---|" + "---|" * len(feats)]
        lines += [f"| {m} | " + " | ".join(f"{r[f][m]:.2f}" for f in feats) + " |" for m in MODELS]
        if all(f in r for f in ("E (all band bins)", "E^O (OSPA bins)")):
            d = np.subtract(r["E^O (OSPA bins)"]["fourier1"].values, r["E (all band bins)"]["fourier1"].values)
            lines.append(f"\nFourier-1, E^O minus E per seed: {', '.join(f'{x:+.3f}' for x in d)}.")
        if "network (training fit)" in r:
            lines.append(f"\nNetwork force head on the same training chirps: R2 {r['network (training fit)']:.2f}.")
        lines += ["", "![](fig13.png)\n"]
    if "table1" in res:
        r = res["table1"]["table1"]
        lines += ["## Table I: force (paper: " + PAPER["table1"] + ")\n", "| scenario, model | RMSE | sigma | cross-correlation |",
                  "|---|---|---|---|"]
        lines += [f"| {k} | {v['rmse_n']:.2f} N | {v['sigma_n']:.2f} N | {v['xcorr']:.1%} |" for k, v in r.items()]
        for fig_name, title in (("stationary", "Stationary robot, one-shot"), ("fig14", "Fig. 14: moving robot"),
                                ("fig15", "Fig. 15: unseen people")):
            if fig_name not in res["table1"]:
                continue
            r = res["table1"][fig_name]
            lines += ["", f"## {title} (paper: {PAPER[fig_name]})\n", f"| | {col} |", "|---|" + "---|" * len(ks)]
            for key, lab in (("accuracy", "accuracy"), ("within_2cm", "< 2 cm"), ("within_3cm", "< 3 cm"),
                             ("false_touch", "false touches"), ("missed_touch", "missed touches")):
                lines.append(f"| {lab} | " + " | ".join(_pct(r[k][key]) for k in ks) + " |")
            lines += ["", f"![]({fig_name}.png)"] if fig_name != "stationary" else [""]
    if "fig16" in res:
        r = res["fig16"]
        lines += ["", "## Fig. 16: materials (paper: " + PAPER["fig16"] + ")\n",
                  "| surface | " + " | ".join(f"accuracy {c} | force RMSE {c}" for c in col.split(" | ")) + " |",
                  "|---|" + "---|---|" * len(ks)]
        lines += [f"| {n} | " + " | ".join(f"{_pct(r[n][k]['accuracy'])} | {r[n][k]['force']['rmse_n']:.2f} N" for k in ks) + " |"
                  for n in r]
        lines += ["", "![](fig16.png)", ""]
    return "\n".join(lines)
