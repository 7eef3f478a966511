"""Touch on the robot's own bus (issue 35): every link's Contact at a fixed rate with its state, the MCAP file that
lasts (chunked, zstd, a kill -9 loses at most its last second), the robot's URDF and transforms, and the same messages
live over DDS (ROS 2 topics, a subscriber in another process) and Foxglove's WebSocket (a client that subscribes)."""

from __future__ import annotations

import json
import math
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


def _matrix(tf) -> np.ndarray:
    """The 4x4 of a geometry_msgs/Transform (a decoded message or the dict sent)."""
    g = (lambda o, k: o[k]) if isinstance(tf, dict) else getattr
    t, q = g(tf, "translation"), g(tf, "rotation")
    x, y, z, w = (g(q, k) for k in "xyzw")
    T = np.eye(4)
    T[:3, :3] = [[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                 [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                 [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]]
    T[:3, 3] = [g(t, k) for k in "xyz"]
    return T


def test_the_robot_its_static_transforms_and_joint_states(arm, tmp_path):
    """The MCAP file opens with /robot_description (the URDF the arm file names) and /tf_static (every joint at zero);
    Listener.set_joint_state adds /joint_states and the /tf of those joints: each transform what yourdfpy's forward
    kinematics of the same URDF gives."""
    yourdfpy = pytest.importorskip("yourdfpy")
    from sonicskin.api import Listener
    from sonicskin.errors import SonicskinError

    urdf = arm.parent / "arm6.urdf"
    model = yourdfpy.URDF.load(str(urdf), build_scene_graph=True, load_meshes=False)
    lst = Listener(arm, fast=True, duration_s=6, mcap=tmp_path / "a.mcap")
    lst.set_joint_state({"elbow_joint": 0.5})  # before the run: sent at its start
    for bad, why in (({"knee": 1.0}, "'knee'"), ({"elbow_joint": math.nan}, "nan"), ([0.5], "[0.5]"), ({}, "{}")):
        with pytest.raises(SonicskinError) as e:
            lst.set_joint_state(bad)
        assert str(e.value).startswith("joint positions are a dict of joint name -> finite rad (or m) over the URDF's "
                                       "moving joints ['elbow_joint', 'shoulder_lift_joint', ") and why in str(e.value)
    from sonicskin.rosbag import McapEventWriter

    with McapEventWriter(tmp_path / "no-urdf.mcap", t0_unix_s=0) as w, pytest.raises(SonicskinError) as e:
        w.joints({"elbow_joint": 0.5})
    assert str(e.value).startswith("joint states move the joints of the arm's URDF, and this run has none (an arm file ")
    later = {"elbow_joint": -0.25, "wrist_roll_joint": 1.0, "shoulder_pan_joint": 2.0}
    for i, _ in enumerate(lst):
        if i == 0:
            lst.set_joint_state(later, t_unix_s=1_800_000_000.5)
    msgs = _messages(tmp_path / "a.mcap")
    t0 = round(lst.opened.mcap.t0_unix_s * 1e9)
    topic, schema, t, desc = msgs[0]
    assert (topic, schema, t, desc.data) == ("/robot_description", "std_msgs/msg/String", t0, urdf.read_text())
    assert urdf.read_text() == (REPO / "configs" / "arms" / "arm6.urdf").read_text()
    topic, schema, t, static = msgs[1]
    assert (topic, schema, t) == ("/tf_static", "tf2_msgs/msg/TFMessage", t0)
    assert len(static.transforms) == len(model.joint_map) == 5
    for tf in static.transforms:
        j = next(j for j in model.joint_map.values() if j.child == tf.child_frame_id)
        assert tf.header.frame_id == j.parent and _ns(tf.header.stamp) == t0
        np.testing.assert_allclose(_matrix(tf.transform), j.origin, atol=1e-12)
    states = [(t, m) for topic, _, t, m in msgs if topic == "/joint_states"]
    moved = [(t, m) for topic, _, t, m in msgs if topic == "/tf" and not m.transforms[0].child_frame_id.endswith("_contact")]
    assert [(t, list(m.name), list(m.position)) for t, m in states] == [
        (t0, ["elbow_joint"], [0.5]), (1_800_000_000_500_000_000, sorted(later), [later[k] for k in sorted(later)])]
    assert [t for t, _ in moved] == [t for t, _ in states]
    for (_, m), cfg in zip(moved, ({"elbow_joint": 0.5}, later)):
        model.update_cfg({k: cfg.get(k, 0.0) for k in model.actuated_joint_names})
        assert len(m.transforms) == len(cfg)
        for tf in m.transforms:
            np.testing.assert_allclose(_matrix(tf.transform), model.get_transform(tf.child_frame_id, tf.header.frame_id),
                                       atol=1e-12)


def test_joint_transforms_follow_the_urdf_conventions():
    """rpy origins (URDF's fixed-axis roll, pitch, yaw), revolute and prismatic joints on tilted axes: the transforms
    published are yourdfpy's."""
    yourdfpy = pytest.importorskip("yourdfpy")
    import io

    from sonicskin.rosbag import _joint_tf, urdf_joints

    text = """<robot name="r"><link name="a"/><link name="b"/><link name="c"/><link name="d"/>
      <joint name="j1" type="revolute"><parent link="a"/><child link="b"/><origin xyz="0.1 -0.2 0.3" rpy="0.3 -1.1 2.5"/>
        <axis xyz="0.6 0 0.8"/><limit lower="-3" upper="3" effort="1" velocity="1"/></joint>
      <joint name="j2" type="prismatic"><parent link="b"/><child link="c"/><origin xyz="0 0.05 0" rpy="1.2 0.4 -0.7"/>
        <axis xyz="0 1 1"/><limit lower="-1" upper="1" effort="1" velocity="1"/></joint>
      <joint name="j3" type="fixed"><parent link="c"/><child link="d"/><origin rpy="0 1.5707963 0"/></joint></robot>"""
    model = yourdfpy.URDF.load(io.StringIO(text), build_scene_graph=True, load_meshes=False)
    joints = urdf_joints(text)
    for cfg in ({"j1": 0.0, "j2": 0.0}, {"j1": 0.7, "j2": -0.3}, {"j1": -2.9, "j2": 0.9}):
        model.update_cfg(cfg)
        for name, j in joints.items():
            tf = _joint_tf(j, cfg.get(name, 0.0), 0)
            assert (tf["header"]["frame_id"], tf["child_frame_id"]) == (j["parent"], j["child"])
            np.testing.assert_allclose(_matrix(tf["transform"]), model.get_transform(j["child"], j["parent"]), atol=1e-9)


# -- live: ROS 2 over DDS ---------------------------------------------------------------------------------------------
# Cyclone DDS on the loopback interface alone, discovery by unicast to 127.0.0.1: nothing leaves this machine.
LOOPBACK = ('<CycloneDDS><Domain Id="any"><General><Interfaces><NetworkInterface name="lo"/></Interfaces>'
            '<AllowMulticast>false</AllowMulticast></General><Discovery><ParticipantIndex>auto</ParticipantIndex>'
            '<MaxAutoParticipantIndex>30</MaxAutoParticipantIndex><Peers><Peer address="127.0.0.1"/></Peers></Discovery>'
            '</Domain></CycloneDDS>')
FRAMES = ["forearm_link", "hand_plate"]


@pytest.fixture(scope="module")
def dds_run(arm, tmp_path_factory):
    """`live --ros2 DOMAIN --mcap F` on the arm while tests/ros2_subscriber.py subscribes in another process: what it
    received and what discovery announced, the run's MCAP file, and the run's stderr."""
    pytest.importorskip("cyclonedds")
    import os
    import subprocess
    import sys
    import time

    from sonicskin.rosbag import topics

    root = tmp_path_factory.mktemp("dds")
    domain = 100 + os.getpid() % 100  # its own domain: another test run on this machine does not cross it
    env = {**os.environ, "CYCLONEDDS_URI": LOOPBACK}
    (root / "topics.json").write_text(json.dumps(topics(FRAMES)))
    sub = subprocess.Popen([sys.executable, str(REPO / "tests" / "ros2_subscriber.py"), str(domain), str(root / "topics.json"),
                            str(root / "got.json"), str(root / "stop")], env=env, stdout=subprocess.PIPE, text=True)
    try:
        assert sub.stdout.readline().strip() == "ready"
        run = subprocess.run([sys.executable, "-m", "sonicskin", "live", "--links", str(arm), "--fast", "--duration", "6",
                              "--no-status", "--ros2", str(domain), "--mcap", str(root / "run.mcap")], env=env,
                             capture_output=True, text=True, timeout=600)
        assert run.returncode == 0, run.stderr[-2000:]
        time.sleep(1.0)  # what is still in the subscriber's socket reaches its readers
        (root / "stop").touch()
        assert sub.wait(timeout=120) == 0
    finally:
        sub.kill()
    return json.loads((root / "got.json").read_text()), root / "run.mcap", run.stderr


def test_a_ros2_subscriber_in_another_process_receives_every_message(dds_run):
    """Every message of the run's MCAP file reaches the subscriber over DDS, byte for byte, and ROS 2's own types
    (rosbags' Jazzy store, sonicskin_msgs from its .msg) decode each one."""
    import base64

    rosbags = pytest.importorskip("rosbags.typesys")
    from mcap.reader import make_reader

    got, mcap, stderr = dds_run
    assert "sonicskin live: the ROS 2 publisher is on DDS domain" in stderr
    with open(mcap, "rb") as f:
        sent = [(c.topic, s.name, m.data) for s, c, m in make_reader(f).iter_messages(log_time_order=False)]  # as sent
    ts = rosbags.get_typestore(rosbags.Stores.ROS2_JAZZY)
    ts.register(rosbags.get_types_from_msg((REPO / "sonicskin/msg/sonicskin_msgs/msg/Contact.msg").read_text(),
                                           "sonicskin_msgs/msg/Contact"))
    types = dict((t, s) for t, s, _ in sent)
    assert len(sent) > 500 and {t for t, _, _ in sent} >= {"/robot_description", "/tf_static", "/tf", "/sonicskin/markers",
                                                            *(f"/sonicskin/{f}/contact{w}" for f in FRAMES
                                                              for w in ("", "_point", "_wrench"))}
    for topic in types:
        mine = [d for t, _, d in sent if t == topic]
        theirs = [base64.b64decode(x) for x in got["messages"][topic]]
        assert theirs == mine, (topic, len(theirs), len(mine))  # every message, in order, the same bytes
        for data in theirs:
            msg = ts.deserialize_cdr(data, types[topic])
            assert bytes(ts.serialize_cdr(msg, types[topic])) == data
    contact = ts.deserialize_cdr(base64.b64decode(got["messages"]["/sonicskin/hand_plate/contact"][-1]),
                                 "sonicskin_msgs/msg/Contact")
    assert contact.link == "hand" and contact.header.frame_id == "hand_plate" and contact.model == "svm"


def test_ros2_topic_and_type_names_and_qos_are_a_ros2_nodes(dds_run):
    """What DDS discovery announces is what a ROS 2 node (rmw_cyclonedds, rmw_fastrtps) expects: ``rt/`` topics, types
    ``pkg::msg::dds_::Type_``, the sensor stream best effort, /tf reliable, the URDF and /tf_static latched."""
    got, _, _ = dds_run
    pubs = got["publications"]
    want = {"rt/robot_description": ["std_msgs::msg::dds_::String_", "Reliable", "TransientLocal"],
            "rt/tf_static": ["tf2_msgs::msg::dds_::TFMessage_", "Reliable", "TransientLocal"],
            "rt/tf": ["tf2_msgs::msg::dds_::TFMessage_", "Reliable", "Volatile"],
            "rt/joint_states": ["sensor_msgs::msg::dds_::JointState_", "Reliable", "Volatile"],
            "rt/sonicskin/markers": ["visualization_msgs::msg::dds_::MarkerArray_", "BestEffort", "Volatile"]}
    for f in FRAMES:
        want |= {f"rt/sonicskin/{f}/contact": ["sonicskin_msgs::msg::dds_::Contact_", "BestEffort", "Volatile"],
                 f"rt/sonicskin/{f}/contact_point": ["geometry_msgs::msg::dds_::PointStamped_", "BestEffort", "Volatile"],
                 f"rt/sonicskin/{f}/contact_wrench": ["geometry_msgs::msg::dds_::WrenchStamped_", "BestEffort",
                                                      "Volatile"]}
    assert pubs == want


def test_bad_bus_options_are_one_line(arm, tmp_path, capsys, monkeypatch):
    """A domain out of range, a bad ROS_DOMAIN_ID, no cyclonedds or foxglove-sdk installed, a taken or bad Foxglove port:
    one line each naming the problem and the fix, before the models load."""
    import subprocess
    import sys

    cases = [(["--ros2", "300"], "--ros2 300: a ROS 2 domain id is an integer 0-232 (0-101 on every OS), the one the robot's "
                                 "nodes use (their ROS_DOMAIN_ID)"),
             (["--ros2", "x"], "--ros2 x: a ROS 2 domain id is an integer 0-232"),
             (["--foxglove", "70000"], "--foxglove '70000': give a TCP port 1-65535 (or 0 for any free one, or --foxglove "
                                       "alone for Foxglove's 8765)")]
    for extra, message in cases:
        assert main(["live", "--links", str(arm), "--fast", "--duration", "1", "--no-status", *extra]) == 2
        err = capsys.readouterr().err.strip()
        assert message in err and len(err.splitlines()) == 1 and "Traceback" not in err
    monkeypatch.setenv("ROS_DOMAIN_ID", "-3")
    assert main(["live", "--links", str(arm), "--fast", "--duration", "1", "--no-status", "--ros2"]) == 2
    assert "ROS_DOMAIN_ID='-3': a ROS 2 domain id is an integer 0-232" in capsys.readouterr().err
    monkeypatch.delenv("ROS_DOMAIN_ID")
    for module, option, package in (("cyclonedds", "--ros2", "cyclonedds"), ("foxglove", "--foxglove", "foxglove-sdk")):
        code = (f"import sys; sys.modules[{module!r}] = None  # as if not installed\n"
                f"from sonicskin.cli import main; sys.exit(main(['live', '--links', {str(arm)!r}, '--fast', '--no-status', "
                f"{option!r}]))")
        r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
        assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr
        assert f"{option}/{option[2:]}= needs {package} (" in r.stderr and r.stderr.strip().endswith(
            "pip install 'sonicskin[ros]'")
    pytest.importorskip("foxglove")
    import socket

    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        assert main(["live", "--links", str(arm), "--fast", "--duration", "1", "--no-status", "--foxglove", str(port),
                     "--mcap", str(tmp_path / "a.mcap")]) == 2
        err = capsys.readouterr().err.strip()
    assert err == (f"sonicskin live: error: --foxglove {port}: cannot serve on 127.0.0.1:{port} (Failed to bind port: "
                   f"Address already in use (os error 98)); pick another port, or 0 for any free one")
    assert not (tmp_path / "a.mcap").exists()  # refused before anything was recorded


# -- live: Foxglove's WebSocket -----------------------------------------------------------------------------------------
def _foxglove_client(url: str, got: list, ready, stop) -> None:
    """A Foxglove WebSocket client: subscribes to every channel the server advertises and keeps each message as
    (topic, schema name, schema text, log time, payload)."""
    import struct

    from websockets.sync.client import connect

    channels = {}
    with connect(url, subprotocols=["foxglove.sdk.v1", "foxglove.websocket.v1"]) as ws:
        while not stop.is_set():
            try:
                m = ws.recv(timeout=0.2)
            except TimeoutError:
                ready.set()  # every channel announced so far is subscribed
                continue
            except Exception:  # the server stopped: the run is over
                break
            if isinstance(m, str):
                d = json.loads(m)
                if d["op"] == "advertise":
                    subs = [{"id": c["id"], "channelId": c["id"]} for c in d["channels"]]
                    channels |= {c["id"]: c for c in d["channels"]}
                    ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))
            elif m[0] == 1:  # message data: opcode, subscription id, log time, payload
                sub, t = struct.unpack_from("<IQ", m, 1)
                c = channels[sub]
                got.append((c["topic"], c["schemaName"], c["schema"], t, bytes(m[13:])))
                ready.set()


