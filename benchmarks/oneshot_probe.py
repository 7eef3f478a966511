"""One press per marker: the package's SVM, the plain floors, nuisance-aware candidates and networks (issue 26).

    nice -n 10 .venv/bin/python benchmarks/oneshot_probe.py                      # design seeds 0-9 of `random`
    nice -n 10 .venv/bin/python benchmarks/oneshot_probe.py --seeds design 100-139 --net
    nice -n 10 .venv/bin/python benchmarks/oneshot_probe.py --scenario moving --seeds 0 1 2 --net
    nice -n 10 .venv/bin/python benchmarks/oneshot_probe.py --merge --net         # add the networks to earlier rows

Per rig (a simulated dataset, cached under ``--cache``): the features of every usable bin, relative to each
session's boot reference (the mean of its first ``beta`` chirps, Alg. 2's hands-off calibration, the same
reference the live loop boots on; no label is read to form it).  Every model is trained on the touch chirps of
the training session (s000), scored on the validation session (s001) and on every touch chirp of the test
sessions (s002, s003; given the touch decision, as the benchmarks' floors are):

- ``package SVM``: the package's own path (gamma, C and kernel width validated on s001 by
  :func:`sonicskin.selection.select_gamma_on_table`; OSPA bins on s000; scaler + RBF SVC);
- the plain floors of issue 26 (``floor ...``): SVC on every usable bin (defaults), shrinkage LDA (1000 OSPA bins
  and every usable bin), Normalizer + scaler + SVC(C=10) on 300 OSPA bins and on every bin, LDA / SVC after
  per-chirp mean-level removal;
- the candidates of :mod:`sonicskin.nuisance` (normalized LDA, level / tilt removal, metric heads);
- with ``--net`` the networks, chirp by chirp on the test streams as the live loop sees them (the touch decision
  chosen on s001 by :func:`training.quick.choose_detector`, and the alternative ``either`` = head or the SVM's
  input-RMS detector; force: its head or a pooled ridge chosen on s001): the package's SVM-kernel network
  (``net: SVM kernel (frozen)``, the copy of the SVM) and the augmented networks of :mod:`training.augment`;
  ``svm head`` is the package SVM with its own detector and validated force model on the same streams.

Validation: every candidate (networks too) is also fitted on s001 and scored on s000 (``val_swap``); a *validated
pick* (``PICK_SETS``) takes per rig the candidate with the best mean of the two folds (ties: the first listed)
and reports its test accuracy: what the product would do.  The best candidate in hindsight is not a result.
Printed: mean +- std over rigs and paired differences against the package SVM with 95 % Student t intervals (the
unit is the rig).  Rows go to ``OUT/<scenario>/rows/<seed>.json``, the table to ``summary.md``.

The held-out seeds of issue 26 (7001-7032, 7101-7103; anything in 7000-7999) are refused: a development tool.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
import warnings
from pathlib import Path

for _v in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import numpy as np  # noqa: E402

SPLITS = {  # scenario -> (train, val, test) sessions; multi-person: leave-subjects-out (Split.make)
    "random": (["s000"], ["s001"], ["s002", "s003"]),
    "moving": (["s000"], ["s001"], ["s002"]),
    "stationary": (["s000"], ["s001"], ["s002"]),
    "plate-aluminium": (["s000"], ["s001"], ["s002"]),
    "two-points": (["s000"], ["s001"], ["s002"]),
    "multi-person": None,
}
MULTI_PERSON_TEST = [8, 9, 10, 11]
FORBIDDEN = (range(7000, 8000),)  # issue 26's held-out seeds live here: never simulated or scored by this probe


# -- data ------------------------------------------------------------------------------------------------------
def load_rig(path, split=None) -> dict:
    """Everything the models need of one dataset: relative inputs over every usable bin (boot reference per
    session), the OSPA order on the training sessions, labels and masks of train / val / test touch chirps."""
    from sonicskin.dataset import Dataset
    from sonicskin.features import FeatureSpec, Split, load_features_cached, select_bins, touch_mask
    from sonicskin.selection import press_ids

    ds = Dataset(path)
    t = load_features_cached(ds, progress=False)
    rig = ds.rig
    if split is None:
        sp = Split.make(t, test_subjects=MULTI_PERSON_TEST)
        split = (list(sp.train), list(sp.val), list(sp.test))
    train, val, test = split
    allowed = np.flatnonzero(rig.allowed_mask)
    beta = FeatureSpec((0,), "relative").reference(rig.chirps_per_s).beta
    A = t.X[:, allowed].astype(np.float64)
    R = np.empty_like(A)
    sess = t["session"]
    for s in np.unique(sess):
        idx = np.flatnonzero(sess == s)
        touched = t["location"][idx] >= 0
        lead = int(np.argmax(touched)) if touched.any() else idx.size
        if lead < beta:
            raise ValueError(f"{path} session {s}: {lead} leading hands-off chirps, fewer than beta = {beta}")
        R[idx] = A[idx] - A[idx[:beta]].mean(axis=0)  # the boot reference: the stream's first beta chirps, no label
    tr_t = t.select(np.isin(sess, train))
    order_band = select_bins(tr_t, rig, int(allowed.size))  # every usable bin, best (OSPA) first
    pos = np.full(rig.n_band, -1)
    pos[allowed] = np.arange(allowed.size)
    touch = touch_mask(t)
    no_touch_tr = (t["location"] < 0) & np.isin(sess, train)
    moving = no_touch_tr & (t["moving"] > 0)
    lay = ds.layout
    seg = t["segment"] if "segment" in t.labels else None
    return {"path": str(path), "table": t, "rig": rig, "layout": lay, "split": split, "allowed": allowed, "R": R,
            "order": pos[order_band], "y": t["location"], "force": t["force_n"], "session": sess,
            "press": press_ids(t["location"], sess, seg),
            "tr": touch & np.isin(sess, train), "va": touch & np.isin(sess, val), "te": touch & np.isin(sess, test),
            "rest": moving if moving.sum() >= 10 else no_touch_tr & ~np.isin(np.arange(len(sess)), _leading(sess, beta)),
            "rest_is_moving": bool(moving.sum() >= 10), "freqs_hz": rig.freqs_hz[rig.band_bins][allowed], "beta": beta}


def _leading(sess, beta) -> np.ndarray:
    """Row indices of each session's first ``beta`` chirps (the boot reference, zero by construction)."""
    out = []
    for s in np.unique(sess):
        out.extend(np.flatnonzero(sess == s)[:beta])
    return np.asarray(out, int)


