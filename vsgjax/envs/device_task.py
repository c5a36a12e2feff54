"""The interface of an on-device task family: what the device loop
(:mod:`vsgjax.loop.device_program`) steps inside its compiled program.

A family registers in :mod:`vsgjax.registry.tasks` (``on_device=True``) with ``parse`` (the
task name), ``build`` (``(env_cfg) -> DeviceTask``), its ``options`` (the ``env.*`` keys only
its tasks take) and ``check`` (``(config) -> None``: its options against the rest of the
config, before anything is built). ``mjx_`` (:mod:`vsgjax.envs.mjx`) and ``gymnax_``
(:mod:`vsgjax.envs.gymnax_tasks`) implement it.

The loop runs the N envs of a run in lockstep, so every episode of a task lasts
:attr:`DeviceTask.episode_steps` agent steps, and it ends there either by truncation (MJX's
time limit, ``is_last``) or by termination (MemoryChain, ``is_last`` and ``is_terminal``).
The loop resets every env at the start of each episode inside its compiled program
(``reset`` with a fresh key), records the reset observation as step 0 (``is_first``, zero
action and reward) and step t as the observation that action t - 1 led to (the host format).
"""

from __future__ import annotations

from typing import Any, Protocol

import jax


class DeviceState(Protocol):
    """One env's state after ``reset`` or ``step`` (a pytree; the loop batches it with vmap).

    ``obs``: ``{key: array}`` in the task's ``obs_keys``; ``reward``: this step's (0 after
    reset); ``is_first``: set by ``reset`` only; ``is_last``: the episode ended at this step;
    ``is_terminal``: it ended by termination (no value beyond it), not by a time limit.
    """

    obs: dict[str, jax.Array]
    reward: jax.Array
    is_first: jax.Array
    is_last: jax.Array
    is_terminal: jax.Array


class DeviceTask(Protocol):
    """A task stepped inside JAX; frozen and hashable (a static argument of ``jax.jit``).

    ``action_dim``: the agent's action size; ``discrete``: actions are one-hot vectors of that
    size (the task takes their argmax), else values in ``[-1, 1]``. ``action_repeat``: env
    steps per agent step (the run's step counters count env steps). ``episode_steps``: agent
    steps per episode, the same for every episode. ``obs_keys`` and ``observation_spec()``
    (``{key: (shape, dtype)}``): vector observations, which ``flat_obs`` concatenates into the
    one ``vector`` the agent reads (leading batch axes kept).

    A task that asks for memory may also name its gap, ``memory_gap``: the agent steps between
    a cue and the step that asks for it (MemoryChain's L); the gated agents' logs then report
    the units held closed that long (``gates/holding_<gap>``, beside the fixed gaps).
    """

    name: str
    action_dim: int
    discrete: bool
    action_repeat: int
    episode_steps: int
    obs_keys: tuple[str, ...]

    def observation_spec(self) -> dict[str, tuple[tuple[int, ...], Any]]: ...

    def flat_obs(self, obs: dict[str, jax.Array]) -> jax.Array: ...

    def reset(self, key: jax.Array) -> DeviceState: ...

    def step(self, state: DeviceState, action: jax.Array) -> DeviceState: ...
