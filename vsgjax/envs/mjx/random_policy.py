"""The reference every MJX learning curve is read against: a uniform random policy's return."""

from __future__ import annotations

import functools
import math

import jax
import jax.numpy as jnp

from vsgjax.envs.mjx.core import MjxTask


@functools.partial(jax.jit, static_argnums=(0, 1))
def random_returns(task: MjxTask, episodes: int, key: jax.Array) -> jax.Array:
    """Returns ``[episodes]`` of whole episodes (``task.time_limit`` env steps) under actions
    drawn uniformly from [-1, 1]^A at every agent step, the envs reset from ``split(key)``."""
    reset_key, action_key = jax.random.split(key)
    states = jax.vmap(task.reset)(jax.random.split(reset_key, episodes))

    def step(states, key):
        actions = jax.random.uniform(key, (episodes, task.action_dim), jnp.float32, -1.0, 1.0)
        states = jax.vmap(task.step)(states, actions)
        return states, states.reward

    agent_steps = math.ceil(task.time_limit / task.action_repeat)
    _, rewards = jax.lax.scan(step, states, jax.random.split(action_key, agent_steps))
    return rewards.sum(0)
