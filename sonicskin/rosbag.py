"""Touch events as ROS 2 messages in an MCAP file (``ros2 bag play FILE``, Foxglove), without ROS installed.

:class:`McapEventWriter` writes each event that carries the robot-frame fields (schema v2,
:func:`sonicskin.events.attach_surface`) as ``/sonicskin/<frame>/contact_point`` (PointStamped),
``/sonicskin/<frame>/contact_wrench`` (WrenchStamped: ``F = -force_n * normal``, torque ``p x F``) and
``/sonicskin/markers`` (MarkerArray: an arrow and a sphere at the point, deleted on a release), CDR-encoded by
``mcap-ros2-support``, stamped ``t0_unix_s + t_s``; the topics: docs/robot-frame.md.  Events without those fields
are counted (:attr:`McapEventWriter.skipped`), with one warning.  Each event's messages close their own chunk and are
flushed, so a process killed hard loses nothing written (``mcap recover`` restores the index); :meth:`close` writes
the summary.  An existing file is refused unless ``overwrite=True``; the file is opened and locked (``flock``) when
the writer is made, written from the first event on, and removed again when the writer is dropped before that.  An
``OSError`` (a full disk) is one line naming the file, and closes the writer.
"""

from __future__ import annotations

import contextlib
import math
import os
import re
import threading
import warnings
import weakref
from collections.abc import Callable
from pathlib import Path

from .errors import SonicskinError, brief
from .events import TouchEvent

try:
    import fcntl
except ImportError:  # not POSIX: a second writer on one file is not refused
    fcntl = None

__all__ = ["McapEventWriter", "MARKER_TOPIC", "topic_for"]

# -- the ROS 2 message definitions written, in the concatenated form MCAP's ``ros2msg`` schema encoding takes (the
# type's ``.msg`` text, then each type it uses after a line of 80 ``=`` and ``MSG: pkg/Type``): the field lists of ROS 2
# Humble and later, so ``ros2 bag play`` decodes the CDR bytes with the installed types; comments left out.
_SEP = "=" * 80

_MSGS = {
    "builtin_interfaces/Time": "int32 sec\nuint32 nanosec\n",
    "builtin_interfaces/Duration": "int32 sec\nuint32 nanosec\n",
    "std_msgs/Header": "builtin_interfaces/Time stamp\nstring frame_id\n",
    "std_msgs/ColorRGBA": "float32 r\nfloat32 g\nfloat32 b\nfloat32 a\n",
    "geometry_msgs/Point": "float64 x\nfloat64 y\nfloat64 z\n",
    "geometry_msgs/Vector3": "float64 x\nfloat64 y\nfloat64 z\n",
    "geometry_msgs/Quaternion": "float64 x 0\nfloat64 y 0\nfloat64 z 0\nfloat64 w 1\n",
    "geometry_msgs/Pose": "Point position\nQuaternion orientation\n",
    "geometry_msgs/PointStamped": "std_msgs/Header header\nPoint point\n",
    "geometry_msgs/Wrench": "Vector3 force\nVector3 torque\n",
    "geometry_msgs/WrenchStamped": "std_msgs/Header header\nWrench wrench\n",
    "sensor_msgs/CompressedImage": "std_msgs/Header header\nstring format\nuint8[] data\n",
    "visualization_msgs/UVCoordinate": "float32 u\nfloat32 v\n",
    "visualization_msgs/MeshFile": "string filename\nuint8[] data\n",
    "visualization_msgs/Marker": (
        "int32 ARROW=0\nint32 CUBE=1\nint32 SPHERE=2\nint32 CYLINDER=3\nint32 LINE_STRIP=4\nint32 LINE_LIST=5\n"
        "int32 CUBE_LIST=6\nint32 SPHERE_LIST=7\nint32 POINTS=8\nint32 TEXT_VIEW_FACING=9\nint32 MESH_RESOURCE=10\n"
        "int32 TRIANGLE_LIST=11\nint32 ARROW_STRIP=12\n"
        "int32 ADD=0\nint32 MODIFY=0\nint32 DELETE=2\nint32 DELETEALL=3\n"
        "std_msgs/Header header\nstring ns\nint32 id\nint32 type\nint32 action\ngeometry_msgs/Pose pose\n"
        "geometry_msgs/Vector3 scale\nstd_msgs/ColorRGBA color\nbuiltin_interfaces/Duration lifetime\nbool frame_locked\n"
        "geometry_msgs/Point[] points\nstd_msgs/ColorRGBA[] colors\nstring texture_resource\n"
        "sensor_msgs/CompressedImage texture\nUVCoordinate[] uv_coordinates\nstring text\nstring mesh_resource\n"
        "MeshFile mesh_file\nbool mesh_use_embedded_materials\n"),
    "visualization_msgs/MarkerArray": "Marker[] markers\n",
}

