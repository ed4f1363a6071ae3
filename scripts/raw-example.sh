#!/usr/bin/env bash
# Regenerates datasets/examples/raw: three wall_avoidance episodes (seeds 0-2) in the raw
# dataset format, each showing a different way to give masks and trajectories:
#   episode_000: masks.png + objects.json, trajectory.json at 10 Hz
#   episode_001: masks/<object>.png + objects.json, trajectory.csv at 10 Hz (fps in meta.json)
#   episode_002: masks.png + objects.json, trajectory.json at 25 Hz (resampled on conversion)
set -euo pipefail
source "$(dirname "$0")/common.sh"
cnfmp="$repo/target/release/cnfmp"
out="$repo/datasets/examples/raw"
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
rm -rf "$out"
for seed in 0 1 2; do
    episode="$work/episode_00$seed"
    "$cnfmp" sim render --task wall_avoidance --seed "$seed" --out "$episode" >/dev/null
    "$cnfmp" sim expert --task wall_avoidance --seed "$seed" --out "$work/expert_$seed.json"
    fps=$([[ $seed == 2 ]] && echo 25 || echo 10)
    "$cnfmp" trajectory resample "$work/expert_$seed.json" --fps "$fps" --out "$episode/trajectory.json"
done
"$repo/.venv/bin/python" - "$work" <<'PY'
import json, os, sys
import numpy as np
from PIL import Image

work = sys.argv[1]
for seed in range(3):
    episode = os.path.join(work, f"episode_00{seed}")
    scene = json.load(open(os.path.join(episode, "objects.json")))
    trajectory = json.load(open(os.path.join(episode, "trajectory.json")))
    json.dump({"task": scene["task"], "prompt": scene["prompt"], "fps": trajectory["fps"], "seed": scene["seed"]},
              open(os.path.join(episode, "meta.json"), "w"), indent=2)
    if seed == 1:  # per-object masks and a CSV trajectory
        labels = np.asarray(Image.open(os.path.join(episode, "masks.png")))
        os.makedirs(os.path.join(episode, "masks"))
        for k, name in enumerate(scene["objects"], start=1):
            Image.fromarray(((labels == k) * 255).astype(np.uint8)).save(os.path.join(episode, "masks", f"{name}.png"))
        os.remove(os.path.join(episode, "masks.png"))
        json.dump(scene["objects"], open(os.path.join(episode, "objects.json"), "w"))
        with open(os.path.join(episode, "trajectory.csv"), "w") as csv:
            csv.write("t,x,y,z,qw,qx,qy,qz,gripper\n")
            for f in trajectory["frames"]:
                csv.write(",".join(repr(v) for v in [f["t"], *f["position"], *f["orientation"], f["gripper"]]) + "\n")
        os.remove(os.path.join(episode, "trajectory.json"))
PY
rm "$work"/expert_*.json
mkdir -p "$(dirname "$out")"
mv "$work" "$out"
trap - EXIT
chmod 755 "$out"
say "wrote $out"
