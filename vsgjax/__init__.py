"""vsgjax: world-model reinforcement learning with Variational Sparse Gating, in JAX.

Public API (imported lazily, so ``import vsgjax`` stays cheap)::

    config = vsgjax.make_config(task="bbs_basic", model="vsg", size="small")
    state = vsgjax.init(config, key, obs_shape=(64, 64, 3), action_dim=2)
    state, metrics, posts = vsgjax.train_step(config, state, batch, key)
    rollout = vsgjax.imagine(state.params, start, H=15, config=config, key=key, action_dim=2)

    run = vsgjax.load("runs/bbs_basic-vsg-s0")     # a trained run: config, params, episodes
    posts = run.observe(run.episode(-1))           # posterior states [T, ...]
    rollout = vsgjax.imagine(run.params, jax.tree.map(lambda x: x[14], posts), H=15)

    stats = vsgjax.gate_statistics(run.params, batch)  # VSG / SVSG gates: open fractions,
    stats.summary()                                    # gate KL, closed-run lengths

(``run.params`` carry their config, so that last call needs no ``config``/``key``; see
``vsgjax.load`` and docs/notebook.md.)
"""

import importlib

_EXPORTS = {
    "make_config": "vsgjax.config",
    "Config": "vsgjax.config",
    "ConfigError": "vsgjax.config",
    "make_dynamics": "vsgjax.model.dynamics",
    "WorldModel": "vsgjax.model.world_model",
    "init": "vsgjax.model.api",
    "train_step": "vsgjax.model.api",
    "imagine": "vsgjax.model.api",
    "observe": "vsgjax.model.api",
    "TrainState": "vsgjax.model.api",
    "TrainedParams": "vsgjax.model.api",
    "load": "vsgjax.loop.load",
    "TrainedRun": "vsgjax.loop.load",
    "make_optimizer": "vsgjax.model.optim",
    "Agent": "vsgjax.model.agent",
    "gate_statistics": "vsgjax.model.gate_statistics",
    "GateStatistics": "vsgjax.model.gate_statistics",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name):
    if name not in _EXPORTS:
        raise AttributeError(f"module 'vsgjax' has no attribute {name!r}")
    return getattr(importlib.import_module(_EXPORTS[name]), name)
