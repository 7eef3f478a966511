"""Network vs SVM over several simulator seeds and training seeds, with a paired confidence interval.

The paired difference is net minus SVM on the same data; the unit of the interval is the simulator seed (the
network's mean over its training seeds minus the SVM's), a Student t interval over those differences."""

from __future__ import annotations

import dataclasses
import functools
import json
import time
from pathlib import Path

import numpy as np

from .compare import replay_sessions, split_line, stream_metrics
from .dataset import Dataset, Split
from .feature_cache import code_digest, load_features_cached
from .features import FeatureSpec, touch_mask
from .fit import fit_models, prepare, write_artifact
from .jsonio import json_safe
from .kinds import BASELINE, CLOSED_FORM, NETWORK
from .metrics import t_interval
from .ospa import select_bins
from .plots import pyplot
from .rig import Rig
from .runtime import SkinRuntime
from .sim.generate import simulate_dataset
from .sim.scenario import Scenario

__all__ = ["SCENARIOS", "METRICS", "scenario_dataset", "compare_seeds", "summarize", "format_markdown", "save_seeds",
           "plain_floors", "FLOOR_NAMES", "RUN_CODE", "run_code", "stored_run"]

# Scenario -> how it is split.  One-shot: the first session trains, every later session tests.
SCENARIOS: dict[str, dict] = {
    "moving": {}, "stationary": {}, "drift-2h": {}, "two-points": {}, "plate-aluminium": {},
    "multi-person": {"test_subjects": [8, 9, 10, 11]},  # leave-subjects-out: 8 people train, 4 test
}

# name -> (how to read it from a stream_metrics result, unit / format, larger is better)
METRICS: dict[str, tuple] = {
    "accuracy": (lambda r: r["localization"]["accuracy"], "pct", True),
    "within_2cm": (lambda r: r["localization"]["within_2cm"], "pct", True),
    "continuous_error_cm": (lambda r: r["continuous_error_cm"]["median"], "cm", False),
    "force_rmse_n": (lambda r: r["force"].get("rmse_n", np.nan), "N", False),  # absent without a force sensor
    "false_touch": (lambda r: r["detection"].get("false_touch_rate", np.nan), "pct", False),
    "missed_touch": (lambda r: r["detection"].get("missed_touch_rate", np.nan), "pct", False),
}
LABELS = {"accuracy": "accuracy", "within_2cm": "error < 2 cm", "continuous_error_cm": "continuous xy error (median)",
          "force_rmse_n": "force RMSE", "false_touch": "false touches", "missed_touch": "missed touches"}


# -- the plain scikit-learn floors every accuracy claim is printed beside (a result below them is not a result): fitted
# on the training sessions' touch chirps, scored on every test touch chirp, default parameters (svc and lda on every
# usable bin, normalized_svc on OSPA's 300; force: a pooled SVR and the training mean), on dB minus each session's
# boot reference
#: floor key -> how reports name it
FLOOR_NAMES = {"svc": "SVC floor (all bins)", "lda": "shrinkage LDA floor (all bins)",
               "normalized_svc": "normalized SVC floor (OSPA 300)", "svr": "pooled SVR floor", "mean": "training-mean floor"}


def boot_relative(t, rig) -> np.ndarray:
    """Every usable bin of every chirp minus its session's boot reference (the first ``beta`` chirps)."""
    beta = FeatureSpec((0,), "relative").reference(rig.chirps_per_s).beta
    X = t.X[:, rig.allowed_mask].astype(np.float64)
    for s in np.unique(t["session"]):
        idx = np.flatnonzero(t["session"] == s)
        X[idx] -= X[idx[:beta]].mean(axis=0)
    return X