def test_a_foxglove_client_subscribes_and_decodes_every_channel(arm, tmp_path):
    """`foxglove=` serves the run's channels on 127.0.0.1 (ros2msg schemas, cdr messages): a WebSocket client subscribed
    before the run starts gets every message of the MCAP file, byte for byte, each decoded with its own schema; one
    that subscribes after the start still gets /robot_description and /tf_static."""
    pytest.importorskip("foxglove")
    pytest.importorskip("websockets")
    import threading
    import time

    from mcap.reader import make_reader
    from mcap.records import Schema
    from mcap_ros2.decoder import DecoderFactory

    from sonicskin.api import Listener

    lst = Listener(arm, fast=True, duration_s=6, mcap=tmp_path / "a.mcap", foxglove=0)
    (bus,) = lst.opened.buses
    assert bus.url.startswith("ws://127.0.0.1:") and bus.server.port > 0
    got, ready, stop = [], threading.Event(), threading.Event()
    client = threading.Thread(target=_foxglove_client, args=(bus.url, got, ready, stop), daemon=True)
    client.start()
    assert ready.wait(60)
    events = list(lst)
    assert len(events) > 20
    stop.set()
    client.join(60)
    with open(tmp_path / "a.mcap", "rb") as f:
        sent = [(c.topic, s.name, m.log_time, m.data) for s, c, m in make_reader(f).iter_messages(log_time_order=False)]
    assert [g[:2] + g[3:] for g in got] == sent  # every message, in order, the same bytes and log times
    decoders = {}
    for _topic, name, schema, _, data in got:
        if name not in decoders:
            decoders[name] = DecoderFactory().decoder_for("cdr", Schema(id=len(decoders) + 1, name=name, encoding="ros2msg",
                                                                        data=schema.encode()))
        dec = decoders[name]
        msg = dec(data)
        if name == "sonicskin_msgs/msg/Contact":
            assert msg.header.frame_id in FRAMES and abs(math.hypot(msg.normal.x, msg.normal.y, msg.normal.z) - 1) < 1e-9
    assert {t for t, *_ in got} >= {"/robot_description", "/tf_static", "/sonicskin/markers", "/sonicskin/hand_plate/contact"}
    # a client that connects during a run, after the latched messages went out, gets them when it subscribes
    late, late_ready = [], threading.Event()
    lst = Listener(arm, fast=False, duration_s=30, foxglove=0)
    lst.start()
    for _ in lst:  # the stream is on
        break
    stop = threading.Event()
    client = threading.Thread(target=_foxglove_client, args=(lst.opened.buses[0].url, late, late_ready, stop), daemon=True)
    client.start()
    assert late_ready.wait(60)
    time.sleep(0.5)  # its subscriptions answered
    lst.stop()
    stop.set()
    client.join(60)
    urdf = [d for t, _, _, _, d in late if t == "/robot_description"]
    assert len(urdf) == 1 and (arm.parent / "arm6.urdf").read_text() in urdf[0].decode(errors="replace")
    assert [t for t, *_ in late].count("/tf_static") == 1


