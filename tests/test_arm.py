"""The whole arm: arm files (sonicskin.links), the simulated arm on one multi-channel source, and simulate / fit-svm /
live / listen() over every link at once, with events in each link's URDF frame."""

from __future__ import annotations

import json
import math
import shutil
import urllib.request
from pathlib import Path

import numpy as np
import pytest
import yaml

from sonicskin.acquire import SimulatedSource
from sonicskin.cli import main
from sonicskin.links import load_links
from sonicskin.rig import Rig, config_dir
from sonicskin.session import open_run
from sonicskin.sim import Simulator, build_timeline

FAST = Rig.load("fast")


def test_arm6_places_six_links_in_their_urdf_frames():
    links = load_links("arm6", FAST)
    assert [lk.name for lk in links] == ["base", "shoulder", "upper-arm", "forearm", "wrist", "hand"]
    assert [lk.frame for lk in links] == ["base_link", "shoulder_link", "upper_arm_link", "forearm_link", "wrist_link",
                                          "hand_plate"]
    assert len({lk.tx for lk in links}) == len({lk.rx for lk in links}) == 6  # own TX/RX pair each: all chirp at once
    assert all(lk.n_slots == 1 and lk.rig is None for lk in links)
    fore = links[3]
    # The simulated tube is the URDF's cylinder (r 3.75 cm, 25 cm), so the layout's circumference is the surface's.
    assert fore.scenario.geometry == {"kind": "tube", "radius_cm": 3.75, "length_cm": 25.0}
    assert fore.scenario.make_layout().circumference_cm == pytest.approx(2 * math.pi * 3.75)
    hand = links[5]
    assert hand.surface.kind == "plate" and hand.scenario.geometry == {"kind": "plate", "width_cm": 20.0, "length_cm": 25.0}
    assert len({lk.scenario.material for lk in links}) >= 3  # different materials
    for lk in links:  # every marker lies on its link's surface, with a unit outward normal
        p, n = lk.surface.point_normal(lk.scenario.make_layout().xy_cm)
        assert np.allclose(np.linalg.norm(n, axis=1), 1.0)
        if lk.surface.kind == "tube":  # radial: the point is r from the axis, the normal points away from it
            axis_off = p - lk.surface.pose[:3, 3]
            assert np.allclose(np.linalg.norm(axis_off[:, :2], axis=1), lk.surface.radius_m)
            assert np.all(np.sum(axis_off[:, :2] * n[:, :2], axis=1) > 0)


def _arm_file(tmp_path: Path, links: list[dict], **top) -> Path:
    p = tmp_path / "arm.yaml"
    p.write_text(yaml.safe_dump({"name": "t", "duplex": "none", **top, "links": links}, sort_keys=False))
    return p


TINY = {"base": "stationary", "layout": {"kind": "rings", "counts": [3, 2], "spacing_cm": 1.2, "x0_cm": 2.4, "y0_cm": 11.9},
        "sessions": 1, "train_repeats": 2, "touch_s": 1.0, "gap_s": 0.5, "calibration_s": 3.0}