def plain_floors(t, rig, *, train, test, min_force_n: float = 0.5) -> dict:
    """The plain floors on the feature table ``t``: ``<floor>_accuracy`` and the force RMSEs (without sensor: absent)."""
    from sklearn.discriminant_analysis import LinearDiscriminantAnalysis
    from sklearn.pipeline import make_pipeline
    from sklearn.preprocessing import Normalizer, StandardScaler
    from sklearn.svm import SVC, SVR

    X = boot_relative(t, rig)
    touch = touch_mask(t, min_force_n)
    tr = touch & np.isin(t["session"], list(train))
    te = touch & np.isin(t["session"], list(test))
    loc, f = t["location"], t["force_n"]
    t0 = time.perf_counter()
    allowed = np.flatnonzero(rig.allowed_mask)
    pos = np.full(rig.n_band, -1)
    pos[allowed] = np.arange(allowed.size)
    ospa = pos[select_bins(t.select(np.isin(t["session"], list(train))), rig, min(300, allowed.size), min_force_n)]
    models = {"svc": (make_pipeline(StandardScaler(), SVC()), slice(None)),
              "lda": (LinearDiscriminantAnalysis(solver="lsqr", shrinkage="auto"), slice(None)),
              "normalized_svc": (make_pipeline(Normalizer(), StandardScaler(), SVC(C=10)), ospa)}
    out = {}
    for name, (model, cols) in models.items():
        model.fit(X[tr][:, cols], loc[tr])
        out[f"{name}_accuracy"] = float(np.mean(model.predict(X[te][:, cols]) == loc[te]))
    a, b = tr & np.isfinite(f), te & np.isfinite(f)
    if a.sum() >= 8 and b.any() and np.ptp(f[a]) > 0:
        svr = make_pipeline(StandardScaler(), SVR()).fit(X[a], f[a])
        out["svr_force_rmse_n"] = float(np.sqrt(np.mean((np.clip(svr.predict(X[b]), 0, None) - f[b]) ** 2)))
        out["mean_force_rmse_n"] = float(np.sqrt(np.mean((f[a].mean() - f[b]) ** 2)))
    return {**out, "n_bins": int(X.shape[1]), "n_train_touch": int(tr.sum()), "n_test_touch": int(te.sum()),
            "fit_s": time.perf_counter() - t0}


#: what a finished run executes: the package and the folders pyproject.toml maps into it (models/, training/ and export/
#: sit at the top of the checkout, outside sonicskin/)
RUN_CODE = ("sonicskin", "sonicskin.models", "sonicskin.training", "sonicskin.export")


@functools.cache
def run_code() -> str:
    """:func:`code_digest` of :data:`RUN_CODE`, read once per process (close to the code it imported)."""
    return code_digest(*RUN_CODE)


#: what simulating a scenario executes (the simulator and the modules it imports): a cached dataset is made again when
#: one of them changes, not when a model or a verb does
SIM_CODE = ("sonicskin.sim", "sonicskin.rig", "sonicskin.dsp", "sonicskin.dataset", "sonicskin.errors", "sonicskin.threads")


@functools.cache
def _sim_code() -> str:
    return code_digest(*SIM_CODE)


def stored_run(path: Path, key: dict, log=print) -> dict | None:
    """The finished run stored at ``path`` (a JSON object with ``"key"``) when its key is ``key``, which names the code
    (:func:`run_code`); else ``None``, and one line says why a stored run is run again."""
    if not path.is_file():
        return None
    try:
        doc = json.loads(path.read_text())
    except (OSError, ValueError):
        doc = None
    old = doc.get("key") if isinstance(doc, dict) else None
    if old == json.loads(json.dumps(key)):
        return doc
    why = ("it names no code (stored before runs were keyed by it)" if not isinstance(old, dict) or "code" not in old
           else f"it was made by other code ({old['code']}, now {key.get('code')})" if old["code"] != key.get("code")
           else "it was made with other settings")
    log(f"{path}: not resumed, {why}; running it again")
    return None


def _stamp_differs(path: Path, want: dict) -> str | None:
    """Why the simulated dataset ``path`` was not made as ``want`` says (its ``.cache/made-by.json``), or ``None``."""
    try:
        have = json.loads((path / ".cache" / "made-by.json").read_text())
    except (OSError, ValueError):
        return "it has no readable .cache/made-by.json (made by an older sonicskin, or interrupted)"
    if not isinstance(have, dict):
        return "its .cache/made-by.json is not a JSON object"
    for k, what in (("code", "other code"), ("scenario", "another scenario"), ("rig", "another rig")):
        if have.get(k) != want[k]:
            return f"it was made with {what}" + (f" ({have.get('code')}, now {want['code']})" if k == "code" else "")
    return None


