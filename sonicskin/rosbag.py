"""Touch as ROS 2 messages, the same in the MCAP file and on the live buses (:mod:`sonicskin.ros2`), without ROS.

A :class:`Publisher` makes a run's messages (docs/robot-frame.md); a subclass sends them.  :class:`McapEventWriter`
writes 1 MiB zstd chunks, each closed and flushed after at most a second, so a process killed hard loses at most its
last second (:func:`recover` restores the rest)."""

from __future__ import annotations

import contextlib
import functools
import math
import os
import re
import sys
import threading
import time
import warnings
import weakref
import xml.etree.ElementTree as ET
from collections.abc import Callable
from importlib import resources
from pathlib import Path

import numpy as np

from .errors import SonicskinError, brief, is_number
from .events import TouchEvent
from .surface import pose_matrix

try:
    import fcntl
except ImportError:  # not POSIX: a second writer on one file is not refused
    fcntl = None

__all__ = ["Publisher", "McapEventWriter", "MARKER_TOPIC", "topic_for", "topics", "definition", "encode", "recover", "urdf_joints"]

_SEP = "=" * 80
_PRIMITIVES = set("bool byte char int8 uint8 int16 uint16 int32 uint32 int64 uint64 float32 float64 string".split())
POINT, WRENCH, MARKERS, CONTACT = ("geometry_msgs/msg/PointStamped", "geometry_msgs/msg/WrenchStamped",
                                   "visualization_msgs/msg/MarkerArray", "sonicskin_msgs/msg/Contact")
TF, STRING, JOINTS = "tf2_msgs/msg/TFMessage", "std_msgs/msg/String", "sensor_msgs/msg/JointState"
MARKER_TOPIC = "/sonicskin/markers"
LATCHED = ("/robot_description", "/tf_static")  # sent once, kept for late subscribers (ROS 2: transient local)
RELIABLE = ("/tf", "/joint_states")  # what tf2 and robot_state_publisher read reliably; the rest is a sensor stream
ARROW, SPHERE, ADD, DELETE = 0, 2, 0, 2  # visualization_msgs/Marker constants
ARROW_BASE_M, ARROW_M_PER_N, SPHERE_M = 0.01, 0.02, 0.01
CALIBRATING, FREE, TOUCHED = 0, 1, 2  # sonicskin_msgs/Contact's states
IDLE_S = 0.05  #: while nothing changes a link's Contact goes out at the first chirp this long (of stream) after its last
CHUNK_BYTES, FLUSH_S = 1 << 20, 1.0  # the MCAP file's chunks: at most this big, closed and flushed at least this often


@functools.cache
def _texts() -> dict[str, str]:
    """Each message's own text by ``pkg/Type``: ROS 2's (``msg/ros2.msg``) and ``sonicskin_msgs/Contact``."""
    root = resources.files("sonicskin") / "msg"
    out = dict(b.partition("\n")[::2] for b in (root / "ros2.msg").read_text().split(f"{_SEP}\nMSG: ")[1:])
    out["sonicskin_msgs/Contact"] = (root / "sonicskin_msgs" / "msg" / "Contact.msg").read_text()
    return out


def fields(name: str) -> list[tuple[str, str, str | None]]:
    """The fields of ``pkg/Type`` as ``(type, name, array)``: array None, ``""`` (a sequence) or its length."""
    name = name.replace("/msg/", "/")
    out = []
    for line in _texts()[name].splitlines():
        tok = line.split("#")[0].split()
        if len(tok) < 2 or "=" in tok[1]:  # a blank or comment line, a constant
            continue
        typ, _, arr = tok[0].partition("[")
        out.append((typ if typ in _PRIMITIVES or "/" in typ else f"{name.split('/')[0]}/{typ}", tok[1], arr[:-1] if arr else None))
    return out


def _uses(name: str, seen: dict) -> dict:
    for typ, _, _ in fields(name):
        if typ not in _PRIMITIVES and typ not in seen:
            seen[typ] = None
            _uses(typ, seen)
    return seen


@functools.cache
def definition(name: str) -> str:
    """``name``'s definition as MCAP's ``ros2msg`` schemas hold it: its text, then each type it uses."""
    key = name.replace("/msg/", "/")
    return _texts()[key] + "".join(f"{_SEP}\nMSG: {t}\n{_texts()[t]}" for t in _uses(key, {}))


