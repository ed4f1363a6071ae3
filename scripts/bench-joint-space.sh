#!/usr/bin/env bash
# The joint-space benchmark: one task's expert demonstrations recorded twice from the same
# training seeds, as end-effector poses and as the simulator arm's joint angles
# (`dataset generate --joint-space`), each trained with the default recipe and evaluated on
# the same held-out scenes. The joint model is executed through the arm's forward kinematics,
# so both are judged by the same physics. Prints success and MED (cm) side by side.
#
#   bash scripts/bench-joint-space.sh [TASK] [DEMOS] [SCENES]   (default wall_avoidance 20 50)
set -euo pipefail
source "$(dirname "$0")/common.sh"
cd "$repo"
task=${1:-wall_avoidance}
demos=${2:-20}
scenes=${3:-50}
work=${BENCH_WORK:-$(mktemp -d)}
mkdir -p "$work"
cnfmp=target/release/cnfmp
for form in pose joints; do
    flag=(); [[ $form == joints ]] && flag=(--joint-space)
    say "$form: recording $demos demonstrations of $task"
    $cnfmp dataset generate --task "$task" --episodes "$demos" --seed 0 --out "$work/$form-data" "${flag[@]}" >/dev/null
    start=$(date +%s)
    $cnfmp train --dataset "$work/$form-data" --out "$work/$form-model" >/dev/null
    echo "$(( $(date +%s) - start ))" > "$work/$form-train-seconds"
    $cnfmp eval --model "$work/$form-model" --task "$task" --episodes "$scenes" --json "$work/$form-eval.json" >/dev/null
done
.venv/bin/python - "$work" "$task" "$demos" "$scenes" <<'PY'
import json, sys
work, task, demos, scenes = sys.argv[1:]
print(f"{task}: {demos} demonstrations, default recipe, {scenes} held-out scenes (seeds 1000000..)")
for form in ("pose", "joints"):
    report = json.load(open(f"{work}/{form}-eval.json"))
    seconds = open(f"{work}/{form}-train-seconds").read().strip()
    print(f"{form:>6}: success {report['success_rate']:.2f}, MED {report['med_cm']:.2f} cm, "
          f"train {seconds} s, predict p50 {report['latency_ms_p50']:.0f} ms")
PY
