""":func:`make_config`: a run config from a task, a model, a size and overrides.

The task and the model are resolved once, in their registries, and their entries passed down:
the presets (:mod:`vsgjax.config.presets`) check that the agent fits the task and reads the
keys given and layer the agent's presets; the schema (:mod:`vsgjax.config.schema`) builds the
agent's config class and applies the layers and the overrides; the checks
(:mod:`vsgjax.config.checks`) check every value.
"""

from __future__ import annotations

from collections.abc import Sequence

from vsgjax.config.checks import check_config
from vsgjax.config.presets import check_agent_fits, check_keys_for, check_size, preset_layers
from vsgjax.config.schema import (
    Config,
    ConfigError,
    EnvConfig,
    apply_values,
    class_for_entry,
    parse_overrides,
)
from vsgjax.registry.agents import DEFAULT_MODEL, agent_entry
from vsgjax.registry.tasks import DEFAULT_TASK, TaskError, family_of


def make_config(
    task: str = DEFAULT_TASK,
    model: str = DEFAULT_MODEL,
    size: str = "paper",
    overrides: Sequence[str] = (),
) -> Config:
    """Resolve presets for (task's column, model, size), then apply ``key=value`` overrides;
    every value is checked (:mod:`vsgjax.config.checks`)."""
    try:
        family = family_of(task)
        entry = agent_entry(model)
    except (TaskError, ValueError) as error:
        raise ConfigError(str(error)) from None
    check_size(size)
    check_agent_fits(entry, family, task, size)
    check_keys_for(entry, [item.partition("=")[0].strip() for item in overrides if "=" in item])
    layers = preset_layers(entry, family, task, size)
    config_type = class_for_entry(entry)
    config = config_type(domain=family.preset_column, size=size, env=EnvConfig(task=task))
    for layer in layers:
        config = apply_values(config, layer)
    config = apply_values(config, parse_overrides(overrides, config_type))
    check_config(config, family)
    return config
