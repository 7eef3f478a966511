"""A live view of the skin in a web browser: the arm in 3D with each touch and its force, each link's surface
unrolled, the last events, the drift state.

:class:`ViewServer` serves one self-contained page (``sonicskin/view.html``, nothing from the internet) on
``127.0.0.1``: ``/`` the page, ``/links.json`` the links' geometry and the arm's URDF (once per load), ``/state.json``
what changes (polled every 100 ms, so ``stop()`` never waits on an open connection).  The live loop's calls copy
into the shared state under a lock, so it never waits on a browser.  Frames: as in :mod:`sonicskin.events`."""

from __future__ import annotations

import dataclasses
import http.server
import ipaddress
import json
import math
import queue
import sys
import threading
import time
import weakref
from collections import deque
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

from .errors import SonicskinError, brief, is_number
from .events import TouchEvent, parse_event
from .rig import Layout

__all__ = ["LinkView", "ViewServer", "loop_status", "attach_view", "view_loops", "parse_view_port", "STATUS_KEYS"]

#: The keys :meth:`ViewServer.set_status` accepts (all optional), with their meaning on the page.
STATUS_KEYS = {
    "refreshes": "references taken (Alg. 2), the boot's included",
    "stretch": "the drift tracker's frequency stretch (None: no drift tracking)",
    "reference_age_s": "stream seconds since the reference in use was taken",
    "chirps": "chirps processed",
    "text": "one short line (e.g. the drift tracker's status, 'calibrating')",
}
N_EVENTS = 10  # the events the page lists
POOL_THREADS = 8  # handler threads of one view (a page polls one short request at a time)
CONN_TIMEOUT_S = 5.0  # a connection that sends no request in this long is closed


def _finite(x) -> float | None:
    try:
        x = float(x)
    except (TypeError, ValueError):
        return None
    return x if math.isfinite(x) else None


@dataclasses.dataclass(frozen=True)
class LinkView:
    """One link as the page draws it: name, layout, kind, surface size and transducers (cm)."""

    name: str
    layout: Layout
    kind: str | None = None
    length_cm: float | None = None
    width_cm: float | None = None
    tx_cm: tuple[float, float] | None = None
    rx_cm: tuple[float, float] | None = None
    surface: Any = None  # the link's LinkSurface: the page draws it in 3D, in its frame

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name.strip():
            raise SonicskinError(f"a link's name must be a non-empty string, got {brief(self.name)}")
        if not isinstance(self.layout, Layout):
            raise SonicskinError(f"link {brief(self.name)}: layout must be a sonicskin.rig.Layout (e.g. SkinRuntime(...).layout), "
                                 f"got {type(self.layout).__name__}")
        kind = self.kind if self.kind is not None else ("tube" if self.layout.circumference_cm else "plate")
        if kind not in ("tube", "plate"):
            raise SonicskinError(f"link {brief(self.name)}: kind must be 'tube' or 'plate', got {brief(kind)}")
        if kind == "tube" and not self.layout.circumference_cm:
            raise SonicskinError(f"link {brief(self.name)} is a tube but its layout has no circumference_cm; give the layout "
                                 f"its circumference or draw the link as kind='plate'")
        object.__setattr__(self, "kind", kind)
        for k in ("length_cm", "width_cm"):
            v = getattr(self, k)
            if v is not None and not (_finite(v) and v > 0):
                raise SonicskinError(f"link {brief(self.name)}: {k} must be a positive number of cm or None, got {brief(v)}")
        for k in ("tx_cm", "rx_cm"):
            v = getattr(self, k)
            if v is not None:
                try:
                    p = tuple(float(c) for c in v)
                except (TypeError, ValueError):
                    p = ()
                if len(p) != 2 or not all(map(math.isfinite, p)):
                    raise SonicskinError(f"link {brief(self.name)}: {k} must be (x_cm, y_cm), got {brief(v)}")
                object.__setattr__(self, k, p)

    @classmethod
    def from_scenario(cls, name: str, scenario, surface=None) -> LinkView:
        """The link of a simulated scenario (:class:`sonicskin.sim.Scenario`): its layout, geometry and transducers."""
        g = scenario.geometry
        return cls(name, scenario.make_layout(), kind=g["kind"], length_cm=g.get("length_cm"), width_cm=g.get("width_cm"),
                   tx_cm=getattr(scenario, "tx_cm", None), rx_cm=getattr(scenario, "rx_cm", None), surface=surface)

    def to_dict(self) -> dict[str, Any]:
        """What ``/links.json`` says of the link (the page works out the markers' spacing and the extent it draws)."""
        return {"name": self.name, "kind": self.kind, "circumference_cm": self.layout.circumference_cm,
                "length_cm": self.length_cm, "width_cm": self.width_cm, "tx_cm": self.tx_cm, "rx_cm": self.rx_cm,
                "markers": [{"id": i, "x_cm": round(float(x), 4), "y_cm": round(float(y), 4)}
                            for i, (x, y) in zip(self.layout.ids, self.layout.xy_cm)],
                "shape": None if self.surface is None else {"frame": self.surface.frame_id, "kind": self.surface.kind,
                                                            "dims_m": self.surface.dims_m, "pose": self.surface.pose.tolist()}}


