"""The event stream is a contract: the schema (v2, reading v1) and its validator, and `live`'s stdout, UDP and
LSL output checked against it."""

import dataclasses
import json
import math
import socket
import threading
import time

import pytest
from cli_helpers import run

from sonicskin.events import (
    EVENT_SCHEMA,
    SCHEMA_VERSION,
    EventError,
    TouchEvent,
    attach_surface,
    parse_event,
    surface_fields,
    validate_event,
)

GOOD = {"v": 2, "t_s": 4.2667, "kind": "touch", "location": 3, "x_cm": 6.1, "y_cm": 12.0, "force_n": 2.5,
        "confidence": 0.9, "model": "svm", "latency_ms": 0.8}


def test_event_round_trip_and_nulls():
    ev = TouchEvent(4.26667, "touch", 3, 6.1, 12.0, math.nan, 0.9, "svm", 0.81234)
    d = json.loads(ev.to_json())
    assert list(d)[0] == "v" and d["v"] == SCHEMA_VERSION == 2 and EVENT_SCHEMA["properties"]["v"]["enum"] == [1, 2]
    assert d["force_n"] is None and d["t_s"] == 4.2667  # no force model: null; 4 decimals
    back = parse_event(ev.to_json())
    assert back.kind == "touch" and back.location == 3 and math.isnan(back.force_n)
    optional = {"link", "frame_id", "point_m", "normal", "force_vec_n", "force_reliable"}  # link: --links only; frame_id,
    assert set(EVENT_SCHEMA["required"]) == set(d) == set(EVENT_SCHEMA["properties"]) - optional  # ...: a surface
    for flag in (True, False):  # force_reliable: the artifact's verdict on its force, written when it has one
        ev2 = dataclasses.replace(ev, force_reliable=flag)
        assert json.loads(ev2.to_json())["force_reliable"] is flag and parse_event(ev2.to_json()).force_reliable is flag
    with pytest.raises(EventError, match=r"force_reliable must be boolean, got 'yes'"):
        validate_event({**GOOD, "force_reliable": "yes"})


@pytest.mark.parametrize("change, msg", [
    ({"v": 3}, "v must be one of [1, 2], got 3 (a reader for schema v2: a newer sonicskin reads newer events)"),
    ({"kind": "press"}, "kind must be one of ['touch', 'release'], got 'press'"),
    ({"confidence": 1.5}, "confidence must be <= 1, got 1.5"),
    ({"force_n": -0.1}, "force_n must be >= 0, got -0.1"),
    ({"location": 2.5}, "location must be integer, got 2.5"),
    ({"t_s": "now"}, "t_s must be number, got 'now'"),
    ({"model": 5}, "model must be string, got 5"),  # any model kind of the artifact (sonicskin.kinds) names itself
    ({"link": 1}, "link must be string, got 1"),  # unknown fields are kept, not refused (test_hostile_live.py)
    ({"frame_id": "f", "point_m": [0, 0, 0.1], "normal": [0, 0, 2]}, "normal must be a unit vector, got [0, 0, 2] (length 2)"),
    ({"point_m": [0, 0.1], "normal": [0, 0, 1]}, "point_m must be 3 numbers, got [0, 0.1]"),
    ({"point_m": [0, 0, "a"], "normal": [0, 0, 1]}, "point_m must be 3 numbers, got [0, 0, 'a']"),
    ({"point_m": [0, 0, 0.1]}, "point_m and normal come together with the frame_id they are in, force_vec_n only with them "
                               "(schema v2), got ['point_m']"),
    # issue 37: a point in no frame, and a frame without a name, are no robot-frame contact
    ({"point_m": [0, 0, 0.1], "normal": [0, 0, 1]}, "point_m and normal come together with the frame_id they are in, "
                                                   "force_vec_n only with them (schema v2), got ['normal', 'point_m']"),
    ({"frame_id": ""}, "frame_id must be a non-blank string, got ''"),
    ({"frame_id": "", "point_m": [0, 0, 0.1], "normal": [0, 0, 1]}, "frame_id must be a non-blank string, got ''"),
    # a blank link or frame was taken: an event of no link, in a frame no tf tree has
    ({"frame_id": " "}, "frame_id must be a non-blank string, got ' '"),
    ({"frame_id": "\t\n", "point_m": [0, 0, 0.1], "normal": [0, 0, 1]}, "frame_id must be a non-blank string, got '\\t\\n'"),
    ({"link": ""}, "link must be a non-blank string, got ''"),
    ({"link": "  "}, "link must be a non-blank string, got '  '"),
    ({"model": " "}, "model must be a non-blank string, got ' '"),
    ({"frame_id": ["f"]}, "frame_id must be string, got ['f']"),
])
def test_validator_names_the_problem(change, msg):
    validate_event(GOOD)
    with pytest.raises(EventError) as e:
        validate_event({**GOOD, **change})
    assert str(e.value) == msg
    with pytest.raises(EventError, match=r"event lacks \['x_cm'\]"):
        validate_event({k: v for k, v in GOOD.items() if k != "x_cm"})
    with pytest.raises(EventError, match="not a JSON event"):
        parse_event("{nan")


