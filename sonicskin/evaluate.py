"""Evaluate the paper's reference system on a dataset (Table I), with the paper's ablations on the same split: OSPA vs
every band bin (Fig. 6b), Alg. 2 vs the training reference only (Fig. 12), force from ``E^O`` vs the band (Fig. 9)."""

from __future__ import annotations

import dataclasses
import json
import tempfile
import time
from pathlib import Path

import numpy as np

from .calibration import OnlineReference
from .compare import chirps_per_location, counts_line, coverage_note, replay_sessions, split_line, stream_metrics
from .dataset import Dataset, FeatureTable, Split, write_file
from .features import MIN_REST_CHIRPS, FeatureSpec, light_touches, quiet_mask, rest_beta, touch_mask, usable_bins
from .fit import fit_artifact, prepare
from .force import PerLocationForce, energy_db
from .jsonio import json_safe
from .kinds import BASELINE
from .metrics import force_report
from .plots import cdf_panel, confusion_panel, detection_panel, location_names, pyplot
from .rig import Rig
from .runtime import SkinRuntime

__all__ = ["split_sessions", "evaluate_svm"]


def split_sessions(table: FeatureTable, train_sessions: list[str]) -> tuple[FeatureTable, FeatureTable]:
    s = table["session"]
    unknown = set(train_sessions) - set(s)
    if unknown:
        raise ValueError(f"training sessions {sorted(unknown)} are not in the dataset ({', '.join(sorted(set(s.tolist())))})")
    tr = np.isin(s, train_sessions)
    if tr.all():
        raise ValueError("every session is a training session; leave at least one to test on")
    return table.select(tr), table.select(~tr)


NOT_MEASURABLE = "not measurable on this data"
#: the paper's SVM: its own C, kernel width and per-location Fourier-1 (no selection), its own touch rule
PAPER_SVM = {BASELINE: {"select": False, "detector": "paper"}}


def _force_absent(tr: FeatureTable, touch_tr: np.ndarray) -> str | None:
    """Why force cannot be trained or reported on this data, or ``None`` when it can."""
    f = tr["force_n"][touch_tr]
    if not np.isfinite(f).any():
        return "absent: no force sensor (force_n is empty/NaN)"
    if np.ptp(f[np.isfinite(f)]) == 0:
        return f"absent: force_n is constant ({f[np.isfinite(f)][0]:g} N), as without a force sensor"
    return None


