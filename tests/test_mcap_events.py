"""Touch events as ROS 2 messages in MCAP (sonicskin.rosbag), decoded back with mcap-ros2-support's own reader and
checked one for one against the events."""

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest

from sonicskin.events import TouchEvent, attach_surface
from sonicskin.rosbag import MARKER_TOPIC, McapEventWriter, topic_for
from sonicskin.surface import LinkSurface

ARM = Path(__file__).resolve().parents[1] / "configs" / "arms" / "arm6.urdf"
T0 = 1_795_000_000.25  # the stream's t_s = 0 as UNIX seconds
PERIOD = 0.10667


def _events():
    """Two links pressed in turn (forearm tube, hand plate), each press a few touches then one release."""
    fore, hand = LinkSurface.from_urdf(ARM, "forearm_link"), LinkSurface.from_urdf(ARM, "hand_plate")
    out, k = [], 0
    for surf, link, xy in ((fore, "forearm", [(3.0, 5.0), (3.2, 5.1), (3.1, 5.0)]), (hand, "hand", [(10.0, 20.0), (11.0, 19.0)]),
                           (fore, "forearm", [(20.0, 22.0)])):
        for i, (x, y) in enumerate(xy):
            out.append(attach_surface(TouchEvent(k * PERIOD, "touch", i, x, y, 1.0 + i, 0.9, "svm", 0.5, link=link), surf))
            k += 1
        out.append(attach_surface(TouchEvent(k * PERIOD, "release", 0, x, y, 0.0, 0.9, "svm", 0.5, link=link), surf))
        k += 1
    return out


class _Msg:
    def __init__(self, schema, channel, message, ros_msg):
        self.schema, self.channel, self.log_time_ns, self.ros_msg = schema, channel, message.log_time, ros_msg


def read_ros2_messages(path):
    """Every message of the file, decoded by the library's own reader (mcap's reader with mcap-ros2's decoder)."""
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    with open(path, "rb") as f:
        return [_Msg(*r) for r in make_reader(f, decoder_factories=[DecoderFactory()]).iter_decoded_messages()]


def _raw(path):
    """(topic, log time, CDR bytes) of every message of the file."""
    from mcap.reader import make_reader

    with open(path, "rb") as f:
        return [(c.topic, m.log_time, m.data) for _, c, m in make_reader(f).iter_messages()]


def _rotation(q):
    """The rotation matrix of a quaternion (x, y, z, w)."""
    x, y, z, w = q
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def _stamp_ns(msg):
    return msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec


