"""The Dreamer family's settings: its config sections (``model``, ``wm``, ``ac``, ``optim`` and
DreamerPro's ``proto``) as frozen dataclasses, the valid names of their string keys, their
valid ranges and the checks between their keys.

A registry entry names this module as its ``settings`` and the sections it reads
(:mod:`vsgjax.registry.agents`); :func:`vsgjax.config.config_class` builds the run config of
an agent from them, and :func:`vsgjax.config.check_config` applies :data:`RANGES` and
:func:`check`.
"""

from __future__ import annotations

from dataclasses import dataclass

from vsgjax.config.checks import AT_LEAST_0, AT_LEAST_1, OPEN_UNIT, POSITIVE, UNIT, Range
from vsgjax.config.schema import ConfigError
from vsgjax.registry.agents import gated_models

ALIGNMENTS = ("release", "next_state")  # ac.alignment: see vsgjax/agents/dreamer/behaviour.py
ACTOR_GRADS = ("auto", "dynamics", "reinforce", "both")
# ac.actor_dist: see vsgjax/agents/dreamer/behaviour.py (continuous actions)
ACTOR_DISTS = ("trunc_normal", "tanh_normal")
EPS_PLACEMENTS = ("release", "optax")  # optim.eps_placement: see vsgjax/agents/dreamer/optim.py
WEIGHT_DECAYS = ("release", "adamw")  # optim.weight_decay: see vsgjax/agents/dreamer/optim.py
# wm.encoder: see vsgjax/agents/dreamer/world_model.py (check_encoders)
ENCODERS = ("auto", "cnn", "mlp")
# wm.gate_objective: see vsgjax/agents/dreamer/gate_objectives.py
GATE_OBJECTIVES = ("release", "rate", "rate_kl", "gatel0rd")
# String keys whose values are names from a fixed list (checked when a config is built).
CHOICES = {"ac.alignment": ALIGNMENTS, "ac.actor_grad": ACTOR_GRADS, "ac.actor_dist": ACTOR_DISTS,
           "optim.eps_placement": EPS_PLACEMENTS, "optim.weight_decay": WEIGHT_DECAYS,
           "wm.encoder": ENCODERS, "wm.gate_objective": GATE_OBJECTIVES}


@dataclass(frozen=True)
class ModelConfig:
    """Latent dynamics."""

    deter: int = 1024  # deterministic state size (0 for the purely stochastic svsg / ssm)
    hidden: int = 1024  # width of the dense layers inside the dynamics
    stoch: int = 32  # Gaussian dims, or number of categorical variables
    classes: int = 32  # classes per categorical variable; 0 means Gaussian latents
    cell_norm: bool = False  # LayerNorm over the GRU's 3*D pre-activations
    min_std: float = 0.1  # Gaussian std = 2*sigmoid(s/2) + min_std
    gate_mode: str = "sample"  # "sample" (the release: Bernoulli everywhere) or "threshold" (p>0.5)
    gate_bias: float = -1.0  # update-gate bias: p = sigmoid(u + gate_bias)


@dataclass(frozen=True)
class WorldModelConfig:
    """Encoder, decoder, heads, world-model loss and its optimizer."""

    # "auto": the CNN for the image key, the MLP for vector keys; "cnn" / "mlp": one of the two
    # only (an observation spec with keys it cannot encode is an error)
    encoder: str = "auto"
    cnn_depth: int = 48
    mlp_layers: int = 4
    mlp_units: int = 400
    reward_layers: int = 4
    discount_layers: int = 4
    kl_scale: float = 1.0
    kl_balance: float = 0.8  # fraction of the KL gradient that trains the prior
    kl_free: float = 0.0  # free nats on the batch mean of the per-step KL
    kl_masked: bool = False  # SVSG: multiply the per-dimension KL by the gate sample
    gate_alpha: float = 0.1  # sparsity loss scale (0 = the NoSparsityLoss ablation)
    gate_kappa: float = 0.3  # prior gate probability
    gate_free: float = 0.1  # free nats of the sparsity loss
    # the gated models' gate objective: "release" (the KL above), "rate" (gate_lambda·mean p),
    # "rate_kl" (each unit's open rate to kappa), "gatel0rd" (GateL0RD's ReTanh gate and L0)
    gate_objective: str = "release"
    gate_lambda: float = 1.0  # scale of the rate and gatel0rd penalties (THICK's default)
    gate_noise: float = 0.1  # gatel0rd: std of the gate's pre-activation noise (GateL0RD's)
    reward_scale: float = 1.0
    reward_tanh: bool = False  # Atari: train on tanh(reward)
    discount_head: bool = True
    discount_scale: float = 1.0
    lr: float = 1e-4
    eps: float = 1e-5
    clip: float = 100.0
    weight_decay: float = 1e-6