# -- models ----------------------------------------------------------------------------------------------------
def package_svm(d: dict, params: dict | None = None) -> dict:
    """The package's SVM as ``compare`` trains it: gamma, C, width validated on the validation session
    (``params``: that choice, made before on the same rig)."""
    from sklearn.pipeline import make_pipeline
    from sklearn.preprocessing import StandardScaler
    from sklearn.svm import SVC

    from sonicskin.features import select_bins
    from sonicskin.selection import select_gamma_on_table

    t, rig = d["table"], d["rig"]
    train, val, _ = d["split"]
    if params is None:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            params = select_gamma_on_table(t, rig, train_sessions=train, val_sessions=val, log=lambda m: None)["params"]
    p = params
    bins = select_bins(t.select(np.isin(t["session"], train)), rig, p["n_bins"])
    pos = np.full(rig.n_band, -1)
    pos[d["allowed"]] = np.arange(d["allowed"].size)
    cols = pos[bins]
    model = make_pipeline(StandardScaler(), SVC(C=p["C"], gamma=p["kernel_width"] / len(cols)))
    return {"model": model, "cols": cols, "params": p}


def directions(d: dict, cols: np.ndarray, **kw) -> np.ndarray:
    """Nuisance rows (:func:`sonicskin.nuisance.nuisance_directions`) measured on every usable bin of the
    training session, then restricted to ``cols`` (stacked over kinds)."""
    from sonicskin.nuisance import nuisance_directions

    key = tuple(sorted(kw.items()))
    cache = d.setdefault("_dirs", {})
    if key not in cache:
        R, y, tr = d["R"], d["y"], d["tr"]
        lay = d["layout"]
        labels = np.unique(y[tr])
        cache[key] = nuisance_directions(R[tr], y[tr], X_rest=R[d["rest"]], freqs_hz=d["freqs_hz"],
                                         positions_cm=lay.coords(labels), circumference_cm=lay.circumference_cm, **kw)
    return np.vstack([v[:, cols] for v in cache[key].values()])


