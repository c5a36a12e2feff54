"""Evaluating a run directory's newest checkpoint (``python -m vsgjax.evaluate``): episode
infos, their table, and the JSON lines file of them."""

from __future__ import annotations

import json
import math
from pathlib import Path

import jax

from vsgjax.agents import make_agent
from vsgjax.data import checkpoint
from vsgjax.data.collect import make_env_batch
from vsgjax.loop.evaluator import Evaluator, summarize
from vsgjax.loop.run_state import restore_latest
from vsgjax.loop.rundir import RunDir, episode_records


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
    agent = make_agent(config, envs.spec)
    key = jax.random.PRNGKey(seed)
    restored = restore_latest(rundir.ckpt_dir, agent, key)
    if restored is None:
        envs.close()
        raise FileNotFoundError(f"no readable checkpoint in {rundir.ckpt_dir}")
    evaluator = Evaluator(agent, envs)
    try:
        infos, _ = evaluator.run(agent.acting_params(restored.tree["agent"]), episodes, key)
    finally:
        evaluator.close()
    return infos, restored.step  # checkpoints are numbered by env step


def write_episodes(path: Path, infos: list[dict], step: int) -> Path:
    """Write :func:`episode_records` as JSON lines to ``path`` atomically."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    text = "".join(json.dumps(record) + "\n" for record in episode_records(infos, step))
    return checkpoint.atomic_write(path, text.encode())
