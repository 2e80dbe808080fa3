"""ONNX Runtime (PyPI `onnxruntime`, the library `ort`'s load-dynamic would use) beside
LiteRT (PyPI `ai-edge-litert`) on the BlazePose models, in one run: the models converted
from TFLite to ONNX by `tf2onnx` (which needs TensorFlow: `pip install tensorflow-cpu
tf2onnx onnxruntime 'ai-edge-litert==2.3.*'`), milliseconds per run on one and two
threads, and the largest difference of their outputs (docs/image-detector.md, "Runtimes").

usage: python benches/ort_vs_litert.py MODELS_DIR WORK_DIR
"""

import subprocess
import sys
import time

import numpy as np
import onnxruntime as ort
from ai_edge_litert.interpreter import Interpreter

models, work = sys.argv[1], sys.argv[2]
rng = np.random.default_rng(0)


def timed(run, runs=40):
    for _ in range(5):
        run()
    began = time.perf_counter()
    for _ in range(runs):
        run()
    return (time.perf_counter() - began) / runs * 1e3


for name in ["pose_landmark_lite", "pose_landmark_full", "pose_detection"]:
    onnx = f"{work}/{name}.onnx"
    converted = subprocess.run(
        [sys.executable, "-m", "tf2onnx.convert", "--tflite", f"{models}/{name}.tflite",
         "--output", onnx, "--opset", "13"],
        capture_output=True, text=True,
    )
    if converted.returncode != 0:
        last = converted.stderr.strip().splitlines()[-1:] or ["?"]
        print(f"{name:20} tf2onnx cannot convert it: {last[0]}")
        continue
    for threads in [1, 2]:
        it = Interpreter(model_path=f"{models}/{name}.tflite", num_threads=threads)
        it.allocate_tensors()
        inp = it.get_input_details()[0]
        x = rng.random(inp["shape"], dtype=np.float32)
        it.set_tensor(inp["index"], x)
        litert_ms = timed(it.invoke)
        reference = [it.get_tensor(o["index"]) for o in it.get_output_details()]
        options = ort.SessionOptions()
        options.intra_op_num_threads = threads
        options.inter_op_num_threads = 1
        session = ort.InferenceSession(onnx, options, providers=["CPUExecutionProvider"])
        feed = {session.get_inputs()[0].name: x}
        ort_ms = timed(lambda: session.run(None, feed))
        outputs = session.run(None, feed)
        # Output names differ between the two: each output against the LiteRT output
        # of its size it is closest to.
        diff = max(
            min(
                float(np.max(np.abs(a.reshape(-1) - b.reshape(-1))))
                for b in reference
                if a.size == b.size
            )
            for a in outputs
        )
        print(f"{name:20} {threads} thread(s)  LiteRT {litert_ms:7.2f} ms  "
              f"ONNX Runtime {ort_ms:7.2f} ms  (largest output difference {diff:.2e})")
