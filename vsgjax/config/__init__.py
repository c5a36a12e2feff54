"""Configuration: frozen (hashable, jit-static) dataclasses, presets and dotted overrides.

A config is built from three names and a list of overrides::

    make_config(task="bbs_basic", model="vsg", size="small", overrides=["wm.kl_scale=0.3"])

* the *domain* (``bbs``, ``dmc``, ``atari``) comes from the task name's prefix and selects the
  column of the paper's hyperparameter table (docs/models.md);
* the *model* (a name of :data:`vsgjax.registry.agents.MODELS`) selects the agent and the
  config's class: the fields every agent has (``agent``, ``domain``, ``size``, ``precision``,
  ``env``, ``train``) and the sections the agent's own settings module defines
  (``vsgjax/agents/<family>/settings.py``), and its model-specific defaults;
* the *size* (``paper``, ``small``, ``cpu``, ``debug``) scales the networks: ``paper`` is the
  table, ``small`` is CPU-friendly (smaller networks, and batch 8 x 32 every 2 agent steps so
  that a small CPU updates about once a second), ``cpu`` learns the ``mjx_`` tasks (vector
  observations) on a CPU, ``debug`` is for tests.

Unknown names, unknown keys, values of the wrong type and values out of their range
(:mod:`vsgjax.config.checks`) are errors that name the bad value and list what is valid.

The package: :mod:`~vsgjax.config.schema` (the shared dataclasses, the agents' config classes,
overrides), :mod:`~vsgjax.config.saved` (the saved form, its versions, the comparison on
resume), :mod:`~vsgjax.config.checks` (the valid ranges), :mod:`~vsgjax.config.presets` (the
presets and whether an agent fits a task), :mod:`~vsgjax.config.make` (:func:`make_config`:
the names resolved once and their entries passed down). No module here imports an agent: an
agent's sections, ranges, checks and presets live in its package and are found through its
registry entry.
"""

from vsgjax.config.checks import RANGES, check_config
from vsgjax.config.make import make_config
from vsgjax.config.presets import VECTOR_SIZES, preset_column
from vsgjax.config.saved import RESUMABLE_KEYS, config_changes, from_dict, migrate, to_dict
from vsgjax.config.schema import (
    BACKGROUNDS,
    CHOICES,
    LOOPS,
    PRECISIONS,
    SIZES,
    Config,
    ConfigError,
    EnvConfig,
    TrainConfig,
    apply_overrides,
    apply_values,
    config_class,
    default_config,
    settings_of,
)
from vsgjax.registry.agents import MODELS
from vsgjax.registry.tasks import PRESET_COLUMNS as DOMAINS

__all__ = [
    "BACKGROUNDS", "CHOICES", "DOMAINS", "LOOPS", "MODELS", "PRECISIONS", "RANGES",
    "RESUMABLE_KEYS", "SIZES", "VECTOR_SIZES", "Config", "ConfigError", "EnvConfig",
    "TrainConfig", "apply_overrides", "apply_values", "check_config", "config_changes",
    "config_class", "default_config", "from_dict", "make_config", "migrate", "preset_column",
    "settings_of", "to_dict",
]
