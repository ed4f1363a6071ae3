#!/usr/bin/env bash
# Reproduces the shipped core models under models/: for each task, a training dataset of the
# size in scripts/demos.sh (training seeds from 0; drawer_place as a cnfmp-3d model on scans,
# configs/core/drawer_place.json) and one `cnfmp train` run, seed 0, with the default
# configuration of the model type (configs/core/<task>.json where one exists: only
# drawer_place's, which names its model type).
# Two tasks train at a time (one torch thread each). Usage: scripts/train-models.sh [TASK ...]
# Environment: MODELS_DIR (default models), DATASETS_DIR (default a temporary directory).
set -euo pipefail
source "$(dirname "$0")/common.sh"
cd "$repo"
source "$repo/scripts/demos.sh"
tasks=("$@")
[[ ${#tasks[@]} -gt 0 ]] || tasks=(wall_avoidance incline_pick_place cup_stacking cube_stacking language_pick_place drawer_place)
models=${MODELS_DIR:-models}
datasets=${DATASETS_DIR:-$(mktemp -d)}
mkdir -p "$models" "$datasets"
train_one() {
    local task=$1 n=${DEMOS[$1]}
    [[ -n $n ]] || { echo "unknown task $task (choose from ${!DEMOS[*]})" >&2; return 2; }
    if [[ ! -d $datasets/$task-$n ]]; then
        target/release/cnfmp dataset generate --task "$task" --episodes "$n" --seed 0 --out "$datasets/$task-$n" >/dev/null
    fi
    rm -rf "$models/$task"
    # drawer_place's file names the model type of scans; every other task has none.
    local config=()
    [[ -f configs/core/$task.json ]] && config=(--config "configs/core/$task.json")
    target/release/cnfmp train --dataset "$datasets/$task-$n" --out "$models/$task" --threads 1 "${config[@]}" \
        2> >(sed "s/^/[$task] /" >&2)
}
running=0
for task in "${tasks[@]}"; do
    train_one "$task" &
    running=$((running + 1))
    if ((running == 2)); then wait -n; running=$((running - 1)); fi
done
wait
