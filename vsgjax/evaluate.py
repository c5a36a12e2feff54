"""Evaluation: run the actor's mode for whole episodes; ``python -m vsgjax.evaluate LOGDIR``.

The training loop (:mod:`vsgjax.train`) and this command share the pieces defined here: the
acting policy used for collection, the layout of a checkpoint, and :class:`Evaluator`, which
runs ``episodes`` complete episodes in separate evaluation envs (seeds disjoint from training's)
and returns each episode's ``info`` (return, length, and env metrics such as BringBackShapes'
``discovery/*``) plus the recorded episodes for videos.

    python -m vsgjax.evaluate runs/bbs_basic-vsg-s0 --episodes 10
    python -m vsgjax.evaluate runs/bbs_basic-vsg-s0 --episodes 50 --output evaluation.jsonl

``--output`` writes one JSON object per episode and line, as the trainer's
``eval_episodes.jsonl``: ``{"step": <checkpoint env step>, "episode": i, "return": ...,
"length": ..., "discovery/...": ...}`` with NaN written as ``null``. The file is written
atomically once every episode has run, so a killed evaluation leaves no partial file.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from vsgjax import checkpoint
from vsgjax.agent import Agent, AgentState
from vsgjax.collect import Collector, EnvBatch, make_env_batch, random_policy
from vsgjax.config import Config, from_dict
from vsgjax.envs import EnvSpec, resolve_loop

EVAL_CHUNK = 50  # agent steps per collection call while evaluating


def acting_policy(agent: Agent, spec: EnvSpec, mode: str):
    """A collection policy over ``(agent params, explore_randomly)``.

    ``explore_randomly`` (a bool scalar) swaps the agent's action for a uniform random one
    (the prefill phase) while the agent's latent state still follows the observations, so one
    compiled collector serves prefill and training.
    """
    uniform = random_policy(spec)

    def policy(inputs, carry, obs, key):
        params, explore_randomly = inputs
        agent_key, random_key = jax.random.split(key)
        carry, action = agent.policy_step(params, carry, obs, agent_key, mode=mode)
        _, random_action = uniform(None, None, obs, random_key)
        return carry, jnp.where(explore_randomly, random_action, action)

    return policy


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
    from vsgjax.device_loop import DeviceLoop
    from vsgjax.envs.mjx import make_mjx_task

    env = agent.config.env
    loop = DeviceLoop(agent.config, make_mjx_task(env.task, env.action_repeat, env.time_limit))
    restored = checkpoint.restore(ckpt_dir, {"loop": jax.eval_shape(loop.init, key)}, max_step)
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


def load_config(logdir: Path) -> Config:
    path = logdir / "config.json"
    if not path.exists():
        raise FileNotFoundError(f"{path} not found: is {logdir} a training log directory?")
    return from_dict(json.loads(path.read_text()))


def evaluate_logdir(logdir: Path, episodes: int | None = None, seed: int | None = None
                    ) -> tuple[list[dict], int]:
    """Run the newest checkpoint of ``logdir`` -> (episode infos, checkpoint env step)."""
    config = load_config(logdir)
    if not checkpoint.list_checkpoints(logdir / "checkpoints"):
        raise FileNotFoundError(f"{logdir} has no checkpoint in {logdir / 'checkpoints'}: "
                                "train the run first")
    seed = config.train.seed if seed is None else seed
    episodes = config.train.eval_episodes if episodes is None else episodes
    envs = make_env_batch(config.env, seed, config.env.eval_envs, eval=True)
    agent = Agent(config, envs.spec.obs, envs.spec.action_dim, envs.spec.discrete)
    key = jax.random.PRNGKey(seed)
    restored = restore_latest(logdir / "checkpoints", agent, key)
    if restored is None:
        envs.close()
        raise FileNotFoundError(f"no readable checkpoint in {logdir / 'checkpoints'}")
    evaluator = Evaluator(agent, envs)
    try:
        infos, _ = evaluator.run(restored.tree["agent"].params, episodes, key)
    finally:
        evaluator.close()
    return infos, restored.step  # checkpoints are numbered by env step


def episode_records(infos: list[dict], step: int) -> list[dict]:
    """One JSON-able record per episode: ``{"step", "episode", **info}``, NaN/inf -> None."""
    return [{"step": step, "episode": index,
             **{k: (None if isinstance(v, float) and not math.isfinite(v) else v)
                for k, v in info.items()}} for index, info in enumerate(infos)]


def write_episodes(path: Path, infos: list[dict], step: int) -> Path:
    """Write :func:`episode_records` as JSON lines to ``path`` atomically."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    text = "".join(json.dumps(record) + "\n" for record in episode_records(infos, step))
    return checkpoint.atomic_write(path, text.encode())


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m vsgjax.evaluate", description=__doc__.split(
        "\n")[0])
    parser.add_argument("logdir", type=Path, help="a training run's log directory")
    parser.add_argument("--episodes", type=int, default=None,
                        help="episodes to run (default: the run's train.eval_episodes)")
    parser.add_argument("--seed", type=int, default=None,
                        help="evaluation env seed (default: the run's seed)")
    parser.add_argument("--output", type=Path, default=None, metavar="PATH",
                        help="also write the episodes as JSON lines to PATH (atomically)")
    args = parser.parse_args(argv)
    try:
        infos, env_steps = evaluate_logdir(args.logdir, args.episodes, args.seed)
    except (FileNotFoundError, ValueError) as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    print(f"{args.logdir}: checkpoint at env step {env_steps}, {len(infos)} episodes, "
          "actor mode")
    print(format_table(infos))
    if args.output is not None:
        print(f"wrote {len(infos)} episodes to {write_episodes(args.output, infos, env_steps)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
