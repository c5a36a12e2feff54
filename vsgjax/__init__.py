"""vsgjax: world-model reinforcement learning with Variational Sparse Gating, in JAX.

Public API (imported lazily, so ``import vsgjax`` stays cheap)::

    config = vsgjax.make_config(task="bbs_basic", model="vsg", size="small")
    state = vsgjax.init(config, key, obs_shape=(64, 64, 3), action_dim=2)
    state, metrics, posts = vsgjax.world_model_step(config, state, batch, key)
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
    "make_dynamics": "vsgjax.agents.dreamer.dynamics",
    "WorldModel": "vsgjax.agents.dreamer.world_model",
    "init": "vsgjax.agents.dreamer.api",
    "world_model_step": "vsgjax.agents.dreamer.api",
    "imagine": "vsgjax.agents.dreamer.api",
    "observe": "vsgjax.agents.dreamer.api",
    "TrainState": "vsgjax.agents.dreamer.api",
    "TrainedParams": "vsgjax.agents.dreamer.api",
    "load": "vsgjax.analysis.load",
    "TrainedRun": "vsgjax.analysis.load",
    "make_optimizer": "vsgjax.agents.dreamer.optim",
    "DreamerAgent": "vsgjax.agents.dreamer.agent",
    "make_agent": "vsgjax.agents",
    "gate_statistics": "vsgjax.agents.dreamer.gate_statistics",
    "GateStatistics": "vsgjax.agents.dreamer.gate_statistics",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name):
    if name not in _EXPORTS:
        raise AttributeError(f"module 'vsgjax' has no attribute {name!r}")
    return getattr(importlib.import_module(_EXPORTS[name]), name)
