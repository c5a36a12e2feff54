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

BREAK_ACTOR_GRAD = os.environ.get("VSGJAX_BREAK_ACTOR_GRAD") == "1"
BREAK_PERCEPTION = os.environ.get("VSGJAX_BREAK_PERCEPTION") == "1"


@pytest.fixture
def actor_learns(monkeypatch) -> bool:
    """Whether the actor gets its gradient: with ``VSGJAX_BREAK_ACTOR_GRAD=1`` the actor's
    loss is wrapped in ``stop_gradient`` (the actor never learns), and every learning test
    that uses this fixture must then FAIL: that shows it measures learning."""
    if BREAK_ACTOR_GRAD:
        from vsgjax.model import behaviour

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
        from vsgjax.model.world_model import WorldModel

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

