#!/usr/bin/env bash
# Benchmark of the shipped core models: `cnfmp eval` on 50 held-out scenes per task
# (seeds 1000000..1000049): success rate, MED (cm), inference latency p50/p95 with the model
# loaded, scene-fit PSNR and mask IoU (drawer_place: a cnfmp-3d model predicting from scans).
# Per-episode JSON goes to $BENCH_OUT (default a temp dir).
set -euo pipefail
source "$(dirname "$0")/common.sh"
cd "$repo"
episodes=${BENCH_EPISODES:-50}
out=${BENCH_OUT:-$(mktemp -d)}
mkdir -p "$out"
for task in ${BENCH_TASKS:-wall_avoidance incline_pick_place cup_stacking cube_stacking language_pick_place drawer_place}; do
    target/release/cnfmp eval --model "models/$task" --task "$task" --episodes "$episodes" \
        --seed-start 1000000 --json "$out/$task.json" 2>/dev/null
done
echo "per-episode results: $out"
