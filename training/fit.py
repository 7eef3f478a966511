"""The network's part of the one fit (:mod:`sonicskin.fit`): train it in-process, choose its touch decision and its
force model on data it did not train on, and hand it over for export as a :class:`NetFit`.

``sonicskin train`` (LightningCLI) trains the same module; ``sonicskin export`` then calls :func:`finish_network` on
the checkpoint's network, so both paths end in the same choices.
"""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path

import numpy as np

__all__ = ["NetFit", "train_network", "choose_network_layer", "finish_network", "artifact_from_checkpoint"]


@dataclasses.dataclass
class NetFit:
    """A trained network ready for export: the torch module, its hyperparameters (``skin.json`` ``hparams``), the
    touch decision its head applies (``skin.json`` ``detector``; ``None``: its own p(touch)), what was chosen and
    how (``selection["net"]``), and the training time."""

    model: object
    hparams: dict
    detector: dict | None
    selection: dict
    train_time_s: float | None = None


def _plain_hparams(h) -> dict:
    return {k: (list(v) if isinstance(v, tuple) else v) for k, v in dict(h).items()}


def train_network(data, *, svm, select: bool = True, seed: int = 0, epochs: int | None = None, layer: dict | None = None,
                  **hparams) -> NetFit:
    """Train the network on the training chirps of ``data`` (a :class:`sonicskin.fit.TrainingData`) in-process.

    ``select``: its location layer is chosen first (:func:`choose_network_layer`); without validation it is the SVM's
    copy (:data:`training.quick.UNVALIDATED`).  ``layer``: that choice already made (several training seeds share
    it).  The network reads the first inputs its layer asks for (OSPA order) and, unless it is the SVM's copy, trains
    on augmented presses of its own training session (:func:`training.augment.make_augmenter`).  Then
    :func:`finish_network`."""
    from .augment import make_augmenter
    from .quick import DEFAULTS, UNVALIDATED, fit_net, layer_hparams

    n, X, cls, force = data.n_locations, data.X, data.cls, data.force
    train = data.rows("train")
    kw = {} if epochs is None else {"epochs": int(epochs)}
    if layer is None and select:
        layer = choose_network_layer(data, svm=svm, seed=seed, epochs=epochs)
    if not layer or "location_layer" not in layer:
        layer = {"location_layer": UNVALIDATED, "layer_how": "not validated (model selection off)"}
    hp = {**DEFAULTS, **hparams,
          **(layer.get("hparams") or layer_hparams(layer["location_layer"], n_in=X.shape[1], n_svm=data.n_svm))}
    aug = make_augmenter(data, train) if hp.get("augment") else None
    svm_fits = svm is not None and hp.get("layer") == "kernel" and int(svm.pipe[0].n_features_in_) == hp.get("n_inputs")
    t0 = time.perf_counter()
    predict = fit_net(X[train], cls[train], force[train], n_locations=n, seed=int(seed), augmenter=aug,
                      kernel_svm=svm.pipe if svm_fits else None, **kw, **hp)
    train_s = time.perf_counter() - t0
    model = predict.model
    hparams_out = _plain_hparams({"n_in": int(X.shape[1]), "n_locations": n, **hp,
                                  "n_centres": int(model.kernel.centres.shape[0]) if model.kernel is not None else 0})
    return finish_network(model, data, svm=svm, selection=layer, train_time_s=train_s, hparams=hparams_out, seed=seed)


def layer_folds(data):
    """Where the network's location layer is validated: ``([(train rows, held-out rows, augmenter)], how)``.

    With a validation session: trained on the training session and scored on the validation session, and the other
    way round (the mean of both halves the ties at 100 % of one session).  Without one: the training session's last
    pass over the markers held out (trained on the others).  ``[]`` when nothing can validate (one press per marker,
    no validation session)."""
    from sonicskin.selection import press_ids, press_passes

    from .augment import make_augmenter

    t = data.table
    train, val = data.rows("train"), data.rows("val")
    if val.any():
        return ([(train, val, make_augmenter(data, train)), (val, train, make_augmenter(data, val))],
                f"validation on {', '.join(data.split.val)} (and trained there, scored on {', '.join(data.split.train)})")
    seg = t["segment"] if "segment" in t.labels else None
    passes = press_passes(np.where(train, press_ids(t["location"], t["session"], seg), -1), t["location"])
    if passes.max() >= 1:
        last = passes == passes.max()
        return [(train & ~last, train & last, make_augmenter(data, train & ~last))], "held-out last pass"
    return [], "one press per location and no validation session: not validated"


