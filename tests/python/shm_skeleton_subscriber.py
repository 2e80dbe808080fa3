"""An independent shared-memory client: reads posestream's skeletons from iceoryx2 with
the Python binding (PyPI `iceoryx2`), using the C layout documented in
msgs/SHARED_MEMORY.md, and prints each sample as one JSON line.

usage: shm_skeleton_subscriber.py SERVICE COUNT TIMEOUT_S
"""

import ctypes
import json
import sys
import time

import iceoryx2 as iox2

MAX_JOINTS = 32
NAME_BYTES = 24
FRAME_ID_BYTES = 64


class SkeletonSample(ctypes.Structure):
    """posestream::SkeletonSample (msgs/SHARED_MEMORY.md)."""

    _fields_ = [
        ("stamp_ns", ctypes.c_int64),
        ("sequence", ctypes.c_uint64),
        ("track_id", ctypes.c_uint32),
        ("joints", ctypes.c_uint32),
        ("lag", ctypes.c_uint32),
        ("state", ctypes.c_uint8),
        ("units", ctypes.c_uint8),
        ("metric_source", ctypes.c_uint8),
        ("frames_since_look", ctypes.c_uint8),
        ("frame_id", ctypes.c_char * FRAME_ID_BYTES),
        ("joint_names", (ctypes.c_char * NAME_BYTES) * MAX_JOINTS),
        ("positions", ctypes.c_double * (3 * MAX_JOINTS)),
        ("position_std", ctypes.c_double * (3 * MAX_JOINTS)),
        ("keypoints", ctypes.c_double * (2 * MAX_JOINTS)),
        ("keypoint_std", ctypes.c_double * MAX_JOINTS),
        ("projected", ctypes.c_double * (2 * MAX_JOINTS)),
        ("mean_bone_length", ctypes.c_double),
    ]

    @staticmethod
    def type_name() -> str:
        return "posestream::SkeletonSample"


assert ctypes.sizeof(SkeletonSample) == 3688, ctypes.sizeof(SkeletonSample)

service_name, count, timeout = sys.argv[1], int(sys.argv[2]), float(sys.argv[3])
iox2.set_log_level_from_env_or(iox2.LogLevel.Warn)
node = iox2.NodeBuilder.new().create(iox2.ServiceType.Ipc)
service = (
    node.service_builder(iox2.ServiceName.new(service_name))
    .publish_subscribe(SkeletonSample)
    .subscriber_max_buffer_size(16)
    .open_or_create()
)
subscriber = service.subscriber_builder().buffer_size(16).create()
print("ready", flush=True)

got = 0
deadline = time.time() + timeout
while got < count and time.time() < deadline:
    sample = subscriber.receive()
    if sample is None:
        time.sleep(0.005)
        continue
    s = sample.payload().contents
    p = s.joints
    got += 1
    print(
        json.dumps(
            {
                "stamp": [s.stamp_ns // 1_000_000_000, s.stamp_ns % 1_000_000_000],
                "sequence": s.sequence,
                "track_id": s.track_id,
                "lag": s.lag,
                "state": s.state,
                "units": s.units,
                "metric_source": s.metric_source,
                "frames_since_look": s.frames_since_look,
                "frame_id": s.frame_id.decode(),
                "joint_names": [s.joint_names[j].value.decode() for j in range(p)],
                "positions": list(s.positions[: 3 * p]),
                "position_std": list(s.position_std[: 3 * p]),
                "keypoints": list(s.keypoints[: 2 * p]),
                "keypoint_std": list(s.keypoint_std[:p]),
                "projected": list(s.projected[: 2 * p]),
                "mean_bone_length": s.mean_bone_length,
            }
        ),
        flush=True,
    )
    del sample
sys.exit(0 if got >= count else 1)
