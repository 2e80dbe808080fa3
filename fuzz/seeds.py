#!/usr/bin/env python3
"""Writes the seed inputs of the fuzz targets into fuzz/corpus/<target>/seed-*.

    python3 fuzz/seeds.py

Small, valid inputs of every format, made here (CDR by hand, MCAP with the `mcap`
package, NPY with numpy, MAT with scipy, images with Pillow) or taken from the
repository's own files (configuration, the shipped dictionary cut to 2 bases, one heat-map
message of a shipped recording). Needs numpy, scipy, Pillow and mcap (.ci/run's virtual
environment has them). The fuzzers grow the corpus from these; `cargo fuzz cmin` keeps
it small.
"""

import io
import json
import struct
from pathlib import Path

import numpy as np
import scipy.io
from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer
from PIL import Image

ROOT = Path(__file__).resolve().parent.parent
CORPUS = ROOT / "fuzz" / "corpus"
JOINTS = [
    "pelvis", "l-hip", "l-knee", "l-ankle", "r-hip", "r-knee", "r-ankle", "spine", "thorax",
    "neck", "head-top", "l-shoulder", "l-elbow", "l-wrist", "r-shoulder", "r-elbow", "r-wrist",
]


class Cdr:
    """CDR little-endian (XCDR1) behind the encapsulation header, as ROS 2 writes it."""

    def __init__(self):
        self.b = bytearray()

    def align(self, n):
        while len(self.b) % n:
            self.b.append(0)

    def put(self, fmt, v, n):
        self.align(n)
        self.b += struct.pack("<" + fmt, v)
        return self

    def u8(self, v):
        return self.put("B", v, 1)

    def u32(self, v):
        return self.put("I", v, 4)

    def i32(self, v):
        return self.put("i", v, 4)

    def u64(self, v):
        return self.put("Q", v, 8)

    def f32(self, v):
        return self.put("f", v, 4)

    def f64(self, v):
        return self.put("d", v, 8)

    def string(self, s):
        data = s.encode() + b"\0"
        self.u32(len(data))
        self.b += data
        return self

    def seq(self, items, kind):
        """A sequence of `kind` (the name of one of the methods above)."""
        self.u32(len(items))
        for i in items:
            getattr(self, kind)(i)
        return self

    def header(self, sec=1700000000, frame="camera"):
        return self.i32(sec).u32(0).string(frame)

    def bytes(self):
        return b"\x00\x01\x00\x00" + bytes(self.b)


def heatmaps(seq, h, w, values=None, quantized=None, scale=0.0):
    c = Cdr().header().u64(seq).u32(0).seq(JOINTS, "string")
    c.u32(h).u32(w).f64(10.0).f64(20.0).f64(64.0).f64(64.0)
    c.u8(0 if values is not None else 1)
    c.seq(values or [], "f32")
    c.seq(quantized or [], "u8")
    c.f32(scale)
    return c.bytes()


def skeleton(seq, state):
    p = len(JOINTS)
    c = Cdr().header().u64(seq).u32(3).seq(JOINTS, "string").u8(0)
    for n in (3 * p, p, 2 * p, p, 2 * p):
        c.seq([0.1 * i for i in range(n)], "f64")
    return c.u32(2).u8(state).bytes()


def write(target, name, data):
    d = CORPUS / target
    d.mkdir(parents=True, exist_ok=True)
    (d / f"seed-{name}").write_bytes(data)


def small_maps():
    peak = [0.0] * 16
    peak[5] = 1.0
    return peak * len(JOINTS)


