"""The gate statistics of a training run's logs: ``gates/*`` lines in ``metrics.jsonl`` (and
TensorBoard), once per log, for the agents with gates (:attr:`logs_gates`: VSG, SVSG).

At every log each seed's current state (the one its checkpoint of that step holds) goes
through the agent's ``gate_summary(state, batch)`` on a batch of its training data, which for
the Dreamer family is ``vsgjax.gate_statistics(vsgjax.load(logdir).params, batch).summary()``.
The host loop uses its latest training batch, the device loop a batch it samples from its
replay (:func:`probe_key`). The cost is one posterior and one open-loop prior pass of one
batch per log, outside the update.
"""

from __future__ import annotations

import jax

PROBE_STREAM = 1  # fold_in(seed key, step) is the device loop's evaluation key; this is apart


def logs_gates(agent) -> bool:
    """Whether the agent has gates to log (an agent with gates offers ``gate_summary``)."""
    return getattr(agent, "gated", False)


def probe_key(seed: int, env_steps: int) -> jax.Array:
    """The key the device loop samples the batch of its ``gates/*`` line at ``env_steps`` with."""
    step_key = jax.random.fold_in(jax.random.PRNGKey(seed), env_steps)
    return jax.random.fold_in(step_key, PROBE_STREAM)
