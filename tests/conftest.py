"""Shared test setup: CPU only, headless rendering, deterministic XLA on the CPU."""

import os

os.environ.setdefault("JAX_PLATFORMS", "cpu")
os.environ.setdefault("MUJOCO_GL", "osmesa")
os.environ.setdefault("PYOPENGL_PLATFORM", "osmesa")
os.environ.setdefault("SDL_VIDEODRIVER", "dummy")
# No persistent XLA compilation cache inside test processes: two crashes (segmentation faults in
# XLA's compiler) in full-suite runs both happened on the cache's compile-and-write path, with
# several test processes sharing ~/.cache/vsgjax/xla. Subprocess runs that want a cache set it.
os.environ.setdefault("JAX_ENABLE_COMPILATION_CACHE", "false")

