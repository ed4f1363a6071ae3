"""Process set-up for the numerics: thread limits, deterministic torch kernels, subnormal
floats flushed to zero, offline flags and the MuJoCo GL backend.

Every process that runs cnfmp numerics calls :func:`configure` once, before torch, OpenCV,
MuJoCo or any Hugging Face library is imported: the embedded interpreter does it on its
worker thread right after start-up, pytest does it from ``conftest.py``. Environment
variables that the user already set win over these defaults.

Why: torch's pip wheel uses libgomp, whose threads spin-wait; on the 2 shared cores of our
machines two intra-op threads collapsed a server's throughput (``../shared/facts.md``), so
one thread is the default. Training, which owns the machine, runs one per core with a short
spin (:data:`GOMP_SPIN_COUNT`), which keeps trainings side by side from collapsing. Nothing may
reach a model hub at run time, so the Hugging Face libraries are forced offline.
"""

from __future__ import annotations

import os
import sys
import threading

#: Environment defaults applied by :func:`configure` (values the user set are kept).
ENV_DEFAULTS = {
    "HF_HUB_OFFLINE": "1",
    "TRANSFORMERS_OFFLINE": "1",
    "HF_DATASETS_OFFLINE": "1",
    "HF_HUB_DISABLE_TELEMETRY": "1",
    "TOKENIZERS_PARALLELISM": "false",
}

_THREAD_VARS = ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS")
#: libgomp's spin count at a barrier before a waiting thread sleeps, with several intra-op
#: threads. Its default (300,000) keeps a thread spinning while its peer waits for a core,
#: so two 2-thread trainings on 2 cores took 3.1x as long as one alone; at 1000 they take
#: 1.5x, one alone costs what it did (150 cup_stacking steps 13.9 s against 13.6) and a
#: passive wait (0) loses most of the second thread's gain (18.0 s; 1 thread 20.3 s).
GOMP_SPIN_COUNT = "1000"

_configured_threads: int | None = None


def configure(threads: int = 1) -> dict:
    """Apply thread limits and offline defaults; idempotent.

    Args:
        threads: torch intra-op threads (and OpenMP/BLAS threads); >= 1.

    Returns:
        ``{"threads": int, "torch_loaded": bool}``: torch_loaded says whether torch was
        already imported (then configured at once); otherwise torch and OpenCV are configured
        when first imported.

    Raises:
        ValueError: ``threads`` < 1, or a second call asks for a different count after
            torch was configured (torch's inter-op pool cannot be resized).
    """
    global _configured_threads
    if threads < 1:
        raise ValueError(f"threads must be >= 1, got {threads}")
    if _configured_threads is not None:
        if threads != _configured_threads:
            raise ValueError(
                f"threads already configured to {_configured_threads}; cannot change to {threads}"
            )
        return {"threads": threads, "torch_loaded": "torch" in sys.modules}

    for key, value in ENV_DEFAULTS.items():
        os.environ.setdefault(key, value)
    choose_gl_backend()
    for key in _THREAD_VARS:
        # libgomp reads these when torch loads it, so they must be set before the import.
        os.environ.setdefault(key, str(threads))
    if threads > 1:
        os.environ.setdefault("GOMP_SPINCOUNT", GOMP_SPIN_COUNT)

    _configured_threads = threads
    # torch and OpenCV take seconds to import; a command that never needs them (rendering a
    # scene, reading a dataset) must not pay for them, so each is configured when it loads.
    for name, apply in (("torch", _configure_torch), ("cv2", _configure_cv2)):
        if name in sys.modules:
            apply(sys.modules[name])
        else:
            _AFTER_IMPORT[name] = apply
    if _AFTER_IMPORT and not any(isinstance(f, _ConfigureOnImport) for f in sys.meta_path):
        sys.meta_path.insert(0, _ConfigureOnImport())
    return {"threads": threads, "torch_loaded": "torch" in sys.modules}


def _configure_torch(torch) -> None:
    """Thread pools and deterministic kernels, before torch runs any parallel work."""
    torch.set_num_threads(_configured_threads)
    # Training drives some activations and gradients into the subnormal range, where x86
    # arithmetic is many times slower: a cup_stacking training step went from 0.17 s to
    # 0.28-0.30 s after its first hundred steps. Flushing them to zero (a value below 1e-38
    # changes no result) keeps every step at the first one's cost. The flag is per thread:
    # worker_pool() sets it on its threads too.
    torch.set_flush_denormal(True)
    # Some CPU backward kernels (index accumulation) are not bitwise reproducible by default:
    # one seeded training step differed from run to run. Deterministic mode costs nothing
    # measurable here (60 training steps 4.0-4.6 s either way); warn_only keeps an op without
    # a deterministic kernel usable, with a warning.
    set_aten_flag = getattr(torch._C, "_set_deterministic_algorithms", None)
    if set_aten_flag is None:  # a torch without the private setter: pay the compiler-stack import
        torch.use_deterministic_algorithms(True, warn_only=True)
    else:
        set_aten_flag(True, warn_only=True)
    try:
        torch.set_num_interop_threads(_configured_threads)
    except RuntimeError:
        pass  # already fixed by earlier parallel work in this process; doctor reports it


