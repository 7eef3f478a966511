"""Both models and plain scikit-learn floors on rigs we did not design on (issue 15.5).

    nice -n 5 .venv/bin/python benchmarks/bench_random_rigs.py            # the 12 held-out seeds
    nice -n 5 .venv/bin/python benchmarks/bench_random_rigs.py --seeds design   # the design seeds (develop here)

Every seed of the ``random`` scenario family (``configs/scenarios/random.yaml``) is another rig: material,
tube or plate, size, transducer positions, loss factor, modal irregularity, marker grid, people, motion
and warm-up.  Each is simulated once (cached under ``--cache``) with four sessions, one press per marker
each: **s000 trains, s001 validates, s002 and s003 test**.

Per seed, the package itself runs as a user would run it: ``sonicskin compare --data D --train s000 --val
s001 --test s002 s003`` trains and exports both models (the network with LightningCLI, validated on s001;
the SVM of the same artifact) and replays the test sessions as the live loop runs them (boot calibration,
refreshes from each model's own detection, no test label).  Whatever the package chooses by itself
(bins, model selection) is therefore what is measured.

On the same split, plain scikit-learn floors with default parameters, on every usable bin (the rig's
matched-filter mask) minus the session's boot reference (the mean of its first 3 s, the same no-touch
reference the runtime boots on; no label):

- location: ``StandardScaler + SVC()`` trained on the touch chirps of s000;
- force: ``StandardScaler + SVR()`` pooled over all locations, and "predict the training mean".

Floors are scored on every touch chirp of the test sessions (they are given the touch decision); the
models' force RMSE is on the touch chirps their own detector found (as ``compare`` reports it).

Reported: mean and spread (std over seeds) per model and floor, and the paired differences
(net - SVM, SVM - floor, net - floor) with a 95 % Student t interval over seeds (the unit is the rig).
Writes ``OUT/random.json`` and ``OUT/random.md``; per-seed results under ``OUT/seeds/`` (``--resume``
keeps them).
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

for _v in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

METRICS = {  # name -> (unit, larger is better)
    "accuracy": ("pct", True),
    "within_2cm": ("pct", True),
    "force_rmse_n": ("N", False),
    "missed_touch": ("pct", False),
    "false_touch": ("pct", False),
}
LABELS = {"accuracy": "accuracy", "within_2cm": "error < 2 cm", "force_rmse_n": "force RMSE",
          "missed_touch": "missed touches", "false_touch": "false touches"}
SPLIT = {"train": ["s000"], "val": ["s001"], "test": ["s002", "s003"]}
#: the protocols users run (issue 36): train s000 and validate on s001, the deployed models refitted on both
#: ("refit", compare's default); or one session and nothing to validate on ("oneshot", --val none)
PROTOCOLS = {"refit": ["--val", "s001"], "oneshot": ["--val", "none"]}
MODELS = ("net", "svm", "lda")


def _model_metrics(r: dict) -> dict:
    def num(v):  # compare.json writes a value that is not measurable as null
        return float("nan") if v is None else v

    return {"accuracy": r["localization"]["accuracy"], "within_2cm": r["localization"]["within_2cm"],
            "force_rmse_n": num(r["force"].get("rmse_n")),
            "missed_touch": num(r["detection"].get("missed_touch_rate")),
            "false_touch": num(r["detection"].get("false_touch_rate"))}


def floors(ds, *, train, min_force_n: float = 0.5) -> dict:
    """The plain scikit-learn floors trained on the sessions ``train`` (:func:`sonicskin.seeds.plain_floors`)."""
    from sonicskin.feature_cache import load_features_cached
    from sonicskin.seeds import plain_floors

    return plain_floors(load_features_cached(ds, progress=False), ds.rig, train=train, test=SPLIT["test"],
                        min_force_n=min_force_n)


def describe(sc) -> dict:
    g = sc.geometry
    size = (f"tube r {g['radius_cm']:.1f} x {g['length_cm']:.0f} cm" if g["kind"] == "tube"
            else f"plate {g['width_cm']:.0f} x {g['length_cm']:.0f} cm")
    return {"material": sc.material, "surface": size, "locations": len(sc.make_layout()), "people": list(sc.subjects),
            "motion": sc.motion.get("level", 0.0) if sc.motion.get("enabled") else 0.0, "loss_factor": sc.loss_factor,
            "warmup_c": sc.temperature["warmup_c"]}


def run_seed(seed: int, *, cache: Path, out: Path, rig_name: str, epochs: int | None, protocol: str, log) -> dict:
    from sonicskin.cli import main
    from sonicskin.rig import Rig
    from sonicskin.seeds import scenario_dataset
    from sonicskin.sim.scenario import Scenario

    t0 = time.perf_counter()
    # simulated again when the cached one was made by other code, another family draw or another rig (its made-by stamp)
    ds = scenario_dataset("random", seed, cache, rig=Rig.load(rig_name), log=log)
    sim_s = time.perf_counter() - t0
    rep = out / "compare" / f"random-{seed}"
    argv = ["compare", "--data", str(ds.root), "--train", *SPLIT["train"], *PROTOCOLS[protocol], "--test", *SPLIT["test"],
            "--runs", str(out / "runs"), "--out", str(rep), "--trainer.enable_progress_bar", "false",
            "--trainer.enable_model_summary", "false"]
    if epochs:
        argv += ["--trainer.max_epochs", str(epochs)]
    t1 = time.perf_counter()
    buf_out, buf_err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(buf_out), contextlib.redirect_stderr(buf_err):
        code = main(argv)
    (rep.parent / f"random-{seed}.log").write_text(buf_out.getvalue() + "\n--- stderr ---\n" + buf_err.getvalue())
    if code != 0:
        raise RuntimeError(f"seed {seed}: sonicskin compare exited {code}: {buf_err.getvalue().strip().splitlines()[-1:]}")
    res = json.loads((rep / "compare.json").read_text())
    models_s = time.perf_counter() - t1
    t2 = time.perf_counter()
    # floors trained on the same presses as the deployed models: s000, and with the refit s000 + s001 (both printed)
    fl = floors(ds, train=SPLIT["train"] + (SPLIT["val"] if protocol == "refit" else []))
    fl1 = floors(ds, train=SPLIT["train"]) if protocol == "refit" else fl
    fl.update({f"{k}_s000": v for k, v in fl1.items() if k.endswith("accuracy") or k.endswith("rmse_n")})
    row = {"seed": int(seed), "rig": describe(Scenario.load("random", seed=seed)), "split": res["split"],
           "protocol": protocol, "chirps_per_location": res["chirps_per_location"],
           **{k: _model_metrics(res["models"][k]) for k in MODELS if k in res["models"]}, "floor": fl,
           "net_layer": ((json.loads((Path(res["artifact"]) / "skin.json").read_text()).get("selection") or {}).get("net")
                         or {}).get("location_layer"),
           "seconds": {"simulate": sim_s, "models": models_s, "floors": time.perf_counter() - t2}}
    log(f"seed {seed} ({row['rig']['material']} {row['rig']['surface']}, {row['rig']['locations']} locations): accuracy "
        f"net {row['net']['accuracy']:.1%} ({row['net_layer']}) svm {row['svm']['accuracy']:.1%} "
        f"lda {row.get('lda', {}).get('accuracy', np.nan):.1%} floors SVC "
        f"{fl['svc_accuracy']:.1%} LDA {fl['lda_accuracy']:.1%} normalized SVC {fl['normalized_svc_accuracy']:.1%}; force RMSE net "
        f"{row['net']['force_rmse_n']:.2f} svm {row['svm']['force_rmse_n']:.2f} SVR {fl.get('svr_force_rmse_n', np.nan):.2f} "
        f"mean {fl.get('mean_force_rmse_n', np.nan):.2f} N; missed net {row['net']['missed_touch']:.1%} "
        f"svm {row['svm']['missed_touch']:.1%} ({time.perf_counter() - t0:.0f} s)")
    return row


def summarize(rows: list[dict]) -> dict:
    """Per quantity: mean and std over seeds; per pair: mean difference and 95 % t interval over seeds."""
    from sonicskin.metrics import t_interval

    def col(get):
        return np.array([get(r) for r in rows], float)

    q = {f"{m}/{k}": col(lambda r, m=m, k=k: r.get(k, {}).get(m, np.nan)) for m in METRICS for k in MODELS}
    for k in ("svc", "lda", "normalized_svc"):
        q[f"accuracy/{k}_floor"] = col(lambda r, k=k: r["floor"].get(f"{k}_accuracy", np.nan))
        if any("lda_accuracy_s000" in r["floor"] and r.get("protocol") == "refit" for r in rows):
            q[f"accuracy/{k}_floor_s000"] = col(lambda r, k=k: r["floor"].get(f"{k}_accuracy_s000", np.nan))
    q["force_rmse_n/svr_floor"] = col(lambda r: r["floor"].get("svr_force_rmse_n", np.nan))
    q["force_rmse_n/mean_floor"] = col(lambda r: r["floor"].get("mean_force_rmse_n", np.nan))
    q = {k: v for k, v in q.items() if np.isfinite(v).any()}
    out = {"values": {k: {"mean": float(np.nanmean(v)), "std": float(np.nanstd(v, ddof=1)) if np.isfinite(v).sum() > 1 else 0.0,
                          "n": int(np.isfinite(v).sum())} for k, v in q.items()}, "pairs": {}}
    pairs = [(f"{m}/net", f"{m}/svm") for m in METRICS] + [(f"{m}/net", f"{m}/lda") for m in METRICS] + [
        ("accuracy/svm", "accuracy/svc_floor"), ("accuracy/net", "accuracy/svc_floor"),
        ("accuracy/svm", "accuracy/lda_floor"), ("accuracy/net", "accuracy/lda_floor"),
        ("accuracy/svm", "accuracy/normalized_svc_floor"), ("accuracy/net", "accuracy/normalized_svc_floor"),
        *[("accuracy/net", f"accuracy/{k}_floor_s000") for k in ("svc", "lda", "normalized_svc") if f"accuracy/{k}_floor_s000" in q],
        ("force_rmse_n/svm", "force_rmse_n/svr_floor"), ("force_rmse_n/net", "force_rmse_n/svr_floor"),
        ("force_rmse_n/svm", "force_rmse_n/mean_floor"), ("force_rmse_n/net", "force_rmse_n/mean_floor")]
    for a, b in [(a, b) for a, b in pairs if a in q and b in q]:
        d = q[a] - q[b]
        lo, hi = t_interval(d[np.isfinite(d)])
        out["pairs"][f"{a} - {b}"] = {"mean": float(np.nanmean(d)), "ci95": [lo, hi], "n": int(np.isfinite(d).sum())}
    return out


from sonicskin.seeds import FLOOR_NAMES  # noqa: E402


def _f(v: float, unit: str, signed: bool = False) -> str:
    s = "+" if signed else ""
    return f"{v * 100:{s}.1f}" if unit == "pct" else f"{v:{s}.2f}"


NAMES = {"net": "network", "svm": "package SVM", "lda": "package LDA", **{f"{k}_floor": v for k, v in FLOOR_NAMES.items()},
         **{f"{k}_floor_s000": f"{v}, trained on s000 alone" for k, v in FLOOR_NAMES.items()}}


def format_markdown(res: dict) -> str:
    S = res["summary"]
    u = {"pct": " %", "N": " N"}
    how = (f"validation {', '.join(SPLIT['val'])}, the deployed models and the floors refitted on s000 + s001"
           if res.get("protocol", "refit") == "refit" else "no validation session (one session, one press per marker)")
    lines = [f"Random rigs, seeds {res['seeds']} ({res['seed_list']}); sessions: train {', '.join(SPLIT['train'])}, "
             f"{how}, test {', '.join(SPLIT['test'])} (one press per marker per session). "
             f"Mean ± std over {len(res['rows'])} rigs; intervals: 95 % Student t over rigs of the paired difference. "
             f"Wall time {res['wall_s'] / 60:.0f} min.", "",
             "| metric | model / floor | mean ± std |", "|---|---|---|"]
    for key, v in S["values"].items():
        m, who = key.split("/")
        unit = METRICS[m][0]
        lines.append(f"| {LABELS[m]} | {NAMES[who]} | {_f(v['mean'], unit)} ± {_f(v['std'], unit)}{u[unit]} |")
    lines += ["", "| paired difference | mean [95 % CI] |", "|---|---|"]
    for key, v in S["pairs"].items():
        a, b = key.split(" - ")
        m = a.split("/")[0]
        unit = METRICS[m][0]
        lo, hi = v["ci95"]
        lines.append(f"| {LABELS[m]}: {NAMES[a.split('/')[1]]} − {NAMES[b.split('/')[1]]} | {_f(v['mean'], unit, True)} "
                     f"[{_f(lo, unit, True)}, {_f(hi, unit, True)}]{u[unit]} |")
    lines += ["", "Per rig (F: force RMSE in N; missed / false: touch detection in %):", "",
              "| seed | rig | locations | motion | net acc | SVM acc | SVC floor | LDA floor | norm. SVC floor | net layer | "
              "net F | SVM F | SVR F | mean F | net missed | SVM missed | net false | SVM false |",
              "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in res["rows"]:
        g, n, s, fl = r["rig"], r["net"], r["svm"], r["floor"]
        counts = np.array(list(r["chirps_per_location"].values()))
        lines.append(f"| {r['seed']} | {g['material']} {g['surface']} | {g['locations']} ({counts.min()}-{counts.max()} chirps each) | "
                     f"{g['motion']:.2f} | {n['accuracy']:.1%} | {s['accuracy']:.1%} | {fl['svc_accuracy']:.1%} | "
                     f"{fl.get('lda_accuracy', np.nan):.1%} | {fl.get('normalized_svc_accuracy', np.nan):.1%} | "
                     f"{r.get('net_layer') or '-'} | "
                     f"{n['force_rmse_n']:.2f} | {s['force_rmse_n']:.2f} | {fl.get('svr_force_rmse_n', np.nan):.2f} | "
                     f"{fl.get('mean_force_rmse_n', np.nan):.2f} | "
                     f"{n['missed_touch']:.1%} | {s['missed_touch']:.1%} | {n['false_touch']:.1%} | {s['false_touch']:.1%} |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    from sonicskin.seeds import run_code, stored_run
    from sonicskin.sim.scenario import family_seeds

    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--seeds", nargs="+", default=["heldout"],
                   help="'heldout' (default: the family's held-out seeds), 'previous' (the earlier held-out set), 'design', "
                        "or seed numbers")
    p.add_argument("--cache", default="data/random", help="simulated datasets (default: data/random)")
    p.add_argument("--out", default="reports/random-rigs", help="report folder (default: reports/random-rigs)")
    p.add_argument("--rig", default="jaco", help="acquisition rig (default: jaco, the paper's)")
    p.add_argument("--epochs", type=int, help="network epochs (default: the training config's)")
    p.add_argument("--resume", action="store_true",
                   help="keep per-seed results already in OUT/seeds made by the same code and settings (default: recompute)")
    p.add_argument("--protocol", choices=sorted(PROTOCOLS), default="refit",
                   help="refit: validate on s001, refit on s000 + s001 (default); oneshot: s000 alone, no validation")
    a = p.parse_args(argv)
    fam = family_seeds("random")
    if a.seeds in (["heldout"], ["design"], ["previous"]):
        seed_list, seeds = a.seeds[0], list(fam[a.seeds[0]])
    else:
        seeds = [int(s) for s in a.seeds]
        seed_list = ("held-out" if set(seeds) <= set(fam["heldout"]) else "previous held-out" if set(seeds) <= set(fam["previous"])
                     else "design" if set(seeds) <= set(fam["design"]) else "mixed")
    out = Path(a.out)
    (out / "seeds").mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    rows = []
    for s in seeds:
        f = out / "seeds" / f"{s}.json"
        key = {"code": run_code(), "rig": a.rig, "epochs": a.epochs, "protocol": a.protocol}
        stored = stored_run(f, key) if a.resume else None  # a seed made by other code or settings is run again
        if stored is not None:
            rows.append(stored)
            continue
        row = {**run_seed(s, cache=Path(a.cache), out=out, rig_name=a.rig, epochs=a.epochs, protocol=a.protocol, log=print),
               "key": key}
        f.write_text(json.dumps(row, indent=1))
        rows.append(row)
        sys.stdout.flush()
    res = {"seeds": seeds, "seed_list": seed_list, "split": SPLIT, "protocol": a.protocol, "rows": rows, "summary": summarize(rows),
           "wall_s": time.perf_counter() - t0}
    (out / "random.json").write_text(json.dumps(res, indent=1))
    md = format_markdown(res)
    (out / "random.md").write_text(md + "\n")
    print(md)
    print(f"wrote {out}/random.json, {out}/random.md")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