def choose_network_layer(data, *, svm, seed: int = 0, epochs: int | None = None, **hparams) -> dict:
    """The network's location layer chosen on presses it did not train on (:func:`layer_folds`,
    :func:`sonicskin.training.quick.choose_layer`); the SVM's copy when nothing can validate."""
    from .quick import UNVALIDATED, choose_layer

    folds, how = layer_folds(data)
    if not folds:
        return {"location_layer": UNVALIDATED, "layer_how": how}
    kw = {**hparams, **({} if epochs is None else {"epochs": int(epochs)})}
    alpha = ((svm.selection.get("force") or {}).get("alpha") or 10.0) if svm is not None else 10.0
    return choose_layer(data.X, data.cls, data.force, n_locations=data.n_locations, folds=folds, how=how, seed=seed,
                        location_ids=np.asarray(data.layout.ids), alpha=alpha, n_svm=data.n_svm, **kw)


def choose_auto_layer(module, datamodule, *, epochs: int) -> dict:
    """``sonicskin train`` with ``model.layer: auto``: the Lightning module's location layer chosen as
    :func:`choose_network_layer` chooses it for an in-process network, set on the module (its hyperparameters, then
    the network rebuilt) and recorded in its checkpoint's selection."""
    from .quick import UNVALIDATED, layer_hparams

    datamodule.setup("fit")
    h = module.hparams
    data = datamodule.prepared
    res = choose_network_layer(data, svm=None, epochs=epochs, hidden=tuple(h.hidden), dropout=h.dropout,
                               weight_decay=h.weight_decay)
    hp = res.get("hparams") or layer_hparams(res.get("location_layer", UNVALIDATED), n_in=data.X.shape[1], n_svm=data.n_svm)
    for k, v in hp.items():
        h[k] = v
    module.model = module._build()
    if datamodule.meta is not None:
        datamodule.meta.setdefault("selection", {})["net"] = {k: res[k] for k in ("location_layer", "layer_how")}
    print(f"network location layer: {res['location_layer']} ({res['layer_how']})")
    return res


def finish_network(model, data, *, svm, selection: dict | None = None, train_time_s: float | None = None,
                   hparams: dict | None = None, seed: int | None = None) -> NetFit:
    """The touch decision and the force of a trained network, chosen on chirps it did not train on.

    Touch: with a validation session holding hands-off and touch chirps, the best of its own head, its head
    recalibrated there, the SVM's input-RMS detector and either of them
    (:func:`sonicskin.training.quick.choose_detector`); without one its head cannot be judged on data it did not
    train on, so it is combined with the input-RMS detector (``either``: never more misses than the SVM's).  Force:
    its own head or a pooled ridge (over every input or the first 300), whichever has the lower RMSE on the validation
    presses (:func:`sonicskin.training.quick.choose_force`), or the choice ``selection`` made on a held-out pass."""
    import torch

    from sonicskin.force import PooledForce
    from sonicskin.head import DETECTOR_BINS

    from .quick import choose_detector, choose_force

    sel = dict(selection or {})
    sel.pop("hparams", None)
    model = model.eval()
    if hasattr(model, "set_detector"):
        model.set_detector(None)  # a checkpoint of an older export may carry one: the head decides now
    n, ids = data.n_locations, np.asarray(data.layout.ids)
    X, cls, force, t = data.X[:, :model.n_in], data.cls, data.force, data.table  # the network reads the first n_in
    train, val = data.rows("train"), data.rows("val")
    q = data.quiet
    n_det = min(DETECTOR_BINS, X.shape[1])  # the SVM's detector reads the first (best) inputs only
    ref = np.zeros(n_det) if data.spec.mode == "relative" else X[train & q][:, :n_det].mean(axis=0)
    detection = svm is not None and svm.params["detection"]
    detector = None
    if not detection:
        sel.update(detector="head", how="no hands-off chirps (or no SVM detector): the head's own p(touch)")
    elif (val & q).sum() >= 2 and (val & (cls < n)).any():
        with torch.no_grad():
            logits = model(torch.from_numpy(np.ascontiguousarray(X[val], np.float32)))[0].numpy()
        d = choose_detector(logits, X[val], (cls < n)[val], (t["location"] < 0)[val], threshold=svm.params["threshold"],
                            reference=ref, how=f"validation on {', '.join(data.split.val)}")
        detector = d["config"]
        sel.update(detector=d["detector"], how=d["how"])
    else:
        detector = {"mode": "either", "bias": 0.0, "threshold": float(svm.params["threshold"])}
        sel.update(detector="either", how="no validation session: the head combined with the input-RMS detector")
    if detector is not None:
        detector = {"mode": detector["mode"], "bias": float(detector.get("bias", 0.0)),
                    "threshold": float(detector["threshold"]), "bins": int(n_det),
                    **({} if data.spec.mode == "relative" else {"reference": [float(v) for v in ref]})}
        if detector["mode"] == "head" and not detector["bias"]:
            detector = None  # the graph's own p(touch) >= 0.5: nothing for the head to add
    alpha = ((svm.selection.get("force") or {}).get("alpha") or 10.0) if svm is not None else 10.0
    if val.any():
        sel.update(choose_force(model, X, cls, force, fit_rows=train, val_rows=val, location_ids=ids, alpha=alpha,
                                how=f"validation on {', '.join(data.split.val)}"))
    elif str(sel.get("force", "")).startswith("pooled-ridge"):  # chosen on the held-out pass: refitted on every pass
        fr = train & (cls < n) & np.isfinite(force)
        k = 300 if "first 300" in sel["force"] else X.shape[1]
        pf = PooledForce(alpha).fit(X[fr][:, :k], force[fr], ids[cls[fr]])
        coef = np.zeros(X.shape[1])
        coef[:k] = pf.coef_
        model.set_force({"coef": coef, "loc": [pf.loc_coef_[int(i)] + pf.intercept_ for i in ids]})
    if seed is not None:
        sel["train_seed"] = int(seed)
    return NetFit(model, dict(hparams or {}), detector, sel, train_time_s)


