"""The network as a model kind (:class:`NetTrainer`, the ``sonicskin.kinds`` entry point ``net``): trained in-process,
its choices made on presses it did not train on, refitted on every labelled press, exported to ONNX.
``sonicskin export`` hands a checkpoint's network to :meth:`NetTrainer.fit` (``model=``), so both paths end alike."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import torch
from sonicskin.export.onnx import export_net

from sonicskin.dataset import Dataset, Split
from sonicskin.errors import ArtifactError
from sonicskin.features import FeatureSpec
from sonicskin.fit import fit_artifact, prepare, summary_lines
from sonicskin.force import POOLED, energy_db, force_from_dict
from sonicskin.head import DETECTOR_BINS
from sonicskin.integrity import check_layout, check_rig
from sonicskin.kinds import BASELINE, NETWORK, Fitted
from sonicskin.kinds.net import NetKind

from .augment import make_augmenter
from .checkpoint import load_checkpoint
from .data import session_fingerprints
from .quick import DEFAULTS, REFIT_LAYER, UNVALIDATED, choose_detector, choose_layer, fit_net, layer_hparams

#: the network's force wherever the SVM has a force model (its validated per-location Fourier-1 or pooled ridge, or the
#: unvalidated pooled ridge): trained on one session of each of the 30 design rigs of the random family (stored result
#: ``default``), the network's own head was 0.70 [0.36, 1.04] N worse than the pooled ridge on relative inputs and
#: 0.57 [0.23, 0.91] N on absolute ones; one validation press per marker is too few to overrule that per rig
SVM_FORCE = "the SVM's"
#: its touch decision without a validation session: the SVM's detector OR the head's logit.  On the moving robot at
#: 13.3 ms chirps (design seed 0) it missed 0.6 % of touches and called 6.3 % of rest chirps touched, the SVM's detector
#: alone 17.8 % and 5.7 %.  (Before the SVM's threshold was applied over the SVM's own bins, it called every one touched.)
UNVALIDATED_DETECTOR = "either"

__all__ = ["NetTrainer", "train_network", "choose_network_layer", "finish_network", "score_force", "artifact_from_checkpoint"]


class NetTrainer(NetKind):
    """The network kind with its fit and export (torch)."""

    can_fit = True

    def fit(self, data, *, fitted, selection=None, log=print, model=None, seed: int = 0, epochs: int | None = None,
            select: bool = True, layer: dict | None = None, hparams: dict | None = None, train_time_s: float | None = None,
            **options) -> Fitted:
        """Train on ``data``'s training rows, or finish ``model``, a trained module; ``selection``: an earlier pass's choices."""
        if selection is not None:
            return train_network(data, fitted=fitted, chosen=selection[NETWORK])
        if model is not None:
            return finish_network(model, data, fitted=fitted, selection=layer, hparams=hparams, train_time_s=train_time_s, seed=seed)
        return train_network(data, fitted=fitted, select=select, seed=seed, epochs=epochs, layer=layer, **options)

    def export(self, fit, path, X_check):
        return export_net(fit.model, path, X_check)


def _plain_hparams(h) -> dict:
    return {k: (list(v) if isinstance(v, tuple) else v) for k, v in dict(h).items()}


def train_network(data, *, fitted: dict, select: bool = True, seed: int = 0, epochs: int | None = None,
                  layer: dict | None = None, chosen: dict | None = None, **hparams) -> Fitted:
    """Train the network in-process: its location layer chosen first (or ``layer``), on augmented presses; then :func:`finish_network`."""
    n, X, cls, force = data.n_locations, data.X, data.cls, data.force
    train = data.rows("train")
    if chosen is not None:
        seed, epochs = chosen.get("train_seed", seed), chosen.get("epochs", epochs)
        layer = {"location_layer": chosen.get("location_layer", "as trained"), "layer_how": chosen.get("layer_how", ""),
                 "hparams": chosen.get("hparams")}
    kw = {} if epochs is None else {"epochs": int(epochs)}
    here = layer is None and select
    if here:
        layer = choose_network_layer(data, fitted=fitted, seed=seed, epochs=epochs)
    if not layer or "location_layer" not in layer:
        layer = {"location_layer": UNVALIDATED, "layer_how": "not validated (model selection off)"}
    layer = dict(layer)
    model = layer.pop("fold_model", None) if here else None  # the chosen MLP as its first fold trained it: these rows
    hp = {**DEFAULTS, **hparams, **(layer.get("hparams") or layer_hparams(layer["location_layer"], n_in=X.shape[1]))}
    t0 = time.perf_counter()
    if model is None:
        aug = make_augmenter(data, train) if hp.get("augment") else None
        model = fit_net(X[train], cls[train], force[train], n_locations=n, seed=int(seed), augmenter=aug, fitted=fitted, **kw, **hp).model
    train_s = time.perf_counter() - t0
    hparams_out = _plain_hparams({"n_in": int(X.shape[1]), "n_locations": n, **hp, "epochs": int(epochs or 40),
                                  "n_centres": int(model.kernel.centres.shape[0]) if model.kernel is not None else 0})
    return finish_network(model, data, fitted=fitted, selection=layer, train_time_s=train_s, hparams=hparams_out, seed=seed, chosen=chosen)


def layer_folds(data):
    """Where the network's location layer is validated: ``([(fit rows, held-out rows, augmenter)], how)``."""
    folds, how = data.folds()
    return [(f, h, make_augmenter(data, f)) for f, h in folds], how


