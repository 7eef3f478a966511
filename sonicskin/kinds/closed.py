"""What the closed-form kinds (the SVM, the LDA) fit around their scores: Alg. 2's training reference, the touch
detector's threshold and the force model, all on the training chirps (the entry their :class:`~sonicskin.head.ScoreHead`
reads)."""

from __future__ import annotations

import numpy as np

from ..calibration import TouchDetector
from ..force import POOLED, PerLocationForce, energy_db
from ..head import DETECTOR_BINS, DETECTORS, touch_statistic

__all__ = ["score_entry", "check_score_entry", "SCORE_KEYS"]

#: the entry fields of a closed-form kind (sonicskin.artifact_schema checks them with :func:`check_score_entry`)
SCORE_KEYS = frozenset({"reference_scores", "threshold", "detector", "detector_bins", "detection", "energy_ref_db",
                        "train_false_touch_rate", "train_missed_touch_rate", "force"})


def score_entry(S: np.ndarray, X: np.ndarray, cls: np.ndarray, force: np.ndarray, quiet: np.ndarray, *, n_locations: int,
                location_ids, force_model: str = "fourier1", force_alpha: float = 10.0, force_cols: int | None = None,
                detector: str = "input-rms") -> dict:
    """The ``skin.json`` fields of a closed-form head from its scores ``S`` (n, K) on the training chirps ``X``:
    Alg. 2's reference scores, the ``detector``'s threshold (Youden's J) and the force model (``force_cols`` inputs);
    without rest, no reference and no detector (``detection: false``)."""
    touch = cls < n_locations
    V = np.column_stack([S, np.asarray(X, np.float64)])
    rest = quiet.sum() >= 2 and (~touch).any()
    ref = V[quiet].mean(axis=0) if rest else np.zeros(V.shape[1])
    n_det = min(DETECTOR_BINS, X.shape[1])
    stat = touch_statistic(V - ref, n_locations, n_det, detector=detector)[:, None]
    det = TouchDetector().fit(stat[touch], stat[~touch]) if rest else None
    all_bins = np.arange(X.shape[1])
    e_ref = float(energy_db(X[quiet], all_bins).mean()) if rest else 0.0
    ids = np.asarray(location_ids)
    has_f = touch & np.isfinite(force)  # recordings without a force sensor carry NaN forces
    if has_f.sum() >= 8 and len(np.unique(cls[has_f])) == n_locations and np.ptp(force[has_f]) > 0:
        if force_model in POOLED:  # over the first force_cols inputs and (the ridge) the location
            k = X.shape[1] if force_cols is None else min(int(force_cols), X.shape[1])
            fm = POOLED[force_model](*([force_alpha] if force_model == "pooled-ridge" else [])).fit(
                X[has_f][:, :k], force[has_f], ids[cls[has_f]]).padded(X.shape[1])
        else:
            fm = PerLocationForce(force_model).fit(energy_db(X[has_f], all_bins) - e_ref, force[has_f], ids[cls[has_f]])
    else:
        fm = PerLocationForce("fourier1")  # no force sensor (or a constant force): force is absent (NaN), never 0 N
        fm.curves_ = {}
    return {"reference_scores": ref.tolist(), "threshold": det.threshold_ if rest else 0.0, "detector": detector,
            "detector_bins": n_det, "detection": bool(rest), "energy_ref_db": e_ref,
            "train_false_touch_rate": det.false_touch_rate_ if rest else None,
            "train_missed_touch_rate": det.missed_touch_rate_ if rest else None, "force": fm.to_dict()}


def check_score_entry(doc, m: dict, f: str, *, n_in: int, layout_ids: list) -> None:
    """The closed-form fields of entry ``m`` (at ``f``, e.g. ``models.svm``)."""
    n_loc = len(layout_ids)
    if n_loc < 2:
        doc.fail(f"{f}.n_locations", "must be >= 2 for a closed-form model (it separates locations)")
    ref = doc.list(doc.get(m, "reference_scores", f), f"{f}.reference_scores")
    if len(ref) != n_loc + n_in:
        doc.fail(f"{f}.reference_scores", f"has {len(ref)} values, expected n_locations + n_in = {n_loc} + {n_in} = "
                                          f"{n_loc + n_in}")
    for i, v in enumerate(ref):
        doc.num(v, f"{f}.reference_scores[{i}]", lo=-doc.MAX_SCORE, hi=doc.MAX_SCORE)
    detection = m.get("detection", True)
    if not isinstance(detection, bool):
        doc.fail(f"{f}.detection", f"must be true or false, got {detection!r}")
    if detection:
        doc.num(doc.get(m, "threshold", f), f"{f}.threshold", lo=0, lo_open=True, hi=doc.MAX_THRESHOLD)
    elif doc.get(m, "threshold", f) != 0:  # trained on touches only: every chirp is taken as a touch
        doc.fail(f"{f}.threshold", "must be 0 when detection is false (a model trained on touches only)")
    doc.choice(doc.get(m, "detector", f), f"{f}.detector", DETECTORS)
    if "detector_bins" in m:  # the detector reads the first detector_bins inputs (default: all)
        doc.int(m["detector_bins"], f"{f}.detector_bins", lo=1, hi=n_in)
    doc.num(doc.get(m, "energy_ref_db", f), f"{f}.energy_ref_db", lo=-doc.MAX_SCORE, hi=doc.MAX_SCORE)
    for k in ("train_false_touch_rate", "train_missed_touch_rate"):
        if k in m and not (m[k] is None and not detection):
            doc.num(m[k], f"{f}.{k}", lo=0, hi=1)
    doc.force(doc.get(m, "force", f), f"{f}.force", layout_ids, n_in)
