"""The fully jitted training loop of on-device tasks: ``train.loop=device``.

The tasks of an on-device family (:mod:`vsgjax.envs.device_task`: MJX, gymnax) end every
episode at the same agent step E (``task.episode_steps``: MJX's time limit, MemoryChain's
L + 1), so the N envs of a run live their episodes in lockstep. One call of the compiled
:meth:`DeviceProgram.episode` is K consecutive episodes of all N envs (K E agent steps), with
the updates due at the train ratio inside it (no host boundary anywhere)::

    reset N envs -> [ train_every x (restart ended envs -> policy -> env step -> record)
                      -> sample -> update ] x U
                 -> (K E mod train_every more steps) -> store the N rows of K episodes

U = K E // train_every updates per call (the release's ratio, rounded down per call when
train_every does not divide K E). While prefilling, the same call acts randomly and makes no
update (``train=False``).

K = 1 for a family whose training sequences fit in one episode (MJX: ``train.length`` <= E + 1
is required), whose call has no restart step. A family whose episodes end before a sequence is
full (its registry entry's ``windows_cross_episodes``: MemoryChain's L + 1 steps) takes the
fewest K that hold a sequence and an update, K = max(ceil(train.length / (E + 1)),
ceil(train_every / E)): an env whose episode ended restarts inside the call (``reset`` with
its state's key), a replay row holds its K episodes back to back, and a sequence is cut
anywhere in it, across episode boundaries, where ``is_first`` resets the latent state in the
world model's observe pass and the policy's carry (DreamerV3's replay of a continuous stream,
cut into rows).

The replay is a ring of such rows in device memory (:mod:`vsgjax.data.replay.device`;
M = the row batches that ``train.replay_capacity`` steps hold), from which each update
samples the windows its agent asks for (:attr:`~vsgjax.agents.interface.Agent.replay`).
Records follow the host format: step 0 of an episode is the reset observation (``is_first``,
zero action and reward), step t holds the observation that action t - 1 led to.

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
import numpy as np

from vsgjax.agents import make_agent
from vsgjax.agents.acting import acting_policy
from vsgjax.agents.interface import Agent
from vsgjax.config import Config
from vsgjax.data.replay.device import (
    DeviceReplay,
    empty_replay,
    sample_windows,
    store_episodes,
)
from vsgjax.envs import EnvSpec
from vsgjax.episode_keys import VECTOR_KEY
from vsgjax.loop.driver import FirstUpdate
from vsgjax.registry.tasks import family_of


class LoopState(NamedTuple):
    """One seed's whole training state (a pytree; checkpointed whole)."""

    agent: Any  # the agent's state
    replay: DeviceReplay
    key: jax.Array