# A line `sonicskin live` wrote before schema v2 (commit 33f55f0): still read, and written back as read.
V1_LINE = ('{"v": 1, "t_s": 4.2667, "kind": "touch", "location": 14, "x_cm": 9.6, "y_cm": 13.1, "force_n": 2.47, '
           '"confidence": 0.93, "model": "svm", "latency_ms": 0.71, "link": "forearm"}')


def test_a_v1_event_still_parses():
    ev = parse_event(V1_LINE)
    assert (ev.v, ev.location, ev.link, ev.frame_id, ev.point_m) == (1, 14, "forearm", None, None)
    assert ev.to_json() == V1_LINE


def test_v2_surface_fields_known_answer_and_round_trip():
    from sonicskin.surface import LinkSurface

    s = LinkSurface.from_dict({"frame": "forearm_link", "kind": "tube", "radius_m": 0.0375, "length_m": 0.25,
                               "xyz": [0, 0, 0.125]})
    quarter = 2 * math.pi * 3.75 / 4  # x a quarter of the way round: +90 deg, the normal is +y
    f = surface_fields(s, quarter, 5.0, 2.0)
    assert f["frame_id"] == "forearm_link"
    assert f["point_m"] == pytest.approx((0, 0.0375, 0.05), abs=1e-12) and f["normal"] == pytest.approx((0, 1, 0), abs=1e-12)
    assert f["force_vec_n"] == pytest.approx((0, -2, 0), abs=1e-12)  # the finger pushes into the link
    ev = attach_surface(parse_event(V1_LINE), s)  # a v1 event gets the fields and becomes v2
    d = json.loads(ev.to_json())
    assert d["v"] == 2 and d["frame_id"] == "forearm_link" and d["link"] == "forearm"
    assert list(d)[-4:] == ["frame_id", "point_m", "normal", "force_vec_n"]
    assert all(isinstance(d[k], list) and len(d[k]) == 3 for k in ("point_m", "normal", "force_vec_n"))
    back = parse_event(ev.to_json())
    assert back.point_m == pytest.approx(ev.point_m, abs=1e-6) and back.force_vec_n == pytest.approx(ev.force_vec_n, abs=1e-4)
    assert back.to_json() == ev.to_json()
    # a release: force 0, vector 0 (no "-0.0"); no force model: null vector; no surface: no field at all
    rel = json.loads(attach_surface(dataclasses.replace(ev, kind="release", force_n=0.0), s).to_json())
    assert '"force_vec_n": [0.0, 0.0, 0.0]' in json.dumps(rel)
    nof = json.loads(attach_surface(dataclasses.replace(ev, force_n=math.nan), s).to_json())
    assert nof["force_n"] is None and nof["force_vec_n"] is None
    validate_event(nof)
    assert attach_surface(parse_event(V1_LINE), None).to_json() == V1_LINE


def _check_stream(events, period_s):
    """Every event valid; t_s on the chirp grid; each run of touches ends in exactly one release with force 0."""
    assert events
    for d in events:
        validate_event(d)
    t = [d["t_s"] for d in events]
    assert t == sorted(t)
    steps = [(b - a) / period_s for a, b in zip(t, t[1:])]
    assert all(abs(s - round(s)) * period_s < 2e-4 for s in steps)  # t_s has 4 decimals
    kinds = [d["kind"] for d in events]
    assert "touch" in kinds and "release" in kinds
    for i, d in enumerate(events):
        if d["kind"] == "release":
            assert d["force_n"] == 0 and events[i - 1]["kind"] == "touch"


def test_live_stdout_and_udp_follow_the_schema(cli_files, capsys):
    from sonicskin.rig import Rig

    rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    rx.bind(("127.0.0.1", 0))
    rx.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 22)
    code, out, err = run(capsys, ["live", "--rig", cli_files["rig"], "--scenario", cli_files["scenario"], "--artifact",
                                  cli_files["artifact"], "--fast", "--duration", "30", "--no-status", "--udp",
                                  str(rx.getsockname()[1])])
    assert code == 0, err
    lines = out.splitlines()
    events = [json.loads(x) for x in lines]
    _check_stream(events, Rig.load(cli_files["rig"]).period_s)
    rx.settimeout(1.0)
    got = []
    while len(got) < len(lines):
        got.append(rx.recv(65536).decode())
    assert got == lines  # the same bytes on both transports