def _page() -> bytes:
    return resources.files("sonicskin").joinpath("view.html").read_bytes()


class _Server(http.server.HTTPServer):
    """An HTTP server answered by a fixed pool of daemon threads; a backlog beyond four per thread is closed unanswered."""

    def __init__(self, address, handler, family, threads: int = POOL_THREADS):
        self.address_family = family
        self._queue: queue.Queue = queue.Queue(maxsize=4 * threads)
        self._threads = 0  # a port that cannot be bound closes the server before any thread starts
        super().__init__(address, handler)
        self._threads = threads
        for k in range(threads):
            threading.Thread(target=self._work, name=f"sonicskin-view-{k}", daemon=True).start()

    def process_request(self, request, client_address) -> None:
        try:
            self._queue.put_nowait((request, client_address))
        except queue.Full:
            self.shutdown_request(request)

    def _work(self) -> None:
        while (item := self._queue.get()) is not None:
            try:
                self.finish_request(*item)
            except Exception:
                self.handle_error(*item)
            finally:
                self.shutdown_request(item[0])

    def handle_error(self, request, client_address) -> None:
        if not isinstance(sys.exc_info()[1], OSError):  # a tab closed mid-answer, a reset, a timeout: no traceback
            super().handle_error(request, client_address)

    def server_close(self) -> None:
        super().server_close()
        while True:  # connections not yet answered are closed; then each thread ends
            try:
                self.shutdown_request(self._queue.get_nowait()[0])
            except queue.Empty:
                break
        for _ in range(self._threads):
            self._queue.put(None)


def _serve(server: _Server, stopped: threading.Event) -> None:
    """Answer requests until ``stopped`` is set (by :meth:`ViewServer.stop`, or when the view is garbage collected)."""
    try:
        while not stopped.is_set():
            server.handle_request()  # returns within server.timeout
    finally:
        server.server_close()


