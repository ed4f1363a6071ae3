"""Environment report behind ``cnfmp doctor``: interpreter, pinned packages, threads, rendering.

:func:`collect` returns a JSON document the Rust side prints; each check carries a one-line
fix. Version requirements are not restated here: they are read from the installed ``cnfmp``
distribution's own metadata (``pyproject.toml``), so the doctor and the lock cannot disagree.
Run standalone with ``python -m cnfmp.doctor``.
"""

from __future__ import annotations

import importlib
import importlib.metadata as metadata
import json
import os
import subprocess
import sys
import time

FIX_SETUP = "run `make setup` in the repository root"

# A lit red box in front of a camera: the render check passes only if red pixels come back.
_RENDER_SCENE = """
<mujoco>
  <visual><global offwidth="32" offheight="32"/></visual>
  <worldbody>
    <light pos="0 0 2" dir="0 0 -1"/>
    <camera name="probe" pos="0 0 1" xyaxes="1 0 0 0 1 0"/>
    <geom type="box" size="0.3 0.3 0.05" rgba="1 0 0 1"/>
  </worldbody>
</mujoco>
"""



def render_probe() -> dict:
    """Renders the probe scene at 32x32 with the backend MUJOCO_GL selects.

    Returns ``{"ok", "red", "other", "ms"}``: ok when the red box came back red (mean red
    channel and the mean of the other two channels, 0-255; wall time in ms).
    """
    import mujoco
    import numpy as np

    start = time.perf_counter()
    model = mujoco.MjModel.from_xml_string(_RENDER_SCENE)
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    with mujoco.Renderer(model, 32, 32) as renderer:
        renderer.update_scene(data, camera="probe")
        rgb = renderer.render().astype(np.float64)
    red, other = float(rgb[..., 0].mean()), float(rgb[..., 1:].mean())
    return {"ok": red > 100 and red > 2 * other + 10, "red": red, "other": other,
            "ms": 1000 * (time.perf_counter() - start)}


def _check(name: str, ok: bool, detail: str, fix: str = "") -> dict:
    return {"name": name, "ok": bool(ok), "detail": detail, "fix": "" if ok else fix}


def _venv_python_version() -> str | None:
    """The interpreter version the venv was created with, from its pyvenv.cfg."""
    try:
        with open(os.path.join(sys.prefix, "pyvenv.cfg"), encoding="utf-8") as cfg:
            entries = dict(line.split("=", 1) for line in cfg if "=" in line)
    except OSError:
        return None
    entries = {key.strip(): value.strip() for key, value in entries.items()}
    return entries.get("version_info") or entries.get("version")


def _python_check() -> dict:
    running = sys.version.split()[0]
    detail = f"Python {running}, sys.prefix={sys.prefix}"
    if sys.prefix == sys.base_prefix:
        return _check("python", False, detail, "the interpreter is not running on the project venv; " + FIX_SETUP)
    if sys.version_info[:2] != (3, 11):
        return _check("python", False, detail, "the project needs Python 3.11; " + FIX_SETUP)
    venv_version = _venv_python_version()
    if venv_version is not None and not venv_version.startswith(running):
        # An embedding binary linked against another libpython (Debian's 3.11.2, say) runs
        # that interpreter on the venv's packages: C extensions may then fail at random.
        return _check("python", False, f"{detail}, but the venv was made with Python {venv_version}",
                      "this binary links the wrong libpython; rebuild it with `make setup`")
    return _check("python", True, detail)


def _requirement_checks() -> list[dict]:
    """One check per dependency declared by the installed cnfmp distribution."""
    from packaging.requirements import Requirement

    try:
        declared = metadata.requires("cnfmp") or []
    except metadata.PackageNotFoundError:
        return [_check("cnfmp", False, "package not installed in this interpreter", FIX_SETUP)]
    checks = []
    for text in declared:
        req = Requirement(text)
        if req.marker is not None and not req.marker.evaluate({"extra": ""}):
            continue  # optional (dev) extras are checked by the test run, not here
        try:
            version = metadata.version(req.name)
        except metadata.PackageNotFoundError:
            checks.append(_check(req.name, False, "not installed", FIX_SETUP))
            continue
        ok = req.specifier.contains(version, prereleases=True)
        spec = str(req.specifier) or "any"
        checks.append(_check(req.name, ok, f"{version} (requires {spec})", FIX_SETUP))
    return checks


def _import_check(module: str, name: str) -> dict:
    try:
        importlib.import_module(module)
    except Exception as exc:  # a broken wheel raises more than ImportError
        return _check(f"import {name}", False, f"{type(exc).__name__}: {exc}", FIX_SETUP)
    return _check(f"import {name}", True, "ok")


def _torch_threads_check() -> dict:
    try:
        import torch
    except Exception as exc:
        return _check("torch threads", False, f"torch unavailable: {exc}", FIX_SETUP)
    intra, inter = torch.get_num_threads(), torch.get_num_interop_threads()
    omp = os.environ.get("OMP_NUM_THREADS", "unset")
    detail = f"intra-op {intra}, inter-op {inter}, OMP_NUM_THREADS={omp}"
    return _check("torch threads", omp != "unset", detail,
                  "OMP_NUM_THREADS was not set before torch loaded; call cnfmp.runtime.configure() first")


