"""Write the Foxglove layout shipped for arm6 (configs/arms/arm6.foxglove.json) with foxglove-sdk's layout classes.

A 3D panel on the whole arm (the URDF from /robot_description placed by /tf_static and /tf, the touch markers and
the wrench at the finger, following base_link), beside it a plot of every link's contact force and the raw Contact
of the forearm.  Open it in Foxglove (Layouts, Import from file) with ``sonicskin live --links ART/arm.yaml --foxglove``
connected (Open connection, Foxglove WebSocket, ws://127.0.0.1:8765) or with the run's MCAP file open.

    python tools/foxglove_layout.py [--check]    # --check: exit 1 when the shipped file differs
"""

import json
import sys
from pathlib import Path

import foxglove.layouts as fl

from sonicskin.links import load_links
from sonicskin.rig import Rig
from sonicskin.rosbag import MARKER_TOPIC, topic_for

OUT = Path(__file__).resolve().parents[1] / "configs" / "arms" / "arm6.foxglove.json"


def layout() -> dict:
    frames = [lk.surface.frame_id for lk in load_links("arm6", Rig.load("fast"))]
    topics = {"/robot_description": fl.BaseRendererUrdfTopicSettings(visible=True, display_mode="visual", show_axis=False),
              MARKER_TOPIC: fl.BaseRendererRosMarkerTopicSettings(visible=True),
              **{topic_for(f, "contact_wrench"): fl.BaseRendererBaseSettings(visible=True) for f in frames}}
    three_d = fl.ThreeDeePanel(title="arm6: the arm and its touches", config=fl.ThreeDeeConfig(
        follow_tf="base_link", topics=topics, layers={"grid": fl.BaseRendererGridLayerSettings(visible=True)},
        camera_state=fl.ThreeDeeCameraState(distance=1.8, perspective=True, phi=65.0, theta_offset=40.0,
                                           target_offset=(0.0, 0.0, 0.5))))
    plot = fl.PlotPanel(title="contact force per link (N)", config=fl.PlotConfig(
        paths=[fl.PlotSeries(value=f"{topic_for(f, 'contact')}.force_n", timestamp_method="headerStamp") for f in frames]))
    raw = fl.RawMessagesPanel(title="forearm contact", config=fl.RawMessagesConfig(
        topic_path=topic_for("forearm_link", "contact"), expansion="all"))
    side = fl.SplitContainer(direction="column", items=[fl.SplitItem(content=plot), fl.SplitItem(content=raw)])
    content = fl.SplitContainer(direction="row", items=[fl.SplitItem(proportion=2, content=three_d),
                                                         fl.SplitItem(proportion=1, content=side)])
    return json.loads(fl.Layout(content=content).to_json())


if __name__ == "__main__":
    text = json.dumps(layout(), indent=1) + "\n"
    if "--check" in sys.argv[1:]:
        sys.exit(0 if OUT.read_text() == text else 1)
    OUT.write_text(text)
    print(f"wrote {OUT}")
