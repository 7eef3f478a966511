"""Evaluate the paper's reference system on a dataset, with the paper's ablations.

Train on the first session(s) (the one-shot training), test on the others, and report:
localization (accuracy, < 2 cm, < 3 cm), detection (false/missed touches), force (Table I),
and the three findings the paper builds on, measured on the same split:

- OSPA vs all band bins (Fig. 6b);
- online score calibration (Alg. 2) vs the training session's reference only (Fig. 12);
- force from ``E^O`` (OSPA bins) vs total energy ``E`` over the whole chirp band (Fig. 9).
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

from .baseline import SVMLocalizer
from .dataset import Dataset, FeatureTable
from .force import PerLocationForce, energy_db
from .metrics import force_report, localization_report
from .skin import SkinSVM

__all__ = ["split_sessions", "evaluate_svm"]


def split_sessions(table: FeatureTable, train_sessions: list[str]) -> tuple[FeatureTable, FeatureTable]:
    s = table["session"]
    unknown = set(train_sessions) - set(s)
    if unknown:
        raise ValueError(f"training sessions {sorted(unknown)} are not in the dataset ({sorted(set(s))})")
    tr = np.isin(s, train_sessions)
    if tr.all():
        raise ValueError("every session is a training session; leave at least one to test on")
    return table.select(tr), table.select(~tr)


def _quiet(t: FeatureTable) -> np.ndarray:
    return (t["location"] < 0) & (t["moving"] == 0)


def _touch(t: FeatureTable, min_force_n: float) -> np.ndarray:
    return (t["location"] >= 0) & (t["force_n"] >= min_force_n)


def evaluate_svm(ds: Dataset, *, train_sessions: list[str] | None = None, table: FeatureTable | None = None,
                 ablations: bool = True, min_force_n: float = 0.5, log=print) -> dict:
    """Train :class:`SkinSVM` on ``train_sessions`` (default: the first), test on the rest."""
    table = table if table is not None else ds.features()
    sessions = sorted(set(table["session"]))
    train_sessions = train_sessions or sessions[:1]
    tr, te = split_sessions(table, train_sessions)
    moving_tr = (tr["location"] < 0) & (tr["moving"] > 0)
    X_moving = tr.X[moving_tr] if moving_tr.sum() >= 2 else None
    t0 = time.perf_counter()
    model = SkinSVM(ds.rig, ds.layout, min_force_n=min_force_n)
    model.fit(tr.X, tr["location"], tr["force_n"], quiet=_quiet(tr), X_moving=X_moving)
    train_s = time.perf_counter() - t0
    res: dict = {"dataset": str(ds.root), "train_sessions": list(train_sessions),
                 "test_sessions": sorted(set(te["session"])), "n_train": len(tr), "n_test": len(te),
                 "train_time_s": train_s}
    # Test stream, session by session (each session is a stream with its own calibration).
    preds = {k: [] for k in ("location", "touch", "force", "location_offline")}
    for s in res["test_sessions"]:
        t = te.select(te["session"] == s)
        p = model.predict(t.X, time_s=t["time_s"], online=True)  # Alg. 2 from its own detection, no labels
        p0 = model.predict(t.X, online=False)
        preds["location"].append(p.location)
        preds["touch"].append(p.touch)
        preds["force"].append(np.clip(model.force_.predict(p.energy_db, t["location"].clip(min(ds.layout.ids))), 0, None))
        preds["location_offline"].append(p0.location)
    P = {k: np.concatenate(v) for k, v in preds.items()}
    touch = _touch(te, min_force_n)
    quiet_te = te["location"] < 0
    loc = localization_report(te["location"][touch], P["location"][touch], ds.layout)
    res["localization"] = {k: v for k, v in loc.items() if k != "errors_cm"}
    res["errors_cm"] = loc["errors_cm"].tolist()
    res["detection"] = {"threshold": model.detector_.threshold_,
                        "false_touch_rate": float(np.mean(P["touch"][quiet_te])),
                        "missed_touch_rate": float(np.mean(~P["touch"][touch])),
                        "train_false_touch_rate": model.detector_.false_touch_rate_,
                        "train_missed_touch_rate": model.detector_.missed_touch_rate_}
    # Force at the true location (the paper calibrates and reports force per location).
    res["force"] = force_report(te["force_n"][touch], P["force"][touch])
    if ablations:
        res["ablations"] = _ablations(ds, tr, te, model, P, touch, X_moving, min_force_n, log)
    return res


def _ablations(ds, tr, te, model, P, touch, X_moving, min_force_n, log) -> dict:
    out = {}
    tr_touch = _touch(tr, min_force_n)
    # OSPA vs every bin of the chirp band (no selection, no matched filter).
    t0 = time.perf_counter()
    allbins = SVMLocalizer(n_bins=ds.rig.n_band, allowed=None).fit(tr.X[tr_touch], tr["location"][tr_touch])
    acc_all = float(np.mean(allbins.predict(te.X[touch]) == te["location"][touch]))
    out["accuracy_all_bins"] = acc_all
    out["accuracy_ospa"] = float(np.mean(P["location"][touch] == te["location"][touch]))
    out["all_bins_train_time_s"] = time.perf_counter() - t0
    # Online calibration vs the training reference only.
    out["accuracy_without_online_calibration"] = float(np.mean(P["location_offline"][touch] == te["location"][touch]))
    # Force from total band energy E vs E^O over the OSPA bins.
    all_bins = np.arange(ds.rig.n_band)
    ref_tr = tr.X[_quiet(tr)].mean(axis=0)
    E_tr = energy_db(tr.X[tr_touch], all_bins, ref_tr)
    fm = PerLocationForce("fourier1").fit(E_tr, tr["force_n"][tr_touch], tr["location"][tr_touch])
    beta = model.calibrator.beta  # reference: each test stream's boot calibration (its first beta chirps)
    E_te = np.concatenate([energy_db(te.X[(te["session"] == s)], all_bins, te.X[(te["session"] == s)][:beta])
                           for s in sorted(set(te["session"]))])
    f_total = np.clip(fm.predict(E_te[touch], te["location"][touch]), 0, None)
    out["force_total_energy"] = force_report(te["force_n"][touch], f_total)
    out["force_train_r2_ospa"] = float(np.mean([c.r2 for c in model.force_.curves_.values()]))
    # Alg. 2 applied to the features: both splits minus their own running no-touch reference, the
    # training split's from its labelled rest, the test streams' from the SVM's own detection.
    from .features import relative_features

    cal = model.calibrator
    bins = model.localizer_.selected_
    rel = {"train": relative_features(tr.X[:, bins], _quiet(tr), tr["session"], tr["time_s"], cal),
           "test": relative_features(te.X[:, bins], ~P["touch"], te["session"], te["time_s"], cal)}
    rel_model = SVMLocalizer(n_bins=len(bins)).fit(rel["train"][tr_touch], tr["location"][tr_touch])
    p_rel = rel_model.predict(rel["test"][touch])
    out["accuracy_feature_calibration"] = float(np.mean(p_rel == te["location"][touch]))
    # Accuracy over stream time, session by session (Fig. 12).
    rows = []
    sess_touch = te["session"][touch]
    for s in sorted(set(te["session"])):
        k = sess_touch == s
        sel = (te["session"] == s) & touch
        rows.append({"session": s, "minutes": float(te["time_s"][sel].mean() / 60),
                     "temperature_c": float(te["temperature_c"][sel].mean()),
                     "accuracy": float(np.mean(P["location"][touch][k] == te["location"][touch][k])),
                     "accuracy_feature_calibration": float(np.mean(p_rel[k] == te["location"][touch][k]))})
    out["over_time"] = rows
    out["force_train_r2_total"] = float(np.mean([c.r2 for c in fm.curves_.values()]))
    return out


def format_report(res: dict) -> str:
    L, D, F = res["localization"], res["detection"], res["force"]
    lines = [
        f"dataset {res['dataset']}: train {','.join(res['train_sessions'])} ({res['n_train']} chirps), "
        f"test {len(res['test_sessions'])} sessions ({res['n_test']} chirps)",
        f"  localization  accuracy {L['accuracy']:.1%}   < 2 cm {L['within_2cm']:.1%}   < 3 cm {L['within_3cm']:.1%}   "
        f"mean error {L['mean_error_cm']:.2f} cm   ({L['n']} touch chirps)",
        f"  detection     false touches {D['false_touch_rate']:.1%}   missed touches {D['missed_touch_rate']:.1%}   "
        f"(threshold {D['threshold']:.3f})",
        f"  force (E^O)   RMSE {F['rmse_n']:.2f} N   sigma {F['sigma_n']:.2f} N   xcorr {F['xcorr']:.1%}",
    ]
    if "ablations" in res:
        A = res["ablations"]
        T = A["force_total_energy"]
        lines += [
            "  paper findings on this data:",
            f"    OSPA (Fig. 6b)             all band bins {A['accuracy_all_bins']:.1%} -> OSPA {A['accuracy_ospa']:.1%}",
            f"    online updating (Alg. 2)   without {A['accuracy_without_online_calibration']:.1%} -> with {A['accuracy_ospa']:.1%}",
            f"    force feature (Fig. 9)     total energy E: RMSE {T['rmse_n']:.2f} N, train R2 {A['force_train_r2_total']:.2f}"
            f" -> E^O: RMSE {F['rmse_n']:.2f} N, train R2 {A['force_train_r2_ospa']:.2f}",
            f"    Alg. 2 on the features     {A['accuracy_ospa']:.1%} -> {A['accuracy_feature_calibration']:.1%} "
            f"(inputs minus the running no-touch reference)",
        ]
        if len(A["over_time"]) >= 3:
            lines.append("  accuracy over time (Fig. 12):  min since power-on, temperature, paper's SVM, with Alg. 2 on features")
            lines += [f"    {r['session']}  {r['minutes']:6.1f} min  {r['temperature_c']:5.2f} C  {r['accuracy']:6.1%}  "
                      f"{r['accuracy_feature_calibration']:6.1%}" for r in A["over_time"]]
    return "\n".join(lines)


def save_report(res: dict, out_dir: str | Path, layout) -> list[Path]:
    """Write ``report.json`` and PNG plots (confusion matrix, error CDF)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from .metrics import error_cdf

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    (out / "report.json").write_text(json.dumps(res, indent=2, default=float))
    paths = [out / "report.json"]
    fig, ax = plt.subplots(1, 2, figsize=(11, 4.5))
    cm = np.asarray(res["localization"]["confusion"], float)
    cm = cm / np.maximum(cm.sum(axis=1, keepdims=True), 1)
    im = ax[0].imshow(cm, cmap="viridis", vmin=0, vmax=1)
    ax[0].set(xlabel="predicted location", ylabel="true location",
              title=f"confusion (accuracy {res['localization']['accuracy']:.1%})")
    fig.colorbar(im, ax=ax[0], fraction=0.046)
    e, c = error_cdf(np.asarray(res["errors_cm"]))
    ax[1].step(e, c, where="post")
    ax[1].axvline(2, color="gray", ls="--"); ax[1].axvline(3, color="gray", ls=":")
    ax[1].set(xlabel="localization error (cm)", ylabel="CDF", xlim=(-0.1, max(5, float(e.max()) if e.size else 5)),
              ylim=(0, 1.01), title=f"< 2 cm: {res['localization']['within_2cm']:.1%}")
    ax[1].grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(out / "localization.png", dpi=110)
    plt.close(fig)
    paths.append(out / "localization.png")
    return paths
