"""Independent client: the bodies of a posestream MCAP recording as a ROS 2 user's tools
see them. `/tf` (tf2_msgs/TFMessage) and sensor_msgs/RegionOfInterest are decoded with
rosbags' ROS 2 Humble type store (not with the recording's schemas), and `/tf` again with
Jazzy's, which must read the same; hri_msgs/IdsList and
Skeleton2D with the ros4hri definitions given on the command line; the skeletons with
mcap-ros2-support. Each newest skeleton in metres is rebuilt from its body frame and joint
frames (quaternions composed here) and compared with its published joint positions; the
footprints (with a floor) are counted with their parents.
Prints JSON.

usage: python body_frames.py RECORDING HRI_MSG_DIR
"""

import json
import math
import sys
from pathlib import Path

from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from rosbags.typesys import Stores, get_typestore, get_types_from_msg

path, hri_dir = sys.argv[1], Path(sys.argv[2])
store = get_typestore(Stores.ROS2_HUMBLE)
types = {}
for name in ["NormalizedPointOfInterest2D", "IdsList", "Skeleton2D"]:
    types.update(get_types_from_msg((hri_dir / f"{name}.msg").read_text(), f"hri_msgs/msg/{name}"))
store.register(types)
jazzy = get_typestore(Stores.ROS2_JAZZY)
distros_disagree = 0


def rotate(q, v):
    """v rotated by the unit quaternion q = (x, y, z, w)."""
    x, y, z, w = q
    # t = 2 q_vec x v; v' = v + w t + q_vec x t
    tx = 2 * (y * v[2] - z * v[1])
    ty = 2 * (z * v[0] - x * v[2])
    tz = 2 * (x * v[1] - y * v[0])
    return (
        v[0] + w * tx + (y * tz - z * ty),
        v[1] + w * ty + (z * tx - x * tz),
        v[2] + w * tz + (x * ty - y * tx),
    )


frames = {}  # (stamp ns, child) -> (parent, translation, rotation)
skeletons = []
tracked = []
roi = {}
skeleton2d = {}
unobserved = set()
observed = set()
roi_bad = 0
factory = DecoderFactory()
decoders = {}
with open(path, "rb") as f:
    reader = make_reader(f)
    for schema, channel, message in reader.iter_messages():
        topic = channel.topic
        if topic == "/tf":
            tf = store.deserialize_cdr(message.data, "tf2_msgs/msg/TFMessage")
            other = jazzy.deserialize_cdr(message.data, "tf2_msgs/msg/TFMessage")
            if [
                (t.child_frame_id, t.transform.translation.x, t.transform.rotation.w)
                for t in tf.transforms
            ] != [
                (t.child_frame_id, t.transform.translation.x, t.transform.rotation.w)
                for t in other.transforms
            ]:
                distros_disagree += 1
            for t in tf.transforms:
                stamp = t.header.stamp.sec * 10**9 + t.header.stamp.nanosec
                tr, rq = t.transform.translation, t.transform.rotation
                frames[(stamp, t.child_frame_id)] = (
                    t.header.frame_id,
                    (tr.x, tr.y, tr.z),
                    (rq.x, rq.y, rq.z, rq.w),
                )
        elif topic == "/posestream/skeletons":
            if channel.id not in decoders:
                decoders[channel.id] = factory.decoder_for(channel.message_encoding, schema)
            s = decoders[channel.id](message.data)
            if s.lag == 0 and s.units == 1:
                skeletons.append(s)
        elif topic == "/humans/bodies/tracked":
            ids = store.deserialize_cdr(message.data, "hri_msgs/msg/IdsList")
            tracked.append(sorted(ids.ids))
        elif topic.startswith("/humans/bodies/") and topic.endswith("/roi"):
            body = topic.split("/")[3]
            r = store.deserialize_cdr(message.data, "sensor_msgs/msg/RegionOfInterest")
            roi[body] = roi.get(body, 0) + 1
            if r.width == 0 or r.height == 0:
                roi_bad += 1
        elif topic.startswith("/humans/bodies/") and topic.endswith("/skeleton2d"):
            body = topic.split("/")[3]
            s2 = store.deserialize_cdr(message.data, "hri_msgs/msg/Skeleton2D")
            skeleton2d[body] = skeleton2d.get(body, 0) + 1
            for k, p in enumerate(s2.skeleton):
                if p.c == 0:
                    unobserved.add(k)
                elif not (0 <= p.x <= 1 and 0 <= p.y <= 1 and 0 < p.c <= 1):
                    roi_bad += 1
                else:
                    observed.add(k)

worst, checked, missing, parents = 0.0, 0, 0, set()
# Where people stand (with a floor): body_b<id>_footprint under the floor frame.
footprints = [parent for (_, child), (parent, _, _) in frames.items() if child.endswith("_footprint")]
for s in skeletons:
    stamp = s.header.stamp.sec * 10**9 + s.header.stamp.nanosec
    body = f"body_b{s.track_id}"
    if (stamp, body) not in frames:
        missing += 1
        continue
    parent, origin, q = frames[(stamp, body)]
    parents.add(parent)
    for j, name in enumerate(s.joint_names):
        child = name.replace("-", "_") + f"_b{s.track_id}"
        jp, jt, jq = frames[(stamp, child)]
        assert jp == body, (jp, body)
        r = rotate(q, jt)
        at = [origin[i] + r[i] for i in range(3)]
        want = s.positions[3 * j : 3 * j + 3]
        worst = max(worst, math.dist(at, want))
        checked += 1

print(
    json.dumps(
        {
            "skeletons": len(skeletons),
            "frames": len(frames),
            "joints_checked": checked,
            "without_frames": missing,
            "max_error_m": worst,
            "parents": sorted(parents),
            "tracked": tracked,
            "roi": roi,
            "skeleton2d": skeleton2d,
            "unobserved_keypoints": sorted(unobserved),
            "observed_keypoints": sorted(observed),
            "bad": roi_bad,
            "distros_disagree": distros_disagree,
            "footprints": len(footprints),
            "footprint_parents": sorted(set(footprints)),
        }
    )
)
