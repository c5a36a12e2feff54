"""The config's schema: frozen (hashable, jit-static) dataclasses, the valid names of the
string keys, and dotted ``section.key`` overrides with their types checked.

A run config is an instance of its agent's class (:func:`config_class`): the fields every
agent has (``agent``, ``domain``, ``size``, ``precision``, and the ``env`` and ``train``
sections), and the sections of the agent's own settings module (its registry entry's
``settings`` and ``sections``: ``model``, ``wm``, ``ac``, ... for the Dreamer family, ``drq``
for DrQ-v2). The saved form is :mod:`vsgjax.config.saved`'s.
"""

from __future__ import annotations

import importlib
import math
import types
import typing
from collections.abc import Sequence
from dataclasses import dataclass, field, fields, is_dataclass, make_dataclass, replace

from vsgjax.registry.agents import DEFAULT_MODEL, AgentEntry, agent_entry
from vsgjax.registry.names import did_you_mean
from vsgjax.registry.tasks import DEFAULT_TASK, family_of

SIZES = ("paper", "small", "cpu", "debug")
PRECISIONS = ("float32", "bfloat16")  # precision: the dtype of matmuls and convolutions
LOOPS = ("auto", "host", "device")  # train.loop: see vsgjax/loop/device_program.py
# env.background: see vsgjax/envs/backgrounds.py
BACKGROUNDS = ("none", "video", "dots", "noise", "color")
# String keys every agent has whose values are names from a fixed list (an agent's settings
# module adds its own in ``CHOICES``).
CHOICES = {"precision": PRECISIONS, "train.loop": LOOPS, "env.background": BACKGROUNDS}
# Top-level fields that the command line sets under a dotted key of their own.
DOTTED_FIELDS = {"model.precision": "precision"}
TOP_LEVEL = ("agent", "domain", "size", "precision")


class ConfigError(ValueError):
    """A malformed configuration: unknown name or key, a value of the wrong type or out of its
    range, or a command-line value or run directory that does not fit the run."""


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
    """What every run config holds; a run config is an instance of its agent's subclass
    (:func:`config_class`, :func:`default_config`), which adds the agent's sections."""

    agent: str = DEFAULT_MODEL
    domain: str = family_of(DEFAULT_TASK).preset_column
    size: str = "paper"
    # dtype of the matmuls and convolutions (parameters, optimizer state, distributions, losses
    # and returns stay float32); the command line's `model.precision`; `python -m vsgjax.train`
    # picks bfloat16 for `paper` on a GPU
    precision: str = "float32"
    env: EnvConfig = field(default_factory=EnvConfig)
    train: TrainConfig = field(default_factory=TrainConfig)

    def __post_init__(self):
        if type(self) is not _CLASSES.get(self.agent):
            raise ConfigError(f"a config of agent {self.agent!r} is built by "
                              f"config_class({self.agent!r}) (or default_config), not "
                              f"{type(self).__qualname__}")

    def __reduce__(self):
        # the agents' classes are built at run time: a pickle holds the agent's name and the
        # field values, and rebuilds the class from the registry
        values = {f.name: getattr(self, f.name) for f in fields(self) if f.name != "agent"}
        return _rebuild, (self.agent, values)


def _rebuild(agent: str, values: dict) -> Config:
    return config_class(agent)(**values)


SHARED_SECTIONS = {"env": EnvConfig, "train": TrainConfig}


def settings_of(agent: str) -> types.ModuleType:
    """The settings module of an agent (its registry entry's ``settings``): ``SECTIONS``
    (name -> dataclass), ``RANGES``, and optionally ``CHOICES`` and ``check(config)``."""
    return config_class(agent).settings


def config_class(agent: str) -> type[Config]:
    """The run config class of an agent, by its ``--model`` name (:func:`class_for_entry`)."""
    try:
        entry = agent_entry(agent)
    except ValueError as error:
        raise ConfigError(str(error)) from None
    return class_for_entry(entry)


_CLASSES: dict[str, type[Config]] = {}  # built once per agent, so that equal configs hash equal


