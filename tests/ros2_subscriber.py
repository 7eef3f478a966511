"""A ROS 2 subscriber in its own process, as a ROS 2 node's DDS layer sees sonicskin (tests/test_ros2.py).

Usage: python tests/ros2_subscriber.py DOMAIN TOPICS.json OUT.json STOP_FILE
TOPICS.json maps each ROS 2 topic to its type (``pkg/msg/T``).  Subscribes to ``rt/<topic>`` with type
``pkg::msg::dds_::T_`` (best effort and keep-all; the latched topics reliable and transient local, as a late joiner
asks), prints ``ready``, then takes every sample until STOP_FILE exists, and writes the samples' CDR bytes per topic
and what DDS discovery announced of the publisher's writers (topic, type, reliability, durability) to OUT.json.
"""

import base64
import json
import sys
import time
from pathlib import Path

from cyclonedds.builtin import BuiltinDataReader, BuiltinTopicDcpsPublication
from cyclonedds.domain import DomainParticipant
from cyclonedds.qos import Policy, Qos
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic

from sonicskin.ros2 import dds_type

domain, topics, out, stop = int(sys.argv[1]), json.loads(Path(sys.argv[2]).read_text()), Path(sys.argv[3]), Path(sys.argv[4])
dp = DomainParticipant(domain)
readers = {}
for topic, typ in topics.items():
    latched = topic in ("/robot_description", "/tf_static")
    qos = Qos(Policy.Reliability.Reliable(0) if latched else Policy.Reliability.BestEffort, Policy.History.KeepAll,
              Policy.Durability.TransientLocal if latched else Policy.Durability.Volatile)
    readers[topic] = DataReader(dp, Topic(dp, "rt" + topic, dds_type(typ)), qos=qos)
discovery = BuiltinDataReader(dp, BuiltinTopicDcpsPublication)
print("ready", flush=True)
got = {t: [] for t in topics}
pubs = {}
while True:
    done = stop.exists()  # one more pass after the stop file appears
    for topic, r in readers.items():
        got[topic] += [base64.b64encode(s.serialize()).decode() for s in r.take(N=10_000)
                       if hasattr(s, "serialize")]  # not the writer's end (an InvalidSample)
    for p in discovery.read(N=1000):
        if (p.topic_name or "").startswith("rt/sonicskin") or p.topic_name in ("rt/tf", "rt/tf_static", "rt/robot_description",
                                                                       "rt/joint_states"):
            pubs[p.topic_name] = [p.type_name, type(p.qos[Policy.Reliability]).__name__.rsplit(".", 1)[-1],
                                  str(p.qos[Policy.Durability]).rsplit(".", 1)[-1]]
    if done:
        break
    time.sleep(0.01)
out.write_text(json.dumps({"messages": got, "publications": pubs}))
