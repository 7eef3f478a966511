"""The live view (sonicskin.view): its state, its HTTP endpoints, bad input, and the page as a person sees it in a real
headless chromium (DOM read through the DevTools protocol), with scripted events and during a real LiveLoop run."""

import gc
import json
import socket
import struct
import threading
import time
import urllib.error
import urllib.request
from pathlib import Path

import numpy as np
import pytest
from cdp_helpers import Browser, chromium_binary
from test_live import SC, _live_timeline, artifact  # noqa: F401 (the module fixture: a 3-marker SVM artifact on jaco)

from sonicskin.errors import SonicskinError
from sonicskin.events import TouchEvent
from sonicskin.rig import Layout
from sonicskin.sim import Scenario
from sonicskin.view import STATUS_KEYS, LinkView, ViewServer, attach_view, loop_status, parse_view_port, view_loops

REPO = Path(__file__).resolve().parents[1]
needs_chromium = pytest.mark.skipif(chromium_binary() is None, reason="no chromium binary (Debian: apt-get install chromium; "
                                                                      ".ci/run installs it)")


def _links():
    return [LinkView.from_scenario("forearm", Scenario.load("stationary")),
            LinkView.from_scenario("hand-plate", Scenario.load("plate-aluminium"))]


def _event(link: LinkView, loc: int, kind="touch", force=2.5, t=10.0, dx=0.3, dy=-0.2):
    x, y = link.layout.coords(np.asarray([loc]))[0]
    return TouchEvent(t, kind, loc, float(x) + dx, float(y) + dy, force if kind == "touch" else 0.0, 0.9, "svm", 0.5,
                      link=link.name)


def _get(url: str, host: str | None = None):
    req = urllib.request.Request(url, headers={"Host": host} if host else {})
    try:
        with urllib.request.urlopen(req, timeout=10) as r:
            return r.status, r.headers.get("Content-Type"), r.read()
    except urllib.error.HTTPError as e:
        return e.code, e.headers.get("Content-Type"), e.read()


# -- state and server, no browser ----------------------------------------------------------------------------------
def _spacing(link: LinkView) -> float:
    """The median distance from a marker to its nearest neighbour on the surface (what the page works out)."""
    xy = link.layout.xy_cm
    d = link.layout.distance_cm(xy[:, None, :], xy[None, :, :])
    np.fill_diagonal(d, np.inf)
    return float(np.median(d.min(axis=1)))


def test_linkview_geometry_from_scenarios():
    tube, plate = _links()
    assert (tube.kind, plate.kind) == ("tube", "plate")
    assert (tube.tx_cm, tube.rx_cm) == ((0.0, 2.5), (5.9, 22.5))
    d = plate.to_dict()
    assert len(d["markers"]) == 36 and d["markers"][7] == {"id": 7, "x_cm": 10.5, "y_cm": 12.5}
    assert (d["width_cm"], d["length_cm"], d["shape"]) == (30.0, 34.0, None)
    assert LinkView("g", Layout.grid(3, 1, 2.4, 6, 12)).kind == "plate"  # kind inferred from the layout


def test_touch_and_release_in_the_state():
    tube, plate = _links()
    view = ViewServer([tube, plate])
    s0 = view.state()
    assert s0["events"] == [] and all(v["touch"] is None for v in s0["links"].values())
    view.push_event(_event(plate, 14, force=3.25, t=1.5))
    s = view.state()
    t = s["links"]["hand-plate"]["touch"]
    assert t["location"] == 14 and t["x_cm"] == pytest.approx(13.8) and t["y_cm"] == pytest.approx(15.3)
    assert t["force_n"] == 3.25 and t["t_s"] == 1.5 and s["links"]["forearm"]["touch"] is None
    assert s["seq"] > s0["seq"] and s["links"]["hand-plate"]["touches"] == 1
    view.push_event(_event(plate, 14, force=3.5, t=1.55))  # the same press, its next chirp
    view.push_event(_event(plate, 14, kind="release", t=1.6))
    s = view.state()
    assert s["links"]["hand-plate"]["touch"] is None and [e["kind"] for e in s["events"]] == ["release", "touch", "touch"]
    view.push_event(_event(plate, 3, t=2.5))
    assert view.state()["links"]["hand-plate"]["touches"] == 2  # the counter counts presses, not touched chirps
    # a tube's x wraps at its circumference; the list keeps the last ten, newest first
    C = tube.layout.circumference_cm
    view.push_event(TouchEvent(2.0, "touch", 0, C + 1.0, 12.0, 1.0, 0.9, "svm", 0.5, link="forearm"))
    assert view.state()["links"]["forearm"]["touch"]["x_cm"] == pytest.approx(1.0)
    for k in range(12):
        view.push_event(_event(tube, k, t=3.0 + k))
    ev = view.state()["events"]
    assert len(ev) == 10 and [e["location"] for e in ev] == list(range(11, 1, -1))
    # a single-link view takes events without a link; the JSON line and the dict work as the event does
    one = ViewServer([LinkView("only", tube.layout)])
    one.push_event(TouchEvent(1.0, "touch", 3, 5.0, 12.0, 1.0, 0.9, "svm", 0.5).to_json())
    assert one.state()["links"]["only"]["touch"]["location"] == 3
    one.push_event(TouchEvent(1.1, "release", 3, 5.0, 12.0, 0.0, 0.9, "svm", 0.5).to_dict())
    assert one.state()["links"]["only"]["touch"] is None