def scenario_dataset(name: str, seed: int, cache: str | Path, *, rig: Rig | None = None, log=print, **overrides) -> Dataset:
    """Scenario ``name`` simulated with ``seed`` under ``cache`` (made on first use); ``overrides`` replace scenario fields.

    A cached dataset is used only when its ``.cache/made-by.json`` names the code (:func:`code_digest` of
    :data:`SIM_CODE`), the scenario and the rig asked for; otherwise it is simulated again (one line says why)."""
    rig = rig or Rig.load("jaco")
    path = Path(cache) / ("" if rig.name == "jaco-link" else rig.name) / f"{name}-seed{seed}"
    sc = Scenario.load(name, seed=int(seed))  # a family (random) draws another rig per seed
    if overrides:
        sc = sc.replace(**overrides)
    want = json.loads(json.dumps({"code": _sim_code(), "scenario": sc.to_dict(), "rig": rig.to_dict()}))
    done = (path / "dataset.json").is_file() and Dataset(path).sessions and all(
        (path / s / "session.json").is_file() for s in Dataset(path).sessions)
    why = _stamp_differs(path, want) if done else None
    if why:
        log(f"{path}: simulated again, {why}")
    if not done or why:
        (path / ".cache" / "made-by.json").unlink(missing_ok=True)  # stamped again only once whole
        simulate_dataset(sc, rig, path, mode="overwrite", progress=False, log=log)
        (path / ".cache").mkdir(exist_ok=True)
        (path / ".cache" / "made-by.json").write_text(json.dumps(want, indent=1) + "\n")
    return Dataset(path)


def _split(t, test_subjects=None, val: bool = False) -> Split:
    """One-shot: the first session trains, the later ones test; ``val``: the next validates, then a refit on both."""
    if test_subjects:
        sp = Split.make(t, test_subjects=test_subjects)
        return sp if val else Split(sp.train + sp.val, (), sp.test)
    return Split.make(t, val_sessions=None if val else [])


def _floors(ds: Dataset, t, split) -> dict:
    """The plain floors on the same split (:func:`plain_floors`) under the names the summaries use."""
    f = plain_floors(t, ds.rig, train=list(split.train) + list(split.val), test=list(split.test))
    out = {"accuracy": f["svc_accuracy"], "lda_accuracy": f["lda_accuracy"], "normalized_svc_accuracy": f["normalized_svc_accuracy"]}
    if "svr_force_rmse_n" in f:
        out.update(force_rmse_n=f["svr_force_rmse_n"], force_rmse_constant_n=f["mean_force_rmse_n"])
    return out


def _one_seed(name: str, ds: Dataset, train_seeds, work: Path, *, epochs: int | None, log, select: bool = True,
              train_stride: int = 1, val: bool = False) -> list[dict]:
    """Every model on one simulated dataset through the one fit, each exported to ``work`` and its test sessions replayed."""
    quiet_log = lambda m: None  # noqa: E731
    t = load_features_cached(ds, progress=False)
    split = _split(t, SCENARIOS.get(name, {}).get("test_subjects"), val)
    data = prepare(ds, table=t, split=split, n_bins=None if select else 300, wide=True, log=quiet_log)
    if train_stride > 1:
        data = dataclasses.replace(data, usable=data.usable & (np.arange(len(t)) % int(train_stride) == 0))
    te = t.select(split.mask(t, "test"))
    floor = _floors(ds, t, Split(split.train + split.val, (), split.test))  # the floors train on every labelled press
    out, closed_metrics, layer = [], {}, None
    for seed in train_seeds:
        final, fits = fit_models(data, [NETWORK], log=quiet_log,
                                 options={BASELINE: {"select": select}, NETWORK: {"select": select, "seed": int(seed),
                                                                                  "epochs": epochs, "layer": layer}})
        net = fits[NETWORK]
        layer = layer or {k: v for k, v in net.selection[NETWORK].items() if k in ("location_layer", "layer_how", "hparams")}
        skin = write_artifact(final, work, fits, training={"train_seed": int(seed)}, log=quiet_log)
        sel = skin.get("selection") or {}
        row = {"train_seed": int(seed), "train_s": {k: f.fit_s for k, f in fits.items()}, "floor": floor,
               "split": skin["training"]["split"] | ({"refit": True} if skin["training"].get("refit") else {}),
               "selection": {k: {kk: v[kk] for kk in ("params", "model", "name", "location_layer", "detector", "force") if kk in v}
                             for k, v in sel.items() if isinstance(v, dict)}}
        for k in fits:
            if k in closed_metrics:  # deterministic: the same model every training seed
                row[k] = closed_metrics[k]
                continue
            p = replay_sessions(SkinRuntime(work, k), te, split.test)
            row[k] = {m: float(f(stream_metrics(p, te, ds.layout))) for m, (f, _, _) in METRICS.items()}
        closed_metrics = {k: row[k] for k in fits if k != NETWORK}
        n, b = row[NETWORK], row[BASELINE]
        log(f"  {name} seed {ds.root.name.rsplit('seed', 1)[-1]} train seed {seed}: accuracy net {n['accuracy']:.1%} svm "
            f"{b['accuracy']:.1%} lda {row.get(CLOSED_FORM, {}).get('accuracy', np.nan):.1%} floor {floor['accuracy']:.1%} "
            f"LDA floor {floor['lda_accuracy']:.1%}; force net {n['force_rmse_n']:.2f} svm {b['force_rmse_n']:.2f} SVR floor "
            f"{floor.get('force_rmse_n', np.nan):.2f} N; missed net {n['missed_touch']:.1%} svm {b['missed_touch']:.1%} "
            f"(net trained in {net.fit_s:.0f} s; {row['selection']})")
        out.append(row)
    return out