def choose_network_layer(data, *, fitted: dict, seed: int = 0, epochs: int | None = None, **hparams) -> dict:
    """The network's location layer chosen on presses it did not train on; the closed form when nothing can validate,
    or when a refit on every labelled press follows (:data:`training.quick.REFIT_LAYER`: no MLP is trained)."""
    if data.refit_follows:
        return {"location_layer": REFIT_LAYER, "layer_how": "the closed form: a refit on every labelled press follows, "
                "where it gains more from a second press per marker than an MLP"}
    folds, how = layer_folds(data)
    if not folds:
        return {"location_layer": UNVALIDATED, "layer_how": f"{how}: not validated, the closed form"}
    kw = {**hparams, **({} if epochs is None else {"epochs": int(epochs)})}
    return choose_layer(data, folds=folds, how=how, fitted=fitted, seed=seed, **kw)


def choose_auto_layer(module, datamodule, *, epochs: int) -> dict:
    """``model.layer: auto``: the layer chosen as for an in-process network, set on the module and in its selection."""
    datamodule.setup("fit")
    h = module.hparams
    data = datamodule.prepared
    res = choose_network_layer(data, fitted=datamodule.fitted, epochs=epochs, hidden=tuple(h.hidden), dropout=h.dropout,
                               weight_decay=h.weight_decay)
    res.pop("fold_model", None)
    for k, v in (res.get("hparams") or layer_hparams(res["location_layer"], n_in=data.X.shape[1])).items():
        h[k] = v
    module.model = module._build()
    if datamodule.meta is not None:
        datamodule.meta.setdefault("selection", {})[NETWORK] = {k: res[k] for k in ("location_layer", "layer_how")}
    print(f"network location layer: {res['location_layer']} ({res['layer_how']})")
    return res