def test_status_and_missing_values():
    tube, plate = _links()
    view = ViewServer([tube, plate])
    view.set_status("forearm", {"refreshes": 2, "stretch": -4e-4, "reference_age_s": 3.5, "chirps": 90, "text": "drift"})
    view.set_status("hand-plate", {"refreshes": 1, "stretch": None, "reference_age_s": float("nan")})
    s = view.state()["links"]
    assert s["forearm"]["status"] == {"refreshes": 2, "stretch": -4e-4, "reference_age_s": 3.5, "chirps": 90, "text": "drift"}
    assert s["hand-plate"]["status"] == {"refreshes": 1, "reference_age_s": None}
    # an event without a position (null x/y in the JSON) is drawn at its marker; null force stays null
    d = _event(plate, 9).to_dict() | {"x_cm": None, "y_cm": None, "force_n": None}
    view.push_event(d)
    t = view.state()["links"]["hand-plate"]["touch"]
    assert (t["x_cm"], t["y_cm"], t["force_n"]) == (16.5, 12.5, None)
    json.dumps(view.state(), allow_nan=False)
    assert set(STATUS_KEYS) == {"refreshes", "stretch", "reference_age_s", "chirps", "text"}


@pytest.mark.parametrize("make, message", [
    (lambda: ViewServer([]), r"at least one link"),
    (lambda: ViewServer([_links()[0], _links()[0]]), r"link names must be unique, \['forearm'\]"),
    (lambda: ViewServer(_links(), port=70000), r"view port must be 0 \(any free port\) or 1-65535, got 70000"),
    (lambda: ViewServer([Layout.grid(2, 1, 1.0)]), r"links must be LinkView\(name, layout, kind\), got Layout"),
    (lambda: LinkView("a", Layout.grid(2, 1, 1.0), kind="tube"), r"link 'a' is a tube but its layout has no circumference_cm"),
    (lambda: LinkView("a", Layout.grid(2, 1, 1.0), kind="cone"), r"kind must be 'tube' or 'plate', got 'cone'"),
    (lambda: LinkView("", Layout.grid(2, 1, 1.0)), r"a link's name must be a non-empty string"),
    (lambda: LinkView("a", [[0, 0]]), r"layout must be a sonicskin.rig.Layout"),
    (lambda: LinkView("a", Layout.grid(2, 1, 1.0), length_cm=-3), r"length_cm must be a positive number of cm or None, got -3"),
    (lambda: LinkView("a", Layout.grid(2, 1, 1.0), tx_cm=(1, 2, 3)), r"tx_cm must be \(x_cm, y_cm\)"),
    (lambda: ViewServer(_links()).push_event(TouchEvent(1.0, "touch", 0, 1, 1, 1, 1, "svm", 0)),
     r"event at t=1.000 s names no link but the view shows 2 \(forearm, hand-plate\); set the event's link"),
    (lambda: ViewServer(_links()).push_event(TouchEvent(1.0, "touch", 0, 1, 1, 1, 1, "svm", 0, link="elbow")),
     r"names link 'elbow', which the view does not show \(forearm, hand-plate\)"),
    (lambda: ViewServer(_links()).push_event(42), r"push_event takes a TouchEvent \(or its dict or JSON line\), got int"),
    (lambda: ViewServer(_links()).set_status("forearm", {"refresh": 1}), r"unknown key\(s\) \['refresh'\]; the view shows"),
    (lambda: ViewServer(_links()).url, r"the view is not serving: call start\(\) first"),
])
def test_bad_input_is_one_line_naming_the_fix(make, message):
    with pytest.raises(SonicskinError, match=message) as e:
        make()
    assert "\n" not in str(e.value)


