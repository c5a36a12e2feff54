"""Shared test setup: CPU only, headless rendering, deterministic XLA on the CPU."""

import os
import shutil
import tempfile

os.environ.setdefault("JAX_PLATFORMS", "cpu")
os.environ.setdefault("MUJOCO_GL", "osmesa")
os.environ.setdefault("PYOPENGL_PLATFORM", "osmesa")
os.environ.setdefault("SDL_VIDEODRIVER", "dummy")
# One persistent XLA compilation cache per test session, in a fresh directory: the test
# processes (xdist workers) and every training subprocess they start inherit it, so a program
# that one test compiled is loaded, not compiled again, by the next test that builds the same
# one (in any file or process). Never the user's own cache (~/.cache/vsgjax/xla).
SESSION_CACHE = "VSGJAX_TEST_XLA_CACHE"
if SESSION_CACHE not in os.environ:  # the first process of the session (the xdist controller)
    os.environ[SESSION_CACHE] = tempfile.mkdtemp(prefix="vsgjax-tests-xla-")
    _OWNS_CACHE = True
else:
    _OWNS_CACHE = False
os.environ["JAX_COMPILATION_CACHE_DIR"] = os.environ[SESSION_CACHE]
os.environ["JAX_ENABLE_COMPILATION_CACHE"] = "true"
os.environ["JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS"] = "0"

import gc  # noqa: E402

import jax  # noqa: E402
import pytest  # noqa: E402

BREAK_ACTOR_GRAD = os.environ.get("VSGJAX_BREAK_ACTOR_GRAD") == "1"
BREAK_PERCEPTION = os.environ.get("VSGJAX_BREAK_PERCEPTION") == "1"


@pytest.fixture
def actor_learns(monkeypatch) -> bool:
    """Whether the actor gets its gradient: with ``VSGJAX_BREAK_ACTOR_GRAD=1`` the actor's
    loss is wrapped in ``stop_gradient`` (the actor never learns), and every learning test
    that uses this fixture must then FAIL: that shows it measures learning."""
    if BREAK_ACTOR_GRAD:
        from vsgjax.agents.dreamer import behaviour

        original = behaviour.actor_loss

        def broken(actor_params, *args):
            loss, aux = original(actor_params, *args)
            return jax.lax.stop_gradient(loss), aux

        monkeypatch.setattr(behaviour, "actor_loss", broken)
    return not BREAK_ACTOR_GRAD


@pytest.fixture
def perception_works(monkeypatch) -> bool:
    """Whether the world model sees the observations: with ``VSGJAX_BREAK_PERCEPTION=1`` the
    encoder's embedding is multiplied by zero (in training and in acting), and every learning
    test that uses this fixture must then FAIL: that shows it measures learning from what the
    agent sees."""
    if BREAK_PERCEPTION:
        from vsgjax.agents.dreamer.world_model import WorldModel

        original = WorldModel.encode

        def blind(self, params, obs):
            return 0.0 * original(self, params, obs)

        monkeypatch.setattr(WorldModel, "encode", blind)
    return not BREAK_PERCEPTION


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



def pytest_unconfigure(config):
    if _OWNS_CACHE:
        shutil.rmtree(os.environ[SESSION_CACHE], ignore_errors=True)