def test_every_message_matches_its_event(tmp_path):
    events = _events()
    path = tmp_path / "arm.mcap"
    with McapEventWriter(path, t0_unix_s=T0) as w:
        for ev in events:
            w.write(ev)
    assert (w.written, w.skipped, w.messages) == (len(events), 0, 4 * len(events))
    msgs = read_ros2_messages(path)
    assert len(msgs) == 4 * len(events)  # every press ended in a release: no DELETE added on close
    by_topic = {}
    for m in msgs:
        by_topic.setdefault(m.channel.topic, []).append(m)
    assert set(by_topic) == {"/sonicskin/forearm_link/contact_point", "/sonicskin/forearm_link/contact_wrench",
                             "/sonicskin/hand_plate/contact_point", "/sonicskin/hand_plate/contact_wrench", MARKER_TOPIC, "/tf"}
    assert {m.schema.name for m in msgs} == {"geometry_msgs/msg/PointStamped", "geometry_msgs/msg/WrenchStamped",
                                            "visualization_msgs/msg/MarkerArray", "tf2_msgs/msg/TFMessage"}
    seen = {t: 0 for t in by_topic}
    for ev in events:
        ns = round(T0 * 1e9) + round(ev.t_s * 1e9)
        pt = by_topic[topic_for(ev.frame_id, "contact_point")][seen[topic_for(ev.frame_id, "contact_point")]]
        wr = by_topic[topic_for(ev.frame_id, "contact_wrench")][seen[topic_for(ev.frame_id, "contact_wrench")]]
        mk = by_topic[MARKER_TOPIC][seen[MARKER_TOPIC]]
        tf = by_topic["/tf"][seen["/tf"]].ros_msg.transforms
        for t in (topic_for(ev.frame_id, "contact_point"), topic_for(ev.frame_id, "contact_wrench"), MARKER_TOPIC, "/tf"):
            seen[t] += 1
        for m in (pt, wr, mk):
            assert m.log_time_ns == ns
        p = np.array([pt.ros_msg.point.x, pt.ros_msg.point.y, pt.ros_msg.point.z])
        f = np.array([wr.ros_msg.wrench.force.x, wr.ros_msg.wrench.force.y, wr.ros_msg.wrench.force.z])
        tau = np.array([wr.ros_msg.wrench.torque.x, wr.ros_msg.wrench.torque.y, wr.ros_msg.wrench.torque.z])
        assert pt.ros_msg.header.frame_id == ev.frame_id and _stamp_ns(pt.ros_msg) == ns
        assert p.tolist() == list(ev.point_m)  # float64 on both sides: exact
        # the wrench in the contact frame, which /tf puts at the point with its z the outward normal (at the same stamp)
        assert wr.ros_msg.header.frame_id == f"{ev.frame_id}_contact" and _stamp_ns(wr.ros_msg) == ns
        assert len(tf) == 1 and (tf[0].header.frame_id, tf[0].child_frame_id) == (ev.frame_id, f"{ev.frame_id}_contact")
        assert _stamp_ns(tf[0]) == ns
        tr, q = tf[0].transform.translation, tf[0].transform.rotation
        np.testing.assert_allclose([tr.x, tr.y, tr.z], p)
        R = _rotation([q.x, q.y, q.z, q.w])
        np.testing.assert_allclose(R[:, 2], ev.normal, atol=1e-12)  # the contact frame's z: the outward normal
        np.testing.assert_allclose(f, [0.0, 0.0, -ev.force_n])
        np.testing.assert_allclose(tau, 0.0)
        np.testing.assert_allclose(R @ f, -ev.force_n * np.array(ev.normal), atol=1e-12)  # in the link frame: force_vec_n
        markers = mk.ros_msg.markers
        assert len(markers) == 2 and [(k.ns, k.id) for k in markers] == [(f"sonicskin/{ev.frame_id}", 0), (f"sonicskin/{ev.frame_id}", 1)]
        assert all(k.header.frame_id == ev.frame_id and _stamp_ns(k) == ns for k in markers)
        if ev.kind == "release":
            assert [k.action for k in markers] == [2, 2]  # DELETE that link's arrow and sphere
            assert f.tolist() == [0.0, 0.0, 0.0]
        else:
            arrow, sphere = markers
            assert (arrow.type, arrow.action, sphere.type, sphere.action) == (0, 0, 2, 0)
            tail, tip = (np.array([q.x, q.y, q.z]) for q in arrow.points)
            np.testing.assert_allclose(tip, p)
            np.testing.assert_allclose(tail - tip, (0.01 + 0.02 * ev.force_n) * np.array(ev.normal), atol=1e-12)
            np.testing.assert_allclose([sphere.pose.position.x, sphere.pose.position.y, sphere.pose.position.z], p)
    assert seen == {t: len(v) for t, v in by_topic.items()}  # nothing left over


def test_events_without_a_surface_are_counted_with_one_warning(tmp_path):
    events = _events()
    bare = [TouchEvent(9.0 + i, "touch", 0, 1.0, 1.0, 1.0, 0.9, "svm", 0.5) for i in range(3)]
    logged = []
    with McapEventWriter(tmp_path / "a.mcap", t0_unix_s=T0, log=logged.append) as w:
        for ev in [events[0], *bare, events[1]]:
            w.write(ev)
    assert (w.written, w.skipped) == (2, 3)
    assert logged == [f"warning: {tmp_path / 'a.mcap'}: an event without the robot-frame fields (no surface for link "
                      "(single link)) is not written to the MCAP file; give the link a surface (frame, URDF) to record it"]
    assert len(read_ros2_messages(tmp_path / "a.mcap")) == 8 + 1  # + the markers' DELETE on close (still pressed)


