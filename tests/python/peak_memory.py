"""Runs a command and writes its exit status and peak resident memory to a JSON file.

    peak_memory.py OUT.json COMMAND [ARGS...]

The command's stdout and stderr pass through. The peak is `ru_maxrss` of the waited-for
child (kB). It is measured from this small process, not from the test binary that starts
it: Linux counts the resident memory of the process a child was spawned from into the
child's peak (vfork shares it), and a test process holding recordings is large.
"""

import json
import resource
import subprocess
import sys

proc = subprocess.run(sys.argv[2:])
with open(sys.argv[1], "w") as f:
    json.dump(
        {
            "returncode": proc.returncode,
            "maxrss_kb": resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss,
        },
        f,
    )