@dataclass(frozen=True)
class BehaviourConfig:
    """Imagination actor-critic."""

    alignment: str = "release"  # "release" (the authors' ImagBehavior) or "next_state"
    horizon: int = 15  # release: H states per start, the start included; next_state: H steps
    starts: int = 0  # imagination starts per update: 0 = every posterior (the release), K = K drawn
    gamma: float = 0.99
    lam: float = 0.95
    actor_layers: int = 4
    critic_layers: int = 4
    actor_lr: float = 8e-5
    critic_lr: float = 2e-4
    actor_grad: str = "auto"  # "dynamics", "reinforce", "both" or "auto" (by action space)
    actor_grad_mix: float = 0.0  # weight of the dynamics gradient when actor_grad == "both"
    actor_min_std: float = 0.1
    # continuous actions: "trunc_normal" (the VSG release) or "tanh_normal" (DreamerPro's)
    actor_dist: str = "trunc_normal"
    entropy: float = 2e-3
    slow_critic_every: int = 100
    eps: float = 1e-5
    clip: float = 100.0
    weight_decay: float = 1e-6
    memoryless: bool = False  # act from each observation alone (no carried latent state)
    # with memoryless: imagination also starts from each observation's posterior alone, so the
    # actor trains on the states it acts from
    memoryless_starts: bool = False


@dataclass(frozen=True)
class OptimConfig:
    """The update rule shared by the world-model, actor and critic optimizers
    (vsgjax/agents/dreamer/optim.py).

    Rates stay in their sections (``wm.lr``, ``wm.eps``, ``wm.weight_decay``, ``ac.*``).
    """

    eps_placement: str = "release"  # TF's Adam: eps added to sqrt(v); "optax": to sqrt(v-hat)
    weight_decay: str = "release"  # var <- (1 - wd) var after the step; "adamw": lr * wd


@dataclass(frozen=True)
class PrototypeConfig:
    """DreamerPro's prototypical representation (fdeng18/dreamer-pro, ``configs.yaml``;
    vsgjax/agents/dreamer/representation/): read by the ``prototypes`` models (dreamerpro,
    vsgpro) instead of a decoder."""

    prototypes: int = 2500  # number of prototypes
    dim: int = 32  # the projections' and prototypes' size
    temperature: float = 0.1  # of the softmax over prototypes
    sinkhorn_eps: float = 0.05  # Sinkhorn's entropic regulariser (0.0125 in the dmc column)
    sinkhorn_iters: int = 3
    warm_up: int = 1  # first timesteps of each sequence left out of the prototype losses
    freeze_updates: int = 10_000  # updates during which the prototypes' gradient is zero
    ema_fraction: float = 0.05  # per update, of the target encoder and projection
    shift: float = 3.0  # augmentation: one shift per sequence, uniform in [-shift, shift] px
    swav_scale: float = 1.0
    temp_scale: float = 1.0
    norm_scale: float = 1.0  # the release's standard-DMC runs turned it off (norm_off: 0)


# Every section of the family, by its name in the config; an entry reads the ones it lists.
SECTIONS = {"model": ModelConfig, "wm": WorldModelConfig, "ac": BehaviourConfig,
            "optim": OptimConfig, "proto": PrototypeConfig}

