"""The touch-event stream as a contract: one JSON object per line (stdout) or per datagram (UDP).

Every event a running skin emits is a :class:`TouchEvent`, its JSON form described by :data:`EVENT_SCHEMA` and
checked by :func:`validate_event`.  Fields are only ever added within a version, so a reader keeps the fields it
does not know (:attr:`TouchEvent.extra`).  Units, frames and meanings: docs/api.md and docs/robot-frame.md."""

from __future__ import annotations

import dataclasses
import json
import math
from typing import Any

from .errors import SonicskinError, brief, is_number

__all__ = ["SCHEMA_VERSION", "READS", "EVENT_SCHEMA", "TouchEvent", "EventError", "validate_event", "parse_event",
           "surface_fields", "attach_surface"]

SCHEMA_VERSION = 2
#: the schema versions this reader accepts (version 2 only adds optional fields to version 1)
READS = (1, 2)


class EventError(SonicskinError):
    """A JSON event that does not follow :data:`EVENT_SCHEMA`."""


_NUM_OR_NULL = {"type": ["number", "null"]}
_VEC3 = {"type": "array", "items": {"type": "number"}, "minItems": 3, "maxItems": 3}
_UNIT_TOL = 1e-3  # |normal| within 1 +- this (the JSON keeps 6 decimals)
_OPTIONAL = ("link", "frame_id", "point_m", "normal", "force_vec_n", "force_reliable")  # written only when set

EVENT_SCHEMA: dict[str, Any] = {
    "$schema": "https://json-schema.org/draft/2020-12/schema",
    "$id": "https://sonicskin.invalid/schemas/touch-event-2.json",
    "title": "sonicskin touch event",
    "type": "object",
    "required": ["v", "t_s", "kind", "location", "x_cm", "y_cm", "force_n", "confidence", "model", "latency_ms"],
    "additionalProperties": True,  # fields are only ever added within a version: a reader ignores (and keeps) them
    "properties": {
        "v": {"enum": list(READS), "description": "schema version; 2 adds the optional robot-frame fields"},
        "t_s": {"type": "number", "minimum": 0, "description": "stream time of the chirp's first sample, s"},
        "kind": {"enum": ["touch", "release"]},
        "location": {"type": "integer", "description": "marker id of the artifact's layout"},
        "x_cm": {**_NUM_OR_NULL, "description": "along the circumference of the unrolled surface, cm"},
        "y_cm": {**_NUM_OR_NULL, "description": "along the link axis from the transmitter end, cm"},
        "force_n": {**_NUM_OR_NULL, "minimum": 0, "description": "normal force, N; 0 on release, null: no force model"},
        "confidence": {"type": "number", "minimum": 0, "maximum": 1},
        "model": {"type": "string", "minLength": 1, "pattern": r"\S"},
        "latency_ms": {"type": "number", "minimum": 0},
        "link": {"type": "string", "minLength": 1, "pattern": r"\S",
                 "description": "the link that sensed it (live --links); absent on a single link"},
        "frame_id": {"type": "string", "minLength": 1, "pattern": r"\S",
                     "description": "v2: the link's frame (its URDF link name); absent without a surface"},
        "point_m": {**_VEC3, "description": "v2: contact point [x, y, z] in the link frame, m"},
        "normal": {**_VEC3, "description": "v2: unit outward surface normal [x, y, z] at the point, link frame"},
        "force_vec_n": {"type": ["array", "null"], "items": {"type": "number"}, "minItems": 3, "maxItems": 3,
                        "description": "v2: force of the finger on the link, -force_n * normal, N, link frame; null: no force model"},
        "force_reliable": {"type": "boolean", "description": "false: validation found the link's force no better than a "
                                                             "constant; absent: not validated"},
    },
}


@dataclasses.dataclass(frozen=True)
class TouchEvent:
    """One event of the stream (units and frames: docs/api.md)."""

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
    # v2, the robot's frame (not written when None; see attach_surface)
    frame_id: str | None = None
    point_m: tuple[float, float, float] | None = None
    normal: tuple[float, float, float] | None = None
    force_vec_n: tuple[float, float, float] | None = None
    force_reliable: bool | None = None  # the artifact's verdict on its force (not written when None)
    #: fields of the event this reader does not know (a later writer of the same major version), kept as read
    extra: dict[str, Any] = dataclasses.field(default_factory=dict, hash=False, repr=False)

    def to_dict(self) -> dict[str, Any]:
        d = {f.name: getattr(self, f.name) for f in dataclasses.fields(self) if f.name not in ("extra", *_OPTIONAL)}
        for k in ("t_s", "x_cm", "y_cm", "force_n", "confidence", "latency_ms"):
            x = float(d[k])
            d[k] = round(x, 4) if math.isfinite(x) else None
        d["location"] = int(d["location"])
        out = {"v": d.pop("v"), **d}
        if self.link is not None:
            out["link"] = self.link
        for k in ("frame_id", "force_reliable"):
            if getattr(self, k) is not None:
                out[k] = getattr(self, k)
        for k, nd in (("point_m", 6), ("normal", 6), ("force_vec_n", 4)):
            vec = getattr(self, k)
            if vec is not None:
                out[k] = _vec(vec, nd)
        if self.force_vec_n is None and self.normal is not None:
            out["force_vec_n"] = None  # a surface but no force model
        return {**out, **{k: v for k, v in self.extra.items() if k not in out}}

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), allow_nan=False)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> TouchEvent:
        """A validated event; fields the schema does not know are kept in :attr:`extra`."""
        validate_event(d)
        known = {k: (math.nan if d[k] is None else d[k]) for k in d if k in EVENT_SCHEMA["properties"]}
        for k in ("point_m", "normal", "force_vec_n"):
            if k in known:
                known[k] = None if d[k] is None else tuple(float(a) for a in d[k])
        return cls(**known, extra={k: v for k, v in d.items() if k not in EVENT_SCHEMA["properties"]})