def candidates(d: dict, names=None) -> dict:
    """name -> (unfitted estimator, input columns).  Floors first, then the nuisance-aware candidates."""
    from sklearn.pipeline import make_pipeline
    from sklearn.preprocessing import Normalizer, StandardScaler
    from sklearn.svm import SVC

    from sonicskin.nuisance import LevelRemoval, ShrinkageLDA

    o = d["order"]
    n = o.size
    every = np.arange(n)
    g = {300: o[:min(300, n)], 1000: o[:min(1000, n)], "all": every}
    f = d["freqs_hz"]

    def lvl(cols, tilt=False):
        return LevelRemoval(tilt=tilt, freqs_hz=f[cols] if tilt else None)

    c = {
        "floor SVC (all bins)": (make_pipeline(StandardScaler(), SVC()), every),
        "floor shrinkage LDA (OSPA 1000)": (ShrinkageLDA(), g[1000]),
        "floor shrinkage LDA (all bins)": (ShrinkageLDA(), every),
        "floor normalized SVC (OSPA 300)": (make_pipeline(Normalizer(), StandardScaler(), SVC(C=10)), g[300]),
        "floor normalized SVC (all bins)": (make_pipeline(Normalizer(), StandardScaler(), SVC(C=10)), every),
        "floor level-removed LDA (all bins)": (make_pipeline(lvl(every), ShrinkageLDA()), every),
        "floor level-removed SVC (all bins)": (make_pipeline(lvl(every), StandardScaler(), SVC(C=10)), every),
    }
    c["level+tilt LDA (all bins)"] = (make_pipeline(lvl(every, True), ShrinkageLDA()), every)
    c["normalized LDA (all bins)"] = (make_pipeline(Normalizer(), ShrinkageLDA()), every)
    c["normalized LDA (OSPA 3000)"] = (make_pipeline(Normalizer(), ShrinkageLDA()), o[:min(3000, n)])
    c["level-removed normalized LDA (all bins)"] = (make_pipeline(lvl(every), Normalizer(), ShrinkageLDA()), every)
    c["normalized SVC C=1 (all bins)"] = (make_pipeline(Normalizer(), StandardScaler(), SVC(C=1)), every)
    c["metric head: gain (all bins)"] = (ShrinkageLDA(nuisance=directions(d, every, kinds=("gain",))), every)
    c["metric head: gain+tilt (all bins)"] = (ShrinkageLDA(nuisance=directions(d, every, kinds=("gain", "tilt"))), every)
    c["metric head: all kinds (all bins)"] = (ShrinkageLDA(nuisance=directions(d, every)), every)
    if names:
        c = {k: v for k, v in c.items() if any(s in k for s in names)}
    return c


def score_rig(d: dict, *, names=None, net: bool = False, swap_val: bool = True, have: dict | None = None,
              log=print) -> dict:
    """Validation (s001) and test accuracy of the package SVM, every floor and candidate, on one rig.  ``have``: an
    earlier result of this rig; what it holds (with its swapped fold, when asked for) is kept, not computed again."""
    from sklearn.base import clone

    R, y = d["R"], d["y"]
    tr, va, te = d["tr"], d["va"], d["te"]
    out: dict = {k: v for k, v in (have or {}).items() if not k.startswith(("_", "pick"))
                 and (not swap_val or "val_swap" in v)}
    t0 = time.perf_counter()
    pk = package_svm(d, (have or {}).get("_meta", {}).get("svm_params")) if "package SVM" not in out or net else None
    cands = {"package SVM": (pk["model"], pk["cols"])} if pk is not None and "package SVM" not in out else {}
    cands.update({k: v for k, v in candidates(d, names).items() if k not in out})
    for name, (model, cols) in cands.items():
        t1 = time.perf_counter()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            swap = clone(model).fit(R[va][:, cols], y[va]) if swap_val else None
            model.fit(R[tr][:, cols], y[tr])
        out[name] = {"val": float(np.mean(model.predict(R[va][:, cols]) == y[va])),
                     "test": float(np.mean(model.predict(R[te][:, cols]) == y[te])), "fit_s": time.perf_counter() - t1}
        if swap is not None:  # the other fold of a two-session cross-validation: train on s001, score s000
            out[name]["val_swap"] = float(np.mean(swap.predict(R[tr][:, cols]) == y[tr]))
    if net:
        out.update(net_candidates(d, pk, swap_val=swap_val, log=log))
    out["_meta"] = {"svm_params": (pk or {}).get("params") or (have or {}).get("_meta", {}).get("svm_params"),
                    "n_markers": int(np.unique(y[tr]).size), "n_train": int(tr.sum()),
                    "n_test": int(te.sum()), "n_bins": int(R.shape[1]), "rest_is_moving": d["rest_is_moving"],
                    "seconds": time.perf_counter() - t0}
    return out


