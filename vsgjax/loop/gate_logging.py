"""The gate statistics of a training run's logs: ``gates/*`` lines in ``metrics.jsonl`` (and
TensorBoard), once per log, for the gated models (VSG, SVSG).

At every log each seed's current world model (the params its checkpoint of that step holds)
goes through :func:`vsgjax.gate_statistics` on a batch of its training data (with its default
key), so that ``vsgjax.gate_statistics(vsgjax.load(logdir).params, batch).summary()`` is the
logged line.
The host loop uses its latest training batch, the device loop a batch it samples from its
replay (:func:`probe_key`). The cost is one posterior and one open-loop prior pass of one
batch per log, outside the update.
"""

from __future__ import annotations

import jax

from vsgjax.config import Config
from vsgjax.model.gate_statistics import GATED_MODELS, gate_statistics

PROBE_STREAM = 1  # fold_in(seed key, step) is the device loop's evaluation key; this is apart


def logs_gates(config: Config) -> bool:
    """Whether the run's model has gates to log."""
    return config.model.name in GATED_MODELS


def gate_summary(config: Config, wm_params: dict, batch: dict) -> dict[str, float]:
    """The ``gates/*`` scalars of world model ``wm_params`` on a ``[B, T]`` ``batch``."""
    return gate_statistics(wm_params, batch, config=config).summary()


def probe_key(seed: int, env_steps: int) -> jax.Array:
    """The key the device loop samples the batch of its ``gates/*`` line at ``env_steps`` with."""
    step_key = jax.random.fold_in(jax.random.PRNGKey(seed), env_steps)
    return jax.random.fold_in(step_key, PROBE_STREAM)
