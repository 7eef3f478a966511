"""Reading an artifact folder's files, bounded and confined: ``skin.json`` (parsed strictly, then checked against
:mod:`sonicskin.artifact_schema`) and the ONNX model files it names (inside the folder, within a size, matching their
checksums, carrying their own weights).
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

from .artifact_schema import REEXPORT, _check_file_name, _Doc, validate_skin
from .errors import ArtifactError

__all__ = ["load_skin", "model_file", "read_model_file", "read_bounded", "MAX_MODEL_BYTES", "MAX_SKIN_JSON_BYTES"]

MAX_MODEL_BYTES = 256 * 2**20  # an SVM of 31 locations x 300 bins is a few MB; a net < 1 MB
MAX_SKIN_JSON_BYTES = 64 * 2**20


def _no_duplicates(pairs):
    keys = [k for k, _ in pairs]
    if len(set(keys)) != len(keys):
        raise ValueError(f"duplicate key {sorted({k for k in keys if keys.count(k) > 1})[0]!r}")
    return dict(pairs)


def load_skin(folder: str | Path) -> dict:
    """Read and validate ``folder/skin.json`` (no duplicate keys; a NaN or Infinity is refused by the field
    that holds it)."""
    folder = Path(folder)
    path = folder / "skin.json"
    if not path.is_file():
        raise ArtifactError(f"{folder} is not a sonicskin artifact (skin.json missing); create one with "
                            f"`sonicskin export` or `sonicskin fit-svm`")
    raw = read_bounded(path, MAX_SKIN_JSON_BYTES, "an artifact's metadata")
    try:
        meta = json.loads(raw.decode("utf-8"), object_pairs_hook=_no_duplicates)
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