@functools.cache
def _encoder(name: str) -> Callable[[dict], bytes]:
    from mcap_ros2._dynamic import serialize_dynamic

    return serialize_dynamic(name, definition(name))[name]


def encode(name: str, msg: dict) -> bytes:
    """``msg`` (a dict of its fields; a missing one takes its default) as the CDR bytes a ROS 2 node sends for ``name``."""
    return _encoder(name)(msg)


def topic_for(frame_id: str, what: str) -> str:
    """``/sonicskin/<frame>/<what>``, the frame made a valid ROS name token."""
    tok = re.sub(r"[^A-Za-z0-9_]", "_", frame_id) or "_"
    return f"/sonicskin/{'_' * tok[0].isdigit()}{tok}/{what}"


def _time(ns: int) -> dict:
    return {"sec": ns // 1_000_000_000, "nanosec": ns % 1_000_000_000}


def _xyz(v) -> dict:
    return dict(zip("xyz", (float(a) for a in v)))


# -- the robot: its joints from the URDF, transforms as quaternions (x, y, z, w) ---------------------------------------
def urdf_joints(text: str) -> dict[str, dict]:
    """The joints of a URDF document: name -> ``parent``, ``child``, ``type``, the origin's ``xyz``/``rpy`` and ``axis``."""
    def vec(el, key, default):
        return [float(v) for v in (el.get(key) if el is not None and el.get(key) else default).split()]

    return {j.get("name"): {"parent": j.find("parent").get("link"), "child": j.find("child").get("link"), "type": j.get("type"),
                            "xyz": vec(j.find("origin"), "xyz", "0 0 0"), "rpy": vec(j.find("origin"), "rpy", "0 0 0"),
                            "axis": vec(j.find("axis"), "xyz", "1 0 0")} for j in ET.fromstring(text).findall("joint")}


def _quat(axis, angle: float) -> np.ndarray:
    a = np.asarray(axis, float)
    return np.r_[a / np.linalg.norm(a) * math.sin(angle / 2), math.cos(angle / 2)]


def _qmul(a, b) -> np.ndarray:
    (x1, y1, z1, w1), (x2, y2, z2, w2) = a, b
    return np.array([w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2, w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
                     w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2, w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2])


def _z_to(n) -> np.ndarray:
    """The rotation that takes +z to the unit vector ``n``."""
    q = np.array([-n[1], n[0], 0.0, 1.0 + n[2]])
    return q / np.linalg.norm(q) if q[3] > 1e-9 else np.array([1.0, 0.0, 0.0, 0.0])


def _transform(parent: str, child: str, xyz, q, ns: int) -> dict:
    return {"header": {"stamp": _time(ns), "frame_id": parent}, "child_frame_id": child,
            "transform": {"translation": _xyz(xyz), "rotation": dict(zip("xyzw", map(float, q)))}}


def _joint_tf(j: dict, pos: float, ns: int) -> dict:
    """A joint's transform (parent -> child) at position ``pos`` (rad or m)."""
    r, p, y = j["rpy"]
    q, xyz = _qmul(_qmul(_quat((0, 0, 1), y), _quat((0, 1, 0), p)), _quat((1, 0, 0), r)), np.asarray(j["xyz"])
    if j["type"] in ("revolute", "continuous"):
        q = _qmul(q, _quat(j["axis"], pos))
    elif j["type"] == "prismatic":
        xyz = xyz + pose_matrix(rpy=j["rpy"])[:3, :3] @ np.asarray(j["axis"]) * pos
    return _transform(j["parent"], j["child"], xyz, q, ns)


def topics(frames: list[str]) -> dict[str, str]:
    """Every topic a run of links in ``frames`` sends on, with its type."""
    per_link = (("contact", CONTACT), ("contact_point", POINT), ("contact_wrench", WRENCH))
    return {"/robot_description": STRING, "/tf_static": TF, "/tf": TF, "/joint_states": JOINTS, MARKER_TOPIC: MARKERS,
            **{topic_for(f, what): typ for f in frames for what, typ in per_link}}


class Publisher:
    """The messages of a run, sent by a subclass's ``_send``; thread-safe: the loops of all links share one."""

    name, kind = "sonicskin", "the publisher"  # as errors name it

    def __init__(self, *, t0_unix_s: float, log: Callable[[str], None] | None = None):
        self.written = self.skipped = self.messages = 0  # events written, events without a frame, messages sent
        self.t0_unix_s = t0_unix_s
        self._log = log or (lambda m: warnings.warn(m, stacklevel=3))
        self._seq: dict[str, int] = {}
        self._touching: dict[str, int] = {}  # frame_id -> stamp (ns) of its last touch, while touched
        self._last: dict[str, tuple[float, int]] = {}  # frame_id -> (t_s, state) of its last Contact
        self.static: list[tuple] = []  # the latched messages: (topic, type, msg, ns)
        self._urdf, self._joints, self._pending, self._started = None, {}, None, False
        self._closed = False
        self._lock = threading.Lock()

    @property
    def t0_unix_s(self) -> float:
        """The wall-clock time (UNIX seconds) of the stream's ``t_s = 0``; settable until the first message."""
        return self._t0_ns / 1e9

    @t0_unix_s.setter
    def t0_unix_s(self, t0_unix_s: float) -> None:
        if not (is_number(t0_unix_s) and t0_unix_s >= 0):
            raise SonicskinError(f"t0_unix_s must be the stream start as UNIX seconds (e.g. time.time()), got {brief(t0_unix_s)}")
        if self.messages:
            raise SonicskinError(f"{self.name}: the stream start cannot move once events are written")
        self._t0_ns = round(float(t0_unix_s) * 1e9)

    def _call(self, fn, *args) -> None:
        with self._lock:
            if self._closed:
                raise SonicskinError(f"{self.name}: {self.kind} is closed")
            self._io(fn, *args)

    _io = staticmethod(lambda fn, *args: fn(*args))  # MCAP: the file's errors as one line

    def _put(self, topic: str, typ: str, msg: dict, ns: int) -> None:
        seq = self._seq.get(topic, 0)
        self._send(topic, typ, msg, ns, seq)
        self._seq[topic] = seq + 1
        self.messages += 1

    # -- the robot ----------------------------------------------------------------------------------------------------
    def announce(self, frames: list[str], urdf: str | Path | None = None) -> None:
        """Before the run: open every topic of the links in ``frames`` and read the arm's ``urdf``."""
        if urdf is not None:
            self._urdf = Path(urdf).read_text()
            self._joints = urdf_joints(self._urdf)
        for topic, typ in topics(frames).items():
            self._open(topic, typ)

    _open = _end = staticmethod(lambda *args: None)  # a bus opens a topic's writer or channel; ends

    def start(self) -> None:
        """``/robot_description`` and ``/tf_static`` (every joint at zero) at the stream's start, then the joint state given before it."""
        t = self._t0_ns
        if self._urdf is not None:
            self.static = [("/robot_description", STRING, {"data": self._urdf}, t),
                           ("/tf_static", TF, {"transforms": [_joint_tf(j, 0.0, t) for j in self._joints.values()]}, t)]

        def send():
            for m in self.static:
                self._put(*m)
            self._started = True
            if self._pending:
                self._joint_state(self._pending, t)
        self._call(send)

    def joints(self, positions: dict[str, float], t_unix_s: float | None = None) -> None:
        """``/joint_states`` and ``/tf`` of joints at ``positions`` (rad or m) at ``t_unix_s`` (default: now)."""
        moving = sorted(n for n, j in self._joints.items() if j["type"] in ("revolute", "continuous", "prismatic"))
        if not moving:
            raise SonicskinError("joint states move the joints of the arm's URDF, and this run has none (an arm file with "
                                 "`urdf:` naming a URDF with revolute, continuous or prismatic joints)")
        bad = next((k for k, v in positions.items() if k not in moving or not is_number(v)), None) if isinstance(
            positions, dict) and positions else "?"
        if bad is not None:
            raise SonicskinError(f"joint positions are a dict of joint name -> finite rad (or m) over the URDF's moving "
                                 f"joints {moving}, got {brief(positions)}")
        ns = round((time.time() if t_unix_s is None else t_unix_s) * 1e9)
        self._call(lambda: self._joint_state(positions, ns) if self._started else setattr(self, "_pending", dict(positions)))

    def _joint_state(self, positions: dict, ns: int) -> None:
        names = sorted(positions)
        self._put("/joint_states", JOINTS, {"header": {"stamp": _time(ns)}, "name": names,
                                            "position": [float(positions[n]) for n in names]}, ns)
        self._put("/tf", TF, {"transforms": [_joint_tf(self._joints[n], positions[n], ns) for n in names]}, ns)

    # -- the skin -----------------------------------------------------------------------------------------------------
    def contact(self, lp, t_s: float, p) -> None:
        """The Contact of ``lp``'s link at one chirp: at each touch and change of state, else every :data:`IDLE_S`."""
        state = CALIBRATING if p is None else TOUCHED if lp.touching else FREE  # the loop's press rule
        surf, lay = lp.surface, lp.rt.layout
        last = self._last.get(surf.frame_id)
        if state != TOUCHED and last is not None and last[1] == state and t_s - last[0] < IDLE_S - 1e-9:
            return
        self._last[surf.frame_id] = (t_s, state)
        loc, xy, f, conf = (-1, (math.nan,) * 2, 0.0, 0.0) if p is None else (
            lp.place[0], lp.place[1:], float(p.force_n[0]), float(p.confidence[0]))
        if not np.all(np.isfinite(xy)):  # no centroid: the marker's place (calibrating: the markers' centre)
            xy = lay.coords(np.asarray([loc]))[0] if loc in lay.ids else np.mean(lay.xy_cm, axis=0)
        point, normal = surf.point_normal_one(float(xy[0]), float(xy[1]))
        ns = self._ns(t_s)
        msg = {"header": {"stamp": _time(ns), "frame_id": surf.frame_id}, "link": lp.link_name or surf.frame_id,
               "state": state, "touched": state == TOUCHED, "location": loc, "point": _xyz(point), "normal": _xyz(normal),
               "force_n": f, "force": _xyz(0.0 - f * a for a in normal), "confidence": conf, "model": lp.rt.kind,
               "force_reliable": lp.rt.m.get("force_reliable") is not False and math.isfinite(f)}
        self._call(self._put, topic_for(surf.frame_id, "contact"), CONTACT, msg, ns)

    def _ns(self, t_s: float) -> int:
        return self._t0_ns + round(t_s * 1e9)

    @staticmethod
    def _markers(frame: str, header: dict, action: int, p=None, n=None, force_n: float = math.nan) -> dict:
        ns = f"sonicskin/{frame}"
        base = {"header": header, "ns": ns, "action": action, "lifetime": {"sec": 0, "nanosec": 0}, "frame_locked": True,
                "pose": {"position": _xyz((0, 0, 0)), "orientation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}}}
        if action == DELETE:
            return {"markers": [{**base, "id": 0, "type": ARROW}, {**base, "id": 1, "type": SPHERE}]}
        length = ARROW_BASE_M + ARROW_M_PER_N * (force_n if math.isfinite(force_n) else 0.0)
        tail, tip = _xyz(a + length * b for a, b in zip(p, n)), _xyz(p)
        arrow = {**base, "id": 0, "type": ARROW, "points": [tail, tip], "scale": {"x": 0.003, "y": 0.006, "z": 0.006},
                 "color": {"r": 0.9, "g": 0.2, "b": 0.1, "a": 1.0}}
        sphere = {**base, "id": 1, "type": SPHERE, "pose": {**base["pose"], "position": tip},
                  "scale": {"x": SPHERE_M, "y": SPHERE_M, "z": SPHERE_M}, "color": {"r": 1.0, "g": 0.8, "b": 0.1, "a": 1.0}}
        return {"markers": [arrow, sphere]}

    def write(self, ev: TouchEvent) -> None:
        """Send the messages of one event (nothing, counted in :attr:`skipped`, when it has no robot-frame fields)."""
        self._call(self._write, ev)

    def _write(self, ev: TouchEvent) -> None:
        if ev.frame_id is None or ev.point_m is None or ev.normal is None:
            self.skipped += 1
            if self.skipped == 1:
                self._log(f"warning: {self.name}: an event without the robot-frame fields (no surface for link "
                          f"{ev.link or '(single link)'}) is not written to the MCAP file; give the link a surface "
                          "(frame, URDF) to record it")
            return
        ns, frame = self._ns(ev.t_s), ev.frame_id
        header = {"stamp": _time(ns), "frame_id": frame}
        p, n = [float(a) for a in ev.point_m], [float(a) for a in ev.normal]
        trusted = ev.force_vec_n is not None and ev.force_reliable is not False  # else no wrench, a short arrow
        self._put(topic_for(frame, "contact_point"), POINT, {"header": header, "point": _xyz(p)}, ns)
        self._put("/tf", TF, {"transforms": [_transform(frame, f"{frame}_contact", p, _z_to(n), ns)]}, ns)
        if trusted:  # in the contact frame: the finger pushes along -z, no torque about the point
            self._put(topic_for(frame, "contact_wrench"), WRENCH, {"header": {**header, "frame_id": f"{frame}_contact"},
                      "wrench": {"force": _xyz((0, 0, 0.0 - ev.force_n)), "torque": _xyz((0, 0, 0))}}, ns)
        if ev.kind == "release":
            self._touching.pop(frame, None)
            markers = self._markers(frame, header, DELETE)
        else:
            self._touching[frame] = ns
            markers = self._markers(frame, header, ADD, p, n, ev.force_n if trusted else math.nan)
        self._put(MARKER_TOPIC, MARKERS, markers, ns)
        self.written += 1

    # -- life cycle -------------------------------------------------------------------------------------------------
    def close(self) -> None:
        """Delete the markers of links still touched (no stale contact in a viewer), then end (idempotent)."""
        with self._lock:
            if self._closed:
                return
            try:
                self._io(self._finish)
            finally:
                self._closed = True
                self._end()

    def _finish(self) -> None:
        for frame, ns in sorted(self._touching.items()):
            self._put(MARKER_TOPIC, MARKERS, self._markers(frame, {"stamp": _time(ns), "frame_id": frame}, DELETE), ns)

    def discard(self) -> None:
        """A run that never started: end."""
        self.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()


#: the first bytes of every MCAP file (the MCAP specification's magic, version 0)
MCAP_MAGIC = b"\x89MCAP0\r\n"


def _head(path: Path) -> bytes:
    try:
        with open(path, "rb") as f:
            return f.read(len(MCAP_MAGIC))
    except OSError:
        return b""


class McapEventWriter(Publisher):
    """Write the run's ROS 2 messages into the MCAP file ``path`` (a context manager; an existing file only with ``overwrite``)."""

    kind = "the MCAP writer"

    def __init__(self, path: str | Path, *, t0_unix_s: float, log: Callable[[str], None] | None = None,
                 overwrite: bool = False):
        if not isinstance(path, (str, os.PathLike)) or not str(path):
            raise SonicskinError(f"the MCAP file must be a file path, got {brief(path)}")
        self.path, self.name = Path(path), str(path)
        if self.path.is_dir():
            raise SonicskinError(f"{path} is a directory: give --mcap (mcap=) the path of a file to record into, e.g. "
                                 f"{self.path / 'run.mcap'}")
        super().__init__(t0_unix_s=t0_unix_s, log=log)
        created = not (overwrite and self.path.exists())
        if overwrite and self.path.is_file() and _head(self.path) not in (b"", MCAP_MAGIC):
            raise SonicskinError(f"{path} is not an MCAP recording (an arm file, a skin.json, a URDF?): --overwrite "
                                 f"replaces an earlier recording only; choose another file for --mcap")
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
        self._w = None  # the MCAP writer, started at the first message or at close
        # a writer dropped before it wrote anything (its run failed to start) leaves no empty file behind
        self._abandon = weakref.finalize(self, _abandon, self._file, self.path if created else None)

    def _io(self, fn, *args) -> None:
        """``fn(*args)``; an ``OSError`` (a full disk) closes the writer and is one line naming the file."""
        try:
            if self._w is None:
                self._begin()
            fn(*args)
        except OSError as e:
            self._closed = True
            with contextlib.suppress(OSError):
                self._file.close()
            raise SonicskinError(f"{self.path}: cannot write the MCAP file ({e.strerror or e}); the recording stops here "
                                 f"(free space on its disk, or record to another file)") from None

    def _begin(self) -> None:
        """Truncate the file (an overwritten one) and write the MCAP header."""
        from mcap.writer import CompressionType, IndexType, Writer

        self._abandon.detach()
        if os.fstat(self._file.fileno()).st_size:
            self._file.truncate(0)
        # chunks indexed, messages not (16 bytes a message): every reader finds them by their chunk
        self._w = Writer(self._file, chunk_size=CHUNK_BYTES, compression=CompressionType.ZSTD,
                         index_types=IndexType.ALL & ~IndexType.MESSAGE)
        self._w.start(profile="ros2", library="sonicskin")
        self._ids: dict[str, int] = {}
        self._flushed = (self._t0_ns, time.monotonic())

    def _send(self, topic: str, typ: str, msg: dict, ns: int, seq: int) -> None:
        if typ not in self._ids:
            self._ids[typ] = self._w.register_schema(typ, "ros2msg", definition(typ).encode())
        if topic not in self._ids:
            self._ids[topic] = self._w.register_channel(topic, "cdr", self._ids[typ])
        self._w.add_message(self._ids[topic], log_time=ns, data=encode(typ, msg), publish_time=ns, sequence=seq)
        if ns - self._flushed[0] >= FLUSH_S * 1e9 or time.monotonic() - self._flushed[1] >= FLUSH_S:
            self._w.flush()  # the chunk closed, on disk: a kill loses at most what came after
            self._flushed = (ns, time.monotonic())

    def _finish(self) -> None:
        super()._finish()
        self._w.finish()
        self._file.flush()

    def _end(self) -> None:
        self._file.close()

    def discard(self) -> None:
        """A run that never started: close the file, and remove it when this writer created it and wrote nothing."""
        with self._lock:
            if not self._closed and self._w is None:
                self._closed = True
                self._abandon()
        self.close()


def _abandon(file, created: Path | None) -> None:
    """A writer dropped before its first message: close its file, remove it when the writer created it (still empty)."""
    file.close()
    if created is not None:
        created.unlink(missing_ok=True)


def recover(src: str | Path, dst: str | Path) -> int:
    """Copy the messages of an MCAP file whose writer died into the new complete file ``dst``; returns their number."""
    from mcap.records import Channel, Message, Schema
    from mcap.stream_reader import StreamReader
    from mcap.writer import CompressionType, Writer

    src, dst = Path(src), Path(dst)
    with open(src, "rb") as f:
        if f.read(8) != b"\x89MCAP0\r\n":
            raise SonicskinError(f"{src} is not an MCAP file (no MCAP magic at its start); give the .mcap that `live --mcap` wrote")
    if dst.exists():
        same = src.resolve() == dst.resolve()
        raise SonicskinError(f"{dst} {'is the file to recover from' if same else 'exists'}; give a new OUT file (nothing was changed)")
    n, ids = 0, {}
    tmp = dst.with_name(f".{dst.name}.partial-{os.getpid()}")
    try:
        with open(src, "rb") as f, open(tmp, "wb") as out:
            w = Writer(out, chunk_size=CHUNK_BYTES, compression=CompressionType.ZSTD)
            w.start(profile="ros2", library="sonicskin recover")
            with contextlib.suppress(Exception):  # the cut-off end: a partial record or chunk, whatever the reader says of it
                for r in StreamReader(f, skip_magic=False).records:
                    if isinstance(r, Schema) and ("s", r.id) not in ids:
                        ids["s", r.id] = w.register_schema(r.name, r.encoding, r.data)
                    elif isinstance(r, Channel) and r.id not in ids:
                        ids[r.id] = w.register_channel(r.topic, r.message_encoding, ids.get(("s", r.schema_id), 0), r.metadata)
                    elif isinstance(r, Message):
                        w.add_message(ids[r.channel_id], r.log_time, r.data, r.publish_time, r.sequence)
                        n += 1
            w.finish()
        os.replace(tmp, dst)
    finally:
        tmp.unlink(missing_ok=True)
    return n


if __name__ == "__main__":  # python -m sonicskin.rosbag IN OUT
    if len(sys.argv) != 3 or not Path(sys.argv[1]).is_file():
        sys.exit("usage: python -m sonicskin.rosbag IN.mcap OUT.mcap: recover what a killed writer left in IN into OUT")
    try:
        print(f"{sys.argv[2]}: {recover(*sys.argv[1:])} messages recovered from {sys.argv[1]}")
    except (OSError, SonicskinError) as e:
        why = f"{e.filename}: {e.strerror}; give an OUT in a folder you can write" if isinstance(e, OSError) and e.strerror else e
        sys.exit(f"python -m sonicskin.rosbag: error: {why}")