# -- the networks (torch; --net) ---------------------------------------------------------------------------------
def _detected(p_touch_logit: np.ndarray) -> np.ndarray:
    return p_touch_logit >= 0.0


def stream_rows(d: dict) -> dict:
    """Masks for chirp-by-chirp scoring as the live loop sees a test stream: every chirp after each session's boot
    calibration (the boot reference is the mean of those first beta chirps, so relative inputs are as replayed)."""
    from sonicskin.features import training_targets

    t, lay, sess = d["table"], d["layout"], d["session"]
    train_s, val_s, test_s = d["split"]
    boot = np.zeros(len(sess), bool)
    boot[_leading(sess, d["beta"])] = True
    cls, usable = training_targets(t, lay)
    TE = np.isin(sess, test_s) & ~boot
    return {"cls": cls, "TR": usable & np.isin(sess, train_s), "VA": usable & np.isin(sess, val_s), "TE": TE,
            "touch_te": TE & d["te"], "quiet_te": TE & (d["y"] < 0), "n": len(lay), "ids": np.asarray(lay.ids)}


def svm_head_metrics(d: dict, pk: dict, S: dict) -> dict:
    """The package SVM with its detector and validated force model, chirp by chirp on the test streams."""
    from sonicskin.svm_head import fit_svm_head, ovo_decision, score_vector, touch_statistic

    from sonicskin.features import quiet_mask
    from sonicskin.force import energy_db, force_from_dict
    from sonicskin.selection import select_on_inputs

    X = d["R"][:, pk["cols"]]
    t, n, ids, cls, TR, VA = d["table"], S["n"], S["ids"], S["cls"], S["TR"], S["VA"]
    p = pk["params"]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        sel = select_on_inputs(X, t, cls=cls, train_mask=TR, val_mask=VA, n_locations=n, location_ids=ids,
                               selection={"svm": {"params": p}}, log=lambda m: None)
    fs = sel.get("force") or {}
    S["force_alpha"] = fs.get("alpha") or 10.0
    pipe, prm = fit_svm_head(X[TR], cls[TR], d["force"][TR].astype(np.float32), quiet_mask(t)[TR], n_locations=n,
                             location_ids=ids, C=p["C"], kernel_gamma=p["kernel_width"] / X.shape[1],
                             force_model=fs.get("model", "fourier1"), force_alpha=fs.get("alpha") or 10.0)
    V = score_vector(ovo_decision(pipe, X), n, X)
    Vb = np.zeros_like(V)
    sess = d["session"]
    for s_ in np.unique(sess):  # each stream's boot reference of the score vector (Alg. 2's S_c)
        idx = np.flatnonzero(sess == s_)
        Vb[idx] = V[idx[:d["beta"]]].mean(axis=0)
    stat = touch_statistic(V - Vb, n, prm["detector_bins"])
    det = stat >= prm["threshold"]
    loc = ids[np.argmax(V[:, :n], axis=1)]
    fm = force_from_dict(prm["force"])
    E = energy_db(X, np.arange(X.shape[1])) - prm["energy_ref_db"]
    f = np.clip(fm.predict(E, loc, inputs=X), 0, None)
    return _stream_scores(d, S, loc, det, f, val_loc=loc)


