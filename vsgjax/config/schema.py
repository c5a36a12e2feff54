"""The config's schema: frozen (hashable, jit-static) dataclasses, the valid names of the
string keys, dotted ``section.key`` overrides with their types checked, and the JSON form a run
directory saves."""

from __future__ import annotations

import dataclasses
import math
import types
import typing
from collections.abc import Sequence
from dataclasses import dataclass, field, fields, replace

from vsgjax.registry.agents import DEFAULT_MODEL
from vsgjax.registry.names import did_you_mean
from vsgjax.registry.tasks import DEFAULT_TASK, family_of

SIZES = ("paper", "small", "cpu", "debug")
ALIGNMENTS = ("release", "next_state")  # ac.alignment: see vsgjax/agents/dreamer/behaviour.py
ACTOR_GRADS = ("auto", "dynamics", "reinforce", "both")
# ac.actor_dist: see vsgjax/agents/dreamer/behaviour.py (continuous actions)
ACTOR_DISTS = ("trunc_normal", "tanh_normal")
EPS_PLACEMENTS = ("release", "optax")  # optim.eps_placement: see vsgjax/agents/dreamer/optim.py
WEIGHT_DECAYS = ("release", "adamw")  # optim.weight_decay: see vsgjax/agents/dreamer/optim.py
PRECISIONS = ("float32", "bfloat16")  # model.precision: the dtype of matmuls and convolutions
# wm.encoder: see vsgjax/agents/dreamer/world_model.py (check_encoders)
ENCODERS = ("auto", "cnn", "mlp")
LOOPS = ("auto", "host", "device")  # train.loop: see vsgjax/loop/device_program.py
# env.background: see vsgjax/envs/backgrounds.py
BACKGROUNDS = ("none", "video", "dots", "noise", "color")
# wm.gate_objective: see vsgjax/agents/dreamer/gate_objectives.py
GATE_OBJECTIVES = ("release", "rate", "rate_kl", "gatel0rd")
# String keys whose values are names from a fixed list (checked when a config is built).
CHOICES = {"ac.alignment": ALIGNMENTS, "ac.actor_grad": ACTOR_GRADS, "ac.actor_dist": ACTOR_DISTS,
           "optim.eps_placement": EPS_PLACEMENTS, "optim.weight_decay": WEIGHT_DECAYS,
           "model.precision": PRECISIONS, "train.loop": LOOPS, "wm.encoder": ENCODERS,
           "env.background": BACKGROUNDS, "wm.gate_objective": GATE_OBJECTIVES}


class ConfigError(ValueError):
    """A malformed configuration: unknown name or key, a value of the wrong type or out of its
    range, or a command-line value or run directory that does not fit the run."""


@dataclass(frozen=True)
class ModelConfig:
    """Latent dynamics."""

    name: str = DEFAULT_MODEL
    deter: int = 1024  # deterministic state size (0 for the purely stochastic svsg / ssm)
    hidden: int = 1024  # width of the dense layers inside the dynamics
    stoch: int = 32  # Gaussian dims, or number of categorical variables
    classes: int = 32  # classes per categorical variable; 0 means Gaussian latents
    cell_norm: bool = False  # LayerNorm over the GRU's 3*D pre-activations
    min_std: float = 0.1  # Gaussian std = 2*sigmoid(s/2) + min_std
    gate_mode: str = "sample"  # "sample" (the release: Bernoulli everywhere) or "threshold" (p>0.5)
    gate_bias: float = -1.0  # update-gate bias: p = sigmoid(u + gate_bias)
    # dtype of the matmuls and convolutions (parameters, optimizer state, distributions, losses
    # and returns stay float32); `python -m vsgjax.train` picks bfloat16 for `paper` on a GPU
    precision: str = "float32"


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
class DrQConfig:
    """DrQ-v2, the model-free baseline (facebookresearch/drqv2's ``drqv2.py`` and ``cfgs/``)."""

    feature_dim: int = 50  # the trunk: Linear(repr, 50) -> LayerNorm -> tanh
    hidden: int = 1024  # actor and twin-Q MLP widths
    cnn_depth: int = 32  # channels of the 4 conv layers (pixel observations only)
    frame_stack: int = 3  # frames stacked along channels (pixel observations only)
    nstep: int = 3  # n of the n-step return
    gamma: float = 0.99
    tau: float = 0.01  # Polyak rate of the target critic
    lr: float = 1e-4  # Adam, for encoder, actor and critic
    std_start: float = 1.0  # exploration std: linear from std_start ...
    std_end: float = 0.1  # ... to std_end ...
    std_steps: int = 500_000  # ... over this many agent steps (the task's horizon)
    std_clip: float = 0.3  # the target's and the actor loss's noise clip
    shift_pad: int = 4  # random-shift augmentation: edge-pad by this many pixels, crop back


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