def test_the_shipped_foxglove_layout_opens_the_3d_panel_on_the_arm():
    """configs/arms/arm6.foxglove.json is what foxglove-sdk's layout classes write (tools/foxglove_layout.py): a 3D panel
    following the URDF's root frame, showing the robot from /robot_description, the markers and every link's wrench,
    beside a plot of every link's contact force."""
    pytest.importorskip("foxglove.layouts")
    import subprocess
    import sys

    from sonicskin.links import load_links
    from sonicskin.rig import Rig
    from sonicskin.rosbag import urdf_joints

    r = subprocess.run([sys.executable, str(REPO / "tools" / "foxglove_layout.py"), "--check"], capture_output=True, text=True)
    assert r.returncode == 0, "the shipped layout differs: run python tools/foxglove_layout.py"
    layout = json.loads((REPO / "configs" / "arms" / "arm6.foxglove.json").read_text())

    def panels(node):
        if node.get("type") == "panel":
            yield node
        for item in node.get("items", []):
            yield from panels(item["content"])

    by_type = {p["panelType"]: p["config"] for p in panels(layout["content"])}
    frames = [lk.surface.frame_id for lk in load_links("arm6", Rig.load("fast"))]
    joints = urdf_joints((REPO / "configs" / "arms" / "arm6.urdf").read_text())
    root = ({j["parent"] for j in joints.values()} - {j["child"] for j in joints.values()}).pop()
    three_d = by_type["ThreeDee"]
    assert three_d["followTf"] == root == "base_link"
    assert three_d["topics"]["/robot_description"]["visible"] and three_d["topics"]["/sonicskin/markers"]["visible"]
    assert all(three_d["topics"][f"/sonicskin/{f}/contact_wrench"]["visible"] for f in frames)
    assert [p["value"] for p in by_type["Plot"]["paths"]] == [f"/sonicskin/{f}/contact.force_n" for f in frames]