def class_for_entry(entry: AgentEntry) -> type[Config]:
    """The run config class of an agent's registry entry: :class:`Config` and the sections the
    entry reads, from its settings module, which the class keeps as ``settings``."""
    if entry.name not in _CLASSES:
        tables = importlib.import_module(entry.settings)
        missing = [name for name in entry.sections if name not in tables.SECTIONS]
        if missing:
            raise ConfigError(f"model {entry.name!r} reads sections {missing} that its settings "
                              f"module {entry.settings} lacks; valid: "
                              f"{', '.join(tables.SECTIONS)}")
        own = [(name, tables.SECTIONS[name], field(default_factory=tables.SECTIONS[name]))
               for name in entry.sections]
        _CLASSES[entry.name] = make_dataclass(
            f"Config[{entry.name}]", [("agent", str, field(default=entry.name)), *own],
            bases=(Config,), frozen=True, namespace={"settings": tables})
    return _CLASSES[entry.name]


def default_config(agent: str = DEFAULT_MODEL, **top) -> Config:
    """The config of an agent with every default (``top``: other top-level fields)."""
    return config_class(agent)(**top)


def sections_of(config_type: type[Config]) -> dict[str, type]:
    """``name: dataclass`` of every section of a config class: its agent's, then env and
    train."""
    own = {f.name: f.type for f in fields(config_type)
           if isinstance(f.type, type) and is_dataclass(f.type)}
    return {**own, **SHARED_SECTIONS}


def choices_of(config_type: type[Config]) -> dict[str, tuple[str, ...]]:
    """The fixed-list string keys of an agent's config class: every agent's and its own."""
    return {**CHOICES, **getattr(config_type.settings, "CHOICES", {})}


def parse_overrides(overrides: Sequence[str], config_type: type[Config]) -> dict:
    """Command-line style ``section.key=value`` strings -> ``{key: value}`` (values parsed by
    the key's type in ``config_type``; unknown keys and a key given twice are errors)."""
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
        values[key] = _parse(key, text.strip(), _split_key(key, config_type)[2])
    return values


def apply_overrides(config: Config, overrides: Sequence[str]) -> Config:
    """Apply command-line style ``section.key=value`` strings (values parsed by field type)."""
    return apply_values(config, parse_overrides(overrides, type(config)))


def apply_values(config: Config, values: dict) -> Config:
    """Apply a dict of dotted keys to typed values, checking every key and type."""
    choices = choices_of(type(config))
    for key, value in values.items():
        section, name, kind = _split_key(key, type(config))
        value = _coerce(key, value, kind)
        listed = choices.get(name if section is None else key)
        if listed and value not in listed:
            raise ConfigError(f"config key {key!r} got {value!r}; valid: {', '.join(listed)}")
        if section is None:
            config = replace(config, **{name: value})
        else:
            config = replace(config, **{section: replace(getattr(config, section),
                                                         **{name: value})})
    return config


def _split_key(key: str, config_type: type[Config]) -> tuple[str | None, str, type]:
    """``(section, field, the field's type)`` of a dotted key; ``(None, field, type)`` for a
    top-level field set under a dotted key (:data:`DOTTED_FIELDS`)."""
    if key in DOTTED_FIELDS:
        name = DOTTED_FIELDS[key]
        return None, name, typing.get_type_hints(Config)[name]
    sections = sections_of(config_type)
    section, sep, name = key.partition(".")
    if not sep or section not in sections:
        hint = did_you_mean(key, [f"{s}.{name}" for s in sections]) if sep else ""
        raise ConfigError(f"unknown config key {key!r}{hint}; sections: {', '.join(sections)}")
    valid = [f.name for f in fields(sections[section])]
    if name not in valid:
        hint = did_you_mean(name, valid).replace("'", f"'{section}.", 1)
        raise ConfigError(f"unknown config key {key!r}{hint}; valid keys of {section!r}: "
                          f"{', '.join(valid)}")
    return section, name, typing.get_type_hints(sections[section])[name]


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
