#!/usr/bin/env bash
# Benchmark of the simulator: expert success on 100 held-out seeds per task, and dataset
# generation throughput (episodes per second of `cnfmp dataset generate`, 2 workers) per task,
# including the time for 100 cube_stacking episodes. Prints one line per figure.
set -euo pipefail
source "$(dirname "$0")/common.sh"
cd "$repo"
episodes=${BENCH_EPISODES:-100}
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
echo "== expert success, $episodes held-out seeds per task (python -m cnfmp.sim.validate)"
.venv/bin/python -m cnfmp.sim.validate --episodes "$episodes"
echo "== dataset generate, 2 workers"
for task in $(target/release/cnfmp sim tasks | awk '{print $1}'); do
    n=$([[ $task == cube_stacking ]] && echo 100 || echo "${BENCH_DATASET_EPISODES:-20}")
    start=$SECONDS
    target/release/cnfmp dataset generate --task "$task" --episodes "$n" --seed 0 --out "$work/$task" 2>/dev/null >"$work/$task.json"
    printf '%-22s %3d episodes in %4d s (%.2f episodes/s), %s on disk\n' "$task" "$n" $((SECONDS - start)) \
        "$(.venv/bin/python -c 'import json,sys; print(json.load(open(sys.argv[1]))["episodes_per_second"])' "$work/$task.json")" \
        "$(du -sh "$work/$task" | cut -f1)"
done
