"""The valid values of a built config: a range for every numeric key, and the checks between
keys and against the task (a sequence must fit in an episode of the task).

:func:`check_config` runs at the end of :func:`~vsgjax.config.make.make_config`, so a bad
value stops a run before it writes anything; the error names the key, the value and what is
valid.
``train.devices`` is checked against the devices JAX sees when training starts
(:func:`vsgjax.loop.parallel.resolve_devices`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

from vsgjax.config.schema import Config, ConfigError, EnvConfig
from vsgjax.registry import resolve
from vsgjax.registry.tasks import FAMILIES, TaskFamily, family_of

# Seeds up to 2**30 leave room below 2**31 for the evaluation envs' offset and the env index.
MAX_SEED = 2**30
MIN_LENGTH = 2  # a training sequence needs one transition for the dynamics to learn from


@dataclass(frozen=True)
class Range:
    """Numbers from ``low`` to ``high`` (None: unbounded), each end included unless open."""

    low: float | None = None
    high: float | None = None
    open_low: bool = False
    open_high: bool = False

    def __contains__(self, value: float) -> bool:
        if not math.isfinite(value):
            return False
        above = self.low is None or (value > self.low if self.open_low else value >= self.low)
        below = self.high is None or (value < self.high if self.open_high else value <= self.high)
        return above and below

    def __str__(self) -> str:
        if self.high is None:
            return "any finite number" if self.low is None else (
                f"{'>' if self.open_low else '>='} {_number(self.low)}")
        left, right = "(" if self.open_low else "[", ")" if self.open_high else "]"
        return f"{left}{_number(self.low)}, {_number(self.high)}{right}"


def _number(value: float) -> str:
    return str(int(value)) if float(value).is_integer() else f"{value:g}"


AT_LEAST_0, AT_LEAST_1, POSITIVE = Range(0), Range(1), Range(0, open_low=True)
UNIT, OPEN_UNIT = Range(0, 1), Range(0, 1, open_low=True, open_high=True)

# The ranges of the keys every agent has; an agent's settings module holds its own.
RANGES = {
    "env.action_repeat": AT_LEAST_1, "env.time_limit": AT_LEAST_1, "env.image_size": AT_LEAST_1,
    "env.sticky": UNIT, "env.num_envs": AT_LEAST_1, "env.eval_envs": AT_LEAST_1,
    "env.flicker": Range(0, 1, open_high=True), "env.show_steps": AT_LEAST_0,
    "env.noise_dims": AT_LEAST_0, "env.noise_scale": AT_LEAST_0, "env.memory_length": AT_LEAST_1,
    "train.seed": Range(0, MAX_SEED), "train.steps": AT_LEAST_1, "train.batch": AT_LEAST_1,
    "train.length": Range(MIN_LENGTH), "train.train_every": AT_LEAST_1,
    "train.prefill": AT_LEAST_0, "train.replay_capacity": AT_LEAST_1,
    "train.pretrain": AT_LEAST_0, "train.eval_every": AT_LEAST_1,
    "train.eval_episodes": AT_LEAST_1, "train.log_every": AT_LEAST_1,
    "train.ckpt_every": AT_LEAST_1, "train.video_every": AT_LEAST_1,
}
# Numeric keys checked elsewhere (when the devices are known).
CHECKED_AT_START = ("train.devices",)
ATARI_OPTIONS = ("env.grayscale", "env.sticky")
BACKGROUND_OPTIONS = ("env.background", "env.background_dir")


def check_config(config: Config, family: TaskFamily | None = None) -> None:
    """Raise ConfigError for the first value out of its range or in conflict with the task,
    then run the agent's own checks (its settings module's ``check``). ``family``: the task's
    family where the caller has resolved it (default: looked up from ``config.env.task``)."""
    family = family_of(config.env.task) if family is None else family
    settings = type(config).settings
    ranges = {**RANGES, **settings.RANGES}
    for key, value in numeric_values(config).items():
        if key in ranges and value not in ranges[key]:
            finite = "" if math.isfinite(value) else ", which is not a finite number"
            raise ConfigError(f"config key {key!r} got {value!r}{finite}; valid: {ranges[key]}")
    _check_sequences(config, family)
    _check_atari_options(config, family)
    _check_background_options(config, family)
    _check_family_options(config, family)
    if hasattr(settings, "check"):
        settings.check(config)


def numeric_values(config: Config) -> dict[str, float]:
    """``section.key: value`` of every int and float of a config."""
    values = {}
    for section in fields(config):
        part = getattr(config, section.name)
        if not hasattr(part, "__dataclass_fields__"):
            continue
        for item in fields(part):
            value = getattr(part, item.name)
            if isinstance(value, int | float) and not isinstance(value, bool):
                values[f"{section.name}.{item.name}"] = value
    return values


def max_episode_steps(config: Config) -> int:
    """The most steps an episode of the task stores (agent steps + the first observation).

    BringBackShapes truncates after ``time_limit + 2`` physics sub-steps (bbs/env.py; its
    family's ``extra_steps``); the other families after ``time_limit`` env steps (DeepMind
    Control may end sooner, at its own limit); an agent step is ``action_repeat`` of them.
    """
    return _episode_steps(config.env, family_of(config.env.task))


def _episode_steps(env: EnvConfig, family: TaskFamily) -> int:
    return math.ceil((env.time_limit + family.extra_steps) / env.action_repeat) + 1


def _check_sequences(config: Config, family: TaskFamily) -> None:
    train, steps = config.train, _episode_steps(config.env, family)
    if train.length > steps and not family.windows_cross_episodes:  # the family checks its own
        raise ConfigError(
            f"train.length={train.length} is longer than an episode of {config.env.task} can be "
            f"({steps} stored steps with env.time_limit={config.env.time_limit} and "
            f"env.action_repeat={config.env.action_repeat}); valid: <= {steps}")
    if train.replay_capacity < train.length:
        raise ConfigError(f"train.replay_capacity={train.replay_capacity} holds no sequence "
                          f"of train.length={train.length} steps; valid: >= {train.length}")
    most = train.replay_capacity // train.length
    if train.batch > most:
        raise ConfigError(f"train.batch={train.batch} sequences of train.length={train.length} "
                          f"steps are more steps than the replay ever holds "
                          f"(train.replay_capacity={train.replay_capacity}); valid: "
                          f"train.batch <= {most}")


def _check_atari_options(config: Config, family: TaskFamily) -> None:
    if family.grayscale_sticky:
        return
    for key in ATARI_OPTIONS:
        section, name = key.split(".")
        value = getattr(getattr(config, section), name)
        if value:
            off = False if isinstance(value, bool) else 0
            raise ConfigError(f"{key}={value} is an Atari option; valid for task "
                              f"{config.env.task!r}: {key}={off}")


def _check_family_options(config: Config, family: TaskFamily) -> None:
    """A family's own options (its ``options``) keep their defaults on every other family's
    tasks; then the task's family checks its options (its ``check``)."""
    env, defaults = config.env, EnvConfig()
    for owner in FAMILIES.values():
        if owner is family:
            continue
        for key in owner.options:
            name = key.partition(".")[2]
            value, default = getattr(env, name), getattr(defaults, name)
            if value != default and key not in family.options:
                raise ConfigError(f"{key}={value!r} is an option of the {owner.pattern} tasks; "
                                  f"valid for task {env.task!r}: {key}={default!r}")
    if family.check:
        resolve(family.check)(config)


def _check_background_options(config: Config, family: TaskFamily) -> None:
    """The backgrounds are DMC's; ``video`` needs ``env.background_dir`` (whether it holds two
    videos or more is checked where the env is built, and by ``vsgjax.train`` first, which also
    decodes the first frame of every one: :func:`vsgjax.envs.backgrounds.check_videos`)."""
    env, defaults = config.env, EnvConfig()
    if not family.backgrounds:
        for key in BACKGROUND_OPTIONS:
            name = key.partition(".")[2]
            value, default = getattr(env, name), getattr(defaults, name)
            if value != default:
                patterns = ", ".join(f.pattern for f in FAMILIES.values() if f.backgrounds)
                raise ConfigError(f"{key}={value!r} is an option of the {patterns} tasks; valid "
                                  f"for task {env.task!r}: {key}={default!r}")
        return
    if env.background == "video":
        if not env.background_dir:
            raise ConfigError("env.background=video without env.background_dir; valid: "
                              "env.background_dir=<a folder of at least 2 video files>")
    elif env.background_dir:
        raise ConfigError(f"env.background_dir={env.background_dir!r} with env.background="
                          f"{env.background!r}; valid: env.background_dir='' (the folder is read "
                          "only with env.background=video)")