def check_same_sessions(meta: dict, ds, ckpt) -> None:
    """The dataset holds the sessions of the checkpoint's split, and (checkpoints that record it) the very recordings:
    the SVM is trained here on them, next to a network trained on the checkpoint's.  Other data under the same rig,
    layout and session names gave an artifact whose two models were trained on different recordings."""
    from sonicskin.errors import ArtifactError

    from .data import session_fingerprints

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




def artifact_from_checkpoint(ckpt: str | Path, out: str | Path, *, data: str | Path | None = None, log=print) -> dict:
    """``sonicskin export``: the checkpoint's network beside the SVM, through the one fit (:mod:`sonicskin.fit`).

    The SVM is fitted on the checkpoint's own split, bins and inputs, so both models in the artifact see exactly the
    same bins, reference and sessions; the network's touch decision and force are chosen as for an in-process network
    (:func:`finish_network`).  ``data`` (default: the checkpoint's) must have the checkpoint's rig and marker layout
    and hold the very recordings it was trained on.  ``out`` is replaced as a whole at the end."""
    from sonicskin.dataset import Dataset
    from sonicskin.errors import ArtifactError
    from sonicskin.features import FeatureSpec
    from sonicskin.fit import fit_artifact, prepare, summary_lines
    from sonicskin.integrity import check_layout, check_rig
    from sonicskin.split import Split

    from .checkpoint import load_checkpoint

    lit = load_checkpoint(ckpt)  # weights_only: nothing in the file is executed
    meta = lit.meta
    spec = FeatureSpec.from_dict(meta["spec"])
    ds = Dataset(data or meta["data"])
    # The data must be the checkpoint's rig and marker layout: the SVM is fitted on its positions here.
    check_rig({"rig": meta["rig"]}, ds.rig, what=f"checkpoint {Path(ckpt).name}", here=f"dataset {ds.root}")
    check_layout({"layout": meta["layout"]}, ds.layout, what=f"checkpoint {Path(ckpt).name}", here=f"dataset {ds.root}")
    check_same_sessions(meta, ds, ckpt)
    split = Split(**{k: tuple(v) for k, v in meta["split"].items()})
    d = prepare(ds, split=split, bins=spec.bins, mode=spec.mode, alpha_s=spec.alpha_s, min_force_n=meta["min_force_n"],
                progress=False, log=log)
    if d.spec != spec:
        raise ArtifactError(f"dataset {ds.root} gives other model inputs than checkpoint {Path(ckpt).name} was trained on "
                            f"({d.spec.mode}, beta {d.spec.beta_s:g} s vs {spec.mode}, beta {spec.beta_s:g} s); pass the "
                            f"dataset it was trained on with --data")
    d.selection = dict(meta.get("selection") or {})
    d.n_svm = int(meta.get("n_svm", len(spec.bins)))  # the SVM reads the first n_svm of the network's bins
    skin = fit_artifact(d, out, net=lit.model, training={"checkpoint": str(ckpt)}, log=log,
                        net_options={"hparams": _plain_hparams(lit.hparams), "train_time_s": meta.get("train_time_s"),
                                     "selection": (meta.get("selection") or {}).get("net")})
    for line in summary_lines(out, skin):
        log(line)
    return skin