def test_view_port_argument():
    assert [parse_view_port(x) for x in (None, True, "0", "8765", 8765)] == [0, 0, 0, 8765, 8765]
    for bad in ("http", "-1", "70000", False):
        with pytest.raises(SonicskinError, match=rf"--view {bad}: give a TCP port 1-65535 for the page \(or 0, or --view "
                                                 r"alone, for any free one\)"):
            parse_view_port(bad)


def test_attach_view_chains_the_loops_callbacks():
    """attach_view keeps callbacks already set (a recorder's on_chirp, listen()'s on_event) and calls them first."""
    from types import SimpleNamespace

    calls = []
    ref = SimpleNamespace(refreshes=0, t_set_s=None, boot_cause="power-on")
    loop = SimpleNamespace(link_name=None, on_event=lambda ev: calls.append(("event", ev.kind)),
                           on_chirp=lambda t, p: calls.append(("chirp", t)), events=[], n_chirps=0,
                           stream=SimpleNamespace(calibrating=True, reference=ref, drift=None))
    view = ViewServer([LinkView("only", Layout.grid(2, 1, 1.0))])
    attach_view(view, loop, every_s=0.5)
    for k in range(4):  # chirps 0.2 s apart: a status at 0.0, the next at 0.6 (every_s)
        loop.n_chirps += 1
        loop.on_chirp(0.2 * k, None)
        assert view.state()["links"]["only"]["status"]["chirps"] == (1 if k < 3 else 4)
    assert view.state()["links"]["only"]["status"]["text"] == "calibrating (hands off; power-on)"
    loop.stream.calibrating, ref.refreshes, ref.t_set_s = False, 1, 0.7  # the boot's reference: shown at once
    loop.on_chirp(0.8, None)
    st = view.state()["links"]["only"]["status"]
    assert st == {"refreshes": 1, "reference_age_s": pytest.approx(0.1), "chirps": 4, "text": "running, no drift tracking"}
    loop.on_event(TouchEvent(0.9, "touch", 1, 1.0, 0.0, 2.0, 0.9, "svm", 0.1))
    assert calls[-1] == ("event", "touch") and [t for kind, t in calls[:-1]] == pytest.approx([0.0, 0.2, 0.4, 0.6, 0.8])
    assert view.state()["links"]["only"]["touch"]["location"] == 1


def test_endpoints_and_a_busy_port():
    with ViewServer(_links()) as view:
        assert view.url.startswith("http://127.0.0.1:")
        code, ctype, body = _get(view.url)
        assert code == 200 and ctype.startswith("text/html") and b'id="links"' in body
        code, ctype, body = _get(view.url + "links.json")
        links = json.loads(body)["links"]
        assert code == 200 and ctype == "application/json" and [lk["name"] for lk in links] == ["forearm", "hand-plate"]
        view.push_event(_event(view.links["forearm"], 5))
        code, _, body = _get(view.url + "state.json")
        assert code == 200 and json.loads(body)["links"]["forearm"]["touch"]["location"] == 5
        assert _get(view.url + "nothing")[0] == 404
        # a page of another site that renamed its host to this address (DNS rebinding) reads nothing
        assert _get(view.url + "state.json", host="evil.example:80")[0] == 403
        assert _get(view.url + "state.json", host=f"localhost:{view.url.rsplit(':', 1)[1].strip('/')}")[0] == 200
        port = int(view.url.rsplit(":", 1)[1].strip("/"))
        with pytest.raises(SonicskinError, match=rf"cannot serve the view on 127.0.0.1:{port} \(.*\); pick another port, "
                                                 r"or 0 for any free one"):
            ViewServer(_links(), port=port).start()
    with pytest.raises(urllib.error.URLError):  # stopped: nothing listens any more
        urllib.request.urlopen(view_url := f"http://127.0.0.1:{port}/state.json", timeout=2)
    assert view_url


