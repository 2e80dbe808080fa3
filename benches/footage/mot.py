#!/usr/bin/env python3
"""MOT metrics of a footage run, by an established library (`motmetrics`, PyPI, MIT):
an independent check of `score.rs`'s IDF1 and id switches, plus MOTA, fragmentations
and the people mostly tracked.

    python3 benches/footage/mot.py ANNOTATIONS.json FOUND.json

FOUND.json is what `cargo bench --bench footage` writes beside the recording
(target/footage/CLIP-found.json): every skeleton's frame, track and the median of its 2D
joints. Prints one JSON object.

The same rules as score.rs where the library has no word for them: the objects are the
counted people (at least 60 px tall, not uncertain); a skeleton may match a person whose
box, grown by 15 % on each side, holds its median point (the distance is the point's
distance from the box centre over the box height); a skeleton that score.rs's matching
(each box one skeleton, the nearest box centre first, over every annotated person)
gives to a person not counted is neither right nor wrong (left out). The matching of
the rest to the counted people (per frame, keeping last frame's pairs where they still
hold, MOTChallenge's rule), IDF1 and the switches are motmetrics' own.
"""

import json
import math
import sys

import motmetrics as mm

MIN_HEIGHT = 60.0
GROW = 0.15


def holds(box, p):
    w, h = box[2] - box[0], box[3] - box[1]
    return (
        box[0] - GROW * w <= p[0] <= box[2] + GROW * w
        and box[1] - GROW * h <= p[1] <= box[3] + GROW * h
    )


def counted(person):
    b = person["box"]
    return not person.get("uncertain", False) and b[3] - b[1] >= MIN_HEIGHT


def centre_distance(box, p):
    c = ((box[0] + box[2]) / 2, (box[1] + box[3]) / 2)
    return math.hypot(c[0] - p[0], c[1] - p[1]) / max(box[3] - box[1], 1.0)


def on_uncounted(people, hyps):
    """The hypotheses score.rs's greedy matching gives to a person not counted."""
    pairs = sorted(
        (centre_distance(p["box"], at), i, j)
        for i, p in enumerate(people)
        for j, (_, at) in enumerate(hyps)
        if holds(p["box"], at)
    )
    used_p, used_h, out = set(), set(), set()
    for _, i, j in pairs:
        if i not in used_p and j not in used_h:
            used_p.add(i)
            used_h.add(j)
            if not counted(people[i]):
                out.add(j)
    return out


def accumulate(clip, found):
    by_frame = {}
    for f in found:
        by_frame.setdefault(f["frame"], []).append(f)
    acc = mm.MOTAccumulator(auto_id=False)
    for frame in clip["frames"]:
        people = frame["people"]
        objects = [p for p in people if counted(p)]
        hyps = [(f["track"], (f["x"], f["y"])) for f in by_frame.get(frame["frame"], [])]
        ignored = on_uncounted(people, hyps)
        hyps = [h for j, h in enumerate(hyps) if j not in ignored]
        dists = [
            [centre_distance(p["box"], at) if holds(p["box"], at) else math.nan for _, at in hyps]
            for p in objects
        ]
        acc.update(
            [p["id"] for p in objects],
            [t for t, _ in hyps],
            dists,
            frameid=frame["frame"],
        )
    return acc


def load(path):
    try:
        with open(path) as f:
            return json.load(f)
    except (OSError, ValueError) as e:
        sys.exit(f"{path}: {e}")


def checked(clip, found):
    """One clear error for inputs that are not an annotation file and a found list."""
    number = (int, float)
    try:
        assert isinstance(clip, dict), "the annotations are not an object"
        assert isinstance(clip["clip"], str), "clip is not a name"
        for frame in clip["frames"]:
            assert isinstance(frame["frame"], int), f"frame {frame['frame']!r} is not an integer"
            ids = [p["id"] for p in frame["people"]]
            assert len(set(ids)) == len(ids), f"frame {frame['frame']}: an id twice"
            for p in frame["people"]:
                b = p["box"]
                assert len(b) == 4 and all(isinstance(v, number) for v in b), f"box {b!r}"
                assert isinstance(p.get("uncertain", False), bool), "uncertain is not a boolean"
        frames = [f["frame"] for f in clip["frames"]]
        assert len(set(frames)) == len(frames), "a frame annotated twice"
        assert isinstance(found, list), "the found skeletons are not a list"
        for f in found:
            assert isinstance(f["frame"], int) and isinstance(f["track"], int), f"{f!r}"
            assert all(isinstance(f[k], number) for k in ("x", "y")), f"{f!r}"
    except (AssertionError, KeyError, TypeError) as e:
        sys.exit(f"{sys.argv[1]}, {sys.argv[2]}: not annotations and found skeletons: {e!r}")


def main():
    if len(sys.argv) != 3:
        sys.exit(__doc__)
    clip, found = load(sys.argv[1]), load(sys.argv[2])
    checked(clip, found)
    annotated = {f["frame"] for f in clip["frames"]}
    if found and not any(f["frame"] in annotated for f in found):
        print("no skeleton falls on an annotated frame (another clip's?)", file=sys.stderr)
    acc = accumulate(clip, found)
    metrics = [
        "idf1",
        "idp",
        "idr",
        "mota",
        "recall",
        "precision",
        "num_switches",
        "num_fragmentations",
        "num_unique_objects",
        "mostly_tracked",
        "num_objects",
        "num_false_positives",
    ]
    summary = mm.metrics.create().compute(acc, metrics=metrics, name=clip["clip"])
    row = summary.loc[clip["clip"]]
    out = {}
    for m in metrics:
        v = float(row[m])
        # NaN or infinite (nobody counted) is JSON's null.
        out[m] = None if not math.isfinite(v) else (v if "num" not in m and m != "mostly_tracked" else int(v))
    out["clip"] = clip["clip"]
    out["tracks"] = len({f["track"] for f in found})
    print(json.dumps(out))


if __name__ == "__main__":
    main()
