"""Writing deployment artifacts (ONNX + ``skin.json``) without torch.

``export/onnx.py`` adds the network; everything about the SVM, the metadata and checksums is
here, so a machine without torch can still build an SVM-only artifact from a recording
(``sonicskin fit-svm``), as the paper's system does.
"""

from __future__ import annotations

import contextlib
import ctypes
import glob
import hashlib
import json
import os
import re
import shutil
import sys
import warnings
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from . import __version__
from .artifact_files import model_file
from .artifact_schema import ARTIFACT_FORMAT, ARTIFACT_VERSION, nonfinite_field, probe_widths, validate_skin
from .dataset import write_file
from .errors import ArtifactError
from .head.heads import ovr_scores_from_ovo
from .head.heads import pairwise as _pairwise
from .integrity import artifact_digest, binding, canonical, check_session, run_probe, stamp_binding
from .jsonio import json_safe

__all__ = ["ARTIFACT_FORMAT", "PARITY_TOL", "ParityError", "parity_bound", "decisions_parity", "require_parity", "sha256",
           "ort_session",
           "export_svm", "skin_json", "atomic_artifact"]

#: Export parity (issue 27.1).  The exported graph runs in float32 in onnxruntime, the original in torch (float32) or
#: scikit-learn (float64): their outputs differ by rounding that grows with the size of the values (a network's
#: log-probabilities reach -100 and more, an SVM's decision values tens).  What must agree is what the artifact
#: decides: the location (argmax), the touch decision, and the continuous outputs (scores or logits, force) to
#: within ``PARITY_TOL`` x the output's scale (its largest magnitude on the check chirps, at least 1).  A chirp whose
#: decision the original makes by less than that bound (a near tie) may go either way and is counted, not judged.
#: A fixed 1e-4 on raw logits failed valid exports at 1.05e-4 (the README's WAV walkthrough, issue 27).
PARITY_TOL = 1e-3
PROBE_ROWS = 4


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

    The location label is the argmax of output ``label`` (its columns ``label_cols``); ``touch``: the touch decision
    statistic of both (got, ref), a touch where it is >= 0.  Every output ``k`` gets ``max_abs_<k>`` and its bound
    ``<k>_tol`` (:func:`parity_bound` of the reference), ``labels_equal``/``touch_equal`` whether the decisions agree,
    and ``ok`` whether all of it holds.  Two kinds of chirps are judged less strictly:

    - ``near_ties``: the original decides by less than the label output's bound (its two best locations, or its touch
      statistic and 0, that close): rounding may move the decision, so only the outputs are judged there;
    - ``votes_flipped``: chirps of ``vote_tie`` (a pairwise vote within rounding of zero) whose outputs differ beyond
      their bound: the vote went the other way, which moves scores by a whole vote.  Only the outputs named in
      ``every_chirp`` (those a vote cannot move: the force, decision values) are judged there.
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
    """``parity`` (of :func:`decisions_parity`) without its verdict, or :class:`ParityError`: one line
    (:func:`parity_failure`) ending "onnxruntime <version> runs the graph ``how``"."""
    if not parity.pop("ok"):
        import onnxruntime

        raise ParityError(parity_failure(what, original, parity, n_checked,
                                         f"onnxruntime {onnxruntime.__version__} runs the graph {how}"))
    return parity