def _stream_scores(d, S, loc, det, f, *, val_loc) -> dict:
    y, F = d["y"], d["force"]
    tt, qt = S["touch_te"], S["quiet_te"]
    fsel = tt & det & np.isfinite(F)
    va = d["va"]
    return {"val": float(np.mean(val_loc[va] == y[va])), "test": float(np.mean(loc[d["te"]] == y[d["te"]])),
            "missed": float(np.mean(~det[tt])), "false": float(np.mean(det[qt])),
            "force_rmse_n": float(np.sqrt(np.mean((f[fsel] - F[fsel]) ** 2))) if fsel.any() else float("nan")}


def net_metrics(d: dict, S: dict, predict, X: np.ndarray, *, threshold: float, force_alpha: float = 10.0,
                force_first: tuple = (None, 300)) -> dict:
    """A trained network (``predict``) on inputs ``X`` (every chirp): its touch decision chosen on the validation
    session as ``compare`` chooses it (:func:`training.quick.choose_detector`), then scored on the test streams."""
    from sonicskin.svm_head import DETECTOR_BINS
    from sonicskin.training.augment import choose_force
    from sonicskin.training.quick import choose_detector, touch_logit

    n, ids, cls, VA = S["n"], S["ids"], S["cls"], S["VA"]
    # its head or a pooled ridge (over every input or the first 300), chosen on validation as compare chooses
    fc = choose_force(predict.model, X, cls, d["force"], fit_rows=S["TR"], val_rows=VA, location_ids=ids,
                      alpha=force_alpha, first=force_first)
    logits, f_all = predict(X)
    ref = np.zeros(min(DETECTOR_BINS, X.shape[1]))
    dch = choose_detector(logits[VA], X[VA], (cls < n)[VA], (d["y"] < 0)[VA], threshold=threshold, reference=ref,
                          how="validation")
    cfg = dch["config"]
    tl = touch_logit(logits) + cfg["bias"]
    rms = np.sqrt(np.mean((X[:, :ref.size] - ref) ** 2, axis=1))
    det = {"head": tl >= 0, "input-rms": rms >= threshold, "either": (tl >= 0) | (rms >= threshold)}[cfg["mode"]]
    k = np.argmax(logits[:, :n], axis=1)
    f = np.clip(f_all[np.arange(len(k)), k], 0, None)
    out = _stream_scores(d, S, ids[k], det, f, val_loc=ids[k])
    out["detector"], out["force"] = dch["detector"], fc.get("force")
    # the alternative that cannot miss more than the SVM's detector: the head (recalibrated) or the input RMS
    either = (tl >= 0) | (rms >= threshold)
    out["missed_either"] = float(np.mean(~either[S["touch_te"]]))
    out["false_either"] = float(np.mean(either[S["quiet_te"]]))
    return out


