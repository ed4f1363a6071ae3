#!/usr/bin/env bash
# Load benchmark of the HTTP API on loopback: `cnfmp serve` with the shipped models and the
# default segmenter; how long it takes to listen and its first request's latency; then wrk
# POSTing one held-out language_pick_place scene (seed 1000003, as JSON with the image in
# base64) at 1, 4, 16 and 64 concurrent connections for a fixed duration each. Prints per
# level requests/s served, p50 and p99, the answers by status (200 served, 503 refused because
# the queue was full: deliberate, the client then waits Retry-After; anything else an error)
# and the server's resident memory (now and peak); then, with stress-ng present, one client
# again while two busy processes take both cores (graceful under contention).
# Environment: BENCH_SECONDS (default 30), BENCH_LEVELS (default "1 4 16 64"),
# BENCH_SERVE_ARGS (extra `cnfmp serve` flags, e.g. "--max-batch 1").
set -euo pipefail
source "$(dirname "$0")/common.sh"
cd "$repo"
command -v wrk >/dev/null || die "wrk is missing; run make setup (scripts/setup-system.sh installs it)"
work=$(mktemp -d)
server_pid=
cleanup() {
    [[ -n $server_pid ]] && kill -TERM "$server_pid" 2>/dev/null && wait "$server_pid" 2>/dev/null
    rm -rf "$work"
}
trap cleanup EXIT

target/release/cnfmp sim render --task language_pick_place --seed 1000003 --out "$work/scene" >/dev/null 2>&1
.venv/bin/python - "$work" <<'PY'
import base64, json, sys
work = sys.argv[1]
scene = json.load(open(f"{work}/scene/objects.json"))
image = base64.b64encode(open(f"{work}/scene/image.png", "rb").read()).decode()
json.dump({"image_base64": image, "prompt": scene["prompt"]}, open(f"{work}/body.json", "w"))
PY

started=$(date +%s.%N)
# shellcheck disable=SC2086  # BENCH_SERVE_ARGS is a list of flags
target/release/cnfmp serve --addr 127.0.0.1:0 ${BENCH_SERVE_ARGS:-} >"$work/server.out" 2>"$work/server.log" &
server_pid=$!
for _ in $(seq 600); do
    grep -q "listening on" "$work/server.out" 2>/dev/null && break
    kill -0 "$server_pid" 2>/dev/null || { cat "$work/server.log" >&2; die "the server exited"; }
    sleep 0.5
done
url=$(sed -n 's/^cnfmp serve: listening on //p' "$work/server.out")/v1/trajectories
[[ -n $url ]] || die "the server did not start listening"
ready_s=$(awk -v a="$started" -v b="$(date +%s.%N)" 'BEGIN { printf "%.1f", b - a }')
say "server at $url ($(grep -c '^cnfmp serve: loaded' "$work/server.log") models) listening after $ready_s s; $(nproc) cores; $(date -u +%F)"

export BENCH_BODY="$work/body.json"
seconds=${BENCH_SECONDS:-30}
# The first request after listening (the server warms its models up before it listens), then
# the next one for comparison.
for which in first second; do
    seconds_taken=$(curl -sf -o /dev/null -w '%{time_total}' -H 'Content-Type: application/json' --data-binary "@$BENCH_BODY" "$url")
    echo "$which request: $(awk -v s="$seconds_taken" 'BEGIN { printf "%.0f", 1000 * s }') ms"
done
# The server's resident memory now and at its peak (VmRSS, VmHWM), MiB, and its helper
# processes' (its children) together.
memory() {
    awk '/^VmRSS/ {rss = $2} /^VmHWM/ {hwm = $2} END {printf "rss %.0f MiB (peak %.0f MiB)", rss / 1024, hwm / 1024}' "/proc/$server_pid/status"
    local helpers
    helpers=$(pgrep -P "$server_pid" || true)
    if [[ -n $helpers ]]; then
        # shellcheck disable=SC2086  # one status file per helper
        awk '/^VmRSS/ {rss += $2} /^VmHWM/ {hwm += $2} END {printf ", helpers rss %.0f MiB (peak %.0f MiB)", rss / 1024, hwm / 1024}' \
            $(printf '/proc/%s/status ' $helpers)
    fi
}
level() {
    local connections=$1 label=$2
    local threads=$(( connections < 2 ? connections : 2 ))
    local result
    result=$(wrk -t"$threads" -c"$connections" -d"${seconds}s" --timeout 60s -s scripts/bench-serve.lua "$url" | grep '^RESULT')
    echo "$label $connections, ${seconds} s: ${result#RESULT }; $(memory)"
}
for connections in ${BENCH_LEVELS:-1 4 16 64}; do
    level "$connections" concurrency
done
if command -v stress-ng >/dev/null; then
    stress-ng --cpu 2 --timeout "$(( seconds + 10 ))s" --quiet &
    stress_pid=$!
    sleep 2
    level 1 "with stress-ng --cpu 2, concurrency"
    kill "$stress_pid" 2>/dev/null; wait "$stress_pid" 2>/dev/null || true
else
    say "stress-ng is missing (make setup installs it): the run under contention is skipped"
fi
