#!/usr/bin/env bash
# Cold start and scripted use of `cnfmp predict` (issue 32): wall time of one call per process
# with masks (cube_stacking) and with a prompt (language_pick_place), BENCH_CALLS calls each
# (median and max), then BENCH_SCENES held-out scenes in one `cnfmp predict --scenes` call,
# checked against BENCH_SCENES x the warm per-scene latency + 5 s. Ends with `cnfmp doctor`'s
# stage-by-stage cold start. Environment: BENCH_CALLS (default 5), BENCH_SCENES (default 100).
set -euo pipefail
source "$(dirname "$0")/common.sh"
cd "$repo"
calls=${BENCH_CALLS:-5}
scenes=${BENCH_SCENES:-100}
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
say "$(nproc) cores, $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | xargs); $(date -u +%F)"

# The held-out scenes, rendered in one process (seeds from 1000000, as `cnfmp sim render`).
.venv/bin/python - "$work/scenes" "$scenes" <<'PY'
import sys
from cnfmp import runtime

if __name__ == "__main__":
    runtime.configure(threads=1)
    from cnfmp.sim import api

    out, count = sys.argv[1], int(sys.argv[2])
    for k in range(count):
        api.render("cube_stacking", 1_000_000 + k, f"{out}/scene-{k:03d}")
    api.render("language_pick_place", 1_000_003, f"{out}-prompted")
PY

# Wall seconds of each of $calls fresh `cnfmp predict` processes, then "median max".
time_calls() {
    local times=()
    for k in $(seq "$calls"); do
        local start
        start=$(date +%s%N)
        target/release/cnfmp predict "$@" --out "$work/one-$k.json" 2>/dev/null
        times+=("$(( ($(date +%s%N) - start) / 1000000 ))")
    done
    printf '%s\n' "${times[@]}" | sort -n | awk '{v[NR]=$1/1000} END {printf "median %.2f s, max %.2f s (%d calls)", (NR%2 ? v[(NR+1)/2] : (v[NR/2]+v[NR/2+1])/2), v[NR], NR}'
}
first="$work/scenes/scene-000"
say "one call with masks (cube_stacking): $(time_calls --model models/cube_stacking --image "$first/image.png" --masks "$first/masks.png" --objects "$first/objects.json")"
prompt=$(.venv/bin/python -c 'import json, sys; print(json.load(open(sys.argv[1]))["prompt"])' "$work/scenes-prompted/objects.json")
say "one call with a prompt (language_pick_place, \"$prompt\"): $(time_calls --model models/language_pick_place --image "$work/scenes-prompted/image.png" --prompt "$prompt")"

start=$(date +%s%N)
target/release/cnfmp predict --model models/cube_stacking --scenes "$work/scenes" --out "$work/batch" 2>/dev/null
wall_ms=$(( ($(date +%s%N) - start) / 1000000 ))
.venv/bin/python - "$work/batch/summary.json" "$wall_ms" <<'PY'
import json, sys

summary, wall = json.load(open(sys.argv[1])), float(sys.argv[2]) / 1000
n, warm = summary["scenes"], summary["latency_ms_p50"] / 1000
bound = n * warm + 5
print(f"{summary['predicted']} of {n} scenes in one call: wall {wall:.1f} s (start-up {summary['startup_s']:.1f} s, "
      f"warm p50 {1000 * warm:.0f} ms / p95 {summary['latency_ms_p95']:.0f} ms per scene); "
      f"target {n} x warm + 5 s = {bound:.1f} s: {'met' if wall <= bound else 'NOT met'}")
PY

target/release/cnfmp doctor --model models/cube_stacking | sed -n '/^cold start/,$p'