def finish_network(model, data, *, fitted: dict, selection: dict | None = None, train_time_s: float | None = None,
                   hparams: dict | None = None, seed: int | None = None, chosen: dict | None = None) -> Fitted:
    """The touch decision and the force of a trained network, chosen on chirps it did not train on: touch, the SVM's
    input-RMS detector or ``either`` of it and the network's own logit (:func:`sonicskin.training.quick.choose_detector`;
    without a validation session :data:`UNVALIDATED_DETECTOR`: never more misses than the SVM's); force, the SVM's force
    model wherever it has one (:data:`SVM_FORCE`; both scored on the validation presses, :func:`score_force`), else the
    head.  ``chosen``:
    both choices of an earlier pass (a refit), applied with this data's SVM."""
    sel = {k: v for k, v in (selection or {}).items() if k not in ("hparams", "fold_model")}
    model = model.eval()
    n, ids = data.n_locations, np.asarray(data.layout.ids)
    X, cls, force, t = data.X[:, :model.n_in], data.cls, data.force, data.table  # the network reads the first n_in
    train, val = data.rows("train"), data.rows("val")
    q = data.quiet
    svm = fitted.get(BASELINE)
    detection = svm is not None and svm.entry["detection"]
    # the SVM's detector: its threshold holds for the RMS over its own first (best) inputs, as many as it read
    n_det = min(int(svm.entry["detector_bins"]) if detection else DETECTOR_BINS, X.shape[1])
    ref = X[train & q][:, :n_det].mean(axis=0) if data.spec.mode == "absolute" and (train & q).any() else np.zeros(n_det)
    threshold = float(svm.entry["threshold"]) if detection else 0.0
    if chosen is not None:
        sel.update({k: v for k, v in chosen.items() if k in ("detector", "how", "detector_mode", "bias", "force", "force_how",
                                                             "force_rmse")})
        detector = {"mode": chosen["detector_mode"], "bias": chosen.get("bias", 0.0)} if chosen.get("detector_mode") else None
    elif not detection:
        detector = None
        sel.update(detector="head", how="no hands-off chirps (or no SVM detector): the head's own p(touch)")
    elif (val & q).sum() >= 2 and (val & (cls < n)).any():
        with torch.no_grad():
            logits = model(torch.from_numpy(np.ascontiguousarray(X[val], np.float32)))[0].numpy()
        d = choose_detector(logits, X[val], (cls < n)[val], (t["location"] < 0)[val], threshold=threshold,
                            reference=ref, how=f"validation on {', '.join(data.split.val)}")
        detector = d["config"]
        sel.update(detector=d["detector"], how=d["how"])
    else:
        detector = {"mode": UNVALIDATED_DETECTOR, "bias": 0.0}
        sel.update(detector=UNVALIDATED_DETECTOR, how="no validation session: the head combined with the input-RMS detector")
    if detector is not None:
        detector = {"mode": detector["mode"], "bias": float(detector.get("bias", 0.0)), "threshold": threshold,
                    "bins": int(n_det), **({} if data.spec.mode == "relative" else {"reference": [float(v) for v in ref]})}
        sel.update(detector_mode=detector["mode"], bias=detector["bias"])
        if detector["mode"] == "head" and not detector["bias"]:
            detector = None  # the graph's own p(touch) >= 0.5: nothing for the head to add
    if chosen is None:
        sel.update(score_force(model, X, cls, force, val_rows=val, location_ids=ids, svm=svm,
                               how=f"validation on {', '.join(data.split.val)}" if val.any() else ""))
    use_svm = sel.get("force") == SVM_FORCE and has_force(svm) and svm.n_in <= model.n_in
    if seed is not None:
        sel["train_seed"] = int(seed)
    hp = dict(hparams or {})
    if hp.get("epochs"):
        sel["epochs"] = int(hp["epochs"])
    sel["hparams"] = {k: v for k, v in hp.items() if k not in ("n_in", "n_locations", "n_centres", "epochs")}
    entry = {"hparams": hp, **({"detector": detector} if detector is not None else {}),
             **({"force": svm.entry["force"], "force_bins": int(svm.n_in), "energy_ref_db": svm.entry["energy_ref_db"]}
                if use_svm else {})}
    return Fitted(model, entry, int(model.n_in), {NETWORK: sel}, train_time_s)


def score_force(model, X, cls, force, *, val_rows, location_ids, svm=None, how: str = "") -> dict:
    """The network's force: the SVM's force model wherever it has one (:data:`SVM_FORCE`), else its own head; with
    both RMSEs on the validation presses (``how`` names them; empty: none) for the report, not for a choice."""
    if not has_force(svm) or svm.n_in > X.shape[1]:
        return {"force": "head", "force_how": "no SVM force model (no force sensor, or it reads more bins than the network)"}
    ids = np.asarray(location_ids)
    f = np.asarray(force, np.float64)
    vr = val_rows & (cls < len(ids)) & np.isfinite(f)
    if not how or vr.sum() < 2:
        return {"force": SVM_FORCE, "force_how": "not validated (no validation presses with a force reading); the "
                                                 "head is never deployed beside an SVM force model"}
    with torch.no_grad():
        head = model(torch.from_numpy(np.ascontiguousarray(X[vr], np.float32)))[1].numpy()[np.arange(vr.sum()), cls[vr]]
    pred = {SVM_FORCE: svm_force(svm, X[vr], ids[cls[vr]]), "head": head}
    rmse = {k: float(np.sqrt(np.mean((np.clip(np.nan_to_num(p), 0, None) - f[vr]) ** 2))) for k, p in pred.items()}
    return {"force": SVM_FORCE, "force_how": f"{how}: " + ", ".join(f"{k} {v:.2f} N" for k, v in rmse.items())
            + "; the SVM's is deployed (the head lost across the design rigs)", "force_rmse": rmse}


def has_force(svm) -> bool:
    """The SVM has a force model (its data had a force sensor)."""
    return svm is not None and bool(svm.entry["force"]["curves"] or svm.entry["force"]["model"] in POOLED)


