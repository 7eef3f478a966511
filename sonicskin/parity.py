"""Export parity: an exported graph must decide as the model it was exported from (every kind's export checks it)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .errors import ArtifactError

__all__ = ["PARITY_TOL", "ParityError", "parity_bound", "decisions_parity", "require_parity", "ort_session"]

#: Export parity: the graph in onnxruntime (float32) and the original (torch float32, scikit-learn float64) differ by
#: rounding that grows with the values, so what must agree is what the artifact decides (location, touch) and the
#: continuous outputs within ``PARITY_TOL`` x the output's scale (its largest magnitude on the check chirps, at least
#: 1); a near tie (decided by less than that) is counted, not judged.
PARITY_TOL = 1e-3


class ParityError(ArtifactError):
    """The exported ONNX model does not decide as the model it was exported from."""


def parity_bound(ref: np.ndarray) -> float:
    """The largest rounding difference accepted on outputs ``ref``: ``PARITY_TOL`` x max(1, max |ref|) (finite values)."""
    ref = np.asarray(ref, np.float64)
    finite = np.abs(ref[np.isfinite(ref)])
    return PARITY_TOL * max(1.0, float(finite.max(initial=0.0)))


def _top2_gap(scores: np.ndarray) -> np.ndarray:
    """Per row, the winner's lead over the runner-up (inf with one column)."""
    if scores.shape[1] < 2:
        return np.full(len(scores), np.inf)
    top = np.sort(scores, axis=1)[:, -2:]
    return top[:, 1] - top[:, 0]


def decisions_parity(got: dict[str, np.ndarray], ref: dict[str, np.ndarray], *, label: str, label_cols: slice = slice(None),
                     touch: tuple[np.ndarray, np.ndarray] | None = None, vote_tie: np.ndarray | None = None,
                     every_chirp: tuple[str, ...] = ()) -> dict:
    """Parity figures of an export: outputs ``got`` (onnxruntime) against ``ref`` (the original), by output name.

    The location is the argmax of output ``label`` (columns ``label_cols``); ``touch``: the touch statistic of both
    (a touch where >= 0).  Every output ``k`` gets ``max_abs_<k>`` and its bound ``<k>_tol``
    (:func:`parity_bound`), ``labels_equal``/``touch_equal`` and ``ok``.  ``near_ties`` (the original decides by
    less than the label output's bound) are judged on their outputs only; ``votes_flipped`` (chirps of ``vote_tie``,
    a pairwise vote within rounding of zero) on the outputs of ``every_chirp`` only (those a vote cannot move).
    """
    ref_l = np.asarray(ref[label], np.float64)[:, label_cols]
    got_l = np.asarray(got[label], np.float64)[:, label_cols]
    n = len(ref_l)
    tol = {k: parity_bound(ref[k]) for k in ref}
    near = _top2_gap(ref_l) < tol[label]
    if touch is not None:
        near |= np.abs(np.asarray(touch[1], np.float64)) < tol[label]
    diff = {}
    for k in ref:
        d = np.abs(np.asarray(got[k], np.float64) - np.asarray(ref[k], np.float64)).reshape(n, -1)
        diff[k] = np.where(np.isfinite(d), d, np.inf).max(axis=1, initial=0.0)
    label_ok = np.argmax(got_l, 1) == np.argmax(ref_l, 1)
    touch_ok = np.ones(n, bool) if touch is None else (np.asarray(touch[0]) >= 0) == (np.asarray(touch[1]) >= 0)
    row_bad = ~near & ~(label_ok & touch_ok)
    for k in ref:
        if k not in every_chirp:
            row_bad |= diff[k] > tol[k]
    flipped = row_bad & (np.zeros(n, bool) if vote_tie is None else np.asarray(vote_tie, bool))
    judged = ~flipped
    out: dict = {}
    ok = True
    for k in ref:
        rows = slice(None) if k in every_chirp else judged
        out[f"max_abs_{k}"], out[f"{k}_tol"] = float(diff[k][rows].max(initial=0.0)), tol[k]
        ok &= out[f"max_abs_{k}"] <= tol[k]
    out["near_ties"] = int((near & judged).sum())
    if vote_tie is not None:
        out["votes_flipped"] = int(flipped.sum())
    decided = judged & ~near
    out["labels_equal"] = bool(label_ok[decided].all())
    ok &= out["labels_equal"]
    if touch is not None:
        out["touch_equal"] = bool(touch_ok[decided].all())
        ok &= out["touch_equal"]
    out["ok"] = bool(ok)
    return out


def parity_failure(what: str, original: str, parity: dict, n_checked: int, fix: str) -> str:
    """One line: what of ``parity`` failed, on how many chirps, and ``fix``."""
    wrong = [k for k in ("labels_equal", "touch_equal") if parity.get(k) is False]
    over = [f"max |d {k[8:]}| {parity[k]:.2g} > {parity[k[8:] + '_tol']:.2g}" for k in parity
            if k.startswith("max_abs_") and k[8:] + "_tol" in parity and not parity[k] <= parity[k[8:] + "_tol"]]
    parts = [{"labels_equal": "the location differs", "touch_equal": "the touch decision differs"}[k] for k in wrong] + over
    return (f"the exported {what} does not decide as {original} does on its {n_checked} check chirps "
            f"({'; '.join(parts)}): {fix}")


def require_parity(parity: dict, what: str, original: str, n_checked: int, how: str) -> dict:
    """``parity`` without its verdict, or one-line :class:`ParityError` ending "onnxruntime <version> runs the graph ``how``"."""
    if not parity.pop("ok"):
        import onnxruntime

        raise ParityError(parity_failure(what, original, parity, n_checked, f"onnxruntime {onnxruntime.__version__} runs the graph {how}"))
    return parity


def ort_session(path: Path):
    import onnxruntime as ort

    so = ort.SessionOptions()
    so.intra_op_num_threads = 1
    so.log_severity_level = 3
    return ort.InferenceSession(str(path), so, providers=["CPUExecutionProvider"])