class _Handler(http.server.BaseHTTPRequestHandler):
    server_version = "sonicskin-view"
    view_ref: weakref.ref  # set on the subclass made per server: the view, held weakly

    def log_message(self, format, *args) -> None:  # noqa: A002 (the base class's name)
        pass

    def _send(self, code: int, body: bytes, ctype: str) -> None:
        self.send_response(code)
        self.send_header("Content-Type", ctype)
        self.send_header("Content-Length", str(len(body)))
        self.send_header("Cache-Control", "no-store")
        self.send_header("X-Content-Type-Options", "nosniff")
        self.end_headers()
        if self.command != "HEAD":
            self.wfile.write(body)

    def do_GET(self) -> None:  # noqa: N802 (http.server's name)
        view = self.view_ref()
        if view is None:
            self._send(503, b"sonicskin view: stopped\n", "text/plain; charset=utf-8")
            return
        if not view._host_ok(self.headers.get("Host", "")):
            self._send(403, b"sonicskin view: open it by its own address (127.0.0.1 or localhost)\n", "text/plain; charset=utf-8")
            return
        path = self.path.split("?", 1)[0]
        if path in ("/", "/index.html"):
            self._send(200, view._page, "text/html; charset=utf-8")
        elif path == "/links.json":
            self._send(200, view._links_json, "application/json")
        elif path == "/state.json":
            self._send(200, json.dumps(view.state(), allow_nan=False).encode(), "application/json")
        else:
            self._send(404, b"not found: the view serves /, /links.json and /state.json\n", "text/plain; charset=utf-8")

    do_HEAD = do_GET