def net_candidates(d: dict, pk: dict, *, epochs: int = 40, seed: int = 0, n_trunk: int = 300, layers=None,
                   swap_val: bool = True, log=print) -> dict:
    """The package's network (frozen SVM kernel, as ``compare`` trains it) and the augmented networks of
    :mod:`training.augment`, each with its validated touch decision; plus the package SVM's own detector and force.
    ``swap_val``: each network is also trained on the validation session and scored on the training session's
    touches (``val_swap``, the second fold of the validation, as for the sklearn candidates)."""
    from sklearn.preprocessing import normalize
    from sonicskin.svm_head import fit_svm_head
    from sonicskin.training.augment import Augmenter, fit_augmented_net, net_layers
    from sonicskin.training.quick import fit_net

    from sonicskin.features import quiet_mask
    from sonicskin.nuisance import ShrinkageLDA

    S = stream_rows(d)
    n, cls, TR, VA = S["n"], S["cls"], S["TR"], S["VA"]
    F = d["force"].astype(np.float32)
    y, sess = d["y"], d["session"]
    out = {"svm head": svm_head_metrics(d, pk, S)}
    Xs = d["R"][:, pk["cols"]]
    _, prm = fit_svm_head(Xs[TR], cls[TR], F[TR], quiet_mask(d["table"])[TR], n_locations=n, location_ids=S["ids"])
    thr = prm["threshold"]

    def swap_acc(pred, X):  # trained on the validation session: accuracy on the training session's touches
        lg, _ = pred(X[d["tr"]])
        return float(np.mean(lg[:, :n].argmax(1) == cls[d["tr"]]))

    t0 = time.perf_counter()
    pred = fit_net(Xs[TR], cls[TR], F[TR], n_locations=n, epochs=epochs, seed=seed, kernel=True, kernel_lr=0.0)
    out["net: SVM kernel (frozen)"] = {**net_metrics(d, S, pred, Xs, threshold=thr, force_alpha=S["force_alpha"]),
                                       "fit_s": time.perf_counter() - t0}
    if swap_val:
        out["net: SVM kernel (frozen)"]["val_swap"] = swap_acc(
            fit_net(Xs[VA], cls[VA], F[VA], n_locations=n, epochs=epochs, seed=seed, kernel=True, kernel_lr=0.0), Xs)
    Xa = d["R"][:, d["order"]]  # every usable bin, OSPA order: the trunk reads the first n_trunk
    lab = d["layout"].coords(np.unique(y[d["tr"]]))

    def session_fit(fit_rows: np.ndarray, touch: np.ndarray, rest: np.ndarray):
        """What a network needs of one session: its LDAs, its augmenter and the positions of its touches."""
        lda = ShrinkageLDA().fit(Xa[touch], y[touch])
        lda_unit = ShrinkageLDA().fit(normalize(Xa[touch]), y[touch])
        aug = Augmenter(d["R"][touch], y[touch], d["press"][touch], cols=d["order"], freqs_hz=d["freqs_hz"],
                        X_rest=d["R"][rest], positions_cm=lab, circumference_cm=d["layout"].circumference_cm)
        rows = np.flatnonzero(fit_rows)
        pos = np.full(len(fit_rows), -1)
        pos[rows] = np.arange(rows.size)
        return rows, lda, lda_unit, aug, pos[np.flatnonzero(touch)]

    fits = {"train": session_fit(TR, d["tr"], d["rest"])}
    if swap_val:
        val_rest = (y < 0) & np.isin(sess, d["split"][1]) & (d["table"]["moving"] > 0)
        if val_rest.sum() < 10:
            val_rest = (y < 0) & np.isin(sess, d["split"][1])
        fits["val"] = session_fit(VA, d["va"], val_rest)
    layers = dict(layers or net_layers())
    layers["MLP, the SVM's bins (augmented)"] = {"layer": "mlp", "n_inputs": len(pk["cols"])}  # its validated gamma
    for name, opts in layers.items():
        t0 = time.perf_counter()
        opts = dict(opts)
        k = opts.pop("n_inputs", None) or Xa.shape[1]
        preds = {}
        for part, (rows, lda, lda_unit, aug, touch_rows) in fits.items():
            preds[part] = fit_augmented_net(Xa[rows][:, :k], cls[rows], F[rows], n_locations=n,
                                            augmenter=aug.restricted(k) if k < Xa.shape[1] else aug, touch_rows=touch_rows,
                                            lda=lda_unit if opts.get("unit_norm") else lda, epochs=epochs, seed=seed,
                                            n_trunk=n_trunk, **opts)
        out[f"net: {name}"] = {**net_metrics(d, S, preds["train"], Xa[:, :k], threshold=thr, force_alpha=S["force_alpha"]),
                               "fit_s": time.perf_counter() - t0}
        if "val" in preds:
            out[f"net: {name}"]["val_swap"] = swap_acc(preds["val"], Xa[:, :k])
        log(f"  net: {name}: {out[f'net: {name}']}")
    return out


