"""The saved form of a run config (a run directory's ``config.json`` and every checkpoint's
meta): a versioned JSON object, the old versions migrated when read, and the comparison that
tells whether a log directory holds the run a config describes.

Version 2, written by :func:`to_dict`: ``version``, ``agent``, ``domain``, ``size``,
``precision``, the agent's own sections (its registry entry's ``sections``), ``env`` and
``train``. Version 1 (no ``version`` key) held every agent's sections side by side, the agent's
name in ``model.name`` and the precision in ``model.precision``; :func:`migrate` turns it into
version 2 by moving those two to the top level and dropping the sections the agent does not
read (which it never read: a DrQ-v2 run's ``model``, ``wm``, ``ac``, ``optim``, ``proto``).
"""

from __future__ import annotations

import dataclasses

from vsgjax.config.schema import (
    TOP_LEVEL,
    Config,
    ConfigError,
    apply_values,
    config_class,
    default_config,
    sections_of,
)
from vsgjax.registry.agents import AGENTS, agent_entry

VERSION = 2
# The keys a run may change when it resumes: how far it trains, and how often it is logged,
# evaluated, checkpointed and filmed, and over how many devices its batch is split. Every other
# key (train.seed, the model, the env, the data and the train ratio) makes it another run.
RESUMABLE_KEYS = ("train.steps", "train.log_every", "train.eval_every", "train.eval_episodes",
                  "train.ckpt_every", "train.video_every", "train.devices")


def to_dict(config: Config) -> dict:
    """The JSON-serialisable saved form: the version, the top-level fields, the agent's
    sections, env and train."""
    sections = {name: dataclasses.asdict(getattr(config, name))
                for name in sections_of(type(config))}
    return {"version": VERSION, **{name: getattr(config, name) for name in TOP_LEVEL},
            **sections}


def from_dict(data: dict) -> Config:
    """Inverse of :func:`to_dict`, for every saved version (:func:`migrate`); rejects unknown
    keys like :func:`~vsgjax.config.schema.apply_values`."""
    data = migrate(data)
    top = {k: v for k, v in data.items() if not isinstance(v, dict) and k != "version"}
    unknown = set(top) - set(TOP_LEVEL)
    if unknown:
        raise ConfigError(f"unknown top-level config keys {sorted(unknown)}; valid: "
                          f"{', '.join(TOP_LEVEL)}")
    agent = top.pop("agent", None)
    if agent is None:
        raise ConfigError(f"a saved config of format version {VERSION} without 'agent'")
    config_type = config_class(agent)
    sections = {k: v for k, v in data.items() if isinstance(v, dict)}
    foreign = set(sections) - set(sections_of(config_type))
    if foreign:
        readers = {name: [a for a, e in AGENTS.items() if name in e.sections] for name in foreign}
        raise ConfigError(f"config sections {sorted(foreign)} are not read by model "
                          f"{agent!r}; read by: {readers}")
    values = {f"{s}.{k}": v for s, part in sections.items() for k, v in part.items()}
    return apply_values(config_type(**top), values)


def migrate(data: dict) -> dict:
    """A saved config of any version as version 2; ConfigError naming the version found when
    it is not one this code reads."""
    version = data.get("version", 1)
    if version == VERSION:
        return data
    model = data.get("model")
    if version != 1 or not isinstance(model, dict) or "name" not in model:
        found = "1 without model.name" if version == 1 else repr(version)
        raise ConfigError(f"a saved config of format version {found} cannot be migrated; "
                          f"valid: version {VERSION}, or version 1 (no 'version' key, the model's "
                          "name in model.name)")
    model = dict(model)
    agent = model.pop("name")
    precision = model.pop("precision", Config.precision)
    try:
        reads = agent_entry(agent).sections
    except ValueError as error:
        raise ConfigError(f"a saved config of format version 1: {error}") from None
    top = {k: v for k, v in data.items() if not isinstance(v, dict)}
    sections = {k: (model if k == "model" else v) for k, v in data.items()
                if isinstance(v, dict) and (k in reads or k in ("env", "train"))}
    return {"version": VERSION, **top, "agent": agent, "precision": precision, **sections}


def config_changes(saved: dict, current: dict) -> list[str]:
    """``key: saved -> current`` for every key but :data:`RESUMABLE_KEYS` where two saved
    configs (any version: both are migrated) differ ([] when they agree): what makes a log
    directory hold another run than ``current``."""
    saved, current = migrate(saved), migrate(current)
    changed = [f"{key}: {saved.get(key)!r} -> {current.get(key)!r}"
               for key in sorted(set(current) | set(saved))
               if not isinstance(current.get(key, saved.get(key)), dict)
               and key != "version" and saved.get(key) != current.get(key)]
    old_defaults, new_defaults = _defaults(saved), _defaults(current)
    for section in sorted(k for k in set(current) | set(saved)
                          if isinstance(current.get(k, saved.get(k)), dict)):
        # a key a saved config predates counts as its default (e.g. wm.encoder)
        new = {**new_defaults.get(section, {}), **current.get(section, {})}
        old = {**old_defaults.get(section, {}), **saved.get(section, {})}
        changed += [f"{section}.{key}: {old.get(key)!r} -> {new.get(key)!r}"
                    for key in sorted(set(new) | set(old))
                    if old.get(key) != new.get(key) and f"{section}.{key}" not in RESUMABLE_KEYS]
    return changed


def _defaults(data: dict) -> dict:
    """The saved form of the defaults of a saved config's agent ({} for an unknown one)."""
    agent = data.get("agent")
    return to_dict(default_config(agent)) if agent in AGENTS else {}
