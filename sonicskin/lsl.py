"""Touch events as a Lab Streaming Layer stream (optional: ``pip install 'sonicskin[lsl]'``).

LSL is what lab recorders (LabRecorder, XDF files), MNE-LSL, OpenViBE and many robot/EEG
tool-chains already read.  A skin publishes one irregular-rate *string* stream, type
``TouchEvents``, one channel: each sample is one event's JSON (the contract of
:mod:`sonicskin.events`, schema version in the stream's ``desc/schema_version`` and in every
event).  LSL stamps every sample with its own clock (``pylsl.local_clock``) so recordings of
several streams line up; the event's ``t_s`` (stream time of the chirp) is inside the JSON.

pylsl's wheel bundles ``liblsl`` (checked on Linux x86-64, pylsl 1.18.6); no system library needed.
"""

from __future__ import annotations

from .errors import SonicskinError
from .events import SCHEMA_VERSION

__all__ = ["LslSink", "STREAM_TYPE", "import_pylsl"]

STREAM_TYPE = "TouchEvents"


def import_pylsl():
    try:
        import pylsl
    except (ImportError, RuntimeError, OSError) as e:  # pylsl raises RuntimeError when liblsl cannot load
        raise SonicskinError(f"--lsl needs pylsl ({str(e).splitlines()[0][:120]}): pip install 'sonicskin[lsl]'") from None
    return pylsl


class LslSink:
    """Publish event JSON lines on an LSL outlet named ``name``."""

    def __init__(self, name: str = "sonicskin", *, source_id: str | None = None):
        pylsl = import_pylsl()
        info = pylsl.StreamInfo(name, STREAM_TYPE, 1, pylsl.IRREGULAR_RATE, pylsl.cf_string, source_id or f"sonicskin-{name}")
        desc = info.desc()
        desc.append_child_value("schema_version", str(SCHEMA_VERSION))
        desc.append_child_value("format", "one JSON touch event per sample (sonicskin.events)")
        self.outlet = pylsl.StreamOutlet(info)

    def __call__(self, line: str) -> None:
        self.outlet.push_sample([line])
