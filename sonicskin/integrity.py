"""An artifact's integrity, and whether it fits where it is asked to run.

Every ONNX file carries in its ``metadata_props`` (``sonicskin.binding``) what it was trained with;
:func:`check_integrity` compares that with ``skin.json`` field by field, then the digest, then re-runs the probes."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path
from typing import Any

from . import kinds
from .artifact_schema import REEXPORT, _short
from .errors import ArtifactError, is_number
from .rig import Layout, Rig

__all__ = ["BINDING_KEY", "canonical", "artifact_digest", "binding", "read_binding", "stamp_binding", "run_probe",
           "check_integrity", "check_session", "check_rig", "check_layout"]

BINDING_KEY = "sonicskin.binding"
PROBE_RTOL = PROBE_ATOL = 1e-3  # onnxruntime on another CPU may round differently; another model differs by far more
_UNBOUND = {"file", "sha256", "parity", "probe"}  # entry keys written after the model file (not in its binding)
RESTORE = "restore the artifact folder as it was exported, or " + REEXPORT


def canonical(obj: Any) -> bytes:
    """One byte string per JSON value: sorted keys, no spaces, ASCII, no NaN (a ``ValueError``)."""
    return json.dumps(obj, sort_keys=True, separators=(",", ":"), ensure_ascii=True, allow_nan=False).encode("ascii")


def artifact_digest(meta: dict) -> str:
    """sha256 of the canonical document without ``digest`` and of every model file's sha256."""
    body = {k: v for k, v in meta.items() if k != "digest"}
    models = body.get("models") if isinstance(body.get("models"), dict) else {}
    files = b"".join(f"{k}={m.get('sha256') if isinstance(m, dict) else None}\n".encode() for k, m in sorted(models.items()))
    return hashlib.sha256(b"sonicskin-artifact/2\0" + canonical(body) + b"\0" + files).hexdigest()


def binding(meta: dict, model: str) -> dict:
    """What ``model`` was trained and exported with, as stored inside its ONNX file (``metadata_props``)."""
    entry = {k: v for k, v in meta["models"][model].items() if k not in _UNBOUND}
    return {"model": model, "kind": kinds.get(model).graph, "rig": meta["rig"], "layout": meta["layout"],
            "features": meta["features"], "min_force_n": meta["min_force_n"], "split": meta["training"]["split"],
            "entry_sha256": hashlib.sha256(canonical(entry)).hexdigest()}


def _describe_order(have: list, want: list, what: str) -> str:
    """How the list in skin.json (``have``) differs from the model's (``want``)."""
    if len(have) != len(want):
        return f"{len(have)} {what} listed, the model has {len(want)}"
    def order(v):  # numbers by value (bins, ids), anything else after them by its text
        return (0, v, "") if is_number(v, finite=False) else (1, 0, repr(v))
    if sorted(have, key=order) == sorted(want, key=order):
        if have == sorted(want, key=order) and have != want:
            return f"the model's {what} sorted"
        if have == want[::-1]:
            return f"the model's {what} reversed"
        diff = [i for i, (a, b) in enumerate(zip(have, want)) if a != b]
        return (f"the model's {what} in another order: {len(diff)} positions differ, first index {diff[0]} "
                f"({have[diff[0]]} where the model has {want[diff[0]]})")
    extra = [(i, a) for i, a in enumerate(have) if a not in want]
    i, a = extra[0]
    return f"{len(extra)} not among the model's, first {a} at index {i} where the model has {want[i]}"


