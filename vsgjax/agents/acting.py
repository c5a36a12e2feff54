"""Collection policies over any agent (:mod:`vsgjax.agents.interface`), for both loops: pure
JAX, so the host loop's collector jits them and the device loop compiles them into its program.

A policy is ``policy(inputs, carry, obs, key) -> (carry, action [N, A])``.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp

Policy = Callable[[Any, Any, dict, jax.Array], tuple[Any, jax.Array]]


def random_policy(space) -> Policy:
    """Uniform random actions in the agent's format (one-hot if discrete) for an action space
    with ``.action_dim`` and ``.discrete`` (an env spec or an agent); carry unused."""

    def policy(params, carry, obs, key):
        n = obs["is_first"].shape[0]
        if space.discrete:
            index = jax.random.randint(key, (n,), 0, space.action_dim)
            return carry, jax.nn.one_hot(index, space.action_dim, dtype=jnp.float32)
        return carry, jax.random.uniform(key, (n, space.action_dim), jnp.float32, -1.0, 1.0)

    return policy


def acting_policy(agent, mode: str) -> Policy:
    """A collection policy over ``(acting params, explore_randomly)``.

    ``explore_randomly`` (a bool scalar) swaps the agent's action for a uniform random one
    (the prefill phase) while the agent's carry still follows the observations, so one
    compiled collector serves prefill and training.
    """
    uniform = random_policy(agent)

    def policy(inputs, carry, obs, key):
        params, explore_randomly = inputs
        agent_key, random_key = jax.random.split(key)
        carry, action = agent.policy_step(params, carry, obs, agent_key, mode=mode)
        _, random_action = uniform(None, None, obs, random_key)
        return carry, jnp.where(explore_randomly, random_action, action)

    return policy