class ViewServer:
    """Serve the live view of ``links`` on ``http://host:port/`` (:attr:`url`); its setters may be called from any thread."""

    def __init__(self, links: list[LinkView], host: str = "127.0.0.1", port: int = 0, *, n_events: int = N_EVENTS,
                 urdf: str | None = None):
        links = list(links)
        if not links:
            raise SonicskinError("the view needs at least one link (LinkView(name, layout))")
        bad = [type(lk).__name__ for lk in links if not isinstance(lk, LinkView)]
        if bad:
            raise SonicskinError(f"links must be LinkView(name, layout, kind), got {bad[0]}")
        names = [lk.name for lk in links]
        dup = sorted({n for n in names if names.count(n) > 1})
        if dup:
            raise SonicskinError(f"link names must be unique, {dup} appear more than once")
        if not is_number(port, integer=True) or not 0 <= port <= 65535:
            raise SonicskinError(f"view port must be 0 (any free port) or 1-65535, got {brief(port)}")
        self.links = {lk.name: lk for lk in links}
        self.host, self.port = host, port
        self._run_id = f"{time.time_ns():x}"  # a page that sees another run id reloads the links
        self._links_json = json.dumps({"run": self._run_id, "links": [lk.to_dict() for lk in links], "urdf": urdf}).encode()
        self._page = _page()
        self._lock = threading.Lock()
        self._seq = 0
        self._touch: dict[str, dict | None] = dict.fromkeys(self.links)
        self._status: dict[str, dict | None] = dict.fromkeys(self.links)
        self._counts: dict[str, int] = dict.fromkeys(self.links, 0)
        self._events: deque = deque(maxlen=int(n_events))
        self._server: _Server | None = None
        self._thread: threading.Thread | None = None
        self._loopback = False

    # -- server ------------------------------------------------------------------------
    @property
    def url(self) -> str:
        """``http://host:port/`` (the port the system chose when it was 0); only once started."""
        if self._server is None:
            raise SonicskinError("the view is not serving: call start() first")
        host, port = self._server.server_address[:2]
        host = f"[{host}]" if ":" in host else host
        return f"http://{host}:{port}/"

    def start(self) -> ViewServer:
        if self._server is not None:
            return self
        handler = type("Handler", (_Handler,), {"view_ref": weakref.ref(self), "timeout": CONN_TIMEOUT_S})
        family = http.server.HTTPServer.address_family
        try:
            ip = ipaddress.ip_address(self.host)
            self._loopback = ip.is_loopback
            if ip.version == 6:
                import socket

                family = socket.AF_INET6
        except ValueError:
            self._loopback = self.host == "localhost"
        try:
            self._server = _Server((self.host, self.port), handler, family)
        except OSError as e:
            raise SonicskinError(f"cannot serve the view on {self.host}:{self.port} ({e.strerror or e}); pick another port, "
                                 f"or 0 for any free one") from None
        self._server.timeout = 0.2  # how soon the serving thread sees stop()
        self._stopped = threading.Event()
        weakref.finalize(self, self._stopped.set)  # dropped without stop(): stop serving all the same
        self._thread = threading.Thread(target=_serve, args=(self._server, self._stopped), name="sonicskin-view", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        """Stop serving (a page left open says it lost the connection)."""
        if self._server is None:
            return
        self._stopped.set()
        self._thread.join(timeout=5)
        self._server = self._thread = None

    def __enter__(self) -> ViewServer:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

    def _host_ok(self, host_header: str) -> bool:
        """On a loopback address only requests naming it or localhost (DNS rebinding cannot read the events)."""
        if not self._loopback:
            return True
        host = host_header.rsplit(":", 1)[0] if not host_header.endswith("]") else host_header
        host = host.strip("[]").lower()
        if host == "localhost":
            return True
        try:
            return ipaddress.ip_address(host).is_loopback
        except ValueError:
            return False

    # -- state -------------------------------------------------------------------------
    def _link_of(self, name: str | None, what: str) -> str:
        if name is None:
            if len(self.links) == 1:
                return next(iter(self.links))
            raise SonicskinError(f"{what} names no link but the view shows {len(self.links)} ({', '.join(self.links)}); "
                                 f"set the event's link (LiveLoop(link=...) does)")
        if name not in self.links:
            raise SonicskinError(f"{what} names link {brief(name)}, which the view does not show ({', '.join(self.links)}); "
                                 f"list it in ViewServer(links=[LinkView({brief(name)}, layout), ...])")
        return name

    def push_event(self, ev: TouchEvent | dict | str) -> None:
        """Show one event (a TouchEvent, its dict or JSON line): a ``touch`` sets the link's touch, a ``release`` clears it."""
        if isinstance(ev, (str, bytes)):
            ev = parse_event(ev)
        elif isinstance(ev, dict):
            ev = TouchEvent.from_dict(ev)
        elif not isinstance(ev, TouchEvent):
            raise SonicskinError(f"push_event takes a TouchEvent (or its dict or JSON line), got {type(ev).__name__}")
        link = self._link_of(ev.link, f"event at t={ev.t_s:.3f} s")
        x, y = _finite(ev.x_cm), _finite(ev.y_cm)
        lk = self.links[link]
        if x is not None and lk.kind == "tube":
            x = x % lk.layout.circumference_cm
        if (x is None or y is None) and int(ev.location) in lk.layout.ids:  # no centroid: the marker's position
            x, y = (float(c) for c in lk.layout.coords(np.asarray([int(ev.location)]))[0])
        d = {"link": link, "kind": ev.kind, "t_s": round(float(ev.t_s), 4), "location": int(ev.location),
             "x_cm": None if x is None else round(x, 3), "y_cm": None if y is None else round(y, 3),
             "force_n": None if _finite(ev.force_n) is None else round(float(ev.force_n), 3),
             "confidence": _finite(ev.confidence), "model": ev.model, "point_m": ev.point_m, "normal": ev.normal}
        with self._lock:
            self._counts[link] += ev.kind == "touch" and self._touch[link] is None  # presses, not touched chirps
            self._touch[link] = d if ev.kind == "touch" else None
            self._events.appendleft(d)
            self._seq += 1

    def set_status(self, link_name: str | None, status: dict[str, Any]) -> None:
        """Show a link's reference and drift state: any of :data:`STATUS_KEYS` (``link_name`` None: the only link)."""
        link = self._link_of(link_name, "set_status")
        if not isinstance(status, dict):
            raise SonicskinError(f"set_status takes a dict of {sorted(STATUS_KEYS)}, got {type(status).__name__}")
        unknown = sorted(set(status) - set(STATUS_KEYS))
        if unknown:
            raise SonicskinError(f"set_status: unknown key(s) {unknown}; the view shows {sorted(STATUS_KEYS)}")
        s = {k: (str(v) if k == "text" else _finite(v)) for k, v in status.items() if v is not None}
        with self._lock:
            self._status[link] = s
            self._seq += 1

    def clear(self, link_name: str | None = None) -> None:
        """Forget the touch on one link (``None``: on every link), e.g. when its loop stopped."""
        names = [self._link_of(link_name, "clear")] if link_name is not None else list(self.links)
        with self._lock:
            for n in names:
                self._touch[n] = None
            self._seq += 1

    def state(self) -> dict[str, Any]:
        """The snapshot ``/state.json`` serves (JSON-able)."""
        with self._lock:  # the dicts are replaced, never changed in place: shallow copies are a consistent snapshot
            seq, touch, status, counts, events = self._seq, dict(self._touch), dict(self._status), dict(self._counts), list(self._events)
        return {"run": self._run_id, "seq": seq, "events": events,
                "links": {n: {"touch": touch[n], "status": status[n], "touches": counts[n]} for n in self.links}}


# -- wiring to the live loop ------------------------------------------------------------------------------------------
def loop_status(loop, t_s: float | None = None) -> dict[str, Any]:
    """The status :meth:`ViewServer.set_status` shows for a live loop at stream time ``t_s`` (``None``: the last event's)."""
    stream = loop.stream
    ref = stream.reference
    drift = stream.drift
    if t_s is None:
        t_s = loop.events[-1].t_s if loop.events else None
    age = None if ref.t_set_s is None or t_s is None else max(0.0, float(t_s) - ref.t_set_s)
    text = (f"calibrating (hands off; {ref.boot_cause})" if stream.calibrating else
            drift.status() if drift is not None else "running, no drift tracking")
    return {"refreshes": int(ref.refreshes), "stretch": None if drift is None else float(drift.stretch),
            "reference_age_s": age, "chirps": int(loop.n_chirps), "text": text}


def attach_view(view: ViewServer, loop, *, every_s: float = 0.5) -> None:
    """Show ``loop``'s events and status in ``view``, chaining the loop's ``on_event`` and ``on_chirp``."""
    name = loop.link_name
    view._link_of(name, f"the loop of link {brief(name)}" if name else "the loop")  # fails now, not at the first event
    prev_event, prev_chirp = loop.on_event, loop.on_chirp
    last = [-math.inf, None]  # stream time and (calibrating, refreshes) of the last status shown

    def on_event(ev: TouchEvent) -> None:
        if prev_event is not None:
            prev_event(ev)
        view.push_event(ev)

    def on_chirp(t_s: float, p) -> None:
        if prev_chirp is not None:
            prev_chirp(t_s, p)
        state = (loop.stream.calibrating, loop.stream.reference.refreshes)
        if t_s - last[0] >= every_s or state != last[1]:  # a new reference is shown at once
            last[0], last[1] = t_s, state
            view.set_status(name, loop_status(loop, t_s))

    loop.on_event, loop.on_chirp = on_event, on_chirp


def view_loops(loops, *, links: list[LinkView] | None = None, scenarios: list | None = None, host: str = "127.0.0.1",
               port: int = 0, urdf=None) -> ViewServer:
    """Serve a started view of the live loops (one per link), each attached, the arm placed by ``urdf``."""
    loops = list(loops)
    if links is None and scenarios:
        links = [LinkView.from_scenario(name, sc, lp.surface) for (name, sc), lp in zip(scenarios, loops)]
    if links is None:
        links = [LinkView(lp.link_name or "skin", lp.rt.layout, surface=lp.surface) for lp in loops]
    view = ViewServer(links, host=host, port=port, urdf=None if urdf is None else Path(urdf).read_text())
    for lp in loops:
        attach_view(view, lp)
    return view.start()


def parse_view_port(text: str | int | None) -> int:
    """``--view [PORT]``: 0 (any free port) when given without a port; one line naming the fix otherwise."""
    if text is None or text is True:
        return 0
    try:
        port = int(text)
    except (TypeError, ValueError):
        port = -1
    if not 0 <= port <= 65535 or isinstance(text, bool):
        raise SonicskinError(f"--view {text}: give a TCP port 1-65535 for the page (or 0, or --view alone, for any free one)")
    return port