# -- validated picks -------------------------------------------------------------------------------------------
#: candidate lists validation chooses among (ties: the first listed).
PICK_SETS = {
    "pick: SVM or floors": ["package SVM", "floor shrinkage LDA (all bins)", "floor normalized SVC (all bins)",
                            "floor level-removed LDA (all bins)"],
    "pick: recommended set": ["normalized LDA (all bins)", "floor shrinkage LDA (all bins)",
                              "floor normalized SVC (all bins)", "package SVM"],
    "pick: wide set": ["normalized LDA (all bins)", "normalized LDA (OSPA 3000)", "level-removed normalized LDA (all bins)",
                       "metric head: all kinds (all bins)", "level+tilt LDA (all bins)", "floor level-removed LDA (all bins)",
                       "floor shrinkage LDA (all bins)", "floor normalized SVC (all bins)", "package SVM"],
    "pick: network": ["net: MLP, every bin (augmented)", "net: MLP, 1000 bins (augmented)", "net: metric (normalized LDA)",
                      "net: MLP, the SVM's bins (augmented)", "net: SVM kernel (frozen)"],
}


#: what the networks (and the SVM with its own detector, "svm head") report beside accuracy
EXTRA = ("missed", "false", "missed_either", "false_either", "force_rmse_n")


def val_score(r: dict, how: str = "swap") -> float:
    """What validation ranks by: accuracy on s001 (``"val"``), or its mean with the swapped fold (train on s001,
    score s000; ``"swap"``), which halves the ties at 100 % of one session."""
    if how == "swap" and "val_swap" in r:
        return 0.5 * (r["val"] + r["val_swap"])
    return r["val"]


def add_picks(res: dict, sets: dict | None = None, how: str = "swap") -> dict:
    for pname, names in (sets or PICK_SETS).items():
        have = [n for n in names if n in res]
        if not have:
            continue
        best = max(have, key=lambda n: (val_score(res[n], how), -have.index(n)))
        res[pname] = {**{k: v for k, v in res[best].items() if k in EXTRA}, "val": val_score(res[best], how),
                      "test": res[best]["test"], "chose": best}
    return res


# -- summaries ---------------------------------------------------------------------------------------------------
def t_interval(x: np.ndarray) -> tuple[float, float]:
    from scipy import stats

    x = np.asarray(x, float)
    if x.size < 2:
        return float("nan"), float("nan")
    half = stats.t.ppf(0.975, x.size - 1) * x.std(ddof=1) / np.sqrt(x.size)
    return float(x.mean() - half), float(x.mean() + half)


def summarize(rows: dict, ref: str = "package SVM") -> list[dict]:
    names = [k for k in next(iter(rows.values())) if not k.startswith("_")]
    out = []
    for n in names:
        have = [s for s in rows if n in rows[s]]
        te = np.array([rows[s][n]["test"] for s in have])
        va = np.array([rows[s][n]["val"] for s in have])
        dif = te - np.array([rows[s][ref]["test"] for s in have])
        lo, hi = t_interval(dif)
        chose = {}
        for s in have:
            c = rows[s][n].get("chose")
            if c:
                chose[c] = chose.get(c, 0) + 1
        extra = {k: float(np.nanmean([rows[s][n][k] for s in have])) for k in EXTRA if all(k in rows[s][n] for s in have)}
        out.append({"name": n, "n": len(have), "test_mean": float(te.mean()), "test_std": float(te.std(ddof=1)) if te.size > 1 else 0.0,
                    "val_mean": float(va.mean()), "diff_mean": float(dif.mean()), "diff_ci95": [lo, hi], "chose": chose, **extra})
    return out


def format_table(summary: list[dict], title: str) -> str:
    lines = [title, "", "| model | test accuracy (mean ± std) | s001 (validation) | − package SVM [95 % CI] | missed / false "
             "touches (validated detector; 'either') | force RMSE |", "|---|---|---|---|---|---|"]
    for r in summary:
        lo, hi = r["diff_ci95"]
        ch = ("; chose " + ", ".join(f"{k} {v}x" for k, v in sorted(r["chose"].items(), key=lambda kv: -kv[1]))) if r["chose"] else ""
        det = (f"{100 * r['missed']:.2f} / {100 * r['false']:.2f} %" if "missed" in r else "") + (
            f"; {100 * r['missed_either']:.2f} / {100 * r['false_either']:.2f} %" if "missed_either" in r else "")
        frc = f"{r['force_rmse_n']:.2f} N" if "force_rmse_n" in r else ""
        lines.append(f"| {r['name']}{ch} | {100 * r['test_mean']:.1f} ± {100 * r['test_std']:.1f} % | {100 * r['val_mean']:.1f} % | "
                     f"{100 * r['diff_mean']:+.1f} [{100 * lo:+.1f}, {100 * hi:+.1f}] | {det} | {frc} |")
    return "\n".join(lines)