def evaluate_svm(ds: Dataset, *, train_sessions: list[str] | None = None, table: FeatureTable | None = None,
                 ablations: bool = True, min_force_n: float = 0.5, n_bins: int | None = None, mode: str = "relative",
                 val_sessions=(), artifact: str | Path | None = None, alpha_s: float = FeatureSpec.alpha_s,
                 beta_s: float = FeatureSpec.beta_s, log=print) -> dict:
    """The paper's system trained on ``train_sessions`` (default: the first), tested on the rest, as deployed: fitted by
    :mod:`sonicskin.fit`, exported, and every test session replayed through the artifact.  Without hands-off chirps
    detection and Alg. 2 are reported as not measurable, without a force sensor force as absent."""
    if mode not in ("relative", "absolute"):
        raise ValueError(f"mode must be relative or absolute, got {mode!r}")
    table = table if table is not None else ds.features()
    sessions = sorted(set(table["session"]))
    train_sessions = train_sessions or sessions[:1]
    tr, te = split_sessions(table, train_sessions)
    trained = set(np.unique(tr["location"][touch_mask(tr, min_force_n)]).tolist())
    never = [str(i) for i in ds.layout.ids if int(i) not in trained]
    if never:  # the SVM has no class for them: every test touch there would be an error the accuracy alone hides
        raise ValueError(f"training session(s) {', '.join(train_sessions)} touch {len(ds.layout) - len(never)} of the "
                         f"layout's {len(ds.layout)} locations (never trained: {', '.join(never[:12])}"
                         f"{', ...' if len(never) > 12 else ''}); the SVM needs a press at every location: train on "
                         f"sessions that touch every location (--train)" +
                         (f"; {why}" if (why := light_touches(tr["force_n"], tr["location"] >= 0, min_force_n)) else ""))
    gamma = usable_bins(ds.rig, n_bins, log=lambda m: log(f"note: {m}"))
    cal = OnlineReference.from_seconds(beta_s=beta_s, alpha_s=alpha_s, chirps_per_s=ds.rig.chirps_per_s)
    beta = rest_beta(table, cal.beta, log=lambda m: log(f"note: {m}"))
    rest = beta is not None  # every stream has a no-touch reference: detection and Alg. 2 are measurable
    if not rest:
        log(f"note: not every session has {MIN_REST_CHIRPS} consecutive hands-off chirps (touches only?): localization "
            f"and force only, on absolute features; detection and Alg. 2 are {NOT_MEASURABLE}")
    test_sessions = sorted(set(te["session"]))
    split = Split(tuple(str(s) for s in train_sessions), (), tuple(str(s) for s in test_sessions))
    quiet = lambda m: None  # noqa: E731

    def paper_data(**kw):
        d = prepare(ds, table=table, split=split, mode="absolute", min_force_n=min_force_n, alpha_s=alpha_s, beta_s=beta_s, log=quiet, **kw)
        if rest and beta < cal.beta:  # Alg. 2's reference averages the rest every stream has
            d.spec = dataclasses.replace(d.spec, beta_s=beta / ds.rig.chirps_per_s)
        if not rest:  # no hands-off chirps in some stream: no detector, no Alg. 2 reference
            d.usable = d.usable & (d.cls < d.n_locations)
        return d

    with tempfile.TemporaryDirectory(prefix="sonicskin-evaluate-") as tmp:
        data = paper_data(n_bins=gamma)
        paper = Path(artifact) if artifact is not None else Path(tmp) / "paper"
        skin = fit_artifact(data, paper, options=PAPER_SVM, log=quiet)
        rt = SkinRuntime(paper, BASELINE)
        # Alg. 2 from the model's own detection (boot: each stream's first beta chirps); no test labels.
        p = (replay_sessions(rt, te, test_sessions) if rest and mode == "relative" else rt.predict_inputs(rt.inputs(te.X)))
        if p.calibrating is None:
            p.calibrating = np.zeros(len(te), bool)
        offline = rt.predict_inputs(rt.inputs(te.X))  # the training session's reference throughout
        m = stream_metrics(p, te, ds.layout, min_force_n=min_force_n, detection=rest)
        svm = skin["models"][BASELINE]
        res: dict = {"dataset": str(ds.root), "train_sessions": list(train_sessions), "test_sessions": test_sessions,
                     "n_train": len(tr), "n_test": len(te), "train_time_s": skin["training"][f"{BASELINE}_train_time_s"],
                     "n_bins": len(data.spec.bins), "beta_chirps": beta}
        touch = touch_mask(te, min_force_n)
        res["localization"] = m["localization"]
        res["errors_cm"] = m["errors_cm"]
        res["val_sessions"] = list(val_sessions)
        res["chirps_per_location"] = chirps_per_location(te, touch, ds.layout)
        res["coverage_note"] = coverage_note(res["chirps_per_location"])
        res["detection"] = ({**m["detection"], "threshold": svm["threshold"],
                             "train_false_touch_rate": svm["train_false_touch_rate"],
                             "train_missed_touch_rate": svm["train_missed_touch_rate"]}
                            if rest and m["detection"].get("measurable", True)
                            else {"measurable": False, "reason": f"{NOT_MEASURABLE}: no hands-off chirps"})
        absent = _force_absent(tr, touch_mask(tr, min_force_n)) or _force_absent(te, touch)
        res["force"] = {"measurable": False, "reason": absent} if absent else m["force"]
        if ablations:
            res["ablations"] = _ablations(ds, tr, te, p, offline, touch, svm, data, paper_data, Path(tmp), beta, rest=rest,
                                          force=absent is None, alg2={"alpha_s": alpha_s, "beta_s": beta_s})
    return res