def _configure_cv2(cv2) -> None:
    cv2.setNumThreads(_configured_threads)


#: Top-level module name -> what to apply to it right after its first import.
_AFTER_IMPORT: dict = {}


class _ConfigureOnImport:
    """A meta-path hook that finds nothing itself: for a module in :data:`_AFTER_IMPORT` it
    asks the other finders for the spec and makes that spec's loader apply the settings right
    after the module's code ran, before the importer gets it back."""

    def find_spec(self, name, path=None, target=None):
        apply = _AFTER_IMPORT.get(name)
        if apply is None:
            return None
        for finder in sys.meta_path:
            if finder is self or not hasattr(finder, "find_spec"):
                continue
            spec = finder.find_spec(name, path, target)
            if spec is not None:
                break
        else:
            return None
        if spec.loader is None or not hasattr(spec.loader, "exec_module"):
            return spec
        run_module = spec.loader.exec_module

        def exec_then_configure(module):
            run_module(module)
            # A package may import itself again while it loads (OpenCV swaps in its native
            # module): the settings go to whichever load completes first, once.
            if _AFTER_IMPORT.pop(name, None) is not None:
                apply(module)

        # The loader instance belongs to this one spec, so shadowing its method is local.
        spec.loader.exec_module = exec_then_configure
        return spec



_POOL = None


def worker_pool():
    """Threads for numerics that can run side by side (the objects of a scene, the scenes of
    a batch): one per core the process may use (``CNFMP_INFERENCE_THREADS`` overrides),
    created on first use. torch and OpenCV release the GIL inside their kernels, so with one
    intra-op thread per kernel this is how a process uses its other cores."""
    global _POOL
    if _POOL is None:
        from concurrent.futures import ThreadPoolExecutor

        workers = int(os.environ.get("CNFMP_INFERENCE_THREADS", 0)) or len(os.sched_getaffinity(0))

        class NumericsPool(ThreadPoolExecutor):
            def submit(self, fn, /, *args, **kwargs):
                return super().submit(_flushing_denormals, fn, *args, **kwargs)

        _POOL = NumericsPool(max_workers=max(1, workers), thread_name_prefix="cnfmp-worker")
    return _POOL


_THREAD_STATE = threading.local()


def _flushing_denormals(fn, *args, **kwargs):
    """Calls `fn` after making sure this thread flushes subnormal floats to zero, as
    :func:`_configure_torch` makes the configuring thread do (torch may load after the pool
    starts, so each thread checks on its calls until it has done it)."""
    if not getattr(_THREAD_STATE, "flushes", False) and "torch" in sys.modules:
        sys.modules["torch"].set_flush_denormal(True)
        _THREAD_STATE.flushes = True
    return fn(*args, **kwargs)


def on_every_worker(function) -> None:
    """Runs `function()` once on each thread of :func:`worker_pool` (a barrier holds every
    call until all threads have one), so a warm-up pays each thread's first-call costs."""
    pool = worker_pool()
    barrier = threading.Barrier(pool._max_workers)

    def run(_):
        barrier.wait()
        function()

    list(pool.map(run, range(pool._max_workers)))


def choose_gl_backend() -> str:
    """Sets MUJOCO_GL, unless the user did, to the first offscreen backend whose library
    loads: EGL, else OSMesa (no display is needed for either). Returns the choice.

    MuJoCo binds its backend when first imported, so this must run before that.
    """
    if "MUJOCO_GL" not in os.environ:
        import ctypes

        os.environ["MUJOCO_GL"] = "egl"
        for backend, library in (("egl", "libEGL.so.1"), ("osmesa", "libOSMesa.so.8")):
            try:
                ctypes.CDLL(library)
            except OSError:
                continue
            os.environ["MUJOCO_GL"] = backend
            break
    return os.environ["MUJOCO_GL"]


def bridge_selftest(array):
    """Doubles a float64 numpy array in place and returns it (the same object).

    The bridge sends an array it owns, calls this, and checks both that the values doubled
    and that the buffer address did not change: proof that arrays cross without copies.

    Args:
        array: a writable, C-contiguous ``numpy.ndarray`` of dtype float64, any shape.

    Returns:
        The same array object, after ``array *= 2``.
    """
    import numpy as np

    if not isinstance(array, np.ndarray) or array.dtype != np.float64:
        raise TypeError(f"expected a float64 numpy array, got {type(array).__name__}")
    array *= 2.0
    return array
