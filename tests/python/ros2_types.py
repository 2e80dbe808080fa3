"""What the independent ROS 2 clients of the tests share (Python `cyclonedds`): DDS kept on
the loopback interface (unicast discovery to 127.0.0.1; set on import, before cyclonedds
is loaded), and the message types written by hand from the `.msg` files, as any non-Rust
client would."""

import os
from dataclasses import dataclass

os.environ["CYCLONEDDS_URI"] = (
    "<CycloneDDS><Domain id='any'><General><Interfaces>"
    "<NetworkInterface address='127.0.0.1'/></Interfaces>"
    "<AllowMulticast>false</AllowMulticast></General>"
    "<Discovery><ParticipantIndex>auto</ParticipantIndex><MaxAutoParticipantIndex>50</MaxAutoParticipantIndex>"
    "<Peers><Peer address='127.0.0.1'/></Peers></Discovery></Domain></CycloneDDS>"
)

from cyclonedds.idl import IdlStruct  # noqa: E402
from cyclonedds.idl.annotations import final  # noqa: E402
from cyclonedds.idl.types import float32, float64, int32, sequence, uint8, uint32, uint64  # noqa: E402


@final
@dataclass
class Time(IdlStruct, typename="builtin_interfaces::msg::dds_::Time_"):
    sec: int32
    nanosec: uint32


@final
@dataclass
class Header(IdlStruct, typename="std_msgs::msg::dds_::Header_"):
    stamp: Time
    frame_id: str


@final
@dataclass
class Vector3(IdlStruct, typename="geometry_msgs::msg::dds_::Vector3_"):
    x: float64
    y: float64
    z: float64


@final
@dataclass
class Point(IdlStruct, typename="geometry_msgs::msg::dds_::Point_"):
    x: float64
    y: float64
    z: float64


@final
@dataclass
class Quaternion(IdlStruct, typename="geometry_msgs::msg::dds_::Quaternion_"):
    x: float64
    y: float64
    z: float64
    w: float64


@final
@dataclass
class Pose(IdlStruct, typename="geometry_msgs::msg::dds_::Pose_"):
    position: Point
    orientation: Quaternion


@final
@dataclass
class HeatMaps(IdlStruct, typename="posestream_msgs::msg::dds_::HeatMaps_"):
    header: Header
    sequence: uint64
    track_id: uint32
    joint_names: sequence[str]
    height: uint32
    width: uint32
    crop_x: float64
    crop_y: float64
    crop_width: float64
    crop_height: float64
    encoding: uint8
    values: sequence[float32]
    quantized_values: sequence[uint8]
    quantization_scale: float32
    frames_since_look: uint32
