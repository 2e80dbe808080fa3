"""Independent client: read an MCAP file through its summary and index, as a seeking
reader does (Python `mcap`'s `make_reader`: the summary's chunk indexes, then the chunks
they point at), decode every message with `mcap-ros2-support`, and print per topic the
messages read and decoded as JSON, with the summary's statistics. Used by tests/hardening.rs
on the copies `posestream recover` writes."""

import json
import sys

from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory


def main():
    path = sys.argv[1]
    out = {"topics": {}, "decoded": 0, "chunk_indexes": 0, "statistics": None}
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        summary = reader.get_summary()
        if summary is None:
            raise SystemExit(f"{path}: no summary")
        out["chunk_indexes"] = len(summary.chunk_indexes)
        if summary.statistics is not None:
            out["statistics"] = summary.statistics.message_count
        for _schema, channel, _message, decoded in reader.iter_decoded_messages():
            out["topics"][channel.topic] = out["topics"].get(channel.topic, 0) + 1
            if decoded is not None:
                out["decoded"] += 1
    print(json.dumps(out))


if __name__ == "__main__":
    main()