def _binding_diff(have: dict, want: dict, file: str) -> tuple[str, str] | None:
    """The first field where skin.json (``want``, from the document) and the model's binding (``have``) differ."""
    if have.get("model") != want["model"] or have.get("kind") != want["kind"]:
        return (f"models.{want['model']}.file", f"({file}) is the {have.get('model')!r} model of an artifact "
                                                f"({have.get('kind')}), not its {want['model']!r} ({want['kind']})")
    hf = have.get("features") if isinstance(have.get("features"), dict) else {}
    wf = want["features"]
    if hf.get("bins") != wf["bins"]:
        return "features.bins", (f"are not the bins {file} was trained with "
                                 f"({_describe_order(wf['bins'], list(hf.get('bins') or []), 'bins')})")
    for k in ("mode", "beta_s", "alpha_s"):
        if hf.get(k) != wf.get(k):
            return f"features.{k}", f"is {wf.get(k)!r} but {file} was trained with {hf.get(k)!r}"
    if hf != wf:
        return "features", f"has other keys than {file} was trained with"
    if have.get("rig") != want["rig"]:
        hr = have.get("rig") if isinstance(have.get("rig"), dict) else {}
        wr = want["rig"]
        keys = sorted(k for k in set(hr) | set(wr) if hr.get(k) != wr.get(k))
        what = ", ".join(f"{k}: {_short(wr.get(k), 24)} vs {_short(hr.get(k), 24)}" for k in keys[:3])
        return "rig", f"differs from the rig {file} was trained on ({what})"
    hl = have.get("layout") if isinstance(have.get("layout"), dict) else {}
    wl = want["layout"]
    if hl.get("ids") != wl["ids"]:
        return "layout.ids", (f"are not the location ids {file} was trained with "
                              f"({_describe_order(wl['ids'], list(hl.get('ids') or []), 'ids')})")
    if hl.get("xy_cm") != wl["xy_cm"]:
        hxy = hl.get("xy_cm") if isinstance(hl.get("xy_cm"), list) else []
        bad = [i for i, a in enumerate(wl["xy_cm"]) if i >= len(hxy) or a != hxy[i]] or [0]
        return "layout.xy_cm", (f"differs from the marker positions {file} was trained with (first at location "
                                f"{wl['ids'][bad[0]]}: {wl['xy_cm'][bad[0]]} vs {hxy[bad[0]] if bad[0] < len(hxy) else None} cm)")
    if hl != wl:
        return "layout", f"differs from the layout {file} was trained with (circumference)"
    if have.get("min_force_n") != want["min_force_n"]:
        return "min_force_n", f"is {want['min_force_n']!r} but {file} was trained with {have.get('min_force_n')!r}"
    if have.get("split") != want["split"]:
        return "training.split", f"is not the split {file} was trained on (the test sessions would include training ones)"
    if have.get("entry_sha256") != want["entry_sha256"]:
        return (f"models.{want['model']}", f"holds other parameters than were exported with {file} (threshold, reference "
                                           f"scores, force curves, hparams, n_in or n_locations changed)")
    if have != want:
        return "the document", f"does not match the binding inside {file}"
    return None


def read_binding(data: bytes) -> dict | None:
    """The binding stored in an ONNX file's ``metadata_props`` (``None``: none, or not parseable)."""
    import onnx

    m = onnx.ModelProto()
    try:
        m.ParseFromString(data)
    except Exception:  # protobuf's DecodeError and friends
        return None
    props = {p.key: p.value for p in m.metadata_props}
    if BINDING_KEY not in props:
        return None
    try:
        b = json.loads(props[BINDING_KEY])
    except (ValueError, RecursionError):
        return None
    return b if isinstance(b, dict) else None


def stamp_binding(path: Path, b: dict) -> None:
    """Store binding ``b`` in the ONNX file at ``path`` (replacing an older one); the graph is unchanged."""
    import onnx

    m = onnx.ModelProto()
    m.ParseFromString(Path(path).read_bytes())
    keep = [(p.key, p.value) for p in m.metadata_props if p.key != BINDING_KEY]
    del m.metadata_props[:]
    for k, v in [*keep, (BINDING_KEY, canonical(b).decode("ascii"))]:
        m.metadata_props.add(key=k, value=v)
    Path(path).write_bytes(m.SerializeToString())


def run_probe(session, inputs) -> list:
    import numpy as np

    return session.run(None, {session.get_inputs()[0].name: np.asarray(inputs, np.float32)})


def check_integrity(session, meta: dict, model: str, data: bytes, *, folder: str | Path) -> None:
    """The model file's binding, the document's digest, and the probes' export-time outputs (within 1e-3), checked."""
    import numpy as np

    folder = Path(folder)
    src = str(folder / "skin.json")
    file = meta["models"][model]["file"]
    have = read_binding(data)
    if have is None:
        raise ArtifactError(f"{folder / file} carries no sonicskin binding (the bins, layout and rig it was trained with): "
                            f"it is not a model this sonicskin exported; {REEXPORT}")
    diff = _binding_diff(have, binding(meta, model), file)
    if diff:
        raise ArtifactError(f"{src}: {diff[0]} {diff[1]}; {RESTORE}")
    if artifact_digest(meta) != meta["digest"]:
        raise ArtifactError(f"{src} was changed after export: its digest does not match its content; {RESTORE}")
    probe = meta["models"][model]["probe"]
    try:
        got = run_probe(session, probe["inputs"])
    except Exception as e:  # onnxruntime raises its own exception types
        raise ArtifactError(f"{folder / file} fails on its probe inputs ({str(e).splitlines()[0][:120]}); {REEXPORT}") from None
    for k, want in enumerate(probe["outputs"]):
        if want is None:
            continue
        g, w = np.asarray(got[k], np.float64), np.asarray(want, np.float64)
        if g.shape != w.shape or not np.isfinite(g).all() or not np.allclose(g, w, rtol=PROBE_RTOL, atol=PROBE_ATOL):
            why = (f"shape {g.shape} vs {w.shape}" if g.shape != w.shape else "non-finite outputs" if not np.isfinite(g).all()
                   else f"max |difference| {np.abs(g - w).max():.3g}")
            raise ArtifactError(f"{folder / file} does not reproduce the outputs it gave at export on the probe inputs in "
                                f"skin.json (output {k}: {why}): it is not the model this artifact was exported with; {RESTORE}")


