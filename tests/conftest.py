"""Shared test setup: CPU only, headless rendering, deterministic XLA on the CPU."""

import os

os.environ.setdefault("JAX_PLATFORMS", "cpu")
os.environ.setdefault("MUJOCO_GL", "osmesa")
os.environ.setdefault("PYOPENGL_PLATFORM", "osmesa")
os.environ.setdefault("SDL_VIDEODRIVER", "dummy")
# Each test process compiles its own programs; the e2e subprocesses that want a persistent
# compilation cache set it themselves.
os.environ.setdefault("JAX_ENABLE_COMPILATION_CACHE", "false")

import gc  # noqa: E402

import jax  # noqa: E402
import pytest  # noqa: E402


@pytest.fixture(autouse=True, scope="module")
def _free_compiled_programs():
    """Free every compiled program when a test file ends.

    XLA:CPU maps each compiled program's code into memory in pieces: one ``debug`` agent update
    adds ~2,200 memory mappings, held as long as the program is cached. A long test process
    that keeps them all reaches the kernel's limit (``vm.max_map_count``, 65,530 by default);
    XLA's next compile then cannot map its code and the process aborts inside the compiler
    (what killed three full-suite runs). Tests that share programs share them within a file.
    """
    yield
    jax.clear_caches()
    gc.collect()

