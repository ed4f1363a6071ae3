#!/usr/bin/env bash
# Re-resolves requirements.lock from pyproject.toml (runtime + dev extras) with hashes, for
# Linux x86_64 and CPython 3.11. Run `make setup` afterwards: a new lock means a new base venv.
set -euo pipefail
source "$(dirname "$0")/common.sh"
find_python
find_uv
resolved=$(mktemp)
trap 'rm -f "$resolved"' EXIT
# uv prefers the versions already in its output file: start from the current lock so adding
# a dependency does not silently upgrade the others.
[[ -f $lock ]] && cp "$lock" "$resolved"
"$uv" pip compile "$repo/pyproject.toml" --extra dev --python-version 3.11 \
    --python-platform x86_64-manylinux_2_28 --generate-hashes --no-header --quiet -o "$resolved"
{
    echo "# Pinned lock of every Python dependency (runtime + dev), generated from pyproject.toml"
    echo "# by \`make lock\` (scripts/lock.sh). The venv cache is keyed by this file's hash:"
    echo "# editing it creates a fresh venv."
    cat "$resolved"
} >"$lock"
say "wrote $lock ($(grep -c '^[a-z]' "$lock") packages)"
