"""Configuration: frozen (hashable, jit-static) dataclasses, presets and dotted overrides.

A config is built from three names and a list of overrides::

    make_config(task="bbs_basic", model="vsg", size="small", overrides=["wm.kl_scale=0.3"])

* the *domain* (``bbs``, ``dmc``, ``atari``) comes from the task name's prefix and selects the
  column of the paper's hyperparameter table (docs/models.md);
* the *model* (a name of :data:`vsgjax.registry.agents.MODELS`) selects the agent, its
  latent dynamics and its model-specific defaults;
* the *size* (``paper``, ``small``, ``cpu``, ``debug``) scales the networks: ``paper`` is the
  table, ``small`` is CPU-friendly (smaller networks, and batch 8 x 32 every 2 agent steps so
  that a small CPU updates about once a second), ``cpu`` learns the ``mjx_`` tasks (vector
  observations) on a CPU, ``debug`` is for tests.

Unknown names, unknown keys, values of the wrong type and values out of their range
(:mod:`vsgjax.config.checks`) are errors that name the bad value and list what is valid.

The package: :mod:`~vsgjax.config.schema` (the dataclasses, overrides, the saved form),
:mod:`~vsgjax.config.checks` (the valid ranges), :mod:`~vsgjax.config.presets` (the presets and
:func:`make_config`).
"""

from vsgjax.config.checks import RANGES, check_config
from vsgjax.config.presets import VECTOR_SIZES, make_config, preset_column
from vsgjax.config.schema import (
    ACTOR_GRADS,
    ALIGNMENTS,
    CHOICES,
    ENCODERS,
    EPS_PLACEMENTS,
    GATE_OBJECTIVES,
    LOOPS,
    PRECISIONS,
    RESUMABLE_KEYS,
    SIZES,
    WEIGHT_DECAYS,
    BehaviourConfig,
    Config,
    ConfigError,
    DrQConfig,
    EnvConfig,
    ModelConfig,
    OptimConfig,
    PrototypeConfig,
    TrainConfig,
    WorldModelConfig,
    apply_overrides,
    apply_values,
    config_changes,
    from_dict,
    to_dict,
)
from vsgjax.registry.agents import MODELS
from vsgjax.registry.tasks import PRESET_COLUMNS as DOMAINS

__all__ = [
    "ACTOR_GRADS", "ALIGNMENTS", "CHOICES", "DOMAINS", "ENCODERS", "EPS_PLACEMENTS",
    "GATE_OBJECTIVES", "LOOPS", "MODELS", "PRECISIONS", "RANGES", "RESUMABLE_KEYS", "SIZES",
    "VECTOR_SIZES",
    "WEIGHT_DECAYS", "BehaviourConfig", "Config", "ConfigError", "DrQConfig", "EnvConfig",
    "ModelConfig", "OptimConfig", "PrototypeConfig", "TrainConfig", "WorldModelConfig",
    "apply_overrides", "apply_values",
    "check_config", "config_changes", "from_dict", "make_config", "preset_column", "to_dict",
]
