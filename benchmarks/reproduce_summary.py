"""One table of `sonicskin reproduce`'s findings next to the paper's, from its report.json (stdout: markdown).

    python benchmarks/reproduce_summary.py reports/reproduce/report.json

Every cell is the mean ± std over the report's simulator seeds (the report's own `mean`/`std`); rows of
experiments the report did not run are left out. The whole report, per session and per model, is the
report.md beside the JSON.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

KINDS = (("svm", "SVM"), ("net", "network"))
CHECKPOINTS_MIN = (30, 60, 90, 120)  # Fig. 12's time axis


def _num(v) -> float:
    return float("nan") if v is None else float(v)  # report.json is strict JSON: a number not measured is null


def _mean(x) -> float:
    return _num(x["mean"]) if isinstance(x, dict) else float(np.mean([_num(v) for v in np.ravel(x)]))


def _std(x) -> float:
    return _num(x["std"]) if isinstance(x, dict) else float(np.std([_num(v) for v in np.ravel(x)]))


def pct(x) -> str:
    return f"{_mean(x):.1%} ± {_std(x):.1%}"


def newton(x) -> str:
    return f"{_mean(x):.2f} ± {_std(x):.2f} N"


def rows(r: dict) -> list[tuple[str, str, str, str]]:
    out = []
    have = [k for k, _ in KINDS if k in r.get("fig6b", r.get("table1", {}).get("fig14", {}))] or ["svm"]

    def both(f):
        return tuple(f(k) if k in have else "not run" for k, _ in KINDS)

    if "fig6b" in r:
        f = r["fig6b"]
        out.append(("Fig. 6b: all 6400 band bins -> OSPA, moving robot", "54.3 -> 96.7 %",
                    *both(lambda k: f"{pct(f[k]['all_bins'])} -> {pct(f[k]['ospa'])}")))
    if "fig11" in r:
        f = r["fig11"]

        def best(k):
            g = {int(float(a)): np.mean([_mean(v) for v in (b if isinstance(b, list) else [b])]) for a, b in f[k].items()}
            top = max(g, key=g.get)
            return f"best gamma {top}: {g[top]:.1%}; gamma {max(g)}: {g[max(g)]:.1%}"
        out.append(("Fig. 11: accuracy vs gamma", "> 95 % from a few hundred bins", *both(best)))
    if "table1" in r:
        t = r["table1"]
        for key, label, paper in (("stationary", "stationary one-shot accuracy", "99.4 %"),
                                  ("fig14", "Fig. 14: moving robot, accuracy / < 3 cm", "96.2 / 97.0 %"),
                                  ("fig15", "Fig. 15: unseen people, accuracy / < 3 cm", "97.2 / 98.5 %")):
            if key not in t:
                continue
            if key == "stationary":
                out.append((label, paper, *both(lambda k, t=t, key=key: pct(t[key][k]["accuracy"]))))
            else:
                def acc3(k, t=t, key=key):
                    return f"{pct(t[key][k]['accuracy'])} / {_mean(t[key][k]['within_3cm']):.1%}"
                out.append((label, paper, *both(acc3)))
        if "fig14" in t:
            out.append(("moving robot: false / missed touches", "not reported",
                        *both(lambda k: f"{_mean(t['fig14'][k]['false_touch']):.1%} / {_mean(t['fig14'][k]['missed_touch']):.1%}")))
        tab = t.get("table1", {})
        for scen, paper in (("stationary", "0.59 N"), ("moving", "1.86 N")):
            cells = []
            for k, name in KINDS:
                key = next((n for n in tab if scen in n and (name.lower() in n.lower() or k in n.lower())), None)
                cells.append(newton(tab[key]["rmse_n"]) if key else "not run")
            out.append((f"Table I: force RMSE, {scen}", paper, *cells))
    if "fig12" in r:
        f = r["fig12"]
        at = np.array([_mean(m) for m in f["minutes"]])
        # The paper's checkpoints: the session nearest each half hour (the full run has one every 5 min;
        # report.md lists them all).
        keep = (sorted({int(np.argmin(np.abs(at - t))) for t in CHECKPOINTS_MIN}) if len(at) > len(CHECKPOINTS_MIN)
                else range(len(at)))
        mins = " / ".join(f"{at[i]:.0f}" for i in keep)

        def series(k, a):
            key = f"{k} alpha={a}"
            return " / ".join(f"{_mean(f[key][i]):.1%}" for i in keep) if key in f else "not run"
        out.append((f"Fig. 12: warm-up, no updating, at {mins} min", "drops after 30 min", *both(lambda k: series(k, "never"))))
        out.append((f"Fig. 12: warm-up, Alg. 2 every 20 min, at {mins} min", "stays stable", *both(lambda k: series(k, "20 min"))))
        if "two_months" in f:
            tm = f["two_months"]

            def rng(k):
                parts = []
                for a in ("with updating", "without"):
                    v = [_mean(x) for x in tm.get(f"{k} {a}", [])]
                    parts.append(f"{a} {min(v):.0%}-{max(v):.0%}" if v else f"{a} not run")
                return "; ".join(parts)
            out.append(("Fig. 12: two months of daily ±3 C swings (range over sessions)", "stable with updating", *both(rng)))
    if "fig13" in r:
        f = r["fig13"]
        e, eo = f.get("E (all band bins)"), f.get("E^O (OSPA bins)")
        if e and eo:
            net = f.get("network (training fit)")
            out.append(("Fig. 9/13: force curve fit R², Fourier-1, E vs E^O", "E^O better, 0.92",
                        f"E {_mean(e['fourier1']):.2f} ± {_std(e['fourier1']):.2f} vs E^O {_mean(eo['fourier1']):.2f} ± "
                        f"{_std(eo['fourier1']):.2f}", f"force head {_mean(net):.2f}" if net is not None else "not run"))
    if "fig16" in r:
        f = r["fig16"]
        two = [n for n in f if "36" not in n]
        plate = [n for n in f if "36" in n]

        def mat(k):
            if k not in f[two[0]]:
                return "not run"
            acc = [_mean(f[n][k]["accuracy"]) for n in two]
            frc = [_mean(f[n][k]["force"]["rmse_n"]) for n in two]
            s = f"2 markers: {min(acc):.1%}-{max(acc):.1%}, force {min(frc):.2f}-{max(frc):.2f} N"
            if plate:
                s += f"; plate: {pct(f[plate[0]][k]['accuracy'])}"
            return s
        out.append((f"Fig. 16: 2 markers 1.2 cm apart on {len(two)} materials; 36-marker plate", "100 %; force < 0.5 N",
                    *both(mat)))
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("report", help="report.json written by `sonicskin reproduce`")
    a = ap.parse_args(argv)
    p = Path(a.report)
    if not p.is_file():
        print(f"reproduce_summary: error: {p} does not exist; run `sonicskin reproduce --out {p.parent}` first", file=sys.stderr)
        return 2
    r = json.loads(p.read_text())
    print(f"Seeds {r['seeds']}, {'quick' if r['quick'] else 'full'} size, experiments {', '.join(r['experiments'])}; "
          f"run time {r['runtime_s'] / 60:.1f} min. Mean ± std over the seeds.")
    print()
    print("| paper's finding | paper | SVM | network |")
    print("|---|---|---|---|")
    for row in rows(r):
        print("| " + " | ".join(row) + " |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