def main():
    # heatmaps_cdr: small float32 and uint8 frames, and one real 64 x 64 frame.
    write("heatmaps_cdr", "f32-4x4", heatmaps(3, 4, 4, values=small_maps()))
    write("heatmaps_cdr", "u8-4x4", heatmaps(4, 4, 4, quantized=[int(v * 255) for v in small_maps()], scale=1 / 255))
    with open(ROOT / "recordings" / "kick.mcap", "rb") as f:
        for _, channel, message in make_reader(f).iter_messages():
            if channel.topic == "/posestream/heatmaps":
                write("heatmaps_cdr", "kick-frame-0", message.data)
                break
    # skeleton_cdr.
    write("skeleton_cdr", "tracking", skeleton(7, 1))
    write("skeleton_cdr", "lost", skeleton(8, 2))
    # shm_sample: kind byte, then the header fields, names, payload (f32).
    names = b"".join(j.encode().ljust(24, b"\0") for j in JOINTS[:4])
    head = struct.pack("<qQIIII4d", 1700000000, 5, 0, 17, 2, 2, 0.0, 0.0, 64.0, 64.0)
    payload = struct.pack("<68f", *([0.5] * 68))
    write("shm_sample", "heatmaps", b"\x00" + head + b"camera".ljust(64, b"\0") + names + payload)
    sk = struct.pack("<qQIII2B", 1700000000, 9, 1, 17, 0, 1, 0)
    write("shm_sample", "skeleton", b"\x01" + sk + b"camera".ljust(64, b"\0") + names + struct.pack("<51d", *range(51)))
    # mcap: three small frames, chunked zstd, lz4 and uncompressed.
    schema_text = None
    with open(ROOT / "recordings" / "kick.mcap", "rb") as f:
        for schema in make_reader(f).get_summary().schemas.values():
            if schema.name == "posestream_msgs/msg/HeatMaps":
                schema_text = schema.data
    for name, compression in [("zstd", CompressionType.ZSTD), ("lz4", CompressionType.LZ4), ("none", CompressionType.NONE)]:
        out = io.BytesIO()
        w = Writer(out, compression=compression, chunk_size=2048)
        w.start(profile="ros2", library="posestream fuzz seeds")
        sid = w.register_schema("posestream_msgs/msg/HeatMaps", "ros2msg", schema_text)
        cid = w.register_channel("/posestream/heatmaps", "cdr", sid)
        for i in range(3):
            data = heatmaps(i, 4, 4, values=small_maps())
            w.add_message(cid, log_time=i * 33_000_000, data=data, publish_time=i * 33_000_000)
        w.finish()
        write("mcap", name, out.getvalue())
    # npy.
    for name, a in [
        ("f64-keypoints", np.arange(2 * 17 * 2, dtype="<f8").reshape(2, 17, 2)),
        ("f32-maps", np.ones((1, 17, 4, 4), dtype="<f4")),
        ("fortran", np.asfortranarray(np.arange(12, dtype="<f8").reshape(3, 4))),
        ("big-endian", np.arange(6, dtype=">f4").reshape(2, 3)),
    ]:
        buf = io.BytesIO()
        np.save(buf, a)
        write("npy", name, buf.getvalue())
    # dictionary: the shipped one cut to 2 bases, as JSON (kind 1) and MAT (kind 0).
    d = json.loads((ROOT / "config" / "dictionaries" / "default-k128.json").read_text())
    d["bases"] = d["bases"][:2]
    write("dictionary", "json-2-bases", b"\x01" + json.dumps(d).encode())
    p = len(d["joints"])
    bases = np.array(d["bases"])  # k x 3 x p
    b = bases.reshape(-1, p)  # 3k x p: rows 3i..3i+2 are basis i
    tree = np.zeros((1, p), dtype=[("name", "O"), ("children", "O")])
    for j in range(p):
        tree[0, j]["name"] = d["joints"][j]
        tree[0, j]["children"] = np.array(
            [c + 1 for c in range(p) if d["parents"][c] == j], dtype=float
        ).reshape(1, -1)
    skel = {"tree": tree, "torso": np.array([t + 1 for t in d["torso"]], dtype=float).reshape(1, -1)}
    buf = io.BytesIO()
    scipy.io.savemat(buf, {"B": b, "mu": np.array(d["mean"]).reshape(3, p), "skel": skel})
    write("dictionary", "mat-2-bases", b"\x00" + buf.getvalue())
    # bvh: a small hierarchy with position channels on the root and an end site.
    write("bvh", "three-joints", b"""HIERARCHY
ROOT Hips
{
  OFFSET 0 0 0
  CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation
  JOINT Spine
  {
    OFFSET 0 10 0
    CHANNELS 3 Zrotation Xrotation Yrotation
    End Site
    {
      OFFSET 0 5 0
    }
  }
}
MOTION
Frames: 2
Frame Time: 0.033333
0 90 0 0 0 0 10 0 0
1 90 0 0 5 0 10 0 0
""")
    # toml: kind byte, then the text.
    write("toml", "service", b"\x00" + (ROOT / "config" / "default.toml").read_bytes())
    for f in sorted((ROOT / "config" / "skeletons").glob("*.toml")):
        write("toml", f"mapping-{f.stem}", b"\x01" + f.read_bytes())
    for f in sorted((ROOT / "config" / "detectors").glob("*.toml")):
        write("toml", f"channels-{f.stem}", b"\x02" + f.read_bytes())
    for f in sorted((ROOT / "config" / "splits").glob("*.toml")):
        write("toml", f"split-{f.stem}", b"\x03" + f.read_bytes())
    # image_file and sensor_image.
    img = Image.new("RGB", (5, 3), (10, 20, 30))
    for fmt, mode in [("PNG", "RGB"), ("PNG", "RGBA"), ("PNG", "L"), ("PNG", "I;16"), ("JPEG", "RGB"), ("GIF", "P")]:
        buf = io.BytesIO()
        img.convert(mode).save(buf, format=fmt)
        write("image_file", f"{fmt.lower()}-{mode.replace(';', '')}", buf.getvalue())
        if fmt in ("PNG", "JPEG") and mode == "RGB":
            c = Cdr().header().string(fmt.lower()).seq(list(buf.getvalue()), "u8")
            write("sensor_image", f"compressed-{fmt.lower()}", b"\x01" + c.bytes())
    for enc, ch in [("rgb8", 3), ("bgra8", 4), ("mono8", 1)]:
        w, h, step = 3, 2, 3 * ch + 1
        c = Cdr().header().u32(h).u32(w).string(enc).u8(0).u32(step)
        c.seq([v % 256 for v in range(step * h)], "u8")
        write("sensor_image", f"raw-{enc}", b"\x00" + c.bytes())

    # live_view: a viewer's upgrade request and frames (masked: a ping, a subscribe in
    # two fragments, a pong, a close), read in 8-byte pieces; a page request; a server's
    # answer and frames.
    def frame(fin, opcode, payload, mask=True):
        f = bytes([(0x80 if fin else 0) | opcode])
        n = len(payload)
        m = 0x80 if mask else 0
        if n < 126:
            f += bytes([m | n])
        elif n < 65536:
            f += bytes([m | 126]) + struct.pack(">H", n)
        else:
            f += bytes([m | 127]) + struct.pack(">Q", n)
        if mask:
            key = b"\x01\x02\x03\x04"
            f += key + bytes(b ^ key[i % 4] for i, b in enumerate(payload))
        else:
            f += payload
        return f
    upgrade = (b"GET / HTTP/1.1\r\nHost: 127.0.0.1:8765\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
               b"Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\nSec-WebSocket-Version: 13\r\n"
               b"Sec-WebSocket-Protocol: foxglove.sdk.v1\r\n\r\n")
    subscribe = b'{"op":"subscribe","subscriptions":[{"id":1,"channelId":1}]}'
    viewer = (frame(True, 0x9, b"ping") + frame(False, 0x1, subscribe[:20]) + frame(True, 0x0, subscribe[20:])
              + frame(True, 0xA, b"") + frame(True, 0x8, b"\x03\xe8"))
    write("live_view", "viewer", b"\x01" + upgrade + viewer)
    write("live_view", "page", b"\x00GET / HTTP/1.1\r\nHost: x\r\n\r\n")
    server = frame(True, 0xA, b"ping", mask=False) + frame(True, 0x2, bytes(300), mask=False)
    write("live_view", "server", b"\x03HTTP/1.1 101 Switching Protocols\r\nUpgrade: websocket\r\n\r\n" + server)


if __name__ == "__main__":
    main()