@dataclass(frozen=True)
class DeviceProgram:
    """The compiled collection-and-update program of one device task and config
    (jit-static)."""

    config: Config
    task: Any  # a vsgjax.envs.device_task.DeviceTask (hashable)

    @functools.cached_property
    def agent(self) -> Agent:
        return make_agent(self.config, self.spec)

    @property
    def spec(self) -> EnvSpec:
        return EnvSpec({VECTOR_KEY: (self.obs_dim,)}, self.task.action_dim, self.task.discrete)

    @property
    def obs_dim(self) -> int:
        return sum(shape[0] for shape, _ in self.task.observation_spec().values())

    @property
    def episode_steps(self) -> int:
        """E: agent steps per episode."""
        return self.task.episode_steps

    @property
    def episodes_per_call(self) -> int:
        """K: 1, or for a family whose sequences cross episodes, the fewest episodes of a row
        that hold one training sequence and one update (see the module doc)."""
        if not family_of(self.config.env.task).windows_cross_episodes:
            return 1
        steps = self.episode_steps
        return max(1, math.ceil(self.agent.replay.length / (steps + 1)),
                   math.ceil(self.config.train.train_every / steps))

    @property
    def row_steps(self) -> int:
        """The stored steps of one env's replay row: K episodes of E + 1."""
        return self.episodes_per_call * (self.episode_steps + 1)

    @property
    def updates_per_episode(self) -> int:
        """E // train_every: the updates of a one-episode call (K = 1)."""
        return self.episode_steps // self.config.train.train_every

    @property
    def agent_steps_per_call(self) -> int:
        return self.episodes_per_call * self.episode_steps

    @property
    def updates_per_call(self) -> int:
        """One update per ``train_every`` agent steps of a call (rounded down per call)."""
        return self.agent_steps_per_call // self.config.train.train_every

    @property
    def replay_episodes(self) -> int:
        """M: the row batches of N envs that ``train.replay_capacity`` steps hold."""
        per_batch = self.config.env.num_envs * self.row_steps
        return max(1, self.config.train.replay_capacity // per_batch)

    def check(self) -> None:
        """Raise for a config this loop cannot run, naming the value."""
        length, steps = self.agent.replay.length, self.row_steps
        history = self.agent.replay.history
        if history and self.episodes_per_call > 1:
            raise ValueError(f"the agent stacks {history} past frames per step, which would "
                             f"reach across the episodes of a replay row of {self.task.name}; "
                             "valid: an agent without frame stacking (the Dreamer family)")
        if length > steps:
            raise ValueError(f"the agent's updates sample {length} steps (train.length for the "
                             f"Dreamer family), longer than an episode of {self.task.name} "
                             f"({steps} stored steps); valid: <= {steps}")
        every = self.config.train.train_every
        if every > self.agent_steps_per_call:
            raise ValueError(f"train.train_every={every} is longer than an episode of "
                             f"{self.task.name} ({self.episode_steps} agent steps), inside which "
                             f"the device loop makes its updates: it would make none; valid: "
                             f"<= {self.episode_steps}")

    @property
    def env_steps_per_call(self) -> int:
        return self.config.env.num_envs * self.agent_steps_per_call * self.task.action_repeat

    def first_update(self) -> FirstUpdate:
        """The first training call is the first to start once prefill has ended and the
        replay holds an episode batch to sample; its first update comes ``train_every`` agent
        steps into it (or at its start, pretraining)."""
        per_call, train = self.env_steps_per_call, self.config.train
        start = max(1, -(-train.prefill // per_call)) * per_call
        into = 0 if train.pretrain else (self.config.env.num_envs * train.train_every
                                         * self.task.action_repeat)
        why = (f"the first training call starts at env step {start}, after prefill "
               f"(train.prefill={train.prefill}) in whole calls of {per_call} env steps "
               f"(env.num_envs={self.config.env.num_envs} x {self.episodes_per_call} episodes "
               f"of {self.episode_steps} agent steps)")
        return FirstUpdate(start + into, start + 1, why)

    # --- state ---------------------------------------------------------------------------------

    def init(self, key: jax.Array) -> LoopState:
        """Fresh agent (``agent.init(key)``, as the host loop), an empty replay, the loop key."""
        agent_state = self.agent.init(key)
        m, n, t = self.replay_episodes, self.config.env.num_envs, self.row_steps
        shapes = {VECTOR_KEY: ((self.obs_dim,), jnp.float32),
                  "action": ((self.task.action_dim,), jnp.float32),
                  "reward": ((), jnp.float32), "is_first": ((), jnp.bool_),
                  "is_terminal": ((), jnp.bool_)}
        return LoopState(agent_state, empty_replay(shapes, m, n, t),
                         jax.random.fold_in(key, 1))

    # --- one episode -------------------------------------------------------------------------

    def _policy(self, mode: str):
        return acting_policy(self.agent, mode)

    def _observation(self, envs) -> dict[str, jax.Array]:
        return {VECTOR_KEY: self.task.flat_obs(envs.obs), "is_first": envs.is_first}

    def _record(self, envs, action) -> dict[str, jax.Array]:
        return {VECTOR_KEY: self.task.flat_obs(envs.obs), "action": action,
                "reward": envs.reward, "is_first": envs.is_first,
                "is_terminal": envs.is_terminal}

    def _steps(self, params, explore, mode, carry, keys, restarts: bool = False):
        """``len(keys)`` agent steps of every env; returns the carry and ``[steps, N]`` records.

        ``restarts``: an env whose episode ended (``is_last``) first restarts (``reset`` with
        its state's ``key``), and each step's records are the pair (the restart's reset record,
        which is meaningful only after an episode's end, the step's record)."""
        policy = self._policy(mode)

        def step(carry, key):
            envs, policy_carry = carry
            if restarts:
                envs, fresh = self._restart_ended(envs)
            policy_carry, action = policy((params, explore), policy_carry,
                                          self._observation(envs), key)
            envs = jax.vmap(self.task.step)(envs, action)
            record = self._record(envs, action)
            return (envs, policy_carry), ((fresh, record) if restarts else record)

        return jax.lax.scan(step, carry, keys)

    def _restart_ended(self, envs):
        """The envs with every ended episode replaced by a fresh one, and their reset
        records ``[N]``."""
        fresh = jax.vmap(self.task.reset)(envs.key)
        ended = envs.is_last

        def pick(new, old):
            return jnp.where(ended.reshape(ended.shape + (1,) * (old.ndim - 1)), new, old)

        envs = jax.tree.map(pick, fresh, envs)
        count = ended.shape[0]
        return envs, self._record(envs, jnp.zeros((count, self.task.action_dim), jnp.float32))

    def _reset(self, count: int, key: jax.Array):
        """``count`` fresh envs and their reset record ``[1, N]``, and a fresh policy carry."""
        envs = jax.vmap(self.task.reset)(jax.random.split(key, count))
        first = self._record(envs, jnp.zeros((count, self.task.action_dim), jnp.float32))
        return envs, self.agent.initial_carry(count), jax.tree.map(lambda x: x[None], first)

    def sample(self, replay: DeviceReplay, key: jax.Array) -> dict[str, jax.Array]:
        """``train.batch`` windows of what the agent samples (:attr:`Agent.replay`)."""
        length, history = self.agent.replay
        return sample_windows(replay, key, self.config.train.batch, length, history)

    def _update(self, state: LoopState, key: jax.Array) -> tuple[LoopState, dict]:
        sample_key, update_key = jax.random.split(key)
        batch = self.sample(state.replay, sample_key)
        agent_state, metrics = self.agent.train_step(state.agent, batch, update_key)
        return state._replace(agent=agent_state), metrics

    def episode(self, state: LoopState, train: bool) -> tuple[LoopState, dict, dict]:
        """One call: K episodes of every env (random actions and no update unless ``train``).

        Returns the new state, the updates' metrics ``[updates_per_call]`` (empty without
        ``train``) and the records ``[N, K (E + 1)]``, each env's K episodes back to back
        (also stored in the replay as one row per env).
        """
        keys = jax.random.split(state.key, 3 + self.updates_per_call)
        key, reset_key, tail_key, block_keys = keys[0], keys[1], keys[2], keys[3:]
        state = state._replace(key=key)
        explore = jnp.asarray(not train)
        every, restarts = self.config.train.train_every, self.episodes_per_call > 1
        envs, carry, first = self._reset(self.config.env.num_envs, reset_key)

        def block(loop, block_key):
            state, carry = loop
            step_key, update_key = jax.random.split(block_key)
            carry, records = self._steps(self.agent.acting_params(state.agent), explore,
                                         "train", carry,
                                         jax.random.split(step_key, every), restarts)
            metrics = {}
            if train:
                state, metrics = self._update(state, update_key)
            return (state, carry), (records, metrics)

        (state, carry), (blocks, metrics) = jax.lax.scan(block, (state, (envs, carry)),
                                                         block_keys)
        tail = self.agent_steps_per_call - self.updates_per_call * every
        _, rest = self._steps(self.agent.acting_params(state.agent), explore, "train", carry,
                              jax.random.split(tail_key, tail), restarts)
        steps = jax.tree.map(lambda b, c: jnp.concatenate([b.reshape(-1, *b.shape[2:]), c]),
                             blocks, rest)
        records = self._row(first, steps) if restarts else jax.tree.map(
            lambda a, b: jnp.concatenate([a, b]), first, steps)
        records = jax.tree.map(lambda x: jnp.swapaxes(x, 0, 1), records)  # [N, K (E + 1)]
        return state._replace(replay=store_episodes(state.replay, records)), metrics, records

    def _row(self, first: dict, steps: tuple[dict, dict]) -> dict:
        """The records ``[K (E + 1), N]`` of K episodes in a row, from the first reset record
        ``[1, N]`` and the (reset, step) record pairs ``[K E, N]`` of :meth:`_steps`: each
        episode's E step records, and the reset record of the step after an episode's end."""
        fresh, stepped = steps
        e, k = self.episode_steps, self.episodes_per_call
        order = [0]
        for episode in range(k):
            if episode:  # the restart before agent step episode * E
                order.append(1 + k * e + episode * e)
            order.extend(1 + episode * e + i for i in range(e))
        index = np.asarray(order)
        return jax.tree.map(lambda a, b, c: jnp.concatenate([a, b, c])[index],
                            first, stepped, fresh)

    def pretrain(self, state: LoopState, updates: int) -> tuple[LoopState, dict]:
        """``updates`` updates in a row (the release's pretraining when prefill ends)."""
        keys = jax.random.split(state.key, updates + 1)
        state, metrics = jax.lax.scan(self._update, state._replace(key=keys[0]), keys[1:])
        return state, metrics

    def evaluate(self, agent_state, key: jax.Array, episodes: int) -> dict:
        """``episodes`` episodes in parallel acting in ``eval`` mode -> ``{"return":
        [episodes]}``, and for an agent with the ``open_loop_errors`` hook its open-loop errors
        on those episodes, ``"open_loop": {"obs_mse": [H], "reward_mse": [H]}`` (computed here,
        so only the 2 x H numbers leave the device; key ``fold_in(key, 1)``)."""
        steps, records = self._eval_steps(agent_state, key, episodes)
        out = {"return": steps["reward"].sum(0)}
        errors = getattr(self.agent, "open_loop_errors", None)
        if errors is not None:
            result = errors(agent_state, records, jax.random.fold_in(key, 1))
            if result is not None:
                out["open_loop"] = result
        return out

    def eval_records(self, agent_state, key: jax.Array, episodes: int) -> dict:
        """The records ``[episodes, E + 1]`` of :meth:`evaluate`'s episodes (the host format:
        the reset step first), for the same key."""
        return self._eval_steps(agent_state, key, episodes)[1]

    def _eval_steps(self, agent_state, key: jax.Array, episodes: int) -> tuple[dict, dict]:
        """(the steps' records ``[E, episodes]``, the episodes' records ``[episodes, E + 1]``)."""
        params = self.agent.acting_params(agent_state)
        reset_key, step_key = jax.random.split(key)
        envs, carry, first = self._reset(episodes, reset_key)
        _, steps = self._steps(params, jnp.asarray(False), "eval", (envs, carry),
                               jax.random.split(step_key, self.episode_steps))
        records = jax.tree.map(lambda a, b: jnp.swapaxes(jnp.concatenate([a, b]), 0, 1),
                               first, steps)
        return steps, records
