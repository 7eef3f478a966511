"""The network's configuration when nothing can validate, measured across the random rig family (issue 36).

    nice -n 5 .venv/bin/python benchmarks/bench_default.py                 # design seeds 0-29, both input modes
    nice -n 5 .venv/bin/python benchmarks/bench_default.py --no-net        # the closed forms only (a minute)

With one session and one press per marker there is nothing to validate on: the package takes the configuration that
is best and most robust across rigs it was not tuned on.  Here every design rig of the ``random`` family
(``configs/scenarios/random.yaml``: material, tube or plate, size, transducers, loss, irregularity, markers, people,
motion, warm-up) trains on session s000 alone and is scored on every touch chirp of s002 and s003 (inputs relative to
each session's labelled no-touch reference, or absolute as a table of touches only gives them), for:

- the LDA kind's candidate views (:func:`sonicskin.kinds.lda.lda_candidates`: 1000 bins or every bin, each chirp as
  measured, its level removed or at unit length) alone, and their ensemble (the scores summed: the package's LDA);
- the LDA view that folds inside the one session choose (each press's early chirps against its late ones, both
  ways; issue 36 asks whether they rank the candidates as held-out presses do);
- the package's SVM (C 10, ``gamma="scale"``, OSPA's 300 bins);
- the network's MLP layers trained on augmented presses (``--no-net`` leaves them out);

and the force RMSE (N, at the true marker, touch chirps with a force reading) of the candidates for the force model
without validation: the network's own force head (the network as the package fits it, :func:`sonicskin.fit.fit_models`),
the paper's per-location Fourier-1 of the energy over the SVM's bins, a pooled ridge over the first 300 inputs
(alpha 10, 100, 1000) and the pooled SVR floor.

A second table per mode: s001 validates and the deployed model is refitted on s000 + s001 (the LDA's views, their
ensemble, the view validation chooses, the ensemble or a view as validation chooses, the package SVM).

Printed: mean, worst and 10th percentile over rigs per candidate and mode, and the paired difference of each against
the default (the ensemble, :data:`sonicskin.kinds.lda.ENSEMBLE`) with a 95 % t interval over rigs.  The held-out seeds are refused.
"""

from __future__ import annotations

import argparse
import os
import warnings
from pathlib import Path

for _v in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import numpy as np  # noqa: E402
from tqdm import tqdm  # noqa: E402

from sonicskin.dataset import Split  # noqa: E402
from sonicskin.fit import prepare  # noqa: E402
from sonicskin.kinds.lda import ENSEMBLE, LDAViews, candidate_name, lda_candidates  # noqa: E402
from sonicskin.kinds.svm import fit_pipeline  # noqa: E402
from sonicskin.metrics import t_interval  # noqa: E402
from sonicskin.rig import Rig  # noqa: E402
from sonicskin.seeds import scenario_dataset  # noqa: E402
from sonicskin.selection import press_ids  # noqa: E402
from sonicskin.sim.scenario import family_seeds  # noqa: E402


