#!/usr/bin/env bash
# Benchmark of `cnfmp dataset convert`: 1000 small raw episodes (128x128 scene image, label
# map, 20-frame trajectory; scripts/make-bench-episodes.py) converted into a LeRobot dataset
# with 2 workers. Prints episodes per second for the whole run and per phase (staging,
# lerobot writing), the peak resident memory of the converter process, and the sizes.
set -euo pipefail
source "$(dirname "$0")/common.sh"
cd "$repo"
episodes=${BENCH_CONVERT_EPISODES:-1000}
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
.venv/bin/python scripts/make-bench-episodes.py datasets/examples/raw/episode_000 "$work/raw" "$episodes"
echo "== dataset convert: $episodes raw episodes ($(du -sh "$work/raw" | cut -f1)), 2 workers"
/usr/bin/time -v target/release/cnfmp dataset convert --from "raw:$work/raw" --out "$work/lerobot" --workers 2 \
    >"$work/report.json" 2>"$work/log"
.venv/bin/python - "$work/report.json" "$work/log" <<'PY'
import json, re, sys
report = json.load(open(sys.argv[1]))
log = open(sys.argv[2]).read()
peak_kib = int(re.search(r"Maximum resident set size \(kbytes\): (\d+)", log).group(1))
staging = re.findall(r"staging: \d+/\d+ \(100%\), ([\d.]+)/s", log)
writing = re.findall(r"writing: 100%.*?([\d.]+)episode/s\]", log)
print(f"converted {report['converted']} episodes, {report['frames']} frames in {report['seconds']:.1f} s: "
      f"{report['episodes_per_second']:.2f} episodes/s overall")
print(f"staging (Rust, 2 workers): {staging[-1] if staging else '?'} episodes/s; "
      f"lerobot writing: {writing[-1] if writing else '?'} episodes/s")
print(f"peak resident memory: {peak_kib / 1024:.0f} MiB")
PY
echo "dataset on disk: $(du -sh "$work/lerobot" | cut -f1)"