def _probe_render(backend: str, in_process: bool) -> dict:
    """:func:`render_probe` with ``backend``: in this process when it is the backend this
    process already uses (MuJoCo binds its GL backend at import), else in a child process."""
    if in_process:
        try:
            return render_probe()
        except Exception as exc:
            return {"ok": False, "error": f"{type(exc).__name__}: {exc}"}
    env = dict(os.environ, MUJOCO_GL=backend, PYOPENGL_PLATFORM=backend)
    code = "import json; from cnfmp.doctor import render_probe; print(json.dumps(render_probe()))"
    try:
        proc = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True,
                              text=True, timeout=60)
    except subprocess.TimeoutExpired:
        return {"ok": False, "error": "timed out after 60 s"}
    if proc.returncode != 0:
        last = (proc.stderr.strip().splitlines() or ["no output"])[-1]
        return {"ok": False, "error": last}
    return json.loads(proc.stdout.strip().splitlines()[-1])


def _render_check() -> dict:
    backend = os.environ.get("MUJOCO_GL", "egl")
    result = _probe_render(backend, in_process=True)
    if result.get("ok"):
        detail = f"MUJOCO_GL={backend} rendered a 32x32 test frame in {result['ms']:.0f} ms"
        check = _check("mujoco render", True, detail)
    else:
        why = result.get("error") or f"test frame wrong (mean red {result.get('red', 0):.0f})"
        fix = "install the EGL/Mesa packages with `make setup`"
        if backend != "osmesa":
            fallback = _probe_render("osmesa", in_process=False)
            if fallback.get("ok"):
                fix = f"MUJOCO_GL={backend} failed but osmesa renders: export MUJOCO_GL=osmesa"
        check = _check("mujoco render", False, f"MUJOCO_GL={backend} failed: {why}", fix)
    check["backend"] = backend
    return check


# Run in a fresh interpreter by :func:`startup_costs`: what a cold `cnfmp predict` pays, stage
# by stage. The scene is synthetic (grey, one square per object slot): costs, not accuracy.
_STARTUP_SCRIPT = """
import json, sys, time
began = time.perf_counter()
from cnfmp import runtime
runtime.configure(threads=1)
stages, last = [], began
def mark(name):
    global last
    now = time.perf_counter()
    stages.append({"name": name, "ms": round(1000 * (now - last), 1)})
    last = now
import numpy as np
import torch
mark("import numpy and torch")
from cnfmp.core import api
mark("import the inference path")
from cnfmp.segmenter import api as segmenter_api
segmenter_api.backend("auto")
mark("load the prompt segmenter")
model = sys.argv[1] if len(sys.argv) > 1 else None
if model:
    names = json.loads(api.describe(model))["objects"] or ["object 1", "object 2"]
    mark("load the model")
    scene = api.synthetic_scene(names)
    api.predict(model, *scene)
    mark("first prediction")
    api.predict(model, *scene)
    mark("warm prediction")
print(json.dumps(stages))
"""


def startup_costs(model_dir: str | None = None) -> dict:
    """Times a cold start in a fresh interpreter on this venv: importing numpy and torch, the
    inference path, loading the prompt segmenter and, with `model_dir`, loading that model and
    predicting a synthetic scene twice (first and warm).

    Returns ``{"stages": [{"name", "ms"}], "process_ms": wall time of the whole child process
    including interpreter start and exit}``, or ``{"error": str}`` when the child failed.
    """
    args = [sys.executable, "-c", _STARTUP_SCRIPT] + ([os.fspath(model_dir)] if model_dir else [])
    started = time.perf_counter()
    try:
        proc = subprocess.run(args, capture_output=True, text=True, timeout=600)
    except subprocess.TimeoutExpired:
        return {"error": "the start-up probe took over 600 s"}
    process_ms = round(1000 * (time.perf_counter() - started), 1)
    if proc.returncode != 0:
        lines = proc.stderr.strip().splitlines() or ["no output"]
        return {"error": lines[-1]}
    return {"stages": json.loads(proc.stdout.strip().splitlines()[-1]), "process_ms": process_ms}


def collect() -> str:
    """Runs every check; returns ``{"checks": [...], "python": {...}}`` as a JSON string.

    Each check is ``{"name", "ok", "detail", "fix"}``; ``fix`` is a one-line instruction,
    empty when the check passed. The render check also carries ``backend``.
    """
    checks = [_python_check()]
    checks += _requirement_checks()
    checks += [_import_check(m, n) for m, n in
               (("torch", "torch"), ("mujoco", "mujoco"), ("cv2", "opencv"),
                ("lerobot.datasets.lerobot_dataset", "lerobot"))]
    checks.append(_torch_threads_check())
    checks.append(_render_check())
    python = {
        "version": sys.version.split()[0],
        "executable": sys.executable,
        "prefix": sys.prefix,
        "base_prefix": sys.base_prefix,
    }
    return json.dumps({"checks": checks, "python": python})


def main() -> int:
    from cnfmp import runtime

    runtime.configure()
    report = json.loads(collect())
    for check in report["checks"]:
        mark = "ok  " if check["ok"] else "FAIL"
        print(f"{mark} {check['name']:<24} {check['detail']}")
        if check["fix"]:
            print(f"     fix: {check['fix']}")
    return 0 if all(c["ok"] for c in report["checks"]) else 1


if __name__ == "__main__":
    sys.exit(main())
