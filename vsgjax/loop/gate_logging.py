"""The gate statistics of a training run's logs: ``gates/*`` lines in ``metrics.jsonl`` (and
TensorBoard), once per log, for the agents with gates (:attr:`logs_gates`: VSG, SVSG, VSGPro).

At every log each seed's current state (the one its checkpoint of that step holds) goes
through the agent's ``gate_summary(state, batch)`` on a batch of its training data, which for
the Dreamer family is ``vsgjax.gate_statistics(vsgjax.load(logdir).params, batch).summary()``.
The host loop uses its latest training batch, the device loop a batch it samples from its
replay (:func:`probe_key`). The cost is one posterior and one open-loop prior pass of one
batch per log, outside the update.

A line holds every key of ``GateStatistics.summary()``, those that show holding included: the
closed runs' mean, 90th percentile and max against the geometric null of the same open rate,
GateL0RD's three rates, and ``gates/holding_<gap>`` for each gap of ``HOLDING_GAPS`` (5, 10,
20, 50 steps) that fits ``train.length`` and for the task's ``memory_gap`` if it names one
(MemoryChain's L; with ``gates/written_and_held_<L>``, the units written at the cue and held to
the query, where an episode fits the window), every null counting the batch's episode starts,
and, where the batch shows episode starts, the gate probability at episode step 1 (MemoryChain's
cue) against the other steps. The gate objective's own loss and value are the
update's metrics (``train/wm/gate_*``), not these.
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
