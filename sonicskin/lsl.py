"""Touch events as a Lab Streaming Layer stream (optional: ``pip install 'sonicskin[lsl]'``).

One irregular-rate *string* stream, type ``TouchEvents``, one channel: each sample is one event's JSON
(:mod:`sonicskin.events`), the schema version in ``desc/schema_version``; LSL stamps every sample with its own
clock, so recordings of several streams line up.  pylsl's wheel bundles ``liblsl``.
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
