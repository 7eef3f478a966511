"""One decision path: model outputs -> touch, location, position, force, confidence.

- :class:`Predictions` is the one record of per-chirp decisions (live, replays, every report).
- A model kind's head (:mod:`sonicskin.kinds`) turns what its model computed (the outputs of its ONNX graph) into
  :class:`Predictions`; :class:`ScoreHead` is the closed-form models' (the SVM's, the LDA's): Alg. 2's score offset,
  the touch detector (the input-RMS statistic, or the paper's own thresholded calibrated score) and the force model.
- :class:`Stream` runs one stream chirp by chirp or replays a recording: band features -> the artifact's
  bins -> Alg. 2's running no-touch reference -> model -> head.  ``live``, ``listen()``, ``compare``,
  ``evaluate``, ``seeds`` and ``reproduce`` all go through it (:class:`sonicskin.runtime.SkinRuntime`
  builds one per stream from an artifact).
"""

from .heads import DETECTOR_BINS, DETECTORS, ScoreHead, input_rms, touch_statistic
from .predictions import Predictions
from .stream import Stream

__all__ = ["Predictions", "ScoreHead", "Stream", "touch_statistic", "input_rms", "DETECTOR_BINS", "DETECTORS"]
