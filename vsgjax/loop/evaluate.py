"""Evaluation: the actor's mode for whole episodes in evaluation envs (seeds disjoint from
training's), and evaluating a run directory's newest checkpoint (``python -m vsgjax.evaluate``).
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from vsgjax.data import checkpoint
from vsgjax.data.collect import Collector, EnvBatch, acting_policy, make_env_batch
from vsgjax.envs import resolve_loop
from vsgjax.envs.mjx import make_mjx_task
from vsgjax.loop.device_program import DeviceProgram
from vsgjax.loop.rundir import RunDir, episode_records
from vsgjax.model.agent import Agent, AgentState

EVAL_CHUNK = 50  # agent steps per collection call while evaluating


def checkpoint_tree(state: AgentState, key: jax.Array) -> dict:
    """What a checkpoint holds as arrays: the whole agent state and the training PRNG key."""
    return {"agent": state, "key": key}


def restore_latest(ckpt_dir: Path, agent: Agent, key: jax.Array,
                   max_step: int | None = None) -> checkpoint.Checkpoint | None:
    """The newest readable checkpoint (of a step up to ``max_step``, if given) filled into the
    agent's structure, or None. A device-loop run's checkpoint holds its whole loop state
    (agent, device replay, key): its tree is given as ``{"agent", "key"}`` too."""
    if resolve_loop(agent.config) == "device":
        return _restore_device_run(ckpt_dir, agent, key, max_step)
    target = checkpoint_tree(jax.eval_shape(agent.init, key), key)  # shapes only, no compute
    return checkpoint.restore(ckpt_dir, target, max_step)


def _restore_device_run(ckpt_dir: Path, agent: Agent, key: jax.Array,
                        max_step: int | None) -> checkpoint.Checkpoint | None:
    env = agent.config.env
    program = DeviceProgram(agent.config,
                            make_mjx_task(env.task, env.action_repeat, env.time_limit))
    restored = checkpoint.restore(ckpt_dir, {"loop": jax.eval_shape(program.init, key)},
                                  max_step)
    if restored is None:
        return None
    state = restored.tree["loop"]
    return restored._replace(tree=checkpoint_tree(state.agent, state.key))


class Evaluator:
    """Runs whole evaluation episodes with the actor's mode in dedicated envs."""

    def __init__(self, agent: Agent, envs: EnvBatch, chunk: int = EVAL_CHUNK):
        self.agent, self.envs = agent, envs
        self._finished: list[tuple[dict, dict]] = []
        self._collector = Collector(envs, acting_policy(agent, envs.spec, "eval"), chunk=chunk,
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


def format_table(infos: list[dict]) -> str:
    """A plain-text table: one row per episode, one column per info entry, then the mean."""
    keys = ["return", "length"] + sorted({k for info in infos for k in info} - {"return", "length"})
    rows = [[str(i)] + [_cell(info.get(k)) for k in keys] for i, info in enumerate(infos)]
    summary = summarize(infos)
    rows.append(["mean"] + [_cell(summary.get(k)) for k in keys])
    header = ["episode"] + keys
    widths = [max(len(r[c]) for r in [header] + rows) for c in range(len(header))]
    lines = ["  ".join(cell.rjust(width) for cell, width in zip(row, widths, strict=True))
             for row in [header] + rows]
    lines.insert(1, "  ".join("-" * w for w in widths))
    lines.insert(-1, lines[1])
    return "\n".join(lines)


def _cell(value) -> str:
    if value is None:
        return "-"
    if isinstance(value, float):
        return f"{value:.3f}" if math.isfinite(value) else "nan"
    return str(value)


def evaluate_logdir(logdir: Path, episodes: int | None = None, seed: int | None = None
                    ) -> tuple[list[dict], int]:
    """Run the newest checkpoint of ``logdir`` -> (episode infos, checkpoint env step)."""
    rundir = RunDir(logdir)
    config = rundir.load_config()
    if not rundir.checkpoints():
        raise FileNotFoundError(f"{logdir} has no checkpoint in {rundir.ckpt_dir}: "
                                "train the run first")
    seed = config.train.seed if seed is None else seed
    episodes = config.train.eval_episodes if episodes is None else episodes
    envs = make_env_batch(config.env, seed, config.env.eval_envs, eval=True)
    agent = Agent(config, envs.spec.obs, envs.spec.action_dim, envs.spec.discrete)
    key = jax.random.PRNGKey(seed)
    restored = restore_latest(rundir.ckpt_dir, agent, key)
    if restored is None:
        envs.close()
        raise FileNotFoundError(f"no readable checkpoint in {rundir.ckpt_dir}")
    evaluator = Evaluator(agent, envs)
    try:
        infos, _ = evaluator.run(restored.tree["agent"].params, episodes, key)
    finally:
        evaluator.close()
    return infos, restored.step  # checkpoints are numbered by env step


def write_episodes(path: Path, infos: list[dict], step: int) -> Path:
    """Write :func:`episode_records` as JSON lines to ``path`` atomically."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    text = "".join(json.dumps(record) + "\n" for record in episode_records(infos, step))
    return checkpoint.atomic_write(path, text.encode())