@pytest.mark.parametrize("links, top, message", [
    ([{"name": "a", "tx": 0, "rx": 0}, {"name": "b", "tx": 0, "rx": 1}], {},
     "duplex none: links share transmitter channels [0, 0]; each link needs its own TX channel"),
    ([{"name": "a", "tx": 0, "rx": 0, "colour": "red"}], {}, "link 0: unknown keys ['colour']; a link has artifact, frame"),
    ([{"name": "a", "tx": 0, "rx": 0}, {"name": "a", "tx": 1, "rx": 1}], {}, "link names ['a', 'a'] repeat"),
    ([{"name": "a", "tx": 0, "rx": 0, "frame": "forearm_link"}], {"urdf": "nowhere.urdf"},
     "urdf 'nowhere.urdf' does not exist next to it"),
    ([{"name": "a", "tx": 0, "rx": 0, "scenario": {**TINY, "layout": {"kind": "rings", "counts": [3, 2], "spacing_cm": 1.2,
                                                                       "x0_cm": 2.4, "y0_cm": 40.0}}}], {},
     "link 'a': scenario: layout marker 0 at (2.4, 40) cm lies outside the tube (x 0..23.56 round it, y 0..25 cm)"),
    ([{"name": "a", "tx": 0, "rx": 0, "frame": "wrist_link",
       "scenario": {**TINY, "geometry": {"kind": "tube", "radius_cm": 3.75, "length_cm": 25.0}}}], {"urdf": "arm6.urdf"},
     "link 'a': the layout's circumference 23.5619 cm is not that of the tube of wrist_link"),
    ([{"name": "a", "tx": 0, "rx": 0, "scenario": {**TINY, "material": "cheese"}}], {}, "link 'a': scenario:"),
    # issue 37: a link's name names its folders (data/<name>, out/<name>): a name, never a path
    ([{"name": "../../fit-escaped", "tx": 0, "rx": 0}], {}, "link 0: name '../../fit-escaped' is not a plain name (letters, "
                                                           "digits, '.', '_', '-', starting with a letter or digit, at most 64"),
    ([{"name": "/tmp/abs", "tx": 0, "rx": 0}], {}, "link 0: name '/tmp/abs' is not a plain name"),
    ([{"name": "", "tx": 0, "rx": 0}], {}, "link 0: name '' is not a plain name"),
    ([{"name": ".", "tx": 0, "rx": 0}], {}, "link 0: name '.' is not a plain name"),
    # the simulated arm plays link k on channel pair k: other channels are refused, not silently run on 0/1
    ([{"name": "a", "tx": 0, "rx": 0, "scenario": {**TINY, "seed": 1}}, {"name": "b", "tx": 7, "rx": 1, "scenario": {**TINY}}],
     {}, "link 'b': tx 7, rx 1, but the simulated arm plays link k (in file order) on its own TX/RX pair k: give tx: 1, rx: 1"),
], ids=["shared-tx", "unknown-key", "same-name", "no-urdf", "layout-off-link", "urdf-not-the-simulated-link",
        "bad-scenario", "name-escapes", "name-absolute", "name-empty", "name-dot", "sim-channel-7"])
def test_arm_file_mistakes_are_one_line(tmp_path, capsys, links, top, message):
    shutil.copyfile(config_dir() / "arms" / "arm6.urdf", tmp_path / "arm6.urdf")
    f = _arm_file(tmp_path, links, **top)
    with pytest.raises(ValueError) as e:
        load_links(f, FAST)
    assert message in str(e.value) and "\n" not in str(e.value)
    code = main(["simulate", "--links", str(f), "--out", str(tmp_path / "d"), "--quiet"])  # the CLI: one line, exit 2
    err = capsys.readouterr().err
    assert code == 2 and message in err and "Traceback" not in err


def test_simulated_arm_plays_each_link_on_its_own_channel(tmp_path):
    """The arm's source carries link k on input channel k: each column is sample for sample that link played alone."""
    links = load_links(_arm_file(tmp_path, [{"name": "a", "tx": 0, "rx": 0, "scenario": {**TINY, "seed": 1}},
                                            {"name": "b", "tx": 1, "rx": 1, "scenario": {**TINY, "seed": 2,
                                                                                        "material": "aluminium"}}]), FAST)
    sims = [Simulator(lk.scenario, FAST) for lk in links]
    tls = [build_timeline(lk.scenario, FAST).select(np.arange(60)) for lk in links]

    def stream(src):
        out = []
        with src:
            while not (src.finished.is_set() and src.queue.empty()):
                b = src.read(timeout=0.5)
                if b is not None:
                    out.append(b.samples)
        return np.concatenate(out)

    both = stream(SimulatedSource(sims, tls, realtime=False, blocksize=1000))
    assert both.ndim == 2 and both.shape[1] == 2
    for k in range(2):
        alone = stream(SimulatedSource(Simulator(links[k].scenario, FAST), tls[k], realtime=False, blocksize=1000))
        assert np.array_equal(both[:, k], alone)
    assert not np.allclose(both[:, 0], both[:, 1])  # two different walls