def _vec(v, nd: int) -> list[float] | None:
    x = [float(a) for a in v]
    return [round(a, nd) + 0.0 for a in x] if all(math.isfinite(a) for a in x) else None  # + 0.0: no "-0.0"


def _type_ok(value, types) -> bool:
    types = [types] if isinstance(types, str) else types
    for t in types:
        if t == "null" and value is None:
            return True
        if (t == "integer" and is_number(value, integer=True)) or (t == "number" and is_number(value)):
            return True
        if (t == "string" and isinstance(value, str)) or (t == "boolean" and isinstance(value, bool)):
            return True
        if t == "array" and isinstance(value, list):
            return True
    return False


def validate_event(d: Any) -> None:
    """Check one decoded event against :data:`EVENT_SCHEMA`; an :class:`EventError` names the first problem."""
    if not isinstance(d, dict):
        raise EventError(f"an event is a JSON object, got {type(d).__name__}")
    missing = [k for k in EVENT_SCHEMA["required"] if k not in d]
    if missing:
        raise EventError(f"event lacks {missing}")
    for k, rule in EVENT_SCHEMA["properties"].items():
        if k not in d:  # an optional field (required ones were checked above)
            continue
        x = d[k]
        if k == "v" and (x not in READS or isinstance(x, bool)):
            raise EventError(f"v must be one of {list(READS)}, got {brief(x)} (a reader for schema v{SCHEMA_VERSION}: "
                             "a newer sonicskin reads newer events)")
        if "enum" in rule and x not in rule["enum"]:
            raise EventError(f"{k} must be one of {rule['enum']}, got {brief(x)}")
        if "type" in rule and not _type_ok(x, rule["type"]):
            raise EventError(f"{k} must be {rule['type']}, got {brief(x)}")
        if is_number(x, finite=False):
            if "minimum" in rule and x < rule["minimum"]:
                raise EventError(f"{k} must be >= {rule['minimum']}, got {brief(x)}")
            if "maximum" in rule and x > rule["maximum"]:
                raise EventError(f"{k} must be <= {rule['maximum']}, got {brief(x)}")
        if isinstance(x, str) and "minLength" in rule and not x.strip():  # "" or " ": no name (schema: minLength, pattern)
            raise EventError(f"{k} must be a non-blank string, got {brief(x)}")
        if isinstance(x, list) and (len(x) != rule["minItems"] or not all(_type_ok(a, rule["items"]["type"]) for a in x)):
            raise EventError(f"{k} must be {rule['minItems']} numbers, got {brief(x)}")
    if ("point_m" in d) != ("normal" in d) or ("force_vec_n" in d and "normal" not in d) or ("normal" in d) > ("frame_id" in d):
        raise EventError("point_m and normal come together with the frame_id they are in, force_vec_n only with them "
                         f"(schema v2), got {sorted(k for k in ('frame_id', 'point_m', 'normal', 'force_vec_n') if k in d)}")
    if "normal" in d and abs(math.hypot(*d["normal"]) - 1) > _UNIT_TOL:
        raise EventError(f"normal must be a unit vector, got {brief(d['normal'])} (length {math.hypot(*d['normal']):.4g})")


def parse_event(line: str | bytes) -> TouchEvent:
    """One JSON line or datagram -> :class:`TouchEvent` (validated)."""
    try:
        d = json.loads(line)
    except ValueError as e:
        raise EventError(f"not a JSON event ({e})") from None
    return TouchEvent.from_dict(d)


def surface_fields(surface, x_cm: float, y_cm: float, force_n: float) -> dict[str, Any]:
    """The version-2 fields of a contact at ``(x_cm, y_cm)`` with ``force_n`` on ``surface``."""
    out: dict[str, Any] = {"frame_id": surface.frame_id}
    if not (math.isfinite(x_cm) and math.isfinite(y_cm)):
        return out
    p, normal = surface.point_normal_one(float(x_cm), float(y_cm))
    f = float(force_n) if force_n is not None else math.nan
    out |= {"point_m": p, "normal": normal, "force_vec_n": tuple(-f * a + 0.0 for a in normal) if math.isfinite(f) else None}
    return out


def attach_surface(ev: TouchEvent, surface) -> TouchEvent:
    """``ev`` with the version-2 robot-frame fields of its contact on ``surface`` (``surface=None``: ``ev`` unchanged)."""
    if surface is None:
        return ev
    return dataclasses.replace(ev, v=SCHEMA_VERSION, **surface_fields(surface, ev.x_cm, ev.y_cm, ev.force_n))