# -- force you can trust ----------------------------------------------------------------------------------------------
def test_a_force_no_better_than_a_constant_is_marked_and_its_wrench_not_published(tmp_path, capsys, arm):
    """arm6's wrist with a broken force sensor (its readings shuffled among all touch chirps): the validated force RMSE
    is worse than a constant's. fit-svm and compare say so, skin.json marks the SVM's force_reliable false, its events
    and Contact say so, and no wrench goes out for it; the forearm's force (better than a constant) is marked reliable
    and its wrenches go out."""
    import re

    from cli_helpers import reseal

    from sonicskin.api import Listener
    from sonicskin.artifact_schema import validate_skin
    from sonicskin.errors import ArtifactError

    shutil.copyfile(REPO / "configs" / "arms" / "arm6.urdf", tmp_path / "arm6.urdf")
    wrist = next(d for d in yaml.safe_load((REPO / "configs" / "arms" / "arm6.yaml").read_text())["links"] if d["name"] == "wrist")
    f = tmp_path / "arm.yaml"
    f.write_text(yaml.safe_dump({"name": "w", "rig": "fast", "urdf": "arm6.urdf", "duplex": "none",
                                 "links": [{**wrist, "tx": 0, "rx": 0}]}))
    assert main(["simulate", "--links", str(f), "--out", str(tmp_path / "data"), "--quiet"]) == 0
    parts = sorted((tmp_path / "data" / "wrist").glob("s0*/part-*.csv"))  # every touch's reading moved to another touch
    rows = {p: p.read_text().splitlines() for p in parts}
    cols = rows[parts[0]][0].split(",")
    cells = {p: [r.split(",") for r in rows[p][1:]] for p in parts}
    touch = [(p, i) for p in parts for i, c in enumerate(cells[p]) if int(c[cols.index("location")]) >= 0]
    for (p, i), v in zip(touch, np.random.default_rng(0).permutation([cells[p][i][cols.index("force_n")] for p, i in touch])):
        cells[p][i][cols.index("force_n")] = v
    for p in parts:
        p.write_text("\n".join([rows[p][0]] + [",".join(c) for c in cells[p]]) + "\n")
    for sess in sorted((tmp_path / "data" / "wrist").glob("s0*")):
        reseal(sess)
    assert main(["fit-svm", "--links", str(f), "--data", str(tmp_path / "data"), "--out", str(tmp_path / "art"), "--n-bins",
                 "300"]) == 0
    line = re.search(r"svm force UNRELIABLE: validated RMSE [\d.]+ N, a constant's [\d.]+ N \(its events say "
                     r"force_reliable false; no wrench is published\)", capsys.readouterr().out).group(0)
    skin = json.loads((tmp_path / "art" / "wrist" / "skin.json").read_text())
    assert skin["models"]["svm"]["force_reliable"] is False
    assert json.loads((arm.parent / "forearm" / "skin.json").read_text())["models"]["svm"]["force_reliable"] is True
    assert main(["compare", "--data", str(tmp_path / "data" / "wrist"), "--artifact", str(tmp_path / "art" / "wrist"),
                 "--test", "s001", "--out", str(tmp_path / "cmp")]) == 0
    assert f"expected at training: {line}" in capsys.readouterr().out
    with pytest.raises(ArtifactError, match=r"models.svm.force_reliable must be true or false, got 'no'"):
        validate_skin({**skin, "models": {"svm": {**skin["models"]["svm"], "force_reliable": "no"}}})
    events = list(Listener(tmp_path / "art", fast=True, duration_s=8, mcap=tmp_path / "w.mcap"))
    assert len(events) > 20 and all(ev.force_reliable is False and '"force_reliable": false' in ev.to_json() for ev in events)
    msgs = _messages(tmp_path / "w.mcap")
    topics = {topic for topic, *_ in msgs}
    assert "/sonicskin/wrist_link/contact_point" in topics and "/sonicskin/wrist_link/contact_wrench" not in topics
    contacts = [m for topic, _, _, m in msgs if topic == "/sonicskin/wrist_link/contact"]
    assert contacts and not any(m.force_reliable for m in contacts)
    arrows = [m.markers[0] for topic, _, _, m in msgs if topic == "/sonicskin/markers" and m.markers[0].action == 0]
    for a in arrows:  # the arrow says where, not how hard: its base length
        assert math.dist(*([p.x, p.y, p.z] for p in a.points)) == pytest.approx(0.01)
    events = list(Listener(arm, fast=True, duration_s=6))  # the trusted links
    assert events and all(ev.force_reliable is True for ev in events)
