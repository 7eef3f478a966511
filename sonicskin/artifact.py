"""Deployment artifacts (ONNX + ``skin.json``): writing the document, its seal and the atomic swap, and reading an
artifact folder's files, bounded and confined.  Torch-free, so ``sonicskin fit-svm`` builds an artifact without torch."""

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
from .artifact_schema import ARTIFACT_FORMAT, ARTIFACT_VERSION, REEXPORT, _check_file_name, _Doc, nonfinite_field, validate_skin
from .dataset import refuse_inside_dataset, swap_folders, unique_keys, write_file
from .errors import ArtifactError
from .integrity import artifact_digest, binding, canonical, check_session, run_probe, stamp_binding
from .jsonio import json_safe
from .parity import ort_session

__all__ = ["ARTIFACT_FORMAT", "PROBE_ROWS", "sha256", "skin_json", "atomic_artifact", "load_skin", "model_file",
           "read_model_file", "read_bounded", "MAX_MODEL_BYTES", "MAX_SKIN_JSON_BYTES"]

PROBE_ROWS = 4


def sha256(path: Path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def _default_probe(n_in: int) -> np.ndarray:
    """Probe inputs when the writer passes none: relative-dB-like values from a fixed seed."""
    return np.random.default_rng(0).normal(0.0, 3.0, size=(PROBE_ROWS, n_in)).astype(np.float32)


def skin_json(out: Path, *, rig: dict, layout: dict, spec, min_force_n: float, training: dict, models: dict,
              probe_inputs: np.ndarray | None = None, selection: dict | None = None, drift: dict | None = None) -> dict:
    """Write ``out/skin.json`` checked against :mod:`sonicskin.artifact_schema`, then sealed: each ONNX file its binding,
    each entry the file's sha256 and ``probe`` (real model inputs where given: an RBF SVM is flat far from its data)."""
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
    """Write an artifact into a new sibling folder, then swap it in; ``out`` may be absent, empty or an artifact folder."""
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


# -- reading
MAX_MODEL_BYTES = 256 * 2**20  # an SVM of 31 locations x 300 bins is a few MB; a net < 1 MB
MAX_SKIN_JSON_BYTES = 64 * 2**20


def load_skin(folder: str | Path) -> dict:
    """Read and validate ``folder/skin.json`` (no duplicate keys; a NaN or Infinity is refused by the field that holds it)."""
    folder = Path(folder)
    path = folder / "skin.json"
    if not path.is_file():
        raise ArtifactError(f"{folder} is not a sonicskin artifact (skin.json missing); create one with "
                            f"`sonicskin export` or `sonicskin fit-svm`")
    raw = read_bounded(path, MAX_SKIN_JSON_BYTES, "an artifact's metadata")
    try:
        meta = json.loads(raw.decode("utf-8"), object_pairs_hook=unique_keys)
    except (ValueError, RecursionError) as e:  # JSONDecodeError and UnicodeDecodeError are ValueErrors
        raise ArtifactError(f"{path} is corrupt ({str(e).splitlines()[0][:120]}); {REEXPORT}") from None
    return validate_skin(meta, source=str(path))


def read_bounded(path: Path, limit: int, what: str) -> bytes:
    """The bytes of ``path``, refused by its size before reading (and never more than ``limit`` read)."""
    size = path.stat().st_size
    if size > limit:
        raise ArtifactError(f"{path} is {size / 2**20:,.0f} MB, more than {what} can be ({limit / 2**20:.0f} MB at most); "
                            f"{REEXPORT}")
    with open(path, "rb") as fh:
        data = fh.read(limit + 1)
    if len(data) > limit:  # grew while being read
        raise ArtifactError(f"{path} is larger than {what} can be ({limit / 2**20:.0f} MB at most); {REEXPORT}")
    return data


def model_file(folder: str | Path, meta: dict, model: str) -> Path:
    """Path of ``model``'s ONNX file, confined to ``folder`` (a symlink may not lead out of it)."""
    folder = Path(folder)
    models = meta["models"]
    if model not in models:
        raise ArtifactError(f"model {model!r} is not in the artifact (it has {sorted(models)}); choose one of those "
                            f"with --model")
    doc = _Doc(str(folder / "skin.json"))
    name = _check_file_name(doc, models[model]["file"], f"models.{model}.file")
    path = folder / name
    if path.is_symlink() or path.exists():
        try:
            real, root = path.resolve(strict=True), folder.resolve()
        except (OSError, RuntimeError) as e:  # a symlink loop (RuntimeError before Python 3.13), a dangling link
            doc.fail(f"models.{model}.file", f"({name}) is a link that leads nowhere ({type(e).__name__}: "
                                             f"{' '.join(str(e).split())[:80]})",
                     "copy the model file into the artifact folder instead of linking it")
        if real.parent != root:
            doc.fail(f"models.{model}.file", f"({name}) is a link to {real}, outside the artifact folder",
                     "copy the model file into the artifact folder instead of linking it")
    if not path.exists():
        raise ArtifactError(f"{path} is missing; copy the whole artifact folder or {REEXPORT}")
    if not path.is_file():
        raise ArtifactError(f"{path} is not a regular file (a folder, FIFO or device); copy the whole artifact folder or "
                            f"{REEXPORT}")
    return path


def read_model_file(folder: str | Path, meta: dict, model: str) -> bytes:
    """The bytes of ``model``'s ONNX file after the confinement and checksum checks."""
    path = model_file(folder, meta, model)
    data = read_bounded(path, MAX_MODEL_BYTES, "a model file")
    if hashlib.sha256(data).hexdigest() != meta["models"][model]["sha256"]:
        raise ArtifactError(f"{path} does not match its checksum in skin.json: the file is corrupt or was "
                            f"replaced; {REEXPORT}")
    _no_external_data(data, path)
    return data


def _no_external_data(data: bytes, path: Path) -> None:
    """An ONNX file must carry its weights: external data would be read from outside the artifact folder."""
    import onnx

    m = onnx.ModelProto()
    try:
        m.ParseFromString(data)  # the protobuf only: nothing outside the file is read
    except Exception:  # not parseable: onnxruntime reports it when loading
        return
    graphs, ext = [m.graph], []
    while graphs:
        g = graphs.pop()
        ext += [t.name for t in g.initializer if t.data_location == onnx.TensorProto.EXTERNAL]
        for node in g.node:
            for a in node.attribute:
                graphs += ([a.g] if a.HasField("g") else []) + list(a.graphs)
                if a.HasField("t") and a.t.data_location == onnx.TensorProto.EXTERNAL:
                    ext.append(node.name or node.op_type)
    if ext:
        raise ArtifactError(f"{path} keeps weights in external files ({ext[:3]}); an artifact's ONNX files must be "
                            f"self-contained; {REEXPORT}")