@dataclass(frozen=True)
class EnvConfig:
    task: str = DEFAULT_TASK
    action_repeat: int = 4
    time_limit: int = 3000  # in env steps (physics sub-steps / frames), before action repeat
    image_size: int = 64
    grayscale: bool = False
    sticky: float = 0.0  # Atari sticky-action probability
    num_envs: int = 1
    eval_envs: int = 1
    # Partially observed and noisy variants of device tasks (vsgjax/envs/mjx/variants.py):
    flicker: float = 0.0  # probability that the whole observation is zeros, per agent step
    hide: str = ""  # comma-separated observation keys that are always zero ("velocity")
    show_keys: str = ""  # comma-separated keys zeroed from agent step show_steps on
    show_steps: int = 0  # agent steps show_keys are visible (the reset is step 0); 0 = off
    noise_dims: int = 0  # extra observation dims following Gaussian random walks from 0
    noise_scale: float = 0.1  # the std of the noise dims' increment per agent step
    # gymnax_memory_len (vsgjax/envs/gymnax_tasks.py): agent steps between the context and
    # the query (an episode is memory_length + 1 steps); gymnax's default
    memory_length: int = 5
    # Distracting backgrounds of the dmc_ tasks (vsgjax/envs/backgrounds.py):
    background: str = "none"  # none, video, dots, noise or color
    background_dir: str = ""  # env.background=video: a folder of video files (>= 2)


@dataclass(frozen=True)
class TrainConfig:
    seed: int = 0
    steps: int = 2_500_000  # env steps (counting action repeat)
    batch: int = 16
    length: int = 50
    train_every: int = 5  # agent steps per update
    prefill: int = 10_000  # env steps of random actions before training
    replay_capacity: int = 2_000_000  # in stored steps
    oversample_ends: bool = False
    pretrain: int = 0  # updates made once, right after prefill (before the train ratio applies)
    eval_every: int = 100_000  # env steps; the first evaluation runs when prefill ends
    eval_episodes: int = 10
    log_every: int = 1_000  # env steps
    ckpt_every: int = 1_000  # updates
    video_every: int = 100_000  # env steps; open-loop prediction and eval videos
    devices: int = 0  # devices the batch is sharded over (data parallel); 0: every visible one
    loop: str = "auto"  # "device": the fully jitted loop (mjx_, gymnax_ tasks); "auto": device
    # for them


@dataclass(frozen=True)
class Config:
    domain: str = family_of(DEFAULT_TASK).preset_column
    size: str = "paper"
    model: ModelConfig = field(default_factory=ModelConfig)
    wm: WorldModelConfig = field(default_factory=WorldModelConfig)
    ac: BehaviourConfig = field(default_factory=BehaviourConfig)
    optim: OptimConfig = field(default_factory=OptimConfig)
    drq: DrQConfig = field(default_factory=DrQConfig)
    proto: PrototypeConfig = field(default_factory=PrototypeConfig)
    env: EnvConfig = field(default_factory=EnvConfig)
    train: TrainConfig = field(default_factory=TrainConfig)


def parse_overrides(overrides: Sequence[str]) -> dict:
    """Command-line style ``section.key=value`` strings -> ``{key: value}`` (values parsed by
    the key's type; unknown keys and a key given twice are errors)."""
    values, given = {}, {}
    for item in overrides:
        key, sep, text = item.partition("=")
        key = key.strip()
        if not sep:
            raise ConfigError(f"override {item!r} is not of the form section.key=value")
        if key in given:
            raise ConfigError(f"config key {key!r} is given twice ({given[key]!r} and "
                              f"{item!r}); give it once")
        given[key] = item
        values[key] = _parse(key, text.strip(), _field_type(key))
    return values


def apply_overrides(config: Config, overrides: Sequence[str]) -> Config:
    """Apply command-line style ``section.key=value`` strings (values parsed by field type)."""
    return apply_values(config, parse_overrides(overrides))


def apply_values(config: Config, values: dict) -> Config:
    """Apply a dict of dotted keys to typed values, checking every key and type."""
    for key, value in values.items():
        section, name = _split_key(key)
        kind = _field_type(key)
        value = _coerce(key, value, kind)
        if key in CHOICES and value not in CHOICES[key]:
            raise ConfigError(f"config key {key!r} got {value!r}; valid: {', '.join(CHOICES[key])}")
        config = replace(config, **{section: replace(getattr(config, section), **{name: value})})
    return config


