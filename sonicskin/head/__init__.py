"""One decision path: model outputs -> touch, location, position, force, confidence.

:class:`Predictions` is the one record of per-chirp decisions; a model kind's head turns its ONNX outputs into them;
:class:`Stream` runs one stream chirp by chirp or replays a recording, for every verb alike."""

from .heads import DETECTOR_BINS, DETECTORS, Predictions, ScoreHead, input_rms, touch_statistic
from .stream import Stream

__all__ = ["Predictions", "ScoreHead", "Stream", "touch_statistic", "input_rms", "DETECTOR_BINS", "DETECTORS"]
