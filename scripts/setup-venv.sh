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
#
# Environment:
#   CNFMP_CACHE   cache root (default: ${XDG_CACHE_HOME:-~/.cache}/cnfmp)
#   CNFMP_PYTHON  a CPython 3.11 built with --enable-shared (default: python3.11 on PATH)
set -euo pipefail

repo=$(cd "$(dirname "$0")/.." && pwd)
cache=${CNFMP_CACHE:-${XDG_CACHE_HOME:-$HOME/.cache}/cnfmp}
uv_version=0.13.9
lock="$repo/requirements.lock"

say() { printf '[setup-venv] %s\n' "$*"; }
die() { printf '[setup-venv] error: %s\n' "$*" >&2; exit 1; }

# --- the base interpreter ---------------------------------------------------------------
python_cmd=${CNFMP_PYTHON:-python3.11}
command -v "$python_cmd" >/dev/null 2>&1 || die "no '$python_cmd' on PATH; install CPython 3.11 (pyenv) or set CNFMP_PYTHON"
# Resolve shims (pyenv) to the real executable: the venv must point at the interpreter itself.
python=$("$python_cmd" -c 'import sys; print(sys.executable)')
read -r py_version py_shared < <("$python" -c 'import sys, sysconfig; print("%d.%d.%d" % sys.version_info[:3], sysconfig.get_config_var("Py_ENABLE_SHARED") or 0)')
[[ $py_version == 3.11.* ]] || die "$python is Python $py_version; the project needs 3.11 (lerobot 0.4.4, see ../shared/facts.md)"
[[ $py_shared == 1 ]] || die "$python was built without --enable-shared; the Rust binary embeds libpython and needs it"

# --- uv (fast, cached installs), bootstrapped with pip into the cache -------------------
uv="$cache/tools/uv-$uv_version/bin/uv"
if [[ ! -x $uv ]]; then
    say "installing uv $uv_version into $cache/tools"
    rm -rf "$cache/tools/uv-$uv_version"
    "$python" -m pip install --quiet --disable-pip-version-check --target "$cache/tools/uv-$uv_version" "uv==$uv_version"
fi
export UV_CACHE_DIR=${UV_CACHE_DIR:-$cache/uv}
export UV_PYTHON_DOWNLOADS=never  # only registries are reachable; never fetch interpreters

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