def _sections() -> dict[str, type]:
    hints = typing.get_type_hints(Config)
    return {f.name: hints[f.name] for f in fields(Config)
            if dataclasses.is_dataclass(hints[f.name])}


def _split_key(key: str) -> tuple[str, str]:
    sections = _sections()
    section, sep, name = key.partition(".")
    if not sep or section not in sections:
        hint = did_you_mean(key, [f"{s}.{name}" for s in sections]) if sep else ""
        raise ConfigError(f"unknown config key {key!r}{hint}; sections: {', '.join(sections)}")
    valid = [f.name for f in fields(sections[section])]
    if name not in valid:
        hint = did_you_mean(name, valid).replace("'", f"'{section}.", 1)
        raise ConfigError(f"unknown config key {key!r}{hint}; valid keys of {section!r}: "
                          f"{', '.join(valid)}")
    return section, name


def _field_type(key: str) -> type:
    section, name = _split_key(key)
    return typing.get_type_hints(_sections()[section])[name]


def _parse(key: str, text: str, kind: type):
    if kind is bool:
        lowered = text.lower()
        if lowered in ("true", "1", "yes"):
            return True
        if lowered in ("false", "0", "no"):
            return False
        raise ConfigError(f"config key {key!r} wants a bool (true/false), got {text!r}")
    if kind is int:
        return _parse_int(key, text)
    if kind is float:
        try:
            return float(text)
        except ValueError:
            raise ConfigError(f"config key {key!r} wants a float, got {text!r}") from None
    return text


def _parse_int(key: str, text: str) -> int:
    """An integer written as one (``100000``, ``100_000``); a float's notation is refused,
    naming the integer it stands for when there is one."""
    try:
        return int(text)
    except ValueError:
        pass
    try:
        value = float(text)
    except ValueError:
        raise ConfigError(f"config key {key!r} wants an integer, got {text!r}") from None
    if math.isfinite(value) and value.is_integer():
        raise ConfigError(f"config key {key!r} wants an integer, got {text!r} (a float's "
                          f"notation); write {int(value)}")
    raise ConfigError(f"config key {key!r} wants an integer, got {text!r}")


def _coerce(key: str, value, kind: type):
    if isinstance(kind, types.UnionType):
        raise ConfigError(f"config key {key!r} has an unsupported type {kind}")
    if kind is float and isinstance(value, int) and not isinstance(value, bool):
        return float(value)
    if not isinstance(value, kind) or (kind is int and isinstance(value, bool)):
        raise ConfigError(
            f"config key {key!r} wants {kind.__name__}, got {value!r} ({type(value).__name__})"
        )
    return value


# The keys a run may change when it resumes: how far it trains, and how often it is logged,
# evaluated, checkpointed and filmed, and over how many devices its batch is split. Every other
# key (train.seed, the model, the env, the data and the train ratio) makes it another run.
RESUMABLE_KEYS = ("train.steps", "train.log_every", "train.eval_every", "train.eval_episodes",
                  "train.ckpt_every", "train.video_every", "train.devices")


def config_changes(saved: dict, current: dict) -> list[str]:
    """``section.key: saved -> current`` for every key but :data:`RESUMABLE_KEYS` where two
    :func:`to_dict` configs differ ([] when they agree): what makes a log directory hold
    another run than ``current``."""
    changed, defaults = [], to_dict(Config())
    for section in sorted(set(current) | set(saved)):
        new, old = current.get(section), saved.get(section)
        if isinstance(new, dict) or isinstance(old, dict):
            # a key a saved config predates counts as its default (e.g. wm.encoder)
            section_defaults = defaults.get(section, {})
            new, old = {**section_defaults, **(new or {})}, {**section_defaults, **(old or {})}
            changed += [f"{section}.{key}: {old.get(key)!r} -> {new.get(key)!r}"
                        for key in sorted(set(new) | set(old))
                        if old.get(key) != new.get(key)
                        and f"{section}.{key}" not in RESUMABLE_KEYS]
        elif new != old:
            changed.append(f"{section}: {old!r} -> {new!r}")
    return changed


def to_dict(config: Config) -> dict:
    """A JSON-serialisable nested dict (saved as the run's resolved config)."""
    return dataclasses.asdict(config)


def from_dict(data: dict) -> Config:
    """Inverse of :func:`to_dict`; rejects unknown keys like :func:`apply_values`."""
    top = {k: v for k, v in data.items() if k not in _sections()}
    unknown = set(top) - {"domain", "size"}
    if unknown:
        raise ConfigError(f"unknown top-level config keys {sorted(unknown)}")
    config = Config(**top)
    values = {f"{s}.{k}": v for s in _sections() for k, v in data.get(s, {}).items()}
    return apply_values(config, values)
