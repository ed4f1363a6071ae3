#!/usr/bin/env bash
# Benchmark of the two-command setup: clones HEAD into a temporary directory and times
# `make test` there (no .venv, cold cargo target), then a second `make setup`.
# With COLD_VENV=1 the clone also gets an empty CNFMP_CACHE, so the base venv (~7 GB of
# wheels) is downloaded and installed too, as on a fresh CI machine.
set -euo pipefail
source "$(dirname "$0")/common.sh"
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
git clone --quiet "$repo" "$work/clone"
[[ -d $repo/../shared ]] && ln -s "$(cd "$repo/../shared" && pwd)" "$work/shared"
if [[ ${COLD_VENV:-0} == 1 ]]; then
    export CNFMP_CACHE="$work/cache"
fi
cd "$work/clone"
timed() {
    local label=$1; shift
    local start=$SECONDS
    "$@" >"$work/$label.log" 2>&1 || { tail -30 "$work/$label.log"; die "$label failed"; }
    printf '%-44s %4d s\n' "$label" $((SECONDS - start))
}
echo "commit $(git rev-parse --short HEAD), $(nproc) cores, cache ${CNFMP_CACHE:-$cache}"
timed "make test (fresh clone, cold cargo target)" make test
timed "second make setup" make setup
