"""An independent ROS 2 client: subscribes to posestream's Skeleton3D topic with Eclipse
Cyclone DDS (PyPI `cyclonedds`), the DDS of many ROS 2 distributions, and prints each
message as one JSON line. The types are written here from the `.msg` files, by hand, as
any non-Rust client would.

usage: ros2_skeleton_subscriber.py DOMAIN TOPIC COUNT TIMEOUT_S
Keeps DDS on the loopback interface (unicast discovery to 127.0.0.1).
"""

import json
import sys
import time
from dataclasses import dataclass

domain, topic, count, timeout = int(sys.argv[1]), sys.argv[2], int(sys.argv[3]), float(sys.argv[4])
from ros2_types import Header  # noqa: E402  (DDS on loopback, set on import)

from cyclonedds.core import Policy, Qos  # noqa: E402
from cyclonedds.domain import DomainParticipant  # noqa: E402
from cyclonedds.idl import IdlStruct  # noqa: E402
from cyclonedds.idl.annotations import final  # noqa: E402
from cyclonedds.idl.types import float64, sequence, uint8, uint32, uint64  # noqa: E402
from cyclonedds.sub import DataReader  # noqa: E402
from cyclonedds.topic import Topic  # noqa: E402


@final
@dataclass
class Skeleton3D(IdlStruct, typename="posestream_msgs::msg::dds_::Skeleton3D_"):
    header: Header
    sequence: uint64
    track_id: uint32
    joint_names: sequence[str]
    units: uint8
    positions: sequence[float64]
    position_std: sequence[float64]
    keypoints: sequence[float64]
    keypoint_std: sequence[float64]
    projected: sequence[float64]
    lag: uint32
    state: uint8
    metric_source: uint8
    views: sequence[str]
    frames_since_look: uint32
    mean_bone_length: float64


qos = Qos(
    Policy.Reliability.Reliable(max_blocking_time=100_000_000),
    Policy.Durability.Volatile,
    Policy.History.KeepLast(10),
)
participant = DomainParticipant(domain)
# ROS 2 topic /a/b is the DDS topic rt/a/b.
reader = DataReader(participant, Topic(participant, "rt" + topic, Skeleton3D), qos=qos)
print("ready", flush=True)
got = 0
deadline = time.time() + timeout
while got < count and time.time() < deadline:
    for s in reader.take(N=16):
        got += 1
        print(
            json.dumps(
                {
                    "stamp": [s.header.stamp.sec, s.header.stamp.nanosec],
                    "frame_id": s.header.frame_id,
                    "sequence": s.sequence,
                    "track_id": s.track_id,
                    "joint_names": list(s.joint_names),
                    "units": s.units,
                    "positions": list(s.positions),
                    "position_std": list(s.position_std),
                    "keypoints": list(s.keypoints),
                    "keypoint_std": list(s.keypoint_std),
                    "projected": list(s.projected),
                    "lag": s.lag,
                    "state": s.state,
                    "metric_source": s.metric_source,
                    "views": list(s.views),
                    "frames_since_look": s.frames_since_look,
                    "mean_bone_length": s.mean_bone_length,
                }
            ),
            flush=True,
        )
    time.sleep(0.01)
sys.exit(0 if got >= count else 1)
