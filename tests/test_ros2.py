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
