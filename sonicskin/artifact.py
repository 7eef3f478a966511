"""Writing deployment artifacts (ONNX + ``skin.json``): the document, its seal and the atomic swap.

Each model kind exports its own graph (:mod:`sonicskin.kinds`); everything about the metadata and checksums is here,
torch-free, so a machine without torch can still build an artifact from a recording (``sonicskin fit-svm``).
"""

from __future__ import annotations

import contextlib
import glob
import hashlib
import json
import os
import re
import shutil
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from . import __version__, kinds
from .artifact_files import model_file
from .artifact_schema import ARTIFACT_FORMAT, ARTIFACT_VERSION, nonfinite_field, validate_skin
from .dataset import refuse_inside_dataset, swap_folders, write_file
from .errors import ArtifactError
from .integrity import artifact_digest, binding, canonical, check_session, run_probe, stamp_binding
from .jsonio import json_safe
from .parity import ort_session

__all__ = ["ARTIFACT_FORMAT", "PROBE_ROWS", "sha256", "skin_json", "atomic_artifact"]

PROBE_ROWS = 4


def sha256(path: Path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def _default_probe(n_in: int) -> np.ndarray:
    """Probe inputs when the writer passes none: relative-dB-like values from a fixed seed."""
    return np.random.default_rng(0).normal(0.0, 3.0, size=(PROBE_ROWS, n_in)).astype(np.float32)


def skin_json(out: Path, *, rig: dict, layout: dict, spec, min_force_n: float, training: dict, models: dict,
              probe_inputs: np.ndarray | None = None, selection: dict | None = None, drift: dict | None = None) -> dict:
    """Write ``out/skin.json`` (``models``: name -> entry; ``drift``: drift tracking's training reference), checked
    against :mod:`sonicskin.artifact_schema` and every ONNX file against it first, then sealed: each ONNX file gets
    its binding in its ``metadata_props``, each entry the file's sha256 and ``probe`` (``probe_inputs`` rows, real
    model inputs: an RBF SVM is flat far from its data; else the earlier probe rows, else seeded random rows, and the
    outputs on them), the document its ``digest``.
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
                for g, w in zip(got, kinds.get(name).outputs(entry["n_locations"]))]
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
    as it was (the old, loadable artifact, or nothing; :func:`sonicskin.dataset.swap_folders`).  ``out`` may be
    absent, empty, or an artifact folder (``skin.json`` and ONNX files only); anything else in it is refused.
    """
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
        swap_folders(tmp, out)
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
