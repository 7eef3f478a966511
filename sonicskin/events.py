"""The touch-event stream as a contract: one JSON object per line (stdout) or per datagram (UDP).

Every event a running skin emits (``sonicskin live``, :func:`sonicskin.listen`, UDP, LSL) is a
:class:`TouchEvent`; its JSON form is described by :data:`EVENT_SCHEMA` (a JSON Schema, draft
2020-12) and checked by :func:`validate_event`.  The schema carries a version, ``v``: a reader
accepts the major version it knows; fields are only ever *added* within a version, so a reader of
version 1 accepts an event with fields it does not know (a later 1.x writer's), ignores them and
keeps them (:attr:`TouchEvent.extra`, written back by :meth:`TouchEvent.to_json`).

Semantics (version 1)
---------------------
- ``t_s``: stream time in seconds of the chirp's first sample, counted from the first sample the
  audio device delivered (one clock per run; not wall time).  Consecutive chirps are
  ``n_chirp / fs_hz`` apart (106.7 ms on the paper's rig).
- ``kind``: ``"touch"`` for every chirp the detector calls touched; ``"release"`` once, for the
  first untouched chirp after a run of touched ones.  A press of 1 s therefore gives about nine
  ``touch`` events and one ``release``.  A ``release`` carries the last location estimate of the
  chirp it was computed on and ``force_n`` 0.
- ``location``: the id of the most likely marker of the artifact's layout (its ``layout.ids``).
- ``x_cm``, ``y_cm``: the touch position on the *unrolled surface* of the link, in cm, in the
  layout's frame: ``x`` along the circumference (wrapping at ``layout.circumference_cm`` on a tube),
  ``y`` along the link's axis from its end that holds the transmitter.  It is the probability-
  weighted centroid of the three most likely markers, so it lies between markers.
- ``force_n``: the estimated normal force in newtons (0 on ``release``; ``null`` when the
  artifact has no force model).
- ``confidence``: in [0, 1].  Network: the probability of the chosen marker given that there is a
  touch.  SVM: the share of the pairwise (one-vs-one) votes the chosen marker won.  It ranks how
  sure the model is about *where*, not whether there is a touch (the detector decides that).
- ``model``: ``"svm"`` or ``"net"``, the artifact model that produced the event.
- ``latency_ms``: processing time from the chirp's last sample being available to the event.
- ``link`` (optional): the name of the link that sensed it, on a multi-link rig (``sonicskin live
  --links``: the links config's ``name``); absent on a single link.
"""

from __future__ import annotations

import dataclasses
import json
import math
from typing import Any

from .errors import SonicskinError

__all__ = ["SCHEMA_VERSION", "EVENT_SCHEMA", "TouchEvent", "EventError", "validate_event", "parse_event"]

SCHEMA_VERSION = 1


class EventError(SonicskinError):
    """A JSON event that does not follow :data:`EVENT_SCHEMA`."""


_NUM_OR_NULL = {"type": ["number", "null"]}

EVENT_SCHEMA: dict[str, Any] = {
    "$schema": "https://json-schema.org/draft/2020-12/schema",
    "$id": "https://sonicskin.invalid/schemas/touch-event-1.json",
    "title": "sonicskin touch event",
    "type": "object",
    "required": ["v", "t_s", "kind", "location", "x_cm", "y_cm", "force_n", "confidence", "model", "latency_ms"],
    "additionalProperties": True,  # fields are only ever added within a version: a v1 reader ignores (and keeps) them
    "properties": {
        "v": {"const": SCHEMA_VERSION, "description": "schema version"},
        "t_s": {"type": "number", "minimum": 0, "description": "stream time of the chirp's first sample, s"},
        "kind": {"enum": ["touch", "release"]},
        "location": {"type": "integer", "description": "marker id of the artifact's layout"},
        "x_cm": {**_NUM_OR_NULL, "description": "along the circumference of the unrolled surface, cm"},
        "y_cm": {**_NUM_OR_NULL, "description": "along the link axis from the transmitter end, cm"},
        "force_n": {**_NUM_OR_NULL, "minimum": 0, "description": "normal force, N; 0 on release, null: no force model"},
        "confidence": {"type": "number", "minimum": 0, "maximum": 1},
        "model": {"enum": ["svm", "net"]},
        "latency_ms": {"type": "number", "minimum": 0},
        "link": {"type": "string", "description": "the link that sensed it (live --links); absent on a single link"},
    },
}