def _refused(url: str, within_s: float = 5.0) -> bool:
    """Nothing answers ``url`` any more (polled, the server stops within its poll period)."""
    deadline = time.monotonic() + within_s
    while time.monotonic() < deadline:
        try:
            urllib.request.urlopen(url, timeout=2).close()
        except (urllib.error.URLError, ConnectionError):
            return True
        time.sleep(0.1)
    return False


def test_a_tab_closed_mid_answer_prints_nothing(capfd):
    """Issue 37: every browser tab closed mid-answer printed a BrokenPipeError/ConnectionResetError traceback into
    live's stderr, the stream that carries its status line."""
    with ViewServer(_links()) as view:
        addr = view._server.server_address[:2]
        for k in range(20):
            s = socket.create_connection(addr, timeout=5)
            s.sendall(b"GET " + (b"/" if k % 2 else b"/links.json") + b" HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")
            s.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
            s.close()  # a reset, as a closed tab's
        assert _get(view.url + "state.json")[0] == 200
    err = capfd.readouterr().err
    assert "Traceback" not in err and "Error" not in err, err[:2000]


def test_idle_connections_share_a_bounded_pool_and_time_out(monkeypatch):
    """Issue 37: one thread per connection, an idle one kept forever.  Now a fixed pool answers, and a connection that
    sends nothing is closed after CONN_TIMEOUT_S, so the view answers again."""
    import sonicskin.view as view_module

    monkeypatch.setattr(view_module, "CONN_TIMEOUT_S", 0.5)
    with ViewServer(_links()) as view:
        before = threading.active_count()
        idle = [socket.create_connection(view._server.server_address[:2], timeout=5) for _ in range(20)]
        time.sleep(0.3)
        assert threading.active_count() == before  # no thread per connection
        assert _get(view.url + "state.json")[0] == 200  # answered once the idle ones timed out
        assert all(s.recv(1) == b"" for s in idle)  # each closed by the server
        for s in idle:
            s.close()


def test_a_dropped_view_stops_serving():
    view = ViewServer(_links()).start()
    url = view.url + "state.json"
    assert _get(url)[0] == 200
    del view
    gc.collect()
    assert _refused(url)


def test_a_listener_never_started_does_not_keep_serving_its_view(artifact, tmp_path):  # noqa: F811 (the imported fixture)
    """Issue 37: a Listener(view=True) that was never started and was deleted kept its view serving."""
    import yaml

    from sonicskin.api import Listener

    sc = tmp_path / "sc.yaml"
    sc.write_text(yaml.safe_dump(SC.to_dict()))
    lst = Listener(artifact, scenario=sc, fast=True, view=True)
    url = lst.view_url + "state.json"
    assert _get(url)[0] == 200
    del lst
    gc.collect()
    assert _refused(url)


def test_events_from_many_threads_while_pages_read():
    """push_event from several threads at once, with readers serialising the state: nothing lost, nothing torn."""
    tube, plate = _links()
    with ViewServer([tube, plate], n_events=1000) as view:
        stop = threading.Event()
        reads = []

        def reader():
            while not stop.is_set():
                reads.append(json.loads(_get(view.url + "state.json")[2])["seq"])

        def writer(link, n):
            for k in range(n):
                view.push_event(_event(link, k % len(link.layout), t=float(k)))

        r = threading.Thread(target=reader)
        r.start()
        ws = [threading.Thread(target=writer, args=(lk, 200)) for lk in (tube, plate, tube)]
        for w in ws:
            w.start()
        for w in ws:
            w.join()
        stop.set()
        r.join()
        s = view.state()
    assert s["seq"] == 600 and len(s["events"]) == 600
    assert s["links"]["forearm"]["touches"] == s["links"]["hand-plate"]["touches"] == 1  # one press each, never released
    assert reads == sorted(reads)


def test_the_page_is_self_contained():
    """No CDN, no font or script from elsewhere: the page works on a machine without internet."""
    html = (REPO / "sonicskin" / "view.html").read_text()
    assert "<script src" not in html and "<link" not in html and "@import" not in html and "url(" not in html
    urls = {u.split('"')[0] for u in html.split("http")[1:]}
    assert urls == {"://www.w3.org/2000/svg"}, urls  # the SVG namespace, a name and not a fetch