# The types each message uses, directly or not, in the order they are appended.
_DEPS = {
    "geometry_msgs/PointStamped": ["std_msgs/Header", "builtin_interfaces/Time", "geometry_msgs/Point"],
    "geometry_msgs/WrenchStamped": ["std_msgs/Header", "builtin_interfaces/Time", "geometry_msgs/Wrench", "geometry_msgs/Vector3"],
    "visualization_msgs/MarkerArray": [
        "visualization_msgs/Marker", "std_msgs/Header", "builtin_interfaces/Time", "geometry_msgs/Pose", "geometry_msgs/Point",
        "geometry_msgs/Quaternion", "geometry_msgs/Vector3", "std_msgs/ColorRGBA", "builtin_interfaces/Duration",
        "sensor_msgs/CompressedImage", "visualization_msgs/UVCoordinate", "visualization_msgs/MeshFile"],
}


def definition(name: str) -> str:
    """The concatenated definition of ``name`` (``"geometry_msgs/msg/PointStamped"`` or ``"geometry_msgs/PointStamped"``)."""
    key = name.replace("/msg/", "/")
    parts = [_MSGS[key]] + [f"{_SEP}\nMSG: {dep}\n{_MSGS[dep]}" for dep in _DEPS[key]]
    return "".join(parts)


#: the schemas written, by their ROS 2 type name
DEFINITIONS = {t: definition(t) for t in ("geometry_msgs/msg/PointStamped", "geometry_msgs/msg/WrenchStamped",
                                           "visualization_msgs/msg/MarkerArray")}


MARKER_TOPIC = "/sonicskin/markers"
ARROW, SPHERE, ADD, DELETE = 0, 2, 0, 2  # visualization_msgs/Marker constants
ARROW_BASE_M, ARROW_M_PER_N, SPHERE_M = 0.01, 0.02, 0.01


def topic_for(frame_id: str, what: str) -> str:
    """``/sonicskin/<frame>/<what>``, the frame made a valid ROS name token."""
    tok = re.sub(r"[^A-Za-z0-9_]", "_", frame_id) or "_"
    if tok[0].isdigit():
        tok = "_" + tok
    return f"/sonicskin/{tok}/{what}"