@dataclasses.dataclass(frozen=True)
class TouchEvent:
    """One event of the stream (see the module docstring for units and frames)."""

    t_s: float
    kind: str             # "touch" | "release"
    location: int
    x_cm: float
    y_cm: float
    force_n: float
    confidence: float
    model: str
    latency_ms: float
    v: int = SCHEMA_VERSION
    link: str | None = None  # the link's name on a multi-link rig (not written when None)
    #: fields of the event this reader does not know (a later writer of the same major version), kept as read
    extra: dict[str, Any] = dataclasses.field(default_factory=dict, hash=False, repr=False)

    def to_dict(self) -> dict[str, Any]:
        d = {f.name: getattr(self, f.name) for f in dataclasses.fields(self) if f.name not in ("extra", "link")}
        for k in ("t_s", "x_cm", "y_cm", "force_n", "confidence", "latency_ms"):
            x = float(d[k])
            d[k] = round(x, 4) if math.isfinite(x) else None
        d["location"] = int(d["location"])
        out = {"v": d.pop("v"), **d}
        if self.link is not None:
            out["link"] = self.link
        return {**out, **{k: v for k, v in self.extra.items() if k not in out}}

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), allow_nan=False)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> TouchEvent:
        """A validated event; fields the schema does not know are kept in :attr:`extra`."""
        validate_event(d)
        known = {k: (math.nan if d[k] is None else d[k]) for k in d if k in EVENT_SCHEMA["properties"]}
        return cls(**known, extra={k: v for k, v in d.items() if k not in EVENT_SCHEMA["properties"]})


def _type_ok(value, types) -> bool:
    types = [types] if isinstance(types, str) else types
    for t in types:
        if t == "null" and value is None:
            return True
        if t == "integer" and isinstance(value, int) and not isinstance(value, bool):
            return True
        if t == "number" and isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value):
            return True
        if t == "string" and isinstance(value, str):
            return True
    return False


def validate_event(d: Any) -> None:
    """Check one decoded event against :data:`EVENT_SCHEMA`; raise :class:`EventError` naming the first problem.

    (The subset of JSON Schema the event schema uses: type, const, enum, minimum, maximum,
    required; no third-party validator needed at run time.)  Fields the schema does not declare are
    accepted (``additionalProperties``: within a version, fields are only ever added).
    """
    if not isinstance(d, dict):
        raise EventError(f"an event is a JSON object, got {type(d).__name__}")
    missing = [k for k in EVENT_SCHEMA["required"] if k not in d]
    if missing:
        raise EventError(f"event lacks {missing}")
    for k, rule in EVENT_SCHEMA["properties"].items():
        if k not in d:  # an optional field (required ones were checked above)
            continue
        x = d[k]
        if "const" in rule and x != rule["const"]:
            raise EventError(f"{k} must be {rule['const']!r}, got {x!r} (a reader for schema v{SCHEMA_VERSION})")
        if "enum" in rule and x not in rule["enum"]:
            raise EventError(f"{k} must be one of {rule['enum']}, got {x!r}")
        if "type" in rule and not _type_ok(x, rule["type"]):
            raise EventError(f"{k} must be {rule['type']}, got {x!r}")
        if isinstance(x, (int, float)) and not isinstance(x, bool):
            if "minimum" in rule and x < rule["minimum"]:
                raise EventError(f"{k} must be >= {rule['minimum']}, got {x!r}")
            if "maximum" in rule and x > rule["maximum"]:
                raise EventError(f"{k} must be <= {rule['maximum']}, got {x!r}")


def parse_event(line: str | bytes) -> TouchEvent:
    """One JSON line or datagram -> :class:`TouchEvent` (validated)."""
    try:
        d = json.loads(line)
    except ValueError as e:
        raise EventError(f"not a JSON event ({e})") from None
    return TouchEvent.from_dict(d)