def test_no_force_model_writes_no_wrench_and_a_short_arrow(tmp_path):
    ev = _events()[0]
    fore = LinkSurface.from_urdf(ARM, "forearm_link")
    ev = attach_surface(TouchEvent(0.0, "touch", 0, ev.x_cm, ev.y_cm, math.nan, 0.9, "svm", 0.5), fore)
    with McapEventWriter(tmp_path / "a.mcap", t0_unix_s=T0) as w:
        w.write(ev)
    topics = [m.channel.topic for m in read_ros2_messages(tmp_path / "a.mcap")]
    assert topics == ["/sonicskin/forearm_link/contact_point", "/tf", MARKER_TOPIC, MARKER_TOPIC]  # the last: DELETE on close


def test_ctrl_c_finalises_the_file_and_clears_the_markers(tmp_path):
    events = _events()[:5]  # the forearm pressed and released, the hand still pressed when Ctrl-C comes
    path = tmp_path / "a.mcap"
    with pytest.raises(KeyboardInterrupt):
        with McapEventWriter(path, t0_unix_s=T0) as w:
            for ev in events:
                w.write(ev)
            raise KeyboardInterrupt
    msgs = read_ros2_messages(path)  # a complete file: the summary written on the way out
    marker_arrays = [m for m in msgs if m.channel.topic == MARKER_TOPIC]
    assert len(msgs) == 4 * 5 + 1 and len(marker_arrays) == 6
    last = marker_arrays[-1]
    assert [(k.ns, k.action) for k in last.ros_msg.markers] == [("sonicskin/hand_plate", 2)] * 2
    assert last.log_time_ns == round(T0 * 1e9) + round(events[-1].t_s * 1e9)


def test_a_writer_killed_hard_loses_at_most_its_last_second(tmp_path):
    """Chunks close and reach the disk at least once a second of stream: the bytes of a writer that never closed its
    file (a kill -9) hold every message older than a second before its last one, and recover() makes them a file."""
    from sonicskin.rosbag import CHUNK_BYTES, recover

    fore = LinkSurface.from_urdf(ARM, "forearm_link")
    events = [attach_surface(TouchEvent(k * 0.05, "touch", 0, 3.0, 5.0, 1.0, 0.9, "svm", 0.5, link="f"), fore) for k in range(90)]
    w = McapEventWriter(tmp_path / "a.mcap", t0_unix_s=T0)
    for ev in events:
        w.write(ev)
    (tmp_path / "killed.mcap").write_bytes((tmp_path / "a.mcap").read_bytes())  # as a kill -9 leaves it: no summary
    w.close()
    from mcap.exceptions import McapError

    with pytest.raises(McapError):  # no reader opens it as it is
        read_ros2_messages(tmp_path / "killed.mcap")
    n = recover(tmp_path / "killed.mcap", tmp_path / "fixed.mcap")
    whole, fixed = _raw(tmp_path / "a.mcap"), _raw(tmp_path / "fixed.mcap")
    assert 0 < n == len(fixed) < len(whole) and fixed == whole[:n]  # the same messages, byte for byte
    last_ns = round(T0 * 1e9) + round(events[-1].t_s * 1e9)
    assert all(t > last_ns - 1e9 for _, t, _ in whole[n:])  # what is lost: the last second only
    assert len(read_ros2_messages(tmp_path / "fixed.mcap")) == n  # a complete file
    assert CHUNK_BYTES == 1 << 20 and (tmp_path / "a.mcap").stat().st_size < 20_000  # zstd chunks: 90 events in 19 kB
    # Recovering into the file itself wiped it (opened for writing before it was read), as did any existing OUT: refused,
    # the file untouched; so is an input that is not MCAP.
    from sonicskin.errors import SonicskinError

    before = (tmp_path / "killed.mcap").read_bytes()
    with pytest.raises(SonicskinError, match=r"killed\.mcap is the file to recover from; give a new OUT file \(nothing was changed\)"):
        recover(tmp_path / "killed.mcap", tmp_path / "killed.mcap")
    with pytest.raises(SonicskinError, match=r"fixed\.mcap exists; give a new OUT file"):
        recover(tmp_path / "killed.mcap", tmp_path / "fixed.mcap")
    assert (tmp_path / "killed.mcap").read_bytes() == before and len(read_ros2_messages(tmp_path / "fixed.mcap")) == n
    (tmp_path / "notes.txt").write_text("not a bag")
    with pytest.raises(SonicskinError, match=r"notes\.txt is not an MCAP file"):
        recover(tmp_path / "notes.txt", tmp_path / "x.mcap")
    assert not (tmp_path / "x.mcap").exists() and not list(tmp_path.glob(".*partial*"))