@pytest.mark.slow
def test_whole_arm_simulate_fit_live_and_listen_in_the_link_frames(tmp_path, capsys):
    """simulate --links, fit-svm --links (one artifact per link and the arm file), live --links ART/arm.yaml --fast: every
    link reports its scripted touches in its own frame, contact points on the finger; a Listener gives the same events."""
    links = [{"name": "upper", "tx": 0, "rx": 0, "scenario": {**TINY, "seed": 11}},
             {"name": "plate", "tx": 1, "rx": 1, "scenario": {**TINY, "base": "plate-aluminium", "seed": 12,
                                                             "layout": {"kind": "grid", "nx": 3, "ny": 2, "spacing_cm": 3.0,
                                                                        "x0_cm": 7.5, "y0_cm": 9.5}}}]
    f = _arm_file(tmp_path, links, rig="fast")
    assert main(["simulate", "--links", str(f), "--out", str(tmp_path / "data"), "--quiet", "--sessions", "2"]) == 0
    assert main(["fit-svm", "--links", str(f), "--data", str(tmp_path / "data"), "--out", str(tmp_path / "art"),
                 "--train", "s000"]) == 0
    (tmp_path / "single").mkdir()
    (tmp_path / "single" / "skin.json").write_text("{}")  # a single-link artifact: the arm used to be mixed into it
    capsys.readouterr()
    assert main(["fit-svm", "--links", str(f), "--data", str(tmp_path / "data"), "--out", str(tmp_path / "single")]) == 2
    assert "single holds a single-link artifact (skin.json); an arm's artifacts written there would mix" in capsys.readouterr().err
    assert sorted(p.name for p in (tmp_path / "single").iterdir()) == ["skin.json"]
    # every link's artifact scored on its own later session, a report per link
    assert main(["compare", "--links", str(f), "--data", str(tmp_path / "data"), "--artifact", str(tmp_path / "art"),
                 "--test", "s001", "--out", str(tmp_path / "cmp")]) == 0
    out = capsys.readouterr().out
    assert "## link upper" in out and "## link plate" in out
    assert (tmp_path / "cmp" / "upper" / "compare.json").is_file() and (tmp_path / "cmp" / "plate" / "compare.json").is_file()
    arm = tmp_path / "art" / "arm.yaml"
    written = yaml.safe_load(arm.read_text())
    assert [d["artifact"] for d in written["links"]] == ["upper", "plate"] and written["rig"]["name"] == "fast"
    trained = json.loads((tmp_path / "art" / "plate" / "skin.json").read_text())["training"]  # the link it is for
    assert trained["link"] == {"name": "plate", "frame": "plate_link"} and trained["wall"]["what"].startswith("aluminium plate")
    with pytest.raises(ValueError, match="link 'upper': .* was trained for link 'plate' and frame 'plate_link' and another wall"):
        open_run(links=f, link_artifacts=[tmp_path / "art" / "plate", tmp_path / "art" / "upper"], fast=True)
    capsys.readouterr()
    assert main(["live", "--links", str(arm), "--fast", "--duration", "14", "--no-status"]) == 0
    out = capsys.readouterr()
    events = [json.loads(x) for x in out.out.splitlines()]
    summary = json.loads(out.err.strip().splitlines()[-1])["summary"]
    assert set(summary) == {"upper", "plate"}
    by_link = {n: [e for e in events if e["link"] == n and e["kind"] == "touch"] for n in ("upper", "plate")}
    assert all(len(v) >= 10 for v in by_link.values())  # scripted touches on every link
    assert {e["frame_id"] for e in by_link["upper"]} == {"upper_link"} and {e["frame_id"] for e in by_link["plate"]} == {"plate_link"}
    loaded = {lk.name: lk for lk in load_links(arm, FAST)}
    for name, evs in by_link.items():
        lk = loaded[name]
        tl = build_timeline(lk.scenario.replace(seed=lk.scenario.seed + 1000, sessions=1), FAST)
        near = []
        for e in evs:
            k = int(round((e["t_s"] * FAST.fs_hz + 4321) / FAST.n_chirp))  # SimulatedSource's default offset
            assert e["v"] == 2 and np.linalg.norm(e["normal"]) == pytest.approx(1.0, abs=1e-3)
            assert np.allclose(e["force_vec_n"], -e["force_n"] * np.asarray(e["normal"]), atol=1e-3)
            if tl.event[k] >= 0:
                finger, _ = lk.surface.point_normal([[tl.x_cm[k], tl.y_cm[k]]])
                near.append(np.linalg.norm(np.asarray(e["point_m"]) - finger[0]) <= 0.015)
        assert np.mean(near) >= 0.8, (name, np.mean(near))
    # The same arm through the Python API: the same touches, chirp for chirp, into an MCAP file and a live page.
    from sonicskin.api import Listener

    lst = Listener(tmp_path / "art", fast=True, duration_s=14, mcap=tmp_path / "arm.mcap", view=True)
    with urllib.request.urlopen(lst.view_url + "links.json", timeout=10) as r:  # the page draws both links to scale
        drawn = json.loads(r.read())
    assert [d["name"] for d in drawn["links"]] == ["upper", "plate"]
    assert [d["kind"] for d in drawn["links"]] == ["tube", "plate"]
    api = [ev.to_dict() for ev in lst]
    key = lambda e: (e["link"], e["t_s"], e["kind"], e["location"])  # noqa: E731
    assert sorted(map(key, api)) == sorted(map(key, events))
    from mcap_ros2.reader import read_ros2_messages

    points = [m for m in read_ros2_messages(str(tmp_path / "arm.mcap")) if m.channel.topic.endswith("/contact_point")]
    assert len(points) == len(api)
    for frame in ("upper_link", "plate_link"):  # one PointStamped per event, in the event's frame, at its point
        msgs = [m.ros_msg for m in points if m.ros_msg.header.frame_id == frame]
        evs = sorted((e for e in api if e["frame_id"] == frame), key=lambda e: e["t_s"])
        assert len(msgs) == len(evs) > 10
        assert np.allclose([[m.point.x, m.point.y, m.point.z] for m in msgs], [e["point_m"] for e in evs], atol=1e-6)


