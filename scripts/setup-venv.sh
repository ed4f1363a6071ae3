#!/usr/bin/env bash
# Creates or reuses the project's Python environment; idempotent.
#
# Two layers, so a second clone or CI run on the same machine does not reinstall ~7 GB:
#   1. a *base* venv with every pinned dependency from requirements.lock, cached outside the
#      clone under $CNFMP_CACHE/venvs/<key>, key = hash of (lock file, interpreter version);
#   2. the clone's own small `.venv`, which sees the base venv's site-packages through a .pth
#      file and holds the editable install of this clone's `cnfmp` package.
# Layer 2 is per clone because an editable install points at one checkout; sharing it would
# make one clone silently import another clone's code.
# Environment: CNFMP_CACHE, CNFMP_PYTHON (see common.sh).
set -euo pipefail
source "$(dirname "$0")/common.sh"
find_python
find_uv

# --- layer 1: the cached base venv -----------------------------------------------------
key=$( (cat "$lock"; echo "$python $py_version") | sha256sum | cut -c1-16)
base="$cache/venvs/$key"
mkdir -p "$cache/venvs"
exec 9>"$cache/venvs/.lock"
flock 9  # two setups on one machine must not build the same venv at once
if [[ -f $base/.cnfmp-complete ]]; then
    say "reusing base venv $base"
else
    say "building base venv $base (first time on this machine: ~7 GB, a few minutes)"
    rm -rf "$base"
    "$uv" venv --quiet --python "$python" "$base"
    "$uv" pip sync --python "$base/bin/python" --require-hashes "$lock"
    touch "$base/.cnfmp-complete"  # written last: an interrupted build is redone, never reused
fi
flock -u 9

# --- layer 2: the clone's .venv ----------------------------------------------------------
venv="$repo/.venv"
site="$venv/lib/python3.11/site-packages"
if [[ -f $venv/pyvenv.cfg && "$(cat "$venv/.cnfmp-base" 2>/dev/null)" == "$base" ]] && "$venv/bin/python" -c 'import cnfmp' 2>/dev/null; then
    say "reusing $venv"
else
    say "creating $venv on top of the base venv"
    rm -rf "$venv"
    "$uv" venv --quiet --python "$python" "$venv"
    # `import` lines in a .pth run at start-up; addsitedir (unlike a bare path line) also
    # processes the base venv's own .pth files.
    "$python" -c 'import sys; print("import site; site.addsitedir(%r)" % sys.argv[1])' \
        "$base/lib/python3.11/site-packages" >"$site/_cnfmp_base_venv.pth"
    "$uv" pip install --quiet --python "$venv/bin/python" --no-deps --editable "$repo"
    echo "$base" >"$venv/.cnfmp-base"
fi
"$venv/bin/python" -c 'import cnfmp, torch, mujoco, lerobot' || die "$venv does not import the project's dependencies; remove $base and rerun make setup"
say "ok: $venv (base $key)"