def svm_force(svm, X: np.ndarray, location) -> np.ndarray:
    """The SVM's force model at ``location`` on chirps ``X`` (their first ``svm.n_in`` inputs), as the head applies it."""
    xs = np.asarray(X, np.float64)[:, :svm.n_in]
    E = energy_db(xs, np.arange(svm.n_in)) - svm.entry["energy_ref_db"]
    return force_from_dict(svm.entry["force"]).predict(E, location, inputs=xs)


def check_same_sessions(meta: dict, ds, ckpt) -> None:
    """The dataset holds the checkpoint's sessions and (where recorded) the very recordings it was trained on."""
    split = [s for k in ("train", "val", "test") for s in meta["split"][k]]
    missing = [s for s in split if s not in set(ds.sessions)]
    if missing:
        raise ArtifactError(f"dataset {ds.root} lacks session(s) {', '.join(missing)} of checkpoint {Path(ckpt).name}'s split "
                            f"(train {', '.join(meta['split']['train'])}); pass the dataset it was trained on (--data)")
    want = meta.get("sessions_sha256")
    if isinstance(want, dict):
        have = session_fingerprints(ds.root, list(want))
        other = [s for s in want if have[s] != want[s]]
        if other:
            raise ArtifactError(f"dataset {ds.root}'s session(s) {', '.join(other)} are other recordings than checkpoint "
                                f"{Path(ckpt).name} was trained on (their session.json differs); pass the dataset it was "
                                f"trained on (a copy of it is fine) with --data")


def artifact_from_checkpoint(ckpt: str | Path, out: str | Path, *, data: str | Path | None = None, refit: bool = True,
                             log=print) -> dict:
    """``sonicskin export``: the checkpoint's network beside the closed-form models, through the one fit
    (:mod:`sonicskin.fit`), all on the checkpoint's split, bins and inputs; the network's touch decision and force as
    for an in-process network, then (a validation session and ``refit``) every model fitted again on the training
    and validation sessions.  ``data`` (default: the checkpoint's) must hold the very recordings it was trained on.
    ``out`` is replaced as a whole at the end."""
    lit = load_checkpoint(ckpt)  # weights_only: nothing in the file is executed
    meta = lit.meta
    spec = FeatureSpec.from_dict(meta["spec"])
    ds = Dataset(data or meta["data"])
    # The data must be the checkpoint's rig and marker layout: the closed forms are fitted on its positions here.
    check_rig({"rig": meta["rig"]}, ds.rig, what=f"checkpoint {Path(ckpt).name}", here=f"dataset {ds.root}")
    check_layout({"layout": meta["layout"]}, ds.layout, what=f"checkpoint {Path(ckpt).name}", here=f"dataset {ds.root}")
    check_same_sessions(meta, ds, ckpt)
    split = Split(**{k: tuple(v) for k, v in meta["split"].items()})
    d = prepare(ds, split=split, bins=spec.bins, mode=spec.mode, alpha_s=spec.alpha_s, beta_s=spec.beta_s,
                min_force_n=meta["min_force_n"], progress=False, log=log)
    if d.spec != spec:
        raise ArtifactError(f"dataset {ds.root} gives other model inputs than checkpoint {Path(ckpt).name} was trained on "
                            f"({d.spec.mode}, beta {d.spec.beta_s:g} s vs {spec.mode}, beta {spec.beta_s:g} s); pass the "
                            f"dataset it was trained on with --data")
    d.selection = {k: v for k, v in (meta.get("selection") or {}).items() if k != NETWORK}
    d.n_svm = int(meta.get("n_svm", len(spec.bins)))  # the SVM reads the first n_svm of the network's bins
    d.options = {"wide": True, "bins": None}  # a refit chooses OSPA's bins again on every labelled press
    net_sel = (meta.get("selection") or {}).get(NETWORK) or {}
    hp = _plain_hparams(lit.hparams)
    hp["epochs"] = int(meta.get("epochs") or 40)
    skin = fit_artifact(d, out, (NETWORK,), refit=refit, training={"checkpoint": str(ckpt)}, log=log,
                        options={NETWORK: {"model": lit.model, "hparams": hp, "train_time_s": meta.get("train_time_s"),
                                           "layer": net_sel, "seed": 0}})
    for line in summary_lines(out, skin):
        log(line)
    return skin
