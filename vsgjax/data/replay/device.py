"""The device loop's replay: a ring of whole episodes in device memory, pure JAX.

``[M, N, T, ...]`` per key (M batches of N envs' rows of T stored steps each: one episode of
E + 1 steps, or K episodes back to back for a family whose sequences cross episodes,
:mod:`vsgjax.loop.device_program`); a window is cut from one stored row at a uniform start, so
it never crosses a row (with one episode a row, never an episode boundary; across K episodes,
``is_first`` marks where one starts), and only finished rows are sampled (as the host replay
samples finished episodes, :mod:`vsgjax.data.replay.buffer`).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp


class DeviceReplay(NamedTuple):
    """A ring of ``M`` episode batches ``[M, N, E + 1, ...]``; ``stored`` counts batches."""

    data: dict[str, jax.Array]
    stored: jax.Array


def empty_replay(shapes: dict[str, tuple[tuple[int, ...], jnp.dtype]], episodes: int,
                 envs: int, steps: int) -> DeviceReplay:
    """Zeros for ``episodes`` batches of ``envs`` episodes of ``steps`` stored steps, for
    ``shapes``: ``{key: (per-step shape, dtype)}``."""
    data = {k: jnp.zeros((episodes, envs, steps, *shape), dtype)
            for k, (shape, dtype) in shapes.items()}
    return DeviceReplay(data, jnp.zeros((), jnp.int32))


def sample_windows(replay: DeviceReplay, key: jax.Array, batch: int, length: int,
                   history: int = 0) -> dict[str, jax.Array]:
    """``batch`` windows ``[batch, history + length, ...]``, each from one stored episode:
    ``length`` steps from a uniform start, after ``history`` steps edge-padded with the
    episode's first (frame stacking)."""
    m_key, n_key, s_key = jax.random.split(key, 3)
    m, n, t = replay.data["reward"].shape
    episode = jax.random.randint(m_key, (batch,), 0, jnp.minimum(replay.stored, m))
    env = jax.random.randint(n_key, (batch,), 0, n)
    start = jax.random.randint(s_key, (batch,), 0, t - length + 1)
    times = jnp.maximum(start[:, None] + jnp.arange(-history, length), 0)
    return {k: v[episode[:, None], env[:, None], times] for k, v in replay.data.items()}


def store_episodes(replay: DeviceReplay, records: dict) -> DeviceReplay:
    """The replay with one batch of episodes ``[N, E + 1, ...]`` written over the oldest."""
    slot = replay.stored % replay.data["reward"].shape[0]
    data = {k: v.at[slot].set(records[k]) for k, v in replay.data.items()}
    return DeviceReplay(data, replay.stored + 1)
