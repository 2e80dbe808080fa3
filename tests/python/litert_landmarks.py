"""The reference runtime: Google's LiteRT (PyPI `ai-edge-litert`) runs an original
BlazePose landmark model on a real photo (scikit-image's `astronaut`, a person), and
writes the input it used and the heat-map logits it got as NPY files, for
tests/models.rs to compare with tract on the rewritten model.

usage: litert_landmarks.py MODEL.tflite OUT_DIR
"""

import json
import sys
from pathlib import Path

import numpy as np
from ai_edge_litert.interpreter import Interpreter
from skimage import data
from skimage.transform import resize

model, out = sys.argv[1], Path(sys.argv[2])
# The astronaut's head and shoulders: the whole 512 x 512 photo, scaled to the model's
# 256 x 256 input, RGB in [0, 1].
image = resize(data.astronaut(), (256, 256), anti_aliasing=True).astype(np.float32)
x = image[None, ...]

interpreter = Interpreter(model_path=model)
interpreter.allocate_tensors()
interpreter.set_tensor(interpreter.get_input_details()[0]["index"], x)
interpreter.invoke()
outputs = {tuple(d["shape"]): interpreter.get_tensor(d["index"]) for d in interpreter.get_output_details()}
heatmaps = outputs[(1, 64, 64, 39)]
np.save(out / "input.npy", x)
np.save(out / "heatmaps.npy", heatmaps.astype(np.float32))
print(json.dumps({"shapes": [[int(v) for v in s] for s in outputs], "pose_flag": float(outputs[(1, 1)].ravel()[0])}))
