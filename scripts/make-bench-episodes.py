"""Writes N small raw episodes for the conversion benchmark (scripts/bench-convert.sh).

Each episode: the example scene image (128x128) shifted by a few pixels, its masks shifted
alike, a 20-frame trajectory at 10 Hz offset per episode, meta.json. Deterministic (seeded).
Usage: make-bench-episodes.py EXAMPLE_EPISODE OUT_DIR N
"""

import json
import os
import sys

import numpy as np
from PIL import Image

example, out, count = sys.argv[1], sys.argv[2], int(sys.argv[3])
image = np.asarray(Image.open(os.path.join(example, "image.png")).convert("RGB"))
masks = np.asarray(Image.open(os.path.join(example, "masks.png")))
objects = json.load(open(os.path.join(example, "objects.json")))
meta = json.load(open(os.path.join(example, "meta.json")))
frames = json.load(open(os.path.join(example, "trajectory.json")))["frames"][:20]
rng = np.random.default_rng(0)
for k in range(count):
    episode = os.path.join(out, f"episode_{k:05d}")
    os.makedirs(episode)
    dx, dy = rng.integers(-4, 5, size=2)
    Image.fromarray(np.roll(image, (dy, dx), axis=(0, 1))).save(os.path.join(episode, "image.png"))
    Image.fromarray(np.roll(masks, (dy, dx), axis=(0, 1))).save(os.path.join(episode, "masks.png"))
    json.dump(objects, open(os.path.join(episode, "objects.json"), "w"))
    json.dump({**meta, "seed": k}, open(os.path.join(episode, "meta.json"), "w"))
    offset = rng.normal(0, 0.01, 3)
    shifted = [{**f, "position": list(np.asarray(f["position"]) + offset)} for f in frames]
    json.dump({"fps": 10.0, "frames": shifted}, open(os.path.join(episode, "trajectory.json"), "w"))
