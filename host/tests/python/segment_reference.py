"""Runs the same ONNX network with onnxruntime on the inputs `cosem segment
--check-dir DIR` wrote (NNNNNN.input.npy) and compares its labels with cosem's
(NNNNNN.labels.npy): prints one line per image and `all FRACTION`.

    python3 segment_reference.py MODEL.onnx DIR
"""
import glob
import os
import sys

import numpy as np
import onnxruntime as ort

model, d = sys.argv[1], sys.argv[2]
s = ort.InferenceSession(model, providers=["CPUExecutionProvider"])
total = agree = 0
for f in sorted(glob.glob(os.path.join(d, "*.input.npy"))):
    x = np.load(f)
    logits = s.run(None, {s.get_inputs()[0].name: x})[0][0]
    ref = logits.argmax(0)
    # Channels 0-18: Cityscapes training ids; any further one: void (255).
    ref = np.where(ref >= 19, 255, ref).astype(np.uint8)
    got = np.load(f.replace(".input.npy", ".labels.npy"))
    a, n = int((ref == got).sum()), ref.size
    print(os.path.basename(f), a / n)
    total += n
    agree += a
if total == 0:
    sys.exit("no *.input.npy in " + d)
print("all", agree / total)
