"""Evaluation while training: the agent acting in ``eval`` mode for whole episodes in
evaluation envs (seeds disjoint from training's), and the summary of their infos."""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np

from vsgjax.agents.acting import acting_policy
from vsgjax.agents.interface import Agent
from vsgjax.data.collect import Collector, EnvBatch

EVAL_CHUNK = 50  # agent steps per collection call while evaluating


class Evaluator:
    """Runs whole evaluation episodes with the actor's mode in dedicated envs."""

    def __init__(self, agent: Agent, envs: EnvBatch, chunk: int = EVAL_CHUNK):
        self.agent, self.envs = agent, envs
        self._finished: list[tuple[dict, dict]] = []
        self._collector = Collector(envs, acting_policy(agent, "eval"), chunk=chunk,
                                    on_episode=self._on_episode)

    def _on_episode(self, episode: dict, index: int, info: dict) -> None:
        self._finished.append((episode, info))

    def run(self, params: dict, episodes: int, key: jax.Array) -> tuple[list[dict], list[dict]]:
        """``episodes`` complete episodes from fresh resets -> (infos, recorded episodes)."""
        if episodes < 1:
            raise ValueError(f"episodes must be >= 1, got {episodes}")
        self._finished = []
        self._collector.reset()
        carry = self.agent.initial_carry(self.envs.num_envs)
        inputs = (params, jnp.asarray(False))
        while len(self._finished) < episodes:
            key, chunk_key = jax.random.split(key)
            carry, _ = self._collector.run(inputs, carry, chunk_key)
        done = self._finished[:episodes]
        return [info for _, info in done], [episode for episode, _ in done]

    def close(self) -> None:
        self._collector.close()


def summarize(infos: list[dict]) -> dict[str, float]:
    """Mean of every numeric entry over episodes (NaN entries, e.g. 'never visited', skipped),
    plus the standard deviation of the return."""
    keys = sorted({k for info in infos for k, v in info.items() if isinstance(v, int | float)})
    summary = {}
    for key in keys:
        values = [float(info[key]) for info in infos if key in info and math.isfinite(info[key])]
        if values:
            summary[key] = float(np.mean(values))
    summary["return_std"] = float(np.std([info["return"] for info in infos]))
    return summary
