"""pytest set-up: the same process configuration the embedded interpreter applies (one torch
thread, offline Hugging Face libraries, EGL rendering), and a private HF cache per session."""

import importlib.util
import os
import tempfile

import pytest

os.environ.setdefault("HF_HOME", tempfile.mkdtemp(prefix="cnfmp-hf-"))

from cnfmp import runtime  # noqa: E402  (HF_HOME must be set first)

runtime.configure(threads=1)


#: The repository's scripts/ directory.
SCRIPTS_DIR = os.path.join(os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))), "scripts")


@pytest.fixture(scope="session")
def load_script():
    """Imports a file of scripts/ as a module, for testing its functions:
    ``load_script("release-errors")`` -> the module of scripts/release-errors.py."""
    def load(name: str):
        spec = importlib.util.spec_from_file_location(name.replace("-", "_"), os.path.join(SCRIPTS_DIR, f"{name}.py"))
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
        return module
    return load
