"""pytest set-up: the same process configuration the embedded interpreter applies (one torch
thread, offline Hugging Face libraries, EGL rendering), and a private HF cache per session."""

import os
import tempfile

os.environ.setdefault("HF_HOME", tempfile.mkdtemp(prefix="cnfmp-hf-"))

from cnfmp import runtime  # noqa: E402  (HF_HOME must be set first)

runtime.configure(threads=1)
