"""Independent client: decode a posestream MCAP recording with the `mcap` and
`mcap-ros2-support` packages (and, for a rosbag2 folder, with `rosbags`), and print what
it holds as JSON. Used by tests/recording.rs."""

import json
import sys
from pathlib import Path


def read_mcap(path, allow_truncated):
    from mcap.stream_reader import StreamReader
    from mcap.records import Channel, Chunk, Message, Schema
    from mcap.decoder import DecoderFactory as _Unused  # noqa: F401 (import check)
    from mcap_ros2.decoder import DecoderFactory

    factory = DecoderFactory()
    schemas, channels, decoders = {}, {}, {}
    out = {
        "topics": {},
        "schemas": {},
        "skeletons": [],
        "heatmaps": [],
        "markers": [],
        "arrays": [],
        "floors": [],
        "error": None,
    }

    def handle(msg):
        channel = channels[msg.channel_id]
        schema = schemas[channel.schema_id]
        key = channel.id
        if key not in decoders:
            decoders[key] = factory.decoder_for(channel.message_encoding, schema)
        decoded = decoders[key](msg.data)
        out["topics"][channel.topic] = out["topics"].get(channel.topic, 0) + 1
        out["schemas"][channel.topic] = schema.name
        if schema.name == "posestream_msgs/msg/Skeleton3D" and len(out["skeletons"]) < 50:
            out["skeletons"].append(
                {
                    "topic": channel.topic,
                    "sequence": decoded.sequence,
                    "stamp": [decoded.header.stamp.sec, decoded.header.stamp.nanosec],
                    "frame_id": decoded.header.frame_id,
                    "joint_names": list(decoded.joint_names),
                    "positions": list(decoded.positions),
                    "position_std": list(decoded.position_std),
                    "keypoints": list(decoded.keypoints),
                    "lag": decoded.lag,
                    "state": decoded.state,
                    "units": decoded.units,
                }
            )
        if schema.name == "visualization_msgs/msg/MarkerArray" and len(out["markers"]) < 5:
            out["markers"].append(
                [
                    {
                        "ns": m.ns,
                        "id": m.id,
                        "type": m.type,
                        "frame_id": m.header.frame_id,
                        "points": [[p.x, p.y, p.z] for p in m.points],
                        "scale": [m.scale.x, m.scale.y, m.scale.z],
                        "color": [m.color.r, m.color.g, m.color.b, m.color.a],
                        "orientation_w": m.pose.orientation.w,
                        "lifetime": [m.lifetime.sec, m.lifetime.nanosec],
                    }
                    for m in decoded.markers
                ]
            )
        if schema.name == "posestream_msgs/msg/Skeleton3DArray":
            out["arrays"].append(
                {
                    "sequence": decoded.sequence,
                    "lag": decoded.lag,
                    "stamp": [decoded.header.stamp.sec, decoded.header.stamp.nanosec],
                    "tracks": [s.track_id for s in decoded.skeletons],
                    "sequences": [s.sequence for s in decoded.skeletons],
                    "first_positions": list(decoded.skeletons[0].positions)
                    if decoded.skeletons
                    else [],
                }
            )
        if schema.name == "geometry_msgs/msg/PoseWithCovarianceStamped":
            p = decoded.pose.pose.position
            out["floors"].append(
                {
                    "frame_id": decoded.header.frame_id,
                    "position": [p.x, p.y, p.z],
                    "covariance": [float(v) for v in decoded.pose.covariance],
                }
            )
        if schema.name == "sensor_msgs/msg/CameraInfo" and "camera_info" not in out:
            out["camera_info"] = {
                "width": decoded.width,
                "height": decoded.height,
                "k": [float(v) for v in decoded.k],
                "p": [float(v) for v in decoded.p],
                "binning_x": decoded.binning_x,
                "roi_width": decoded.roi.width,
            }
        if schema.name == "posestream_msgs/msg/HeatMaps" and len(out["heatmaps"]) < 3:
            out["heatmaps"].append(
                {
                    "sequence": decoded.sequence,
                    "height": decoded.height,
                    "width": decoded.width,
                    "encoding": decoded.encoding,
                    "values": len(decoded.values),
                    "quantized_values": len(decoded.quantized_values),
                }
            )

    try:
        with open(path, "rb") as f:
            for record in StreamReader(f, emit_chunks=False).records:
                if isinstance(record, Schema):
                    schemas[record.id] = record
                elif isinstance(record, Channel):
                    channels[record.id] = record
                elif isinstance(record, Message):
                    handle(record)
    except Exception as e:  # a truncated file ends with an error; say which
        if not allow_truncated:
            raise
        out["error"] = f"{type(e).__name__}: {e}"
    return out


def read_rosbag2(folder):
    from rosbags.highlevel import AnyReader

    counts, first = {}, {}
    with AnyReader([Path(folder)]) as reader:
        for conn, _t, raw in reader.messages():
            msg = reader.deserialize(raw, conn.msgtype)
            counts[conn.topic] = counts.get(conn.topic, 0) + 1
            if conn.topic not in first and hasattr(msg, "positions"):
                first[conn.topic] = {
                    "type": conn.msgtype,
                    "sequence": int(msg.sequence),
                    "positions": [float(v) for v in msg.positions],
                }
    return {"topics": counts, "first": first}


def main():
    args = sys.argv[1:]
    allow_truncated = "--allow-truncated" in args
    args = [a for a in args if a != "--allow-truncated"]
    if args[0] == "--rosbag2":
        print(json.dumps(read_rosbag2(args[1])))
    else:
        print(json.dumps(read_mcap(args[0], allow_truncated)))


if __name__ == "__main__":
    main()