def summarize(runs: dict[int, list[dict]]) -> dict:
    """Mean and std per model, and the paired net - SVM difference with its 95 % t interval over simulator seeds."""
    out = {}
    for m in METRICS:
        net = np.array([r[NETWORK][m] for rows in runs.values() for r in rows], float)
        svm = np.array([rows[0][BASELINE][m] for rows in runs.values()], float)
        d = np.array([np.mean([r[NETWORK][m] for r in rows]) - rows[0][BASELINE][m] for rows in runs.values()], float)
        lo, hi = t_interval(d)
        lda = np.array([rows[0].get(CLOSED_FORM, {}).get(m, np.nan) for rows in runs.values()], float)
        out[m] = {"net_mean": float(net.mean()), "net_std": float(net.std(ddof=1)) if net.size > 1 else 0.0,
                  "lda_mean": float(np.nanmean(lda)) if np.isfinite(lda).any() else None,
                  "svm_mean": float(svm.mean()), "svm_std": float(svm.std(ddof=1)) if svm.size > 1 else 0.0,
                  "diff_mean": float(d.mean()), "diff_ci95": [lo, hi], "n_sim_seeds": int(d.size), "n_net_runs": int(net.size)}
    return out


def compare_seeds(scenarios: list[str], *, sim_seeds=(0, 1, 2), train_seeds=(0, 1), cache: str | Path = "data/seeds",
                  out: str | Path = "reports/compare-seeds", epochs: int | None = None, select: bool = True,
                  rig: Rig | None = None, val: bool = False, log=print) -> dict:
    """Run every scenario over ``sim_seeds`` x ``train_seeds`` (``val``: the second session validates, then a refit on both)."""
    unknown = [s for s in scenarios if s not in SCENARIOS]
    if unknown:
        raise ValueError(f"unknown scenario(s) {unknown}; the comparison knows {sorted(SCENARIOS)}")
    if len(sim_seeds) < 2:
        raise ValueError("a confidence interval needs at least 2 simulator seeds (--sim-seeds 0 1 2)")
    out = Path(out)
    rig = rig or Rig.load("jaco")
    res: dict = {"sim_seeds": [int(s) for s in sim_seeds], "train_seeds": [int(s) for s in train_seeds],
                 "epochs": epochs, "rig": rig.name, "validation": bool(val), "scenarios": {}}
    for name in scenarios:
        t0 = time.perf_counter()
        runs = {}
        for s in sim_seeds:
            # Finished seeds are kept (an interrupted comparison resumes) while the code is the same; delete runs/ to train again.
            done = out / "runs" / f"{name}-seed{s}.json"
            key = {"code": run_code(), "train_seeds": [int(x) for x in train_seeds], "epochs": epochs, "select": bool(select),
                   "rig": rig.to_dict(), "val": bool(val)}
            stored = stored_run(done, key, log)
            if stored is not None:
                runs[int(s)] = stored["rows"]
                continue
            ds = scenario_dataset(name, s, cache, rig=rig, log=log)
            runs[int(s)] = _one_seed(name, ds, train_seeds, out / "artifacts" / f"{name}-seed{s}", epochs=epochs, log=log,
                                     select=select, val=val)
            done.parent.mkdir(parents=True, exist_ok=True)
            done.write_text(json.dumps({"key": key, "rows": runs[int(s)]}))
        res["scenarios"][name] = {"runs": {str(k): v for k, v in runs.items()}, "summary": summarize(runs),
                                  "wall_s": time.perf_counter() - t0}
        save_seeds(res, out)
    return res


def _fmt(v: float, unit: str, signed: bool = False) -> str:
    s = "+" if signed else ""
    if unit == "pct":
        return f"{v * 100:{s}.1f}"
    return f"{v:{s}.2f}"


