"""Touch on the robot's own bus (issue 35): every link's Contact at a fixed rate with its state, the MCAP file that
lasts (chunked, zstd, a kill -9 loses at most its last second), the robot's URDF and transforms, and the same messages
live over DDS (ROS 2 topics, a subscriber in another process) and Foxglove's WebSocket (a client that subscribes)."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml

from sonicskin.cli import main

REPO = Path(__file__).resolve().parents[1]
TINY = {"layout": {"kind": "rings", "counts": [3, 2], "spacing_cm": 1.2, "x0_cm": 2.4, "y0_cm": 11.9}, "sessions": 1,
        "train_repeats": 2, "touch_s": 1.0, "gap_s": 0.5, "calibration_s": 3.0}


@pytest.fixture(scope="module")
def arm(tmp_path_factory) -> Path:
    """A two-link arm on arm6.urdf's forearm tube and hand plate, trained (simulate, fit-svm): its arm file."""
    root = tmp_path_factory.mktemp("ros2-arm")
    shutil.copyfile(REPO / "configs" / "arms" / "arm6.urdf", root / "arm6.urdf")
    links = [{"name": "forearm", "tx": 0, "rx": 0, "frame": "forearm_link", "scenario": {**TINY, "seed": 41}},
             {"name": "hand", "tx": 1, "rx": 1, "frame": "hand_plate",
              "scenario": {**TINY, "base": "plate-aluminium", "seed": 42, "tx_cm": [3.0, 4.0], "rx_cm": [16.0, 21.0],
                           "layout": {"kind": "grid", "nx": 3, "ny": 2, "spacing_cm": 3.0, "x0_cm": 7.0, "y0_cm": 10.5}}}]
    f = root / "arm.yaml"
    f.write_text(yaml.safe_dump({"name": "t", "rig": "fast", "urdf": "arm6.urdf", "duplex": "none", "links": links}))
    assert main(["simulate", "--links", str(f), "--out", str(root / "data"), "--quiet", "--sessions", "2"]) == 0
    assert main(["fit-svm", "--links", str(f), "--data", str(root / "data"), "--out", str(root / "art"), "--train", "s000"]) == 0
    return root / "art" / "arm.yaml"


def _messages(path) -> list:
    """(topic, schema name, log time ns, decoded message) of every message of an MCAP file, by mcap-ros2-support."""
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    with open(path, "rb") as f:
        return [(c.topic, s.name, m.log_time, r) for s, c, m, r in
                make_reader(f, decoder_factories=[DecoderFactory()]).iter_decoded_messages()]


def _ns(stamp) -> int:
    return stamp.sec * 1_000_000_000 + stamp.nanosec


def test_every_link_says_its_contact_state_at_a_fixed_rate(arm, tmp_path):
    """One sonicskin_msgs/Contact per link at each touched chirp (exactly the touch events), at each change, and at
    least every 50 ms of stream while nothing changes: touched or not explicit, the normal unit at every force."""
    from sonicskin.api import Listener
    from sonicskin.rosbag import IDLE_S

    lst = Listener(arm, fast=True, duration_s=8, mcap=tmp_path / "a.mcap")
    events = [ev for ev in lst]
    t0 = lst.opened.mcap.t0_unix_s
    msgs = _messages(tmp_path / "a.mcap")
    for link, frame in (("forearm", "forearm_link"), ("hand", "hand_plate")):
        contacts = [(t, m) for topic, schema, t, m in msgs if topic == f"/sonicskin/{frame}/contact"]
        assert {schema for topic, schema, _, _ in msgs if topic == f"/sonicskin/{frame}/contact"} == {"sonicskin_msgs/msg/Contact"}
        assert all(_ns(m.header.stamp) == t and m.header.frame_id == frame and m.link == link for t, m in contacts)
        stamps = np.array([t for t, _ in contacts])
        period_ns = 2560 / 192000 * 1e9  # the fast rig's chirp: one at least every IDLE_S, at the first chirp after it
        assert np.all(np.diff(stamps) > 0) and np.diff(stamps).max() <= IDLE_S * 1e9 + period_ns + 1 <= 0.1e9
        assert (stamps[-1] - stamps[0]) / 1e9 > 7.5  # from the start (calibrating) to the end
        states = [m.state for _, m in contacts]
        assert states[0] == 0 and 1 in states and 2 in states  # CALIBRATING, then FREE and TOUCHED
        for _, m in contacts:
            n = np.array([m.normal.x, m.normal.y, m.normal.z])
            assert abs(np.linalg.norm(n) - 1) < 1e-9  # unit, also at zero force and while calibrating
            assert m.touched == (m.state == 2) and (m.location == -1) == (m.state == 0) and m.model == "svm"
            assert m.force_n >= 0 and (m.force_n == 0 or m.touched)
            assert np.allclose([m.force.x, m.force.y, m.force.z], -m.force_n * n, atol=1e-12) and m.force_reliable
        by_stamp = {t: m for t, m in contacts}
        mine = [ev for ev in events if ev.link == link]
        touches = [ev for ev in mine if ev.kind == "touch"]
        assert len(touches) >= 5 and sum(m.touched for _, m in contacts) == len(touches)  # every touched chirp, no other
        for ev in mine:  # the event's chirp has its Contact: the same place, normal and force
            m = by_stamp[round(t0 * 1e9) + round(ev.t_s * 1e9)]
            assert m.touched == (ev.kind == "touch") and m.location == ev.location
            assert np.allclose([m.point.x, m.point.y, m.point.z], ev.point_m, atol=1e-6)
            assert np.allclose([m.normal.x, m.normal.y, m.normal.z], ev.normal, atol=1e-6)
            assert m.force_n == pytest.approx(ev.force_n, abs=1e-4) and m.confidence == pytest.approx(ev.confidence, abs=1e-4)