# -- the page in a real browser ---------------------------------------------------------------------------------------
def _dots(b: Browser) -> list[dict]:
    return b.js("[...document.querySelectorAll('circle.touch')].map(d => ({...d.dataset, "
                "panel: d.closest('section.link').dataset.link}))")


@needs_chromium
def test_a_scripted_touch_appears_on_the_right_link_within_one_second():
    """The page polls every 100 ms: one second of its time after push_event the dot is on the touched link, at the
    event's place (within one marker spacing of the marker), its marker highlighted; a release clears it."""
    tube, plate = _links()
    with ViewServer([tube, plate]) as view, Browser() as b:
        b.open(view.url, ready="document.querySelectorAll('section.link').length === 2 && document.body.dataset.seq")
        assert b.js("[...document.querySelectorAll('section.link')].map(s => s.dataset.link)") == ["forearm", "hand-plate"]
        geo = b.js("links.map(l => [l.spacing_cm, l.extent_cm])")  # the page's spacing and extent, as the view draws them
        assert geo[0][0] == pytest.approx(_spacing(tube)) == pytest.approx(1.2) and geo[1][0] == pytest.approx(3.0)
        assert geo[0][1] == pytest.approx([0.0, 2 * np.pi * 3.75, 0.0, 25.0]) and geo[1][1] == pytest.approx([0, 30, 0, 34])
        assert b.js("document.querySelectorAll('section[data-link=forearm] circle.marker').length") == 31
        assert _dots(b) == []
        for link, loc, other in ((plate, 14, tube), (tube, 20, plate)):
            ev = _event(link, loc, force=3.4, t=12.25)
            view.push_event(ev)
            b.advance(1000)
            (dot,) = _dots(b)
            assert dot["panel"] == dot["link"] == link.name and int(dot["location"]) == loc
            assert float(dot["xCm"]) == pytest.approx(ev.x_cm, abs=1e-3) and float(dot["yCm"]) == pytest.approx(ev.y_cm, abs=1e-3)
            true_xy = link.layout.coords(np.asarray([loc]))[0]
            assert link.layout.distance_cm(np.array([float(dot["xCm"]), float(dot["yCm"])]), true_xy) < _spacing(link)
            assert float(dot["forceN"]) == 3.4 and float(dot["tS"]) == 12.25
            sel = f"section[data-link='{link.name}']"
            assert b.js(f"[...document.querySelectorAll(\"{sel} circle.marker.hit\")].map(m => m.dataset.location)") == [str(loc)]
            assert b.js(f"document.querySelector(\"{sel}\").dataset.touching") == "true"
            assert b.js(f"document.querySelector(\"section[data-link='{other.name}']\").dataset.touching") == "false"
            assert "3.40 N at marker" in b.js(f"document.querySelector(\"{sel} .readout\").textContent")
            view.push_event(_event(link, loc, kind="release", t=12.35))
            b.advance(1000)
            assert _dots(b) == [] and b.js("document.querySelectorAll('circle.marker.hit').length") == 0
        rows = b.js("[...document.querySelectorAll('#events tbody tr')].map(r => r.dataset.link + ' ' + r.dataset.kind)")
        assert rows == ["forearm release", "forearm touch", "hand-plate release", "hand-plate touch"]
        view.set_status("hand-plate", {"refreshes": 3, "reference_age_s": 12.8, "chirps": 412, "text": "drift +1.20e-04 (-5.0 K)"})
        b.advance(1000)
        status = b.js("document.querySelector(\"section[data-link='hand-plate'] .status\").textContent")
        assert "reference: 3 taken, 12.8 s old" in status and "412 chirps" in status and "drift +1.20e-04" in status
        # the server stops: the page says so instead of showing a stale touch as live
        view.stop()
        b.advance(1000)
        assert b.js("document.getElementById('conn').textContent").startswith("disconnected")
    # no size given: the plate drawn is the markers' extent plus one spacing
    with ViewServer([LinkView("g", Layout.grid(3, 1, 2.4, 6, 12))]) as grid, Browser() as b:
        b.open(grid.url, ready="document.querySelectorAll('section.link').length === 1")
        assert b.js("links[0].extent_cm") == pytest.approx([0.0, 13.2, 0.0, 14.4])