def _ablations(ds, tr, te, p, offline, touch, svm: dict, data, paper_data, tmp: Path, beta, *, rest: bool = True,
               force: bool = True, alg2: dict) -> dict:
    """The paper's findings on the same split, each an artifact replayed as deployed."""
    out = {}
    quiet = lambda m: None  # noqa: E731
    loc = te["location"]
    scored = touch & ~p.calibrating
    # OSPA vs every bin of the chirp band (no selection, no matched filter: a rig without PWM notches).
    t0 = time.perf_counter()
    every = paper_data(bins=np.arange(ds.rig.n_band), rig=Rig.from_dict({**ds.rig.to_dict(), "pwm_hz": []}))
    fit_artifact(every, tmp / "all-bins", options=PAPER_SVM, log=quiet)
    rt_all = SkinRuntime(tmp / "all-bins", BASELINE)
    out["accuracy_all_bins"] = float(np.mean(rt_all.predict_inputs(rt_all.inputs(te.X[touch])).location == loc[touch]))
    out["accuracy_ospa"] = float(np.mean(p.location[scored] == loc[scored]))
    out["all_bins_train_time_s"] = time.perf_counter() - t0
    if not rest:  # no rest in the streams: Alg. 2 has nothing to calibrate on
        out["alg2"] = {"measurable": False, "reason": f"{NOT_MEASURABLE}: no hands-off chirps"}
    else:
        out["accuracy_without_online_calibration"] = float(np.mean(offline.location[touch] == loc[touch]))
    if force and rest:
        # Force from total band energy E vs E^O over the OSPA bins (per-location Fourier-1 at the true location).
        all_bins = np.arange(ds.rig.n_band)
        ref_tr = tr.X[quiet_mask(tr)].mean(axis=0)
        tr_touch = touch_mask(tr, data.min_force_n)
        has_f = tr_touch & np.isfinite(tr["force_n"])
        E_tr = energy_db(tr.X[has_f], all_bins, ref_tr)
        fm = PerLocationForce("fourier1").fit(E_tr, tr["force_n"][has_f], tr["location"][has_f])
        # Test reference: each stream's boot calibration (its first beta chirps), not its labelled rest.
        E_te = np.concatenate([energy_db(te.X[(te["session"] == s)], all_bins, te.X[(te["session"] == s)][:beta])
                               for s in sorted(set(te["session"]))])
        f_total = np.clip(fm.predict(E_te[touch], loc[touch]), 0, None)
        out["force_total_energy"] = force_report(te["force_n"][touch], f_total)
        out["force_train_r2_ospa"] = float(np.mean([c["r2"] for c in svm["force"]["curves"].values()]))
        out["force_train_r2_total"] = float(np.mean([c.r2 for c in fm.curves_.values()]))
    p_rel = None
    if rest:
        # Alg. 2 applied to the features: the same bins minus the stream's running no-touch reference (the training
        # session's from its labelled rest, the test streams' from the SVM's own detection).
        d = prepare(data.dataset, table=data.table, split=data.split, bins=data.spec.bins, mode="relative",
                    min_force_n=data.min_force_n, log=quiet, **alg2)
        fit_artifact(d, tmp / "relative", options=PAPER_SVM, log=quiet)
        pr = replay_sessions(SkinRuntime(tmp / "relative", BASELINE), te, sorted(set(te["session"])))
        p_rel = pr.location
        ok = touch & ~pr.calibrating
        out["accuracy_feature_calibration"] = float(np.mean(p_rel[ok] == loc[ok]))
    rows = []
    for s in sorted(set(te["session"])):
        sel = (te["session"] == s) & scored
        if not sel.any():  # a hands-off session: nothing to score over time
            continue
        rows.append({"session": s, "minutes": float(te["time_s"][sel].mean() / 60),
                     "temperature_c": float(te["temperature_c"][sel].mean()),
                     "accuracy": float(np.mean(p.location[sel] == loc[sel])),
                     "accuracy_feature_calibration": float(np.mean(p_rel[sel] == loc[sel])) if p_rel is not None else None})
    out["over_time"] = rows
    return out


def _force_line(F: dict, label: str = "force (E^O)") -> str:
    if F.get("measurable") is False:
        return f"  {label:13s} {F['reason']}"
    part = f" (on the {F['n']} of {F['n'] + F['n_unmeasured']} chirps with a force)" if F.get("n_unmeasured") else ""
    return f"  {label:13s} RMSE {F['rmse_n']:.2f} N   sigma {F['sigma_n']:.2f} N   xcorr {F['xcorr']:.1%}{part}"


