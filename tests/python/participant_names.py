"""Independent client: the names DDS participants announce in discovery (the EntityName
QoS of DCPSParticipant, what `cyclonedds ls` prints), as Python `cyclonedds` sees them
on DOMAIN, printed as JSON once NAME is among them or TIMEOUT_S has passed.

usage: participant_names.py DOMAIN NAME TIMEOUT_S
"""

import json
import sys
import time

domain, wanted, timeout = int(sys.argv[1]), sys.argv[2], float(sys.argv[3])
import ros2_types  # noqa: E402,F401  (DDS on loopback, set on import)

from cyclonedds.builtin import BuiltinDataReader, BuiltinTopicDcpsParticipant  # noqa: E402
from cyclonedds.core import Policy  # noqa: E402
from cyclonedds.domain import DomainParticipant  # noqa: E402

participant = DomainParticipant(domain)
reader = BuiltinDataReader(participant, BuiltinTopicDcpsParticipant)
names = {}
deadline = time.monotonic() + timeout
while time.monotonic() < deadline and wanted not in names.values():
    for sample in reader.take(N=100):
        try:
            name = sample.qos[Policy.EntityName].name
        except (KeyError, AttributeError, TypeError):
            name = None
        names[str(sample.key)] = name
    time.sleep(0.1)
print(json.dumps({"names": sorted(n for n in names.values() if n is not None),
                  "unnamed": sum(1 for n in names.values() if n is None)}))