def one_rig(ds, mode: str, net: bool) -> dict:
    d = prepare(ds, split=Split(("s000",), (), ("s002", "s003")), n_bins=300, wide=True, mode=mode, progress=False,
                log=lambda *_: None)
    n = d.n_locations
    tr, te = d.rows("train") & (d.cls < n), d.rows("test") & (d.cls < n)
    out, inside = {}, {}
    early = early_chirps(d, tr)
    halves = [(tr & early, tr & ~early), (tr & ~early, tr & early)]
    for name, vs in _configurations(d.X.shape[1]).items():
        out[f"LDA, {name}"] = _acc(d, vs, tr, te)
        inside[f"LDA, {name}"] = np.mean([_acc(d, vs, a, b) for a, b in halves])
    svm = fit_pipeline(d.X[tr][:, :300], d.cls[tr], n)
    out["package SVM (300 bins)"] = float(np.mean(svm.predict(d.X[te][:, :300]) == d.cls[te]))
    if net:
        import torch
        from sklearn.pipeline import make_pipeline
        from sklearn.preprocessing import StandardScaler
        from sklearn.svm import SVR
        from sonicskin.training.augment import make_augmenter
        from sonicskin.training.quick import DEFAULTS as NET
        from sonicskin.training.quick import fit_net, layer_hparams

        from sonicskin.fit import fit_models
        from sonicskin.force import PerLocationForce, PooledForce, energy_db

        rows = d.rows("train")
        for layer in ("MLP, every bin", "MLP, 1000 bins"):
            hp = {**NET, **layer_hparams(layer, n_in=d.X.shape[1])}
            pred = fit_net(d.X[rows], d.cls[rows], d.force[rows], n_locations=n, augmenter=make_augmenter(d, rows), **hp)
            out[f"network, {layer}"] = float(np.mean(pred(d.X[te])[0][:, :n].argmax(1) == d.cls[te]))
        _, fits = fit_models(d, ["net"], refit=False, log=lambda *_: None)
        fr, f_te = rows & (d.cls < n) & np.isfinite(d.force), te & np.isfinite(d.force)
        if f_te.any() and fr.sum() >= 8:
            ids, F, k = np.asarray(d.layout.ids), d.force[f_te].astype(np.float64), fits["svm"].n_in
            netm = fits["net"].model
            with torch.no_grad():
                head = netm(torch.from_numpy(np.ascontiguousarray(d.X[f_te][:, :netm.n_in], np.float32)))[1].numpy()
            e_ref = fits["svm"].entry["energy_ref_db"]
            cand = {"force: the network's own head": head[np.arange(len(F)), d.cls[f_te]],
                    "force: per-location Fourier-1 (paper)": PerLocationForce("fourier1").fit(
                        energy_db(d.X[fr][:, :k], np.arange(k)) - e_ref, d.force[fr], ids[d.cls[fr]]).predict(
                        energy_db(d.X[f_te][:, :k], np.arange(k)) - e_ref, ids[d.cls[f_te]])}
            for alpha in (10.0, 100.0, 1000.0):
                cand[f"force: pooled ridge 300, alpha {alpha:g}"] = PooledForce(alpha).fit(
                    d.X[fr][:, :300], d.force[fr], ids[d.cls[fr]]).predict(None, ids[d.cls[f_te]], inputs=d.X[f_te][:, :300])
            cand["force: pooled SVR floor (every bin)"] = make_pipeline(StandardScaler(), SVR()).fit(
                d.X[fr], d.force[fr]).predict(d.X[f_te])
            for name, p in cand.items():
                out[name] = float(np.sqrt(np.mean((np.clip(np.nan_to_num(p), 0, None) - F) ** 2)))
    default = f"LDA, {ENSEMBLE}"
    out["default"] = out[default]
    # issue 36: folds inside the one session (each press's early chirps against its late ones), ties to the default
    out["LDA chosen by early vs late chirps of each press"] = out[max(inside, key=lambda c: (round(100 * inside[c]), c == default))]
    return out


def _configurations(n_in: int) -> dict:
    """The LDA's candidate views alone, their ensemble, and the ensemble of the every-bin views."""
    views = lda_candidates(n_in)
    return {ENSEMBLE: views, "every-bin views (ensemble)": [v for v in views if v[0] >= n_in],
            **{candidate_name(k, n_in, nm): [(k, nm)] for k, nm in views}}


def _acc(d, views, fit_rows, test_rows) -> float:
    return float(np.mean(LDAViews(views).fit(d.X[fit_rows], d.cls[fit_rows]).predict(d.X[test_rows]) == d.cls[test_rows]))


def refit_rig(ds, mode: str) -> dict:
    """s001 validates, the deployed model is refitted on s000 + s001: the ensemble, the view validation chooses, the
    ensemble or a view as validation chooses, each view, and the package SVM on OSPA's 300 bins."""
    d = prepare(ds, split=Split(("s000",), ("s001",), ("s002", "s003")), n_bins=300, wide=True, mode=mode, progress=False,
                log=lambda *_: None)
    n = d.n_locations
    tr, va, te = (d.rows(k) & (d.cls < n) for k in ("train", "val", "test"))
    confs = _configurations(d.X.shape[1])
    out = {f"LDA, {name}": _acc(d, vs, tr | va, te) for name, vs in confs.items()}
    val = {name: round(100 * _acc(d, vs, tr, va)) for name, vs in confs.items()}
    single = [c for c in confs if "ensemble" not in c]
    out["LDA, the view s001 chooses"] = out[f"LDA, {max(single, key=lambda c: val[c])}"]
    out["LDA, the ensemble or a view as s001 chooses"] = out[f"LDA, {max(confs, key=lambda c: (val[c], c == ENSEMBLE))}"]
    svm = fit_pipeline(d.X[tr | va][:, :300], d.cls[tr | va], n)
    out["package SVM (300 bins)"] = float(np.mean(svm.predict(d.X[te][:, :300]) == d.cls[te]))
    out["default"] = out[f"LDA, {ENSEMBLE}"]
    return out


