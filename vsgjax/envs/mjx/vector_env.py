"""N MJX envs behind gymnasium's vector-env interface, for the host loop (``train.loop=host``).

:class:`MjxVectorEnv` is a ``gymnasium.vector.VectorEnv`` over one :class:`MjxTask` (or any
on-device task, :mod:`vsgjax.envs.device_task`: a discrete one takes ``Discrete(n)`` actions,
as ``python -m vsgjax.evaluate`` runs a ``gymnax_`` checkpoint), so
:class:`vsgjax.data.collect.EnvBatch`, and with it the host loop's collector, trainer and evaluator,
drives MJX tasks as it drives gymnasium envs. Each ``step`` call is one jitted ``vmap`` of
``task.step`` over all N envs (one device call, one transfer each way), not N Python envs.

* Observations: ``{"vector": float32 [N, D]}``, ``task.flat_obs`` of the state (dm_control's
  key order), as the device loop records them.
* Episodes: the task's own action repeat and time limit (``MjxTask.step``); MJX tasks never
  terminate, so every episode is truncated at the limit (``truncated``), exactly the
  episodes of the device loop.
* Autoreset: gymnasium's ``AutoresetMode.NEXT_STEP``, as ``EnvBatch`` expects: the step call
  after an env's episode ended resets that env, ignores its action and returns the new
  episode's first observation with reward 0. The N envs start together and share the time
  limit, so their episodes end at the same step (as in the device loop) and that call is one
  jitted, vmapped reset of all N instead of a step.
* Seeding: env i's first episode is ``task.reset(keys[i])``; every later episode of env i is
  ``task.reset(state.key)`` of its previous episode (the key ``MjxTask.reset`` leaves in the
  state for the next reset), so a batch is a deterministic function of its N start keys.
  :func:`vsgjax.envs.make_envs` (what ``make_env_batch`` builds) starts env i from
  ``jax.random.PRNGKey(seed + i)`` (``+ EVAL_SEED_OFFSET`` for eval envs, the seed ranges of
  the gymnasium tasks); the device loop resets its N envs from ``split(reset_key, N)``, and
  an ``MjxVectorEnv`` built with those keys replays its episodes
  (``tests/loop/test_mjx_host_loop.py``).
  ``reset(seed=s)`` restarts env i from ``PRNGKey(s + i)`` (or ``PRNGKey(s[i])`` for a list);
  ``reset()`` without a seed starts the next episodes of the envs' key streams.
"""

from __future__ import annotations

import functools
from collections.abc import Sequence

import gymnasium
import jax
import jax.numpy as jnp
import numpy as np

from vsgjax.envs.mjx.core import MjxState, MjxTask
from vsgjax.episode_keys import VECTOR_KEY


def seed_keys(seeds: Sequence[int]) -> jax.Array:
    """``[N, 2]`` PRNG keys, ``jax.random.PRNGKey(seed)`` of each seed."""
    return jnp.stack([jax.random.PRNGKey(int(seed)) for seed in seeds])


class MjxVectorEnv(gymnasium.vector.VectorEnv):
    """``len(keys)`` envs of ``task``, stepped by one jitted vmapped call (see the module doc).

    ``keys``: ``[N, 2]`` PRNG keys, env i's first reset key.
    """

    metadata = {"autoreset_mode": gymnasium.vector.AutoresetMode.NEXT_STEP}

    def __init__(self, task: MjxTask, keys: jax.Array):
        keys = jnp.asarray(keys)
        if keys.ndim != 2 or keys.shape[0] < 1 or keys.shape[1] != 2:
            raise ValueError(f"keys must be [N, 2] PRNG keys with N >= 1, got shape "
                             f"{tuple(keys.shape)}")
        self.task, self.num_envs = task, int(keys.shape[0])
        dim = sum(shape[0] for shape, _ in task.observation_spec().values())
        self.single_observation_space = gymnasium.spaces.Dict(
            {VECTOR_KEY: gymnasium.spaces.Box(-np.inf, np.inf, (dim,), np.float32)})
        self.single_action_space = (
            gymnasium.spaces.Discrete(task.action_dim) if task.discrete
            else gymnasium.spaces.Box(-1.0, 1.0, (task.action_dim,), np.float32))
        self.observation_space = gymnasium.vector.utils.batch_space(
            self.single_observation_space, self.num_envs)
        self.action_space = gymnasium.vector.utils.batch_space(self.single_action_space,
                                                               self.num_envs)
        self._start_keys = keys
        self._state: MjxState | None = None
        self._autoreset = False  # every env's episode is over: the next step resets them

    def reset(self, *, seed: int | Sequence[int] | None = None, options: dict | None = None):
        """Start a new episode in every env -> ``({"vector": [N, D]}, {})``."""
        if seed is not None:
            seeds = [seed + i for i in range(self.num_envs)] if isinstance(seed, int) else seed
            if len(seeds) != self.num_envs:
                raise ValueError(f"reset needs one seed per env ({self.num_envs}), got "
                                 f"{len(seeds)}")
            self._start_keys, self._state = seed_keys(seeds), None
        keys = self._start_keys if self._state is None else self._state.key
        self._state, outputs = _reset(self.task, keys)
        self._autoreset = False
        return {VECTOR_KEY: np.asarray(outputs[VECTOR_KEY])}, {}

    def step(self, actions):
        """Step every env (envs whose episode just ended reset and ignore their action)."""
        if self._state is None:
            raise RuntimeError("call reset() before step()")
        actions = np.asarray(actions, np.int64 if self.task.discrete else np.float32)
        if actions.shape != self.action_space.shape:
            raise ValueError(f"actions must have shape {self.action_space.shape} (envs"
                             + ("" if self.task.discrete else ", action dim")
                             + f"), got {actions.shape}")
        if self.task.discrete:  # the task steps with the agent's one-hot actions
            actions = np.eye(self.task.action_dim, dtype=np.float32)[actions]
        if self._autoreset:
            self._state, outputs = _reset(self.task, self._state.key)
        else:
            self._state, outputs = _step(self.task, self._state, actions)
        outputs = jax.device_get(outputs)
        terminated = outputs["is_terminal"]
        truncated = outputs["is_last"] & ~terminated
        self._autoreset = bool((terminated | truncated).all())  # lockstep: all or none
        return ({VECTOR_KEY: outputs[VECTOR_KEY]}, outputs["reward"], terminated, truncated,
                {})


def _outputs(task: MjxTask, state: MjxState) -> dict[str, jax.Array]:
    return {VECTOR_KEY: task.flat_obs(state.obs), "reward": state.reward,
            "is_last": state.is_last, "is_terminal": state.is_terminal}


@functools.partial(jax.jit, static_argnums=0)
def _reset(task: MjxTask, keys: jax.Array) -> tuple[MjxState, dict]:
    state = jax.vmap(task.reset)(keys)
    return state, _outputs(task, state)


@functools.partial(jax.jit, static_argnums=0)
def _step(task: MjxTask, state: MjxState, actions: jax.Array) -> tuple[MjxState, dict]:
    state = jax.vmap(task.step)(state, actions)
    return state, _outputs(task, state)
