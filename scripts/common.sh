# Shared by the setup scripts (sourced, not run): cache location, the base interpreter, uv.
#
# Environment:
#   CNFMP_CACHE   cache root (default: ${XDG_CACHE_HOME:-~/.cache}/cnfmp)
#   CNFMP_PYTHON  a CPython 3.11 built with --enable-shared (default: python3.11 on PATH)

repo=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
cache=${CNFMP_CACHE:-${XDG_CACHE_HOME:-$HOME/.cache}/cnfmp}
uv_version=0.13.9
lock="$repo/requirements.lock"

say() { printf '[%s] %s\n' "$(basename "$0" .sh)" "$*"; }
die() { printf '[%s] error: %s\n' "$(basename "$0" .sh)" "$*" >&2; exit 1; }

# Sets $python (the real executable, shims resolved) and $py_version.
find_python() {
    local python_cmd=${CNFMP_PYTHON:-python3.11} py_shared
    command -v "$python_cmd" >/dev/null 2>&1 || die "no '$python_cmd' on PATH; install CPython 3.11 (pyenv) or set CNFMP_PYTHON"
    # Resolve shims (pyenv) to the real executable: venvs must point at the interpreter itself.
    python=$("$python_cmd" -c 'import sys; print(sys.executable)')
    read -r py_version py_shared < <("$python" -c 'import sys, sysconfig; print("%d.%d.%d" % sys.version_info[:3], sysconfig.get_config_var("Py_ENABLE_SHARED") or 0)')
    [[ $py_version == 3.11.* ]] || die "$python is Python $py_version; the project needs 3.11 (lerobot 0.4.4, see ../shared/facts.md)"
    [[ $py_shared == 1 ]] || die "$python was built without --enable-shared; the Rust binary embeds libpython and needs it"
}

# Sets $uv, installing the pinned uv into the cache with pip the first time.
find_uv() {
    uv="$cache/tools/uv-$uv_version/bin/uv"
    if [[ ! -x $uv ]]; then
        say "installing uv $uv_version into $cache/tools"
        rm -rf "$cache/tools/uv-$uv_version"
        "$python" -m pip install --quiet --disable-pip-version-check --target "$cache/tools/uv-$uv_version" "uv==$uv_version"
    fi
    export UV_CACHE_DIR=${UV_CACHE_DIR:-$cache/uv}
    export UV_PYTHON_DOWNLOADS=never  # only package registries are reachable
}