@needs_chromium
def test_a_live_loop_run_shows_its_touches_in_the_browser(rig, artifact):  # noqa: F811 (the imported fixture)
    """A real LiveLoop on the simulated device, wired with attach_view: the loop is held at its first touch event and
    at the release after it while the page is read; the dot sits on the loop's link at the scripted marker."""
    from sonicskin.acquire import Link, SimulatedSource
    from sonicskin.live import LiveLoop
    from sonicskin.runtime import SkinRuntime

    sim, tl = _live_timeline(rig)
    src = SimulatedSource(sim, tl, realtime=False, offset=5000)
    rt = SkinRuntime(artifact, "svm")
    loop = LiveLoop(rt, src, emit=lambda _: None, link=Link(name="forearm"))
    other = LinkView.from_scenario("upper-arm", Scenario.load("stationary"))
    with pytest.raises(SonicskinError, match=r"the loop of link 'forearm' names link 'forearm', which the view does not show"):
        view_loops([loop], links=[other])
    view = view_loops([loop], links=[LinkView("forearm", rt.layout, length_cm=25.0), other])  # started, loop attached
    held, go, abort = threading.Event(), threading.Event(), threading.Event()
    seen: list[TouchEvent] = []
    attached = loop.on_event

    def hold(ev):  # after the view got it: hold the loop at the first touch and at the release after it
        attached(ev)
        if not abort.is_set() and ((ev.kind == "touch" and not seen) or (ev.kind == "release" and len(seen) == 1)):
            seen.append(ev)
            held.set()
            go.wait(timeout=120)
            go.clear()

    loop.on_event = hold
    result = {}
    runner = threading.Thread(target=lambda: result.setdefault("summary", loop.run(stop=abort)), daemon=True)
    try:
        _run_and_read(view, src, runner, held, go, seen, rt, tl, rig)
    finally:  # a failed check must not leave the loop held
        abort.set()
        go.set()
        runner.join(timeout=300)
    assert not runner.is_alive() and result["summary"]["touch_events"] > 1
    status = loop_status(loop)
    assert status["refreshes"] == loop.refreshes and status["chirps"] == loop.n_chirps and status["text"]


def _run_and_read(view, src, runner, held, go, seen, rt, tl, rig):
    with view, Browser() as b, src:
        b.open(view.url, ready="document.querySelectorAll('section.link').length === 2")
        runner.start()
        assert held.wait(timeout=120)
        held.clear()
        b.advance(1000)
        (dot,) = _dots(b)
        ev = seen[0]
        k = int(round((ev.t_s * rig.fs_hz + 5000) / rig.n_chirp))  # the chirp of the scripted timeline
        true_xy = rt.layout.coords(np.asarray([tl.location[k]]))[0]
        assert dot["panel"] == dot["link"] == "forearm" and int(dot["location"]) == ev.location == tl.location[k]
        assert float(dot["xCm"]) == pytest.approx(ev.x_cm, abs=1e-3) and float(dot["yCm"]) == pytest.approx(ev.y_cm, abs=1e-3)
        assert rt.layout.distance_cm(np.array([float(dot["xCm"]), float(dot["yCm"])]), true_xy) < 2.4  # the marker spacing
        assert float(dot["forceN"]) == pytest.approx(ev.force_n, abs=1e-3) and ev.force_n > 0
        st = b.js("({...document.querySelector(\"section[data-link='forearm'] .status\").dataset})")
        assert int(st["refreshes"]) == 1 and int(st["chirps"]) > 0 and float(st["referenceAgeS"]) >= 0
        assert b.js("document.querySelector(\"section[data-link='upper-arm']\").dataset.touching") == "false"
        go.set()
        assert held.wait(timeout=120)  # the release
        held.clear()
        b.advance(1000)
        assert _dots(b) == [] and seen[1].kind == "release"
        go.set()
        runner.join(timeout=300)


