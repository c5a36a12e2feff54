"""The fully jitted training loop of on-device (MJX) tasks: ``train.loop=device``.

MJX tasks never terminate and share one time limit, so the N envs of a run live their episodes
in lockstep, and one call of the compiled :meth:`DeviceProgram.episode` is one episode of all N
envs, with the updates due at the train ratio inside it (no host boundary anywhere)::

    reset N envs -> [ train_every x (policy -> env step -> record) -> sample -> update ] x U
                 -> (E mod train_every more steps) -> store the N episodes in the replay

E = ceil(time_limit / action_repeat) agent steps per episode, U = E // train_every updates per
episode (the release's ratio, rounded down per episode when train_every does not divide E).
While prefilling, the same call acts randomly and makes no update (``train=False``).

The replay is a ring of whole episodes in device memory, ``[M, N, E + 1, ...]`` (M = the
episode batches that ``train.replay_capacity`` steps hold): a sequence of ``train.length``
steps is cut from one stored episode at a uniform start, so it never crosses an episode
boundary, and only finished episodes are sampled (as the host replay). Records follow the
host format: step 0 is the reset observation (``is_first``, zero action and reward), step t
holds the observation that action t - 1 led to.

Everything a run needs to continue is one pytree (:class:`LoopState`: agent state, env states,
replay, PRNG key), which the checkpoint holds whole. Several seeds vmap the whole loop
(:func:`vsgjax.loop.parallel.seed_batched`); :mod:`vsgjax.loop.device_trainer` drives it.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp

from vsgjax.config import Config
from vsgjax.data.collect import acting_policy
from vsgjax.envs import EnvSpec
from vsgjax.keys import VECTOR_KEY
from vsgjax.model.agent import Agent, AgentState


class DeviceReplay(NamedTuple):
    """A ring of ``M`` episode batches ``[M, N, E + 1, ...]``; ``stored`` counts batches."""

    data: dict[str, jax.Array]
    stored: jax.Array


class LoopState(NamedTuple):
    """One seed's whole training state (a pytree; checkpointed whole)."""

    agent: AgentState
    replay: DeviceReplay
    key: jax.Array


