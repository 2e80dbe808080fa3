"""A robot's static transforms on ROS 2, as tf2's StaticTransformBroadcaster publishes them:
the `/tf_static` messages of a recording (decoded with rosbags' ROS 2 Humble type store, not
with posestream's schemas) published once with Eclipse Cyclone DDS (PyPI `cyclonedds`) on
`rt/tf_static`, reliable and transient local, keeping the last one: a node that joins later
still gets them. The types are written here from ROS 2's `.msg` files, as any client would.

usage: ros2_tf_static_publisher.py DOMAIN RECORDING SECONDS
Prints `published N` (the transforms sent), then `matched` once a reader matched the
writer, then stays SECONDS and prints one JSON line: what it published.
Keeps DDS on the loopback interface (unicast discovery to 127.0.0.1).
"""

import json
import sys
import time
from dataclasses import dataclass

domain, path, seconds = int(sys.argv[1]), sys.argv[2], float(sys.argv[3])
from ros2_types import Header, Quaternion, Time, Vector3  # noqa: E402  (DDS on loopback, set on import)

from cyclonedds.core import Policy, Qos  # noqa: E402
from cyclonedds.domain import DomainParticipant  # noqa: E402
from cyclonedds.idl import IdlStruct  # noqa: E402
from cyclonedds.idl.annotations import final  # noqa: E402
from cyclonedds.idl.types import sequence  # noqa: E402
from cyclonedds.pub import DataWriter  # noqa: E402
from cyclonedds.topic import Topic  # noqa: E402
from mcap.reader import make_reader  # noqa: E402
from rosbags.typesys import Stores, get_typestore  # noqa: E402


@final
@dataclass
class Transform(IdlStruct, typename="geometry_msgs::msg::dds_::Transform_"):
    translation: Vector3
    rotation: Quaternion


@final
@dataclass
class TransformStamped(IdlStruct, typename="geometry_msgs::msg::dds_::TransformStamped_"):
    header: Header
    child_frame_id: str
    transform: Transform


@final
@dataclass
class TFMessage(IdlStruct, typename="tf2_msgs::msg::dds_::TFMessage_"):
    transforms: sequence[TransformStamped]


store = get_typestore(Stores.ROS2_HUMBLE)
transforms = []
with open(path, "rb") as f:
    reader = make_reader(f)
    for _schema, channel, message in reader.iter_messages(topics=["/tf_static"]):
        decoded = store.deserialize_cdr(message.data, "tf2_msgs/msg/TFMessage")
        for t in decoded.transforms:
            tr, q = t.transform.translation, t.transform.rotation
            transforms.append(
                TransformStamped(
                    header=Header(
                        stamp=Time(sec=t.header.stamp.sec, nanosec=t.header.stamp.nanosec),
                        frame_id=t.header.frame_id,
                    ),
                    child_frame_id=t.child_frame_id,
                    transform=Transform(
                        translation=Vector3(x=tr.x, y=tr.y, z=tr.z),
                        rotation=Quaternion(x=q.x, y=q.y, z=q.z, w=q.w),
                    ),
                )
            )
if not transforms:
    sys.exit(f"no /tf_static transforms in {path}")

# tf2_ros::StaticBroadcasterQoS: reliable, transient local, keep last 1 (every static
# transform in the one message).
qos = Qos(
    Policy.Reliability.Reliable(max_blocking_time=100_000_000),
    Policy.Durability.TransientLocal,
    Policy.History.KeepLast(1),
)
participant = DomainParticipant(domain)
writer = DataWriter(participant, Topic(participant, "rt/tf_static", TFMessage), qos=qos)
writer.write(TFMessage(transforms=transforms))
print(f"published {len(transforms)}", flush=True)
end = time.monotonic() + seconds
matched = False
while time.monotonic() < end:
    if not matched and writer.get_matched_subscriptions():
        matched = True
        print("matched", flush=True)
    time.sleep(0.02)
print(
    json.dumps(
        {
            "transforms": [
                {"parent": t.header.frame_id, "child": t.child_frame_id} for t in transforms
            ],
            "matched": matched,
        }
    ),
    flush=True,
)