def _time(ns: int) -> dict:
    return {"sec": ns // 1_000_000_000, "nanosec": ns % 1_000_000_000}


class McapEventWriter:
    """Write touch events as ROS 2 messages into the MCAP file ``path`` (a context manager); ``t0_unix_s``: the
    wall-clock time of ``t_s = 0``; ``overwrite``: replace an existing file (else refused)."""

    def __init__(self, path: str | Path, *, t0_unix_s: float, log: Callable[[str], None] | None = None,
                 overwrite: bool = False):
        self.written = 0  # events written
        self.t0_unix_s = t0_unix_s
        if not isinstance(path, (str, os.PathLike)) or not str(path):
            raise SonicskinError(f"the MCAP file must be a file path, got {brief(path)}")
        self.path = Path(path)
        created = not (overwrite and self.path.exists())
        try:  # O_EXCL: an existing file (an earlier recording, an arm.yaml) is never replaced unasked
            fd = os.open(self.path, os.O_WRONLY | os.O_CREAT | (0 if overwrite else os.O_EXCL), 0o644)
        except FileExistsError:
            raise SonicskinError(f"{path}: the file exists; pass --overwrite (overwrite=True) to replace it, or choose "
                                 f"another file") from None
        except OSError as e:
            raise SonicskinError(f"{path}: cannot write the MCAP file ({e.strerror})") from None
        try:
            if fcntl is not None:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            os.close(fd)
            raise SonicskinError(f"{path}: another writer is recording into this MCAP file (it holds the file's lock); "
                                 f"give each recording its own file") from None
        self._file = os.fdopen(fd, "wb")
        self._w = None  # the MCAP writer, started at the first event or at close
        # a writer dropped before it wrote anything (its run failed to start) leaves no empty file behind
        self._abandon = weakref.finalize(self, _abandon, self._file, self.path if created else None)
        self._log = log or (lambda m: warnings.warn(m, stacklevel=3))
        self._seq: dict[str, int] = {}
        self._touching: dict[str, int] = {}  # frame_id -> stamp (ns) of its last touch, while touched
        self.skipped = 0  # events without the robot-frame fields
        self.messages = 0
        self._closed = False
        self._lock = threading.Lock()  # one writer for the loops of all links

    @property
    def t0_unix_s(self) -> float:
        """The wall-clock time (UNIX seconds) of the stream's ``t_s = 0``; settable until the first event is written (a
        writer made, and its file claimed, before the stream starts)."""
        return self._t0_ns / 1e9

    @t0_unix_s.setter
    def t0_unix_s(self, t0_unix_s: float) -> None:
        if not (isinstance(t0_unix_s, (int, float)) and math.isfinite(t0_unix_s) and t0_unix_s >= 0):
            raise SonicskinError(f"t0_unix_s must be the stream start as UNIX seconds (e.g. time.time()), got {brief(t0_unix_s)}")
        if self.written:
            raise SonicskinError(f"{self.path}: the stream start cannot move once events are written")
        self._t0_ns = round(float(t0_unix_s) * 1e9)

    # -- messages ---------------------------------------------------------------------------------------------------
    def _start(self) -> None:
        """Truncate the file (an overwritten one) and write the MCAP header and schemas."""
        from mcap.writer import CompressionType
        from mcap_ros2.writer import Writer

        self._abandon.detach()
        if os.fstat(self._file.fileno()).st_size:
            self._file.truncate(0)
        # chunk_size=0: every message closes its chunk; with the flush after each event the file holds all of it
        self._w = Writer(self._file, chunk_size=0, compression=CompressionType.NONE)
        self._schemas = {name: self._w.register_msgdef(name, text) for name, text in DEFINITIONS.items()}

    def _put(self, topic: str, schema: str, msg: dict, ns: int) -> None:
        seq = self._seq.get(topic, 0)
        self._w.write_message(topic, self._schemas[schema], msg, log_time=ns, publish_time=ns, sequence=seq)
        self._seq[topic] = seq + 1
        self.messages += 1

    @staticmethod
    def _markers(frame: str, header: dict, action: int, p=None, n=None, force_n: float = math.nan) -> dict:
        ns = f"sonicskin/{frame}"
        base = {"header": header, "ns": ns, "action": action, "lifetime": {"sec": 0, "nanosec": 0}, "frame_locked": True,
                "pose": {"position": {"x": 0.0, "y": 0.0, "z": 0.0}, "orientation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}}}
        if action == DELETE:
            return {"markers": [{**base, "id": 0, "type": ARROW}, {**base, "id": 1, "type": SPHERE}]}
        length = ARROW_BASE_M + ARROW_M_PER_N * (force_n if math.isfinite(force_n) else 0.0)
        tail = {"x": p[0] + length * n[0], "y": p[1] + length * n[1], "z": p[2] + length * n[2]}
        tip = {"x": p[0], "y": p[1], "z": p[2]}
        arrow = {**base, "id": 0, "type": ARROW, "points": [tail, tip], "scale": {"x": 0.003, "y": 0.006, "z": 0.006},
                 "color": {"r": 0.9, "g": 0.2, "b": 0.1, "a": 1.0}}
        sphere = {**base, "id": 1, "type": SPHERE, "pose": {**base["pose"], "position": tip},
                  "scale": {"x": SPHERE_M, "y": SPHERE_M, "z": SPHERE_M}, "color": {"r": 1.0, "g": 0.8, "b": 0.1, "a": 1.0}}
        return {"markers": [arrow, sphere]}

    def write(self, ev: TouchEvent) -> None:
        """Write the messages of one event (nothing, counted in :attr:`skipped`, when it has no robot-frame fields).
        Thread-safe: the loops of several links may share one writer."""
        with self._lock:
            if self._closed:
                raise SonicskinError(f"{self.path}: the MCAP writer is closed")
            self._io(self._write, ev)

    def _io(self, fn, *args) -> None:
        """``fn(*args)``; an ``OSError`` (a full disk) closes the writer and is one line naming the file."""
        try:
            if self._w is None:
                self._start()
            fn(*args)
        except OSError as e:
            self._closed = True
            with contextlib.suppress(OSError):
                self._file.close()
            raise SonicskinError(f"{self.path}: cannot write the MCAP file ({e.strerror or e}); the recording stops here "
                                 f"(free space on its disk, or record to another file)") from None

    def _write(self, ev: TouchEvent) -> None:
        if ev.frame_id is None or ev.point_m is None or ev.normal is None:
            self.skipped += 1
            if self.skipped == 1:
                self._log(f"warning: {self.path}: an event without the robot-frame fields (no surface for link "
                          f"{ev.link or '(single link)'}) is not written to the MCAP file; give the link a surface "
                          "(frame, URDF) to record it")
            return
        ns = self._t0_ns + round(ev.t_s * 1e9)
        frame = ev.frame_id
        header = {"stamp": _time(ns), "frame_id": frame}
        p, n = [float(a) for a in ev.point_m], [float(a) for a in ev.normal]
        self._put(topic_for(frame, "contact_point"), "geometry_msgs/msg/PointStamped",
                  {"header": header, "point": dict(zip("xyz", p))}, ns)
        if ev.force_vec_n is not None:
            f = [float(a) for a in ev.force_vec_n]
            tau = [p[1] * f[2] - p[2] * f[1], p[2] * f[0] - p[0] * f[2], p[0] * f[1] - p[1] * f[0]]
            self._put(topic_for(frame, "contact_wrench"), "geometry_msgs/msg/WrenchStamped",
                      {"header": header, "wrench": {"force": dict(zip("xyz", f)), "torque": dict(zip("xyz", tau))}}, ns)
        if ev.kind == "release":
            self._touching.pop(frame, None)
            markers = self._markers(frame, header, DELETE)
        else:
            self._touching[frame] = ns
            markers = self._markers(frame, header, ADD, p, n, ev.force_n)
        self._put(MARKER_TOPIC, "visualization_msgs/msg/MarkerArray", markers, ns)
        self._file.flush()
        self.written += 1

    # -- life cycle -------------------------------------------------------------------------------------------------
    def close(self) -> None:
        """Write the file's summary and close it (idempotent).  Links still touched get their markers deleted at their
        last touch's stamp, so a viewer shows no stale contact after the recording ends."""
        with self._lock:
            if self._closed:
                return
            try:
                self._io(self._finish)
            finally:
                self._closed = True
                self._file.close()

    def _finish(self) -> None:
        for frame, ns in sorted(self._touching.items()):
            self._put(MARKER_TOPIC, "visualization_msgs/msg/MarkerArray",
                      self._markers(frame, {"stamp": _time(ns), "frame_id": frame}, DELETE), ns)
        self._w.finish()
        self._file.flush()

    def discard(self) -> None:
        """A run that never started: close the file, and remove it when this writer created it and wrote nothing."""
        with self._lock:
            if not self._closed and self._w is None:
                self._closed = True
                self._abandon()
        self.close()

    def __enter__(self) -> McapEventWriter:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def _abandon(file, created: Path | None) -> None:
    """A writer dropped before its first message: close its file, remove it when the writer created it (still empty)."""
    file.close()
    if created is not None:
        created.unlink(missing_ok=True)