def sha256(path: Path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def ort_session(path: Path):
    import onnxruntime as ort

    so = ort.SessionOptions()
    so.intra_op_num_threads = 1
    so.log_severity_level = 3
    return ort.InferenceSession(str(path), so, providers=["CPUExecutionProvider"])


def export_svm(pipe, n_locations: int, path: Path, X_check: np.ndarray) -> dict:
    """scikit-learn scaler + SVC(ovo) -> ONNX (2 nodes), then parity on ``X_check``: the location the runtime
    reads (argmax of the per-location scores), the scores and the pairwise decision values within
    :data:`PARITY_TOL` of their scale (:func:`decisions_parity`); :class:`ParityError` (one line) otherwise."""
    from skl2onnx import to_onnx
    from sklearn.svm import SVC

    with warnings.catch_warnings():  # skl2onnx reads SVC's deprecated probA_/probB_
        warnings.simplefilter("ignore", FutureWarning)
        onx = to_onnx(pipe, X_check[:1].astype(np.float32), options={SVC: {"zipmap": False}}, target_opset=17)
    # skl2onnx lists the opsets in set order (it changes with PYTHONHASHSEED): sorted, the same inputs give the same bytes
    ops = sorted((o.domain, o.version) for o in onx.opset_import)
    del onx.opset_import[:]
    for domain, version in ops:
        onx.opset_import.add(domain=domain, version=version)
    write_file(path, onx.SerializeToString())
    sess = ort_session(path)
    _, ovo = sess.run(None, {sess.get_inputs()[0].name: X_check.astype(np.float32)})
    ref_ovo = pipe.decision_function(X_check.astype(np.float32))
    S, S_ref = ovr_scores_from_ovo(ovo, n_locations), ovr_scores_from_ovo(ref_ovo, n_locations)
    # The runtime's location is argmax S (votes, ties by confidence).  A pairwise decision within float32 rounding of
    # zero can vote the other way in onnxruntime than in scikit-learn (float64) and move a score by a whole vote:
    # such chirps are near ties, held to their decision values only.
    d, d_ref = _pairwise(ovo, n_locations), _pairwise(ref_ovo, n_locations)
    tie = (np.abs(d_ref) < parity_bound(d_ref)).any(axis=1)
    parity = decisions_parity({"scores": S, "decision": d}, {"scores": S_ref, "decision": d_ref}, label="scores",
                              vote_tie=tie, every_chirp=("decision",))
    import sklearn

    return require_parity(parity, "svm.onnx", "scikit-learn's SVM", len(X_check),
                          f"skl2onnx wrote differently from scikit-learn {sklearn.__version__}; reinstall the package's "
                          f"dependencies (pip install -c constraints.txt -e .) and fit again")


def _default_probe(n_in: int) -> np.ndarray:
    """Probe inputs when the writer passes none: relative-dB-like values from a fixed seed."""
    return np.random.default_rng(0).normal(0.0, 3.0, size=(PROBE_ROWS, n_in)).astype(np.float32)


def skin_json(out: Path, *, rig: dict, layout: dict, spec, min_force_n: float, training: dict, models: dict,
              probe_inputs: np.ndarray | None = None, selection: dict | None = None, drift: dict | None = None) -> dict:
    """Write ``out/skin.json``; ``models`` maps a name to its entry (``file`` and model parameters); ``drift``:
    drift tracking's training reference (:meth:`sonicskin.drift.DriftTracker.to_dict`).

    The document is checked against :mod:`sonicskin.artifact_schema` and every ONNX file against it (input
    width, output shapes) before ``skin.json`` is written, so a writer bug never ships an artifact
    the runtime would refuse.  Then the artifact is sealed (:func:`sonicskin.integrity.check_integrity`
    checks it at load): each ONNX file gets its binding (features, rig, layout, its entry's parameters)
    in its ``metadata_props``, each entry the file's sha256 and ``probe`` (a few ``probe_inputs`` rows
    and the outputs the model gives on them), and the document its ``digest``.  Pass real model inputs as
    ``probe_inputs`` (an RBF SVM is flat far from its data); without them an entry's earlier probe rows are
    kept, else seeded random rows are used.
    """
    out = Path(out)
    skin = {"format": ARTIFACT_FORMAT, "version": ARTIFACT_VERSION, "sonicskin_version": __version__, "rig": rig,
            "layout": layout, "features": spec.to_dict(), "min_force_n": min_force_n,
            "calibration": {"beta_s": spec.beta_s, "alpha_s": spec.alpha_s}, "training": training,
            "models": {k: {kk: vv for kk, vv in e.items() if kk not in ("sha256", "probe")} for k, e in models.items()}}
    if selection:
        skin["selection"] = json_safe(selection)
    if drift:
        skin["drift"] = drift
    old_probes = {k: e["probe"]["inputs"] for k, e in models.items() if isinstance(e.get("probe"), dict) and "inputs" in e["probe"]}
    where = str(out / "skin.json (being written)")
    skin = json.loads(json.dumps(json_safe(skin, keep_nonfinite=True)))  # NaN kept: refused below, naming the field
    # NaN/Infinity are not JSON: refuse rather than write them, naming the field.  The free-form fields (a training
    # option, a time, a parity figure) here; every checked field gets its own message from validate_skin.
    bad = nonfinite_field({"training": skin["training"], "models": {k: {f: e[f] for f in ("hparams", "parity") if f in e}
                                                                    for k, e in skin["models"].items()}})
    if bad is not None:
        raise ArtifactError(f"{out / 'skin.json'} would hold a NaN or infinite value: {bad[0]} is {bad[1]}; pass finite "
                            f"values to the options it came from (model.*, trainer.*) and train or fit again")
    skin = validate_skin(skin, source=where, sealed=False)
    canonical(skin)  # strict JSON (validate_skin refused every NaN/Infinity)
    for name, entry in skin["models"].items():
        path = model_file(out, skin, name)
        stamp_binding(path, binding(skin, name))
        entry["sha256"] = sha256(path)
        sess = ort_session(path)
        check_session(sess, skin, name, source=str(path))
        x = probe_inputs if probe_inputs is not None else old_probes.get(name)  # resealed: keep its real probe rows
        x = np.asarray(x, np.float32)[:PROBE_ROWS] if x is not None else None
        if x is not None and x.ndim == 2 and x.shape[1] > entry["n_in"]:  # a model reads the first n_in inputs
            x = x[:, :entry["n_in"]]
        if x is None or x.ndim != 2 or x.shape[1] != entry["n_in"]:
            x = _default_probe(entry["n_in"])
        got = run_probe(sess, x)
        outs = [None if w is None else np.asarray(g, np.float64).tolist()
                for g, w in zip(got, probe_widths(name, entry["n_locations"]))]
        entry["probe"] = {"inputs": x.astype(np.float64).tolist(), "outputs": outs}
        if name in models:  # the caller's entry too (callers log parity from it)
            models[name].update(sha256=entry["sha256"])
    skin["digest"] = artifact_digest(skin)
    skin = validate_skin(skin, source=where)
    text = json.dumps(skin, indent=1, allow_nan=False)
    tmp = out / "skin.json.tmp"
    write_file(tmp, text)  # a full disk names the file
    tmp.replace(out / "skin.json")
    return skin


ARTIFACT_FILES = re.compile(r"(skin\.json(\.tmp)?|[\w.-]+\.onnx|learning_curve\.png)")


@contextlib.contextmanager
def atomic_artifact(out: str | Path) -> Iterator[Path]:
    """Write an artifact into a new sibling folder, then swap it in: an interrupted or failed run leaves ``out``
    as it was (the old, loadable artifact, or nothing).

    ``out`` may be absent, empty, or an artifact folder (``skin.json`` and ONNX files only); anything else in it
    is refused rather than replaced.  The swap is one ``renameat2(RENAME_EXCHANGE)`` where Linux offers it,
    else two renames (a crash between them keeps the old artifact as ``.<name>.old-<pid>`` beside it).
    """
    from .dataset import refuse_inside_dataset

    out = Path(out)
    refuse_inside_dataset(out, "an artifact")
    if out.exists() or out.is_symlink():
        if out.is_symlink() or not out.is_dir():
            raise ArtifactError(f"{out} exists and is not a folder; choose another --out")
        other = sorted(p.name for p in out.iterdir() if not ARTIFACT_FILES.fullmatch(p.name) or not p.is_file())
        if other:
            raise ArtifactError(f"{out} holds files that are not part of an artifact ({', '.join(other[:3])}); writing the "
                                f"artifact would replace them: choose an empty or new --out")
    out.parent.mkdir(parents=True, exist_ok=True)
    _remove_stale(out)
    tmp = out.parent / f".{out.name}.partial-{os.getpid()}"
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir()
    try:
        yield tmp
        _swap_in(tmp, out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise


def _remove_stale(out: Path) -> None:
    """Leftovers of runs that were killed (their process is gone)."""
    for p in out.parent.glob(f".{glob.escape(out.name)}.partial-*"):
        pid = p.name.rsplit("-", 1)[-1]
        if pid.isdigit() and not _alive(int(pid)):
            shutil.rmtree(p, ignore_errors=True)


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:
        return True
    return True


def _exchange(a: Path, b: Path) -> bool:
    """Swap two paths atomically (Linux renameat2 RENAME_EXCHANGE); False where that is not available."""
    if sys.platform != "linux":
        return False
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        fn = libc.renameat2
    except (OSError, AttributeError):
        return False
    AT_FDCWD, RENAME_EXCHANGE = -100, 2
    return fn(AT_FDCWD, os.fsencode(a), AT_FDCWD, os.fsencode(b), RENAME_EXCHANGE) == 0


def _swap_in(tmp: Path, out: Path) -> None:
    if not out.exists():
        os.rename(tmp, out)
        return
    if _exchange(tmp, out):  # tmp now holds the old artifact
        shutil.rmtree(tmp, ignore_errors=True)
        return
    old = out.parent / f".{out.name}.old-{os.getpid()}"
    shutil.rmtree(old, ignore_errors=True)
    os.rename(out, old)
    os.rename(tmp, out)
    shutil.rmtree(old, ignore_errors=True)