@needs_chromium
def test_the_arm_is_drawn_in_3d_with_every_link_and_the_touch_with_its_arrow():
    """arm6 as docs/view.png shows it (tools/view_screenshot.py), read from the page at 1280 x 800: the six skins drawn in
    3D in their URDF frames, each whole in the window and named; the touch at its point (metres, placed by the URDF's
    joints) with an arrow along the link's outward normal, 5 cm + 2 cm per N; the counters count presses."""
    import importlib.util

    from sonicskin.rosbag import _joint_tf, urdf_joints

    spec = importlib.util.spec_from_file_location("view_screenshot", REPO / "tools" / "view_screenshot.py")
    tool = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(tool)
    view, events = tool.view_of_arm6()
    with view, Browser(window=(1280, 800)) as b:
        b.open(view.url, ready="document.querySelectorAll('#mesh3d g.skin').length === 6 && document.body.dataset.seq")
        b.advance(1000)
        skins = b.js("[...document.querySelectorAll('#mesh3d g.skin')].map(g => { const r = g.getBoundingClientRect(); "
                     "return {link: g.dataset.link, frame: g.dataset.frame, faces: g.querySelectorAll('polygon').length, "
                     "box: [r.left, r.top, r.right, r.bottom]}; })")
        assert sorted(s["link"] for s in skins) == sorted(["base", "shoulder", "upper-arm", "forearm", "wrist", "hand"])
        assert {s["link"]: s["frame"] for s in skins}["upper-arm"] == "upper_arm_link"
        for s in skins:  # drawn, and whole inside the window
            x0, y0, x1, y1 = s["box"]
            assert s["faces"] >= 3 and x1 - x0 > 5 and y1 - y0 > 5 and 0 <= x0 and x1 <= 1280 and 0 <= y0 and y1 <= 800, s
        labels = b.js("[...document.querySelectorAll('#mesh3d text.label3d')].map(t => [t.dataset.link, t.textContent, "
                      "t.getBoundingClientRect().right])")
        assert len(labels) == 6 and all(right <= 1280 for _, _, right in labels)
        said = {link: text for link, text, _ in labels}
        assert said["forearm"] == "forearm · 1 pressforearm_link" and said["hand"] == "hand · 1 presshand_plate"
        assert said["base"] == "base · 0 pressesbase_link"
        (touch,) = b.js("[...document.querySelectorAll('#touch3d g.touch3d')].map(g => ({...g.dataset, "
                        "arrow: g.querySelectorAll('line.arrow').length, head: g.querySelector('polygon.head')"
                        ".getAttribute('points'), dot: [+g.querySelector('circle').getAttribute('cx'), "
                        "+g.querySelector('circle').getAttribute('cy')]}))")
        ev = events[-1]
        assert touch["link"] == "forearm" and touch["frame"] == "forearm_link" and float(touch["forceN"]) == 4.2
        joints = urdf_joints((REPO / "configs" / "arms" / "arm6.urdf").read_text())
        T, frame = np.eye(4), "forearm_link"  # forearm_link in the world: the joints from the root, at zero
        while (j := next((j for j in joints.values() if j["child"] == frame), None)) is not None:
            tf = _joint_tf(j, 0.0, 0)["transform"]
            A = np.eye(4)
            A[:3, 3] = [tf["translation"][k] for k in "xyz"]
            q = [tf["rotation"][k] for k in "xyzw"]
            assert np.allclose(q, [0, 0, 0, 1])  # arm6's joints have no rotation at zero
            T, frame = A @ T, j["parent"]
        world = T[:3, :3] @ np.asarray(ev.point_m) + T[:3, 3]
        np.testing.assert_allclose([float(v) for v in touch["world"].split(",")], world, atol=1e-9)
        tail = np.array([float(v) for v in touch["tailWorld"].split(",")])
        np.testing.assert_allclose(tail - world, (0.05 + 0.02 * 4.2) * (T[:3, :3] @ np.asarray(ev.normal)), atol=1e-9)
        tip = b.js(f"arm3d.project([{','.join(map(str, world))}])")
        assert touch["arrow"] == 1 and np.allclose(touch["dot"], tip) and np.allclose(
            [float(v) for v in touch["head"].split()[0].split(",")], tip)  # the arrow's head on the point
        assert 0 < tip[0] < 1280 and 0 < tip[1] < 800
        assert "forearm: 4.20 N at (" in b.js("document.getElementById('readout3d').textContent")
        assert b.js("document.querySelector(\"section[data-link='forearm'] .count\").textContent") == "1 press"
        assert b.js("document.querySelector('#mesh3d g.skin[data-link=forearm]').classList.contains('touched')")


def test_docs_screenshot_is_shipped_and_small():
    png = REPO / "docs" / "view.png"
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size < 200_000
