"""Decodes a CDR-encoded visualization_msgs/MarkerArray (header included) with each ROS 2
distribution's definitions (rosbags' type stores), printing per distribution each
marker's (ns, id, type, points, text), or the error.

usage: python marker_distros.py FILE
"""

import json
import sys

from rosbags.typesys import Stores, get_typestore

data = open(sys.argv[1], "rb").read()
out = {}
for store in ["ros2_foxy", "ros2_galactic", "ros2_humble", "ros2_iron", "ros2_jazzy", "ros2_kilted"]:
    try:
        typestore = get_typestore(Stores(store))
        array = typestore.deserialize_cdr(data, "visualization_msgs/msg/MarkerArray")
        out[store] = [[m.ns, m.id, m.type, len(m.points), m.text] for m in array.markers]
    except Exception as e:  # any decoding failure is the answer for that distribution
        out[store] = {"error": f"{type(e).__name__}: {e}"}
print(json.dumps(out))