def early_chirps(d, rows: np.ndarray) -> np.ndarray:
    """The first half (in time) of the chirps of each press among ``rows``."""
    t = d.table
    pid = np.where(rows, press_ids(t["location"], t["session"], t["segment"] if "segment" in t.labels else None), -1)
    early = np.zeros(len(pid), bool)
    for p in np.unique(pid[pid >= 0]):
        idx = np.flatnonzero(pid == p)
        early[idx[: len(idx) // 2]] = True
    return early


def _table(rows: list[dict], title: str) -> None:
    names = sorted((k for k in rows[0] if not k.startswith("force")), key=lambda k: -np.mean([r[k] for r in rows]))
    print(title)
    print("| candidate | mean | worst | 10th percentile | minus the default, 95 % CI |\n|---|---|---|---|---|")
    for k in names:
        v = np.array([r[k] for r in rows])
        d = v - np.array([r["default"] for r in rows])
        lo, hi = t_interval(d) if np.any(d) else (0.0, 0.0)
        print(f"| {k} | {v.mean():.1%} | {v.min():.1%} | {np.percentile(v, 10):.1%} | "
              f"{d.mean() * 100:+.1f} [{lo * 100:+.1f}, {hi * 100:+.1f}] |")


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--seeds", type=int, nargs="+", help="random family seeds (default: the design seeds)")
    p.add_argument("--cache", default="data/random", help="simulated datasets (default: data/random)")
    p.add_argument("--modes", nargs="+", default=["relative", "absolute"], choices=["relative", "absolute"])
    p.add_argument("--no-net", action="store_true", help="leave the network's MLP layers out")
    a = p.parse_args(argv)
    fam = family_seeds("random")
    seeds = a.seeds or list(fam["design"])
    if set(seeds) & set(fam["heldout"]):
        raise SystemExit("bench_default: error: held-out seeds are only ever evaluated (bench_random_rigs.py); choose "
                         "design seeds")
    rig = Rig.load("jaco")
    warnings.simplefilter("ignore")
    for mode in a.modes:
        dss = [scenario_dataset("random", s, Path(a.cache), rig=rig, log=lambda *_: None) for s in tqdm(seeds, desc="simulate")]
        rows = [one_rig(ds, mode, not a.no_net) for ds in tqdm(dss, desc=f"{mode}, one session")]
        refit = [refit_rig(ds, mode) for ds in tqdm(dss, desc=f"{mode}, s001 validates")]
        for what, rr in ((f"{mode} inputs, train s000 alone", rows), (f"{mode} inputs, s001 validates, refit on s000 + s001", refit)):
            _table(rr, f"\n{what}, test s002 s003, {len(rr)} design rigs of the random family (seeds {seeds[0]}-{seeds[-1]}); "
                       f"the default: LDA, {ENSEMBLE}\n")
        forces = [k for k in rows[0] if k.startswith("force")]
        if forces:
            print("\n| force model (RMSE, N) | mean | worst | minus the network's own head, 95 % CI |\n|---|---|---|---|")
            for k in forces:
                v = np.array([r.get(k, np.nan) for r in rows])
                d = v - np.array([r.get("force: the network's own head", np.nan) for r in rows])
                ok = np.isfinite(d)
                lo, hi = t_interval(d[ok]) if np.any(d[ok]) else (0.0, 0.0)
                print(f"| {k[7:]} | {np.nanmean(v):.2f} | {np.nanmax(v):.2f} | {np.nanmean(d):+.2f} [{lo:+.2f}, {hi:+.2f}] |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