def parse_seeds(items: list[str], scenario: str) -> list[int]:
    from sonicskin.sim.scenario import family_seeds

    seeds: list[int] = []
    for it in items:
        if it == "design":
            seeds += list(family_seeds("random")["design"]) if scenario == "random" else [0, 1, 2]
        elif it in ("heldout", "previous"):
            raise SystemExit(f"oneshot_probe: error: the {it} seeds are for the final evaluation only "
                             f"(benchmarks/bench_random_rigs.py); develop on 'design' or seeds outside 7000-7999")
        elif "-" in it:
            a, b = (int(v) for v in it.split("-"))
            seeds += list(range(a, b + 1))
        else:
            seeds.append(int(it))
    bad = [s for s in seeds if any(s in r for r in FORBIDDEN)]
    if bad:
        raise SystemExit(f"oneshot_probe: error: seeds {bad} are in 7000-7999, where issue 26's held-out seeds live; "
                         f"develop on 'design' (0-9) or seeds like 100-139")
    return list(dict.fromkeys(seeds))


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--seeds", nargs="+", default=["design"], help="'design', seed numbers or ranges like 100-139")
    p.add_argument("--scenario", default="random", choices=sorted(SPLITS), help="scenario (default: the random family)")
    p.add_argument("--cache", default=None, help="simulated datasets (default: data/random, or data/seeds for a scenario)")
    p.add_argument("--out", default="reports/oneshot-probe", help="report folder (default: reports/oneshot-probe)")
    p.add_argument("--only", nargs="*", help="only candidates whose name contains one of these")
    p.add_argument("--net", action="store_true", help="also the network candidates (torch; training.augment)")
    p.add_argument("--resume", action="store_true", help="keep per-rig results already in OUT/rows")
    p.add_argument("--merge", action="store_true", help="keep the models already scored in OUT/rows, score only new ones")
    a = p.parse_args(argv)
    from sonicskin.seeds import scenario_dataset

    seeds = parse_seeds(a.seeds, a.scenario)
    cache = Path(a.cache or ("data/random" if a.scenario == "random" else "data/seeds"))
    out = Path(a.out) / a.scenario
    (out / "rows").mkdir(parents=True, exist_ok=True)
    rows: dict[int, dict] = {}
    t0 = time.perf_counter()
    for s in seeds:
        f = out / "rows" / f"{s}.json"
        old = json.loads(f.read_text()) if f.is_file() else None
        if a.resume and old is not None:
            rows[s] = old
            continue
        ds = scenario_dataset(a.scenario, s, cache, log=lambda *_: None)
        d = load_rig(ds.root, SPLITS[a.scenario])
        res = add_picks(score_rig(d, names=a.only, net=a.net, have=old if a.merge else None))
        f.write_text(json.dumps(res, indent=1))
        rows[s] = res
        best = ", ".join(f"{k} {100 * v['test']:.1f}" for k, v in res.items() if not k.startswith("_"))
        print(f"seed {s} ({res['_meta']['n_markers']} markers, {res['_meta']['seconds']:.0f} s): {best}", flush=True)
    summ = summarize(rows)
    md = format_table(summ, f"{a.scenario}: seeds {seeds[0]}..{seeds[-1]} ({len(seeds)} rigs); "
                            f"split {SPLITS[a.scenario] or 'leave-subjects-out'}; "
                            f"accuracy on every touch chirp of the test sessions; wall {time.perf_counter() - t0:.0f} s")
    (out / "summary.json").write_text(json.dumps({"seeds": seeds, "summary": summ}, indent=1))
    (out / "summary.md").write_text(md + "\n")
    print(md)
    return 0


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    raise SystemExit(main())