def format_markdown(res: dict) -> str:
    """One table: scenario, metric, net mean ± std, SVM mean ± std, net - SVM with its 95 % interval."""
    lines = [f"Simulator seeds {res['sim_seeds']}, network training seeds {res['train_seeds']}; test sessions replayed "
             f"as the live loop runs them (no test labels). Mean ± std over runs (network: every simulator x training "
             f"seed; SVM, deterministic: every simulator seed). Percentages in points; interval: 95 % Student t over "
             f"simulator seeds of the paired difference.", "",
             "| scenario | metric | network | SVM | LDA | net − SVM [95 % CI] |", "|---|---|---|---|---|---|"]
    for name, sc in res["scenarios"].items():
        for m, (_, unit, _) in METRICS.items():
            r = sc["summary"][m]
            u = {"pct": " %", "cm": " cm", "N": " N"}[unit]
            lo, hi = r["diff_ci95"]
            lines.append(f"| {name} | {LABELS[m]} | {_fmt(r['net_mean'], unit)} ± {_fmt(r['net_std'], unit)}{u} | "
                         f"{_fmt(r['svm_mean'], unit)} ± {_fmt(r['svm_std'], unit)}{u} | "
                         f"{'n/a' if r.get('lda_mean') is None else _fmt(r['lda_mean'], unit) + u} | {_fmt(r['diff_mean'], unit, True)} "
                         f"[{_fmt(lo, unit, True)}, {_fmt(hi, unit, True)}]{u} |")
    floors = [("accuracy", "SVC (all bins)", "pct"), ("lda_accuracy", "shrinkage LDA (all bins)", "pct"),
              ("normalized_svc_accuracy", "normalized SVC (OSPA 300)", "pct"), ("force_rmse_n", "pooled SVR force", "N")]
    lines += ["", "Plain scikit-learn floors on the same splits (mean ± std over simulator seeds; a result below them is "
              "not a result):", "", "| scenario | " + " | ".join(f for _, f, _ in floors) + " |", "|---|" + "---|" * len(floors)]
    for name, sc in res["scenarios"].items():
        cells = []
        for key, _, unit in floors:
            v = np.array([rows[0].get("floor", {}).get(key, np.nan)  # results written before the floors: n/a
                          for rows in sc.get("runs", {}).values() if rows], float)
            v = v[np.isfinite(v)]
            u = {"pct": " %", "N": " N"}[unit]
            cells.append(f"{_fmt(v.mean(), unit)} ± {_fmt(v.std(ddof=1) if v.size > 1 else 0.0, unit)}{u}" if v.size else "n/a")
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    splits = {name: next((r["split"] for rows in sc.get("runs", {}).values() for r in rows if "split" in r), None)
              for name, sc in res["scenarios"].items()}
    if any(splits.values()):
        lines += [""] + [f"- {name}: {split_line(sp)}" for name, sp in splits.items() if sp]
    return "\n".join(lines)


def save_seeds(res: dict, out: str | Path) -> list[Path]:
    """``seeds.json``, ``seeds.md`` and ``seeds.png`` (paired differences with their intervals)."""
    plt = pyplot()
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "seeds.json").write_text(json.dumps(json_safe(res), indent=1, allow_nan=False))  # a NaN (no force sensor) as null
    (out / "seeds.md").write_text(format_markdown(res) + "\n")
    names = list(res["scenarios"])
    fig, axes = plt.subplots(1, len(METRICS), figsize=(3.2 * len(METRICS), 0.6 * len(names) + 2.2), sharey=True)
    for ax, (m, (_, unit, better_up)) in zip(axes, METRICS.items()):
        scale = 100 if unit == "pct" else 1
        for i, name in enumerate(names):
            r = res["scenarios"][name]["summary"][m]
            lo, hi = r["diff_ci95"]
            ax.errorbar(r["diff_mean"] * scale, i, xerr=[[(r["diff_mean"] - lo) * scale], [(hi - r["diff_mean"]) * scale]],
                        fmt="o", capsize=3, color="C0")
        ax.axvline(0, color="gray", lw=0.8)
        ax.set(title=f"{LABELS[m]}\n(net − SVM, {'points' if unit == 'pct' else unit}; {'>' if better_up else '<'} 0 favours net)")
        ax.title.set_fontsize(8)
        ax.grid(alpha=0.3)
    axes[0].set_yticks(range(len(names)), names)
    fig.suptitle(f"network minus SVM, 95 % interval over simulator seeds {res['sim_seeds']}", fontsize=9)
    fig.tight_layout()
    fig.savefig(out / "seeds.png", dpi=110)
    plt.close(fig)
    return [out / "seeds.json", out / "seeds.md", out / "seeds.png"]
