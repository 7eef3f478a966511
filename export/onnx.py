"""Export the network (torch.onnx) and the SVM baseline (skl2onnx) into one deployment artifact,
each checked for parity against the original right after export."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
from sonicskin.training.checkpoint import load_checkpoint

from sonicskin.artifact import (
    PARITY_TOL,
    ParityError,
    atomic_artifact,
    decisions_parity,
    ort_session,
    parity_bound,
    parity_failure,
    skin_json,
    svm_entry,
)
from sonicskin.features import FeatureSpec, Split, model_inputs, training_targets
from sonicskin.rig import Layout
from sonicskin.schema import check_layout, check_rig

__all__ = ["export_artifact", "export_net"]

TOL = PARITY_TOL  # kept for callers of the old name


def export_net(model: torch.nn.Module, n_in: int, path: Path, X_check: np.ndarray) -> dict:
    """torch -> ONNX with a dynamic batch axis, then parity on ``X_check`` (:func:`sonicskin.artifact.decisions_parity`):
    the location (argmax of the location logits), the touch decision (p(touch) >= 0.5, as the runtime reads it),
    the logits and the force within :data:`~sonicskin.artifact.PARITY_TOL` of their scale.  The raw figures
    (``max_abs_logits``, ``max_abs_force_n``) are returned for ``skin.json``; a mismatch raises
    :class:`~sonicskin.artifact.ParityError` (one line)."""
    model = model.eval()
    example = torch.from_numpy(X_check[:2].astype(np.float32))
    torch.onnx.export(model, (example,), str(path), input_names=["features"], output_names=["logits", "force"],
                      dynamic_shapes=({0: torch.export.Dim("batch", min=1)},), dynamo=True, external_data=False)
    sess = ort_session(path)
    with torch.no_grad():
        ref_logits, ref_force = (t.numpy() for t in model(torch.from_numpy(X_check.astype(np.float32))))
    logits, force = sess.run(None, {sess.get_inputs()[0].name: X_check.astype(np.float32)})
    # The kernel layer votes with sign(d): a pairwise decision within float32 rounding of zero can vote the other
    # way in onnxruntime than in torch and move two locations' logits by a whole vote.  Such a chirp, when its
    # logits differ, is a flipped vote (as for the SVM's export), held to the force only: the force never votes.
    tie = np.zeros(len(X_check), bool)
    kernel = getattr(model, "kernel", None)
    if kernel is not None:
        with torch.no_grad():
            d = kernel.decision(kernel.rbf(model.standardize(torch.from_numpy(X_check.astype(np.float32))))).numpy()
        tie = (np.abs(d) < parity_bound(d)).any(1)

    def touch_margin(lg):  # log p(touch) / p(no touch): the runtime's p(touch) >= 0.5
        from scipy.special import logsumexp

        lg = np.asarray(lg, np.float64)
        return logsumexp(lg[:, :-1], axis=1) - lg[:, -1]

    parity = decisions_parity({"logits": logits, "force_n": force}, {"logits": ref_logits, "force_n": ref_force},
                              label="logits", label_cols=slice(0, -1), touch=(touch_margin(logits), touch_margin(ref_logits)),
                              vote_tie=tie, every_chirp=("force_n",))
    if not parity.pop("ok"):
        import onnxruntime

        raise ParityError(parity_failure("net.onnx", "the torch network", parity, len(X_check),
                                         f"onnxruntime {onnxruntime.__version__} runs the graph torch {torch.__version__} "
                                         f"exported differently; reinstall the tested versions (pip install -c "
                                         f"constraints.txt -e '.[train]') and export again"))
    return parity


def check_same_sessions(meta: dict, ds, ckpt) -> None:
    """The dataset holds the sessions of the checkpoint's split, and (checkpoints that record it) the very recordings:
    the SVM is trained here on them, next to a network trained on the checkpoint's.  Other data under the same rig,
    layout and session names gave an artifact whose two models were trained on different recordings."""
    from sonicskin.training.data import session_fingerprints

    from sonicskin.schema import ArtifactError

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


def export_artifact(ckpt: str | Path, out: str | Path, *, data: str | Path | None = None, log=print) -> dict:
    """Write ``out/{net.onnx, svm.onnx, skin.json}`` from a training checkpoint.

    The SVM is trained here on the checkpoint's training split and inputs, so both models in the
    artifact see exactly the same bins, reference and sessions.  ``data`` (default: the checkpoint's)
    must have the checkpoint's rig and marker layout.  ``out`` is replaced as a whole at the end.
    """
    lit = load_checkpoint(ckpt)  # weights_only: nothing in the file is executed
    meta = lit.meta
    out = Path(out)
    spec = FeatureSpec.from_dict(meta["spec"])
    ds, t, X = model_inputs(data or meta["data"], spec, progress=False)
    # The data must be the checkpoint's rig and marker layout: the SVM is fitted on its positions here.
    check_rig({"rig": meta["rig"]}, ds.rig, what=f"checkpoint {Path(ckpt).name}", here=f"dataset {ds.root}")
    check_layout({"layout": meta["layout"]}, ds.layout, what=f"checkpoint {Path(ckpt).name}", here=f"dataset {ds.root}")
    check_same_sessions(meta, ds, ckpt)
    layout = Layout.from_dict(meta["layout"])
    split = Split(**{k: tuple(v) for k, v in meta["split"].items()})
    n_loc = len(layout)
    cls, usable = training_targets(t, layout, meta["min_force_n"])
    p = {"table": t, "X": X, "cls": cls, "force": t["force_n"].astype(np.float32), "n_locations": n_loc, "dataset": ds}
    with atomic_artifact(out) as tmp:  # an interrupted export keeps the old artifact
        svm, svm_train_s, sel = svm_entry(p, tmp, split.mask(t, "train") & usable, val_mask=split.mask(t, "val") & usable,
                                          selection=meta.get("selection"), log=log)
        probe = svm.pop("_probe")
        from sonicskin.training.quick import calibrate_net_detector

        sel["net"] = {**(sel.get("net") or {}), **calibrate_net_detector(
            lit.model, X, t, cls, train=split.mask(t, "train") & usable, val=split.mask(t, "val") & usable,
            threshold=svm["threshold"] if svm["detection"] else 0.0, mode=spec.mode, n_locations=n_loc)}
        if split.val:  # the network's force head against the pooled model on the validation session's presses
            from sonicskin.training.quick import choose_net_force

            sel["net"].update(choose_net_force(lit.model, X, cls, t["force_n"], fit_rows=split.mask(t, "train") & usable,
                                               val_rows=split.mask(t, "val") & usable, location_ids=layout.ids,
                                               alpha=(sel.get("force") or {}).get("alpha") or 10.0,
                                               how=f"validation on {', '.join(split.val)}"))
        rng = np.random.default_rng(0)
        check = X[rng.choice(X.shape[0], size=min(512, X.shape[0]), replace=False)]
        net_parity = export_net(lit.model, X.shape[1], tmp / "net.onnx", check)
        net = {"file": "net.onnx", "kind": "skinnet", "n_in": int(X.shape[1]), "n_locations": n_loc, "parity": net_parity,
               "hparams": {k: (list(v) if isinstance(v, tuple) else v) for k, v in lit.hparams.items()}}
        skin = skin_json(tmp, rig=meta["rig"], layout=meta["layout"], spec=spec, min_force_n=meta["min_force_n"],
                         training={"data": str(Path(ds.root).resolve()), "split": meta["split"], "checkpoint": str(ckpt),
                                   "svm_train_time_s": svm_train_s, "net_train_time_s": meta.get("train_time_s")},
                         models={"net": net, "svm": svm}, probe_inputs=probe, selection=sel)
    from sonicskin.selection import format_selection

    for line in format_selection(sel):
        log(line)
    log(f"exported {out}: net.onnx ({(out / 'net.onnx').stat().st_size / 1e3:.0f} kB, parity max |d logits| "
        f"{net_parity['max_abs_logits']:.1e}), svm.onnx ({(out / 'svm.onnx').stat().st_size / 1e3:.0f} kB, parity max "
        f"|d scores| {svm['parity']['max_abs_scores']:.1e})")
    return skin
