"""A hostile ROS 2 participant: publishes malformed posestream_msgs/HeatMaps (the defect
inputs of the hardening issue) on the heat-map topic with Eclipse Cyclone DDS (PyPI
`cyclonedds`), the types written here from the `.msg` files as any client would.

usage: ros2_hostile_publisher.py DOMAIN TOPIC SECONDS RATE_HZ
Prints one JSON line at the end: how many messages of each kind it published.
Keeps DDS on the loopback interface (unicast discovery to 127.0.0.1).
"""

import json
import math
import sys
import time

domain, topic, seconds, rate = int(sys.argv[1]), sys.argv[2], float(sys.argv[3]), float(sys.argv[4])
from ros2_types import HeatMaps, Header, Time  # noqa: E402  (DDS on loopback, set on import)

from cyclonedds.core import Policy, Qos  # noqa: E402
from cyclonedds.domain import DomainParticipant  # noqa: E402
from cyclonedds.idl.types import sequence  # noqa: E402
from cyclonedds.pub import DataWriter  # noqa: E402
from cyclonedds.topic import Topic  # noqa: E402


JOINTS = [
    "pelvis", "l-hip", "l-knee", "l-ankle", "r-hip", "r-knee", "r-ankle", "spine", "thorax",
    "neck", "head-top", "l-shoulder", "l-elbow", "l-wrist", "r-shoulder", "r-elbow", "r-wrist",
]


def maps(seq, h, w, values=None, quantized=None, encoding=0, joints=JOINTS, crop=(0, 0, 64, 64), scale=0.0):
    now = time.time()
    return HeatMaps(
        header=Header(stamp=Time(sec=int(now), nanosec=int(now % 1 * 1e9)), frame_id="camera"),
        sequence=seq,
        track_id=0,
        joint_names=joints,
        height=h,
        width=w,
        crop_x=crop[0],
        crop_y=crop[1],
        crop_width=crop[2],
        crop_height=crop[3],
        encoding=encoding,
        values=values if values is not None else [],
        quantized_values=quantized if quantized is not None else [],
        quantization_scale=scale,
        frames_since_look=0,
    )


def hostile(i):
    """The i-th hostile message (cycling through the kinds) and its kind."""
    kinds = [
        # 17 x h x w wraps to the number of values sent.
        ("overflowing size", lambda s: maps(s, 3537046315, 4294949781, values=[0.5] * 96631)),
        # Claims 2048 x 2048 u8 maps, sends a few bytes.
        ("huge claimed maps", lambda s: maps(s, 2048, 2048, quantized=[1] * 64, encoding=1, scale=1.0)),
        # Maps beyond the limits, values consistent.
        ("maps beyond the limits", lambda s: maps(s, 256, 256, quantized=[0] * (17 * 256 * 256), encoding=1, scale=1.0)),
        ("wrong value count", lambda s: maps(s, 64, 64, values=[0.1] * 100)),
        ("NaN scores", lambda s: maps(s, 4, 4, values=[math.nan] * (17 * 16))),
        ("unknown encoding", lambda s: maps(s, 4, 4, values=[0.1] * (17 * 16), encoding=7)),
        ("zero quantisation scale", lambda s: maps(s, 4, 4, quantized=[9] * (17 * 16), encoding=1, scale=0.0)),
        ("infinite crop", lambda s: maps(s, 4, 4, values=[0.1] * (17 * 16), crop=(math.inf, 0, 64, 64))),
        ("huge crop", lambda s: maps(s, 4, 4, values=[0.1] * (17 * 16), crop=(1e308, 0, 1.7e308, 64))),
        ("unknown joints", lambda s: maps(s, 4, 4, values=[0.1] * (17 * 16), joints=["tail"] * 17)),
        ("a thousand joints", lambda s: maps(s, 1, 1, values=[0.1] * 1000, joints=["j"] * 1000)),
    ]
    kind, make = kinds[i % len(kinds)]
    return kind, make(i)


qos = Qos(
    Policy.Reliability.Reliable(max_blocking_time=100_000_000),
    Policy.Durability.Volatile,
    Policy.History.KeepLast(10),
)
participant = DomainParticipant(domain)
writer = DataWriter(participant, Topic(participant, "rt" + topic, HeatMaps), qos=qos)
print("ready", flush=True)
sent = {}
start = time.time()
i = 0
while time.time() - start < seconds:
    kind, msg = hostile(i)
    writer.write(msg)
    sent[kind] = sent.get(kind, 0) + 1
    i += 1
    time.sleep(1.0 / rate)
print(json.dumps({"sent": sent, "total": i}), flush=True)
