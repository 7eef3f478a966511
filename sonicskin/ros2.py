"""Touch on the robot's own bus, live: :mod:`sonicskin.rosbag`'s messages as ROS 2 topics over DDS (``live --ros2``,
``cyclonedds``) and as Foxglove WebSocket channels on 127.0.0.1 (``live --foxglove``), imported only when asked for.
DDS as a ROS 2 node speaks it (topic ``/x`` is ``rt/x``, type ``pkg/msg/T`` is ``pkg::msg::dds_::T_``); docs/robot-frame.md."""

from __future__ import annotations

import functools
import importlib
import os

from .errors import SonicskinError, brief, is_number
from .rosbag import LATCHED, RELIABLE, Publisher, definition, encode, fields

__all__ = ["DdsPublisher", "FoxglovePublisher", "dds_type", "open_buses", "parse_domain", "FOXGLOVE_PORT"]

FOXGLOVE_PORT = 8765  # Foxglove's default
MAX_DOMAIN = 232  # ROS 2's domain ids (0-101 on every OS; ROS_DOMAIN_ID)


def _need(module: str, option: str, package: str):
    try:
        return importlib.import_module(module)
    except ImportError as e:
        raise SonicskinError(f"{option} needs {package} ({str(e).splitlines()[0][:100]}): pip install 'sonicskin[ros]'") from None


@functools.cache
def dds_type(name: str):
    """The cyclonedds type of ROS 2 message ``pkg/msg/Type`` (or ``pkg/Type``), named ``pkg::msg::dds_::Type_`` as rosidl names it."""
    from cyclonedds.idl import make_idl_struct
    from cyclonedds.idl import types as t

    prim, out = {"bool": bool, "string": str, "byte": t.uint8, "char": t.uint8}, {}
    for typ, field, arr in fields(name):
        ft = prim.get(typ) or (dds_type(typ) if "/" in typ else getattr(t, typ))
        out[field] = ft if arr is None else t.sequence[ft] if arr == "" else t.array[ft, int(arr)]
    pkg, typ = name.replace("/msg/", "/").split("/")
    return make_idl_struct(typ, f"{pkg}::msg::dds_::{typ}_", out)


def parse_domain(text) -> int:
    """``--ros2 [DOMAIN]``: the domain id given, else ``ROS_DOMAIN_ID``, else 0; one line naming the fix otherwise."""
    given = text is not None and text is not True
    v = text if given else os.environ.get("ROS_DOMAIN_ID", "").strip() or 0
    try:
        d = int(v) if not isinstance(v, (bool, float)) else -1
    except (ValueError, TypeError):
        d = -1
    if not 0 <= d <= MAX_DOMAIN:
        raise SonicskinError(f"{'--ros2 ' + str(text) if given else 'ROS_DOMAIN_ID=' + brief(v)}: a ROS 2 domain id is an "
                             f"integer 0-{MAX_DOMAIN} (0-101 on every OS), the one the robot's nodes use (their ROS_DOMAIN_ID)")
    return d