def test_the_contact_message_is_a_ros2_package_and_what_ros2_decodes():
    """sonicskin_msgs ships as a ROS 2 package (package.xml, CMakeLists.txt, msg/Contact.msg) and the MCAP schema is its
    .msg text; ROS 2's own parser (rosbags, Humble and Jazzy) reads that text and encodes the same bytes."""
    rosbags = pytest.importorskip("rosbags.typesys")
    from sonicskin.rosbag import CONTACT, definition, encode

    pkg = REPO / "sonicskin" / "msg" / "sonicskin_msgs"
    text = (pkg / "msg" / "Contact.msg").read_text()
    assert definition(CONTACT).startswith(text) and "MSG: geometry_msgs/Point" in definition(CONTACT)
    assert "<name>sonicskin_msgs</name>" in (pkg / "package.xml").read_text()
    assert '"msg/Contact.msg"' in (pkg / "CMakeLists.txt").read_text()
    msg = {"header": {"stamp": {"sec": 1, "nanosec": 2}, "frame_id": "forearm_link"}, "link": "forearm", "state": 2,
           "touched": True, "location": 7, "point": {"x": 0.01, "y": 0.02, "z": 0.03}, "normal": {"x": 1.0, "y": 0.0, "z": 0.0},
           "force_n": 2.5, "force": {"x": -2.5, "y": 0.0, "z": 0.0}, "force_reliable": True, "confidence": 0.75, "model": "svm"}
    data = encode(CONTACT, msg)
    for distro in ("ROS2_HUMBLE", "ROS2_JAZZY"):
        ts = rosbags.get_typestore(getattr(rosbags.Stores, distro))
        ts.register(rosbags.get_types_from_msg(text, CONTACT))
        back = ts.deserialize_cdr(data, CONTACT)
        assert (back.link, back.state, back.touched, back.location, back.force_n, back.model) == ("forearm", 2, True, 7, 2.5, "svm")
        assert (back.TOUCHED, back.FREE, back.CALIBRATING) == (2, 1, 0)
        assert bytes(ts.serialize_cdr(back, CONTACT)) == data


def test_a_live_run_killed_hard_loses_at_most_its_last_second(arm, tmp_path):
    """`live --mcap` killed with SIGKILL mid-run: `python -m sonicskin.rosbag` recovers every message older than a
    second before the last event the run printed (each chunk reaches the disk within a second of stream)."""
    import os
    import signal
    import subprocess
    import sys

    cmd = [sys.executable, "-m", "sonicskin", "live", "--links", str(arm), "--fast", "--duration", "60", "--no-status",
           "--mcap", str(tmp_path / "killed.mcap")]
    child = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    printed = []
    try:
        for line in child.stdout:  # the events as the run prints them, each flushed
            printed.append(json.loads(line))
            if printed[-1]["t_s"] >= 7.0:
                os.kill(child.pid, signal.SIGKILL)
                break
        printed += [json.loads(x) for x in child.stdout.read().splitlines() if x.endswith("}")]
    finally:
        child.kill()
        child.wait(timeout=60)
    assert child.returncode == -signal.SIGKILL
    fixed = tmp_path / "fixed.mcap"
    r = subprocess.run([sys.executable, "-m", "sonicskin.rosbag", str(tmp_path / "killed.mcap"), str(fixed)],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0 and r.stdout.startswith(f"{fixed}: ") and "messages recovered" in r.stdout, r.stderr
    msgs = _messages(fixed)
    t0_ns = next(t for topic, _, t, _ in msgs if topic == "/robot_description")
    have = {}
    for topic, _, t, m in msgs:
        if topic.endswith("/contact_point"):
            have.setdefault(m.header.frame_id, []).append((t - t0_ns) / 1e9)
    t_last = max(ev["t_s"] for ev in printed)
    older = [ev for ev in printed if ev["t_s"] <= t_last - 1.0]
    assert len(older) > 20
    for ev in older:  # its point is there (the printed t_s has 4 decimals)
        assert np.min(np.abs(np.asarray(have[ev["frame_id"]]) - ev["t_s"])) < 1e-4, ev
    assert max(t for _, _, t, _ in msgs) >= t0_ns + (t_last - 1.0) * 1e9
    bad = subprocess.run([sys.executable, "-m", "sonicskin.rosbag", str(tmp_path / "none.mcap")], capture_output=True, text=True)
    assert bad.returncode == 1 and bad.stderr.startswith("usage: python -m sonicskin.rosbag IN.mcap OUT.mcap")
