"""The environment of a training subprocess in the tests: CPU and headless rendering. It
inherits the test session's persistent compilation cache (``tests/conftest.py``), so the
subprocesses load the programs that any test of the session compiled before them."""

from __future__ import annotations

import os


def subprocess_env(**extra: str) -> dict[str, str]:
    return dict(os.environ, JAX_PLATFORMS="cpu", MUJOCO_GL="osmesa", PYOPENGL_PLATFORM="osmesa",
                **extra)
