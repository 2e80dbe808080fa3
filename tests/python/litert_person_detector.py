"""The reference runtime for the person detector: Google's LiteRT (PyPI `ai-edge-litert`)
runs the original `pose_detection.tflite` on a real photo, letterboxed to the detector's
224 x 224 input in [-1, 1], and writes the input and the raw outputs (box values and
score logits per anchor) as NPY files, for tests/models.rs to compare with tract on the
rewritten model.

usage: litert_person_detector.py MODEL.tflite IMAGE OUT_DIR
"""

import json
import sys
from pathlib import Path

import numpy as np
from ai_edge_litert.interpreter import Interpreter
from skimage import io
from skimage.transform import resize

model, image_path, out = sys.argv[1], sys.argv[2], Path(sys.argv[3])
image = io.imread(image_path)[..., :3] / 255.0
h, w = image.shape[:2]
side = max(h, w)
canvas = np.zeros((side, side, 3))
canvas[(side - h) // 2:(side - h) // 2 + h, (side - w) // 2:(side - w) // 2 + w] = image
x = (resize(canvas, (224, 224), anti_aliasing=True) * 2.0 - 1.0).astype(np.float32)[None]

interpreter = Interpreter(model_path=model)
interpreter.allocate_tensors()
interpreter.set_tensor(interpreter.get_input_details()[0]["index"], x)
interpreter.invoke()
outputs = {tuple(d["shape"]): interpreter.get_tensor(d["index"]) for d in interpreter.get_output_details()}
np.save(out / "input.npy", x)
np.save(out / "boxes.npy", outputs[(1, 2254, 12)].astype(np.float32))
np.save(out / "scores.npy", outputs[(1, 2254, 1)].astype(np.float32))
print(json.dumps({"best_logit": float(outputs[(1, 2254, 1)].max())}))
