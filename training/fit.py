"""The network's part of the one fit (:mod:`sonicskin.fit`): train it in-process, choose its touch decision and its
force model on data it did not train on, and hand it over for export as a :class:`NetFit`.

``sonicskin train`` (LightningCLI) trains the same module; ``sonicskin export`` then calls :func:`finish_network` on
the checkpoint's network, so both paths end in the same choices.
"""

from __future__ import annotations

import dataclasses
import time

import numpy as np

__all__ = ["NetFit", "train_network", "choose_network_layer", "finish_network"]


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

    ``select``: its location layer is chosen first (:func:`sonicskin.training.quick.choose_layer`) on the validation
    session, or without one on the training session's last pass over the markers (trained on the others); with one
    press per location and no validation session it stays the default (the SVM's kernel, ``svm.pipe``).  Then
    :func:`finish_network`."""

    from .quick import DEFAULTS, fit_net

    n, X, cls, force = data.n_locations, data.X, data.cls, data.force
    train = data.rows("train")
    kw = {} if epochs is None else {"epochs": int(epochs)}
    if layer is None:
        layer = choose_network_layer(data, svm=svm, seed=seed, epochs=epochs) if select else {}
    hp = {**DEFAULTS, **hparams, **(layer.get("hparams") or {})}
    t0 = time.perf_counter()
    predict = fit_net(X[train], cls[train], force[train], n_locations=n, seed=int(seed),
                      kernel_svm=svm.pipe if (hp.get("kernel") and svm is not None) else None, **kw, **hp)
    train_s = time.perf_counter() - t0
    hparams_out = _plain_hparams({"n_in": int(X.shape[1]), "n_locations": n, **hp,
                                  "n_centres": int(getattr(getattr(predict.model, "kernel", None), "centres", np.zeros((0,))).shape[0])})
    return finish_network(predict.model, data, svm=svm, selection=layer, train_time_s=train_s, hparams=hparams_out,
                          seed=seed)


def choose_network_layer(data, *, svm, seed: int = 0, epochs: int | None = None) -> dict:
    """The network's location layer chosen on the validation session, or without one on the training session's last
    pass over the markers (trained on the others): :func:`sonicskin.training.quick.choose_layer`."""
    from sonicskin.selection import press_ids, press_passes

    from .quick import choose_layer

    n, ids = data.n_locations, np.asarray(data.layout.ids)
    X, cls, force, t = data.X, data.cls, data.force, data.table
    train, val = data.rows("train"), data.rows("val")
    kw = {} if epochs is None else {"epochs": int(epochs)}
    alpha = ((svm.selection.get("force") or {}).get("alpha") or 10.0) if svm is not None else 10.0
    if val.any():
        return choose_layer(X, cls, force, n_locations=n, train=train, val=val, seed=seed,
                            how=f"validation on {', '.join(data.split.val)}", location_ids=ids, alpha=alpha, **kw)
    seg = t["segment"] if "segment" in t.labels else None
    passes = press_passes(np.where(train, press_ids(t["location"], t["session"], seg), -1), t["location"])
    if passes.max() >= 1:
        last = passes == passes.max()
        return choose_layer(X, cls, force, n_locations=n, train=train & ~last, val=train & last, seed=seed,
                            how="held-out last pass", location_ids=ids, alpha=alpha, **kw)
    return {"location_layer": "frozen kernel", "layer_how": "one press per location: not validated", "hparams": {}}


def finish_network(model, data, *, svm, selection: dict | None = None, train_time_s: float | None = None,
                   hparams: dict | None = None, seed: int | None = None) -> NetFit:
    """The touch decision and the force of a trained network, chosen on chirps it did not train on.

    Touch: with a validation session holding hands-off and touch chirps, the best of its own head, its head
    recalibrated there, the SVM's input-RMS detector and either of them
    (:func:`sonicskin.training.quick.choose_detector`); without one its head cannot be judged on data it did not
    train on, so it is combined with the input-RMS detector (``either``: never more misses than the SVM's).  Force:
    its own head or the SVM's pooled ridge, whichever has the lower RMSE on the validation presses
    (:func:`sonicskin.training.quick.choose_net_force`), or the choice ``selection`` made on a held-out pass."""
    import torch

    from sonicskin.force import PooledForce
    from sonicskin.head import DETECTOR_BINS

    from .quick import choose_detector, choose_net_force

    sel = dict(selection or {})
    sel.pop("hparams", None)
    model = model.eval()
    if hasattr(model, "set_detector"):
        model.set_detector(None)  # a checkpoint of an older export may carry one: the head decides now
    n, ids = data.n_locations, np.asarray(data.layout.ids)
    X, cls, force, t = data.X, data.cls, data.force, data.table
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
    if val.any():
        alpha = ((svm.selection.get("force") or {}).get("alpha") or 10.0) if svm is not None else 10.0
        sel.update(choose_net_force(model, X, cls, force, fit_rows=train, val_rows=val, location_ids=ids, alpha=alpha,
                                    how=f"validation on {', '.join(data.split.val)}"))
    elif sel.get("force") == "pooled-ridge":  # validated on the held-out pass: the SVM's pooled model on every pass
        fr = train & (cls < n) & np.isfinite(force)
        alpha = ((svm.selection.get("force") or {}).get("alpha") or 10.0) if svm is not None else 10.0
        pf = PooledForce(alpha).fit(X[fr], force[fr], ids[cls[fr]])
        model.set_force({"coef": pf.coef_, "loc": [pf.loc_coef_[int(k)] + pf.intercept_ for k in ids]})
    if seed is not None:
        sel["train_seed"] = int(seed)
    return NetFit(model, dict(hparams or {}), detector, sel, train_time_s)
