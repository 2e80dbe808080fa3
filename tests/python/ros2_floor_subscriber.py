"""An independent ROS 2 client: subscribes to posestream's learnt floor
(`geometry_msgs/PoseWithCovarianceStamped`) with Eclipse Cyclone DDS (PyPI `cyclonedds`)
as a late joiner (reliable, transient local: the latched floor arrives though it was
published before this reader existed), and prints the first message as JSON. The
types are written here by hand from `geometry_msgs`' `.msg` files.

usage: ros2_floor_subscriber.py DOMAIN TOPIC TIMEOUT_S
Prints the first message received as JSON, then exits (nothing: none came).
"""

import json
import sys
import time
from dataclasses import dataclass

domain, topic, timeout = int(sys.argv[1]), sys.argv[2], float(sys.argv[3])
from ros2_types import Header, Pose  # noqa: E402  (DDS on loopback, set on import)

from cyclonedds.core import Policy, Qos  # noqa: E402
from cyclonedds.domain import DomainParticipant  # noqa: E402
from cyclonedds.idl import IdlStruct  # noqa: E402
from cyclonedds.idl.annotations import final  # noqa: E402
from cyclonedds.idl.types import array, float64  # noqa: E402
from cyclonedds.sub import DataReader  # noqa: E402
from cyclonedds.topic import Topic  # noqa: E402


@final
@dataclass
class PoseWithCovariance(IdlStruct, typename="geometry_msgs::msg::dds_::PoseWithCovariance_"):
    pose: Pose
    covariance: array[float64, 36]


@final
@dataclass
class PoseWithCovarianceStamped(
    IdlStruct, typename="geometry_msgs::msg::dds_::PoseWithCovarianceStamped_"
):
    header: Header
    pose: PoseWithCovariance


qos = Qos(
    Policy.Reliability.Reliable(max_blocking_time=100_000_000),
    Policy.Durability.TransientLocal,
    Policy.History.KeepLast(1),
)
participant = DomainParticipant(domain)
# ROS 2 topic /a/b is the DDS topic rt/a/b.
reader = DataReader(
    participant, Topic(participant, "rt" + topic, PoseWithCovarianceStamped), qos=qos
)
deadline = time.time() + timeout
while time.time() < deadline:
    for m in reader.take(N=1):
        p, q = m.pose.pose.position, m.pose.pose.orientation
        print(
            json.dumps(
                {
                    "stamp": [m.header.stamp.sec, m.header.stamp.nanosec],
                    "frame_id": m.header.frame_id,
                    "position": [p.x, p.y, p.z],
                    "orientation": [q.x, q.y, q.z, q.w],
                    "covariance": list(m.pose.covariance),
                }
            ),
            flush=True,
        )
        sys.exit(0)
    time.sleep(0.05)