def test_record_an_arm_link_by_link(tmp_path, capsys):
    """record --links: each link's guided session on its own channels with its own markers, into OUT/<link>."""
    from sonicskin.dataset import Dataset

    links = [{"name": "a", "tx": 0, "rx": 0, "scenario": {**TINY, "seed": 21}},
             {"name": "b", "tx": 1, "rx": 1, "scenario": {**TINY, "seed": 22, "layout": {"kind": "grid", "nx": 2, "ny": 2,
                                                                                         "spacing_cm": 1.5, "x0_cm": 3.0,
                                                                                         "y0_cm": 10.0}}}]
    f = _arm_file(tmp_path, links, rig="fast")
    assert main(["record", "--links", str(f), "--out", str(tmp_path / "rec"), "--fast", "--passes", "1", "--no-artifact",
                 "--touch-s", "0.5", "--gap-s", "0.2", "--moving-s", "0", "--calibration-s", "1"]) == 0
    assert len(Dataset(tmp_path / "rec" / "a").layout) == 5 and len(Dataset(tmp_path / "rec" / "b").layout) == 4
    # The command record prints next trains the arm: the simulated device's recordings are of each link's own wall
    # (they were refused as "recorded on another wall", and so were the artifacts record writes).
    capsys.readouterr()
    assert main(["fit-svm", "--links", str(f), "--data", str(tmp_path / "rec"), "--out", str(tmp_path / "art")]) == 0, \
        capsys.readouterr().err
    code = main(["record", "--links", str(f), "--out", str(tmp_path / "rec2"), "--tx", "1"])
    assert code == 2 and "record --links takes each link's channels and markers from the arm file" in capsys.readouterr().err


def test_live_on_an_untrained_simulated_arm_trains_each_link_once(tmp_path, capsys, monkeypatch):
    """live --links on an arm file without artifacts trains each simulated link on the spot (as live does for one link),
    says so, and a second run reuses them."""
    monkeypatch.chdir(tmp_path)
    links = [{"name": "a", "tx": 0, "rx": 0, "scenario": {**TINY, "seed": 31}},
             {"name": "b", "tx": 1, "rx": 1, "scenario": {**TINY, "seed": 32, "material": "aluminium"}}]
    f = _arm_file(tmp_path, links, rig="fast")
    assert main(["live", "--links", str(f), "--fast", "--duration", "6", "--no-status"]) == 0
    out = capsys.readouterr()
    assert "training an SVM on the simulated 't-a' link first, once" in out.err
    assert (tmp_path / "artifacts" / "sim-t-a-svm" / "skin.json").is_file()
    assert {json.loads(x)["link"] for x in out.out.splitlines()} == {"a", "b"}
    assert main(["live", "--links", str(f), "--fast", "--duration", "6", "--no-status"]) == 0
    assert "using artifacts/sim-t-b-svm, trained on the simulated 't-b' link by an earlier run" in capsys.readouterr().err
    # issue 37: the two links share a layout, not a wall; their artifacts swapped ran (every touch at the wrong marker)
    code = main(["live", "--links", str(f), "--fast", "--duration", "6", "--no-status", "--link-artifact",
                 "artifacts/sim-t-b-svm", "--link-artifact", "artifacts/sim-t-a-svm"])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and (
        "sonicskin live: error: link 'a': artifacts/sim-t-b-svm was trained for another wall ('aluminium tube radius 3.75 "
        "cm x length 25 cm'; this link's: cfrp tube radius 3.75 cm x length 25 cm), not this link; give each link its own "
        "artifact (--link-artifact DIR once per link, in the order a, b), or train this link: `sonicskin fit-svm --links "
        f"{f} --data DIR --out ART`") in err, err