class DdsPublisher(Publisher):
    """The run's messages as ROS 2 topics on DDS domain ``domain`` (module docstring)."""

    kind = "the ROS 2 publisher"

    def __init__(self, domain: int = 0, *, t0_unix_s: float = 0.0, log=None):
        _need("cyclonedds", "--ros2/ros2=", "cyclonedds")
        from cyclonedds.core import DDSException
        from cyclonedds.domain import DomainParticipant

        super().__init__(t0_unix_s=t0_unix_s, log=log)
        self.domain, self.name = domain, f"DDS domain {domain}"
        try:
            self._dp = DomainParticipant(domain)
        except DDSException as e:
            raise SonicskinError(f"--ros2 {domain}: cannot join DDS domain {domain} ({e}); check the DDS configuration "
                                 f"(CYCLONEDDS_URI: docs/robot-frame.md)") from None
        self._writers: dict = {}

    def _send(self, topic: str, typ: str, msg: dict, ns: int, seq: int) -> None:
        self._open(topic, typ)
        self._writers[topic].write(dds_type(typ).deserialize(encode(typ, msg)), timestamp=ns)

    def _open(self, topic: str, typ: str) -> None:
        if topic in self._writers:
            return
        from cyclonedds.pub import DataWriter
        from cyclonedds.qos import Policy, Qos
        from cyclonedds.topic import Topic
        from cyclonedds.util import duration

        reliable = Policy.Reliability.Reliable(duration(milliseconds=100))
        qos = (Qos(reliable, Policy.Durability.TransientLocal, Policy.History.KeepLast(1)) if topic in LATCHED else
               Qos(reliable, Policy.Durability.Volatile, Policy.History.KeepLast(100)) if topic in RELIABLE else
               Qos(Policy.Reliability.BestEffort, Policy.Durability.Volatile, Policy.History.KeepLast(10)))
        self._writers[topic] = DataWriter(self._dp, Topic(self._dp, "rt" + topic, dds_type(typ)), qos=qos)

    def _end(self) -> None:
        self._writers.clear()
        self._dp = None  # cyclonedds deletes the participant and its writers with the last reference


class FoxglovePublisher(Publisher):
    """The run's messages as Foxglove WebSocket channels at :attr:`url` (``ws://127.0.0.1:PORT``; port 0: any free)."""

    kind = "the Foxglove server"

    def __init__(self, port: int = FOXGLOVE_PORT, *, t0_unix_s: float = 0.0, log=None):
        fg = _need("foxglove", "--foxglove/foxglove=", "foxglove-sdk")
        from foxglove.websocket import ServerListener

        super().__init__(t0_unix_s=t0_unix_s, log=log)
        self._fg, self._ctx, self._channels = fg, fg.Context(), {}
        pub = self

        class Relatch(ServerListener):  # a late subscriber to /robot_description or /tf_static gets it again
            def on_subscribe(self, client, channel) -> None:
                with pub._lock:
                    for m in (m for m in pub.static if m[0] == channel.topic):
                        pub._channels[m[0]].log(encode(m[1], m[2]), log_time=m[3])

        try:
            self.server = fg.start_server(name="sonicskin", host="127.0.0.1", port=port, context=self._ctx, server_listener=Relatch())
        except RuntimeError as e:  # FoxgloveError: Failed to bind port: Address already in use
            raise SonicskinError(f"--foxglove {port}: cannot serve on 127.0.0.1:{port} ({str(e).split(': ', 1)[-1]}); pick "
                                 f"another port, or 0 for any free one") from None
        self.url = self.name = f"ws://127.0.0.1:{self.server.port}"

    def _send(self, topic: str, typ: str, msg: dict, ns: int, seq: int) -> None:
        self._open(topic, typ)
        self._channels[topic].log(encode(typ, msg), log_time=ns)

    def _open(self, topic: str, typ: str) -> None:
        if topic not in self._channels:
            schema = self._fg.Schema(name=typ, encoding="ros2msg", data=definition(typ).encode())
            self._channels[topic] = self._fg.Channel(topic, schema=schema, message_encoding="cdr", context=self._ctx)

    def _end(self) -> None:
        self.server.stop()


def open_buses(ros2=None, foxglove=None) -> list[Publisher]:
    """The live publishers asked for: ``ros2`` a domain id (``True``: ROS_DOMAIN_ID), ``foxglove`` a port (``True``: 8765)."""
    port = FOXGLOVE_PORT if foxglove is True else int(foxglove) if isinstance(foxglove, str) and foxglove.isdigit() else foxglove
    if foxglove is not None and not (is_number(port, integer=True) and 0 <= port <= 65535):
        raise SonicskinError(f"--foxglove {brief(foxglove)}: give a TCP port 1-65535 (or 0 for any free one, or --foxglove "
                             f"alone for Foxglove's {FOXGLOVE_PORT})")
    buses = [DdsPublisher(parse_domain(ros2))] if ros2 is not None else []
    try:
        if foxglove is not None:
            buses.append(FoxglovePublisher(port))
    except BaseException:
        for b in buses:
            b.close()
        raise
    return buses
