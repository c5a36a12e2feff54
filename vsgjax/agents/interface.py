"""The interface every agent implements; the loops, evaluation, checkpoints and ``vsgjax.load``
use nothing else.

An agent is a frozen (hashable, jit-static) object built by
:func:`vsgjax.agents.make_agent` from a config and the env's spec::

    agent = make_agent(config, spec)                 # spec: .obs, .action_dim, .discrete
    state = agent.init(key)                          # a pytree with a .step (updates made)
    params = agent.acting_params(state)              # what acting reads (a pytree)
    carry = agent.initial_carry(num_envs)            # what acting carries between steps
    carry, action = agent.policy_step(params, carry, obs, key, mode="train")
    state, metrics = agent.train_step(state, batch, key)

``obs`` is a batch of the spec's observation keys plus ``is_first`` ``[N]`` (the carry is reset
where it is set). ``batch`` is what the replay samples for ``agent.replay``: windows of
``history + length`` consecutive steps of one episode each (``[B, history + length, ...]`` of
every episode key), whose first ``history`` steps repeat the episode's first step where the
window starts before it (frame stacking). ``metrics`` are float scalars named
``<part>/<name>``. Actions are float32 ``[N, A]``: in [-1, 1], or one-hot when discrete.

An agent with a world model may also offer ``open_loop_video(state, episode, key) -> uint8
frames or None``, which the host loop writes beside the evaluation videos, and
``open_loop_errors(state, episodes, key) -> {"obs_mse": [H], "reward_mse": [H]} or None``, its
prediction error at each of H imagined steps after observing the start of a batch of episodes
``[N, T]`` (jittable: the device loop computes it inside its compiled evaluation), which both
loops log at every evaluation (``open_loop.jsonl``; the Dreamer family's is
:func:`vsgjax.agents.dreamer.open_loop.open_loop_errors`); one whose latent states carry gates
sets ``gated`` and offers ``gate_summary(state, batch, memory_gap=0) -> {name: float}``,
which both loops log (:mod:`vsgjax.loop.gate_logging`). The loops look the optional hooks up with ``getattr``: an
agent without a world model (DrQ-v2) offers none and writes none of these.
"""

from __future__ import annotations

from typing import Any, NamedTuple, Protocol

import jax

from vsgjax.config import Config

POLICY_MODES = ("train", "eval")  # "train": explore as the agent trains; "eval": its best guess


class ReplayNeeds(NamedTuple):
    """What an update samples: windows of ``length`` steps inside one episode, each with the
    ``history`` steps before it (edge-padded with the episode's first step)."""

    length: int
    history: int = 0


class Agent(Protocol):
    config: Config
    action_dim: int
    discrete: bool

    @property
    def replay(self) -> ReplayNeeds: ...

    def init(self, key: jax.Array) -> Any: ...

    def acting_params(self, state: Any) -> Any: ...

    def initial_carry(self, num_envs: int) -> Any: ...

    def policy_step(self, params: Any, carry: Any, obs: dict, key: jax.Array, *,
                    mode: str = "train") -> tuple[Any, jax.Array]: ...

    def train_step(self, state: Any, batch: dict, key: jax.Array) -> tuple[Any, dict]: ...


class AgentParams(NamedTuple):
    """A trained agent's parameters with the config they were trained with (what
    ``vsgjax.load`` gives for an agent without a world model; the Dreamer family's is
    :class:`~vsgjax.agents.dreamer.api.TrainedParams`)."""

    params: dict
    config: Config


def check_mode(mode: str) -> None:
    if mode not in POLICY_MODES:
        raise ValueError(f"unknown policy mode {mode!r}; valid: {', '.join(POLICY_MODES)}")