def _last_dim(shape) -> int | None:
    return shape[-1] if shape and isinstance(shape[-1], int) else None


def check_session(session, meta: dict, model: str, *, source: str = "") -> None:
    """The ONNX graph of ``model`` against ``skin.json``: input width, output count and widths (declared and probed)."""
    import numpy as np

    n_in = int(meta["models"][model]["n_in"])  # the first n_in of features.bins
    n_loc = len(meta["layout"]["ids"])
    where = source or f"the {model} model"
    ins, outs = session.get_inputs(), session.get_outputs()
    if len(ins) != 1 or ins[0].type != "tensor(float)" or len(ins[0].shape) != 2:
        raise ArtifactError(f"{where} must take one float input (batch, {n_in}), it takes "
                            f"{[(i.type, i.shape) for i in ins]}; {REEXPORT}")
    if ins[0].shape[-1] != n_in:
        raise ArtifactError(f"{where} takes {ins[0].shape[-1]} features but skin.json lists {n_in} bins for it; {REEXPORT}")
    kind = kinds.get(model)
    widths = kind.outputs(n_loc)
    want = {k: n for k, n in enumerate(widths) if n is not None}
    what = kind.output_text(n_loc)
    if len(outs) != len(widths):
        raise ArtifactError(f"{where} has {len(outs)} outputs, expected {what}; {REEXPORT}")
    declared = {k: _last_dim(outs[k].shape) for k in want}
    allowed = {k: (None, n, *kind.declared_widths(k, n_loc)) for k, n in want.items()}
    try:
        got = session.run(None, {ins[0].name: np.zeros((2, n_in), np.float32)})
    except Exception as e:  # onnxruntime raises its own exception types
        raise ArtifactError(f"{where} fails on a probe input ({str(e).splitlines()[0][:120]}); {REEXPORT}") from None
    for k, n in want.items():
        shape = np.shape(got[k])
        if declared[k] not in allowed[k] or len(shape) != 2 or shape != (2, n):
            raise ArtifactError(f"{where} output {outs[k].name!r} has shape {shape} (declared {outs[k].shape}), "
                                f"expected {what}: the model does not fit layout.ids; {REEXPORT}")


def check_rig(meta: dict, rig, *, what: str = "the artifact", here: str = "") -> None:
    """Refuse to run an artifact on a rig it was not trained for (sample rate, chirp, bands)."""
    diffs = Rig.from_dict(meta["rig"]).mismatch(rig)
    if diffs:
        raise ArtifactError(f"{what} was trained for another rig ({'; '.join(diffs)}){f' than {here}' if here else ''}; "
                            f"record and train on this rig, or run with {what}'s rig")


def check_layout(meta: dict, layout, *, what: str = "the artifact", here: str = "the surface here") -> None:
    """Refuse to run an artifact on a marker ``layout`` it was not trained for (other ids, count or positions)."""
    import numpy as np

    mine = Layout.from_dict(meta["layout"])
    if mine.ids != layout.ids:
        def span(ids):
            return f"{len(ids)} locations (ids {ids[0]}..{ids[-1]})" if ids else "no locations"
        order = " in another order" if sorted(mine.ids) == sorted(layout.ids) else ""
        raise ArtifactError(f"{what} was trained for {span(mine.ids)} but {here} has {span(layout.ids)}{order}; "
                            f"record and train on this layout, or use data of {what}'s layout")
    if mine != layout:
        d = float(np.max(np.abs(mine.xy_cm - np.asarray(layout.xy_cm, float)))) if mine.xy_cm.shape == np.shape(layout.xy_cm) \
            else float("nan")
        raise ArtifactError(f"{what}'s markers sit elsewhere than those of {here} (up to {d:.2g} cm apart, or another "
                            f"circumference); record and train on this layout, or use data of {what}'s layout")
