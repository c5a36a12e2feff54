"""Experience collection across the host boundary: the policy on the device, envs in Python.

A :class:`Collector` runs a jitted policy step, pulls the action to the host and steps an
:class:`EnvBatch` (N gymnasium envs with NEXT_STEP autoreset, or one vector env), a chunk of
agent steps at a time. Every observation reaches the policy once, in order; each env's
transitions are recorded into episodes in the replay's format (docs/environments.md)::

      <observation keys> [T, ...], action [T, A] float32 (zeros at t=0; one-hot if discrete),
      reward [T] float32 (0 at t=0), is_first [T], is_terminal [T] bool

and every finished episode goes to ``on_episode(episode, env_index, info)`` after its chunk
(``info``: ``return``, ``length`` in agent steps, the env's scalar info at the last step).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import gymnasium
import jax
import jax.numpy as jnp
import numpy as np

from vsgjax.agents.acting import Policy
from vsgjax.config import EnvConfig
from vsgjax.envs import EnvSpec, env_spec, make_envs
from vsgjax.episode_keys import IMAGE_KEY, STEP_KEYS, STREAM_KEYS

OnEpisode = Callable[[dict, int, dict], None]
DEFAULT_CHUNK = 50


# --- host side -------------------------------------------------------------------------------


class EnvBatch:
    """N envs stepped together on the host (worker processes when N > 1), recording episodes.

    ``envs``: functions that build the envs (they must be picklable when workers are used:
    module-level functions or ``functools.partial`` of them), or one gymnasium vector env with
    NEXT_STEP autoreset that steps all N itself (e.g. the MJX tasks' ``MjxVectorEnv``).
    """

    def __init__(self, envs: Sequence[Callable[[], gymnasium.Env]] | gymnasium.vector.VectorEnv,
                 *, workers: bool | None = None):
        self._envs = _vector_env(envs, workers)
        self.spec: EnvSpec = env_spec(self._envs)
        self.num_envs = self._envs.num_envs
        self._done = np.zeros(self.num_envs, bool)
        self._episodes = [self._empty_episode() for _ in range(self.num_envs)]
        self._returns = np.zeros(self.num_envs, np.float64)
        self.finished: list[tuple[dict, int, dict]] = []

    def reset(self) -> dict[str, np.ndarray]:
        """Reset every env (each with the seed it was made with) and start new episodes."""
        observation, _ = self._envs.reset()
        n = self.num_envs
        self._done[:] = False
        self._episodes = [self._empty_episode() for _ in range(n)]
        self._returns[:] = 0.0
        obs = _observation(observation, np.zeros(n, np.float32), np.ones(n, bool),
                           np.zeros(n, bool), np.zeros(n, bool))
        self._record(obs, np.zeros((n, self.spec.action_dim), np.float32), {})
        return obs

    def step(self, action: np.ndarray) -> dict[str, np.ndarray]:
        """Step every env with the agent's actions ``[N, A]`` (one-hot if discrete)."""
        action = np.asarray(action, np.float32)
        env_action = action.argmax(-1) if self.spec.discrete else action
        observation, reward, terminated, truncated, infos = self._envs.step(env_action)
        is_first = self._done.copy()  # NEXT_STEP: these envs just reset and ignored the action
        self._done = terminated | truncated
        obs = _observation(observation, reward.astype(np.float32), is_first, terminated,
                           self._done)
        self._record(obs, np.where(is_first[:, None], 0.0, action).astype(np.float32), infos)
        return obs

    def _record(self, obs: dict[str, np.ndarray], action: np.ndarray, infos: dict) -> None:
        for i in range(self.num_envs):
            if obs["is_first"][i]:
                self._episodes[i] = self._empty_episode()
                self._returns[i] = 0.0
            episode = self._episodes[i]
            for key in (*self.spec.obs.keys, *STEP_KEYS):
                episode[key].append(obs[key][i])
            episode["action"].append(action[i])
            self._returns[i] += obs["reward"][i]
            if obs["is_last"][i]:
                info = {"return": float(self._returns[i]), "length": len(episode["reward"]) - 1,
                        **_env_info(infos, i)}
                self.finished.append(({k: np.stack(v) for k, v in episode.items()}, i, info))

    def _empty_episode(self) -> dict[str, list]:
        return {key: [] for key in (*self.spec.obs.keys, "action", *STEP_KEYS)}

    def close(self) -> None:
        self._envs.close()


def _vector_env(envs, workers: bool | None) -> gymnasium.vector.VectorEnv:
    """``envs`` as one NEXT_STEP-autoreset vector env (see :class:`EnvBatch`)."""
    mode = gymnasium.vector.AutoresetMode.NEXT_STEP
    if isinstance(envs, gymnasium.vector.VectorEnv):
        if workers:
            raise ValueError("workers=True applies to env functions; a vector env steps its "
                             "envs itself")
        if envs.metadata.get("autoreset_mode") != mode:
            raise ValueError(f"the vector env must autoreset with {mode}, got "
                             f"{envs.metadata.get('autoreset_mode')}")
        return envs
    workers = len(envs) > 1 if workers is None else workers
    if workers:
        return gymnasium.vector.AsyncVectorEnv(envs, context="spawn", autoreset_mode=mode)
    return gymnasium.vector.SyncVectorEnv(envs, autoreset_mode=mode)


def _observation(observation, reward, is_first, is_terminal, is_last) -> dict[str, np.ndarray]:
    """The batched observation dict: the env's observation keys (a plain array is the
    ``image``), then the step's reward and flags."""
    keys = dict(observation) if isinstance(observation, dict) else {IMAGE_KEY: observation}
    return {**keys, "reward": reward, "is_first": is_first, "is_terminal": is_terminal,
            "is_last": is_last}


def _env_info(infos: dict, index: int) -> dict[str, float]:
    """Env ``index``'s scalar info entries from a vector env's batched info dict."""
    values = {}
    for key, value in infos.items():
        if key.startswith("_") or not infos.get(f"_{key}", np.ones(index + 1, bool))[index]:
            continue
        if isinstance(value, dict):
            values.update({f"{key}/{k}": v for k, v in _env_info(value, index).items()})
        elif isinstance(value, np.ndarray) and value.ndim == 1 and value.dtype.kind in "biuf":
            values[key] = value[index].item()
    return values


class SeedEnvs:
    """The env batches of S seeds stepped as one: observations and actions ``[S, N, ...]``.

    Finished episodes are reported with the flat index ``seed * N + env``. The seeds' envs step
    one batch after the other.
    """

    def __init__(self, batches: Sequence[EnvBatch]):
        self.batches = list(batches)
        self.spec, self.num_envs = self.batches[0].spec, self.batches[0].num_envs
        if any(b.spec != self.spec or b.num_envs != self.num_envs for b in self.batches):
            raise ValueError("every seed's env batch needs the same spec and number of envs")

    def reset(self) -> dict[str, np.ndarray]:
        return _stack_observations([batch.reset() for batch in self.batches])

    def step(self, action: np.ndarray) -> dict[str, np.ndarray]:
        return _stack_observations([b.step(a) for b, a in zip(self.batches, action, strict=True)])

    @property
    def finished(self) -> list[tuple[dict, int, dict]]:
        return [(episode, seed * self.num_envs + index, info)
                for seed, batch in enumerate(self.batches)
                for episode, index, info in batch.finished]

    @finished.setter
    def finished(self, value: list) -> None:
        if value:
            raise ValueError("SeedEnvs.finished can only be cleared")
        for batch in self.batches:
            batch.finished = []

    def drop(self, keep: Sequence[int]) -> None:
        """Keep only the seeds at the positions ``keep`` (the others' envs are closed)."""
        for position, batch in enumerate(self.batches):
            if position not in keep:
                batch.close()
        self.batches = [self.batches[position] for position in keep]

    def close(self) -> None:
        for batch in self.batches:
            batch.close()


def _stack_observations(observations: list[dict]) -> dict[str, np.ndarray]:
    return {key: np.stack([obs[key] for obs in observations]) for key in observations[0]}


def make_env_batch(env_cfg: EnvConfig, seed: int, num_envs: int, *, eval: bool = False,
                   workers: bool | None = None) -> EnvBatch:
    """``num_envs`` envs of ``env_cfg.task`` seeded ``seed, seed + 1, ...`` (eval envs on the
    disjoint range ``+ EVAL_SEED_OFFSET``); the ``mjx_`` tasks as one vectorised MJX env."""
    if num_envs < 1:
        raise ValueError(f"num_envs must be >= 1, got {num_envs}")
    return EnvBatch(make_envs(env_cfg, seed, num_envs, eval=eval), workers=workers)


class Collector:
    """Runs ``policy`` in ``envs`` a chunk of ``chunk`` agent steps at a time.

    ``policy(params, carry, obs, key) -> (carry, action[N, A])`` is any jittable function over
    the batched observation dict; the step-``k`` key is ``jax.random.split(key, chunk)[k]``.
    With :class:`SeedEnvs` the policy is vmapped over seeds (``[S, N, ...]``, keys ``[S, 2]``)
    and the step-``k`` keys are each seed's own (:func:`step_keys`).
    """

    def __init__(self, envs: EnvBatch | SeedEnvs, policy: Policy, *, chunk: int = DEFAULT_CHUNK,
                 on_episode: OnEpisode | None = None):
        if chunk < 1:
            raise ValueError(f"chunk must be >= 1 agent step, got {chunk}")
        self.envs, self.chunk = envs, chunk
        self._on_episode = on_episode
        self._policy_step = jax.jit(policy)
        self._obs: dict | None = None

    def reset(self) -> None:
        """Start over: the next :meth:`run` resets every env (unfinished episodes are dropped).
        The caller resets its policy carry too (or relies on the policy resetting at is_first)."""
        self._obs = None
        self.envs.finished = []

    def run(self, params, carry, key: jax.Array) -> tuple[Any, dict[str, np.ndarray]]:
        """Collect one chunk; returns the new carry and the chunk's stream ``[chunk, N, ...]``:
        ``action`` (taken at step k) and the ``reward``, ``is_first``, ``is_terminal`` and
        ``is_last`` of the observation it led to. Finished episodes go to ``on_episode``."""
        if self._obs is None:
            self._obs = self.envs.reset()
        carry, stream = self._loop(params, carry, key)
        self._deliver_episodes()
        return carry, jax.tree.map(np.asarray, stream)

    def drop_seeds(self, keep: Sequence[int]) -> None:
        """With :class:`SeedEnvs`: keep only the seeds at the positions ``keep``."""
        self.envs.drop(keep)
        if self._obs is not None:
            self._obs = {key: value[np.asarray(keep)] for key, value in self._obs.items()}

    def _loop(self, params, carry, key):
        steps = []
        for step_key in np.asarray(step_keys(key, self.chunk)):
            carry, action = self._policy_step(params, carry, self._obs, step_key)
            action = np.asarray(action)
            self._obs = self.envs.step(action)
            steps.append(_stream_entry(action, self._obs))
        return carry, {k: np.stack([s[k] for s in steps]) for k in steps[0]}

    def _deliver_episodes(self) -> None:
        finished, self.envs.finished = self.envs.finished, []
        if self._on_episode is not None:
            for episode, index, info in finished:
                self._on_episode(episode, index, info)

    def close(self) -> None:
        self.envs.close()


def step_keys(key: jax.Array, chunk: int) -> jax.Array:
    """The ``chunk`` step keys of one chunk: ``split(key, chunk)`` of one key ``[2]``, or of
    each of S seeds' keys ``[S, 2]`` (-> ``[chunk, S, 2]``: step k's keys of every seed)."""
    if key.ndim == 1:
        return jax.random.split(key, chunk)
    return jnp.swapaxes(jax.vmap(jax.random.split, (0, None))(key, chunk), 0, 1)


def _stream_entry(action, obs: dict) -> dict:
    return {"action": action, **{k: obs[k] for k in STREAM_KEYS}}
