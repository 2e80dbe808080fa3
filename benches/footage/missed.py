"""Where each annotated person the pipeline missed was lost: read from a run's debug log.

    RUST_LOG=posestream_detector::image=debug posestream run --video CLIP --ros2 false \
        --json 2> run.log > /dev/null
    python3 benches/footage/missed.py benches/footage/CLIP.json run.log [--list]

CLIP is the clip as the footage bench runs it (target/footage/<name>-cut.<ext>, whose
images are numbered like the annotations). For every counted person of every annotated
image (not `uncertain`, at least 60 px tall, as the scorer counts them) it says one of:

- found: a person reported there (their body landmarks' centre in the box, 10 % margin);
- kept, not reported: followed, but the track not confirmed yet;
- no search within 3 images: no search's boxes arrived in the image or the 3 before;
- no box on them: the newest search had no box overlapping theirs (IoU >= 0.3);
- box ...: the box on them, the tracker's verdict (Track, Birth, Candidate, Ignored),
  whether it lay at a refused place (a look there found nobody in the last frames), and
  what the landmark model's look found (not looked at, nobody, someone).

Standard library only. The log lines are written by crates/detector/src/image
(`trace_boxes`, and the kept people of `detect`).
"""

import collections
import json
import re
import sys

MIN_HEIGHT = 60.0  # benches/footage/score.rs: MIN_HEIGHT
BOX = re.compile(
    r"image (\d+): box \d+ body (-?[\d.]+),(-?[\d.]+),(-?[\d.]+),(-?[\d.]+) score ([\d.]+) "
    r"detector box (\w+) refused (\w+) verdict (\w+)\S* look (.*)$"
)
KEPT = re.compile(
    r"image (\d+): kept (\d+) body (-?[\d.]+),(-?[\d.]+),(-?[\d.]+),(-?[\d.]+) reported (\w+)"
)
ANSI = re.compile(r"\x1b\[[0-9;]*m")


def iou(a, b):
    w = min(a[2], b[2]) - max(a[0], b[0])
    h = min(a[3], b[3]) - max(a[1], b[1])
    if w <= 0 or h <= 0:
        return 0.0
    inter = w * h
    return inter / ((a[2] - a[0]) * (a[3] - a[1]) + (b[2] - b[0]) * (b[3] - b[1]) - inter)


def inside(p, b, margin=0.1):
    w, h = b[2] - b[0], b[3] - b[1]
    return b[0] - margin * w <= p[0] <= b[2] + margin * w and b[1] - margin * h <= p[1] <= b[3] + margin * h


def main():
    clip = json.load(open(sys.argv[1]))
    boxes, kept = collections.defaultdict(list), collections.defaultdict(list)
    for line in open(sys.argv[2], errors="replace"):
        line = ANSI.sub("", line)
        if m := BOX.search(line):
            boxes[int(m[1])].append(
                {
                    "body": [float(m[k]) for k in range(2, 6)],
                    "refused": m[8] == "true",
                    "verdict": m[9],
                    "look": m[10].strip(),
                }
            )
        elif m := KEPT.search(line):
            body = [float(m[k]) for k in range(3, 7)]
            kept[int(m[1])].append({"centre": ((body[0] + body[2]) / 2, (body[1] + body[3]) / 2), "reported": m[7] == "true"})
    if not boxes and not kept:
        sys.exit(f"{sys.argv[2]}: no detector debug lines (RUST_LOG=posestream_detector::image=debug)")
    why, listed = collections.Counter(), []
    for image in clip["frames"]:
        n = image["frame"]
        for p in image["people"]:
            a = p["box"]
            if p.get("uncertain") or a[3] - a[1] < MIN_HEIGHT:
                continue
            on = [k for k in kept[n] if inside(k["centre"], a)]
            if any(k["reported"] for k in on):
                why["found"] += 1
                continue
            if on:
                reason = "kept, not reported"
            else:
                newest = next((n - d for d in range(4) if boxes.get(n - d)), None)
                best = None if newest is None else max(boxes[newest], key=lambda b: iou(b["body"], a))
                if newest is None:
                    reason = "no search within 3 images"
                elif iou(best["body"], a) < 0.3:
                    reason = "no box on them"
                else:
                    look = {"None": "not looked at", "Some(None)": "nobody"}.get(best["look"], "someone")
                    refused = ", at a refused place" if best["refused"] else ""
                    reason = f"box: {best['verdict']}{refused}, look: {look}"
            why[reason] += 1
            listed.append((n, p["id"], reason))
    counted = sum(why.values())
    print(f"{clip['clip']}: {counted} people counted")
    for reason, count in why.most_common():
        print(f"{count:5d} {count / counted:5.2f}  {reason}")
    if "--list" in sys.argv:
        for n, person, reason in listed:
            print(f"image {n} person {person}: {reason}")


if __name__ == "__main__":
    main()
