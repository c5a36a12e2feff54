"""The environment of a training subprocess in the tests: CPU, headless rendering, and a
persistent compilation cache shared by the subprocesses given the same ``cache`` directory.

The test process itself runs with the cache off (``tests/conftest.py``); its children inherit
that unless they turn it back on, as this does."""

from __future__ import annotations

import os
from pathlib import Path


def subprocess_env(cache: Path, **extra: str) -> dict[str, str]:
    return dict(os.environ, JAX_PLATFORMS="cpu", JAX_COMPILATION_CACHE_DIR=str(cache),
                JAX_ENABLE_COMPILATION_CACHE="true",
                JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS="0", MUJOCO_GL="osmesa",
                PYOPENGL_PLATFORM="osmesa", **extra)