def test_bad_arguments_are_one_line(tmp_path):
    from sonicskin.errors import SonicskinError

    with pytest.raises(SonicskinError, match=r"t0_unix_s must be the stream start as UNIX seconds \(e.g. time.time\(\)\), got nan"):
        McapEventWriter(tmp_path / "a.mcap", t0_unix_s=math.nan)
    with pytest.raises(SonicskinError, match=r"a.mcap: cannot write the MCAP file \(No such file or directory\)"):
        McapEventWriter(tmp_path / "no" / "a.mcap", t0_unix_s=T0)
    assert topic_for("upper-arm", "contact_point") == "/sonicskin/upper_arm/contact_point"
    assert topic_for("3rd", "x") == "/sonicskin/_3rd/x"


@pytest.mark.parametrize("distro", ["ROS2_HUMBLE", "ROS2_JAZZY"])
def test_the_bytes_are_what_ros2_itself_encodes(tmp_path, distro):
    """An independent check of the message definitions: the ROS 2 distribution's own types (rosbags' typestore, the
    .msg files of Humble and Jazzy) decode every message and encode it back to the same bytes."""
    rosbags = pytest.importorskip("rosbags.typesys")
    from mcap.reader import make_reader

    ts = rosbags.get_typestore(getattr(rosbags.Stores, distro))
    with McapEventWriter(tmp_path / "a.mcap", t0_unix_s=T0) as w:
        for ev in _events():
            w.write(ev)
    n = 0
    with open(tmp_path / "a.mcap", "rb") as f:
        for schema, _, message in make_reader(f).iter_messages():
            assert bytes(ts.serialize_cdr(ts.deserialize_cdr(message.data, schema.name), schema.name)) == message.data
            n += 1
    assert n == 4 * len(_events())


# -- the output file (issue 37) ----------------------------------------------------------------------------------------
def test_an_existing_file_is_refused_unless_overwrite(tmp_path):
    from sonicskin.errors import SonicskinError

    arm = tmp_path / "arm.yaml"
    arm.write_text("name: trained\n")
    with pytest.raises(SonicskinError) as e:
        McapEventWriter(arm, t0_unix_s=T0)
    assert str(e.value) == f"{arm}: the file exists; pass --overwrite (overwrite=True) to replace it, or choose another file"
    assert arm.read_text() == "name: trained\n"
    with pytest.raises(SonicskinError) as e:  # --overwrite replaces an earlier recording, never an arm file
        McapEventWriter(arm, t0_unix_s=T0, overwrite=True)
    assert str(e.value) == (f"{arm} is not an MCAP recording (an arm file, a skin.json, a URDF?): --overwrite replaces an "
                            f"earlier recording only; choose another file for --mcap")
    assert arm.read_text() == "name: trained\n"
    earlier = tmp_path / "earlier.mcap"
    McapEventWriter(earlier, t0_unix_s=T0).close()
    with McapEventWriter(earlier, t0_unix_s=T0, overwrite=True) as w:
        w.write(_events()[0])
    assert len(read_ros2_messages(earlier)) == 5  # a touch, and its marker deleted on close
    for bad, shown in ((5, "5"), ("", "''")):  # mcap=5 opened file descriptor 5; '' wrote nothing
        with pytest.raises(SonicskinError, match=f"^the MCAP file must be a file path, got {shown}$"):
            McapEventWriter(bad, t0_unix_s=T0)


def test_a_directory_is_named_as_one_not_as_an_existing_file(tmp_path, monkeypatch):
    """``mcap="."`` said "the file exists; pass --overwrite" of a folder (with overwrite: "Is a directory").  It says the
    path is a directory and asks for a file path, through open_run (``Listener(mcap=)``, ``live --mcap``) too."""
    from sonicskin.errors import SonicskinError
    from sonicskin.session import open_run

    monkeypatch.chdir(tmp_path)
    for overwrite in (False, True):
        with pytest.raises(SonicskinError) as e:
            McapEventWriter(".", t0_unix_s=T0, overwrite=overwrite)
        assert str(e.value) == ". is a directory: give --mcap (mcap=) the path of a file to record into, e.g. run.mcap"
    with pytest.raises(SonicskinError) as e:
        open_run(links="arm6", mcap=tmp_path)
    assert str(e.value) == (f"{tmp_path} is a directory: give --mcap (mcap=) the path of a file to record into, e.g. "
                            f"{tmp_path / 'run.mcap'}")
    assert list(tmp_path.iterdir()) == []


