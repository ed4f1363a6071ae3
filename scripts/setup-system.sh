#!/usr/bin/env bash
# Installs the Debian packages the project needs, only when one is missing (idempotent, and
# fast when nothing is to do): EGL/Mesa for MuJoCo's offscreen rendering (MUJOCO_GL=egl,
# software llvmpipe, no GPU needed), OSMesa as the fallback backend, and wrk for the HTTP
# load benchmark (scripts/bench-serve.sh), stress-ng for its run under CPU contention.
set -euo pipefail

packages=(libegl1 libegl-mesa0 libgl1 libgl1-mesa-dri libgles2 libosmesa6 wrk stress-ng)

missing=()
for package in "${packages[@]}"; do
    dpkg-query -W -f='${Status}' "$package" 2>/dev/null | grep -q "install ok installed" || missing+=("$package")
done
if [[ ${#missing[@]} -eq 0 ]]; then
    echo "[setup-system] Debian packages present: ${packages[*]}"
    exit 0
fi

echo "[setup-system] installing ${missing[*]}"
if [[ $(id -u) -eq 0 ]]; then
    sudo=()
elif command -v sudo >/dev/null 2>&1; then
    sudo=(sudo)
else
    echo "[setup-system] error: need root (or sudo) to install: ${missing[*]}" >&2
    exit 1
fi
export DEBIAN_FRONTEND=noninteractive
"${sudo[@]}" apt-get update -qq
"${sudo[@]}" apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
echo "[setup-system] installed ${missing[*]}"
