"""gymnax's JAX environments as an on-device family (``gymnax_<env>``): bsuite's MemoryChain.

``gymnax_memory_len`` is bsuite's ``memory_len`` experiment (``MemoryChain`` with one context
bit) in gymnax's JAX port, with the memory length L as the option ``env.memory_length``
(L >= 1; gymnax's default 5). An episode is L + 1 agent steps, and it terminates:

* the observation is ``[countdown, query, context]`` (3 floats; the key ``observation``):
  ``countdown = 1 - t / L``, ``context`` = ±1 only at t = 0, ``query`` = 0 always (one context
  bit: the query is its index). As in bsuite and gymnax, step t returns the observation *of
  time t - 1* (computed before the step advances time), so the context is seen twice (the
  reset observation and the first step's) and the last observation shows ``countdown = 0``.
* actions are 2 (one-hot for the agent, its argmax for the env); the reward is 0 at steps
  1, ..., L and ±1 at step L + 1 (+1 when the action equals the context bit); step L + 1 is
  terminal.

gymnax keeps bsuite's layout as a flat ``[3]`` vector where bsuite's numpy environment gives
``[1, 3]``; the values, rewards and episode ends are the same for the same context and actions
(``tests/envs/test_gymnax_tasks.py`` steps both). Only ``memory_len`` is wired: the device loop
runs the N envs of a run in lockstep, which needs episodes of one fixed length, and MemoryChain
is gymnax's only such task with a memory gap; a gymnax env whose episodes vary in length
(CartPole, the MinAtar games) needs per-env resets inside the loop (docs/mjx.md).

The interface the device loop steps is :mod:`vsgjax.envs.device_task`; this module is the
family's registry entry (:mod:`vsgjax.registry.tasks`): ``parse``, ``build`` and ``check``.
"""

from __future__ import annotations

import dataclasses
import functools
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp

from vsgjax.config.schema import ConfigError
from vsgjax.envs.spec import one_of

OBS_KEY = "observation"  # gymnax's flat observation [countdown, query, context]
ENVS = ("memory_len",)  # the gymnax_<env> names wired so far


class GymnaxState(NamedTuple):
    """One env's state after reset or an agent step (a pytree; batch it with vmap).

    ``env``: gymnax's own state; ``obs``: ``{"observation": [3]}``; ``reward`` of this step (0
    after reset); ``is_last`` and ``is_terminal`` set together at step L + 1; ``key``: the
    env's key stream (a caller's next reset takes it, as for MJX).
    """

    env: Any
    obs: dict[str, jax.Array]
    reward: jax.Array
    is_first: jax.Array
    is_last: jax.Array
    is_terminal: jax.Array
    key: jax.Array


@functools.cache
def _memory_chain():
    from gymnax.environments.bsuite import MemoryChain

    return MemoryChain(num_bits=1)


@dataclasses.dataclass(frozen=True)
class MemoryChainTask:
    """bsuite's ``memory_len`` at memory length ``memory_length`` (see the module doc); frozen
    and hashable, a static argument of ``jax.jit`` as the MJX tasks are."""

    memory_length: int = 5

    def __post_init__(self):
        if self.memory_length < 1:
            raise ConfigError(f"env.memory_length={self.memory_length}; valid: >= 1 (agent "
                              "steps between the context and the query)")

    name = "gymnax_memory_len"
    action_dim = 2
    discrete = True
    action_repeat = 1
    obs_keys = (OBS_KEY,)

    @property
    def episode_steps(self) -> int:
        """L + 1: every episode terminates at this agent step."""
        return self.memory_length + 1

    @property
    def memory_gap(self) -> int:
        """L: the context is stored at agent step 1 (the gate of step 1 sees the reset
        observation) and asked for at step L + 1."""
        return self.memory_length

    def _params(self):
        env = _memory_chain()
        return env.default_params.replace(memory_length=self.memory_length)

    def observation_spec(self) -> dict[str, tuple[tuple[int, ...], Any]]:
        return {OBS_KEY: ((3,), jnp.float32)}

    def flat_obs(self, obs: dict[str, jax.Array]) -> jax.Array:
        return obs[OBS_KEY]

    def reset(self, key: jax.Array) -> GymnaxState:
        """A new episode: a uniform context bit from ``key``."""
        key, reset_key = jax.random.split(key)
        obs, env_state = _memory_chain().reset_env(reset_key, self._params())
        false = jnp.zeros((), bool)
        return GymnaxState(env_state, {OBS_KEY: obs}, jnp.zeros((), jnp.float32),
                           jnp.ones((), bool), false, false, key)

    def step(self, state: GymnaxState, action: jax.Array) -> GymnaxState:
        """One agent step with a one-hot ``action`` [2] (its argmax is the env's action)."""
        key, step_key = jax.random.split(state.key)
        obs, env_state, reward, done, _ = _memory_chain().step_env(
            step_key, state.env, jnp.argmax(action, -1), self._params())
        done = jnp.asarray(done, bool)
        return GymnaxState(env_state, {OBS_KEY: obs}, jnp.asarray(reward, jnp.float32),
                           jnp.zeros((), bool), done, done, key)


# --- the family's registry entry -----------------------------------------------------------

def parse(task: str, rest: str) -> tuple[str]:
    """``gymnax_<env>`` -> ``(env,)``; TaskError listing the wired envs otherwise."""
    return (one_of(task, rest, ENVS, "gymnax env"),)


def build(env_cfg) -> MemoryChainTask:
    """The device task of an env config (``env.memory_length``)."""
    return MemoryChainTask(env_cfg.memory_length)


def check(config) -> None:
    """Refuse a config under which the task runs differently from bsuite's, or cannot be
    learned; each error names the key, the value and what is valid."""
    env, length = config.env, config.env.memory_length
    if config.train.loop == "host":
        raise ConfigError(f"train.loop=host for {env.task!r}: the gymnax tasks step only inside "
                          "the compiled device loop; valid: train.loop=device or auto")
    if env.action_repeat != 1:
        raise ConfigError(f"env.action_repeat={env.action_repeat} for {env.task!r}, whose steps "
                          "are bsuite's decisions (one per observation); valid: 1")
    if env.time_limit < length + 1:
        raise ConfigError(f"env.time_limit={env.time_limit} ends an episode of {env.task!r} "
                          f"with env.memory_length={length} before its reward at step "
                          f"{length + 1}; valid: >= {length + 1}")
    if config.train.length < length + 1:
        raise ConfigError(
            f"train.length={config.train.length} with env.memory_length={length}: the context "
            f"is shown at the first two stored steps of an episode and decides the reward "
            f"{length} steps after the second, so a training sequence needs {length + 1} steps "
            f"to hold both and the world model could never learn the reward from the context "
            f"(the device loop does not carry the latent state across sequences); valid: "
            f"train.length >= {length + 1}, or env.memory_length <= "
            f"{config.train.length - 1}")
