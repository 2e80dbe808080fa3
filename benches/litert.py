"""Google's LiteRT (PyPI `ai-edge-litert`, XNNPACK on CPU) on the BlazePose models that
posestream runs with tract: milliseconds per run, one and two threads, to set beside
`cargo bench --bench detector` (docs/speed.md, "The image detector").

usage: python benches/litert.py MODELS_DIR   (the folder `posestream models fetch` fills)
"""

import sys
import time

import numpy as np
from ai_edge_litert.interpreter import Interpreter

models = sys.argv[1] if len(sys.argv) > 1 else "."
rng = np.random.default_rng(0)
for name in ["pose_landmark_lite", "pose_landmark_full", "pose_landmark_heavy", "pose_detection"]:
    for threads in [1, 2]:
        it = Interpreter(model_path=f"{models}/{name}.tflite", num_threads=threads)
        it.allocate_tensors()
        inp = it.get_input_details()[0]
        it.set_tensor(inp["index"], rng.random(inp["shape"], dtype=np.float32))
        for _ in range(5):
            it.invoke()
        runs, began = 40, time.perf_counter()
        for _ in range(runs):
            it.invoke()
        ms = (time.perf_counter() - began) / runs * 1e3
        print(f"{name:22} {threads} thread(s) {ms:7.2f} ms")