def test_an_artifact_trained_for_another_link_is_refused_and_an_older_one_warned_about(tmp_path):
    """What an artifact's training block records (the link's name and frame from fit-svm/record --links, the wall's
    fingerprint always) is checked against the arm's link it is given to; an artifact that records neither (older) runs
    with a warning that says how to have it checked."""
    from types import SimpleNamespace

    from sonicskin.dataset import wall_record
    from sonicskin.session import _check_trained_for

    links = load_links(_arm_file(tmp_path, [{"name": "a", "tx": 0, "rx": 0, "scenario": {**TINY, "seed": 1}},
                                            {"name": "b", "tx": 1, "rx": 1, "frame": "b_frame",
                                             "scenario": {**TINY, "material": "aluminium"}}]), FAST)
    a, b = links
    lay = a.scenario.make_layout()
    wall_a = wall_record({"kind": "simulator", "scenario": a.scenario.to_dict()}, FAST, lay)
    wall_b = wall_record({"kind": "simulator", "scenario": b.scenario.to_dict()}, FAST, lay)
    assert wall_a["sha256"] != wall_b["sha256"] and wall_a["what"] == "cfrp tube radius 3.75 cm x length 25 cm"
    # the same wall of another session or person is the same wall
    assert wall_record({"kind": "simulator", "scenario": a.scenario.replace(seed=9, sessions=3).to_dict()}, FAST,
                       lay) == wall_a

    def rt(**training):
        return SimpleNamespace(meta={"training": training}, folder=tmp_path / "art", rig=FAST, layout=lay)

    _check_trained_for("arm.yaml", a, rt(link={"name": "a", "frame": "a_link"}, wall=wall_a), links)  # its own: runs
    _check_trained_for("arm.yaml", b, rt(wall=wall_b), links)  # trained without --links: its wall is checked
    for training, why in [({"link": {"name": "b", "frame": "b_frame"}, "wall": wall_b},
                           "link 'b' and frame 'b_frame' and another wall"),
                          ({"link": {"name": "a", "frame": "x_link"}, "wall": wall_a}, "frame 'x_link'"),
                          ({"wall": wall_b}, "another wall")]:
        with pytest.raises(ValueError) as e:
            _check_trained_for("arm.yaml", a, rt(**training), links)
        assert str(e.value).startswith(f"link 'a': {tmp_path / 'art'} was trained for {why}") and "\n" not in str(e.value)
    real = [lk.__class__(lk.tx, lk.rx, name=lk.name, frame=lk.frame) for lk in links]  # a real arm: names and frames
    _check_trained_for("arm.yaml", real[1], rt(link={"name": "b", "frame": "b_frame"}, wall=wall_b), real)
    with pytest.raises(ValueError, match="was trained for link 'a' and frame 'a_link', not this link"):
        _check_trained_for("arm.yaml", real[1], rt(link={"name": "a", "frame": "a_link"}, wall=wall_a), real)
    with pytest.warns(UserWarning, match=r"link 'a': .* does not record which link and wall it was trained for \(an "
                                         r"artifact from before sonicskin recorded them\), so it is not checked"):
        _check_trained_for("arm.yaml", a, rt(), links)


def test_mcap_needs_every_link_in_a_frame(tmp_path):
    """MCAP writes touches in the links' frames: an arm whose links have no surface (a real interface's links file) is
    refused in one line that names those links and how to place them, and so is a single artifact, before any device,
    artifact or training is touched (``--mcap`` and ``mcap=`` alike: both open the run through session.open_run)."""

    f = tmp_path / "links.yaml"
    f.write_text(yaml.safe_dump({"duplex": "none", "links": [{"name": "a", "tx": 0, "rx": 0}, {"name": "b", "tx": 1, "rx": 1}]}))
    assert all(lk.surface is None for lk in load_links(f, FAST))
    with pytest.raises(ValueError) as e:
        open_run(links=f, device=0, rig="fast", mcap=tmp_path / "arm.mcap")
    assert str(e.value).startswith("--mcap/mcap= writes each touch in its link's frame")
    assert "['a', 'b']" in str(e.value) and "docs/robot-frame.md" in str(e.value) and "\n" not in str(e.value)
    with pytest.raises(ValueError) as e:
        open_run(tmp_path / "no-artifact", mcap=tmp_path / "arm.mcap")
    assert "which an arm file gives its links: run an arm" in str(e.value) and "\n" not in str(e.value)
    assert not (tmp_path / "arm.mcap").exists()
    assert all(lk.surface is not None for lk in load_links("arm6", FAST))  # every arm6 link has its frame
