"""posestream against MediaPipe Pose, side by side on one video, in interleaved rounds
(issue 45; README, "Against MediaPipe"). Not in CI: it needs MediaPipe from PyPI.

MediaPipe Pose: the legacy `solutions.pose` (`model_complexity=1`, the full landmark
model, tracking between frames), timed two ways: end to end (each frame decoded by
OpenCV, converted to RGB and given to `process`: frames per second over the loop) and its
pose calls alone (milliseconds per `process`: p50, p99 over the calls that gave a pose,
as posestream's latency is over images with someone, and over all calls).
posestream: `posestream run --video VIDEO --ros2 false --record ...` as a user runs it
(decoding, person detectors, landmarks, the estimator in metres, the recording), its own
report: frames per second from its first image to the run's end (closing the recording
included; MediaPipe's clock starts at its first frame too, after loading its models),
and over the whole run (from the process's start, in brackets), latency from a decoded
image to its newest skeleton published (p50, p99).
The two alternate, round after round, so that both see the same minutes of the
machine (this 2-core machine's speed varies by a fifth from minute to minute).

    python3 -m venv target/mediapipe
    target/mediapipe/bin/pip install mediapipe==0.10.14
    cargo build --release
    target/mediapipe/bin/python benches/against_mediapipe.py target/footage-media/bikes.mp4 \
        [--rounds 3] [--posestream target/release/posestream] [-- extra run options]
"""

import argparse
import json
import math
import os
import resource
import subprocess
import sys
import tempfile
import time

import cv2
import mediapipe as mp
import numpy as np


def cpu_seconds():
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def mediapipe_round(video):
    """MediaPipe Pose over `video`: end to end (decode included) and its calls alone."""
    cap = cv2.VideoCapture(video)
    if not cap.isOpened():
        sys.exit(f"{video}: OpenCV cannot open it")
    calls = []
    posed = []
    found = 0
    with mp.solutions.pose.Pose(static_image_mode=False, model_complexity=1) as pose:
        began, cpu = time.perf_counter(), cpu_seconds()
        while True:
            ok, frame = cap.read()
            if not ok:
                break
            rgb = cv2.cvtColor(frame, cv2.COLOR_BGR2RGB)
            at = time.perf_counter()
            result = pose.process(rgb)
            calls.append(time.perf_counter() - at)
            if result.pose_landmarks is not None:
                found += 1
                posed.append(calls[-1])
        wall, cpu = time.perf_counter() - began, cpu_seconds() - cpu
    cap.release()
    if not calls:
        sys.exit(f"{video}: OpenCV decoded no frame of it")
    ms = np.array(calls) * 1e3
    # Like posestream's latency (an image to its skeletons, over images with someone):
    # the calls that gave a pose.
    with_pose = np.array(posed) * 1e3 if posed else np.array([np.nan])
    return {
        "frames": len(calls),
        "with_person": found,
        "fps": len(calls) / wall,
        "calls_fps": len(calls) / (ms.sum() / 1e3),
        "p50": float(np.percentile(ms, 50)),
        "p99": float(np.percentile(ms, 99)),
        "pose_p50": float(np.percentile(with_pose, 50)),
        "pose_p99": float(np.percentile(with_pose, 99)),
        "cores": cpu / wall,
    }


