#!/usr/bin/env bash
# Benchmark of the shipped film segmenter: `cnfmp segmenter eval` on 200 held-out renders of
# language_pick_place (seeds 1000000..1000199: mean IoU for seen phrasings, unseen
# paraphrases and held-out object instances) and 50 of every other task, then the latency
# of one prompt at 128x128. Per-scene JSON goes to $BENCH_OUT (default a temporary directory).
set -euo pipefail
source "$(dirname "$0")/common.sh"
cd "$repo"
out=${BENCH_OUT:-$(mktemp -d)}
mkdir -p "$out"
target/release/cnfmp segmenter eval --task language_pick_place --episodes "${BENCH_EPISODES:-200}" \
    --json "$out/language_pick_place.json" 2>/dev/null
for task in wall_avoidance incline_pick_place cup_stacking cube_stacking; do
    target/release/cnfmp segmenter eval --task "$task" --episodes 50 --json "$out/$task.json" 2>/dev/null
done
.venv/bin/python scripts/bench-segmenter-latency.py --backend film
echo "per-scene results: $out"