def test_udp_to_an_unresolvable_host_is_one_line_before_the_run(cli_files, capsys):
    code, out, err = run(capsys, ["live", "--rig", cli_files["rig"], "--scenario", cli_files["scenario"], "--artifact",
                                  cli_files["artifact"], "--fast", "--duration", "5", "--no-status", "--udp",
                                  "no-such-host.invalid:9999"])
    assert code == 2 and out == ""
    assert err.startswith("sonicskin live: error: --udp no-such-host.invalid:9999: cannot resolve host 'no-such-host.invalid'")
    assert len(err.strip().splitlines()) == 1


def test_live_publishes_on_lab_streaming_layer(cli_files, capsys):
    pylsl = pytest.importorskip("pylsl")
    from sonicskin.live import STREAM_TYPE

    name = f"sonicskin-test-{time.monotonic_ns()}"
    result = {}
    t = threading.Thread(target=lambda: result.update(r=run(capsys, [
        "live", "--rig", cli_files["rig"], "--scenario", cli_files["scenario"], "--artifact", cli_files["artifact"],
        "--duration", "12", "--no-status", "--lsl", name])))
    t.start()
    streams = pylsl.resolve_byprop("name", name, timeout=10)
    assert streams and streams[0].type() == STREAM_TYPE
    inlet = pylsl.StreamInlet(streams[0])
    inlet.open_stream(timeout=5)
    assert inlet.info(timeout=5).desc().child_value("schema_version") == str(SCHEMA_VERSION)
    samples = []
    while t.is_alive() or samples == []:
        s, _ = inlet.pull_sample(timeout=0.5)
        if s is not None:
            samples.append(json.loads(s[0]))
        elif not t.is_alive():
            break
    t.join()
    assert result["r"][0] == 0
    assert samples and all(validate_event(d) is None for d in samples)
    assert any(d["kind"] == "touch" for d in samples)


def _scripted_loop(cli_files, script, force=True):
    """A live loop whose stream says, chirp after chirp, ``script``: (touched, marker, force N); its events."""
    import numpy as np

    from sonicskin import acquire
    from sonicskin.dsp import rig_chirp
    from sonicskin.head.heads import Predictions
    from sonicskin.live import LiveLoop
    from sonicskin.rig import Rig
    from sonicskin.runtime import SkinRuntime

    rig = Rig.load(cli_files["rig"])
    loop = LiveLoop(SkinRuntime(cli_files["artifact"], "svm"), acquire._QueueSource(rig, 1024), emit=lambda line: None)
    said = iter(script)

    def chirp(x, t_s):
        touched, marker, f = next(said)
        return Predictions(np.array([touched]), np.array([marker]), np.array([[1.2 * marker, 12.5]]),
                           np.array([f if force else math.nan]), np.array([0.9]), np.zeros((1, 3)))

    loop.stream.chirp = chirp
    frame = (rig_chirp(rig) * 0.1).astype(np.float32)
    evs = [loop.process_frame(k * rig.n_chirp, frame, time.perf_counter()) for k in range(len(script))]
    return [(e.kind, e.location, e.force_n) for e in evs if e is not None]


def test_a_release_names_its_press_and_a_0_n_blip_is_no_press(cli_files):
    """Issue 37: a release named the marker of the press's last chirp (touch marker 30 ... release marker 5), and a
    press could open with a one-chirp 0 N touch at another marker.  A press opens at its first touched chirp with a
    force (at once) or at its second touched chirp; its release names the marker most of its chirps named."""
    no, touch = (False, 0, 0.0), lambda m, f=3.0: (True, m, f)
    events = _scripted_loop(cli_files, [no, touch(2, 0.0), touch(1), touch(1), touch(1), touch(0, 1.0), no,
                                        no, touch(0, 0.0), no,                 # a one-chirp 0 N blip: no press at all
                                        touch(2), touch(2, 0.0), touch(1), no,  # firm at once: it opens at its first chirp
                                        touch(1, 0.0), touch(1, 0.0), touch(0, 0.0), no])  # 0 N throughout: the second
    assert events == [("touch", 1, 3.0), ("touch", 1, 3.0), ("touch", 1, 3.0), ("touch", 0, 1.0), ("release", 1, 0.0),
                      ("touch", 2, 3.0), ("touch", 2, 0.0), ("touch", 1, 3.0), ("release", 2, 0.0),
                      ("touch", 1, 0.0), ("touch", 0, 0.0), ("release", 1, 0.0)]
    # without a force model every press opens at its second touched chirp
    events = _scripted_loop(cli_files, [no, touch(2), touch(1), touch(1), no, touch(0), no], force=False)
    assert [(k, m) for k, m, _ in events] == [("touch", 1), ("touch", 1), ("release", 1)]
