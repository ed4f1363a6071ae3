"""cnfmp.runtime: thread limits, offline flags, and the bridge's zero-copy self-test."""

import os
import subprocess
import sys

import numpy as np
import pytest

from cnfmp import runtime


def test_configure_applied_one_thread_and_offline_flags():
    import torch

    assert torch.get_num_threads() == 1
    assert os.environ["OMP_NUM_THREADS"] == "1"
    assert os.environ["HF_HUB_OFFLINE"] == "1"
    assert runtime.configure(threads=1)["threads"] == 1  # idempotent


def test_configure_refuses_a_different_thread_count_later():
    with pytest.raises(ValueError, match="already configured"):
        runtime.configure(threads=2)


def test_configure_rejects_zero_threads():
    with pytest.raises(ValueError, match=">= 1"):
        runtime.configure(threads=0)


def test_subnormal_floats_flush_to_zero_here_and_on_the_worker_threads():
    import torch

    def smallest_product():  # 1e-30 * 1e-10 is subnormal in float32
        return float(torch.tensor([1e-30]) * torch.tensor([1e-10]))

    assert smallest_product() == 0.0
    assert list(runtime.worker_pool().map(lambda _: smallest_product(), range(4))) == [0.0] * 4


def test_configure_sets_threads_before_torch_loads_in_a_fresh_process():
    code = (
        "import os, sys\n"
        "from cnfmp import runtime\n"
        "assert 'torch' not in sys.modules\n"
        "runtime.configure(threads=2)\n"
        "import torch\n"
        "print(os.environ['OMP_NUM_THREADS'], torch.get_num_threads(), torch.get_num_interop_threads(),\n"
        "      os.environ.get('GOMP_SPINCOUNT'))\n"
    )
    env = {k: v for k, v in os.environ.items() if k not in ("OMP_NUM_THREADS", "GOMP_SPINCOUNT")}
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    # Several threads wait at libgomp's barriers with a short spin (runtime.GOMP_SPIN_COUNT).
    assert out.stdout.split() == ["2", "2", "2", "1000"]
    one = subprocess.run([sys.executable, "-c", code.replace("threads=2", "threads=1")], env=env,
                         capture_output=True, text=True, check=True)
    assert one.stdout.split() == ["1", "1", "1", "None"]


def test_configure_imports_nothing_heavy_and_sets_torch_and_opencv_up_when_they_load():
    # A command that renders or reads data must not pay seconds for torch; whoever imports
    # torch or OpenCV later still gets the process's settings before any work runs.
    code = (
        "import sys\n"
        "from cnfmp import runtime\n"
        "runtime.configure(threads=1)\n"
        "print(sorted(m for m in ('torch', 'cv2', 'mujoco') if m in sys.modules))\n"
        "import torch, cv2\n"
        "print(torch.get_num_interop_threads(), torch.are_deterministic_algorithms_enabled(), cv2.getNumThreads())\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    # Unconfigured, the inter-op pool has one thread per core and the flag is off.
    assert out.stdout.splitlines() == ["[]", "1 True 1"], out.stdout


def test_user_thread_setting_wins_over_the_default():
    code = "from cnfmp import runtime; import os; runtime.configure(); print(os.environ['MUJOCO_GL'])"
    env = dict(os.environ, MUJOCO_GL="osmesa")
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "osmesa"


def test_bridge_selftest_doubles_in_place():
    array = np.arange(6, dtype=np.float64).reshape(2, 3)
    address = array.ctypes.data
    back = runtime.bridge_selftest(array)
    assert back is array and back.ctypes.data == address
    np.testing.assert_array_equal(back, np.arange(6).reshape(2, 3) * 2.0)


@pytest.mark.parametrize("bad", [np.arange(3, dtype=np.float32), [1.0, 2.0], "x"])
def test_bridge_selftest_rejects_other_types(bad):
    with pytest.raises(TypeError, match="float64 numpy array"):
        runtime.bridge_selftest(bad)


def test_gl_backend_defaults_to_egl_when_its_library_loads():
    code = "from cnfmp import runtime; print(runtime.choose_gl_backend())"
    env = {k: v for k, v in os.environ.items() if k != "MUJOCO_GL"}
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "egl"  # setup-system installs libEGL