@dataclass(frozen=True)
class DeviceProgram:
    """The compiled collection-and-update program of one MJX task and config (jit-static)."""

    config: Config
    task: Any  # vsgjax.envs.mjx.MjxTask (hashable)

    @functools.cached_property
    def agent(self) -> Agent:
        return Agent(self.config, {VECTOR_KEY: (self.obs_dim,)}, self.task.action_dim, False)

    @property
    def obs_dim(self) -> int:
        return sum(shape[0] for shape, _ in self.task.observation_spec().values())

    @property
    def episode_steps(self) -> int:
        """E: agent steps per episode (the last one may repeat the action fewer times)."""
        return math.ceil(self.task.time_limit / self.task.action_repeat)

    @property
    def updates_per_episode(self) -> int:
        return self.episode_steps // self.config.train.train_every

    @property
    def replay_episodes(self) -> int:
        """M: the episode batches of N envs that ``train.replay_capacity`` steps hold."""
        per_batch = self.config.env.num_envs * (self.episode_steps + 1)
        return max(1, self.config.train.replay_capacity // per_batch)

    def check(self) -> None:
        """Raise for a config this loop cannot run, naming the value."""
        train, steps = self.config.train, self.episode_steps + 1
        if train.length > steps:
            raise ValueError(f"train.length={train.length} is longer than an episode of "
                             f"{self.task.name} ({steps} stored steps); valid: <= {steps}")

    # --- state ---------------------------------------------------------------------------------

    def init(self, key: jax.Array) -> LoopState:
        """Fresh agent (``agent.init(key)``, as the host loop), an empty replay, the loop key."""
        agent_state = self.agent.init(key)
        m, n, t = self.replay_episodes, self.config.env.num_envs, self.episode_steps + 1
        shapes = {VECTOR_KEY: ((self.obs_dim,), jnp.float32),
                  "action": ((self.task.action_dim,), jnp.float32),
                  "reward": ((), jnp.float32), "is_first": ((), jnp.bool_),
                  "is_terminal": ((), jnp.bool_)}
        data = {k: jnp.zeros((m, n, t, *shape), dtype) for k, (shape, dtype) in shapes.items()}
        return LoopState(agent_state, DeviceReplay(data, jnp.zeros((), jnp.int32)),
                         jax.random.fold_in(key, 1))

    # --- one episode -------------------------------------------------------------------------

    def _policy(self, mode: str):
        spec = EnvSpec((self.obs_dim,), self.task.action_dim, False)
        return acting_policy(self.agent, spec, mode)

    def _observation(self, envs) -> dict[str, jax.Array]:
        return {VECTOR_KEY: self.task.flat_obs(envs.obs), "is_first": envs.is_first}

    def _record(self, envs, action) -> dict[str, jax.Array]:
        return {VECTOR_KEY: self.task.flat_obs(envs.obs), "action": action,
                "reward": envs.reward, "is_first": envs.is_first,
                "is_terminal": envs.is_terminal}

    def _steps(self, params, explore, mode, carry, keys):
        """``len(keys)`` agent steps of every env; returns the carry and ``[steps, N]`` records."""
        policy = self._policy(mode)

        def step(carry, key):
            envs, policy_carry = carry
            policy_carry, action = policy((params, explore), policy_carry,
                                          self._observation(envs), key)
            envs = jax.vmap(self.task.step)(envs, action)
            return (envs, policy_carry), self._record(envs, action)

        return jax.lax.scan(step, carry, keys)

    def _reset(self, count: int, key: jax.Array):
        """``count`` fresh envs and their reset record ``[1, N]``, and a fresh policy carry."""
        envs = jax.vmap(self.task.reset)(jax.random.split(key, count))
        first = self._record(envs, jnp.zeros((count, self.task.action_dim), jnp.float32))
        return envs, self.agent.initial_carry(count), jax.tree.map(lambda x: x[None], first)

    def sample(self, replay: DeviceReplay, key: jax.Array) -> dict[str, jax.Array]:
        """``train.batch`` sequences of ``train.length`` steps, each from one stored episode."""
        train = self.config.train
        m_key, n_key, s_key = jax.random.split(key, 3)
        m, n, t = replay.data["reward"].shape
        episode = jax.random.randint(m_key, (train.batch,), 0, jnp.minimum(replay.stored, m))
        env = jax.random.randint(n_key, (train.batch,), 0, n)
        start = jax.random.randint(s_key, (train.batch,), 0, t - train.length + 1)
        times = start[:, None] + jnp.arange(train.length)
        return {k: v[episode[:, None], env[:, None], times] for k, v in replay.data.items()}

    def _update(self, state: LoopState, key: jax.Array) -> tuple[LoopState, dict]:
        sample_key, update_key = jax.random.split(key)
        batch = self.sample(state.replay, sample_key)
        agent_state, metrics = self.agent.train_step(state.agent, batch, update_key)
        return state._replace(agent=agent_state), metrics

    def episode(self, state: LoopState, train: bool) -> tuple[LoopState, dict, dict]:
        """One episode of every env (random actions and no update unless ``train``).

        Returns the new state, the updates' metrics ``[U]`` (empty without ``train``) and the
        episode records ``[N, E + 1]`` (also stored in the replay).
        """
        keys = jax.random.split(state.key, 3 + self.updates_per_episode)
        key, reset_key, tail_key, block_keys = keys[0], keys[1], keys[2], keys[3:]
        state = state._replace(key=key)
        explore = jnp.asarray(not train)
        every = self.config.train.train_every
        envs, carry, first = self._reset(self.config.env.num_envs, reset_key)

        def block(loop, block_key):
            state, carry = loop
            step_key, update_key = jax.random.split(block_key)
            carry, records = self._steps(state.agent.params, explore, "train", carry,
                                         jax.random.split(step_key, every))
            metrics = {}
            if train:
                state, metrics = self._update(state, update_key)
            return (state, carry), (records, metrics)

        (state, carry), (blocks, metrics) = jax.lax.scan(block, (state, (envs, carry)),
                                                         block_keys)
        tail = self.episode_steps - self.updates_per_episode * every
        _, rest = self._steps(state.agent.params, explore, "train", carry,
                              jax.random.split(tail_key, tail))
        records = jax.tree.map(
            lambda a, b, c: jnp.concatenate([a, b.reshape(-1, *b.shape[2:]), c]),
            first, blocks, rest)
        records = jax.tree.map(lambda x: jnp.swapaxes(x, 0, 1), records)  # [N, E + 1]
        return state._replace(replay=self._store(state.replay, records)), metrics, records

    def _store(self, replay: DeviceReplay, records: dict) -> DeviceReplay:
        slot = replay.stored % replay.data["reward"].shape[0]
        data = {k: v.at[slot].set(records[k]) for k, v in replay.data.items()}
        return DeviceReplay(data, replay.stored + 1)

    def pretrain(self, state: LoopState, updates: int) -> tuple[LoopState, dict]:
        """``updates`` updates in a row (the release's pretraining when prefill ends)."""
        keys = jax.random.split(state.key, updates + 1)
        state, metrics = jax.lax.scan(self._update, state._replace(key=keys[0]), keys[1:])
        return state, metrics

    def evaluate(self, params: dict, key: jax.Array, episodes: int) -> dict:
        """``episodes`` episodes in parallel with the actor's mode -> returns ``[episodes]``."""
        reset_key, step_key = jax.random.split(key)
        envs, carry, _ = self._reset(episodes, reset_key)
        _, records = self._steps(params, jnp.asarray(False), "eval", (envs, carry),
                                 jax.random.split(step_key, self.episode_steps))
        return {"return": records["reward"].sum(0)}
