#!/usr/bin/env bash
# Seed spread of the default recipe: per task, the training set of scripts/demos.sh, one
# `cnfmp train` with no config per training seed, and `cnfmp eval` on 100 held-out scenes
# (seeds 1000000..1000099); prints success (95% interval), MED, training time and latency per
# task and seed, then each task's median and worst seed. Two jobs at a time, each training
# with the cores divided among the jobs (one torch thread each on 2 cores): the training
# times are those of `cnfmp train --threads 1` beside another job, not of a training alone.
# Usage: scripts/bench-seeds.sh [TASK ...]   (default the five 2D tasks of models/ and bar_into_tray)
# Environment: SEEDS (default "0 1 2"), EPISODES (default 100), JOBS (default 2),
#   BENCH_OUT (default a temporary directory: datasets, models, logs and per-episode JSON).
set -euo pipefail
source "$(dirname "$0")/common.sh"
cd "$repo"
source "$repo/scripts/demos.sh"
tasks=("$@")
[[ ${#tasks[@]} -gt 0 ]] || tasks=(wall_avoidance incline_pick_place cup_stacking cube_stacking language_pick_place bar_into_tray)
read -r -a seeds <<< "${SEEDS:-0 1 2}"
episodes=${EPISODES:-100}
jobs=${JOBS:-2}
threads=$(( $(nproc) / jobs )); ((threads >= 1)) || threads=1
out=${BENCH_OUT:-$(mktemp -d)}
cnfmp=target/release/cnfmp
[[ -x $cnfmp ]] || die "no $cnfmp: run make build first"
for task in "${tasks[@]}"; do
    [[ -n ${DEMOS[$task]:-} ]] || die "unknown task $task (choose from ${!DEMOS[*]})"
    [[ $task != drawer_place ]] || die "drawer_place trains a cnfmp-3d model on scans; see docs/benchmarks.md \"3D scenes\""
done
mkdir -p "$out/datasets" "$out/models" "$out/logs" "$out/evals"
say "tasks ${tasks[*]}, seeds ${seeds[*]}, $episodes held-out scenes each, $jobs jobs at a time; work in $out"
for task in "${tasks[@]}"; do
    dataset=$out/datasets/$task-${DEMOS[$task]}
    [[ -d $dataset ]] || $cnfmp dataset generate --task "$task" --episodes "${DEMOS[$task]}" --seed 0 --out "$dataset" \
        > /dev/null 2> "$out/logs/dataset-$task.log"
done
# One job: train, then evaluate; a finished evaluation is kept (rerun after removing it).
train_and_eval() {
    local task=$1 seed=$2 name=$1-s$2
    [[ -f $out/evals/$name.json ]] && return 0
    rm -rf "$out/models/$name"
    $cnfmp train --dataset "$out/datasets/$task-${DEMOS[$task]}" --out "$out/models/$name" --seed "$seed" \
        --threads "$threads" > "$out/logs/train-$name.json" 2> "$out/logs/train-$name.log"
    CNFMP_INFERENCE_THREADS=1 $cnfmp eval --model "$out/models/$name" --task "$task" --episodes "$episodes" \
        --seed-start 1000000 --json "$out/evals/$name.json.partial" > /dev/null 2> "$out/logs/eval-$name.log"
    mv "$out/evals/$name.json.partial" "$out/evals/$name.json"
    say "$name done"
}
running=0 failed=0
for task in "${tasks[@]}"; do
    for seed in "${seeds[@]}"; do
        train_and_eval "$task" "$seed" &
        running=$((running + 1))
        if ((running == jobs)); then wait -n || failed=1; running=$((running - 1)); fi
    done
done
while ((running > 0)); do wait -n || failed=1; running=$((running - 1)); done
((failed == 0)) || die "a job failed: see the logs in $out/logs"
.venv/bin/python - "$out" "${seeds[*]}" "${tasks[@]}" <<'PY'
import json, statistics, sys
from pathlib import Path
out, seeds, tasks = Path(sys.argv[1]), sys.argv[2].split(), sys.argv[3:]
print("| task | seed | success (95% interval) | MED (cm) | training (s) | latency p50 / p95 (ms) |")
print("|---|---|---|---|---|---|")
spread = []
for task in tasks:
    rates = []
    for seed in seeds:
        name = f"{task}-s{seed}"
        ev = json.loads((out / "evals" / f"{name}.json").read_text())
        train = json.loads((out / "logs" / f"train-{name}.json").read_text())
        low, high = ev["success_interval_95"]
        rates.append((ev["success_rate"], ev["med_cm"]))
        print(f"| {task} | {seed} | {ev['success_rate']:.2f} ({low:.2f}-{high:.2f}) | {ev['med_cm']:.2f} | "
              f"{train['seconds']:.0f} | {ev['latency_ms_p50']:.0f} / {ev['latency_ms_p95']:.0f} |")
    success = [r for r, _ in rates]
    meds = [m for _, m in rates]
    spread.append(f"| {task} | {statistics.median(success):.2f} | {min(success):.2f} | "
                  f"{statistics.median(meds):.2f} | {max(meds):.2f} |")
print()
print("| task | median success | worst success | median MED (cm) | worst MED (cm) |")
print("|---|---|---|---|---|")
print("\n".join(spread))
PY
say "per-episode results and models: $out"
