"""Export the network to ONNX (torch.onnx), checked for parity against torch right after export.

Only exporting happens here: the one fit (:mod:`sonicskin.fit`) trains, chooses and assembles the artifact (every
other kind exports itself, :mod:`sonicskin.kinds`)."""

from __future__ import annotations

import contextlib
import io
import logging
import warnings
from pathlib import Path

import numpy as np
import torch

from sonicskin.kinds.net import touch_logit
from sonicskin.parity import decisions_parity, ort_session, parity_bound, require_parity

__all__ = ["export_net"]


def export_net(model: torch.nn.Module, path: Path, X_check: np.ndarray) -> dict:
    """torch -> ONNX with a dynamic batch axis (the TorchScript exporter: 0.1 s against 3-7 s for dynamo), then
    :func:`sonicskin.parity.decisions_parity` on ``X_check``; a mismatch raises :class:`~sonicskin.parity.ParityError`."""
    model = model.eval()
    example = torch.from_numpy(X_check[:2].astype(np.float32))
    onnx_log = logging.getLogger("torch.onnx")
    level = onnx_log.level
    onnx_log.setLevel(logging.ERROR)  # "torchvision is not installed. Skipping ..."
    # the TorchScript exporter's deprecation notice and progress lines
    with warnings.catch_warnings(), contextlib.redirect_stdout(io.StringIO()):
        warnings.simplefilter("ignore")
        torch.onnx.export(model, (example,), str(path), input_names=["features"], output_names=["logits", "force"],
                          dynamic_axes={"features": {0: "batch"}, "logits": {0: "batch"}, "force": {0: "batch"}},
                          dynamo=False, opset_version=17)
    onnx_log.setLevel(level)
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

    parity = decisions_parity({"logits": logits, "force_n": force}, {"logits": ref_logits, "force_n": ref_force},
                              label="logits", label_cols=slice(0, -1), touch=(touch_logit(logits), touch_logit(ref_logits)),
                              vote_tie=tie, every_chirp=("force_n",))
    return require_parity(parity, "net.onnx", "the torch network", len(X_check),
                          f"torch {torch.__version__} exported differently; reinstall the tested versions (pip install -c "
                          f"constraints.txt -e '.[train]') and export again")