def test_a_second_writer_on_the_same_file_is_refused_while_the_first_is_open(tmp_path):
    """Two Listeners given one path both ran; the file held one writer's messages.  The first writer's flock refuses
    the second (even with overwrite=True), and is released when the first closes."""
    from sonicskin.errors import SonicskinError

    path = tmp_path / "a.mcap"
    first = McapEventWriter(path, t0_unix_s=T0)
    first.write(_events()[0])
    with pytest.raises(SonicskinError) as e:
        McapEventWriter(path, t0_unix_s=T0, overwrite=True)
    assert str(e.value) == (f"{path}: another writer is recording into this MCAP file (it holds the file's lock); give "
                            f"each recording its own file")
    first.write(_events()[1])
    first.close()
    assert len(read_ros2_messages(path)) == 9  # the first writer's file, whole
    McapEventWriter(path, t0_unix_s=T0, overwrite=True).close()
    assert read_ros2_messages(path) == []  # replaced by an empty, complete recording


def test_a_full_disk_is_one_line_naming_the_file(tmp_path):
    from sonicskin.errors import SonicskinError

    w = McapEventWriter("/dev/full", t0_unix_s=T0, overwrite=True)
    w.write(_events()[0])  # into the chunk, which reaches the disk a second (of stream) later
    with pytest.raises(SonicskinError) as e:
        w.write(dataclasses.replace(_events()[1], t_s=1.5))
    assert str(e.value) == ("/dev/full: cannot write the MCAP file (No space left on device); the recording stops here "
                            "(free space on its disk, or record to another file)")
    with pytest.raises(SonicskinError, match="^/dev/full: the MCAP writer is closed$"):
        w.write(_events()[1])
    w.close()  # nothing more to say


def test_a_writer_whose_run_never_started_leaves_no_stub(tmp_path):
    """A run refused after its writer was made (a taken --view port) left a 70-byte MCAP that no reader opens.  Nothing
    is written before the first event or close(); a writer dropped before either removes the empty file it made, and
    leaves a file it was allowed to overwrite as it was."""
    import gc

    from sonicskin.errors import SonicskinError

    path = tmp_path / "a.mcap"
    w = McapEventWriter(path, t0_unix_s=T0)
    assert path.stat().st_size == 0
    del w
    gc.collect()
    assert not path.exists()
    earlier = b"\x89MCAP0\r\n and an earlier recording"
    path.write_bytes(earlier)
    w = McapEventWriter(path, t0_unix_s=T0, overwrite=True)
    del w
    gc.collect()
    assert path.read_bytes() == earlier
    w = McapEventWriter(tmp_path / "d.mcap", t0_unix_s=0)  # made (its file claimed) before the stream starts ...
    w.t0_unix_s = T0  # ... which sets the clock
    w.write(_events()[0])
    with pytest.raises(SonicskinError, match="the stream start cannot move once events are written"):
        w.t0_unix_s = T0 + 1
    w.close()
    assert read_ros2_messages(tmp_path / "d.mcap")[0].log_time_ns == round(T0 * 1e9)
    McapEventWriter(tmp_path / "b.mcap", t0_unix_s=T0).close()  # a run without a touch: a complete, empty recording
    assert read_ros2_messages(tmp_path / "b.mcap") == []
    # `live --mcap F --view PORT` with the port taken: the writer made, then the run refused, the process gone
    import subprocess
    import sys

    code = ("from sonicskin.rosbag import McapEventWriter\nw = McapEventWriter('c.mcap', t0_unix_s=0)\n"
            "raise SystemExit('sonicskin live: error: cannot serve the view on 127.0.0.1:8080')")
    assert subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, timeout=60).returncode == 1
    assert not (tmp_path / "c.mcap").exists()
