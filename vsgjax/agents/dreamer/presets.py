"""The Dreamer family's presets (every model of :func:`vsgjax.registry.agents.dreamer_models`):
the paper's hyperparameter table per preset column (``COLUMN``) and the sizes (``SIZE``), as
dotted config keys. Pure data; what differs between the family's models is in their registry entries
(:mod:`vsgjax.registry.agents`); :func:`vsgjax.config.make_config` applies both.
"""

# DreamerV2's Atari model, loss and actor-critic settings (its discrete-action column)
_DISCRETE_MODEL = {
    "model.deter": 600, "model.hidden": 600,
    "wm.cnn_depth": 48, "wm.mlp_layers": 4, "wm.mlp_units": 400,
    "wm.reward_layers": 4, "wm.discount_layers": 4,
    "wm.kl_scale": 0.1, "wm.kl_balance": 0.8, "wm.kl_free": 0.0,
    "wm.gate_alpha": 0.1, "wm.gate_kappa": 0.4, "wm.gate_free": 0.1,
    "wm.lr": 2e-4, "wm.discount_head": True, "wm.discount_scale": 5.0,
    "wm.reward_scale": 1.0, "wm.reward_tanh": True, "wm.weight_decay": 1e-6,
    "ac.actor_lr": 4e-5, "ac.critic_lr": 1e-4, "ac.gamma": 0.999, "ac.entropy": 1e-3,
    "ac.actor_grad": "reinforce",
    "ac.actor_layers": 4, "ac.critic_layers": 4, "ac.weight_decay": 1e-6,
}

COLUMN = {
    "bbs": {
        "env.action_repeat": 4, "env.time_limit": 3000,
        "model.deter": 1024, "model.hidden": 1024,
        "wm.cnn_depth": 48, "wm.mlp_layers": 4, "wm.mlp_units": 400,
        "wm.reward_layers": 4, "wm.discount_layers": 4,
        "wm.kl_scale": 1.0, "wm.kl_balance": 0.8, "wm.kl_free": 0.0,
        "wm.gate_alpha": 0.1, "wm.gate_kappa": 0.3, "wm.gate_free": 0.1,
        "wm.lr": 1e-4, "wm.discount_head": True, "wm.discount_scale": 1.0,
        "wm.reward_scale": 1.0, "wm.weight_decay": 1e-6,
        "ac.actor_lr": 8e-5, "ac.critic_lr": 2e-4, "ac.gamma": 0.99, "ac.entropy": 2e-3,
        "ac.actor_layers": 4, "ac.critic_layers": 4, "ac.weight_decay": 1e-6,
        "train.batch": 16, "train.train_every": 5, "train.prefill": 10_000,
        "train.oversample_ends": True, "train.pretrain": 1,
        "train.steps": 2_500_000, "train.eval_every": 50_000, "train.eval_episodes": 10,
    },
    "dmc": {
        "env.action_repeat": 2, "env.time_limit": 1000,
        "model.deter": 1024, "model.hidden": 1024,
        "wm.cnn_depth": 32, "wm.mlp_layers": 4, "wm.mlp_units": 400,
        "wm.reward_layers": 2, "wm.discount_layers": 2,
        "wm.kl_scale": 1.0, "wm.kl_balance": 0.8, "wm.kl_free": 1.0,
        "wm.gate_alpha": 0.1, "wm.gate_kappa": 0.4, "wm.gate_free": 0.1,
        "wm.lr": 3e-4, "wm.discount_head": False, "wm.reward_scale": 2.0,
        "wm.weight_decay": 0.0,
        "ac.actor_lr": 8e-5, "ac.critic_lr": 8e-5, "ac.gamma": 0.99, "ac.entropy": 1e-4,
        "ac.actor_layers": 4, "ac.critic_layers": 3, "ac.weight_decay": 0.0,
        "train.batch": 50, "train.train_every": 5, "train.prefill": 2500,
        "train.oversample_ends": False, "train.pretrain": 100,
        "train.steps": 1_000_000, "train.eval_every": 10_000, "train.eval_episodes": 1,
    },
    "atari": {
        "env.action_repeat": 4, "env.time_limit": 108_000, "env.grayscale": True,
        "env.sticky": 0.25,
        **_DISCRETE_MODEL,
        # DreamerV2's Atari counts agent steps (x4 frames); here every count is in env steps
        # (frames): 5e7 agent steps, prefill 5e4, eval every 2.5e5 (train_every stays in agent
        # steps, as everywhere).
        "train.batch": 16, "train.train_every": 16, "train.prefill": 200_000,
        "train.oversample_ends": True, "train.pretrain": 1,
        "train.steps": 200_000_000, "train.eval_every": 1_000_000, "train.eval_episodes": 1,
    },
    # gymnax_ tasks (bsuite's MemoryChain): the release has no such column. The model and loss
    # settings are Atari's (DreamerV2's discrete-action column), the counts fit short episodes
    # of vector observations one decision per step (docs/mjx.md, docs/deviations.md).
    "gymnax": {
        "env.action_repeat": 1, "env.time_limit": 1000,
        **_DISCRETE_MODEL,
        "train.batch": 16, "train.train_every": 5, "train.prefill": 5000,
        "train.oversample_ends": False, "train.pretrain": 100,
        "train.steps": 500_000, "train.eval_every": 10_000, "train.eval_episodes": 100,
    },
}

SIZE = {
    "paper": {},
    "small": {
        "model.deter": 256, "model.hidden": 256, "wm.cnn_depth": 16,
        "wm.mlp_layers": 2, "wm.mlp_units": 256, "wm.reward_layers": 2,
        "wm.discount_layers": 2, "ac.actor_layers": 2, "ac.critic_layers": 2,
        "train.batch": 8, "train.length": 32, "train.train_every": 2,
        "train.prefill": 1000, "train.steps": 200_000,
        "train.eval_every": 10_000, "train.eval_episodes": 2, "train.log_every": 200,
        "train.replay_capacity": 500_000,
    },
    # Vector observations only (mjx_ tasks): chosen for return per CPU-minute (docs/presets.md).
    "cpu": {
        "model.deter": 128, "model.hidden": 128,
        "wm.mlp_layers": 2, "wm.mlp_units": 128, "wm.reward_layers": 2,
        "wm.discount_layers": 2, "ac.actor_layers": 2, "ac.critic_layers": 2,
        "wm.lr": 1e-3, "ac.actor_lr": 3e-4, "ac.critic_lr": 3e-4,
        "env.num_envs": 2, "train.batch": 16, "train.length": 32, "train.train_every": 2,
        "train.prefill": 4000, "train.pretrain": 100, "train.steps": 100_000,
        "train.eval_every": 4000, "train.eval_episodes": 4, "train.log_every": 2000,
        "train.replay_capacity": 200_000,
    },
    # episodes of 200 env steps, so that a debug run trains within its 400 steps on every family
    "debug": {
        "env.time_limit": 200, "model.deter": 32, "model.hidden": 32, "wm.cnn_depth": 4,
        "wm.mlp_layers": 1, "wm.mlp_units": 32, "wm.reward_layers": 1,
        "wm.discount_layers": 1, "ac.actor_layers": 1, "ac.critic_layers": 1,
        "ac.horizon": 5, "train.batch": 4, "train.length": 10, "train.prefill": 100,
        "train.steps": 400, "train.train_every": 10, "train.pretrain": 1, "train.eval_every": 200,
        "train.eval_episodes": 1, "train.log_every": 50, "train.ckpt_every": 5,
        "train.video_every": 200, "train.replay_capacity": 10_000,
    },
}