def format_report(res: dict) -> str:
    L, D, F = res["localization"], res["detection"], res["force"]
    det = (f"  detection     {D['reason']}" if D.get("measurable") is False else
           f"  detection     false touches {D['false_touch_rate']:.1%}   missed touches {D['missed_touch_rate']:.1%}   "
           f"(threshold {D['threshold']:.3f})")
    lines = [
        f"dataset {res['dataset']}: train {','.join(res['train_sessions'])} ({res['n_train']} chirps), "
        f"test {len(res['test_sessions'])} sessions ({res['n_test']} chirps)",
        f"  sessions: {split_line({'train': res['train_sessions'], 'val': res.get('val_sessions', []), 'test': res['test_sessions']})}"
        + (" (validation held out: the SVM has no validation step)" if res.get("val_sessions") else ""),
        f"  {counts_line(res['chirps_per_location'])}" if "chirps_per_location" in res else "",
        f"  note: {res['coverage_note']}" if res.get("coverage_note") else "",
        f"  localization  accuracy {L['accuracy']:.1%}   < 2 cm {L['within_2cm']:.1%}   < 3 cm {L['within_3cm']:.1%}   "
        f"mean error {L['mean_error_cm']:.2f} cm   ({L['n']} touch chirps)",
        det,
        _force_line(F),
    ]
    lines = [ln for ln in lines if ln]
    if "ablations" in res:
        A = res["ablations"]
        lines += ["  paper findings on this data:",
                  f"    OSPA (Fig. 6b)             all band bins {A['accuracy_all_bins']:.1%} -> OSPA {A['accuracy_ospa']:.1%}"]
        if "alg2" in A:
            lines.append(f"    online updating (Alg. 2)   {A['alg2']['reason']}")
        else:
            lines.append(f"    online updating (Alg. 2)   without {A['accuracy_without_online_calibration']:.1%} -> "
                         f"with {A['accuracy_ospa']:.1%}")
        if "force_total_energy" in A:
            T = A["force_total_energy"]
            lines.append(f"    force feature (Fig. 9)     total energy E: RMSE {T['rmse_n']:.2f} N, train R2 "
                         f"{A['force_train_r2_total']:.2f} -> E^O: RMSE {F['rmse_n']:.2f} N, train R2 {A['force_train_r2_ospa']:.2f}")
        else:
            lines.append(f"    force feature (Fig. 9)     {NOT_MEASURABLE}")
        if "accuracy_feature_calibration" in A:
            lines.append(f"    Alg. 2 on the features     {A['accuracy_ospa']:.1%} -> {A['accuracy_feature_calibration']:.1%} "
                         f"(inputs minus the running no-touch reference)")
        if len(A["over_time"]) >= 3 and "accuracy_feature_calibration" in A:
            lines.append("  accuracy over time (Fig. 12):  min since power-on, temperature, paper's SVM, with Alg. 2 on features")
            lines += [f"    {r['session']}  {r['minutes']:6.1f} min  {r['temperature_c']:5.2f} C  {r['accuracy']:6.1%}  "
                      f"{r['accuracy_feature_calibration']:6.1%}" for r in A["over_time"]]
    return "\n".join(lines)


def save_report(res: dict, out_dir: str | Path, layout) -> list[Path]:
    """Write ``report.json`` and PNG plots (confusion matrix, error CDF)."""
    plt = pyplot()
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    write_file(out / "report.json", json.dumps(json_safe(res), indent=2, allow_nan=False))  # strict JSON: NaN as null
    paths = [out / "report.json"]
    fig, ax = plt.subplots(1, 3, figsize=(17, 5), width_ratios=[1.1, 1, 0.8])
    confusion_panel(fig, ax[0], res["localization"]["confusion"], location_names(res.get("dataset"), layout),
                    f"SVM: accuracy {res['localization']['accuracy']:.1%}")
    cdf_panel(ax[1], {"SVM": np.asarray(res["errors_cm"])}, f"error CDF: < 2 cm {res['localization']['within_2cm']:.1%}")
    detection_panel(ax[2], {"SVM": res.get("detection")})
    fig.tight_layout()
    fig.savefig(out / "localization.png", dpi=110)
    plt.close(fig)
    paths.append(out / "localization.png")
    return paths
