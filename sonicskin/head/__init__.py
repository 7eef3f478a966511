"""One decision path: model outputs -> touch, location, position, force, confidence.

- :class:`Predictions` is the one record of per-chirp decisions (live, replays, every report).
- :class:`SVMHead` and :class:`NetHead` turn what a model computed (the outputs of its ONNX graph) into
  :class:`Predictions`; the SVM head holds Alg. 2's score offset, the touch detector (the input-RMS
  statistic, or the paper's own thresholded calibrated score) and the per-location force curves.
- :class:`Stream` runs one stream chirp by chirp or replays a recording: band features -> the artifact's
  bins -> Alg. 2's running no-touch reference -> model -> head.  ``live``, ``listen()``, ``compare``,
  ``evaluate``, ``seeds`` and ``reproduce`` all go through it (:class:`sonicskin.runtime.SkinRuntime`
  builds one per stream from an artifact).
"""

from .heads import DETECTOR_BINS, DETECTORS, NetHead, SVMHead, make_head, score_vector, touch_statistic
from .predictions import Predictions
from .stream import Stream

__all__ = ["Predictions", "SVMHead", "NetHead", "make_head", "Stream", "score_vector", "touch_statistic",
           "DETECTOR_BINS", "DETECTORS"]
