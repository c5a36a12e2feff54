"""Presets: the values of a config per domain (the task's prefix), model and size, and
:func:`make_config`, which resolves them, applies overrides and checks every value."""

from __future__ import annotations

from collections.abc import Sequence

from vsgjax.config.checks import check_config
from vsgjax.config.schema import (
    DOMAINS,
    MODELS,
    SIZES,
    Config,
    ConfigError,
    EnvConfig,
    ModelConfig,
    apply_overrides,
    apply_values,
)

# --- presets ---------------------------------------------------------------------------------
# Each preset is a dict of dotted keys applied in order: domain, model, domain+model, size.

_DOMAIN = {
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
        # DreamerV2's Atari counts agent steps (x4 frames); here every count is in env steps
        # (frames): 5e7 agent steps, prefill 5e4, eval every 2.5e5 (train_every stays in agent
        # steps, as everywhere).
        "train.batch": 16, "train.train_every": 16, "train.prefill": 200_000,
        "train.oversample_ends": True, "train.pretrain": 1,
        "train.steps": 200_000_000, "train.eval_every": 1_000_000, "train.eval_episodes": 1,
    },
}

_MODEL = {
    "dreamerv1": {"model.stoch": 30, "model.classes": 0, "model.cell_norm": True},
    "dreamerv2": {"model.stoch": 32, "model.classes": 32, "model.cell_norm": True},
    "vsg": {"model.stoch": 32, "model.classes": 32, "model.cell_norm": False},
    "svsg": {"model.deter": 0, "model.stoch": 1024, "model.classes": 0,
             "model.cell_norm": False, "wm.kl_masked": True},
    "ssm": {"model.deter": 0, "model.stoch": 30, "model.classes": 0, "model.cell_norm": False},
}

_DOMAIN_MODEL = {
    ("bbs", "svsg"): {"wm.kl_free": 1.0},
    ("bbs", "dreamerv1"): {"wm.kl_free": 1.0, "model.stoch": 32},  # bringbackshapes_gaussian
    ("dmc", "dreamerv1"): {"model.deter": 200, "model.hidden": 200},
}

_SIZE = {
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
    # Vector observations only (mjx_ tasks): chosen for return per CPU-minute (README, Presets).
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
    "debug": {
        "model.deter": 32, "model.hidden": 32, "wm.cnn_depth": 4,
        "wm.mlp_layers": 1, "wm.mlp_units": 32, "wm.reward_layers": 1,
        "wm.discount_layers": 1, "ac.actor_layers": 1, "ac.critic_layers": 1,
        "ac.horizon": 5, "train.batch": 4, "train.length": 10, "train.prefill": 100,
        "train.steps": 400, "train.train_every": 10, "train.pretrain": 1, "train.eval_every": 200,
        "train.eval_episodes": 1, "train.log_every": 50, "train.ckpt_every": 5,
        "train.video_every": 200, "train.replay_capacity": 10_000,
    },
}

# Latent sizes per model at the small / debug sizes (the stochastic state shrinks with the rest).
_SIZE_MODEL = {
    ("small", "svsg"): {"model.deter": 0, "model.stoch": 256},
    ("small", "ssm"): {"model.deter": 0},
    ("small", "dreamerv2"): {"model.stoch": 16, "model.classes": 16},
    ("small", "vsg"): {"model.stoch": 16, "model.classes": 16},
    ("cpu", "svsg"): {"model.deter": 0, "model.stoch": 128},
    ("cpu", "ssm"): {"model.deter": 0, "model.stoch": 16},
    ("cpu", "dreamerv1"): {"model.stoch": 16},
    ("cpu", "dreamerv2"): {"model.stoch": 8, "model.classes": 8},
    ("cpu", "vsg"): {"model.stoch": 8, "model.classes": 8},
    ("debug", "svsg"): {"model.deter": 0, "model.stoch": 32},
    ("debug", "ssm"): {"model.deter": 0, "model.stoch": 8},
    ("debug", "dreamerv1"): {"model.stoch": 8},
    ("debug", "dreamerv2"): {"model.stoch": 4, "model.classes": 4},
    ("debug", "vsg"): {"model.stoch": 4, "model.classes": 4},
}


VECTOR_SIZES = ("cpu",)  # sizes with only an MLP encoder: tasks with vector observations
VECTOR_TASK_PREFIX = "mjx_"

# Task families whose presets are another domain's: the MJX tasks are DeepMind Control tasks.
PRESET_DOMAIN = {"mjx": "dmc"}


def domain_of(task: str) -> str:
    """The preset domain of a task name: its prefix before the first underscore (``mjx_``
    tasks take the ``dmc`` presets)."""
    prefix = task.split("_", 1)[0]
    prefix = PRESET_DOMAIN.get(prefix, prefix)
    if prefix not in DOMAINS or "_" not in task:
        raise ConfigError(
            f"unknown task {task!r}: task names look like "
            "bbs_<variant>, dmc_<domain>_<task>, mjx_<domain>_<task> or atari_<game>"
        )
    return prefix


def _check_name(kind: str, value: str, valid: Sequence[str]) -> None:
    if value not in valid:
        raise ConfigError(f"unknown {kind} {value!r}; valid: {', '.join(valid)}")


def make_config(
    task: str = "bbs_basic",
    model: str = "vsg",
    size: str = "paper",
    overrides: Sequence[str] = (),
) -> Config:
    """Resolve presets for (task's domain, model, size), then apply ``key=value`` overrides;
    every value is checked (:mod:`vsgjax.config_checks`)."""
    domain = domain_of(task)
    _check_name("model", model, MODELS)
    _check_name("size", size, SIZES)
    if size in VECTOR_SIZES and not task.startswith(VECTOR_TASK_PREFIX):
        raise ConfigError(f"size {size!r} is for vector observations and task {task!r} has "
                          f"images; valid: {VECTOR_TASK_PREFIX}<domain>_<task> tasks with "
                          f"{size!r}, or sizes {', '.join(s for s in SIZES if s != size)}")
    config = Config(domain=domain, size=size, model=ModelConfig(name=model),
                    env=EnvConfig(task=task))
    layers = (
        _DOMAIN[domain], _MODEL[model], _DOMAIN_MODEL.get((domain, model), {}),
        _SIZE[size], _SIZE_MODEL.get((size, model), {}),
    )
    for preset in layers:
        config = apply_values(config, preset)
    config = apply_overrides(config, overrides)
    check_config(config)
    return config