def posestream_round(binary, video, extra):
    """One `posestream run` over `video`: its report's figures."""
    with tempfile.TemporaryDirectory() as tmp:
        try:
            out = subprocess.run(
                [binary, "run", "--video", video, "--ros2", "false", "--json",
                 "--record", os.path.join(tmp, "run.mcap"), *extra],
                capture_output=True, text=True, check=False, timeout=3600)
        except subprocess.TimeoutExpired:
            sys.exit("posestream run took over an hour")
        except OSError as e:
            sys.exit(f"{binary}: cannot run it ({e})")
        if out.returncode != 0:
            sys.exit(f"posestream run failed:\n{out.stderr[-2000:]}")
        try:
            report = json.loads(out.stdout)
        except json.JSONDecodeError as e:
            sys.exit(f"posestream run --json printed no report ({e})")
    # A run that ended early is not a figure.
    for side in ("detector", "estimator"):
        if report[side].get("input_error"):
            sys.exit(f"posestream run: {side} input error: {report[side]['input_error']}")
    # Figures posestream left out (an older binary) or had none of (null) are not
    # figures: NaN, printed as such.
    def number(value):
        return float(value) if isinstance(value, (int, float)) else float("nan")

    latency = report.get("latency") or {}
    if not latency.get("count"):
        latency = {}
    stages = {k: number(v) for k, v in (report.get("stages") or {}).items()}
    fps = number(report.get("streaming_frames_per_second"))
    if not math.isfinite(fps) or fps <= 0:
        sys.exit("posestream run reported no streaming_frames_per_second (a build before it?)")
    images = report["detector"]["images"] or {}
    if not images.get("frames"):
        sys.exit("posestream run took no frame of the video")
    return {
        "frames": images.get("frames", 0),
        "with_person": images.get("detected", 0),
        # From its first image, as MediaPipe's clock (model loading left out); the
        # whole run's figure beside it.
        "fps": fps,
        "run_fps": number(report.get("frames_per_second")),
        "p50": number(latency.get("median_ms")),
        "p99": number(latency.get("p99_ms")),
        "stages": stages,
    }


def rounds(text):
    n = int(text)
    if not 1 <= n <= 100:
        raise argparse.ArgumentTypeError(f"{n}: from 1 to 100")
    return n


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("video")
    ap.add_argument("--rounds", type=rounds, default=3, help="1 to 100 (default 3)")
    ap.add_argument("--posestream", default="target/release/posestream")
    ap.add_argument("extra", nargs="*", help="more `posestream run` options (after --)")
    args = ap.parse_args()
    # The video must decode before a round spends a posestream run on it.
    probe = cv2.VideoCapture(args.video)
    if not (probe.isOpened() and probe.read()[0]):
        sys.exit(f"{args.video}: OpenCV cannot decode it")
    probe.release()
    print(f"MediaPipe {mp.__version__}, OpenCV {cv2.__version__}; {os.cpu_count()} cores; "
          f"{args.video}")
    print("| round | posestream frames/s from its first image (whole run) | p50 / p99 ms "
          "| MediaPipe frames/s (decode included) | its calls alone frames/s "
          "| p50 / p99 ms, calls with a pose (all calls) | cores it used | ratio (frames/s) |")
    print("|---|---:|---:|---:|---:|---:|---:|---:|")
    ratios = []
    for r in range(1, args.rounds + 1):
        # Each goes first in every other round.
        if r % 2:
            ours = posestream_round(args.posestream, args.video, args.extra)
            theirs = mediapipe_round(args.video)
        else:
            theirs = mediapipe_round(args.video)
            ours = posestream_round(args.posestream, args.video, args.extra)
        ratio = ours["fps"] / theirs["fps"]
        ratios.append(ratio)
        print(f"| {r} | {ours['fps']:.1f} ({ours['run_fps']:.1f}) | {ours['p50']:.1f} / {ours['p99']:.0f} "
              f"| {theirs['fps']:.1f} | {theirs['calls_fps']:.1f} "
              f"| {theirs['pose_p50']:.1f} / {theirs['pose_p99']:.0f} "
              f"({theirs['p50']:.1f} / {theirs['p99']:.0f}) | {theirs['cores']:.2f} | {ratio:.2f}x |",
              flush=True)
        if r == args.rounds:
            s = ours["stages"]
            print("\nposestream's stages (last round; *_ms in milliseconds): " + ", ".join(
                f"{k} {v:.2f}" for k, v in s.items()))
            print(f"people found: posestream in {ours['with_person']} of {ours['frames']} frames, "
                  f"MediaPipe in {theirs['with_person']} of {theirs['frames']}")
    print(f"\nposestream / MediaPipe frames/s: {min(ratios):.2f}-{max(ratios):.2f}x "
          f"over {len(ratios)} interleaved rounds")


if __name__ == "__main__":
    main()