RANGES = {
    "model.deter": AT_LEAST_0, "model.hidden": AT_LEAST_1, "model.stoch": AT_LEAST_1,
    "model.classes": AT_LEAST_0, "model.min_std": AT_LEAST_0, "model.gate_bias": Range(),
    "wm.cnn_depth": AT_LEAST_1, "wm.mlp_layers": AT_LEAST_0, "wm.mlp_units": AT_LEAST_1,
    "wm.reward_layers": AT_LEAST_0, "wm.discount_layers": AT_LEAST_0,
    "wm.kl_scale": AT_LEAST_0, "wm.kl_balance": UNIT, "wm.kl_free": AT_LEAST_0,
    "wm.gate_alpha": AT_LEAST_0, "wm.gate_kappa": OPEN_UNIT, "wm.gate_free": AT_LEAST_0,
    "wm.gate_lambda": AT_LEAST_0, "wm.gate_noise": AT_LEAST_0,
    "wm.reward_scale": AT_LEAST_0, "wm.discount_scale": AT_LEAST_0,
    "wm.lr": POSITIVE, "wm.eps": POSITIVE, "wm.clip": POSITIVE, "wm.weight_decay": AT_LEAST_0,
    "ac.horizon": AT_LEAST_1, "ac.starts": AT_LEAST_0, "ac.gamma": UNIT, "ac.lam": UNIT,
    "ac.actor_layers": AT_LEAST_0, "ac.critic_layers": AT_LEAST_0,
    "ac.actor_lr": POSITIVE, "ac.critic_lr": POSITIVE, "ac.actor_grad_mix": UNIT,
    "ac.actor_min_std": AT_LEAST_0, "ac.entropy": AT_LEAST_0, "ac.slow_critic_every": AT_LEAST_1,
    "ac.eps": POSITIVE, "ac.clip": POSITIVE, "ac.weight_decay": AT_LEAST_0,
    "proto.prototypes": AT_LEAST_1, "proto.dim": AT_LEAST_1, "proto.temperature": POSITIVE,
    "proto.sinkhorn_eps": POSITIVE, "proto.sinkhorn_iters": AT_LEAST_1,
    "proto.warm_up": AT_LEAST_0, "proto.freeze_updates": AT_LEAST_0, "proto.ema_fraction": UNIT,
    "proto.shift": AT_LEAST_0, "proto.swav_scale": AT_LEAST_0, "proto.temp_scale": AT_LEAST_0,
    "proto.norm_scale": AT_LEAST_0,
}


def check(config) -> None:
    """Raise ConfigError for the first conflict between the family's keys, or with
    ``train``'s (a built config's every value is already in its range)."""
    _check_horizon(config)
    _check_starts(config)
    if hasattr(config, "proto"):
        _check_warm_up(config)
    _check_gate_objective(config)
    if config.ac.memoryless_starts and not config.ac.memoryless:
        raise ConfigError("ac.memoryless_starts=true without ac.memoryless; valid: "
                          "ac.memoryless=true with it (the control that acts and imagines from "
                          "each observation alone), or ac.memoryless_starts=false")


def _check_warm_up(config) -> None:
    if config.proto.warm_up >= config.train.length:
        raise ConfigError(f"config key 'proto.warm_up' got {config.proto.warm_up}, which leaves "
                          f"no step of a train.length={config.train.length} sequence to the "
                          f"prototype losses; valid: < train.length")


def _check_horizon(config) -> None:
    if config.ac.alignment == "release" and config.ac.horizon < 2:
        raise ConfigError(f"config key 'ac.horizon' got {config.ac.horizon} with "
                          "ac.alignment=release, which imagines horizon - 1 steps; valid: >= 2 "
                          "(or ac.alignment=next_state)")


def _check_starts(config) -> None:
    """``ac.starts`` draws from the posteriors that
    :func:`vsgjax.agents.dreamer.behaviour.start_states` gives."""
    train = config.train
    drop_last = config.wm.discount_head and config.ac.alignment == "release"
    available = train.batch * (train.length - drop_last)
    if config.ac.starts > available:
        dropped = " minus its last step (a discount head)" if drop_last else ""
        raise ConfigError(
            f"config key 'ac.starts' got {config.ac.starts}, more than the {available} posterior "
            f"states of an update (train.batch={train.batch} x train.length={train.length}"
            f"{dropped}); valid: 0 (every one) to {available}")


def _check_gate_objective(config) -> None:
    """A gate objective other than the release's needs a model with gates; GateL0RD's gate
    has no fixed bias (vsgjax/agents/dreamer/gate_objectives.py)."""
    objective, model = config.wm.gate_objective, config.model
    if objective != "release" and config.agent not in gated_models():
        raise ConfigError(f"wm.gate_objective={objective} needs a model with gates; model "
                          f"{config.agent!r} has none; valid: the gated models "
                          f"({', '.join(gated_models())}), or wm.gate_objective=release")
    default_bias = ModelConfig().gate_bias
    if objective == "gatel0rd" and model.gate_bias != default_bias:
        raise ConfigError(f"model.gate_bias={model.gate_bias} with wm.gate_objective=gatel0rd, "
                          "whose ReTanh gate has no fixed bias (GateL0RD's gate is a dense "
                          f"layer with a learned bias); valid: model.gate_bias={default_bias} "
                          "(not read by gatel0rd), or another wm.gate_objective")
